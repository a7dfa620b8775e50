"""Build and run the chain-in-a-heart diagram for a scenario, with a watchdog and Meshcat.

Diagram (system names):
    ``plant``, ``scene_graph``: the chain plant (``chain_plant``).
    ``magnetic_wrench``: MagneticWrenchSystem (body poses in, spatial forces out).
    ``feeder_command``: the scenario's insertion ramp as the feeder slide's desired state.
        With ``insertion.external`` it is replaced by ``feeder_interface`` and the diagram
        exports the input port ``inserted_length`` (1, m) for a feeder system.
    ``target_touches``: TargetTouchTracker (``target_contact``), when the atrium has target
        rings: the ablation targets the tip ball has touched so far.
    ``meshcat_visualizer``, ``meshcat_overlays`` (targets, field at the tip, the wall's force on
        the tip): when a Meshcat is given (and ``unit_markers`` for the units); the Meshcat's
        camera is then framed on the atrium (``meshcat_view.frame_scene``).
    With ``units``: per unit ``<u>.magnet``, ``<u>.drive``, ``<u>.hall_sensor``, ``<u>.estimator``,
        ``<u>.controller``, ``<u>.teleoperation``, ``<u>.mode_switch``, ``<u>.joystick``,
        ``<u>.mode_command``, ``<u>.p_WM``, and ``magnet_states`` into the wrench's magnet input
        (``station_units``); ``tip_observer`` when a unit uses the tip-frame mapping. With
        ``insertion.feeder``: ``feeder_command`` -> ``feeder`` -> ``feeder_interface``.
    External commands (a unit's ``joystick_source: external``, ``insertion.feeder_command:
        external``): the ``add_systems`` hook of ``build_chain_diagram`` adds the system that
        drives them (e.g. a simulated operator, ``systems/simulated_operator.py``); whatever it
        leaves unconnected is exported as a diagram input (``<u>.joystick`` (3),
        ``feeder.v_insert_cmd`` (1)).

``run_station`` is the one Simulator loop (watchdog, progress, stop condition, recording, Ctrl-C);
``run_simulation`` stops with ``SimulationFailure`` (saying when and which ball) on a NaN, a
ball leaving the heart or the chain breaking apart, and returns the metrics otherwise.
"""

from __future__ import annotations

import resource
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, EventStatus
from pydrake.systems.primitives import MatrixGain, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from ballchain.drake_models.errors import UserInputError, caused_by_interrupt
from ballchain.drake_models.field_sources import FieldSources, MagnetSource, UniformField
from ballchain.drake_models.heart import HeartParams, LeftAtrium
from ballchain.drake_models.params import BallChain, CylinderMagnet, Sleeve, SphereMagnet
from ballchain.drake_models.safe_files import atomic_write_text, check_output_file
from ballchain.systems.chain_plant import ChainPlant, ChainPlantConfig, SheathConfig, add_chain_plant
from ballchain.systems.chain_scenario import ChainScenario, check_duration
from ballchain.systems.magnetic_wrench import MagneticWrenchSystem
from ballchain.systems.meshcat_overlays import MeshcatOverlays
from ballchain.systems.target_contact import TargetTouchTracker, heart_targets, wall_force_on, wall_geometries
from ballchain.systems.meshcat_view import frame_scene
from ballchain.systems.station_units import TipObserver, UnitMeshcatMarkers, add_feeder, add_units, unit_configs


class SimulationFailure(RuntimeError):
    """The simulation stopped: NaN, a ball out of the heart, or the chain broken.

    Attributes:
        metrics: the metrics up to the failure (same keys as ``run_simulation`` returns).
    """

    def __init__(self, message: str, metrics: dict | None = None):
        super().__init__(message)
        self.metrics = metrics or {}


