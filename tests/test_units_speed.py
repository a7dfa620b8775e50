"""The actuation units' per-step shortcuts give the very values of the plain formulas.

The omni-wheel drive and the feeder step on plain floats; their states must equal the numpy
stepper and feed laws exactly. The Hall sensor remembers each magnet's field for its last orientation; its samples must be
bit-identical to the field law evaluated afresh (``MagnetUnitConfig.source(R).field``), also when
a magnet turns, stops, and turns back to an earlier orientation.
"""

from dataclasses import replace

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.drake_models.params import BallChain
from ballchain.systems.feeder import Feeder
from ballchain.systems.hall_sensor import HallSensor, HallSensorSpec, quantise_reading
from ballchain.systems.omni_wheel_drive import OmniWheelDrive
from ballchain.systems.unit_config import MagnetUnitConfig


def _reference(units, rotations, p_WS, spec):
    """The sensor's reading by the plain formula: every magnet's source rebuilt and summed in order."""
    B = units[0].source(rotations[0]).field(p_WS[None, :])[0]
    for unit, R in zip(units[1:], rotations[1:]):
        B = B + unit.source(R).field(p_WS[None, :])[0]
    return quantise_reading(B, spec)


def test_hall_sensor_samples_equal_the_fresh_field_law_as_magnets_turn_and_return():
    own = MagnetUnitConfig(name="right_unit", p_WM=[0.0, 0.0, 0.0], sensor_noise=False, model="exact")
    other = replace(own, name="left_unit", p_WM=[0.3, 0.1, 0.0])
    spec = HallSensorSpec()
    builder = DiagramBuilder()
    sensor = builder.AddSystem(HallSensor(own, other_units=[other], spec=spec))
    builder.ExportInput(sensor.GetInputPort("X_WM"), "X_WM")
    builder.ExportInput(sensor.GetInputPort("X_WM_left_unit"), "X_WM_left_unit")
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    sim = Simulator(diagram, ctx)
    directions = [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.3, -0.4, 0.8], [1.0, 0.0, 0.0], [0.0, 1.0, 0.2]]
    period = 1.0 / spec.sample_rate_hz
    readings = []
    for k, d in enumerate(directions):
        R_own = rotation_with_z_along(d)
        R_other = rotation_with_z_along(directions[-1 - k])
        diagram.get_input_port(0).FixValue(ctx, RigidTransform(RotationMatrix(R_own), np.zeros(3)))
        diagram.get_input_port(1).FixValue(ctx, RigidTransform(RotationMatrix(R_other), np.array(other.p_WM)))
        sim.AdvanceTo((k + 0.5) * period)  # one sample, at k * period, under these poses
        B = sensor.get_output_port(0).Eval(sensor.GetMyContextFromRoot(ctx))
        expected = _reference((own, other), (R_own, R_other), own.p_WS, spec)
        np.testing.assert_array_equal(B, expected)
        readings.append(B.copy())
    # The poses really changed the reading (the comparison is not of constants).
    assert np.abs(readings[2] - readings[1]).max() > 1e-3


def test_hall_sensor_true_field_is_not_shared_with_its_memory():
    unit = MagnetUnitConfig(p_WM=[0.0, 0.0, 0.0], sensor_noise=False)
    sensor = HallSensor(unit)
    ctx = sensor.CreateDefaultContext()
    R = rotation_with_z_along([0.0, 0.6, 0.8])
    sensor.get_input_port(0).FixValue(ctx, RigidTransform(RotationMatrix(R), np.zeros(3)))
    first = sensor.true_field(ctx)
    first[:] = 0.0  # a caller's scribbling must not reach the next sample
    np.testing.assert_array_equal(sensor.true_field(ctx), unit.source(R).field(unit.p_WS[None, :])[0])


def _advance_with_inputs(system, inputs, period):
    """Run ``system`` alone, one update period per input value; yield (input, state before, context)."""
    ctx = system.CreateDefaultContext()
    sim = Simulator(system, ctx)
    for k, u in enumerate(inputs):
        system.get_input_port(0).FixValue(ctx, u)
        before = [ctx.get_discrete_state().get_vector(i).CopyToVector()
                  for i in range(ctx.num_discrete_state_groups())]
        sim.AdvanceTo((k + 0.5) * period)  # the update at k * period, under input u
        yield u, before, ctx


def test_omni_wheel_drive_update_equals_the_numpy_stepper_law():
    drive = OmniWheelDrive()
    s = drive.spec
    dt, msa = s.update_period, s.microstep_angle
    rng = np.random.default_rng(5)
    inputs = [rng.normal(size=3) * 2.0 for _ in range(12)] + [np.zeros(3)] * 4
    for u, (speed, angle, steps, _), ctx in _advance_with_inputs(drive, inputs, dt):
        target = drive.wheel_command(u)
        exp_speed = speed + np.clip(target - speed, -s.max_acceleration * dt, s.max_acceleration * dt)
        exp_angle = angle + exp_speed * dt
        exp_steps = np.round(exp_angle / msa)
        state = ctx.get_discrete_state()
        np.testing.assert_array_equal(state.get_vector(0).CopyToVector(), exp_speed)
        np.testing.assert_array_equal(state.get_vector(1).CopyToVector(), exp_angle)
        np.testing.assert_array_equal(state.get_vector(2).CopyToVector(), exp_steps)
        np.testing.assert_array_equal(state.get_vector(3).CopyToVector(), (exp_steps - steps) * msa / dt)
    assert np.any(state.get_vector(2).CopyToVector() != 0.0)  # the wheels did move


def test_feeder_update_equals_the_numpy_feed_law_including_the_end_stop():
    chain = BallChain()
    feeder = Feeder(chain, initial_length=chain.length - 1e-7)
    s = feeder.spec
    dt = s.update_period
    inputs = [np.array([v]) for v in (0.01, 0.05, 0.05, 0.05, 0.05, -0.2, -0.2, -0.2, 0.003)]
    stops = 0
    for u, (speed, length, _), ctx in _advance_with_inputs(feeder, inputs, dt):
        v = speed[0]
        target = np.clip(u[0], -s.max_speed, s.max_speed)
        v = v + np.clip(target - v, -s.max_acceleration * dt, s.max_acceleration * dt)
        x = length[0] + v * dt
        if x <= 0.0 or x >= chain.length:
            x, v, stops = np.clip(x, 0.0, chain.length), 0.0, stops + 1
        steps = min(np.round(x / s.step_length), np.floor(chain.length / s.step_length))
        state = ctx.get_discrete_state()
        assert state.get_vector(0).GetAtIndex(0) == v
        assert state.get_vector(1).GetAtIndex(0) == x
        assert state.get_vector(2).GetAtIndex(0) == steps
    assert stops > 0  # the end stop was reached
    assert state.get_vector(0).GetAtIndex(0) < 0.0  # and the feeder retracts from it
