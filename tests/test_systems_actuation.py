"""Actuation systems: ports, outputs for fixed inputs, short simulations, state following physics."""

import numpy as np
import pytest
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator

from ballchain.drake_models.dipole import K_DIPOLE, dipole_field
from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.drake_models.omniwheel import OmniWheelGeometry
from ballchain.drake_models.params import BallChain, CylinderMagnet
from ballchain.systems.actuation_station import StationOptions, make_actuation_station, neutral_direction, unit_system
from ballchain.systems.feeder import Feeder, FeederSpec
from ballchain.systems.hall_sensor import DipoleDirectionEstimator
from ballchain.systems.omni_wheel_drive import OmniWheelDrive, StepperSpec
from ballchain.systems.reconfiguration import ReconfigurationController
from ballchain.systems import rotating_magnet_unit
from ballchain.systems.rotating_magnet_unit import RotatingMagnetUnit, rotation_from_quaternion
from ballchain.systems.teleoperation import ModeSwitch, TeleoperationMapper, apply_dead_band
from ballchain.systems.unit_config import MagnetUnitConfig, left_unit, right_unit

G = OmniWheelGeometry()
M_PROTO = CylinderMagnet().dipole_moment


def port_names(system, kind):
    n = system.num_input_ports() if kind == "in" else system.num_output_ports()
    get = system.get_input_port if kind == "in" else system.get_output_port
    return [get(i).get_name() for i in range(n)]


# --- RotatingMagnetUnit ------------------------------------------------------------------


def test_magnet_unit_ports_and_outputs_at_rest():
    unit = RotatingMagnetUnit(MagnetUnitConfig(p_WM=(0.1, 0.2, 0.3)), field_points_W=[[0.1, 0.2, 0.5]])
    assert unit.get_name() == "right_unit.magnet"
    assert port_names(unit, "in") == ["omega_wheels"]
    assert port_names(unit, "out") == ["q_WM", "X_WM", "m_W", "omega_WM_W", "B_points_W"]
    assert [unit.get_output_port(i).size() for i in (0, 2, 3, 4)] == [4, 3, 3, 3]
    ctx = unit.CreateDefaultContext()
    unit.get_input_port(0).FixValue(ctx, np.zeros(3))
    np.testing.assert_allclose(unit.GetOutputPort("m_W").Eval(ctx), [0, 0, M_PROTO], rtol=1e-14)
    X = unit.GetOutputPort("X_WM").Eval(ctx)
    assert isinstance(X, RigidTransform)
    np.testing.assert_allclose(X.translation(), [0.1, 0.2, 0.3])
    # The field at a point 0.2 m above on the axis, from the shared dipole law: 2 k m / r^3.
    np.testing.assert_allclose(
        unit.GetOutputPort("B_points_W").Eval(ctx), [0, 0, 2 * K_DIPOLE * M_PROTO / 0.2**3], rtol=1e-12, atol=1e-15
    )


def test_magnet_unit_forward_map_and_slip():
    unit = RotatingMagnetUnit(right_unit(slip=0.05))
    ctx = unit.CreateDefaultContext()
    omega = np.array([0.3, -0.2, 0.5])
    unit.get_input_port(0).FixValue(ctx, G.wheel_speeds(omega))
    np.testing.assert_allclose(unit.GetOutputPort("omega_WM_W").Eval(ctx), 0.95 * omega, rtol=1e-12)


@pytest.mark.parametrize("slip", [0.0, 0.05])
def test_rotation_about_z_keeps_m_z_and_turns_by_omega_t(slip):
    # Start tilted 60 deg from z, turn about world z at 1.5 rad/s for 1 s.
    m0 = np.array([np.sin(np.pi / 3), 0.0, np.cos(np.pi / 3)])
    unit = RotatingMagnetUnit(right_unit(slip=slip), R_WM=rotation_with_z_along(m0))
    ctx = unit.CreateDefaultContext()
    w = 1.5
    unit.get_input_port(0).FixValue(ctx, G.wheel_speeds([0.0, 0.0, w]))
    sim = Simulator(unit, ctx)
    sim.get_mutable_integrator().set_target_accuracy(1e-8)
    sim.AdvanceTo(1.0)
    m = unit.GetOutputPort("m_W").Eval(ctx) / M_PROTO
    phi = (1.0 - slip) * w * 1.0
    np.testing.assert_allclose(m[2], m0[2], atol=1e-7)
    np.testing.assert_allclose(m, [m0[0] * np.cos(phi), m0[0] * np.sin(phi), m0[2]], atol=1e-6)
    q = unit.GetOutputPort("q_WM").Eval(ctx)
    assert abs(np.linalg.norm(q) - 1.0) < 1e-6


