"""A reconfiguration request after the controller has latched ``done`` starts a new reconfiguration.

The controller's ``done`` latches once the measured error is below the tolerance; the latch
belongs to one reconfiguration, and the unit's mode going to 1 starts the next. A magnet that
starts neutral latches at the first sample; turned away by teleoperation and asked to
reconfigure, it must go back to neutral (``teleop_two_units``: the left unit).
"""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import EventStatus

from ballchain.drake_models.vectors import angle_between
from ballchain.systems.reconfiguration import ReconfigurationController

PERIOD = 0.01  # the controller's update period [s]
GAIN = 4.0  # K [1/s]
TOL_DEG = 0.5


def _rotate(v: np.ndarray, omega: np.ndarray, dt: float) -> np.ndarray:
    """v turned by the constant angular velocity omega for dt (Rodrigues)."""
    angle = np.linalg.norm(omega) * dt
    if angle == 0.0:
        return v
    k = omega / np.linalg.norm(omega)
    return v * np.cos(angle) + np.cross(k, v) * np.sin(angle) + k * (k @ v) * (1.0 - np.cos(angle))


def _controller():
    m_c = np.array([-1.0, 0.0, 0.0])
    ctrl = ReconfigurationController(m_c, gain=GAIN, max_wheel_speed=1e3, tolerance_deg=TOL_DEG, period=PERIOD)
    ctx = ctrl.CreateDefaultContext()
    return ctrl, ctx, m_c


def _done(ctrl, ctx) -> float:
    return ctrl.GetOutputPort("done").Eval(ctx)[0]


def test_latched_at_neutral_in_teleoperation_and_a_request_restarts_it():
    ctrl, ctx, m_c = _controller()
    mode, m_port = ctrl.GetInputPort("mode"), ctrl.GetInputPort("m_hat_measured_W")
    mode.FixValue(ctx, [0.0])
    m_port.FixValue(ctx, m_c)
    sim = Simulator(ctrl, ctx)
    sim.AdvanceTo(0.5 * PERIOD)
    assert _done(ctrl, ctx) == 1.0  # neutral at the first sample, in teleoperation
    # Teleoperation turns the magnet 30 deg away: the latch holds, the wheels stay still.
    theta0 = np.deg2rad(30.0)
    m = np.array([-np.cos(theta0), np.sin(theta0), 0.0])
    m_port.FixValue(ctx, m)
    sim.AdvanceTo(5.5 * PERIOD)
    assert _done(ctrl, ctx) == 1.0
    np.testing.assert_array_equal(ctrl.GetOutputPort("omega_wheels_cmd").Eval(ctx), np.zeros(3))
    # The request: done clears at the next sample and the wheels turn by the law.
    mode.FixValue(ctx, [1.0])
    sim.AdvanceTo(6.5 * PERIOD)
    assert _done(ctrl, ctx) == 0.0
    np.testing.assert_allclose(ctrl.GetOutputPort("omega_wheels_cmd").Eval(ctx), ctrl.wheel_command(m), rtol=0, atol=0)
    assert np.linalg.norm(ctrl.GetOutputPort("omega_wheels_cmd").Eval(ctx)) > 0.0
    # Close the loop by hand (the magnet turns at omega_desired_W over each period) until done.
    # The law d theta/dt = -K sin(theta) held over each period: theta <- theta - K dt sin(theta).
    theta, expected_steps = theta0, 0
    while theta >= np.deg2rad(TOL_DEG):
        theta -= GAIN * PERIOD * np.sin(theta)
        expected_steps += 1
    steps = 0
    while _done(ctrl, ctx) == 0.0 and steps < 10 * expected_steps:
        m = _rotate(m, ctrl.GetOutputPort("omega_desired_W").Eval(ctx), PERIOD)
        m_port.FixValue(ctx, m)
        sim.AdvanceTo(sim.get_context().get_time() + PERIOD)
        steps += 1
    assert _done(ctrl, ctx) == 1.0
    assert abs(steps - expected_steps) <= 1  # the measured error crosses the tolerance at the same sample (+-1)
    assert np.rad2deg(angle_between(m, m_c)) < TOL_DEG
    # Mode held at 1: the latch holds even if the magnet is moved; a new request (0 -> 1) clears it.
    m_port.FixValue(ctx, [0.0, 1.0, 0.0])
    sim.AdvanceTo(sim.get_context().get_time() + 3 * PERIOD)
    assert _done(ctrl, ctx) == 1.0
    mode.FixValue(ctx, [0.0])
    sim.AdvanceTo(sim.get_context().get_time() + 2 * PERIOD)
    assert _done(ctrl, ctx) == 1.0  # teleoperation does not clear it
    mode.FixValue(ctx, [1.0])
    sim.AdvanceTo(sim.get_context().get_time() + PERIOD)
    assert _done(ctrl, ctx) == 0.0


