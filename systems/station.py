"""The station builder: ``MakeStation(scenario) -> Station``, one diagram for every station.

In the style of Drake's ``MakeHardwareStation`` (``RussTedrake/manipulation``, ``station.py``)
and ``examples/hardware_sim``: a typed scenario (``chain_scenario.ChainScenario``, Drake's own
config structs inside it) goes in, a diagram with named systems and exported ports and a typed
handle dataclass (``Station``) come out. The body of ``MakeStation`` is a short sequence of
steps, one concern each (docs/design.md, "The station builder"); each step takes what it needs
and returns what it adds:

1. ``apply_atrium``: the procedural left atrium, a user's segmented one, or free space.
2. ``add_field_sources``: the fixed external field (uniform field, fixed magnets, or a prebuilt
   FieldSource) and the units' MagnetUnitConfigs at their anchors (``FieldSetup``).
3. ``add_device``: the device model (``device_model.DeviceModel``) of the scenario's
   ``(device, engine)`` (``device_model.device_model_class``, the one registry), which adds
   itself with its field coupling inside: for the ball chain (``chain_model.ChainModel``) its
   ChainPlantConfig (``chain_plant.chain_plant_config``) and the MultibodyPlant with
   ``magnetic_wrench`` (``plant``) or the ``quasi_static_engine`` (``statics``); for the
   steerable catheter (``catheter_model.CatheterModel``) the catheter and the hand on its
   handle. This is the one place the device and the engine are chosen: every later step, the
   run loop and the experiments see the interface only (its ports: the actuation inputs,
   ``body_poses``, ``tip_wall_force``, ``anatomy_offsets``).
4. ``add_units_step``: the rotating actuation units (``station_units.add_units``, wired by
   ``actuation_station.add_unit_systems``, the same step as the actuation-only diagram) into
   the device's ``magnet_states`` input; ``tip_observer`` for the tip-frame mapping.
5. ``add_insertion``: what drives the device's slide (its ``feeder_state`` input, when it has
   one): the scenario's ramp (``feeder_command``), the stepper ``feeder`` (playing the ramp
   itself, or commanded from outside), or an exported ``inserted_length`` input
   (``feeder_interface``).
6. ``add_target_touches``: ``target_touches`` (TargetTouchTracker), when the atrium has rings.
7. ``add_pin``: ``force_sensor_pin`` (``scenario.pin``) on the tip ball, exported output
   ``pin_reading`` (3) [N].
8. ``add_external_commands``: the ``add_systems`` hook (e.g. a simulated operator) and the
   export of the external command inputs it leaves unconnected: ``<u>.joystick`` (3),
   ``feeder.v_insert_cmd`` (1) (the units' and the feeder's, or the device's own: the
   catheter's ``hand.joystick`` and its hand's push).
9. ``add_visualization``: with a Meshcat, the device's view (``DeviceModel.add_visualizer``:
   the chain's ``meshcat_visualizer`` on its SceneGraph, the camera framed on the atrium), the
   fixed magnets, ``unit_markers``, and ``meshcat_overlays`` (targets, field at the tip, the
   device's ``tip_wall_force``) for a device that wants them.

Exported ports (by name, the same for every device): inputs ``inserted_length`` (1, with
``insertion.external``), ``<u>.joystick`` (3), ``feeder.v_insert_cmd`` (1) (external commands
nobody drives); output ``pin_reading`` (3, with a pin). ``chain_simulation.run_station`` is the
one run loop (``scenario.simulator_config``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, InputPort, OutputPort
from pydrake.systems.primitives import MatrixGain, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from ballchain.drake_models.atrium import Atrium
from ballchain.infrastructure.arg_checks import require_type
from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.drake_models.field_sources import FieldSource, MagnetSource, require_field_source
from ballchain.drake_models.params import CylinderMagnet
from ballchain.systems.chain_model import ChainModel, FieldCoupling, subsystem_context
from ballchain.systems.chain_plant import chain_for, chain_plant_config  # noqa: F401 (re-exported)
from ballchain.systems.chain_scenario import ChainScenario
from ballchain.systems.device_model import DeviceModel, device_model_class, engines
from ballchain.systems.feeder import Feeder
from ballchain.systems.meshcat_overlays import MeshcatOverlays
from ballchain.systems.rotating_magnet_unit import MagnetUnitConfig
from ballchain.systems.station_models import apply_anatomy, atrium_for, field_source_for  # noqa: F401 (re-exported)
from ballchain.systems.station_units import (
    TipObserver,
    UnitHandles,
    UnitMeshcatMarkers,
    add_feeder,
    add_units,
    unit_configs,
)
from ballchain.systems.target_contact import TargetTouchTracker, heart_targets

if TYPE_CHECKING:
    from pydrake.geometry import MeshcatVisualizer

    from ballchain.systems.force_sensor_pin import ForceSensorPin

# The ball chain's model of each ``engine`` (a view of the registry, ``device_model.DEVICE_MODELS``).
CHAIN_MODELS: dict[str, type[ChainModel]] = {engine: device_model_class("ball_chain", engine)
                                             for engine in engines("ball_chain")}

# The chain's configuration from a scenario (its home: ``chain_plant.chain_plant_config``).
apply_chain_plant_config = chain_plant_config

# The prebuilt field source's placeholder: "build it from the scenario".
FROM_SCENARIO = object()


@dataclass
class Station:
    """The built station diagram and handles to its parts (``MakeStation``).

    Attributes:
        diagram: the built diagram (the device model's ``diagram_name``: "chain_in_heart", ...).
        chain: the device model (``device_model.DeviceModel``; for the ball chain the plant or
            the quasi-static engine, ``chain_model.ChainModel``); also ``device``.
        heart: the atrium, or None in free space.
        scenario: the scenario it was built from.
        field_source: the fixed external field, or None.
        visualizer: the MeshcatVisualizer, with a Meshcat.
        build_time_s: wall time of the build [s].
        units: {unit name: UnitHandles} (``station_units``; none for a device not magnetic).
        feeder: the Feeder, with ``insertion.feeder`` (on a device with a slide).
        tip_observer: the TipObserver, for the catheter-frame mapping.
        target_touches: the TargetTouchTracker, when the atrium has target rings.
        meshcat_overlays: the MeshcatOverlays, with a Meshcat.
        added: what the ``add_systems`` hook returned, by name.
        pin: the ForceSensorPin, with ``scenario.pin``.

    Readings of a context (the diagram's root context, e.g. ``RunOutcome.context``, or the
    context of the system read): ``ball_positions``, ``tip_position`` (the chain system's),
    ``tip_wall_force``, ``unit_magnet``, ``targets_touched``.
    """

    diagram: Diagram
    chain: DeviceModel
    heart: Atrium | None
    scenario: ChainScenario
    field_source: FieldSource | None
    visualizer: MeshcatVisualizer | None = None
    build_time_s: float = 0.0
    units: dict[str, UnitHandles] = field(default_factory=dict)
    feeder: Feeder | None = None
    tip_observer: TipObserver | None = None
    target_touches: TargetTouchTracker | None = None
    meshcat_overlays: MeshcatOverlays | None = None
    added: dict = field(default_factory=dict)
    pin: ForceSensorPin | None = None

    @property
    def device(self) -> DeviceModel:
        """The device model (``chain``)."""
        return self.chain

    # Readings of a context: each takes the diagram's root context (``RunOutcome.context``, a
    # Simulator's context) or the context of the system it reads (``chain_context`` for the chain).
    def chain_context(self, context):
        """The chain system's (``chain.system``'s) context, from the root context or itself."""
        return subsystem_context(self.chain.system, context)

    def ball_positions(self, context) -> np.ndarray:
        """The ball centres (n, 3) [m], ball 1 (the feeder ball) first, the tip ball last (the
        device's ``body_positions``: for the catheter its rod's nodes, the tip sphere last)."""
        return self.chain.body_positions(self.chain_context(context))

    def tip_position(self, context) -> np.ndarray:
        """The tip ball's (the tip body's) centre (3,) [m]."""
        return self.ball_positions(context)[-1]

    def tip_wall_force(self, context) -> np.ndarray:
        """The walls' contact force on the tip ball f_W (3,) [N] (zeros when nothing pushes)."""
        port = self.chain.get_tip_wall_force_output_port()
        return np.array(port.Eval(subsystem_context(port.get_system(), context))[:3])

    def unit_magnet(self, name: str, context) -> MagnetSource:
        """Unit ``name``'s magnet at its pose in the context (a MagnetSource: its field anywhere)."""
        if not isinstance(name, str) or name not in self.units:
            raise UserInputError(f"no unit {short_repr(name)} in this station; its units: "
                                 f"{', '.join(self.units) or 'none'}")
        magnet = self.units[name].magnet
        return magnet.magnet_source(subsystem_context(magnet, context))

    def targets_touched(self, context) -> list[str]:
        """The names of the ablation targets the tip ball touched so far ([] without target rings)."""
        tracker = self.target_touches
        return [] if tracker is None else tracker.touched_names(context)