def _norm_drift_after_tumbling(monkeypatch, gain):
    monkeypatch.setattr(rotating_magnet_unit, "QUATERNION_NORM_GAIN", gain)
    unit = RotatingMagnetUnit()
    ctx = unit.CreateDefaultContext()
    unit.get_input_port(0).FixValue(ctx, [3.0, -2.0, 4.0])  # about 5.4 rad/s, 20 s: 17 turns
    sim = Simulator(unit, ctx)
    accuracy = sim.get_integrator().get_target_accuracy()
    sim.AdvanceTo(20.0)
    q = ctx.get_continuous_state_vector().CopyToVector()
    R = rotation_from_quaternion(q)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)  # outputs always see a rotation
    return abs(np.linalg.norm(q) - 1.0), accuracy


def test_quaternion_stays_unit_over_a_long_tumbling_run(monkeypatch):
    drift, accuracy = _norm_drift_after_tumbling(monkeypatch, rotating_magnet_unit.QUATERNION_NORM_GAIN)
    drift_free, _ = _norm_drift_after_tumbling(monkeypatch, 0.0)
    # Kept on the unit sphere to within the integrator's own accuracy, and the stabilising
    # term is what does it: without it the norm drifts at least ten times further.
    assert drift < accuracy
    assert drift_free > 10 * drift


# --- OmniWheelDrive ----------------------------------------------------------------------


def test_drive_ports_and_quantised_tracking():
    spec = StepperSpec()
    drive = OmniWheelDrive(spec=spec)
    assert drive.get_name() == "right_unit.drive"
    assert port_names(drive, "in") == ["omega_desired_W"]
    assert port_names(drive, "out") == ["omega_wheels", "wheel_angles", "wheel_speed_setpoint"]
    assert all(drive.get_output_port(i).size() == 3 for i in range(3))
    ctx = drive.CreateDefaultContext()
    omega_W = np.array([0.0, 0.0, 1.0])
    drive.get_input_port(0).FixValue(ctx, omega_W)
    target = G.wheel_speeds(omega_W)  # -0.523 rad/s each, under the limit
    sim = Simulator(drive, ctx)
    sim.AdvanceTo(1.0)
    angles = drive.GetOutputPort("wheel_angles").Eval(ctx)
    # Whole microsteps (1.8 deg / 16).
    steps = angles / spec.microstep_angle
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)
    # Angle = target speed x time minus the acceleration ramp (v^2 / 2a), within one microstep.
    ramp = target**2 / (2 * spec.max_acceleration) * np.sign(target)
    expected = target * 1.0 - ramp
    np.testing.assert_allclose(angles, expected, atol=spec.microstep_angle + abs(target[0]) * spec.update_period)
    np.testing.assert_allclose(drive.GetOutputPort("wheel_speed_setpoint").Eval(ctx), target, rtol=1e-12)


def test_drive_speed_and_acceleration_limits():
    spec = StepperSpec(max_speed=2.0, max_acceleration=10.0)
    drive = OmniWheelDrive(spec=spec)
    ctx = drive.CreateDefaultContext()
    drive.get_input_port(0).FixValue(ctx, [20.0, 5.0, 0.0])
    sim = Simulator(drive, ctx)
    n_updates = 5
    sim.AdvanceTo((n_updates - 1 + 0.5) * spec.update_period)  # updates at t = 0, T, ..., 4 T
    speed = drive.GetOutputPort("wheel_speed_setpoint").Eval(ctx)
    assert np.max(np.abs(speed)) == pytest.approx(n_updates * 10.0 * spec.update_period, rel=1e-12)
    sim.AdvanceTo(1.0)
    speed = drive.GetOutputPort("wheel_speed_setpoint").Eval(ctx)
    # Saturated as a whole: the largest wheel at the limit, the direction kept.
    unsat = G.wheel_speeds([20.0, 5.0, 0.0])
    np.testing.assert_allclose(speed, unsat * 2.0 / np.max(np.abs(unsat)), rtol=1e-12)


# --- ReconfigurationController -----------------------------------------------------------


def test_controller_ports_and_law_by_hand():
    m_c = np.array([-1.0, 0.0, 0.0])
    ctrl = ReconfigurationController(m_c, gain=2.0, max_wheel_speed=100.0)
    assert ctrl.get_name() == "right_unit.controller"
    assert port_names(ctrl, "in") == ["m_hat_measured_W", "mode"]
    assert port_names(ctrl, "out") == ["omega_wheels_cmd", "omega_desired_W", "done", "angle_error"]
    assert [ctrl.get_output_port(i).size() for i in range(4)] == [3, 3, 1, 1]
    ctx = ctrl.CreateDefaultContext()
    ctrl.get_input_port(0).FixValue(ctx, [0.0, 0.0, 1.0])
    # m x m_c = z x (-x) = -y; omega = K (-y); wheels = (rho_a/rho_w) A omega.
    np.testing.assert_allclose(ctrl.GetOutputPort("omega_desired_W").Eval(ctx), [0, -2.0, 0], atol=1e-14)
    np.testing.assert_allclose(
        ctrl.GetOutputPort("omega_wheels_cmd").Eval(ctx), (43.5 / 48.0) * G.A @ [0, -2.0, 0], atol=1e-14
    )
    assert ctrl.GetOutputPort("angle_error").Eval(ctx)[0] == pytest.approx(np.pi / 2)
    assert ctrl.GetOutputPort("done").Eval(ctx)[0] == 0.0


