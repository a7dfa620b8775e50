"""The public API: ``import ballchain`` gives every exported name, lazily, each with its one-line
docstring; the station's readings take the root context; the first script of the README runs."""

import importlib
import subprocess
import sys

import numpy as np
import pytest

import ballchain as bc

SMALL = "free_space_uniform_90deg"  # no heart: builds in a fraction of a second


def test_every_exported_name_resolves_to_its_home_and_has_a_docstring_first_line():
    assert len(set(bc.__all__)) == len(bc.__all__)
    names = set(dir(bc))
    for name in bc.__all__:
        assert name in names, name
        obj = getattr(bc, name)
        if name == "__version__":
            assert isinstance(obj, str) and obj.count(".") == 2
            continue
        if name in bc._SUBPACKAGES:
            assert obj is importlib.import_module(f"ballchain.{name}")
        else:  # the old import path gives the same object
            assert obj is getattr(importlib.import_module(bc._EXPORTS[name]), name), name
        lines = (obj.__doc__ or "").strip().splitlines()
        assert lines and len(lines[0]) > 20, f"{name}: no docstring first line"
        # A dataclass without a docstring gets its signature as one: not a description.
        assert not lines[0].startswith(f"{getattr(obj, '__name__', name)}("), f"{name}: {lines[0]!r}"
        assert lines[0].rstrip().endswith((".", ")", ":")), f"{name}: first line {lines[0]!r} is cut short"


def test_the_paper_layer_packages_say_what_they_hold():
    for package in ("ballchain.systems", "ballchain.optimization", "ballchain.drake_models", "ballchain.experiments"):
        doc = importlib.import_module(package).__doc__ or ""
        assert len(doc.strip().splitlines()[0]) > 20, package
    assert "private by convention" in " ".join(bc.__doc__.split())


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'make_station'"):
        bc.make_station  # noqa: B018
    with pytest.raises(AttributeError, match="no attribute 'no_such_experiment'"):
        bc.experiments.no_such_experiment  # noqa: B018


def test_the_experiments_load_on_first_use():
    assert "alignment" in dir(bc.experiments) and "simulation" in dir(bc.experiments)
    assert callable(bc.experiments.alignment.run)
    assert bc.experiments.simulation is importlib.import_module("ballchain.experiments.simulation")


