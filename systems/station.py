"""The station builder: ``MakeStation(scenario) -> Station``, one diagram for every station.

In the style of Drake's ``MakeHardwareStation`` (``RussTedrake/manipulation``, ``station.py``)
and ``examples/hardware_sim``: a typed scenario (``chain_scenario.ChainScenario``, Drake's own
config structs inside it) goes in, a diagram with named systems and exported ports and a typed
handle dataclass (``Station``) come out. The body of ``MakeStation`` is a short sequence of
steps, one concern each (docs/design.md, "The station builder"):

1. ``apply_atrium``: the procedural left atrium, a user's segmented one, or free space.
2. ``apply_chain_plant_config``: the chain plant's ChainPlantConfig from the scenario (the time
   step's one home is ``scenario.time_step``; Drake's ``MultibodyPlantConfig`` is
   ``scenario.plant_config``).
3. ``add_chain``: the chain's MultibodyPlant (``plant``, ``scene_graph``), or, with
   ``engine: statics``, the geometry handles of the quasi-static engine (no plant).
4. ``add_field_sources``: the fixed external field (uniform field, fixed magnets, or a prebuilt
   FieldSource) and the units' MagnetUnitConfigs at their anchors.
5. ``add_field_coupling``: ``magnetic_wrench`` (MagneticWrenchSystem: body poses in, spatial
   forces out to the plant), or the ``quasi_static_engine`` (which solves the equilibrium in
   the same field).
6. ``add_units_step``: the rotating actuation units (``station_units.add_units``, wired by
   ``actuation_station.add_unit_systems``, the same step as the actuation-only diagram) into
   the field coupling's ``magnet_states`` input; ``tip_observer`` for the tip-frame mapping.
7. ``add_insertion``: what drives ball 1's slide: the scenario's ramp (``feeder_command``),
   the stepper ``feeder``, or an exported ``inserted_length`` input (``feeder_interface``).
8. ``add_target_touches``: ``target_touches`` (TargetTouchTracker), when the atrium has rings.
9. ``add_pin``: ``force_sensor_pin`` (``scenario.pin``) on the tip ball, exported output
   ``pin_reading`` (3) [N].
10. ``add_external_commands``: the ``add_systems`` hook (e.g. a simulated operator) and the
    export of the external command inputs it leaves unconnected: ``<u>.joystick`` (3),
    ``feeder.v_insert_cmd`` (1).
11. ``add_visualization``: with a Meshcat, ``meshcat_visualizer`` (``scenario.visualization``),
    ``meshcat_overlays`` (targets, field at the tip, the wall's force on the tip),
    ``unit_markers``; the camera framed on the atrium (``meshcat_view.frame_scene``).

Exported ports (by name): inputs ``inserted_length`` (1, with ``insertion.external``),
``<u>.joystick`` (3), ``feeder.v_insert_cmd`` (1) (external commands nobody drives); output
``pin_reading`` (3, with a pin). ``chain_simulation.run_station`` is the one run loop
(``scenario.simulator_config``); ``chain_simulation.build_chain_diagram`` and ``ChainDiagram``
are this module's ``MakeStation`` and ``Station`` under the names the rest of the code uses.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import MatrixGain, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from ballchain.drake_models.atrium import Atrium
from ballchain.drake_models.arg_checks import require_type
from ballchain.drake_models.errors import UserInputError, short_repr
from ballchain.drake_models.field_sources import FieldSources, MagnetSource, UniformField, require_field_source
from ballchain.drake_models.heart import HeartParams, LeftAtrium
from ballchain.drake_models.params import BallChain, CylinderMagnet, Sleeve, SphereMagnet
from ballchain.systems.chain_plant import ChainPlant, ChainPlantConfig, SheathConfig, add_chain_plant
from ballchain.systems.chain_scenario import ChainScenario
from ballchain.systems.magnetic_wrench import MagneticWrenchSystem
from ballchain.systems.meshcat_overlays import MeshcatOverlays
from ballchain.systems.meshcat_view import frame_scene
from ballchain.systems.station_units import TipObserver, UnitMeshcatMarkers, add_feeder, add_units, unit_configs
from ballchain.systems.target_contact import TargetTouchTracker, heart_targets

# The prebuilt field source's placeholder: "build it from the scenario".
FROM_SCENARIO = object()


@dataclass
class Station:
    """The built station diagram and handles to its parts (``MakeStation``).

    With ``engine: statics`` there is no MultibodyPlant: ``chain_plant`` holds the geometry
    handles only (``plant`` is None; the ball BodyIndex values are the plant's), ``wrench`` is
    None and ``engine`` is the QuasiStaticEngine.
    """

    diagram: object
    chain_plant: ChainPlant
    wrench: MagneticWrenchSystem | None
    heart: Atrium | None
    scenario: ChainScenario
    field_source: object
    visualizer: object = None
    build_time_s: float = 0.0
    engine: object = None
    units: dict = field(default_factory=dict)  # unit name -> UnitHandles (station_units)
    feeder: object = None  # the Feeder, with ``insertion.feeder``
    tip_observer: object = None  # TipObserver, for the catheter-frame mapping
    target_touches: object = None  # TargetTouchTracker, when the atrium has target rings
    meshcat_overlays: object = None  # MeshcatOverlays / EngineOverlays, with a Meshcat
    added: dict = field(default_factory=dict)  # what the ``add_systems`` hook returned, by name
    pin: object = None  # the ForceSensorPin, with ``scenario.pin``

    @property
    def chain_system(self):
        """The system whose state is the chain: the plant, or the quasi-static engine."""
        return self.engine if self.engine is not None else self.chain_plant.plant

    @property
    def body_poses_port(self):
        """The ``body_poses`` output (list[RigidTransform] by BodyIndex) of the chain system."""
        return self.chain_system.get_body_poses_output_port()

    def ball_positions(self, context) -> np.ndarray:
        """Ball centres (n, 3) [m] from the chain system's context."""
        if self.engine is not None:
            return self.engine.ball_positions(context)
        return self.chain_plant.ball_positions(context)


@dataclass
class StationPorts:
    """What an ``add_systems`` hook of ``MakeStation`` may connect to (before ``Build``).

    Attributes:
        chain_plant: the chain's plant handles.
        body_poses: the plant's ``body_poses`` output port.
        joystick_inputs: {unit name: its mapper's ``joystick`` input (3)} for the units with
            ``joystick_source: external``.
        feeder_command_input: the feeder's ``v_insert_cmd`` input (1) [m/s] with
            ``insertion.feeder_command: external``, else None.
        heart: the atrium (or None).
        targets: ``heart_targets(heart)`` (names, p_WT, n_W, target radius), or None.
        target_touches: the TargetTouchTracker, or None.
        units: {unit name: UnitHandles}.
    """

    chain_plant: ChainPlant
    body_poses: object
    joystick_inputs: dict
    feeder_command_input: object
    heart: object
    targets: tuple | None
    target_touches: object
    units: dict


@dataclass
class _Parts:
    """What the steps of ``MakeStation`` have made so far (the builder's working record)."""

    scenario: ChainScenario
    heart: Atrium | None = None
    config: ChainPlantConfig | None = None
    cp: ChainPlant | None = None
    source: object = None
    unit_configs: list = field(default_factory=list)
    engine: object = None
    wrench: MagneticWrenchSystem | None = None
    body_poses: object = None  # the chain system's body_poses output
    magnet_input: object = None  # the field coupling's magnet_states input
    desired: object = None  # the slide's desired-state input
    units: dict = field(default_factory=dict)
    tip_observer: object = None
    feeder: object = None
    targets: tuple | None = None
    tracker: object = None
    pin: object = None
    added: dict = field(default_factory=dict)
    visualizer: object = None
    overlays: object = None

    @property
    def statics(self) -> bool:
        return self.scenario.engine == "statics"

    @property
    def field_model(self) -> str:
        return self.unit_configs[0].model if self.unit_configs else "dipole"


# ------------------------------------------------------------------------------------------------
# Scenario -> models (no diagram yet).


def atrium_for(scenario: ChainScenario) -> Atrium:
    """The scenario's atrium: the user's surface when ``atrium_file`` is set, else procedural."""
    if not scenario.atrium_file:
        return LeftAtrium(HeartParams(scale=scenario.heart_scale, subdivisions=scenario.heart_subdivisions))
    from ballchain.drake_models.atrium_mesh import UserAtrium, load_atrium_surface
    from ballchain.drake_models.model_files import resolve_uri

    path = scenario.atrium_file
    path = resolve_uri(path) if path.startswith("package://") else Path(path)
    try:
        surface = load_atrium_surface(path, scenario.atrium_units)
    except UserInputError as err:  # name the scenario field the user typed
        raise UserInputError(f"scenario atrium_file: {err}") from None
    return UserAtrium(surface, scenario.puncture, scenario.sheath_aim or None)


def chain_for(scenario: ChainScenario) -> BallChain:
    """The scenario's ball chain (``n_balls``, with the sleeve's bending forces or not)."""
    return BallChain(n_balls=scenario.n_balls, sleeve=Sleeve() if scenario.sleeve else None)


def field_source_for(scenario: ChainScenario, p_WP: np.ndarray):
    """The scenario's fixed external field (a FieldSource or None); p_WP is the puncture [m]."""
    sources = []
    if np.any(np.asarray(scenario.uniform_field) != 0.0):
        sources.append(UniformField(np.asarray(scenario.uniform_field, float)))
    for m in scenario.magnets:
        magnet = CylinderMagnet() if m.shape == "cylinder" else SphereMagnet()
        if m.p_WM:
            p_WM = np.asarray(m.p_WM, float)
        else:
            u = np.asarray(m.direction_W, float)
            p_WM = p_WP + m.distance_from_puncture * u / np.linalg.norm(u)
        sources.append(MagnetSource.pointing(magnet, p_WM, m.m_hat_W, m.model))
    if not sources:
        return None
    return sources[0] if len(sources) == 1 else FieldSources(sources)


class _EngineBody:
    """A ball of the statics engine where code expects a plant body: its BodyIndex only."""

    def __init__(self, index: int):
        from pydrake.multibody.tree import BodyIndex

        self._index = BodyIndex(index)

    def index(self):
        return self._index


def _engine_chain_handles(config: ChainPlantConfig) -> ChainPlant:
    """ChainPlant handles without a plant (the statics engine's geometry: the same sheath exit,
    axis, feeder frame and ball BodyIndex values 1..n as ``add_chain_plant`` makes)."""
    from pydrake.math import RigidTransform, RotationMatrix

    from ballchain.drake_models.field_sources import rotation_with_z_along

    heart = config.heart
    if heart is not None:
        p_WE, axis = heart.p_HE.copy(), heart.sheath_axis_H.copy()
    else:
        p_WE = np.asarray(config.p_WE, float)
        axis = np.asarray(config.sheath_axis_W, float) / np.linalg.norm(config.sheath_axis_W)
    n, d = config.chain.n_balls, config.chain.ball_diameter
    R_WF = RotationMatrix(rotation_with_z_along(axis)[:, [2, 0, 1]])
    X_WF = RigidTransform(R_WF, p_WE - (n - 0.5) * d * axis)
    return ChainPlant(None, None, config, [_EngineBody(i + 1) for i in range(n)], None, None, p_WE, axis, X_WF)


# ------------------------------------------------------------------------------------------------
# The steps of MakeStation, in order.


def apply_atrium(scenario: ChainScenario, heart: Atrium | None) -> Atrium | None:
    """Step 1, the atrium: the prebuilt ``heart`` when given, else the scenario's (procedural or
    the user's ``atrium_file``); None in free space (``heart: false``)."""
    if not scenario.heart:
        return None
    return heart if heart is not None else atrium_for(scenario)


def apply_chain_plant_config(scenario: ChainScenario, heart: Atrium | None) -> ChainPlantConfig:
    """Step 2, the chain plant's configuration from the scenario.

    The plant's step is ``scenario.effective_time_step`` (the time step's one home);
    ``scenario.plant_config`` is Drake's MultibodyPlantConfig. Free space: the sheath exit is
    placed so that ball 1 sits at the origin at s = 0 and the chain extends along +x (the
    canonical statics frame).
    """
    chain = chain_for(scenario)
    quasi = scenario.mode == "quasi-static"
    d = chain.ball_diameter
    return ChainPlantConfig(
        chain=chain,
        time_step=scenario.effective_time_step,
        translational_damping=scenario.translational_damping if quasi else 0.0,
        angular_damping=scenario.angular_damping if quasi else 0.0,
        gravity=scenario.gravity,
        heart=heart,
        sheath=SheathConfig() if scenario.sheath else None,
        p_WE=((chain.n_balls - 0.5) * d, 0.0, 0.0),
        sheath_axis_W=(1.0, 0.0, 0.0),
        initial_inserted_length=scenario.insertion.initial,
        contact=scenario.contact,
        feeder_gains=tuple(scenario.insertion.slide_gains),
        wall_plane=tuple(scenario.wall_plane),
        plant_config=scenario.plant_config,
    )


def add_chain(builder: DiagramBuilder, parts: _Parts) -> None:
    """Step 3, the chain: its MultibodyPlant (``plant``, ``scene_graph``), or with ``engine:
    statics`` the engine's geometry handles (the engine itself is added with the field, step 5).

    Raises:
        UserInputError: an insertion length outside what the sheath holds.
    """
    config = parts.config
    parts.cp = cp = _engine_chain_handles(config) if parts.statics else add_chain_plant(builder, config)
    s_max = cp.max_inserted_length()
    ins = parts.scenario.insertion
    for what, s in (("initial", ins.initial), ("final", ins.final)):
        if not 0.0 <= s <= s_max:
            raise UserInputError(
                f"insertion.{what} = {s * 1e3:.1f} mm is outside 0..{s_max * 1e3:.1f} mm for "
                f"{config.chain.n_balls} balls (ball 1 must stay in the sheath)")


def add_field_sources(parts: _Parts, field_source=FROM_SCENARIO) -> None:
    """Step 4, the fields: the fixed external field (the scenario's uniform field and magnets, or
    a prebuilt FieldSource such as a stand's magnets) and the units' MagnetUnitConfigs, placed
    at their anchors (the puncture, the LA centre, the carinas).

    Raises:
        UserInputError: a prebuilt field source together with scenario fields or magnets.
    """
    scenario, heart = parts.scenario, parts.heart
    p_WP = heart.p_HP if heart is not None else np.zeros(3)
    if field_source is FROM_SCENARIO:
        parts.source = field_source_for(scenario, p_WP)
    else:
        if np.any(np.asarray(scenario.uniform_field) != 0.0) or scenario.magnets:
            raise UserInputError("MakeStation: give the field either as the scenario's uniform_field/magnets or "
                                 "as field_source, not both")
        parts.source = field_source
    anchors = {"puncture": p_WP, "centre": np.zeros(3)}
    if heart is not None:  # a user's atrium has no carinas
        anchors.update({f"carina_{k}": v for k, v in heart.carinas.items()})
    parts.unit_configs = unit_configs(scenario, anchors)


def add_magnetic_wrench(builder, cp: ChainPlant, field_source, port_magnets=(), model: str = "dipole"
                        ) -> MagneticWrenchSystem:
    """The magnetic wrench system (``magnetic_wrench``) on the plant's balls: body poses in,
    spatial forces out to the plant (the one place the plant feels the field)."""
    wrench = builder.AddSystem(MagneticWrenchSystem(
        cp.config.chain, cp.ball_body_indices, field_source=field_source, base_direction_W=cp.sheath_axis_W,
        port_magnets=list(port_magnets), model=model))
    wrench.set_name("magnetic_wrench")
    builder.Connect(cp.plant.get_body_poses_output_port(), wrench.get_body_poses_input_port())
    builder.Connect(wrench.get_spatial_forces_output_port(), cp.plant.get_applied_spatial_force_input_port())
    return wrench


def _add_statics_engine(builder, scenario: ChainScenario, config: ChainPlantConfig, cp: ChainPlant, source, configs):
    """The QuasiStaticEngine of a scenario (wall: the atrium's SDF, or a flat ``wall_plane``)."""
    from ballchain.optimization.wall_constraints import PlaneSDF, SheathGeometry
    from ballchain.systems.quasi_static_engine import QuasiStaticEngine

    sdf = None
    if config.heart is not None:
        from ballchain.drake_models.atrium_sdf import atrium_sdf

        sdf = atrium_sdf(config.heart)
    elif scenario.wall_plane:
        w = np.asarray(scenario.wall_plane, float)
        sdf = PlaneSDF(w[:3], w[3:])
    sheath = None
    if config.sheath is not None:
        sheath = SheathGeometry(cp.p_WE, cp.sheath_axis_W, 0.5 * config.sheath.inner_diameter,
                                0.5 * config.sheath.wall_thickness)
    engine = builder.AddSystem(QuasiStaticEngine(
        config.chain, cp.ball_body_indices, cp.p_WE, cp.sheath_axis_W, sdf=sdf, sheath=sheath, field_source=source,
        port_magnets=[c.magnet for c in configs], model=configs[0].model if configs else "dipole",
        gravity=scenario.gravity, period=scenario.statics_period,
        initial_inserted_length=scenario.insertion.initial))
    engine.set_name("quasi_static_engine")
    engine.warm_up()  # compiled kernels and solvers loaded at build time, not in the timed run
    return engine


def add_field_coupling(builder: DiagramBuilder, parts: _Parts) -> None:
    """Step 5, how the chain feels the field: ``magnetic_wrench`` on the plant, or the
    ``quasi_static_engine`` (the equilibrium in the same field every ``statics_period``).

    Sets the chain system's ``body_poses`` output, the ``magnet_states`` input the units drive
    and the slide's desired-state input the insertion drives.
    """
    cp, configs = parts.cp, parts.unit_configs
    if parts.statics:
        parts.engine = engine = _add_statics_engine(builder, parts.scenario, parts.config, cp, parts.source, configs)
        parts.body_poses = engine.get_body_poses_output_port()
        parts.magnet_input = engine.get_magnet_states_input_port()
        parts.desired = engine.get_feeder_state_input_port()
    else:
        parts.wrench = add_magnetic_wrench(builder, cp, parts.source, port_magnets=[c.magnet for c in configs],
                                           model=parts.field_model)
        parts.body_poses = cp.plant.get_body_poses_output_port()
        parts.magnet_input = parts.wrench.get_magnet_states_input_port()
        parts.desired = cp.plant.get_desired_state_input_port(cp.feeder_instance)


def add_units_step(builder: DiagramBuilder, parts: _Parts) -> None:
    """Step 6, the rotating actuation units into the field coupling's ``magnet_states`` input
    (``station_units.add_units``), with ``tip_observer`` when a unit uses the tip-frame mapping.

    The neutral field is defined where the free chain starts: the sheath exit in the heart,
    ball 1's initial centre in free space (the canonical statics origin).
    """
    if not parts.unit_configs:
        return
    scenario, cp, heart = parts.scenario, parts.cp, parts.heart
    p_W_chain = heart.p_HE if heart is not None else cp.X_WF.multiply(
        np.array([scenario.insertion.initial, 0.0, 0.0]))
    if any(u.teleop_frame == "tip" for u in scenario.units):
        parts.tip_observer = builder.AddSystem(TipObserver(cp.ball_body_indices[-1], cp.ball_body_indices[-2]))
        builder.Connect(parts.body_poses, parts.tip_observer.get_body_poses_input_port())
    parts.units = add_units(builder, scenario, parts.unit_configs, parts.magnet_input, p_W_chain,
                            cp.sheath_axis_W, parts.tip_observer)


def add_insertion(builder: DiagramBuilder, parts: _Parts) -> None:
    """Step 7, what drives ball 1's slide (its desired state (s, s')).

    ``insertion.feeder``: the stepper ``feeder`` (``station_units.add_feeder``);
    ``insertion.external``: ``feeder_interface`` and the exported input ``inserted_length`` (1)
    [m]; else ``feeder_command``, the scenario's ramp (a first-order hold and its derivative).

    Raises:
        UserInputError: both external and feeder.
    """
    ins, desired = parts.scenario.insertion, parts.desired
    if ins.external and ins.feeder:
        raise UserInputError("insertion: choose external (exported port) or feeder (the Feeder system), not both")
    if ins.feeder:
        parts.feeder = add_feeder(builder, parts.config.chain, ins, desired)
    elif ins.external:
        # A feeder's inserted length s (systems/feeder.py's ``inserted_length`` uses the same
        # definition) becomes the slide's desired state (s, 0): the implicit PD tracks it.
        to_state = builder.AddSystem(MatrixGain(np.array([[1.0], [0.0]])))
        to_state.set_name("feeder_interface")
        builder.Connect(to_state.get_output_port(), desired)
        builder.ExportInput(to_state.get_input_port(), "inserted_length")
    else:
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


def add_target_touches(builder: DiagramBuilder, parts: _Parts) -> None:
    """Step 8, ``target_touches``: which ablation targets the tip ball has touched (with or
    without Meshcat: the run's metrics read it), when the atrium has target rings."""
    scenario, heart = parts.scenario, parts.heart
    parts.targets = heart_targets(heart) if heart is not None else None
    if parts.targets is None or not parts.targets[0]:
        return
    names, p_WT, n_W, target_radius = parts.targets
    # The engine's chain moves only at its updates: checking in between finds nothing new.
    period = max(scenario.check_period, scenario.statics_period) if parts.statics else scenario.check_period
    parts.tracker = builder.AddSystem(TargetTouchTracker(
        parts.cp.ball_body_indices[-1], names, p_WT, n_W, target_radius,
        ball_radius=0.5 * parts.config.chain.ball_diameter, period=period))
    builder.Connect(parts.body_poses, parts.tracker.get_body_poses_input_port())


def add_pin(builder: DiagramBuilder, parts: _Parts) -> None:
    """Step 9, ``force_sensor_pin`` (``scenario.pin``, when its point is set): a stiff explicit
    spring from the pin point to the tip ball's centre, into the plant's generalized forces; its
    reading (the force the tip presses on the pin) exported as ``pin_reading`` (3) [N]."""
    pin_scenario = parts.scenario.pin
    if not pin_scenario.point:
        return
    from ballchain.systems.force_sensor_pin import ForceSensorPin

    plant = parts.cp.plant
    parts.pin = pin = builder.AddSystem(ForceSensorPin(plant, parts.cp.ball_bodies[-1],
                                                       np.asarray(pin_scenario.point, float), pin_scenario.stiffness))
    pin.set_name("force_sensor_pin")
    builder.Connect(parts.body_poses, pin.get_body_poses_input_port())
    builder.Connect(pin.get_generalized_force_output_port(), plant.get_applied_generalized_force_input_port())
    builder.ExportOutput(pin.get_reading_output_port(), "pin_reading")


def add_external_commands(builder: DiagramBuilder, parts: _Parts, add_systems=None) -> None:
    """Step 10, the external commands (a unit's ``joystick_source: external``,
    ``insertion.feeder_command: external``): the ``add_systems`` hook adds what drives them
    (e.g. a simulated operator); whatever it leaves unconnected is exported as a diagram input
    (``<u>.joystick`` (3), ``feeder.v_insert_cmd`` (1))."""
    scenario = parts.scenario
    joystick_inputs = {u.name: parts.units[u.name].joystick_input for u in scenario.units
                       if u.joystick_source == "external"}
    feeder_input = None
    if scenario.insertion.feeder and scenario.insertion.feeder_command == "external":
        feeder_input = parts.feeder.GetInputPort("v_insert_cmd")
    if add_systems is not None:
        ports = StationPorts(parts.cp, parts.body_poses, joystick_inputs, feeder_input, parts.heart,
                             parts.targets if parts.tracker is not None else None, parts.tracker, parts.units)
        parts.added = dict(add_systems(builder, ports) or {})
    for name, port in joystick_inputs.items():
        if not builder.IsConnectedOrExported(port):
            builder.ExportInput(port, f"{name}.joystick")
    if feeder_input is not None and not builder.IsConnectedOrExported(feeder_input):
        builder.ExportInput(feeder_input, "feeder.v_insert_cmd")


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


def add_visualization(builder: DiagramBuilder, parts: _Parts, meshcat) -> None:
    """Step 11, the Meshcat view (with a Meshcat): ``meshcat_visualizer`` from
    ``scenario.visualization`` (a VisualizationConfig: publish period, illustration colour,
    ...), the fixed magnets, ``unit_markers``, ``meshcat_overlays`` (targets, the field at the
    tip, the wall's force on the tip), and the camera framed on the atrium. With ``engine:
    statics`` the balls are drawn from the engine's poses through a SceneGraph of their own."""
    if meshcat is None:
        return
    from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams

    scenario, cp, configs = parts.scenario, parts.cp, parts.unit_configs
    vis = scenario.visualization
    period = vis.publish_period
    params = MeshcatVisualizerParams(publish_period=period, default_color=vis.default_illustration_color,
                                     delete_on_initialization_event=vis.delete_on_initialization_event,
                                     enable_alpha_slider=vis.enable_alpha_sliders)
    d = parts.config.chain.ball_diameter
    scene_graph = cp.scene_graph
    if parts.statics:
        from pydrake.geometry import SceneGraph

        from ballchain.systems.quasi_static_engine import EngineGeometry

        scene_graph = builder.AddSystem(SceneGraph())
        scene_graph.set_name("scene_graph")
        geometry = builder.AddSystem(EngineGeometry(
            scene_graph, cp.ball_body_indices, 0.5 * d, parts.heart, parts.engine._sheath,
            cp.sheath_length() if parts.config.sheath is not None else 0.0))
        geometry.set_name("engine_geometry")
        builder.Connect(parts.body_poses, geometry.get_body_poses_input_port())
        builder.Connect(geometry.get_geometry_pose_output_port(), scene_graph.get_source_pose_port(geometry.source_id))
    parts.visualizer = MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, params)
    parts.visualizer.set_name("meshcat_visualizer")
    _draw_magnets(meshcat, parts.source)
    # The camera starts on the atrium (or the free chain's reach), also in the replays.
    frame_scene(meshcat, parts.heart, parts.config.chain.length, cp.p_WE)
    if configs:
        markers = builder.AddSystem(UnitMeshcatMarkers(meshcat, configs, period))
        for c in configs:
            builder.Connect(parts.units[c.name].magnet.GetOutputPort("X_WM"), markers.GetInputPort(f"X_WM_{c.name}"))
    tip_index = cp.ball_body_indices[-1]
    overlay_args = dict(targets=parts.targets if parts.tracker is not None else None, field_source=parts.source,
                        port_magnets=[c.magnet for c in configs], model=parts.field_model)
    if parts.statics:
        from ballchain.systems.quasi_static_engine import EngineOverlays

        overlays = builder.AddSystem(EngineOverlays(meshcat, tip_index, period, **overlay_args))
        builder.Connect(parts.engine.get_tip_wall_force_output_port(), overlays.get_tip_wall_force_input_port())
    else:
        overlays = builder.AddSystem(MeshcatOverlays(
            meshcat, cp.plant, cp.scene_graph.model_inspector(), tip_index, period, **overlay_args))
        builder.Connect(cp.plant.get_contact_results_output_port(), overlays.get_contact_results_input_port())
    builder.Connect(parts.body_poses, overlays.get_body_poses_input_port())
    if parts.tracker is not None:
        builder.Connect(parts.tracker.get_touched_output_port(), overlays.get_touched_input_port())
    if configs:
        builder.Connect(builder.GetSubsystemByName("magnet_states").get_output_port(),
                        overlays.get_magnet_states_input_port())
    parts.overlays = overlays