def test_controller_turns_the_dipole_towards_the_target():
    m_c = np.array([-1.0, 0.0, 0.0])
    ctrl = ReconfigurationController(m_c)
    ctx = ctrl.CreateDefaultContext()
    rng = np.random.default_rng(2)
    for _ in range(20):
        m = rng.normal(size=3)
        m /= np.linalg.norm(m)
        ctrl.get_input_port(0).FixValue(ctx, m)
        omega = ctrl.GetOutputPort("omega_desired_W").Eval(ctx)
        # d(m . m_c)/dt = (omega x m) . m_c > 0 away from the target.
        assert np.cross(omega, m) @ m_c > 0


def test_controller_exactly_antiparallel_does_not_stall():
    m_c = np.array([-1.0, 0.0, 0.0])
    ctrl = ReconfigurationController(m_c, gain=4.0, antiparallel_deg=5.0)
    ctx = ctrl.CreateDefaultContext()
    ctrl.get_input_port(0).FixValue(ctx, -m_c)
    omega = ctrl.GetOutputPort("omega_desired_W").Eval(ctx)
    assert np.linalg.norm(omega) == pytest.approx(4.0 * np.sin(np.deg2rad(5.0)), rel=1e-12)
    assert abs(omega @ m_c) < 1e-12  # about an axis perpendicular to the target


def test_controller_saturates_and_latches_done():
    ctrl = ReconfigurationController([1.0, 0.0, 0.0], gain=100.0, max_wheel_speed=1.0, tolerance_deg=0.5)
    ctx = ctrl.CreateDefaultContext()
    ctrl.GetInputPort("mode").FixValue(ctx, [1.0])
    ctrl.get_input_port(0).FixValue(ctx, [0.0, 1.0, 0.0])
    wheels = ctrl.GetOutputPort("omega_wheels_cmd").Eval(ctx)
    assert np.max(np.abs(wheels)) == pytest.approx(1.0)
    unsat = G.ratio * G.A @ (100.0 * np.cross([0, 1.0, 0], [1.0, 0, 0]))
    np.testing.assert_allclose(wheels, unsat / np.max(np.abs(unsat)), rtol=1e-12)
    # Within tolerance: done latches at the next update, wheels stop, and stays done after.
    ctrl.get_input_port(0).FixValue(ctx, [1.0, np.tan(np.deg2rad(0.3)), 0.0])
    sim = Simulator(ctrl, ctx)
    sim.AdvanceTo(0.015)
    assert ctrl.GetOutputPort("done").Eval(ctx)[0] == 1.0
    ctrl.get_input_port(0).FixValue(ctx, [0.0, 1.0, 0.0])
    sim.AdvanceTo(0.05)
    assert ctrl.GetOutputPort("done").Eval(ctx)[0] == 1.0
    np.testing.assert_array_equal(ctrl.GetOutputPort("omega_wheels_cmd").Eval(ctx), np.zeros(3))


# --- Teleoperation -----------------------------------------------------------------------


def test_dead_band_by_hand():
    np.testing.assert_allclose(apply_dead_band([0.05, -0.55, 1.7], 0.1), [0.0, -0.5, 1.0], atol=1e-15)


def test_world_teleoperation_ports_and_mapping():
    tele = TeleoperationMapper(omega_max=0.8, dead_band=0.1)
    assert tele.get_name() == "right_unit.teleoperation"
    assert port_names(tele, "in") == ["joystick"]
    assert port_names(tele, "out") == ["omega_desired_W"]
    ctx = tele.CreateDefaultContext()
    tele.get_input_port(0).FixValue(ctx, [1.0, -0.55, 0.02])
    np.testing.assert_allclose(tele.get_output_port(0).Eval(ctx), [0.8, -0.4, 0.0], atol=1e-15)


def test_tip_teleoperation_on_the_equator_by_hand():
    # Magnet at -y of the tip with m = -x: on the equator B is along +x (the feed direction).
    p_WM = np.array([0.0, -0.15, 0.0])
    tele = TeleoperationMapper(frame="tip", omega_max=0.6, dead_band=0.0, p_WM=p_WM)
    assert port_names(tele, "in") == ["joystick", "m_W", "p_WT", "tip_direction_W"]
    ctx = tele.CreateDefaultContext()
    tele.GetInputPort("m_W").FixValue(ctx, [-M_PROTO, 0.0, 0.0])
    tele.GetInputPort("p_WT").FixValue(ctx, np.zeros(3))
    tele.GetInputPort("tip_direction_W").FixValue(ctx, [1.0, 0.0, 0.0])
    tele.GetInputPort("joystick").FixValue(ctx, [1.0, 0.0, 0.0])
    # Swinging the tip about +z at w: the equatorial field turns opposite to and twice as fast
    # as the magnet, so the magnet turns at w/2 about -z.
    np.testing.assert_allclose(tele.get_output_port(0).Eval(ctx), [0.0, 0.0, -0.3], atol=1e-12)


