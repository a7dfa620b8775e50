"""Drake's conventions for randomness: a run is a function of its context; the default context
is the run it always was (the old seeding), ``set_random_context(RandomGenerator(seed))`` gives the
same run for the same seed and another run for another; the scenario's ``random_seed``."""

from dataclasses import replace

import numpy as np
import pytest
from pydrake.common import RandomGenerator
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import EventStatus

from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.kernels.actuation import X_K
from ballchain.systems.actuation_station import StationOptions, make_actuation_station, unit_system
from ballchain.systems.actuation_unit import ActuationUnit
from ballchain.systems.hall_sensor import quantise_reading
from ballchain.systems.randomness import MAX_SEED, seeded_systems, set_random_context
from ballchain.systems.simulated_operator import OperatorParams, SimulatedOperator
from ballchain.systems.unit_config import left_unit, right_unit

UNITS = ("right_unit", "left_unit")


def _station(seed: int = 0, compiled: bool = True):
    # Both units noisy, each sensor also seeing the other magnet (the station's default).
    return make_actuation_station([right_unit(model="dipole"), left_unit(model="dipole")],
                                  StationOptions(seed=seed, compiled_units=compiled))


def _sensor(diagram, name: str):
    """Unit ``name``'s Hall sensor: its ``ActuationUnit`` or the composed ``HallSensor``."""
    return unit_system(diagram, name, "hall_sensor")


def _last_sample(sensor, ctx) -> int:
    """The index of the sensor's last sample (its counter - 1)."""
    if isinstance(sensor, ActuationUnit):
        return int(sensor.state(ctx)[X_K]) - 1
    return int(ctx.get_discrete_state(1).GetAtIndex(0)) - 1


def _spec(sensor):
    return sensor.sensor_spec if isinstance(sensor, ActuationUnit) else sensor.spec


def _hold_and_log(station, context, t_end: float = 0.2) -> np.ndarray:
    """Magnets held still (teleoperation, stick at rest): the Hall readings at every step."""
    for n in UNITS:
        station.GetInputPort(f"{n}.mode").FixValue(context, [0.0])
        station.GetInputPort(f"{n}.joystick").FixValue(context, np.zeros(3))
    simulator = Simulator(station, context)
    log = []

    def monitor(ctx):
        log.append(np.concatenate([station.GetOutputPort(f"{n}.B_sensor_T").Eval(ctx) for n in UNITS]))
        return EventStatus.Succeeded()

    simulator.set_monitor(monitor)
    simulator.AdvanceTo(t_end)
    return np.array(log)


def _old_seeding_reading(station, context, k: int, seed: int) -> np.ndarray:
    """What unit k's sensor reads now by the old seeding: noise ``default_rng((seed, sample))``
    on the true field, then the ADC (the last sample's index is the sensor's counter - 1)."""
    sensor = _sensor(station, UNITS[k])
    ctx = sensor.GetMyContextFromRoot(context)
    sample = _last_sample(sensor, ctx)
    noise = np.random.default_rng((seed, sample)).normal(scale=_spec(sensor).noise_std_T, size=3)
    return quantise_reading(sensor.true_field(ctx) + noise, _spec(sensor))


@pytest.mark.parametrize("compiled", [True, False])
def test_the_default_context_is_the_old_seeding(compiled):
    """Unit k's noise seed defaults to StationOptions.seed + k, as the sensors' seeds always were
    (the compiled unit and the composed one)."""
    station = _station(seed=3, compiled=compiled)
    context = station.CreateDefaultContext()
    log = _hold_and_log(station, context)
    assert len(log) > 10 and np.ptp(log, axis=0).max() > 0.0  # noisy readings
    for k, n in enumerate(UNITS):
        assert isinstance(_sensor(station, n), ActuationUnit) == compiled
        assert _sensor(station, n).seed(_sensor(station, n).GetMyContextFromRoot(context)) == 3 + k
        np.testing.assert_array_equal(station.GetOutputPort(f"{n}.B_sensor_T").Eval(context),
                                      _old_seeding_reading(station, context, k, 3 + k))


