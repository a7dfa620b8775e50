"""The actuation units' per-step shortcuts give the very values of the plain formulas.

The Hall sensor remembers each magnet's field for its last orientation; its samples must be
bit-identical to the field law evaluated afresh (``MagnetUnitConfig.source(R).field``), also when
a magnet turns, stops, and turns back to an earlier orientation.
"""

from dataclasses import replace

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.systems.hall_sensor import HallSensor, HallSensorSpec, quantise_reading
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