def test_tip_teleoperation_moves_the_tip_field_as_asked():
    # A generic pose (off the equator), checked by a small finite rotation of the magnet.
    p_WM = np.array([0.05, -0.15, 0.03])
    m = np.array([-120.0, 15.0, 45.0])
    p_WT = np.array([0.01, 0.0, -0.01])
    B0 = dipole_field(p_WT - p_WM, m)
    t = B0 / np.linalg.norm(B0)
    tele = TeleoperationMapper(frame="tip", omega_max=0.5, dead_band=0.0, p_WM=p_WM)
    ctx = tele.CreateDefaultContext()
    tele.GetInputPort("m_W").FixValue(ctx, m)
    tele.GetInputPort("p_WT").FixValue(ctx, p_WT)
    tele.GetInputPort("tip_direction_W").FixValue(ctx, t)
    tele.GetInputPort("joystick").FixValue(ctx, [0.0, 1.0, 0.0])
    omega = tele.get_output_port(0).Eval(ctx)
    assert abs(omega @ m) < 1e-12 * np.linalg.norm(omega) * np.linalg.norm(m)  # no useless spin
    h = 1e-5
    m_new = m + h * np.cross(omega, m)
    B1 = dipole_field(p_WT - p_WM, m_new)
    dt_hat = (B1 / np.linalg.norm(B1) - t) / h
    y_T = np.cross([0, 0, 1.0], t)
    y_T /= np.linalg.norm(y_T)
    z_T = np.cross(t, y_T)
    # Wanted: d t/dt = omega_B x t with omega_B = -0.5 y_T, i.e. 0.5 z_T. Exact, because the
    # unreachable part of dm/dt (along m) would only scale |B|, not turn it (finite-difference
    # tolerance).
    np.testing.assert_allclose(dt_hat, 0.5 * z_T, atol=1e-4)


def test_mode_switch_selects_and_rejects_bad_mode():
    sw = ModeSwitch()
    assert port_names(sw, "in") == ["mode", "omega_teleop_W", "omega_reconfigure_W"]
    ctx = sw.CreateDefaultContext()
    sw.GetInputPort("omega_teleop_W").FixValue(ctx, [1.0, 2.0, 3.0])
    sw.GetInputPort("omega_reconfigure_W").FixValue(ctx, [4.0, 5.0, 6.0])
    sw.GetInputPort("mode").FixValue(ctx, [0.0])
    np.testing.assert_array_equal(sw.get_output_port(0).Eval(ctx), [1.0, 2.0, 3.0])
    sw.GetInputPort("mode").FixValue(ctx, [1.0])
    np.testing.assert_array_equal(sw.get_output_port(0).Eval(ctx), [4.0, 5.0, 6.0])
    sw.GetInputPort("mode").FixValue(ctx, [3.0])
    with pytest.raises(ValueError, match="mode"):
        sw.get_output_port(0).Eval(ctx)


# --- Feeder ------------------------------------------------------------------------------


def test_feeder_ports_insertion_quantisation_and_limits():
    chain = BallChain(n_balls=16)
    spec = FeederSpec()
    feeder = Feeder(chain, spec)
    assert port_names(feeder, "in") == ["v_insert_cmd"]
    assert port_names(feeder, "out") == ["inserted_length", "balls_out"]
    ctx = feeder.CreateDefaultContext()
    feeder.get_input_port(0).FixValue(ctx, [0.01])
    sim = Simulator(feeder, ctx)
    sim.AdvanceTo(1.0)
    L = feeder.GetOutputPort("inserted_length").Eval(ctx)[0]
    steps = L / spec.step_length
    assert steps == pytest.approx(round(steps), abs=1e-6)
    # 10 mm/s for 1 s minus the ramp v^2 / 2a = 0.5 mm, within one period's travel.
    assert L == pytest.approx(0.0095, abs=0.01 * spec.update_period + spec.step_length)
    assert feeder.GetOutputPort("balls_out").Eval(ctx)[0] == np.floor(L / chain.ball_diameter)
    sim.AdvanceTo(8.0)  # would be 80 mm: stops at the chain's length
    L = feeder.GetOutputPort("inserted_length").Eval(ctx)[0]
    assert chain.length - spec.step_length <= L <= chain.length
    assert feeder.GetOutputPort("balls_out").Eval(ctx)[0] == pytest.approx(15.0, abs=1.0)
    feeder.get_input_port(0).FixValue(ctx, [-0.02])
    sim.AdvanceTo(12.0)
    assert feeder.GetOutputPort("inserted_length").Eval(ctx)[0] == 0.0
    assert feeder.GetOutputPort("balls_out").Eval(ctx)[0] == 0.0