@dataclass
class ChainDiagram:
    """The built diagram and handles to its parts.

    With ``engine: statics`` there is no MultibodyPlant: ``chain_plant`` holds the geometry
    handles only (``plant`` is None; the ball BodyIndex values are the plant's), ``wrench`` is
    None and ``engine`` is the QuasiStaticEngine.
    """

    diagram: object
    chain_plant: ChainPlant
    wrench: MagneticWrenchSystem | None
    heart: LeftAtrium | None
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
        port_magnets=[c.magnet for c in configs], model=configs[0].field_model if configs else "dipole",
        gravity=scenario.gravity, period=scenario.statics_period,
        initial_inserted_length=scenario.insertion.initial))
    engine.set_name("quasi_static_engine")
    engine.warm_up()  # compiled kernels and solvers loaded at build time, not in the timed run
    return engine


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


def atrium_for(scenario: ChainScenario):
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
    return BallChain(n_balls=scenario.n_balls, sleeve=Sleeve() if scenario.sleeve else None)


@dataclass
class StationPorts:
    """What an ``add_systems`` hook of ``build_chain_diagram`` may connect to (before ``Build``).

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


def build_chain_diagram(scenario: ChainScenario, meshcat=None, heart: LeftAtrium | None = None,
                        add_systems=None) -> ChainDiagram:
    """Build the diagram of a (validated) scenario.

    Args:
        scenario: the scenario.
        meshcat: a pydrake Meshcat to visualise in, or None.
        heart: a prebuilt atrium to reuse (else built from the scenario when it has one).
        add_systems: None, or ``add_systems(builder, ports: StationPorts) -> dict`` called before
            the diagram is built, to add systems that drive the external commands (a simulated
            operator); the dict it returns is the ChainDiagram's ``added``. External inputs it leaves
            unconnected are exported.

    Returns:
        a ChainDiagram.
    """
    t0 = time.perf_counter()
    scenario.validate()
    chain = chain_for(scenario)
    quasi = scenario.mode == "quasi-static"
    if scenario.heart and heart is None:
        heart = atrium_for(scenario)
    if not scenario.heart:
        heart = None
    # Free space: the sheath exit is placed so that ball 1 sits at the origin at s = 0 and the
    # chain extends along +x (the canonical statics frame).
    d = chain.ball_diameter
    config = ChainPlantConfig(
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
        wall_plane=tuple(scenario.wall_plane),
    )
    builder = DiagramBuilder()
    statics = scenario.engine == "statics"
    cp = _engine_chain_handles(config) if statics else add_chain_plant(builder, config)
    s_max = cp.max_inserted_length()
    for what, s in (("initial", scenario.insertion.initial), ("final", scenario.insertion.final)):
        if not 0.0 <= s <= s_max:
            raise UserInputError(
                f"insertion.{what} = {s * 1e3:.1f} mm is outside 0..{s_max * 1e3:.1f} mm for "
                f"{chain.n_balls} balls (ball 1 must stay in the sheath)")
    p_WP = heart.p_HP if heart is not None else np.zeros(3)
    source = field_source_for(scenario, p_WP)
    anchors = {"puncture": p_WP, "centre": np.zeros(3)}
    if heart is not None:  # a user's atrium has no carinas
        anchors.update({f"carina_{k}": v for k, v in heart.carinas.items()})
    configs = unit_configs(scenario, anchors)
    engine = wrench = None
    if statics:
        engine = _add_statics_engine(builder, scenario, config, cp, source, configs)
        body_poses = engine.get_body_poses_output_port()
        magnet_input = engine.get_magnet_states_input_port()
        desired = engine.get_feeder_state_input_port()
    else:
        wrench = add_magnetic_wrench(builder, cp, source, port_magnets=[c.magnet for c in configs],
                                     model=configs[0].field_model if configs else "dipole")
        body_poses = cp.plant.get_body_poses_output_port()
        magnet_input = wrench.get_magnet_states_input_port()
        desired = cp.plant.get_desired_state_input_port(cp.feeder_instance)
    units, feeder_system, tip_observer, tracker, overlays, added = {}, None, None, None, None, {}
    if configs:
        # The neutral field is defined where the free chain starts: the sheath exit in the
        # heart, ball 1's initial centre in free space (the canonical statics origin).
        p_W_chain = heart.p_HE if heart is not None else cp.X_WF.multiply(
            np.array([scenario.insertion.initial, 0.0, 0.0]))
        if any(u.teleop_frame == "tip" for u in scenario.units):
            tip_observer = builder.AddSystem(TipObserver(cp.ball_body_indices[-1], cp.ball_body_indices[-2]))
            builder.Connect(body_poses, tip_observer.get_body_poses_input_port())
        units = add_units(builder, scenario, configs, magnet_input,
                                    p_W_chain, cp.sheath_axis_W, tip_observer)
    ins = scenario.insertion
    if ins.external and ins.feeder:
        raise UserInputError("insertion: choose external (exported port) or feeder (the Feeder system), not both")
    if ins.feeder:
        feeder_system = add_feeder(builder, chain, ins, desired)
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
        feeder = builder.AddSystem(TrajectorySource(traj, output_derivative_order=1))
        feeder.set_name("feeder_command")
        builder.Connect(feeder.get_output_port(), desired)
    # Which ablation targets the tip touches: tracked with or without Meshcat (for the metrics).
    targets = heart_targets(heart) if heart is not None else None
    tip_index = cp.ball_body_indices[-1]
    if targets is not None and targets[0]:
        names, p_WT, n_W, target_radius = targets
        tracker = builder.AddSystem(TargetTouchTracker(
            tip_index, names, p_WT, n_W, target_radius, ball_radius=0.5 * d,
            # The engine's chain moves only at its updates: checking in between finds nothing new.
            period=max(scenario.check_period, scenario.statics_period) if statics else scenario.check_period))
        builder.Connect(body_poses, tracker.get_body_poses_input_port())
    # External commands: the hook's systems drive them; what is left over is exported.
    joystick_inputs = {u.name: units[u.name].joystick_input for u in scenario.units
                       if u.joystick_source == "external"}
    feeder_input = None
    if ins.feeder and ins.feeder_command == "external":
        feeder_input = feeder_system.GetInputPort("v_insert_cmd")
    if add_systems is not None:
        ports = StationPorts(cp, body_poses, joystick_inputs, feeder_input, heart,
                             targets if tracker is not None else None, tracker, units)
        added = dict(add_systems(builder, ports) or {})
    for name, port in joystick_inputs.items():
        if not builder.IsConnectedOrExported(port):
            builder.ExportInput(port, f"{name}.joystick")
    if feeder_input is not None and not builder.IsConnectedOrExported(feeder_input):
        builder.ExportInput(feeder_input, "feeder.v_insert_cmd")
    visualizer = None
    if meshcat is not None:
        from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams

        params = MeshcatVisualizerParams(publish_period=scenario.publish_period)
        scene_graph = cp.scene_graph
        if statics:  # the balls drawn from the engine's poses through a SceneGraph of their own
            from pydrake.geometry import SceneGraph

            from ballchain.systems.quasi_static_engine import EngineGeometry

            scene_graph = builder.AddSystem(SceneGraph())
            scene_graph.set_name("scene_graph")
            geometry = builder.AddSystem(EngineGeometry(
                scene_graph, cp.ball_body_indices, 0.5 * d, heart, engine._sheath,
                cp.sheath_length() if config.sheath is not None else 0.0))
            geometry.set_name("engine_geometry")
            builder.Connect(body_poses, geometry.get_body_poses_input_port())
            builder.Connect(geometry.get_geometry_pose_output_port(), scene_graph.get_source_pose_port(geometry.source_id))
        visualizer = MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, params)
        visualizer.set_name("meshcat_visualizer")
        _draw_magnets(meshcat, source)
        # The camera starts on the atrium (or the free chain's reach), also in the replays.
        frame_scene(meshcat, heart, chain.length, cp.p_WE)
        if configs:
            markers = builder.AddSystem(UnitMeshcatMarkers(meshcat, configs, scenario.publish_period))
            for c in configs:
                builder.Connect(units[c.name].magnet.GetOutputPort("X_WM"),
                                markers.GetInputPort(f"X_WM_{c.name}"))
        overlay_args = dict(targets=targets if tracker is not None else None, field_source=source,
                            port_magnets=[c.magnet for c in configs],
                            model=configs[0].field_model if configs else "dipole")
        if statics:
            from ballchain.systems.quasi_static_engine import EngineOverlays

            overlays = builder.AddSystem(EngineOverlays(meshcat, tip_index, scenario.publish_period, **overlay_args))
            builder.Connect(engine.get_tip_wall_force_output_port(), overlays.get_tip_wall_force_input_port())
        else:
            overlays = builder.AddSystem(MeshcatOverlays(
                meshcat, cp.plant, cp.scene_graph.model_inspector(), tip_index, scenario.publish_period,
                **overlay_args))
            builder.Connect(cp.plant.get_contact_results_output_port(), overlays.get_contact_results_input_port())
        builder.Connect(body_poses, overlays.get_body_poses_input_port())
        if tracker is not None:
            builder.Connect(tracker.get_touched_output_port(), overlays.get_touched_input_port())
        if configs:
            builder.Connect(builder.GetSubsystemByName("magnet_states").get_output_port(),
                            overlays.get_magnet_states_input_port())
    diagram = builder.Build()
    diagram.set_name("chain_in_heart")
    return ChainDiagram(diagram, cp, wrench, heart, scenario, source, visualizer,
                        time.perf_counter() - t0, engine, units=units, feeder=feeder_system,
                        tip_observer=tip_observer, target_touches=tracker, meshcat_overlays=overlays,
                        added=added)


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


class ChainMonitor:
    """Per-step watchdog and metrics of a ChainDiagram (install with ``simulator.set_monitor``).

    Every ``scenario.check_period`` it checks the state for NaN, the chain for breaks and ball
    overlaps (cheap); every ``wall_check_every``-th of those checks it also checks escapes from
    the heart and the wall clearance (mesh queries, about 2 ms for 16 balls: checked every
    period they cost about 0.4 ms a step). The simulated trajectory does not depend on either;
    the clearance and penetration metrics are samples at the coarser period (plus one at the
    end, in ``metrics``).

    Args:
        cd: the diagram.
        tolerate_sinking: None, or ``tolerate_sinking(p_W (3,)) -> bool``: where a ball sinking
            past the middle of the wall is recorded (``tolerated_sinkings``: [(t, ball, depth [m])],
            at most one entry per ball per 0.1 s) instead of stopping the run (e.g. at the ostium
            rims, where the compliant wall mesh has next to no stiffness). Escapes stay fatal.
        wall_check_every: check escapes and clearance every this many periodic checks (>= 1;
            1 checks them every ``check_period``).
    """

    def __init__(self, cd: ChainDiagram, tolerate_sinking=None, wall_check_every: int = 4):
        if int(wall_check_every) != wall_check_every or wall_check_every < 1:
            raise ValueError(f"wall_check_every must be an integer >= 1, got {wall_check_every!r}")
        self._cd = cd
        self._system = cd.chain_system  # the plant, or the quasi-static engine
        self._d = cd.chain_plant.config.chain.ball_diameter
        self._period = cd.scenario.check_period
        if cd.engine is not None:  # the engine's chain only moves at its updates
            self._period = max(self._period, cd.engine.period)
        self._next_check = 0.0
        self._wall_every = int(wall_check_every)
        self._since_wall = self._wall_every - 1  # the first periodic check includes the wall
        self._last_wall_time = -np.inf
        self.failure: str | None = None
        self.min_clearance = np.inf
        self.max_gap = -np.inf
        self.max_penetration = 0.0
        self.max_ball_overlap = 0.0
        self.max_wall_penetration = 0.0
        self.checks = 0
        self._iu = np.triu_indices(cd.chain_plant.n_balls, k=1)
        self._tolerate_sinking = tolerate_sinking
        self.tolerated_sinkings: list[tuple[float, int, float]] = []

    def _finite(self, context) -> bool:
        if self._cd.engine is not None:
            return bool(np.all(np.isfinite(self._cd.engine.state_vector(context))))
        plant = self._system
        return bool(np.all(np.isfinite(plant.GetPositions(context))) and np.all(np.isfinite(plant.GetVelocities(context))))

    def check(self, plant_context, wall: bool = True) -> str | None:
        """Check a state now; returns a failure message or None, and updates the metrics.

        Args:
            plant_context: the chain system's context (the plant's or the quasi-static engine's).
            wall: also check escapes from the heart and the wall clearance.
        """
        t = plant_context.get_time()
        if not self._finite(plant_context):
            return f"NaN or inf in the state at t = {t:.4f} s: {self._non_finite_ball(plant_context)}"
        if self._cd.engine is not None and self._cd.engine.failure:
            return self._cd.engine.failure
        cp = self._cd.chain_plant
        p = self._cd.ball_positions(plant_context)
        self.checks += 1
        gaps = np.linalg.norm(np.diff(p, axis=0), axis=1) - self._d
        self.max_gap = max(self.max_gap, float(gaps.max()))
        dist = np.linalg.norm(p[self._iu[0]] - p[self._iu[1]], axis=1)
        self.max_ball_overlap = max(self.max_ball_overlap, float(self._d - dist.min()))
        self.max_penetration = max(self.max_penetration, self.max_ball_overlap)
        heart = self._cd.heart
        if heart is not None and not wall:
            return self._check_gaps(gaps, t)
        if heart is not None:
            self._last_wall_time = t
            in_sheath = cp.in_sheath(p)
            outside = ~heart.contains(p) & ~in_sheath
            if np.any(outside):
                i = int(np.argmax(outside))
                return (f"ball {i + 1} escaped the heart at t = {t:.4f} s: centre at "
                        f"{np.round(p[i] * 1e3, 2).tolist()} mm")
            free = ~in_sheath
            if np.any(free):
                clearance = heart.wall_distance(p[free]) - 0.5 * self._d
                self.min_clearance = min(self.min_clearance, float(clearance.min()))
                self.max_wall_penetration = max(self.max_wall_penetration, float(-clearance.min()))
                self.max_penetration = max(self.max_penetration, self.max_wall_penetration)
                half_wall = 0.5 * heart.params.wall_thickness
                if -clearance.min() > half_wall:
                    i = int(np.flatnonzero(free)[np.argmin(clearance)])
                    if self._tolerate_sinking is not None and self._tolerate_sinking(p[i]):
                        last = [e for e in self.tolerated_sinkings if e[1] == i + 1]
                        if not last or t - last[-1][0] >= 0.1:
                            self.tolerated_sinkings.append((t, i + 1, float(-clearance.min())))
                        return self._check_gaps(gaps, t)
                    return (f"ball {i + 1} sank {-clearance.min() * 1e3:.2f} mm into the wall at "
                            f"t = {t:.4f} s, past its middle ({half_wall * 1e3:.2f} mm), where the "
                            "compliant wall would push it out: raise contact.wall_hydroelastic_modulus")
        elif np.any(np.linalg.norm(p, axis=1) > 10 * cp.config.chain.length + 0.1):
            i = int(np.argmax(np.linalg.norm(p, axis=1)))
            return f"ball {i + 1} flew away at t = {t:.4f} s: centre at {np.round(p[i] * 1e3, 1).tolist()} mm"
        return self._check_gaps(gaps, t)

    def _non_finite_ball(self, plant_context) -> str:
        """Which ball's position or velocity is not finite (for the failure message)."""
        if self._cd.engine is not None:
            p = self._cd.engine.ball_positions(plant_context)
            bad = np.flatnonzero(~np.all(np.isfinite(p), axis=1))
            return f"ball {bad[0] + 1} (position)" if len(bad) else "the engine's state"
        plant = self._system
        for i, body in enumerate(self._cd.chain_plant.ball_bodies):
            X = plant.EvalBodyPoseInWorld(plant_context, body).GetAsMatrix34()
            V = plant.EvalBodySpatialVelocityInWorld(plant_context, body).get_coeffs()
            if not (np.all(np.isfinite(X)) and np.all(np.isfinite(V))):
                part = "position" if not np.all(np.isfinite(X)) else "velocity"
                return f"ball {i + 1} ({part})"
        return "the feeder slide"

    def _check_gaps(self, gaps: np.ndarray, t: float) -> str | None:
        if gaps.max() > self._cd.scenario.break_gap:
            i = int(np.argmax(gaps))
            return (f"the chain broke between balls {i + 1} and {i + 2} at t = {t:.4f} s "
                    f"(gap {gaps[i] * 1e3:.2f} mm > {self._cd.scenario.break_gap * 1e3:.2f} mm)")
        return None

    def __call__(self, root_context):
        plant_context = self._system.GetMyContextFromRoot(root_context)
        t = root_context.get_time()
        if t + 1e-12 < self._next_check and not (self._cd.engine is not None and self._cd.engine.failure):
            if self._finite(plant_context):
                return EventStatus.Succeeded()
        self._next_check = t + self._period
        self._since_wall += 1
        wall = self._since_wall >= self._wall_every
        if wall:
            self._since_wall = 0
        self.failure = self.check(plant_context, wall=wall)
        if self.failure:
            return EventStatus.Failed(self._cd.diagram, self.failure)
        return EventStatus.Succeeded()

    def metrics(self, plant_context) -> dict:
        p = self._cd.ball_positions(plant_context)
        if (self._cd.heart is not None and plant_context.get_time() > self._last_wall_time
                and np.all(np.isfinite(p)) and self.failure is None):
            # The clearance at the end of the run too (the wall check runs at a coarser period).
            checks = self.checks
            self.check(plant_context, wall=True)
            self.checks = checks
        return {
            "tip_position_mm": (p[-1] * 1e3).round(3).tolist() if np.all(np.isfinite(p)) else None,
            "min_wall_clearance_mm": None if not np.isfinite(self.min_clearance) else round(self.min_clearance * 1e3, 4),
            "max_neighbor_gap_um": round(self.max_gap * 1e6, 3) if np.isfinite(self.max_gap) else None,
            "max_penetration_um": round(self.max_penetration * 1e6, 3),
            "max_ball_overlap_um": round(self.max_ball_overlap * 1e6, 3),
            "max_wall_penetration_um": round(self.max_wall_penetration * 1e6, 3),
            "monitor_checks": self.checks,
        }