def test_the_same_generator_seed_gives_the_same_run_and_another_another():
    station = _station()
    runs = {}
    for label, seed in (("a", 7), ("again", 7), ("b", 8)):
        context = station.CreateDefaultContext()
        set_random_context(station, context, RandomGenerator(seed))
        runs[label] = _hold_and_log(station, context)
    np.testing.assert_array_equal(runs["a"], runs["again"])
    assert runs["a"].shape == runs["b"].shape and not np.array_equal(runs["a"], runs["b"])
    # And a randomised run is not the default one.
    assert not np.array_equal(runs["a"], _hold_and_log(station, station.CreateDefaultContext()))


def test_each_seeded_system_draws_its_seed_from_the_generator_in_diagram_order():
    station = _station()
    sensors = [_sensor(station, n) for n in UNITS]
    assert seeded_systems(station) == sensors
    context = station.CreateDefaultContext()
    set_random_context(station, context, RandomGenerator(11))
    generator = RandomGenerator(11)
    expected = [generator(), generator()]
    assert [s.seed(s.GetMyContextFromRoot(context)) for s in sensors] == expected
    assert all(0 <= e <= MAX_SEED for e in expected)


def test_drakes_own_set_random_context_does_not_reach_python_systems():
    """Why ``set_random_context`` calls each seeded system itself: pydrake does not dispatch
    SetRandomParameters to a Python LeafSystem. Should it ever, this fails, and the manual call
    (a second draw) must go."""
    station = _station(seed=5)
    context = station.CreateDefaultContext()
    station.SetRandomContext(context, RandomGenerator(11))
    sensors = [_sensor(station, n) for n in UNITS]
    assert [s.seed(s.GetMyContextFromRoot(context)) for s in sensors] == [5, 6]


def _operator(seed: int = 0) -> SimulatedOperator:
    """An operator looking at a tip that never moves, a target it cannot reach (so it probes, then
    steers with tremor, bursts, ...)."""
    return SimulatedOperator(1, 0, ["far"], [[0.05, 0.0, 0.0]], [[-1.0, 0.0, 0.0]],
                             OperatorParams(seed=seed, timeout=1e3))


def _operator_run(op, context, t_end: float = 3.0) -> np.ndarray:
    op.get_body_poses_input_port().FixValue(context, [RigidTransform(), RigidTransform([3e-3, 0.0, 0.0])])
    simulator = Simulator(op, context)
    log = []

    def monitor(ctx):
        log.append(op.GetOutputPort("joystick").Eval(ctx).copy())
        return EventStatus.Succeeded()

    simulator.set_monitor(monitor)
    simulator.AdvanceTo(t_end)
    return np.array(log)


def test_the_operators_tremor_is_its_seed_parameters_stream():
    op = _operator(seed=4)
    context = op.CreateDefaultContext()
    assert op.seed(context) == 4
    stick = _operator_run(op, context)
    # The old seeding: the tremor is numpy's default_rng(params.seed), draw after draw.
    memory = context.get_abstract_state(0).get_value()
    rng, draws = np.random.default_rng(4), 0
    while rng.bit_generator.state != memory.rng.bit_generator.state and draws < 1000:
        rng.uniform(-1.0, 1.0, len(op.params.axes))
        draws += 1
    assert draws > 10 and rng.bit_generator.state == memory.rng.bit_generator.state
    # The seed parameter is the stream: an operator built with another seed, its parameter set to 4.
    other = _operator(seed=9)
    other_context = other.CreateDefaultContext()
    other.set_seed(other_context, 4)
    np.testing.assert_array_equal(_operator_run(other, other_context), stick)


def test_the_operators_tremor_follows_the_generator():
    op = _operator()
    runs = []
    for seed in (7, 7, 8):
        context = op.CreateDefaultContext()
        set_random_context(op, context, RandomGenerator(seed))
        runs.append(_operator_run(op, context))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0], runs[2])