class _Looks(__import__("pydrake.systems.framework", fromlist=["LeafSystem"]).LeafSystem):
    """A command set in periodic unrestricted updates (a simulated operator's looks): 1.4 x the
    feeder's speed limit out, then back, then random speeds within +-1.4 x the limit."""

    def __init__(self, period: float, seed: int):
        from pydrake.common.value import AbstractValue

        super().__init__()
        self._rng = np.random.default_rng(seed)
        self._index = self.DeclareAbstractState(AbstractValue.Make(0.0))
        self.DeclareVectorOutputPort("v", 1, lambda c, o: o.SetAtIndex(0, c.get_abstract_state(0).get_value()),
                                     prerequisites_of_calc={self.abstract_state_ticket(self._index)})
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._look)

    def _look(self, context, state):
        t, fast = context.get_time(), 1.4 * FeederSpec().max_speed
        # Out to the far end stop, back to the near one, then random commands.
        v = fast if t < 3.0 else -fast if t < 6.5 else float(self._rng.uniform(-fast, fast))
        state.get_mutable_abstract_state(0).set_value(v)


class _Reader(__import__("pydrake.systems.framework", fromlist=["LeafSystem"]).LeafSystem):
    """Reads the inserted length in periodic discrete updates (the engine's) into its state."""

    def __init__(self, period: float):
        super().__init__()
        self._u = self.DeclareVectorInputPort("length", 1)
        self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, lambda c, d: d.get_mutable_vector(0).SetAtIndex(
            0, self._u.Eval(c)[0]))


def _trace(builder, feeder, reader_period: float, start: float) -> dict:
    """Run ``feeder`` (added to ``builder`` with its command) to 9 s beside an engine-like reader
    every ``reader_period`` and a 5 ms one: at every simulator step, its outputs and the readers'
    states, by time."""
    from pydrake.systems.framework import EventStatus

    reader = builder.AddSystem(_Reader(reader_period))
    fast = builder.AddSystem(_Reader(0.005))
    for r in (reader, fast):
        builder.Connect(feeder.GetOutputPort("inserted_length"), r.get_input_port())
    simulator = Simulator(builder.Build())
    simulator.get_mutable_context().SetTime(start)
    seen = {}

    def monitor(root):
        context = feeder.GetMyContextFromRoot(root)
        seen[root.get_time()] = (feeder.GetOutputPort("inserted_length").Eval(context)[0],
                                 feeder.GetOutputPort("balls_out").Eval(context)[0],
                                 reader.GetMyContextFromRoot(root).get_discrete_state_vector()[0],
                                 fast.GetMyContextFromRoot(root).get_discrete_state_vector()[0])
        return EventStatus.Succeeded()

    simulator.set_monitor(monitor)
    simulator.Initialize()
    simulator.AdvanceTo(9.0)
    return seen


def _same_at_common_steps(alone: dict, batched: dict | None, chain, fewer: bool = True) -> None:
    """The batched trace equals stepping alone at their common times (most of the batched run's,
    with far fewer steps when ``fewer``), and the run reached both end stops."""
    common = sorted(set(alone) & set(batched))
    assert len(common) > 0.9 * len(batched) and (not fewer or len(batched) < 0.5 * len(alone))
    assert [batched[t] for t in common] == [alone[t] for t in common]
    lengths = [v[0] for v in alone.values()]
    assert min(lengths) == 0.0 and max(lengths) > chain.length - 1e-4  # both end stops


@pytest.mark.parametrize("period, start, initial, seed", [(0.05, 0.0, 0.02, 1), (0.05, 0.0, 0.0, 2),
                                                         (0.01, 0.0, 0.045, 3), (0.05, 0.0131, 0.02, 4)])
def test_feeder_steps_in_batches_give_the_numbers_of_stepping_alone(period, start, initial, seed):
    """``Feeder(command_period=)``: driven by a command set at a system's looks every ``period``,
    the batched feeder's outputs equal the feeder stepping every 2 ms at every simulator step
    (its own and a fast reader's), an engine-like reader at the looks reads the same lengths, and
    the end stops and the acceleration limit are crossed (random commands up to 1.4 x the limit).
    0.05 s against 2 ms steps puts some steps an ulp before a look (they move under the old
    command); a start between looks too."""
    from pydrake.systems.framework import DiagramBuilder

    chain = BallChain(n_balls=16)
    trace = {}
    for batched in (False, True):
        builder = DiagramBuilder()
        looks = builder.AddSystem(_Looks(period, seed))
        feeder = builder.AddSystem(Feeder(chain, initial_length=initial,
                                          command_period=period if batched else None))
        builder.Connect(looks.get_output_port(), feeder.GetInputPort("v_insert_cmd"))
        trace[batched] = _trace(builder, feeder, period, start)
        assert batched == (feeder.command_period == period)
    _same_at_common_steps(trace[False], trace[True], chain)


