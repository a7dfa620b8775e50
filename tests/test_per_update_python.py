"""Issue 48's per-update Python around the solve (docs/performance.md section 25): each shortcut
gives the numbers of the code it replaced, bit for bit, and refuses what it refused.

The compiled Hall and tracker noise against numpy's generator (every key, long streams through
the ziggurat's rare branches), the watchdog's closest pair against numpy's norms, the
navigator's joysticks and misalignment against the numpy expressions they replaced, the unit's
input checks (a NaN or an inf still refused naming the system, the port and the time; huge
finite commands still taken), and the feeder's cached outputs against a fresh context's. The
whole ring's JSON, identical to the code before apart from its CPU times, is the section's
A/B (not a test: minutes)."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from ballchain.infrastructure.errors import NonFiniteSignal
from ballchain.systems.actuation_unit import ActuationUnit
from ballchain.systems.autonomous_navigator import AutonomousNavigator, NavigatorParams
from ballchain.systems.chain_monitor import closest_pair_distance
from ballchain.systems.feeder import Feeder
from ballchain.systems.randomness import MAX_SEED, SampleGenerators
from ballchain.systems.unit_config import right_unit

RNG = np.random.default_rng(20261207)

# (seed, k) pairs at the edges of the entropy's 32-bit words and of the compiled path's range
# (2**63 and beyond: numpy's own default_rng).
KEYS = [(0, 0), (0, 1), (1, 0), (MAX_SEED, 0), (MAX_SEED, 2**32 - 1), (5, 2**32), (7, 2**40 + 3),
        (MAX_SEED, 2**63 - 1), (3, 2**63), (3, 2**64 + 5)]


def _same(a, b) -> bool:
    """Bit for bit (a NaN equal to a NaN of the same bits, -0.0 not 0.0)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


# -- the noise ----------------------------------------------------------------------------------


def test_the_compiled_normals_are_default_rngs():
    generators = SampleGenerators()
    keys = KEYS + [tuple(int(v) for v in RNG.integers(0, MAX_SEED + 1, 2)) for _ in range(400)]
    keys += [(seed, k) for seed in range(3) for k in range(300)]
    for seed, k in keys:
        assert _same(generators.standard_normal(seed, k, 5), np.random.default_rng((seed, k)).standard_normal(5))
        for scale in (3e-6, 0.0, 2.5):
            assert _same(generators.normal(seed, k, scale, 3),
                         np.random.default_rng((seed, k)).normal(scale=scale, size=3)), (seed, k, scale)


def test_a_long_compiled_stream_is_numpys_through_the_ziggurats_rare_branches():
    """200 000 draws: about 1 % take the wedge's test (an exp) and about 50 the tail beyond
    ziggurat_nor_r (two log1p), each the same float as numpy's."""
    for seed, k in ((3, 5), (MAX_SEED, 2**40)):
        reference = np.random.default_rng((seed, k)).standard_normal(200_000)
        assert _same(SampleGenerators().standard_normal(seed, k, 200_000), reference)
        assert np.count_nonzero(np.abs(reference) > 3.6541528853610088) > 10  # the tail was drawn


def test_a_negative_scale_is_numpys_error():
    with pytest.raises(ValueError, match="scale"):
        SampleGenerators().normal(1, 2, -1.0, 3)


# -- the watchdog -------------------------------------------------------------------------------


def test_the_closest_pair_is_numpys_norms_min():
    for n in list(range(2, 24)) * 200:
        p = RNG.normal(size=(n, 3)) * 10.0 ** RNG.uniform(-4.0, 0.0)
        i, j = np.triu_indices(n, k=1)
        assert _same(closest_pair_distance(p), np.linalg.norm(p[i] - p[j], axis=1).min())
    p = RNG.normal(size=(16, 3))
    p[[3, 9]] = p[5]  # coincident balls: 0
    assert closest_pair_distance(p) == 0.0
    p[7, 2] = np.nan
    assert np.isnan(closest_pair_distance(p))


# -- the navigator ------------------------------------------------------------------------------


def _sticks_reference(params, m, m_des):
    """The joysticks as numpy expressions (the code before section 25; the hold band, then 1e-4
    rad, now ``params.hold_band``)."""
    from ballchain.drake_models.vectors import cross

    sticks = np.zeros((len(m), 3))
    for j, (a, b) in enumerate(zip(m, m_des)):
        axis = cross(a, b)
        sin = float(np.linalg.norm(axis))
        angle = float(np.arctan2(sin, a @ b))
        if angle < params.hold_band:
            continue
        u = min(params.magnet_gain * angle, 1.0) * axis / max(sin, 1e-12)
        u /= max(float(np.abs(u).max()), 1.0)
        sticks[j] = np.where(np.abs(u) > 1e-6,
                             np.sign(u) * (params.dead_band + (1.0 - params.dead_band) * np.abs(u)), 0.0)
    return sticks