@dataclass
class StationPorts:
    """What an ``add_systems`` hook of ``MakeStation`` may connect to (before ``Build``).

    Attributes:
        chain: the device model (its geometry: ``tip_body_index``, ``p_WE``, ...); also ``device``.
        body_poses: the device's ``body_poses`` output port.
        joystick_inputs: {unit name: its mapper's ``joystick`` input (3)} for the units with
            ``joystick_source: external``, and the device's own (the catheter's ``hand``).
        feeder_command_input: the feeder's ``v_insert_cmd`` input (1) [m/s] with
            ``insertion.feeder_command: external`` (or the device's own: the catheter hand's
            push), else None.
        heart: the atrium (or None).
        targets: ``heart_targets(heart)`` (names, p_WT, n_W, target radius), or None.
        target_touches: the TargetTouchTracker, or None.
        units: {unit name: UnitHandles}.
    """

    chain: DeviceModel
    body_poses: OutputPort
    joystick_inputs: dict[str, InputPort]
    feeder_command_input: InputPort | None
    heart: Atrium | None
    targets: tuple | None
    target_touches: TargetTouchTracker | None
    units: dict[str, UnitHandles]

    @property
    def device(self) -> DeviceModel:
        """The device model (``chain``)."""
        return self.chain


@dataclass
class FieldSetup:
    """What ``add_field_sources`` returns: the fixed field and the units' configurations."""

    source: FieldSource | None
    unit_configs: list[MagnetUnitConfig]

    @property
    def coupling(self) -> FieldCoupling:
        """What the chain feels: the fixed field and the units' magnets (on ``magnet_states``)."""
        model = self.unit_configs[0].model if self.unit_configs else "dipole"
        return FieldCoupling(self.source, [c.magnet for c in self.unit_configs], model)