def _targets_touched(cd: ChainDiagram, root_context) -> list[str]:
    tracker = cd.target_touches
    return [] if tracker is None else tracker.touched_names(tracker.GetMyContextFromRoot(root_context))


def _tip_wall_force(cd: ChainDiagram, plant_context) -> list[float]:
    """The walls' contact force on the tip ball at the end of the run [N] (world frame)."""
    if cd.engine is not None:
        return [round(float(v), 6) for v in cd.engine.get_tip_wall_force_output_port().Eval(plant_context)[:3]]
    plant = cd.chain_plant.plant
    tip = set(plant.GetCollisionGeometriesForBody(cd.chain_plant.ball_bodies[-1]))
    walls = wall_geometries(plant, cd.chain_plant.scene_graph.model_inspector())
    f, _ = wall_force_on(plant.get_contact_results_output_port().Eval(plant_context), tip, walls)
    return [round(float(v), 6) for v in f]


@dataclass
class RunOutcome:
    """What ``run_station`` ran.

    Attributes:
        sim_time: simulated time reached [s].
        wall_time: wall time of Simulator Initialize + AdvanceTo [s] (the build is not counted).
        cpu_time: the process's CPU time over the same span [s].
        failure: the watchdog's failure message (or the solver's error, with the time), or None.
        stopped: True when ``stop`` ended the run before ``duration``.
        monitor: the ChainMonitor that watched the run (its metrics, tolerated sinkings).
        context: the Simulator's root context at the end.
        simulator: the Simulator.
    """

    sim_time: float
    wall_time: float
    cpu_time: float
    failure: str | None
    stopped: bool
    monitor: ChainMonitor
    context: object
    simulator: Simulator


