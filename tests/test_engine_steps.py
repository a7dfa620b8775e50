"""The engine's continuation arithmetic on plain floats (``engine_kernels.magnet_moves``,
``interpolate_magnets``, the tip force in ``QuasiStaticEngine._tip_force``) gives the very floats
of the numpy expressions it replaced, and a whole teleoperation run is the same state for state."""

from types import SimpleNamespace

import numpy as np
import pytest

from ballchain.systems import engine_system
from ballchain.systems.engine_frames import _norms
from ballchain.systems.engine_kernels import interpolate_magnets, magnet_moves


def _numpy_moves(mag0, mag1):
    """The numpy expression ``_step_size`` had (before the plain floats)."""
    a, b = mag0.reshape(-1, 6), mag1.reshape(-1, 6)
    cos = np.einsum("ij,ij->i", a[:, 3:], b[:, 3:]) / (_norms(a[:, 3:]) * _norms(b[:, 3:]))
    return np.minimum(np.maximum(cos, -1.0), 1.0), float(_norms(a[:, :3] - b[:, :3]).max())


def _numpy_interpolate(mag0, mag1, f):
    a, b = mag0.reshape(-1, 6), mag1.reshape(-1, 6)
    out = (1 - f) * a + f * b
    out[:, 3:] /= _norms(out[:, 3:])[:, None]
    return out.ravel()


def _pairs(rng, k: int, count: int):
    """Magnet states as the engine meets them (a magnet turning by up to a few degrees, centres
    fixed or moving) and anywhere (random directions and sizes)."""
    for j in range(count):
        a = rng.normal(size=(k, 6)) * rng.uniform(1e-3, 10.0)
        if j % 3 == 0:  # turned a little, the same centre
            b = a.copy()
            b[:, 3:] += rng.normal(size=(k, 3)) * 1e-2 * np.abs(a[:, 3:]).max()
        elif j % 3 == 1:
            b = a + rng.normal(size=(k, 6)) * 1e-3
        else:
            b = rng.normal(size=(k, 6))
        yield a.ravel(), b.ravel()


@pytest.mark.parametrize("k", [1, 2, 3])
def test_magnet_moves_are_the_numpy_expressions_floats(k):
    rng = np.random.default_rng(k)
    for mag0, mag1 in _pairs(rng, k, 3000):
        cos, travel = magnet_moves(mag0, mag1)
        cos_np, travel_np = _numpy_moves(mag0, mag1)
        assert np.array_equal(np.asarray(cos), cos_np) and travel == travel_np
        assert float(np.arccos(np.asarray(cos)).max()) == float(np.arccos(cos_np).max())


def test_magnet_moves_clip_a_rounded_cosine_and_meet_antiparallel_magnets():
    m = np.array([0.0, 0.1, 0.2, 0.3, 0.7, -0.2])
    for mag1 in (m.copy(), np.concatenate([m[:3], -m[3:]]), np.concatenate([m[:3], 3.7 * m[3:]])):
        cos, travel = magnet_moves(m, mag1)
        cos_np, travel_np = _numpy_moves(m, mag1)
        assert np.array_equal(np.asarray(cos), cos_np) and travel == travel_np
        assert -1.0 <= cos[0] <= 1.0


@pytest.mark.parametrize("bad", ["zero direction", "nan", "inf"])
def test_magnet_moves_leave_numpys_special_cases_to_numpy(bad):
    """A zero-length direction (numpy's 0 / 0) or a non-finite number: None, and the engine's
    step size then is the numpy expression's, NaN and inf semantics included."""
    mag0 = np.array([0.1, 0.0, 0.0, 0.0, 1.0, 0.0, 0.2, 0.0, 0.0, 1.0, 0.0, 0.0])
    mag1 = mag0.copy()
    mag1[[3, 4, 5]] = {"zero direction": 0.0, "nan": np.nan, "inf": np.inf}[bad]
    assert magnet_moves(mag0, mag1) is None
    engine = SimpleNamespace(max_insertion_step=1e-3, max_angle_step=np.radians(1.0), wall_motion=None)  # what it reads
    with np.errstate(all="ignore"):
        cos, travel = _numpy_moves(mag0, mag1)
        expected = max(abs(0.0) / 1e-3, float(np.arccos(cos).max()) / np.radians(1.0), travel / 5e-3)
        got = engine_system.QuasiStaticEngine._step_size(engine, 0.02, 0.02, mag0, mag1)
    assert got == expected or (np.isnan(got) and np.isnan(expected))