@dataclass
class UnitsStep:
    """What ``add_units_step`` returns."""

    units: dict[str, UnitHandles]
    tip_observer: TipObserver | None
    magnet_states: OutputPort | None  # the units' ``magnet_states`` (6 per unit), None without units


@dataclass
class TargetTouches:
    """What ``add_target_touches`` returns: the targets (``heart_targets``) and their tracker."""

    targets: tuple
    tracker: TargetTouchTracker


@dataclass
class View:
    """What ``add_visualization`` returns."""

    visualizer: MeshcatVisualizer
    overlays: MeshcatOverlays | None


# ------------------------------------------------------------------------------------------------
# The steps of MakeStation, in order.


def apply_atrium(scenario: ChainScenario, heart: Atrium | None) -> Atrium | None:
    """Step 1, the atrium: the prebuilt ``heart`` when given, else the scenario's (procedural or
    the user's ``atrium_file``); None in free space (``heart: false``)."""
    if not scenario.heart:
        return None
    return heart if heart is not None else atrium_for(scenario)


def add_field_sources(scenario: ChainScenario, heart: Atrium | None, field_source=FROM_SCENARIO) -> FieldSetup:
    """Step 2, the fields: the fixed external field (the scenario's uniform field and magnets, or
    a prebuilt FieldSource such as a stand's magnets) and the units' MagnetUnitConfigs, placed
    at their anchors (the puncture, the LA centre, the carinas).

    Raises:
        UserInputError: a prebuilt field source together with scenario fields or magnets.
    """
    p_WP = heart.p_HP if heart is not None else np.zeros(3)
    if field_source is FROM_SCENARIO:
        source = field_source_for(scenario, p_WP)
    else:
        if np.any(np.asarray(scenario.uniform_field) != 0.0) or scenario.magnets:
            raise UserInputError("MakeStation: give the field either as the scenario's uniform_field/magnets or "
                                 "as field_source, not both")
        source = field_source
    anchors = {"puncture": p_WP, "centre": np.zeros(3)}
    if heart is not None:  # a user's atrium has no carinas
        anchors.update({f"carina_{k}": v for k, v in heart.carinas.items()})
    return FieldSetup(source, unit_configs(scenario, anchors))