def test_the_navigators_sticks_and_misalignment_are_the_numpy_expressions():
    navigator = AutonomousNavigator.__new__(AutonomousNavigator)
    for params in (NavigatorParams(), NavigatorParams(magnet_gain=200.0, dead_band=0.0, hold_band=1e-4)):
        navigator.params = params
        for n in range(6000):
            m = RNG.normal(size=(1 + n % 3, 3))
            m /= np.linalg.norm(m, axis=1, keepdims=True)
            m_des = m + 10.0 ** RNG.uniform(-6.0, 0.5) * RNG.normal(size=m.shape)
            m_des /= np.linalg.norm(m_des, axis=1, keepdims=True)
            if n % 7 == 0:
                m_des[0] = m[0]  # aligned: no stick
            if n % 11 == 0:
                m_des[-1] = -m[-1]  # antiparallel
            assert _same(AutonomousNavigator._sticks(navigator, m, m_des), _sticks_reference(params, m, m_des))
            reference = max(float(np.arccos(np.clip(a @ b, -1.0, 1.0))) for a, b in zip(m, m_des))
            assert _same(AutonomousNavigator._misalignment(m, m_des), reference)
        m_des[0, 1] = np.nan  # a NaN: no stick from it, the misalignment NaN, as before
        assert _same(AutonomousNavigator._sticks(navigator, m, m_des), _sticks_reference(params, m, m_des))
        assert np.isnan(AutonomousNavigator._misalignment(m, m_des))


# -- the unit's input checks ----------------------------------------------------------------------


def _unit_context(mode, teleop):
    unit = ActuationUnit(right_unit(), m_neutral_W=[-1.0, 0.2, 0.1])
    context = unit.CreateDefaultContext()
    unit.GetInputPort("mode").FixValue(context, [mode])
    unit.GetInputPort("omega_teleop_W").FixValue(context, teleop)
    return unit, context


@pytest.mark.parametrize("teleop", [[np.nan, 0.0, 0.0], [0.0, np.inf, 0.0], [0.0, 0.0, -np.inf],
                                    [np.inf, -np.inf, 0.0]])
def test_a_non_finite_command_is_refused_naming_the_unit_the_port_and_the_time(teleop):
    unit, context = _unit_context(0.0, teleop)
    with pytest.raises(NonFiniteSignal, match=r"right_unit\.unit: input port 'omega_teleop_W' is not finite at "
                                              r"t = 0 s \(element \d of 3"):
        Simulator(unit, context).AdvanceTo(0.02)


@pytest.mark.parametrize("mode", [np.nan, np.inf, -np.inf])
def test_a_non_finite_mode_is_refused_naming_the_unit_the_port_and_the_time(mode):
    unit, context = _unit_context(mode, np.zeros(3))
    with pytest.raises(NonFiniteSignal, match=r"right_unit\.unit: input port 'mode' is not finite at t = 0 s"):
        Simulator(unit, context).AdvanceTo(0.02)


def test_huge_finite_commands_are_taken_and_a_reconfiguration_does_not_read_the_command():
    """Finite numbers whose sum is past the largest float are not refused (the sum is only the
    fast test); in reconfiguration the command is not read, a NaN there included."""
    unit, context = _unit_context(0.0, [1e308, 1e308, 0.0])
    Simulator(unit, context).AdvanceTo(0.02)
    assert np.all(np.isfinite(unit.state(context)))
    unit, context = _unit_context(1.0, [np.nan, 0.0, 0.0])
    Simulator(unit, context).AdvanceTo(0.02)


# -- the feeder's cached outputs -----------------------------------------------------------------


def test_the_feeders_outputs_are_a_fresh_contexts_whatever_the_command_now():
    """The outputs depend on the time and the state alone (Drake's cache keeps them between): a
    new command at the same time and state leaves them as a fresh context computes them."""
    builder = DiagramBuilder()
    feeder = builder.AddSystem(Feeder(command_period=0.05))
    builder.ExportInput(feeder.get_input_port(0), "v")
    builder.ExportOutput(feeder.GetOutputPort("inserted_length"), "s")
    builder.ExportOutput(feeder.GetOutputPort("balls_out"), "n")
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.get_input_port(0).FixValue(context, [0.02])
    for t in (0.013, 0.05, 0.071, 0.2, 0.333):
        simulator.AdvanceTo(t)
        s, n = diagram.GetOutputPort("s").Eval(context)[0], diagram.GetOutputPort("n").Eval(context)[0]
        diagram.get_input_port(0).FixValue(context, [-0.02 if t > 0.1 else 0.015])
        fresh = diagram.CreateDefaultContext()
        fresh.SetTimeStateAndParametersFrom(context)
        diagram.get_input_port(0).FixValue(fresh, [0.0])
        assert diagram.GetOutputPort("s").Eval(context)[0] == s == diagram.GetOutputPort("s").Eval(fresh)[0]
        assert diagram.GetOutputPort("n").Eval(context)[0] == n == diagram.GetOutputPort("n").Eval(fresh)[0]
    assert s > 0.0