@pytest.mark.slow
def test_import_ballchain_does_not_import_drake_until_a_name_is_used():
    code = ("import sys, ballchain\n"
            "ballchain.__all__, dir(ballchain), ballchain.__version__\n"
            "print(any(m.split('.')[0] == 'pydrake' for m in sys.modules))\n"
            "ballchain.MakeStation\n"
            "print(any(m.split('.')[0] == 'pydrake' for m in sys.modules))\n"
            "print(all(getattr(ballchain, name) is not None for name in ballchain.__all__))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    # Not before a name is used; then it is (the check would see it). In a fresh interpreter
    # every name loads (no import cycle among their modules).
    assert out.split() == ["False", "True", "True"]


def test_scenario_descriptions_cover_every_scenario():
    descriptions = bc.scenario_descriptions()
    assert list(descriptions) == bc.scenario_names()
    assert all(len(d) > 10 for d in descriptions.values())
    assert bc.load_scenario(SMALL).description == descriptions[SMALL]


@pytest.mark.parametrize("engine", ["plant", "statics"])
def test_station_readings_take_the_root_context_or_the_chain_context(engine):
    station = bc.MakeStation(bc.load_scenario(SMALL, "{engine: %s}" % engine))
    outcome = bc.run_station(station, duration=0.1)
    assert outcome.failure is None and outcome.station is station
    root = outcome.context
    own = station.chain.system.GetMyContextFromRoot(root)
    p = station.chain.ball_positions(own)  # the engine's own reading of its own context
    assert p.shape == (station.scenario.n_balls, 3) and np.all(np.isfinite(p))
    for reading in (station.ball_positions(root), station.ball_positions(own), station.chain.ball_positions(root),
                    outcome.ball_positions):
        np.testing.assert_array_equal(reading, p)
    np.testing.assert_array_equal(outcome.tip_position, p[-1])
    np.testing.assert_array_equal(station.tip_position(root), p[-1])
    # The chain stays a chain: neighbours touch (the contact model's overlap is microns).
    d = station.chain.config.chain.ball_diameter
    np.testing.assert_allclose(np.linalg.norm(np.diff(p, axis=0), axis=1), d, atol=0.02 * d)
    assert station.tip_wall_force(root).shape == (3,)
    assert station.targets_touched(root) == []  # free space: no target rings


def test_a_context_of_another_system_is_refused():
    station = bc.MakeStation(bc.load_scenario(SMALL))
    root = station.diagram.CreateDefaultContext()
    other = next(s for s in station.diagram.GetSystems() if s is not station.chain.system)
    with pytest.raises(RuntimeError, match="root context"):
        station.ball_positions(other.GetMyContextFromRoot(root))


@pytest.mark.slow
def test_the_first_script_runs():
    """The README's Python example (docs), checked against the physics it shows."""
    station = bc.MakeStation(bc.load_scenario("heart_left_quasi_static"))
    outcome = bc.run_station(station, duration=1.0)
    assert outcome.failure is None
    tip = outcome.tip_position
    assert tip.shape == (3,) and station.heart.contains(tip[None])[0]
    root = outcome.context
    tracker = station.target_touches
    assert station.targets_touched(root) == tracker.touched_names(tracker.GetMyContextFromRoot(root))

    chain = bc.BallChain(n_balls=16)
    result = bc.ChainStatics(chain).solve(bc.UniformField([0.0, 0.023, 0.0]))
    assert result.converged
    # Ball 1 held at the origin along +x, the field along +y: the tip bends towards +y, in plane.
    p = result.tip_position
    assert p[1] > p[0] > 0.0 and p[2] == pytest.approx(0.0, abs=1e-12)
    assert np.linalg.norm(p) < (chain.n_balls - 1) * chain.ball_diameter


def test_unit_magnet_reading_takes_the_root_context():
    unit = "{name: right_unit, anchor: puncture, distance: 0.12, direction_W: [-1.0, 0.0, 0.0]}"
    station = bc.MakeStation(bc.load_scenario(SMALL, "{uniform_field: [0.0, 0.0, 0.0], units: [%s]}" % unit))
    root = station.diagram.CreateDefaultContext()
    unit = station.units["right_unit"]
    own = unit.magnet.magnet_source(unit.magnet.GetMyContextFromRoot(root))
    source = station.unit_magnet("right_unit", root)
    np.testing.assert_array_equal(source.m_W, own.m_W)
    # At the start the unit's dipole is its neutral direction.
    np.testing.assert_allclose(source.m_W / np.linalg.norm(source.m_W), unit.m_hat_initial_W, atol=1e-12)
    with pytest.raises(bc.UserInputError, match="no unit 'left_unit'.*right_unit"):
        station.unit_magnet("left_unit", root)
    with pytest.raises(bc.UserInputError, match=r"no unit \{\} in this station"):  # not a TypeError: unhashable
        station.unit_magnet({}, root)


class _UserUniformField:
    """A field source written by a user: only ``FieldSource``'s one method, no base class."""

    def __init__(self, B_W):
        self.B_W = np.asarray(B_W, dtype=float)

    def field_and_gradient(self, p_W):
        p = np.atleast_2d(np.asarray(p_W, dtype=float))
        return np.tile(self.B_W, (len(p), 1)), np.zeros((len(p), 3, 3))


def test_a_user_field_source_gives_the_uniform_fields_equilibrium():
    """A class implementing ``bc.FieldSource``'s protocol goes through ``ChainStatics.solve`` (the
    Newton statics evaluate it through the protocol alone) to the equilibrium of a ``UniformField``
    of the same value."""
    B_W = [0.0, 0.023, 0.0]
    chain = bc.BallChain(n_balls=12)
    mine = bc.ChainStatics(chain).solve(_UserUniformField(B_W))
    reference = bc.ChainStatics(chain).solve(bc.UniformField(B_W))
    assert mine.converged and reference.converged
    # The same minimum of the same energy; the user's source skips no evaluation (its gradient's
    # derivative is central differences of zeros): equal to rounding, 1e-12 of a ball diameter.
    np.testing.assert_allclose(mine.positions, reference.positions, rtol=0, atol=1e-12 * chain.ball_diameter)
    np.testing.assert_allclose(mine.energy, reference.energy, rtol=1e-12)
    assert mine.tip_position[1] > 0.0  # bent towards the field


class _UserAtrium:
    """An atrium written by a user: every member of ``bc.Atrium`` (here answered by a procedural
    atrium it holds, so the two stations must agree), no base class."""

    def __init__(self, inner):
        self._inner = inner
        for name in ("p_HP", "p_HE", "sheath_axis_H", "params", "rings", "ostia", "carinas", "lumen_key", "side"):
            setattr(self, name, getattr(inner, name))

    def contains(self, p_H):
        return self._inner.contains(p_H)

    @property
    def wall_tetrahedra(self):
        return self._inner.wall_tetrahedra

    @property
    def blood_surface(self):
        return self._inner.blood_surface

    def lumen_grid_contains(self, origin, spacing, shape):
        return self._inner.lumen_grid_contains(origin, spacing, shape)

    @property
    def wall_distance(self):
        return self._inner.wall_distance

    def write_files(self, directory=None):
        return self._inner.write_files(directory)

    # Targets on the procedural atrium's rings (not an anatomy file's) are placed by its ellipsoid
    # (``target_contact.heart_targets``): an atrium with such rings gives its semi-axes too.
    @property
    def semi_axes(self):
        return self._inner.semi_axes


def test_a_user_atrium_runs_in_the_station(heart):
    """An object implementing ``bc.Atrium``'s protocol is a station's heart: ``MakeStation`` and
    ``run_station`` use it through the protocol alone, to the same run as the atrium it answers from."""
    mine = _UserAtrium(heart)
    assert isinstance(mine, bc.Atrium) and not isinstance(mine, bc.LeftAtrium)
    scenario = bc.load_scenario("heart_left_quasi_static")
    runs = [bc.run_station(bc.MakeStation(scenario, heart=atrium), duration=0.02) for atrium in (mine, heart)]
    assert all(run.failure is None for run in runs)
    np.testing.assert_array_equal(runs[0].tip_position, runs[1].tip_position)
    assert mine.contains(runs[0].tip_position[None])[0]