def _export_recording(cd: ChainDiagram, meshcat, html: Path) -> None:
    cd.visualizer.StopRecording()
    cd.visualizer.PublishRecording()
    atomic_write_text(html, meshcat.StaticHtml())


def station_monitor(cd: ChainDiagram, monitor: ChainMonitor, stop=None, on_time=None):
    """The Simulator monitor of a station run: the watchdog, then ``on_time``, then ``stop``.

    Args:
        cd: the diagram.
        monitor: the watchdog (its failure ends the run).
        stop: None, or ``stop(root_context) -> bool``: a termination when True.
        on_time: None, or ``on_time(t)`` called with the simulated time [s] (a progress bar).

    Returns:
        ``monitor(root_context) -> EventStatus`` for ``Simulator.set_monitor``.
    """

    def watch(root_context):
        status = monitor(root_context)
        if status.severity() == EventStatus.Severity.kFailed:
            return status
        if on_time is not None:
            on_time(root_context.get_time())
        if stop is not None and stop(root_context):
            return EventStatus.ReachedTermination(cd.diagram, "the stop condition")
        return status

    return watch


def run_station(cd: ChainDiagram, *, duration: float, monitor: ChainMonitor | None = None, stop=None,
                progress: str | None = None, progress_step: float | None = None, html: Path | None = None,
                meshcat=None, realtime_rate: float | None = None) -> RunOutcome:
    """Run a built station: the one Simulator loop of the scenario runs and the teleoperation tasks.

    The Simulator's monitor is the watchdog (``monitor``) first, then the progress bar, then
    ``stop``. A watchdog failure, or a RuntimeError / ValueError of the solver, ends the run
    with its message in ``RunOutcome.failure`` (no exception). On Ctrl-C the replay recorded so
    far is written to ``html`` before the KeyboardInterrupt goes on.

    Args:
        cd: the built diagram (``build_chain_diagram``).
        duration: simulated-time limit [s].
        monitor: the watchdog (default: ``ChainMonitor(cd)``).
        stop: None, or ``stop(root_context) -> bool``: end the run (a termination) when True.
        progress: None (no bar), or the label of a tqdm bar of the simulated time on stderr.
        progress_step: update the bar every this many simulated seconds (default duration/200).
        html: record the run in Meshcat and write the replay (self-contained HTML) here; the
            diagram must have been built with ``meshcat`` (the path is checked by the caller).
        meshcat: the Meshcat the diagram was built with (needed with ``html``).
        realtime_rate: the Simulator's target real-time rate (None: as fast as possible).

    Returns:
        RunOutcome.
    """
    from pydrake.systems.analysis import SimulatorStatus

    simulator = Simulator(cd.diagram)
    if realtime_rate is not None:
        simulator.set_target_realtime_rate(realtime_rate)
    monitor = ChainMonitor(cd) if monitor is None else monitor
    bar = None
    if progress is not None:
        from tqdm import tqdm

        bar = tqdm(total=duration, desc=progress, unit="sim s", file=sys.stderr,
                   bar_format="{l_bar}{bar}| {n:.3g}/{total:.3g} sim s [{elapsed}<{remaining}]")
    step = duration / 200 if progress_step is None else progress_step
    shown = [0.0]

    def show(t):
        if t - shown[0] >= step:
            bar.update(t - shown[0])
            shown[0] = t

    simulator.set_monitor(station_monitor(cd, monitor, stop=stop, on_time=None if bar is None else show))
    root = simulator.get_mutable_context()
    record = cd.visualizer is not None and html is not None
    if record:
        cd.visualizer.StartRecording()
    failure, stopped = None, False
    start, cpu = time.perf_counter(), time.process_time()
    try:
        simulator.Initialize()
        status = simulator.AdvanceTo(duration)
        stopped = status.reason() == SimulatorStatus.ReturnReason.kReachedTerminationCondition
    except BaseException as err:
        if caused_by_interrupt(err):  # Ctrl-C (maybe wrapped by a compiled call): keep the replay, stop
            if record:
                _export_recording(cd, meshcat, html)
                print(f"{progress or 'run'}: interrupted at t = {root.get_time():.4f} s; replay so far written "
                      f"to {html}", file=sys.stderr)
            if isinstance(err, KeyboardInterrupt):
                raise
            raise KeyboardInterrupt from err
        if not isinstance(err, (RuntimeError, ValueError)):
            raise
        # The monitor's failure, or a solver/physics error.
        failure = monitor.failure or f"at t = {root.get_time():.4f} s: {' '.join(str(err).split())}"
    finally:
        if bar is not None:
            bar.close()
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    if record:
        _export_recording(cd, meshcat, html)
    return RunOutcome(root.get_time(), wall, cpu, failure, stopped, monitor, root, simulator)