def test_the_navigators_memory_copy_shares_only_what_never_changes():
    """Drake's copy of the navigator's state: every attribute the same, the desired dipoles, the
    sticks and the open record's lists new objects, the closed records shared (they never change)."""
    import copy

    from ballchain.systems.autonomous_navigator import DwellRecord, _Memory

    closed, open_ = DwellRecord("a", 0.0, estimates=[(1.0, 0.1)]), DwellRecord("b", 2.0, estimates=[(3.0, 0.2)])
    memory = _Memory(k=1, phase="dwell", m_des=np.ones((1, 3)), stick=np.zeros((1, 3)), records=[closed, open_],
                     f_est=0.15, looks=(np.ones(3),))
    new = copy.deepcopy(memory)
    assert type(new) is _Memory and new is not memory
    assert {k: v for k, v in vars(new).items() if k not in ("m_des", "stick", "records")} == {
        k: v for k, v in vars(memory).items() if k not in ("m_des", "stick", "records")}
    assert new.m_des is not memory.m_des and np.array_equal(new.m_des, memory.m_des)
    assert new.stick is not memory.stick and np.array_equal(new.stick, memory.stick)
    assert new.records[0] is closed and new.records[1] is not open_ and type(new.records[1]) is DwellRecord
    assert vars(new.records[1]) == vars(open_)
    new.records[1].estimates.append((4.0, 0.3))
    assert open_.estimates == [(3.0, 0.2)]


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_quaternion_of_another_unit_is_refused_naming_the_port(bad):
    """The other units' quaternions (read at each Hall sample) are checked by their float sum:
    a non-finite one is refused naming the unit, the port and the time; huge finite ones pass
    the fast test to ``check_finite_input``, which takes them."""
    from ballchain.systems.unit_config import left_unit

    unit = ActuationUnit(right_unit(), m_neutral_W=[-1.0, 0.2, 0.1], others=[left_unit()])
    context = unit.CreateDefaultContext()
    unit.GetInputPort("mode").FixValue(context, [0.0])
    unit.GetInputPort("omega_teleop_W").FixValue(context, np.zeros(3))
    unit.GetInputPort("q_WM_left_unit").FixValue(context, [1.0, 0.0, bad, 0.0])
    with pytest.raises(NonFiniteSignal, match=r"right_unit\.unit: input port 'q_WM_left_unit' is not finite at "
                                              r"t = 0 s \(element 2 of 4"):
        Simulator(unit, context).AdvanceTo(0.02)
    unit.GetInputPort("q_WM_left_unit").FixValue(context, [1e308, 1e308, 0.0, 0.0])
    assert unit._q_others(context).tolist() == [[1e308, 1e308, 0.0, 0.0]]


def test_the_feeders_steps_are_the_builtins_loop_held_still_and_at_the_stops():
    """``Feeder._steps`` (the clamps written out, a still feeder's steps skipped) gives the floats of
    the loop with the builtins, signed zeros included, moving, held, and against either stop."""
    from ballchain.drake_models.params import BallChain

    rng = np.random.default_rng(3)
    chain = BallChain()
    feeder = Feeder(chain, initial_length=0.02, min_length=0.01)
    end = chain.length
    speeds = [0.0, -0.0, 1e-3, -1e-3, 0.02, -0.02, 0.05, -0.05]
    lengths = [0.01, 0.0100001, 0.02, end - 1e-6, end, 0.009, end + 1e-3]
    cases = [(v, x, c, n) for v in speeds for x in lengths for c in speeds for n in (0, 1, 2, 25, 300)]
    cases += [(rng.uniform(-0.03, 0.03), rng.uniform(0.0, end + 0.01), rng.uniform(-0.05, 0.05),
               int(rng.integers(0, 60))) for _ in range(5000)]
    taken = 0
    for v, x, c, n in cases:
        got, expected = feeder._steps(v, x, c, n), feeder._steps_reference(v, x, c, n)
        assert np.array_equal(np.array(got), np.array(expected)) and all(
            np.signbit(a) == np.signbit(b) for a, b in zip(got, expected)), (v, x, c, n, got, expected)
        taken += n > 0 and c == 0.0 and v == 0.0 and 0.01 < x < end
    assert taken > 20  # the still feeder's shortcut was taken
    got = feeder._steps(0.0, 0.02, float("nan"), 3)
    assert all(np.isnan(got)) and all(np.isnan(feeder._steps_reference(0.0, 0.02, float("nan"), 3)))
