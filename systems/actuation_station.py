"""The actuation station: one or two magnet units (right/left of the patient) and the feeder.

Each unit is wired as a loop: the teleoperation mapper and the reconfiguration controller both
feed the mode switch, which feeds the drive -> magnet -> Hall sensor -> estimator -> controller
(by default all of these but the mapper are one ``actuation_unit.ActuationUnit``, its update
compiled, the same numbers; ``StationOptions(compiled_units=False)``: the composed systems);
and the diagram exports, per unit ``<u>``: inputs ``<u>.joystick`` (3), ``<u>.mode`` (1: 0
teleoperation, 1 reconfiguration), and with ``teleop_frame="tip"`` ``<u>.p_WT`` (3) and
``<u>.tip_direction_W`` (3); outputs ``<u>.q_WM`` (4), ``<u>.X_WM`` (RigidTransform),
``<u>.m_W`` (3), ``<u>.omega_wheels`` (3), ``<u>.B_sensor_T`` (3), ``<u>.m_hat_W`` (3),
``<u>.done`` (1), ``<u>.angle_error`` (1); the total field at the given points ``B_points_W`` (3 k)
when points are given; with the feeder, input ``feeder.v_insert_cmd`` (1) and outputs
``feeder.inserted_length`` (1), ``feeder.balls_out`` (1). No MultibodyPlant is involved: a chain
simulation can read ``B_points_W`` (or each unit's ``X_WM``) and do its own physics.

This is the hardware-interface view of the station: the units are added and wired to one
another by ``add_unit_systems``, the same unit step the full station (``station.MakeStation``,
through ``station_units.add_units``) uses; only what is exported differs. Each unit's settings
are its ``MagnetUnitConfig`` (``unit_config``, the scenario's type), the rest ``StationOptions``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Adder

from ballchain.drake_models.dipole_inversion import neutral_direction
from ballchain.infrastructure.arg_checks import as_vector, require_bool, require_choice, require_int, require_type
from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.drake_models.params import BallChain
from ballchain.systems.feeder import Feeder, FeederSpec
from ballchain.systems.hall_sensor import DipoleDirectionEstimator, HallSensor, HallSensorSpec
from ballchain.systems.omni_wheel_drive import OmniWheelDrive, StepperSpec
from ballchain.systems.reconfiguration import ReconfigurationController
from ballchain.systems.rotating_magnet_unit import RotatingMagnetUnit
from ballchain.systems.teleoperation import ModeSwitch, TeleoperationMapper
from ballchain.systems.unit_config import MagnetUnitConfig, right_unit
from ballchain.systems.actuation_unit import ActuationUnit, compilable


@dataclass
class StationOptions:
    """The actuation station's options besides its units: where the chain enters, the hardware, the feeder.

    Each unit's own settings, from its slip and Hall noise to its controller and joystick
    mapping, are its ``MagnetUnitConfig``'s.

    Attributes:
        p_W_chain: (3,) where the chain enters (the neutral field is defined there) [m].
        feed_direction_W: (3,) insertion direction; neutral field points along it there.
        seed: base Hall-noise seed (each unit adds its index): the default of each sensor's seed
            parameter (``randomness.set_random_context`` draws others).
        sensor_spec, stepper_spec: hardware figures (every unit's).
        field_points_W: (k, 3) points where the total field is exported [m], or None.
        with_feeder: add the feeder.
        chain: the ball chain fed by the feeder.
        compiled_units: each unit as one ``actuation_unit.ActuationUnit`` (its update compiled,
            the same numbers) where it can be (``actuation_unit.compilable``); False: the
            composed Python systems (the reference).
    """

    p_W_chain: np.ndarray = field(default_factory=lambda: np.zeros(3))
    feed_direction_W: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    seed: int = 0
    sensor_spec: HallSensorSpec = field(default_factory=HallSensorSpec)
    stepper_spec: StepperSpec = field(default_factory=StepperSpec)
    field_points_W: np.ndarray | None = None
    with_feeder: bool = False
    chain: BallChain = field(default_factory=BallChain)
    compiled_units: bool = True

    def __post_init__(self) -> None:
        as_vector(self.p_W_chain, "StationOptions.p_W_chain", unit="m")
        as_vector(self.feed_direction_W, "StationOptions.feed_direction_W", nonzero=True)
        require_bool(self.with_feeder, "StationOptions.with_feeder")
        require_bool(self.compiled_units, "StationOptions.compiled_units")
        require_int(self.seed, "StationOptions.seed", 0)
        require_type(self.sensor_spec, HallSensorSpec, "StationOptions.sensor_spec")
        require_type(self.stepper_spec, StepperSpec, "StationOptions.stepper_spec")
        if self.field_points_W is not None:
            try:
                points = np.asarray(self.field_points_W, dtype=float).reshape(-1, 3)
            except (TypeError, ValueError):
                points = np.zeros((0, 3))
            if not len(points) or not np.all(np.isfinite(points)):
                raise UserInputError("StationOptions.field_points_W must be (k, 3) finite points [m] or None, got "
                                     f"{short_repr(self.field_points_W)}")
        require_type(self.chain, BallChain, "StationOptions.chain")


@dataclass
class UnitSystems:
    """The systems of one actuation unit, added by ``add_unit``: six composed systems, or one
    ``ActuationUnit`` in each of the six roles (it has each one's ports and methods)."""

    magnet: RotatingMagnetUnit | ActuationUnit
    drive: OmniWheelDrive | ActuationUnit
    sensor: HallSensor | ActuationUnit
    estimator: DipoleDirectionEstimator | ActuationUnit
    controller: ReconfigurationController | ActuationUnit
    teleop: TeleoperationMapper
    switch: ModeSwitch | ActuationUnit

    @property
    def compiled(self) -> bool:
        """Whether the unit is one ``ActuationUnit``."""
        return isinstance(self.magnet, ActuationUnit)

    @property
    def mode_inputs(self) -> list:
        """The input ports the unit's mode source feeds (the switch's and the controller's)."""
        if self.compiled:
            return [self.magnet.GetInputPort("mode")]
        return [self.switch.GetInputPort("mode"), self.controller.GetInputPort("mode")]


def add_unit(
    builder: DiagramBuilder,
    unit: MagnetUnitConfig,
    opt: StationOptions,
    *,
    m_neutral_W: np.ndarray,
    others: Sequence[MagnetUnitConfig] = (),
    seed: int = 0,
    R_WM: np.ndarray | None = None,
) -> UnitSystems:
    """Add one unit's systems to ``builder`` and close its loops.

    mode switch -> omni-wheel drive -> magnet -> Hall sensor -> estimator -> reconfiguration
    controller -> mode switch (and teleoperation -> mode switch). Left to the caller: the
    joystick and mode inputs (one mode source into both the switch's and the controller's
    ``mode``: the controller starts a new reconfiguration when it goes to 1), the other units'
    poses into the sensor and estimator (``X_WM_<name>`` ports for each of ``others``), and what
    is exported.

    Args:
        builder: the diagram builder.
        unit: the unit's configuration, placed (its slip, Hall noise, controller and mapping).
        opt: hardware figures (and the field points of the magnet's ``B_points_W``).
        m_neutral_W: (3,) the reconfiguration target direction.
        others: units whose fields this unit's sensor sees (and its estimator may subtract).
        seed: the Hall sensor's default noise seed.
        R_WM: initial magnet orientation (default: the unit's own default).
    """
    n = unit.name
    teleop = builder.AddSystem(
        TeleoperationMapper(
            frame=unit.teleop_frame,
            omega_max=unit.teleop_omega_max,
            dead_band=unit.teleop_dead_band,
            p_WM=np.asarray(unit.p_WM),
            name=n,
        )
    )
    if opt.compiled_units and compilable(unit, others, opt.sensor_spec, opt.stepper_spec):
        fused = builder.AddSystem(ActuationUnit(unit, m_neutral_W=m_neutral_W, others=others,
                                                sensor_spec=opt.sensor_spec, stepper_spec=opt.stepper_spec,
                                                seed=seed, R_WM=R_WM, field_points_W=opt.field_points_W))
        if unit.teleop_frame == "tip":
            builder.Connect(fused.GetOutputPort("m_W"), teleop.GetInputPort("m_W"))
        builder.Connect(teleop.GetOutputPort("omega_desired_W"), fused.GetInputPort("omega_teleop_W"))
        return UnitSystems(fused, fused, fused, fused, fused, teleop, fused)
    # The drive holds its wheel speeds over its update period: at that period the magnet's
    # orientation is exact as discrete state (no continuous state, no integrator sub-steps).
    magnet = builder.AddSystem(RotatingMagnetUnit(unit, R_WM=R_WM, field_points_W=opt.field_points_W,
                                                  update_period=opt.stepper_spec.update_period))
    drive = builder.AddSystem(OmniWheelDrive(unit.geometry, opt.stepper_spec, name=n))
    sensor = builder.AddSystem(HallSensor(unit, other_units=others, spec=opt.sensor_spec, seed=seed))
    estimator = builder.AddSystem(
        DipoleDirectionEstimator(unit, compensate_units=others if unit.estimator_compensates_other_units else ())
    )
    controller = builder.AddSystem(
        ReconfigurationController(
            m_neutral_W,
            gain=unit.controller_gain,
            max_wheel_speed=opt.stepper_spec.max_speed,
            tolerance_deg=unit.tolerance_deg,
            period=1.0 / opt.sensor_spec.sample_rate_hz,
            geometry=unit.geometry,
            wheel_map=unit.wheel_map,
            name=n,
        )
    )
    if unit.teleop_frame == "tip":
        builder.Connect(magnet.GetOutputPort("m_W"), teleop.GetInputPort("m_W"))
    switch = builder.AddSystem(ModeSwitch(name=n))
    builder.Connect(teleop.GetOutputPort("omega_desired_W"), switch.GetInputPort("omega_teleop_W"))
    builder.Connect(controller.GetOutputPort("omega_desired_W"), switch.GetInputPort("omega_reconfigure_W"))
    builder.Connect(switch.GetOutputPort("omega_desired_W"), drive.GetInputPort("omega_desired_W"))
    builder.Connect(drive.GetOutputPort("omega_wheels"), magnet.GetInputPort("omega_wheels"))
    builder.Connect(magnet.GetOutputPort("X_WM"), sensor.GetInputPort("X_WM"))
    builder.Connect(sensor.GetOutputPort("B_sensor_T"), estimator.GetInputPort("B_sensor_T"))
    builder.Connect(estimator.GetOutputPort("m_hat_W"), controller.GetInputPort("m_hat_measured_W"))
    return UnitSystems(magnet, drive, sensor, estimator, controller, teleop, switch)


def connect_other_units(builder: DiagramBuilder, units: dict) -> None:
    """Each unit's Hall sensor sees the other magnets; each estimator may subtract them.

    Args:
        builder: the diagram builder.
        units: unit name -> (UnitSystems, the names of the units its sensor sees, whether its
            estimator subtracts their fields: the unit's ``estimator_compensates_other_units``).
    """
    for systems, others, compensate in units.values():
        for o in others:
            if systems.compiled:  # one input per other magnet: its quaternion
                builder.Connect(units[o][0].magnet.GetOutputPort("q_WM"), systems.magnet.GetInputPort(f"q_WM_{o}"))
                continue
            X_port = units[o][0].magnet.GetOutputPort("X_WM")
            builder.Connect(X_port, systems.sensor.GetInputPort(f"X_WM_{o}"))
            if compensate:
                builder.Connect(X_port, systems.estimator.GetInputPort(f"X_WM_{o}"))


def add_unit_systems(
    builder: DiagramBuilder,
    units: Sequence[MagnetUnitConfig],
    options: StationOptions,
    *,
    m_neutral_W: Sequence[np.ndarray],
    seeds: Sequence[int],
    R_WM: Sequence[np.ndarray | None] | None = None,
) -> dict[str, UnitSystems]:
    """Add every unit's systems (``add_unit``) and wire the units to one another: the one unit
    step of both the actuation-only diagram (``make_actuation_station``) and the full station
    (``station_units.add_units``, from ``station.MakeStation``).

    Each unit's Hall sensor sees the other units' magnets when its config says
    ``sensors_see_other_units``, and its estimator subtracts their fields when it says
    ``estimator_compensates_other_units`` (``connect_other_units``). Left to the caller: the
    joystick and mode inputs and what is exported or connected to a chain.

    Args:
        builder: the diagram builder.
        units: the units' configurations, placed (distinct names).
        options: the hardware figures (and field points) of every unit.
        m_neutral_W: one (3,) reconfiguration target direction per unit.
        seeds: one default Hall-noise seed per unit.
        R_WM: one initial magnet orientation per unit (None entries: the unit's own default).

    Returns:
        {unit name: UnitSystems}, in the order of ``units``.
    """
    R_WM = list(R_WM) if R_WM is not None else [None] * len(units)
    systems, wiring = {}, {}
    for unit, m_c, seed, R in zip(units, m_neutral_W, seeds, R_WM):
        others = [u for u in units if u is not unit] if unit.sensors_see_other_units else []
        systems[unit.name] = add_unit(builder, unit, options, m_neutral_W=m_c, others=others, seed=seed, R_WM=R)
        wiring[unit.name] = (systems[unit.name], [o.name for o in others], unit.estimator_compensates_other_units)
    connect_other_units(builder, wiring)
    return systems


def make_actuation_station(
    units: Sequence[MagnetUnitConfig] | None = None, options: StationOptions | None = None
) -> Diagram:
    """Build the station diagram (named ``actuation_station``).

    Args:
        units: one or two (or more) placed unit configs with distinct names (default: the right
            unit); each unit's settings are its own, and with ``teleop_frame: tip`` its mapper's
            ``p_WT`` and ``tip_direction_W`` are exported.
        options: everything else.

    Returns:
        The diagram; see the module docstring for its exported ports. The magnets' orientations
        are set through ``unit_system(diagram, name, "magnet").set_orientation``.
    """
    if units is not None:
        require_type(units, (list, tuple), "make_actuation_station units", "a list of MagnetUnitConfig or None")
        for k, unit in enumerate(units):
            require_type(unit, MagnetUnitConfig, f"make_actuation_station units[{k}]")
    if options is not None:
        require_type(options, StationOptions, "make_actuation_station options", "a StationOptions or None")
    units = [u.check_placed() for u in units] if units is not None else [right_unit()]
    opt = options or StationOptions()
    names = [u.name for u in units]
    if len(set(names)) != len(names) or not names:
        raise UserInputError(f"unit names must be distinct and at least one, got {names}")
    builder = DiagramBuilder()
    magnets = add_unit_systems(
        builder, units, opt,
        m_neutral_W=[neutral_direction(u.p_WM, opt.p_W_chain, opt.feed_direction_W) for u in units],
        seeds=[opt.seed + k for k in range(len(units))])
    for unit in units:
        n = unit.name
        systems = magnets[n]
        magnet, drive, sensor, estimator = systems.magnet, systems.drive, systems.sensor, systems.estimator
        controller, teleop = systems.controller, systems.teleop
        builder.ExportInput(teleop.GetInputPort("joystick"), f"{n}.joystick")
        mode_inputs = systems.mode_inputs
        builder.ExportInput(mode_inputs[0], f"{n}.mode")
        for port in mode_inputs[1:]:
            builder.ConnectInput(f"{n}.mode", port)
        if unit.teleop_frame == "tip":
            builder.ExportInput(teleop.GetInputPort("p_WT"), f"{n}.p_WT")
            builder.ExportInput(teleop.GetInputPort("tip_direction_W"), f"{n}.tip_direction_W")
        for port in ("q_WM", "X_WM", "m_W"):
            builder.ExportOutput(magnet.GetOutputPort(port), f"{n}.{port}")
        builder.ExportOutput(drive.GetOutputPort("omega_wheels"), f"{n}.omega_wheels")
        builder.ExportOutput(sensor.GetOutputPort("B_sensor_T"), f"{n}.B_sensor_T")
        builder.ExportOutput(estimator.GetOutputPort("m_hat_W"), f"{n}.m_hat_W")
        builder.ExportOutput(controller.GetOutputPort("done"), f"{n}.done")
        builder.ExportOutput(controller.GetOutputPort("angle_error"), f"{n}.angle_error")
    if opt.field_points_W is not None:
        k = len(np.asarray(opt.field_points_W).reshape(-1, 3))
        if len(units) == 1:
            builder.ExportOutput(magnets[names[0]].magnet.GetOutputPort("B_points_W"), "B_points_W")
        else:
            adder = builder.AddSystem(Adder(len(units), 3 * k))
            adder.set_name("total_field")
            for i, n in enumerate(names):
                builder.Connect(magnets[n].magnet.GetOutputPort("B_points_W"), adder.get_input_port(i))
            builder.ExportOutput(adder.get_output_port(), "B_points_W")
    if opt.with_feeder:
        feeder = builder.AddSystem(Feeder(opt.chain, FeederSpec()))
        builder.ExportInput(feeder.GetInputPort("v_insert_cmd"), "feeder.v_insert_cmd")
        builder.ExportOutput(feeder.GetOutputPort("inserted_length"), "feeder.inserted_length")
        builder.ExportOutput(feeder.GetOutputPort("balls_out"), "feeder.balls_out")
    diagram = builder.Build()
    diagram.set_name("actuation_station")
    return diagram


def unit_system(diagram: Diagram, name: str, role: str):
    """The system of unit ``name`` in ``role`` ("magnet", "drive", "hall_sensor", "estimator",
    "controller" or "mode_switch"): the unit's ``ActuationUnit`` (named ``<name>.unit``, every
    role) or the composed system ``<name>.<role>``."""
    require_choice(role, ("magnet", "drive", "hall_sensor", "estimator", "controller", "mode_switch"), "unit_system role")
    if diagram.HasSubsystemNamed(f"{name}.unit"):
        return diagram.GetSubsystemByName(f"{name}.unit")
    return diagram.GetSubsystemByName(f"{name}.{role}")