@pytest.mark.parametrize("value", ["-1", "4294967296", "1.5", "true", "abc"])
def test_a_bad_random_seed_is_refused_naming_the_field(value):
    from ballchain.systems.chain_scenario import load_scenario

    with pytest.raises(UserInputError, match="random_seed"):
        load_scenario("teleop_right_unit", f"{{random_seed: {value}}}")


def test_a_scenarios_random_seed_randomises_the_run_loop():
    """A short free-space teleoperation scenario with two noisy units: no random_seed is the old
    seeding (unit k's sensor seed k), a random_seed the same run each time, another another."""
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation, run_station

    scenario = load_scenario("teleop_right_unit", "{heart: false, engine: statics, duration: 0.05, units: "
                                                  "[{name: right_unit, anchor: puncture}, {name: left_unit, direction_W: [0, 1, 0]}]}")
    cd = MakeStation(scenario)
    sensors = [_sensor(cd.diagram, n) for n in UNITS]

    def readings(random_seed):
        run = run_station(replace(cd, scenario=replace(scenario, random_seed=random_seed)), duration=scenario.duration)
        assert run.failure is None
        return run.context, np.concatenate([s.GetOutputPort("B_sensor_T").Eval(s.GetMyContextFromRoot(run.context))
                                            for s in sensors])

    context, default = readings(None)
    for k, sensor in enumerate(sensors):  # the magnets rest until the first key at 0.1 s
        ctx = sensor.GetMyContextFromRoot(context)
        sample = _last_sample(sensor, ctx)
        noise = np.random.default_rng((k, sample)).normal(scale=_spec(sensor).noise_std_T, size=3)
        np.testing.assert_array_equal(default[3 * k:3 * k + 3],
                                      quantise_reading(sensor.true_field(ctx) + noise, _spec(sensor)))
    a, again, b = readings(3)[1], readings(3)[1], readings(4)[1]
    np.testing.assert_array_equal(a, again)
    assert not np.array_equal(a, b) and not np.array_equal(a, default)


# (seed, k) pairs at the edges of the entropy's 32-bit words and of the fast path's range.
_SAMPLE_KEYS = [(0, 0), (0, 1), (1, 0), (MAX_SEED, 0), (MAX_SEED, 2**32 - 1), (5, 2**32), (7, 2**40 + 3),
                (MAX_SEED, 2**63 - 1), (3, 2**63), (3, 2**64 + 5)]


def test_sample_generators_give_default_rngs_streams():
    """``SampleGenerators.generator(seed, k)`` is ``default_rng((seed, k))``: the same numbers
    from every method, for random and edge keys, each call starting its key's stream afresh."""
    from ballchain.systems.randomness import SampleGenerators

    generators = SampleGenerators()
    rng = np.random.default_rng(11)
    keys = _SAMPLE_KEYS + [tuple(int(v) for v in rng.integers(0, MAX_SEED + 1, 2)) for _ in range(300)]
    keys += [(seed, k) for seed in range(3) for k in range(200)]
    for seed, k in keys:
        reference = np.random.default_rng((seed, k))
        fast = generators.generator(seed, k)
        assert np.array_equal(fast.normal(scale=3e-6, size=3), reference.normal(scale=3e-6, size=3)), (seed, k)
    for seed, k in _SAMPLE_KEYS:  # the rest of a stream, other methods, and a key asked twice
        for _ in range(2):
            reference, fast = np.random.default_rng((seed, k)), generators.generator(seed, k)
            assert np.array_equal(fast.standard_normal(5), reference.standard_normal(5))
            assert np.array_equal(fast.integers(0, 2**62, 4), reference.integers(0, 2**62, 4))
            assert np.array_equal(fast.random(3), reference.random(3))
            assert fast.bit_generator.state == reference.bit_generator.state