def add_device(builder: DiagramBuilder, scenario: ChainScenario, heart: Atrium | None, fields: FieldSetup,
               params=None) -> DeviceModel:
    """Step 3, the device model of the scenario's ``(device, engine)`` (the registry's) with its
    field coupling, and its own ``params`` (the model's ``params_type``, or None: its defaults).

    Raises:
        UserInputError: a pair the registry does not hold, params of another type, or what the
            model refuses (e.g. an insertion outside the chain's sheath).
    """
    model = device_model_class(scenario.device, scenario.engine)
    if params is not None:
        if model.params_type is None:
            raise UserInputError(f"MakeStation device_params: device {scenario.device!r} takes none, "
                                 f"got {short_repr(params)}")
        require_type(params, model.params_type, "MakeStation device_params",
                     f"a {model.params_type.__name__} (device {scenario.device!r}) or None")
    return model.add_to_station(builder, scenario, heart, fields.coupling, params)


def add_units_step(builder: DiagramBuilder, scenario: ChainScenario, heart: Atrium | None, chain: DeviceModel,
                   configs: list[MagnetUnitConfig]) -> UnitsStep:
    """Step 4, the rotating actuation units into the device's ``magnet_states`` input
    (``station_units.add_units``), with ``tip_observer`` when a unit uses the tip-frame mapping.

    The neutral field is defined where the free device starts (``DeviceModel.start_point``: for
    the chain the sheath exit in the heart, ball 1's initial centre in free space).

    Raises:
        UserInputError: units for a device without a ``magnet_states`` input.
    """
    if not configs:
        return UnitsStep({}, None, None)
    if chain.get_magnet_states_input_port() is None:
        raise UserInputError(f"scenario units: device {chain.device!r} is not magnetic: it takes no units (units: [])")
    tip_observer = None
    if any(u.teleop_frame == "tip" for u in scenario.units):
        tip_observer = builder.AddSystem(TipObserver(chain.tip_body_index, chain.tip_base_body_index))
        builder.Connect(chain.get_body_poses_output_port(), tip_observer.get_body_poses_input_port())
    units, magnet_states = add_units(builder, scenario, configs, chain.get_magnet_states_input_port(),
                                     chain.start_point, chain.sheath_axis_W, tip_observer)
    return UnitsStep(units, tip_observer, magnet_states)


def add_insertion(builder: DiagramBuilder, scenario: ChainScenario, chain: DeviceModel) -> Feeder | None:
    """Step 5, what drives the device's slide (its feeder desired state (s, s'): the chain's ball 1;
    nothing for a device without one).

    ``insertion.feeder``: the stepper ``feeder`` (``station_units.add_feeder``, returned);
    ``insertion.external``: ``feeder_interface`` and the exported input ``inserted_length`` (1)
    [m]; else ``feeder_command``, the scenario's ramp (a first-order hold and its derivative).

    Raises:
        UserInputError: both external and feeder.
    """
    ins, desired = scenario.insertion, chain.get_feeder_state_input_port()
    if ins.external and ins.feeder:
        raise UserInputError("insertion: choose external (exported port) or feeder (the Feeder system), not both")
    if desired is None:
        return None
    if ins.feeder:
        return add_feeder(builder, chain.fed_chain(), ins, desired, reader_period=chain.move_period)
    if ins.external:
        # A feeder's inserted length s (systems/feeder.py's ``inserted_length`` uses the same
        # definition) becomes the slide's desired state (s, 0): the implicit PD tracks it.
        to_state = builder.AddSystem(MatrixGain(np.array([[1.0], [0.0]])))
        to_state.set_name("feeder_interface")
        builder.Connect(to_state.get_output_port(), desired)
        builder.ExportInput(to_state.get_input_port(), "inserted_length")
        return None
    t1 = max(ins.start_time, 0.0)
    ramp = abs(ins.final - ins.initial) / ins.speed if ins.speed > 0 else 0.0
    if ramp > 0:
        times = [0.0, t1 + 1e-9, t1 + ramp, t1 + ramp + 1.0]
        values = [ins.initial, ins.initial, ins.final, ins.final]
    else:
        times, values = [0.0, 1.0], [ins.initial, ins.initial]
    traj = PiecewisePolynomial.FirstOrderHold(times, np.array(values)[None, :])
    command = builder.AddSystem(TrajectorySource(traj, output_derivative_order=1))
    command.set_name("feeder_command")
    builder.Connect(command.get_output_port(), desired)
    return None