@pytest.mark.parametrize("k", [1, 2])
def test_interpolated_magnets_are_the_numpy_expressions_floats(k):
    rng = np.random.default_rng(10 + k)
    for j, (mag0, mag1) in enumerate(_pairs(rng, k, 2000)):
        for f in (0.0, 1.0, 1 / 3, (j + 1) / (j + 2), rng.uniform()):
            assert np.array_equal(np.array(interpolate_magnets(mag0, mag1, f)), _numpy_interpolate(mag0, mag1, f))
            assert np.array_equal(engine_system.QuasiStaticEngine._interpolate(mag0, mag1, f),
                                  _numpy_interpolate(mag0, mag1, f))


def test_interpolation_through_a_zero_direction_is_numpys():
    mag0 = np.array([0.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    mag1 = np.array([0.0, 0.0, 0.0, 0.0, -1.0, 0.0])
    assert interpolate_magnets(mag0, mag1, 0.5) is None
    with np.errstate(all="ignore"):
        np.testing.assert_array_equal(engine_system.QuasiStaticEngine._interpolate(mag0, mag1, 0.5),
                                      _numpy_interpolate(mag0, mag1, 0.5))  # NaNs where numpy has them


class _Result:
    """What ``_tip_force`` reads of a ``StaticsResult``."""

    def __init__(self, positions, wall_forces_W):
        self.positions, self.wall_forces_W = positions, wall_forces_W


def _numpy_tip_force(d, p, f):
    out = np.zeros(6)
    out[3:] = p[-1]
    size = 0.0 if f is None else np.linalg.norm(f)
    if size > 0:
        out[:3] = f
        out[3:] = p[-1] - 0.5 * d * f / size
    return out


def test_tip_force_is_the_numpy_expressions_floats():
    rng = np.random.default_rng(7)
    engine = SimpleNamespace(_d=0.00635)  # what _tip_force reads
    tip_force = engine_system.QuasiStaticEngine._tip_force
    for j in range(2000):
        p = rng.normal(size=(16, 3)) * 0.03
        f = None if j % 5 == 0 else (np.zeros(3) if j % 5 == 1 else rng.normal(size=3) * rng.uniform(1e-6, 1.0))
        result = _Result(np.zeros((12, 3)), {} if f is None else {11: f})
        assert np.array_equal(np.array(tip_force(engine, p, result)), _numpy_tip_force(engine._d, p, f))
    p = rng.normal(size=(16, 3))
    assert np.array_equal(np.array(tip_force(engine, p, None)), _numpy_tip_force(engine._d, p, None))


def _engine_states(monkeypatch, plain_floats: bool):
    """Every state the engine writes over teleop_two_units (two magnets turning, the feeder moving),
    and how many steps took the plain floats' path."""
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation, run_station

    taken = []
    if plain_floats:
        def counted(fn):
            def wrapper(*args):
                out = fn(*args)
                taken.append(out is not None)
                return out
            return wrapper
        monkeypatch.setattr(engine_system, "magnet_moves", counted(magnet_moves))
        monkeypatch.setattr(engine_system, "interpolate_magnets", counted(interpolate_magnets))
    else:  # the numpy expressions, as before
        monkeypatch.setattr(engine_system, "magnet_moves", lambda *args: None)
        monkeypatch.setattr(engine_system, "interpolate_magnets", lambda *args: None)
    states = []
    store = engine_system.QuasiStaticEngine._store

    def recording(self, discrete_state, *args, **kwargs):
        store(self, discrete_state, *args, **kwargs)
        states.append(discrete_state.get_vector(self._state_index).CopyToVector())

    monkeypatch.setattr(engine_system.QuasiStaticEngine, "_store", recording)
    cd = MakeStation(load_scenario("teleop_two_units", "{engine: statics, mode: quasi-static}"))
    run = run_station(cd, duration=0.7)
    assert run.failure is None
    monkeypatch.undo()
    return states, taken


def test_a_teleoperation_run_is_the_numpy_expressions_state_for_state(monkeypatch):
    fast, taken = _engine_states(monkeypatch, plain_floats=True)
    reference, _ = _engine_states(monkeypatch, plain_floats=False)
    assert len(taken) > 20 and all(taken)  # the plain floats did the work
    assert len(fast) == len(reference) > 10
    for x, y in zip(fast, reference):
        assert np.array_equal(x, y)