def _schedule():
    """A speed schedule over 9 s (zero-order hold) that crosses what a batch must get right:
    knots on the 2 ms step grid and between steps, one at 0.15 s (75 x 0.002 is 0.15 while
    3 x 0.05 is an ulp above it), 1.4 x the speed limit out to the far end stop and back past
    the near one, short segments (several knots in one batch), and random speeds after 6.5 s."""
    from pydrake.trajectories import PiecewisePolynomial

    fast = 1.4 * FeederSpec().max_speed
    rng = np.random.default_rng(7)
    knots = [(0.0, 0.0), (0.0131, 0.01), (0.15, fast), (0.1537, -0.003), (0.161, fast), (3.0, -fast),
             (6.5, 0.0)]
    t = 6.5
    while t < 9.0:
        t += float(rng.uniform(0.001, 0.12))
        knots.append((t, float(rng.uniform(-fast, fast))))
    knots.append((t + 1.0, 0.0))
    times, values = zip(*knots)
    return PiecewisePolynomial.ZeroOrderHold(list(times), np.array([values]))


@pytest.mark.parametrize("batch, start, initial", [(0.05, 0.0, 0.02), (0.01, 0.0, 0.0), (0.05, 0.0131, 0.045),
                                                   (None, 0.0, 0.02)])
def test_feeder_playing_a_schedule_in_batches_gives_the_numbers_of_a_trajectory_source(batch, start, initial):
    """``Feeder(schedule=, batch_period=)`` against the feeder stepping every 2 ms on its input
    from a ``TrajectorySource`` of the same schedule: the same outputs at every simulator step of
    both (its own, an engine-like reader's at the batch period, a 5 ms reader's), the readers'
    states the same, both end stops and the acceleration limit crossed. ``batch=None``: the
    schedule played step by step."""
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import TrajectorySource

    chain, schedule = BallChain(n_balls=16), _schedule()
    trace = {}
    for played in (False, True):
        builder = DiagramBuilder()
        if played:
            feeder = builder.AddSystem(Feeder(chain, initial_length=initial, schedule=schedule, batch_period=batch))
            assert feeder.num_input_ports() == 0 and feeder.batch_period == batch
        else:
            feeder = builder.AddSystem(Feeder(chain, initial_length=initial))
            source = builder.AddSystem(TrajectorySource(schedule))
            builder.Connect(source.get_output_port(), feeder.GetInputPort("v_insert_cmd"))
        trace[played] = _trace(builder, feeder, batch or 0.05, start)
    _same_at_common_steps(trace[False], trace[True], chain, fewer=batch is not None)


def test_feeder_schedule_is_checked():
    from pydrake.trajectories import PiecewisePolynomial

    from ballchain.infrastructure.errors import UserInputError

    hold = PiecewisePolynomial.ZeroOrderHold([0.0, 1.0], np.array([[0.01, 0.0]]))
    cases = [
        (dict(schedule=PiecewisePolynomial.FirstOrderHold([0.0, 1.0], np.array([[0.0, 0.01]]))), "zero-order hold"),
        (dict(schedule=PiecewisePolynomial.ZeroOrderHold([0.0, 1.0], np.zeros((2, 2)))), "zero-order hold"),
        (dict(schedule=PiecewisePolynomial.ZeroOrderHold([0.0, 1.0], np.array([[np.nan, 0.0]]))), "finite"),
        (dict(schedule=[0.0, 0.01]), "Feeder schedule must be a PiecewisePolynomial"),
        (dict(schedule=hold, command_period=0.05), "give one or the other"),
        (dict(batch_period=0.05), "batch_period needs a schedule"),
        (dict(schedule=hold, batch_period=0.003), "feeder batch_period must be a whole multiple"),
    ]
    for kwargs, message in cases:
        with pytest.raises(UserInputError, match=message):
            Feeder(BallChain(), **kwargs)


def test_feeder_command_period_must_be_whole_steps():
    from ballchain.infrastructure.errors import UserInputError

    for bad in (0.003, 0.0, -0.05, float("nan"), "0.05"):
        with pytest.raises(UserInputError, match="whole multiple of the step period"):
            Feeder(BallChain(), command_period=bad)
    assert Feeder(BallChain(), command_period=0.002).command_period is None  # one step: on its own


# --- Station -----------------------------------------------------------------------------


def test_neutral_direction_points_field_along_feed():
    # Unit at -y of the chain, field wanted along +x: dipole along -x (equatorial field is -m).
    np.testing.assert_allclose(neutral_direction([0, -0.1651, 0], np.zeros(3), [1, 0, 0]), [-1, 0, 0], atol=1e-15)