def add_target_touches(builder: DiagramBuilder, scenario: ChainScenario, heart: Atrium | None,
                       chain: DeviceModel) -> TargetTouches | None:
    """Step 6, ``target_touches``: which ablation targets the tip (the device's electrode) has
    touched (with or without Meshcat: the run's metrics read it), when the atrium has target
    rings; on a moving anatomy the device's ``anatomy_offsets`` place them."""
    targets = heart_targets(heart) if heart is not None else None
    if targets is None or not targets[0]:
        return None
    names, p_WT, n_W, target_radius = targets
    # A device that moves only at its updates (an engine's) shows nothing new in between.
    period = max(scenario.check_period, chain.move_period)
    offsets = chain.get_anatomy_offsets_output_port()  # engine: statics with wall_motion
    electrode = chain.electrode
    length = getattr(electrode, "length", 0.0)  # the catheter's: its whole surface
    # The tip ball's centre alone from the centres, not every ball's frame (issue 48).
    positions = getattr(chain, "get_ball_positions_output_port", None)
    n = len(chain.body_indices)
    by_centre = (positions is not None and length <= electrode.radius and electrode.body_index == chain.body_indices[-1]
                 and positions().size() == 3 * n)
    tracker = builder.AddSystem(TargetTouchTracker(
        electrode.body_index, names, p_WT, n_W, target_radius,
        ball_radius=electrode.radius, period=period, moving_wall=offsets is not None,
        electrode_length=length, n_positions=n if by_centre else None))
    if by_centre:
        builder.Connect(positions(), tracker.get_ball_positions_input_port())
    else:
        builder.Connect(chain.get_body_poses_output_port(), tracker.get_body_poses_input_port())
    if offsets is not None:  # the anatomy the device's solves placed
        builder.Connect(offsets, tracker.get_anatomy_offsets_input_port())
    return TargetTouches(targets, tracker)


def add_pin(builder: DiagramBuilder, scenario: ChainScenario, chain: DeviceModel) -> ForceSensorPin | None:
    """Step 7, ``force_sensor_pin`` (``scenario.pin``, when its point is set): a stiff explicit
    spring from the pin point to the tip ball's centre (``ChainModel.add_pin``); its reading
    (the force the tip presses on the pin) exported as ``pin_reading`` (3) [N]."""
    if not scenario.pin.point:
        return None
    pin = chain.add_pin(builder, np.asarray(scenario.pin.point, float), scenario.pin.stiffness)
    builder.ExportOutput(pin.get_reading_output_port(), "pin_reading")
    return pin


def add_external_commands(builder: DiagramBuilder, ports: StationPorts, add_systems=None) -> dict:
    """Step 8, the external commands (a unit's ``joystick_source: external``,
    ``insertion.feeder_command: external``, in ``ports``): the ``add_systems`` hook adds what
    drives them (e.g. a simulated operator) and its dict is returned; whatever it leaves
    unconnected is exported as a diagram input (``<u>.joystick`` (3), ``feeder.v_insert_cmd`` (1))."""
    added = dict(add_systems(builder, ports) or {}) if add_systems is not None else {}
    for name, port in ports.joystick_inputs.items():
        if not builder.IsConnectedOrExported(port):
            builder.ExportInput(port, f"{name}.joystick")
    feeder_input = ports.feeder_command_input
    if feeder_input is not None and not builder.IsConnectedOrExported(feeder_input):
        builder.ExportInput(feeder_input, "feeder.v_insert_cmd")
    return added