def MakeStation(scenario: ChainScenario, meshcat=None, *, heart: Atrium | None = None, add_systems=None,
                field_source=FROM_SCENARIO) -> Station:
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

    Returns:
        a Station.

    Raises:
        UserInputError: a bad scenario (naming the field).
    """
    require_type(scenario, ChainScenario, "MakeStation scenario", "a ChainScenario (from load_scenario)")
    if heart is not None:
        require_type(heart, Atrium, "MakeStation heart", "an atrium (LeftAtrium, UserAtrium) or None")
    if add_systems is not None and not callable(add_systems):
        raise UserInputError(f"MakeStation add_systems must be a function or None, got {short_repr(add_systems)}")
    if field_source is not FROM_SCENARIO:
        require_field_source(field_source, "MakeStation field_source", allow_none=True)
    t0 = time.perf_counter()
    scenario.validate()
    parts = _Parts(scenario)
    parts.heart = apply_atrium(scenario, heart)
    parts.config = apply_chain_plant_config(scenario, parts.heart)
    builder = DiagramBuilder()
    add_chain(builder, parts)
    add_field_sources(parts, field_source)
    add_field_coupling(builder, parts)
    add_units_step(builder, parts)
    add_insertion(builder, parts)
    add_target_touches(builder, parts)
    add_pin(builder, parts)
    add_external_commands(builder, parts, add_systems)
    add_visualization(builder, parts, meshcat)
    diagram = builder.Build()
    diagram.set_name("chain_in_heart")
    return Station(diagram, parts.cp, parts.wrench, parts.heart, scenario, parts.source, parts.visualizer,
                   time.perf_counter() - t0, parts.engine, units=parts.units, feeder=parts.feeder,
                   tip_observer=parts.tip_observer, target_touches=parts.tracker, meshcat_overlays=parts.overlays,
                   added=parts.added, pin=parts.pin)
