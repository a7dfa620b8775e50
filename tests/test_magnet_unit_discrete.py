"""RotatingMagnetUnit with its orientation as discrete state: exact for wheel speeds held over
each period, the same outputs as the continuous state, and the station's units use it."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.drake_models.omniwheel import OmniWheelGeometry
from ballchain.drake_models.params import CylinderMagnet
from ballchain.systems.omni_wheel_drive import OmniWheelDrive, StepperSpec
from ballchain.systems.rotating_magnet_unit import RotatingMagnetUnit
from ballchain.systems.unit_config import right_unit

G = OmniWheelGeometry()
M_PROTO = CylinderMagnet().dipole_moment


def test_discrete_unit_has_the_same_ports_and_no_continuous_state():
    unit = RotatingMagnetUnit(update_period=5e-3, field_points_W=[[0.0, 0.0, 0.2]])
    continuous = RotatingMagnetUnit(field_points_W=[[0.0, 0.0, 0.2]])
    for kind in ("input", "output"):
        count = getattr(unit, f"num_{kind}_ports")()
        assert count == getattr(continuous, f"num_{kind}_ports")()
        names = [getattr(unit, f"get_{kind}_port")(i).get_name() for i in range(count)]
        assert names == [getattr(continuous, f"get_{kind}_port")(i).get_name() for i in range(count)]
    ctx = unit.CreateDefaultContext()
    assert ctx.num_continuous_states() == 0 and ctx.num_discrete_state_groups() == 1
    assert unit.update_period == 5e-3
    with pytest.raises(ValueError, match="update_period"):
        RotatingMagnetUnit(update_period=0.0)


@pytest.mark.parametrize("t_end", [0.0123, 1.0])
def test_constant_speed_turns_exactly_at_any_time(t_end):
    """A fixed wheel speed: the dipole turns about world z by (1 - slip) w t, between updates too."""
    m0 = np.array([np.sin(np.pi / 3), 0.0, np.cos(np.pi / 3)])
    unit = RotatingMagnetUnit(right_unit(slip=0.05), R_WM=rotation_with_z_along(m0), update_period=5e-3)
    ctx = unit.CreateDefaultContext()
    w = 1.5
    unit.get_input_port(0).FixValue(ctx, G.wheel_speeds([0.0, 0.0, w]))
    Simulator(unit, ctx).AdvanceTo(t_end)
    m = unit.GetOutputPort("m_W").Eval(ctx) / M_PROTO
    phi = 0.95 * w * t_end
    np.testing.assert_allclose(m, [m0[0] * np.cos(phi), m0[0] * np.sin(phi), m0[2]], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(unit.GetOutputPort("q_WM").Eval(ctx)), 1.0, atol=1e-14)


def _driven_unit(update_period, command_steps):
    """A drive (5 ms steps, acceleration-limited) turning a magnet under a stepped command."""
    builder = DiagramBuilder()
    spec = StepperSpec()
    drive = builder.AddSystem(OmniWheelDrive(spec=spec))
    unit = builder.AddSystem(RotatingMagnetUnit(R_WM=rotation_with_z_along([1.0, 0.2, 0.3]),
                                                update_period=update_period))
    times = np.array([t for t, _ in command_steps])
    values = np.array([v for _, v in command_steps]).T
    source = builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(times, values)))
    builder.Connect(source.get_output_port(), drive.GetInputPort("omega_desired_W"))
    builder.Connect(drive.GetOutputPort("omega_wheels"), unit.GetInputPort("omega_wheels"))
    diagram = builder.Build()
    return diagram, unit, spec


def test_discrete_matches_the_continuous_state_behind_the_stepper_drive():
    """The drive changes its applied speeds only every update period: the discrete unit at that
    period is exact, the continuous one (tight integrator) agrees to its accuracy."""
    steps = [(0.0, [0.0, 0.0, 0.8]), (0.2, [0.5, -0.3, 0.0]), (0.45, [0.0, 0.7, -0.4]), (1.0, [0.0, 0.0, 0.0])]
    results = {}
    for period in (None, StepperSpec().update_period):
        diagram, unit, _ = _driven_unit(period, steps)
        simulator = Simulator(diagram)
        if period is None:
            simulator.get_mutable_integrator().set_target_accuracy(1e-10)
        context = unit.GetMyContextFromRoot(simulator.get_context())
        trace = []
        for t in np.arange(0.05, 0.75, 0.0371):  # off the drive's grid too
            simulator.AdvanceTo(t)
            trace.append(unit.GetOutputPort("m_W").Eval(context) / M_PROTO)
        results[period] = np.array(trace)
    continuous, discrete = results[None], results[StepperSpec().update_period]
    turned = np.degrees(np.arccos(np.clip(np.sum(continuous[0] * continuous[-1]), -1, 1)))
    assert turned > 2.0  # the magnet really turned (3.9 deg: the drive limits speed and acceleration)
    np.testing.assert_allclose(discrete, continuous, atol=1e-11)  # measured: 9e-15


def test_station_units_use_the_discrete_state():
    from ballchain.systems.actuation_station import make_actuation_station, unit_system

    diagram = make_actuation_station()
    assert unit_system(diagram, "right_unit", "magnet").update_period == StepperSpec().update_period
    assert diagram.CreateDefaultContext().num_continuous_states() == 0