def station_ports(scenario: ChainScenario, heart: Atrium | None, chain: DeviceModel, units: UnitsStep,
                  feeder: Feeder | None, touches: TargetTouches | None) -> StationPorts:
    """What the ``add_systems`` hook may connect to: the external command inputs (a unit's
    ``joystick_source: external``, ``insertion.feeder_command: external``, the device's own:
    ``DeviceModel.operator_inputs``) and the device."""
    own = chain.operator_inputs()
    joystick_inputs = {u.name: units.units[u.name].joystick_input for u in scenario.units
                       if u.joystick_source == "external"}
    joystick_inputs.update(own.joystick_inputs)
    feeder_input = own.feeder_command_input
    if feeder is not None and scenario.insertion.feeder and scenario.insertion.feeder_command == "external":
        feeder_input = feeder.GetInputPort("v_insert_cmd")
    return StationPorts(chain, chain.get_body_poses_output_port(), joystick_inputs, feeder_input, heart,
                        touches.targets if touches is not None else None,
                        touches.tracker if touches is not None else None, units.units)


def _draw_magnets(meshcat, source) -> None:
    """Draw the fixed magnets in Meshcat (illustration only)."""
    from pydrake.geometry import Cylinder, Rgba, Sphere
    from pydrake.math import RigidTransform, RotationMatrix

    sources = getattr(source, "sources", [source]) if source is not None else []
    for k, s in enumerate(sources):
        if not isinstance(s, MagnetSource):
            continue
        path = f"magnets/magnet_{k + 1}"
        if isinstance(s.magnet, CylinderMagnet):
            meshcat.SetObject(path, Cylinder(s.magnet.diameter / 2, s.magnet.length), Rgba(0.6, 0.6, 0.65, 0.8))
        else:
            meshcat.SetObject(path, Sphere(s.magnet.diameter / 2), Rgba(0.6, 0.6, 0.65, 0.8))
        meshcat.SetTransform(path, RigidTransform(RotationMatrix(s.R_WM), s.p_WM))


def add_visualization(builder: DiagramBuilder, scenario: ChainScenario, meshcat, chain: DeviceModel,
                      heart: Atrium | None, fields: FieldSetup, units: UnitsStep,
                      touches: TargetTouches | None) -> View | None:
    """Step 9, the Meshcat view (with a Meshcat): the device's (``DeviceModel.add_visualizer``:
    the chain's ``meshcat_visualizer`` from ``scenario.visualization`` on its SceneGraph, the
    camera framed on the atrium), the fixed magnets, ``unit_markers``, and, for a device with
    ``station_overlays``, ``meshcat_overlays`` (targets, the field at the tip, the device's
    ``tip_wall_force``)."""
    if meshcat is None:
        return None
    configs = fields.unit_configs
    period = scenario.visualization.publish_period
    visualizer = chain.add_visualizer(builder, meshcat, scenario, heart,
                                      touches.targets if touches is not None else None)
    _draw_magnets(meshcat, fields.source)
    if not chain.station_overlays:
        return View(visualizer, None)
    if configs:
        markers = builder.AddSystem(UnitMeshcatMarkers(meshcat, configs, period))
        for c in configs:
            builder.Connect(units.units[c.name].magnet.GetOutputPort("X_WM"), markers.GetInputPort(f"X_WM_{c.name}"))
    coupling = fields.coupling
    overlays = builder.AddSystem(MeshcatOverlays(
        meshcat, chain.tip_body_index, period, targets=touches.targets if touches is not None else None,
        field_source=coupling.field_source, port_magnets=coupling.port_magnets, model=coupling.model,
        moving_wall=touches is not None and touches.tracker.get_anatomy_offsets_input_port() is not None))
    builder.Connect(chain.get_tip_wall_force_output_port(), overlays.get_tip_wall_force_input_port())
    if overlays.get_anatomy_offsets_input_port() is not None:  # the statics engine's (check_wall_motion)
        builder.Connect(chain.get_anatomy_offsets_output_port(), overlays.get_anatomy_offsets_input_port())
    builder.Connect(chain.get_body_poses_output_port(), overlays.get_body_poses_input_port())
    if touches is not None:
        builder.Connect(touches.tracker.get_touched_output_port(), overlays.get_touched_input_port())
    if units.magnet_states is not None:
        builder.Connect(units.magnet_states, overlays.get_magnet_states_input_port())
    return View(visualizer, overlays)