def test_a_run_that_starts_in_reconfiguration_latches_as_before():
    # Mode 1 from t = 0 (the reconfiguration study's set-up): the first sample is a request,
    # with nothing latched to clear; an off-neutral reading is measured, a neutral one latches.
    ctrl, ctx, m_c = _controller()
    ctrl.GetInputPort("mode").FixValue(ctx, [1.0])
    ctrl.GetInputPort("m_hat_measured_W").FixValue(ctx, [0.0, 1.0, 0.0])
    sim = Simulator(ctrl, ctx)
    sim.AdvanceTo(2.5 * PERIOD)
    assert _done(ctrl, ctx) == 0.0
    ctrl.GetInputPort("m_hat_measured_W").FixValue(ctx, m_c)
    sim.AdvanceTo(3.5 * PERIOD)
    assert _done(ctrl, ctx) == 1.0


def _request_time(unit) -> float:
    """The first key that turns the unit's mode from 0 to 1 [s]."""
    previous = 0
    for key in unit.joystick:
        if key.mode == 1 and previous == 0:
            return key.time
        previous = key.mode
    raise AssertionError(f"{unit.name}: no reconfiguration request in the scenario")


@pytest.fixture(scope="module")
def two_units_run():
    """teleop_two_units run past the left unit's request until its controller latches again."""
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation

    station = MakeStation(load_scenario("teleop_two_units", "{engine: statics, mode: quasi-static}"))
    left = station.units["left_unit"]
    t_request = _request_time(left.config)
    m_port = left.magnet.GetOutputPort("m_W")
    done_port = left.controller.GetOutputPort("done")
    simulator = Simulator(station.diagram)
    root = simulator.get_mutable_context()
    magnet_ctx = left.magnet.GetMyContextFromRoot(root)
    controller_ctx = left.controller.GetMyContextFromRoot(root)

    def error_deg() -> float:
        return float(np.rad2deg(angle_between(m_port.Eval(magnet_ctx), left.m_hat_neutral_W)))

    simulator.Initialize()
    simulator.AdvanceTo(t_request - 0.5 * PERIOD)
    before = {"done": done_port.Eval(controller_ctx)[0], "error_deg": error_deg()}
    cleared = []

    def monitor(ctx):
        done = done_port.Eval(controller_ctx)[0]
        cleared.append(done == 0.0)
        if any(cleared) and done == 1.0:
            return EventStatus.ReachedTermination(station.diagram, "left unit reconfigured")
        return EventStatus.Succeeded()

    simulator.set_monitor(monitor)
    # Twice the law's time from the error at the request to the tolerance is plenty.
    theta0 = np.deg2rad(before["error_deg"])
    t_law = np.log(np.tan(theta0 / 2) / np.tan(np.deg2rad(left.config.tolerance_deg) / 2)) / left.config.controller_gain
    simulator.AdvanceTo(t_request + 2.0 * t_law)
    t_latch = root.get_time()
    simulator.clear_monitor()
    simulator.AdvanceTo(t_latch + 0.1)  # the wheels stop; the magnet settles on its microsteps
    B = left.sensor.GetOutputPort("B_sensor_T").Eval(left.sensor.GetMyContextFromRoot(root))
    right = station.units["right_unit"].controller
    right_done = right.GetOutputPort("done").Eval(right.GetMyContextFromRoot(root))[0]
    return dict(station=station, left=left, before=before, cleared=any(cleared), t_request=t_request,
                t_law=t_law, t_latch=t_latch, final_error_deg=error_deg(), B_sensor=np.linalg.norm(B),
                right_done=right_done)


def test_teleop_two_units_left_unit_goes_back_to_neutral_when_asked(two_units_run):
    run = two_units_run
    left = run["left"]
    # The premise: the left magnet started neutral (latched) and teleoperation turned it away.
    assert run["before"]["done"] == 1.0
    assert run["before"]["error_deg"] > 10 * left.config.tolerance_deg
    # The true error after the new latch: the tolerance on the measured error, plus what the
    # sampling can leave between the law and the magnet: the steppers stand on whole
    # microsteps (each wheel up to one microstep off the angle the law integrated; the magnet
    # turn this makes, worst sign pattern) and the estimate's noise (3 sigma of the per-axis
    # Hall noise over the field at the sensor); the station's units have the default hardware.
    from ballchain.systems.hall_sensor import HallSensorSpec
    from ballchain.systems.omni_wheel_drive import StepperSpec

    mu = StepperSpec().microstep_angle
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    microstep_deg = np.rad2deg(max(np.linalg.norm(left.config.geometry.sphere_angular_velocity(s * mu))
                                   for s in signs))
    noise_deg = np.rad2deg(3 * HallSensorSpec().noise_std_T / run["B_sensor"])
    assert run["final_error_deg"] < left.config.tolerance_deg + microstep_deg + noise_deg
    assert run["cleared"], "the request should clear the latch"
    # Unsaturated, the error falls as tan(theta/2) = tan(theta0/2) exp(-K t): the latch comes
    # at the law's time (slip 0), within 10 % (samples, microsteps, the estimate).
    assert left.config.slip == 0.0
    assert run["t_latch"] - run["t_request"] == pytest.approx(run["t_law"], rel=0.10)


def test_teleop_two_units_right_unit_stays_latched(two_units_run):
    # The right unit is never asked to reconfigure: its latch from the first sample holds.
    right = two_units_run["station"].units["right_unit"]
    assert all(key.mode == 0 for key in right.config.joystick)
    assert two_units_run["right_done"] == 1.0