def test_two_unit_station_ports_superposition_and_teleop_rotation():
    points = np.array([[0.0, 0.0, 0.0], [0.02, 0.01, -0.01]])
    opt = StationOptions(field_points_W=points, with_feeder=True)
    station = make_actuation_station([right_unit(sensor_noise=False), left_unit(sensor_noise=False)], opt)
    assert station.get_name() == "actuation_station"
    assert port_names(station, "in") == [
        "right_unit.joystick",
        "right_unit.mode",
        "left_unit.joystick",
        "left_unit.mode",
        "feeder.v_insert_cmd",
    ]
    outs = port_names(station, "out")
    for n in ("right_unit", "left_unit"):
        for p in ("q_WM", "X_WM", "m_W", "omega_wheels", "B_sensor_T", "m_hat_W", "done", "angle_error"):
            assert f"{n}.{p}" in outs
    assert station.GetOutputPort("B_points_W").size() == 6
    ctx = station.CreateDefaultContext()
    for n in ("right_unit", "left_unit"):
        station.GetInputPort(f"{n}.mode").FixValue(ctx, [0.0])
    station.GetInputPort("right_unit.joystick").FixValue(ctx, [0.0, 0.0, 1.0])  # turn about +z
    station.GetInputPort("left_unit.joystick").FixValue(ctx, np.zeros(3))
    station.GetInputPort("feeder.v_insert_cmd").FixValue(ctx, [0.0])
    mag_r = unit_system(station, "right_unit", "magnet")
    m0 = np.array([1.0, 0.0, 0.0])
    mag_r.set_orientation(mag_r.GetMyMutableContextFromRoot(ctx), rotation_with_z_along(m0))
    # Superposition: the exported total field is the sum of both units' MagnetSources.
    srcs = [
        right_unit().source(rotation_with_z_along(m0)),
        left_unit().source(np.eye(3)),
    ]
    expected = srcs[0].field(points) + srcs[1].field(points)
    np.testing.assert_allclose(station.GetOutputPort("B_points_W").Eval(ctx), expected.reshape(-1), rtol=1e-12)
    sim = Simulator(station, ctx)
    sim.AdvanceTo(1.0)
    m = station.GetOutputPort("right_unit.m_W").Eval(ctx) / M_PROTO
    # Full stick about z at 0.5 rad/s for 1 s, minus the stepper ramp and quantisation:
    # m stays horizontal and turns by about 0.5 rad towards +y.
    assert abs(m[2]) < 1e-3
    angle = np.arctan2(m[1], m[0])
    assert angle == pytest.approx(0.5, abs=0.02)
    np.testing.assert_allclose(station.GetOutputPort("left_unit.m_W").Eval(ctx), [0, 0, M_PROTO], atol=1e-9)
    q = station.GetOutputPort("right_unit.q_WM").Eval(ctx)
    assert abs(np.linalg.norm(q) - 1.0) < 1e-6


def test_station_rejects_duplicate_unit_names():
    with pytest.raises(ValueError, match="distinct"):
        make_actuation_station([right_unit(), right_unit()])


def test_estimator_subtracts_the_other_units_field():
    # Dipole models throughout, so the inverse is exact and any error is cross-talk.
    r, l = right_unit(model="dipole"), left_unit(model="dipole")
    m_own = np.array([0.6, -0.3, 0.74])
    m_own /= np.linalg.norm(m_own)
    R_other = rotation_with_z_along([0.0, 1.0, 1.0])
    p_WS = r.p_WS[None]
    B = r.source(rotation_with_z_along(m_own)).field(p_WS)[0] + l.source(R_other).field(p_WS)[0]
    naive = DipoleDirectionEstimator(r)
    comp = DipoleDirectionEstimator(r, compensate_units=[l])
    assert port_names(comp, "in") == ["B_sensor_T", "X_WM_left_unit"]
    ctx_n, ctx_c = naive.CreateDefaultContext(), comp.CreateDefaultContext()
    naive.get_input_port(0).FixValue(ctx_n, B)
    comp.get_input_port(0).FixValue(ctx_c, B)
    comp.GetInputPort("X_WM_left_unit").FixValue(ctx_c, RigidTransform(RotationMatrix(R_other), l.p_WM))
    np.testing.assert_allclose(comp.get_output_port(0).Eval(ctx_c), m_own, atol=1e-12)
    err = np.rad2deg(np.arccos(np.clip(naive.get_output_port(0).Eval(ctx_n) @ m_own, -1, 1)))
    assert err > 0.3  # cross-talk of the other magnet, 0.33 m away