def MakeStation(scenario: ChainScenario, meshcat=None, *, heart: Atrium | None = None, add_systems=None,
                field_source=FROM_SCENARIO, device_params=None) -> Station:
    """Build the station diagram of a scenario (see the module docstring for the steps and ports).

    Args:
        scenario: the scenario (validated here).
        meshcat: a pydrake Meshcat to visualise in, or None.
        heart: a prebuilt atrium (``drake_models.atrium.Atrium``) to reuse (else built from the
            scenario when it has one).
        add_systems: None, or ``add_systems(builder, ports: StationPorts) -> dict`` called before
            the diagram is built, to add systems that drive the external commands (a simulated
            operator); the dict it returns is the Station's ``added``. External inputs it leaves
            unconnected are exported.
        field_source: a prebuilt external FieldSource (or None: no fixed field) instead of the
            scenario's ``uniform_field`` and ``magnets`` (which must then be empty), for fields a
            scenario cannot express (e.g. the force stand's magnets, ``experiments.forces``).
        device_params: the device's own parameters (its model's ``params_type``, e.g.
            ``catheter_station.CatheterParams``), or None: its defaults.

    Returns:
        a Station, for every device.

    Raises:
        UserInputError: a bad scenario (naming the field).

    Example:
        A named scenario's station, built and run for 50 ms::

            >>> import ballchain as bc
            >>> station = bc.MakeStation(bc.load_scenario("free_space_uniform_90deg", "{n_balls: 6}"))
            >>> type(station).__name__, station.chain.n_balls, station.heart is None
            ('Station', 6, True)
            >>> outcome = bc.run_station(station, duration=0.05)  # simulated seconds
            >>> outcome.failure, [round(1e3 * float(v), 1) for v in outcome.tip_position[:2]]  # [mm]
            (None, [14.9, 3.9])
    """
    require_type(scenario, ChainScenario, "MakeStation scenario", "a ChainScenario (from load_scenario)")
    if heart is not None:
        require_type(heart, Atrium, "MakeStation heart", "an atrium (LeftAtrium, UserAtrium) or None")
    if add_systems is not None and not callable(add_systems):
        raise UserInputError(f"MakeStation add_systems must be a function or None, got {short_repr(add_systems)}")
    if field_source is not FROM_SCENARIO:
        require_field_source(field_source, "MakeStation field_source", allow_none=True)
    if meshcat is not None:
        from pydrake.geometry import Meshcat

        require_type(meshcat, Meshcat, "MakeStation meshcat", "a pydrake Meshcat or None")
    t0 = time.perf_counter()
    scenario.validate()
    heart = apply_atrium(scenario, heart)
    if heart is not None:
        heart.wall_distance  # the watchdog's wall distance (a k-d tree), built now: not in the timed run
    fields = add_field_sources(scenario, heart, field_source)
    builder = DiagramBuilder()
    chain = add_device(builder, scenario, heart, fields, device_params)
    units = add_units_step(builder, scenario, heart, chain, fields.unit_configs)
    feeder = add_insertion(builder, scenario, chain)
    touches = add_target_touches(builder, scenario, heart, chain)
    pin = add_pin(builder, scenario, chain)
    added = add_external_commands(builder, station_ports(scenario, heart, chain, units, feeder, touches), add_systems)
    view = add_visualization(builder, scenario, meshcat, chain, heart, fields, units, touches)
    diagram = builder.Build()
    diagram.set_name(chain.diagram_name)
    return Station(diagram, chain, heart, scenario, fields.source, view.visualizer if view is not None else None,
                   time.perf_counter() - t0, units=units.units, feeder=feeder, tip_observer=units.tip_observer,
                   target_touches=touches.tracker if touches is not None else None,
                   meshcat_overlays=view.overlays if view is not None else None, added=added, pin=pin)