def run_simulation(*, scenario: ChainScenario, duration: float | None = None, html: Path | None = None,
                   meshcat=None, heart: LeftAtrium | None = None, progress: bool = False) -> dict:
    """Simulate a scenario and return its metrics.

    Args:
        scenario: the (validated) scenario.
        duration: simulated time [s] (default: the scenario's).
        html: write a self-contained Meshcat recording to this file.
        meshcat: a Meshcat to use (a localhost one is started when ``html`` is given).
        heart: a prebuilt atrium to reuse.
        progress: show a progress bar of the simulated time on stderr.

    Returns:
        {"realtime_factor", "sim_time_s", "tip_position_mm", "min_wall_clearance_mm",
        "max_neighbor_gap_um", "max_penetration_um", "wall_time_s", "build_time_s",
        "time_step_s", "mode", "n_steps", "targets_touched" (names such as "left_3" of the
        ablation targets the tip ball touched, see ``meshcat_overlays``; empty without any),
        "peak_memory_MB" (the process's peak resident set size, ``ru_maxrss``, in MiB),
        "p_W_mm" (n, 3)}.

    Raises:
        SimulationFailure: NaN, escape or break (message says when and which ball).
    """
    duration = scenario.duration if duration is None else duration
    check_duration(duration, scenario.effective_time_step, "duration")
    if html is not None:
        check_output_file(html, "html")
    if html is not None and meshcat is None:
        from pydrake.geometry import Meshcat, MeshcatParams

        meshcat = Meshcat(MeshcatParams(host="localhost"))
    cd = build_chain_diagram(scenario, meshcat=meshcat, heart=heart)
    run = run_station(cd, duration=duration, progress="simulate" if progress else None, html=html, meshcat=meshcat)
    monitor, root, error = run.monitor, run.context, run.failure
    plant_context = cd.chain_system.GetMyContextFromRoot(root)
    wall, sim_time = run.wall_time, run.sim_time
    metrics = {
        "realtime_factor": round(sim_time / wall, 4) if wall > 0 else None,
        "sim_time_s": round(sim_time, 6),
        **monitor.metrics(plant_context),
        "wall_time_s": round(wall, 3),
        "build_time_s": round(cd.build_time_s, 3),
        "time_step_s": scenario.statics_period if cd.engine is not None else scenario.effective_time_step,
        "mode": scenario.mode,
        "engine": scenario.engine,
        "n_steps": int(round(sim_time / (scenario.statics_period if cd.engine is not None
                                         else scenario.effective_time_step))),
        "targets_touched": _targets_touched(cd, root),
        "tip_wall_force_N": _tip_wall_force(cd, plant_context),
        # ru_maxrss is in KiB on Linux: the process's peak resident set size so far (the whole
        # process, not this run alone).
        "peak_memory_MB": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
    }
    if cd.engine is not None:
        solves = np.array(cd.engine.solve_times)
        metrics["statics"] = {
            "solves": int(len(solves)),
            "median_solve_ms": round(float(np.median(solves)) * 1e3, 3) if len(solves) else None,
            "max_solve_ms": round(float(solves.max()) * 1e3, 3) if len(solves) else None,
            "median_iterations": float(np.median(cd.engine.iterations)) if cd.engine.iterations else None,
            "snap_throughs": [{"t_s": round(e.time, 4), "jump_mm": round(e.jump * 1e3, 3), "detail": e.detail}
                              for e in cd.engine.events if e.kind == "snap-through"],
            "failures": [e.detail for e in cd.engine.events if e.kind == "solve failed"],
        }
    if cd.visualizer is not None and html is not None:
        metrics["html"] = str(html)
    if error is not None:
        raise SimulationFailure(f"simulation stopped: {error}", metrics)
    p = cd.ball_positions(plant_context)
    metrics["p_W_mm"] = (p * 1e3).round(4).tolist()
    return metrics