@pytest.mark.slow
def test_two_unit_station_reconfigures_both_units():
    # Dipole models keep it quick; the exact field is exercised by the single-unit study.
    units = [right_unit(model="dipole", slip=0.05, sensor_noise=True),
             left_unit(model="dipole", slip=0.05, sensor_noise=True)]
    station = make_actuation_station(units, StationOptions())
    ctx = station.CreateDefaultContext()
    starts = {"right_unit": [0.0, 0.6, 0.8], "left_unit": [0.3, -0.2, -0.9]}
    for n, m0 in starts.items():
        station.GetInputPort(f"{n}.mode").FixValue(ctx, [1.0])
        station.GetInputPort(f"{n}.joystick").FixValue(ctx, np.zeros(3))
        mag = unit_system(station, n, "magnet")
        mag.set_orientation(mag.GetMyMutableContextFromRoot(ctx), rotation_with_z_along(m0))
    Simulator(station, ctx).AdvanceTo(3.0)
    for n in starts:
        assert station.GetOutputPort(f"{n}.done").Eval(ctx)[0] == 1.0
        m = station.GetOutputPort(f"{n}.m_W").Eval(ctx) / M_PROTO
        # Neutral for both units: -x (field along +x at the chain between them).
        assert np.rad2deg(np.arccos(np.clip(-m[0], -1, 1))) < 1.0


def test_station_tip_frame_teleoperation_turns_the_field_at_the_tip():
    points = np.zeros((1, 3))
    opt = StationOptions(field_points_W=points)
    station = make_actuation_station([right_unit(sensor_noise=False, teleop_frame="tip", teleop_dead_band=0.0)], opt)
    assert {"right_unit.p_WT", "right_unit.tip_direction_W"} <= set(port_names(station, "in"))
    ctx = station.CreateDefaultContext()
    mag = unit_system(station, "right_unit", "magnet")
    mag.set_orientation(mag.GetMyMutableContextFromRoot(ctx), rotation_with_z_along([-1.0, 0.0, 0.0]))
    B0 = station.GetOutputPort("B_points_W").Eval(ctx)
    np.testing.assert_allclose(B0 / np.linalg.norm(B0), [1.0, 0.0, 0.0], atol=1e-12)  # neutral: along feed
    station.GetInputPort("right_unit.mode").FixValue(ctx, [0.0])
    station.GetInputPort("right_unit.p_WT").FixValue(ctx, np.zeros(3))
    station.GetInputPort("right_unit.tip_direction_W").FixValue(ctx, [1.0, 0.0, 0.0])
    station.GetInputPort("right_unit.joystick").FixValue(ctx, [1.0, 0.0, 0.0])  # yaw the tip left
    Simulator(station, ctx).AdvanceTo(1.0)
    B = station.GetOutputPort("B_points_W").Eval(ctx)
    # 0.5 rad/s about z for 1 s, less stepper ramp and quantisation.
    assert np.arctan2(B[1], B[0]) == pytest.approx(0.5, abs=0.02)
    assert abs(B[2]) < 1e-3 * np.linalg.norm(B)


def test_held_value_and_an_unchanged_latch_stay_in_drakes_cache():
    """A constant mode script (``HeldValue``) is computed once, and a controller whose latch update
    changes nothing leaves its outputs cached: the mode switch downstream is not recomputed at
    every step (Drake's ``ConstantVectorSource`` is: it depends on time)."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from ballchain.systems.reconfiguration import ReconfigurationController
    from ballchain.systems.station_units import HeldValue

    builder = DiagramBuilder()
    held = builder.AddSystem(HeldValue([0.0]))
    constant = builder.AddSystem(ConstantVectorSource([0.0]))
    measured = builder.AddSystem(HeldValue([0.0, 0.0, 1.0]))
    controller = builder.AddSystem(ReconfigurationController(np.array([0.0, 0.0, 1.0])))
    builder.Connect(held.get_output_port(), controller.GetInputPort("mode"))
    builder.Connect(measured.get_output_port(), controller.GetInputPort("m_hat_measured_W"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.Initialize()
    root = simulator.get_context()
    contexts = {s: s.GetMyContextFromRoot(root) for s in (held, constant, controller)}
    ports = [(held, held.get_output_port()), (constant, constant.get_output_port()),
             (controller, controller.GetOutputPort("omega_desired_W"))]
    simulator.AdvanceTo(0.015)  # the latch set at its first update (the measurement is the neutral)
    assert controller.GetOutputPort("done").Eval(contexts[controller])[0] == 1.0
    for t in (0.017, 0.021, 0.025, 0.031):  # steps across the controller's 10 ms updates
        for system, port in ports:
            port.Eval(contexts[system])
        simulator.AdvanceTo(t)
        stale = [port.cache_entry().is_out_of_date(contexts[system]) for system, port in ports]
        assert stale == [False, True, False], t
    assert np.array_equal(held.get_output_port().Eval(contexts[held]), [0.0])
    assert np.array_equal(controller.GetOutputPort("omega_desired_W").Eval(contexts[controller]), np.zeros(3))
