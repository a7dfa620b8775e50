"""The actuation side of the chain-in-a-heart station: rotating magnet units and the feeder.

``station.MakeStation`` calls these when a scenario has ``units`` or
``insertion.feeder``. Per unit ``<u>`` (systems named as in ``actuation_station``):

    ``<u>.joystick`` (scripted stick, zero-order hold) -> ``<u>.teleoperation`` ->
    ``<u>.unit`` (``actuation_unit.ActuationUnit``: the drive, magnet, Hall sensor, estimator,
    controller and mode switch in one system, its update compiled; ``<u>.mode_command`` feeds its
    ``mode``), or with the scenario's ``unit_systems: python`` the composed systems
    ``<u>.mode_switch`` (``<u>.mode_command``) -> ``<u>.drive`` -> ``<u>.magnet`` ->
    ``<u>.hall_sensor`` -> ``<u>.estimator`` -> ``<u>.controller`` -> ``<u>.mode_switch``,
    ``<u>.mode_command`` also feeding ``<u>.controller`` (its going to 1 starts a reconfiguration);

with ``joystick_source: external`` there is no ``<u>.joystick``: the mapper's ``joystick`` input
is returned (``UnitHandles.joystick_input``) for another system (a simulated operator) to drive.
With ``teleop_frame: tip`` (the catheter-frame mapping) ``tip_observer`` (TipObserver: the tip
ball's centre and direction from the plant's body poses) feeds the mapper's ``p_WT`` and
``tip_direction_W``, and the magnet's ``m_W`` feeds its ``m_W``.

and every unit's dipole ``m_W`` with its fixed centre ``<u>.p_WM`` goes through
``magnet_states`` (a Multiplexer) into the chain model's ``magnet_states`` input,
so the chain feels the magnets as the wheels turn them. The units themselves (``add_unit`` per
unit, each Hall sensor also seeing the other units, each estimator subtracting them) are wired
by ``actuation_station.add_unit_systems``, the same step as the actuation-only diagram's.

The feeder: ``feeder`` (stepper, quantised; it plays the insertion ramp as a speed schedule, or
with ``insertion.feeder_command: external`` takes its command in ``v_insert_cmd``) ->
``feeder_interface`` (s -> desired slide state (s, 0)) -> the chain.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, OutputPort
from pydrake.systems.primitives import ConstantVectorSource, MatrixGain, Multiplexer, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.drake_models.params import BallChain, CylinderMagnet
from ballchain.drake_models.dipole_inversion import neutral_direction
from ballchain.systems.actuation_station import StationOptions, add_unit_systems
from ballchain.systems.actuation_unit import ActuationUnit
from ballchain.systems.chain_scenario import ChainScenario, InsertionScenario
from ballchain.systems.feeder import Feeder, FeederSpec, whole_steps
from ballchain.systems.hall_sensor import DipoleDirectionEstimator, HallSensor
from ballchain.systems.omni_wheel_drive import OmniWheelDrive
from ballchain.systems.reconfiguration import ReconfigurationController
from ballchain.systems.rotating_magnet_unit import RotatingMagnetUnit
from ballchain.systems.teleoperation import TeleoperationMapper
from ballchain.systems.unit_config import JoystickKey, MagnetUnitConfig
from ballchain.drake_models.vectors import perpendicular_axis


@dataclass
class UnitHandles:
    """The systems of one unit in the station diagram: with the compiled unit (the default) its one
    ``ActuationUnit`` is the magnet, drive, sensor, estimator and controller (it has each one's
    ports and methods)."""

    config: MagnetUnitConfig
    magnet: RotatingMagnetUnit | ActuationUnit
    drive: OmniWheelDrive | ActuationUnit
    sensor: HallSensor | ActuationUnit
    estimator: DipoleDirectionEstimator | ActuationUnit
    controller: ReconfigurationController | ActuationUnit
    teleoperation: TeleoperationMapper
    joystick: TrajectorySource | None
    m_hat_neutral_W: np.ndarray
    m_hat_initial_W: np.ndarray
    joystick_input: object = None  # the mapper's ``joystick`` input port (3)

    def set_joystick(self, keys: list[JoystickKey]) -> None:
        """Replace the scripted stick axes (also mid-run: a live operator re-planning from now on).

        Only the axes: the mode script (``<u>.mode_command``) is the scenario's.
        """
        if self.joystick is None:
            raise UserInputError(f"unit {self.config.name!r}: its joystick is external (joystick_source: external)")
        times = [k.time for k in keys] or [0.0]
        axes = np.array([k.axes for k in keys], float).reshape(-1, 3).T if keys else np.zeros((3, 1))
        self.joystick.UpdateTrajectory(_zoh(times, axes))


def unit_configs(scenario: ChainScenario, anchors: dict[str, np.ndarray]) -> list[MagnetUnitConfig]:
    """The scenario's units, placed (``MagnetUnitConfig.placed``: each a copy with its centre).

    Args:
        scenario: a validated scenario.
        anchors: {"puncture", "centre", ...}: (3,) anchor points in world [m].
    """
    return [u.placed(anchors) for u in scenario.units]


def _zoh_source(times: list[float], values: np.ndarray, name: str, builder):
    """A zero-order-hold TrajectorySource of (size, k) values at k times (zeros before the first)."""
    source = builder.AddSystem(TrajectorySource(_zoh(times, values)))
    source.set_name(name)
    return source


class HeldValue(LeafSystem):
    """A constant vector output (``y0``) that depends on nothing: Drake's cache computes it once.

    Drake's ``ConstantVectorSource`` gives the same value, but its output is recomputed at every
    step (it is declared dependent on everything, time included), and so is every output
    downstream that is declared dependent on its inputs only.
    """

    def __init__(self, value) -> None:
        super().__init__()
        self._value = np.array(value, dtype=float).reshape(-1)
        self.DeclareVectorOutputPort("y0", len(self._value), lambda context, output: output.SetFromVector(self._value),
                                     prerequisites_of_calc={self.nothing_ticket()})


def _mode_source(times: list[float], modes: list[float], name: str, builder):
    """The mode script's source: ``_zoh_source`` of the modes, or a ``HeldValue`` of the one value
    it holds when it never changes (the same output at every time, but one that no step
    invalidates: the mode switch and the controller downstream are then recomputed only when
    their other inputs change, not at every step)."""
    held = _zoh(times, np.array([modes]).reshape(1, -1))
    values = np.unique(np.concatenate(held.vector_values(held.get_segment_times())))
    if len(values) == 1:
        source = builder.AddSystem(HeldValue([float(values[0])]))
        source.set_name(name)
        return source
    return _zoh_source(times, np.array([modes]).reshape(1, -1), name, builder)


def _zoh(times: list[float], values: np.ndarray) -> PiecewisePolynomial:
    """Zero-order hold of (size, k) values at k times, zeros before the first, held after the last."""
    times = list(times)
    values = np.asarray(values, float)
    if not times or times[0] > 0.0:
        times = [0.0] + times
        values = np.hstack([np.zeros((values.shape[0], 1)), values]) if values.size else np.zeros((values.shape[0], 1))
    # Strictly increasing breaks (a later key at the same time wins) and one after the last.
    t_out, v_out = [], []
    for t, v in zip(times, values.T):
        if t_out and t <= t_out[-1]:
            v_out[-1] = v
            continue
        t_out.append(t)
        v_out.append(v)
    t_out.append(t_out[-1] + 1.0)
    v_out.append(v_out[-1])
    return PiecewisePolynomial.ZeroOrderHold(t_out, np.array(v_out).T)


class TipObserver(LeafSystem):
    """The tip ball's centre and direction (from the ball before it) out of the plant's body poses.

    Input ports:
        body_poses: abstract list[RigidTransform] indexed by BodyIndex (the plant's ``body_poses``).

    Output ports:
        p_WT: (3,) the tip ball's centre [m].
        tip_direction_W: (3,) unit vector from the previous ball's centre to the tip ball's.
    """

    def __init__(self, tip_body_index, previous_body_index, name: str = "tip_observer") -> None:
        super().__init__()
        from pydrake.math import RigidTransform

        self.set_name(name)
        self._tip, self._previous = int(tip_body_index), int(previous_body_index)
        self._poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        inputs = {self.all_input_ports_ticket()}  # the poses alone: cached until they change
        self.DeclareVectorOutputPort("p_WT", 3, self._calc_p, prerequisites_of_calc=inputs)
        self.DeclareVectorOutputPort("tip_direction_W", 3, self._calc_direction, prerequisites_of_calc=inputs)

    def get_body_poses_input_port(self):
        return self._poses

    def _calc_p(self, context, output):
        output.SetFromVector(self._poses.Eval(context)[self._tip].translation())

    def _calc_direction(self, context, output):
        poses = self._poses.Eval(context)
        d = poses[self._tip].translation() - poses[self._previous].translation()
        n = np.linalg.norm(d)
        output.SetFromVector(d / n if n > 0 else np.array([1.0, 0.0, 0.0]))


def add_units(builder, scenario: ChainScenario, configs: list[MagnetUnitConfig], magnet_states_port,
              p_W_chain: np.ndarray, feed_direction_W: np.ndarray, tip_observer: TipObserver | None = None
              ) -> tuple[dict[str, UnitHandles], OutputPort]:
    """Add the units' systems to ``builder`` and connect them to the chain's ``magnet_states``.

    Args:
        builder: the station's DiagramBuilder.
        scenario: the scenario (its ``units``, placed, are ``configs``).
        configs: from ``unit_configs``: every setting of each unit.
        magnet_states_port: the chain model's ``magnet_states`` input (6 per unit).
        p_W_chain: (3,) where the neutral field is defined [m] (sheath exit / ball 1).
        feed_direction_W: (3,) the insertion direction (the neutral field's direction there).
        tip_observer: the tip's position and direction, needed by units with ``teleop_frame: tip``.

    Returns:
        ({unit name: UnitHandles}, the units' ``magnet_states`` output (the Multiplexer's)). With
        ``joystick_source: external`` a unit's ``joystick`` is None and its ``joystick_input``
        (the mapper's input port) is left unconnected for the caller.
    """
    handles: dict[str, UnitHandles] = {}
    m_neutral, m_initial = [], []
    for u in configs:
        m_c = neutral_direction(np.asarray(u.p_WM), p_W_chain, feed_direction_W)
        m_neutral.append(m_c / np.linalg.norm(m_c))
        m0 = np.asarray(u.m_hat_W, float) if u.m_hat_W else m_neutral[-1]
        m_initial.append(m0 / np.linalg.norm(m0))
    # The same unit step as the actuation-only diagram (actuation_station.make_actuation_station),
    # with the default hardware; unit k's Hall noise seed defaults to k.
    options = StationOptions(compiled_units=scenario.unit_systems == "compiled")
    unit_systems = add_unit_systems(builder, configs, options, m_neutral_W=m_neutral,
                                    seeds=range(len(configs)), R_WM=[rotation_with_z_along(m0) for m0 in m_initial])
    for u, m_c, m0 in zip(configs, m_neutral, m_initial):
        n = u.name
        systems = unit_systems[n]
        teleop = systems.teleop
        if u.teleop_frame == "tip":
            if tip_observer is None:
                raise UserInputError(f"unit {n!r}: teleop_frame 'tip' needs the tip's pose (a tip observer)")
            builder.Connect(tip_observer.GetOutputPort("p_WT"), teleop.GetInputPort("p_WT"))
            builder.Connect(tip_observer.GetOutputPort("tip_direction_W"), teleop.GetInputPort("tip_direction_W"))
        keys: list[JoystickKey] = u.joystick
        stick = None
        if u.joystick_source == "script":
            stick = _zoh_source([q.time for q in keys], np.array([q.axes for q in keys], float).reshape(-1, 3).T,
                                f"{n}.joystick", builder)
            builder.Connect(stick.get_output_port(), teleop.GetInputPort("joystick"))
        mode = _mode_source([q.time for q in keys], [float(q.mode) for q in keys], f"{n}.mode_command", builder)
        for port in systems.mode_inputs:
            builder.Connect(mode.get_output_port(), port)
        handles[n] = UnitHandles(u, systems.magnet, systems.drive, systems.sensor, systems.estimator,
                                 systems.controller, teleop, stick, m_c, m0, teleop.GetInputPort("joystick"))
    mux = builder.AddSystem(Multiplexer([3] * (2 * len(handles))))
    mux.set_name("magnet_states")
    for k, (n, h) in enumerate(handles.items()):
        centre = builder.AddSystem(ConstantVectorSource(np.asarray(h.config.p_WM)))
        centre.set_name(f"{n}.p_WM")
        builder.Connect(centre.get_output_port(), mux.get_input_port(2 * k))
        # The wrench normalises the dipole: its size is the magnet's, fixed in port_magnets.
        builder.Connect(h.magnet.GetOutputPort("m_W"), mux.get_input_port(2 * k + 1))
    builder.Connect(mux.get_output_port(), magnet_states_port)
    return handles, mux.get_output_port()


def add_feeder(builder, chain: BallChain, insertion: InsertionScenario, desired_state_port,
               reader_period: float = 0.0) -> Feeder:
    """The stepper feeder playing the insertion ramp, driving the slide's desired state.

    The ramp is the feeder's own speed schedule (a zero-order hold: the ramp's speed from its
    start for its duration, zero before and after). With a ``reader_period`` > 0 that is a
    whole number of the feeder's steps (the quasi-static engine's, whose updates alone read the
    length) the feeder makes its steps in batches at the reader's times: the same numbers, a
    third of the simulator steps of a teleoperation second. With ``insertion.feeder_command:
    external`` there is no schedule: the feeder's ``v_insert_cmd`` input is left unconnected for
    the caller (batched at ``insertion.feeder_command_period``).

    Raises:
        UserInputError: the ramp's speed exceeds the feeder's limit.
    """
    spec = FeederSpec()
    ins = insertion
    external = getattr(ins, "feeder_command", "ramp") == "external"
    if ins.speed > spec.max_speed and ins.final != ins.initial and not external:
        raise UserInputError(f"insertion.speed {ins.speed} m/s exceeds the feeder's limit {spec.max_speed} m/s")
    if external:
        feeder = Feeder(chain, spec, initial_length=ins.initial,
                        command_period=getattr(ins, "feeder_command_period", 0.0) or None)
    else:
        ramp = abs(ins.final - ins.initial) / ins.speed if ins.speed > 0 else 0.0
        t1 = max(ins.start_time, 0.0)
        v = np.sign(ins.final - ins.initial) * ins.speed
        schedule = _zoh([t1, t1 + ramp], np.array([[v, 0.0]])) if ramp > 0 else _zoh([0.0], np.zeros((1, 1)))
        feeder = Feeder(chain, spec, initial_length=ins.initial, schedule=schedule,
                        batch_period=reader_period if whole_steps(reader_period, spec.update_period) else None)
    builder.AddSystem(feeder)
    to_state = builder.AddSystem(MatrixGain(np.array([[1.0], [0.0]])))
    to_state.set_name("feeder_interface")
    builder.Connect(feeder.GetOutputPort("inserted_length"), to_state.get_input_port())
    builder.Connect(to_state.get_output_port(), desired_state_port)
    return feeder


class UnitMeshcatMarkers(LeafSystem):
    """Draws the units' magnets (body and dipole arrow) in Meshcat and moves them as they turn.

    Input ports:
        X_WM_<name>: RigidTransform (abstract), one per unit (its magnet's pose; z = dipole).

    Publishes every ``period`` seconds (and at initialisation); while Meshcat is recording, each
    pose is also stored in the animation at the current time, so the HTML replay shows it.
    """

    def __init__(self, meshcat, configs: list[MagnetUnitConfig], period: float) -> None:
        super().__init__()
        from pydrake.geometry import Cylinder, Rgba, Sphere
        from pydrake.math import RigidTransform

        self.set_name("unit_markers")
        self._meshcat = meshcat
        self._paths = [f"units/{c.name}" for c in configs]
        self._ports = [self.DeclareAbstractInputPort(f"X_WM_{c.name}", AbstractValue.Make(RigidTransform()))
                       for c in configs]
        for c, path in zip(configs, self._paths):
            m = c.magnet
            if isinstance(m, CylinderMagnet):
                meshcat.SetObject(f"{path}/body", Cylinder(m.diameter / 2, m.length), Rgba(0.6, 0.6, 0.65, 0.8))
                half = m.length / 2
            else:
                meshcat.SetObject(f"{path}/body", Sphere(m.diameter / 2), Rgba(0.6, 0.6, 0.65, 0.8))
                half = m.diameter / 2
            arrow = 0.06  # [m]
            meshcat.SetObject(f"{path}/dipole", Cylinder(0.004, arrow), Rgba(0.85, 0.1, 0.1, 1.0))
            meshcat.SetTransform(f"{path}/dipole", RigidTransform([0.0, 0.0, half + arrow / 2]))
            meshcat.SetObject(f"{path}/north", Sphere(0.008), Rgba(0.85, 0.1, 0.1, 1.0))
            meshcat.SetTransform(f"{path}/north", RigidTransform([0.0, 0.0, half + arrow]))
        self.DeclarePeriodicPublishEvent(period, 0.0, self._publish)
        self.DeclareInitializationPublishEvent(self._publish)

    def _publish(self, context):
        t = context.get_time()
        for path, port in zip(self._paths, self._ports):
            self._meshcat.SetTransform(path, port.Eval(context), t)


def joystick_keys_for_rotation(m_from_W, m_to_W, omega_max: float, start_time: float = 0.0,
                               dead_band: float = MagnetUnitConfig.teleop_dead_band) -> list[JoystickKey]:
    """A scripted stick that turns a magnet's dipole from ``m_from_W`` to ``m_to_W`` (world mapping).

    The shortest rotation, about ``m_from x m_to``, with the largest stick axis at full travel; the
    stick values are pre-compensated for the mapper's dead band so that the magnet turns about
    exactly that axis. The drive's acceleration ramps are symmetric, so the angle is kept (to
    the steppers' microsteps) as long as no wheel saturates.

    Args:
        m_from_W, m_to_W: (3,) dipole directions (any length).
        omega_max: the unit's ``teleop_omega_max`` [rad/s].
        start_time: when the stick moves [s].
        dead_band: the mapper's dead band (a unit's ``teleop_dead_band``; default: its default).

    Returns:
        two keys: the stick at ``start_time``, released after the rotation's duration.
    """
    a = np.asarray(m_from_W, float) / np.linalg.norm(m_from_W)
    b = np.asarray(m_to_W, float) / np.linalg.norm(m_to_W)
    cross = np.cross(a, b)
    angle = float(np.arctan2(np.linalg.norm(cross), a @ b))
    if angle < 1e-9:
        return [JoystickKey(time=start_time, axes=[0.0, 0.0, 0.0])]
    if np.linalg.norm(cross) < 1e-9:  # antiparallel: any axis perpendicular to a

        cross = perpendicular_axis(a)
    axis = cross / np.linalg.norm(cross)
    scaled = axis / np.abs(axis).max()  # largest component at full stick
    stick = np.where(np.abs(scaled) > 1e-12, np.sign(scaled) * (dead_band + (1 - dead_band) * np.abs(scaled)), 0.0)
    duration = angle / (omega_max * np.linalg.norm(scaled))
    return [JoystickKey(time=start_time, axes=stick.tolist()),
            JoystickKey(time=start_time + duration, axes=[0.0, 0.0, 0.0])]
