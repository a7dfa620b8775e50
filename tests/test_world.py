"""The world the navigator does not know (issue 43, ``drake_models.world``, ``systems.world_apply``):
its draw is Drake's reproducible randomness at the stated magnitudes, ``world: none`` changes
nothing, and a perturbed world's field at the chain differs from the nominal model's by what the
perturbation predicts."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from ballchain.drake_models.dipole import dipole_field, dipole_field_gradient
from ballchain.drake_models.world import NAMES, PRESETS, WorldMagnitudes, draw_world
from ballchain.drake_models.params import BallChain
from ballchain.experiments import teleop
from ballchain.experiments.procedure_runs import _estimator
from ballchain.experiments.procedure_world import with_world, world_block
from ballchain.infrastructure.errors import UserInputError
from ballchain.systems.magnetic_wrench import external_field_source
from ballchain.systems.station import MakeStation


def test_draw_is_reproducible_and_at_its_magnitudes():
    m = PRESETS["literature"]
    assert draw_world(m, 7, 2) == draw_world(m, 7, 2)
    assert draw_world(m, 7, 2).magnet_offsets != draw_world(m, 8, 2).magnet_offsets
    draws = [draw_world(m, seed, 1) for seed in range(300)]
    position = np.array([d.magnet_offsets[0] for d in draws]) * 1e3  # [mm], normal, 2 mm per axis
    assert abs(position.std() - m.magnet_position) < 0.12 * m.magnet_position
    assert abs(position.mean()) < 0.3
    remanence = np.array([d.ball_remanence_scale - 1.0 for d in draws]) * 100  # [%], uniform +-1.4 %
    assert np.all(np.abs(remanence) <= m.ball_remanence + 1e-12)
    assert abs(remanence.std() - m.ball_remanence / np.sqrt(3.0)) < 0.12 * m.ball_remanence / np.sqrt(3.0)
    none = draw_world(PRESETS["none"], 7, 2)
    assert not none.perturbed and none.anatomy_scale == 1.0 and not np.any(none.magnet_offsets)


def test_one_perturbation_alone_has_its_value_with_all():
    m = PRESETS["literature"]
    everything = draw_world(m, 3, 2)
    for name in ("magnet_position", "localisation_bias"):
        alone = draw_world(m.only([name]), 3, 2)
        if name == "magnet_position":
            assert alone.magnet_offsets == everything.magnet_offsets
            assert alone.localisation_bias == (0.0, 0.0, 0.0)
        else:
            assert alone.localisation_bias == everything.localisation_bias
            assert not np.any(alone.magnet_offsets)


@pytest.mark.parametrize("bad", [{"preset": "lab"}, {"preset": "literature", "only": ["wall"]}, 3])
def test_bad_world_refused(bad):
    with pytest.raises(UserInputError, match="world"):
        world_block(bad, 0)
    with pytest.raises(UserInputError, match="magnet_position must be a number in 0..20 mm"):
        WorldMagnitudes(magnet_position=-1.0)


def _station(world: dict | None):
    overrides = with_world(None, world, 5) if world is not None else None
    return MakeStation(teleop.scenario_for("world", None, overrides, None))


def _run(station, duration: float = 0.3) -> np.ndarray:
    context = station.diagram.CreateDefaultContext()
    for i in range(station.diagram.num_input_ports()):
        port = station.diagram.get_input_port(i)
        port.FixValue(context, np.zeros(port.size()))
    simulator = Simulator(station.diagram, context)
    simulator.AdvanceTo(duration)
    return station.ball_positions(simulator.get_context())


def test_world_none_changes_nothing():
    """The default world, ``preset: none`` and a world that only biases the tracker (which the
    engine never sees) build the same engine and give the same chain, bit for bit."""
    nominal = _station(None)
    names = {nominal.diagram.GetSystems()[k].get_name() for k in range(len(nominal.diagram.GetSystems()))}
    assert "world_magnets" not in names
    p0 = _run(nominal)
    assert with_world(None, "none", 5) is None
    p1 = _run(_station({"preset": "literature", "only": ["localisation_bias"]}))
    assert np.array_equal(p0, p1)
    moved = _run(_station({"preset": "literature", "only": ["magnet_position"], "scale": 2.0}))
    assert np.max(np.abs(moved - p0)) > 1e-5  # the world's magnet reaches the chain


def _fields(station, p_W: np.ndarray):
    """(the engine's field at p_W, the nominal model's: the units' own magnet states and magnets)."""
    engine = station.chain.engine_system
    context = station.diagram.CreateDefaultContext()
    for i in range(station.diagram.num_input_ports()):
        port = station.diagram.get_input_port(i)
        port.FixValue(context, np.zeros(port.size()))
    world_states = engine.get_magnet_states_input_port().Eval(engine.GetMyContextFromRoot(context))
    (unit,) = station.units.values()
    magnet = unit.magnet
    m_W = magnet.GetOutputPort("m_W").Eval(magnet.GetMyContextFromRoot(context))
    p_WM = np.asarray(unit.config.p_WM, float)
    B_world = engine._field(np.asarray(world_states)).field_and_gradient(p_W)[0]
    nominal = np.concatenate([p_WM, m_W])
    mag = unit.config.magnet
    B_nominal = external_field_source(None, [mag], np.array([mag.dipole_moment]), np.array([mag.bounding_radius]),
                                      nominal, unit.config.model).field_and_gradient(p_W)[0]
    return np.asarray(B_world), np.asarray(B_nominal), np.asarray(world_states), nominal, mag


def test_world_field_at_the_chain_differs_by_the_expected_amount():
    station = _station({"preset": "literature", "only": ["magnet_position", "magnet_magnetisation"], "seed": 11})
    draw = draw_world(PRESETS["literature"].only(["magnet_position", "magnet_magnetisation"]), 11, 1)
    p_W = np.asarray(station.chain.p_WE, float)  # the sheath exit, where the chain starts
    B_world, B_nominal, world_states, nominal, mag = _fields(station, p_W)
    dp = np.asarray(draw.magnet_offsets[0])
    assert np.allclose(world_states[:3], nominal[:3] + dp, rtol=0, atol=1e-15)
    assert np.allclose(world_states[3:], nominal[3:], rtol=0, atol=1e-15)
    # Exact: the moved magnet's field is the nominal field taken dp back, times the remanence.
    m = mag.dipole_moment * nominal[3:] / np.linalg.norm(nominal[3:])
    r = p_W - nominal[:3]
    expected = draw.magnet_scales[0] * dipole_field(r - dp, m)
    assert np.allclose(B_world, expected, rtol=1e-10, atol=0)
    assert np.allclose(B_nominal, dipole_field(r, m), rtol=1e-10, atol=0)
    # The navigator's own force model (``procedure_runs._estimator``) feels the nominal field.
    estimator = _estimator(SimpleNamespace(heart=station.heart, units=station.units), BallChain(), 16)
    p_S = estimator.R_WS.T @ (p_W - estimator.p_WE)
    B_navigator = estimator.R_WS @ np.asarray(estimator.field_S(nominal[3:]).field_and_gradient(p_S[None])[0]).reshape(3)
    assert np.allclose(B_navigator, B_nominal, rtol=1e-10, atol=0)
    # First order: dB = (dp . grad) B + (scale - 1) B, within the second-order terms (|dp| / |r|).
    G = dipole_field_gradient(r, m)  # dB_i / dr_j
    first = -G @ dp + (draw.magnet_scales[0] - 1.0) * B_nominal
    change = B_world - B_nominal
    assert np.linalg.norm(change) > 1e-3 * np.linalg.norm(B_nominal)  # measurably different
    assert np.linalg.norm(change - first) < 4.0 * np.linalg.norm(dp) / np.linalg.norm(r) * np.linalg.norm(change)


def test_world_preset_names_cover_the_perturbations():
    assert set(PRESETS["literature"].to_dict()) == set(NAMES)
    assert all(v > 0 for v in PRESETS["literature"].to_dict().values())


def test_the_monitor_sees_the_world_wall_from_the_nominal_one():
    """A point of the world's wall (scaled and turned about the sheath exit, then moved) is seen
    where it was on the nominal wall, and the sheath by its own displacement (``monitor_offsets``)."""
    from ballchain.systems.world_apply import monitor_offsets, perturbed_exit

    draw = draw_world(PRESETS["literature"], 2, 1)
    c, axis = np.array([0.01, -0.02, 0.005]), np.array([1.0, 0.0, 0.0])
    q = np.array([[0.03, 0.01, -0.02], [-0.01, 0.02, 0.0]])  # nominal wall points
    R = draw.anatomy_rotation_matrix()
    assert np.linalg.norm(draw.anatomy_rotation) > 0.0  # the literature world turns the anatomy
    p = c + draw.anatomy_scale * (q - c) @ R.T + np.asarray(draw.anatomy_offset)  # the same points of the world's wall
    exit_W = perturbed_exit(c, axis, draw)
    sheath, wall = monitor_offsets(draw, c, exit_W, p)
    assert np.allclose(p - wall, q, rtol=0, atol=1e-15)
    assert abs((exit_W - c - np.asarray(draw.anatomy_offset)) @ axis) < 1e-15  # across the axis only
    assert np.allclose(sheath, exit_W - c, rtol=0, atol=0)
