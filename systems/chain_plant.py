"""The ball chain as a MultibodyPlant: free balls, a feeder ball in the sheath, the heart wall.

Bodies and joints:

* ``ball_1`` is the feeder ball: it sits in the transseptal sheath on a prismatic joint
  ``feeder_slide`` along the sheath axis, driven by a PD-controlled actuator (implicit in SAP)
  to the inserted length. Its dipole points along the sheath axis: it is the canonical
  statics problem's clamped ball 1, and pulls the chain back on retraction.
* ``ball_2`` .. ``ball_n`` are free bodies (quaternion floating joints ``ball_i_floating``),
  with joint damping in the quasi-static mode (implicit in the discrete solver) and none in
  the dynamics mode. A ball's dipole points along its body frame's +x.
* The heart wall (a compliant-hydroelastic tetrahedral shell, ``drake_models.heart``, with a
  hydroelastic margin against tunnelling) is anchored to the world. Balls are rigid-hydroelastic
  spheres; ball-ball contact falls back to point contact (``hydroelastic_with_fallback``), with
  ``sap_near_rigid_threshold = 0`` and a relaxation time near the time step so that the balls
  do not sink into one another (docs/design.md, 5): about 5 um of overlap at 2.2 N.
* The transseptal sheath is a cage of rods (capsules, point contact) around its bore, from
  behind ball 1 to ``sheath_extension`` beyond the septal puncture (see ``_add_sheath_cage``).
* The balls start straight along the sheath axis, touching (4 um of overlap): a pair that
  starts apart is not a contact constraint during the first step, and 2 N of attraction at
  1e-3 s can pull a ball through its neighbour before it is.

Inserted length s [m]: the length of chain beyond the sheath exit p_WE when the chain is
straight; ball 1's centre is at p_WE + (s - (n - 1/2) d) u (u the sheath axis), so at s = 0 the
tip ball touches the exit from inside.
"""

import copy
from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import (
    AddCompliantHydroelasticProperties,
    AddCompliantHydroelasticPropertiesForHalfSpace,
    AddContactMaterial,
    AddRigidHydroelasticProperties,
    Box,
    HalfSpace,
    Mesh,
    ProximityProperties,
    Sphere,
)
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import (
    AddMultibodyPlant,
    CoulombFriction,
    MultibodyPlantConfig,
)
from pydrake.multibody.tree import (
    FixedOffsetFrame,
    PdControllerGains,
    PrismaticJoint,
    QuaternionFloatingJoint,
    SpatialInertia,
    UnitInertia,
)
from pydrake.systems.primitives import ConstantVectorSource

from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.drake_models.heart import LeftAtrium
from ballchain.drake_models.params import GRAVITY, BallChain, Sleeve
from ballchain.systems.chain_model import (
    BallCentres,
    ChainGeometry,
    ChainModel,
    FieldCoupling,
    chain_geometry,
    subsystem_context,
)
from ballchain.systems.magnetic_wrench import MagneticWrenchSystem
from ballchain.systems.target_contact import WallForceOnBall
from ballchain.systems.force_sensor_pin import ForceSensorPin
from ballchain.systems.meshcat_view import TARGET_CENTRE_RADIUS, TARGET_CENTRE_RGBA


def chain_multibody_plant_config(**overrides) -> MultibodyPlantConfig:
    """The chain's MultibodyPlantConfig: Drake's defaults but for the three choices below.

    SAP (the damping and the feeder's PD implicit), hydroelastic wall and balls with point
    contact between balls (``hydroelastic_with_fallback``), and ``sap_near_rigid_threshold = 0``
    so that SAP does not stiffen the ball-ball contacts to near-rigid (docs/design.md, 5). The
    time step is left 0 here: its one home is the scenario's ``time_step`` (``ChainPlantConfig``'s
    ``time_step`` at build time), not this struct.

    Args:
        overrides: MultibodyPlantConfig fields to change.
    """
    values = dict(time_step=0.0, discrete_contact_approximation="sap",
                  contact_model="hydroelastic_with_fallback", sap_near_rigid_threshold=0.0)
    values.update(overrides)
    return MultibodyPlantConfig(**values)


@dataclass
class ContactConfig:
    """Contact parameters (SI).

    Attributes:
        ball_point_stiffness: point-contact stiffness of a ball [N/m] (ball-ball pairs combine
            two in series).
        relaxation_time: SAP dissipation time scale [s]; 0 means "the time step".
        friction: Coulomb friction coefficient (static = dynamic).
        wall_hydroelastic_modulus: of the heart wall [Pa]. Stiffer than atrial tissue on
            purpose: the pressure of a thin compliant shell peaks mid-wall, so a ball pressed
            deeper than half the wall would be pushed out through it. At 1 MPa a ball pressed
            with about 1.5 N sinks about 0.6 mm into the 2.5 mm wall (0.3 MPa: 1.2 mm).
        hydroelastic_margin: against tunnelling at larger steps [m].
        ball_resolution_hint: of the balls' rigid-hydroelastic sphere meshes [m].
    """

    ball_point_stiffness: float = 1e6
    relaxation_time: float = 0.0
    friction: float = 0.1
    wall_hydroelastic_modulus: float = 1e6
    hydroelastic_margin: float = 1e-4
    ball_resolution_hint: float = 1e-3


@dataclass
class SheathConfig:
    """The transseptal sheath (a tube the proximal balls sit in).

    Attributes:
        inner_diameter: bore [m] (must exceed the ball diameter).
        wall_thickness: [m] (also the diameter of the rods of the collision cage).
        extra_length: length behind ball 1 at zero insertion [m].
        n_rods: rods of the collision cage (see ``_add_sheath_cage``).
    """

    inner_diameter: float = 3.6e-3
    wall_thickness: float = 0.6e-3
    extra_length: float = 8e-3
    n_rods: int = 6


@dataclass
class ChainPlantConfig:
    """What ``add_chain_plant`` builds.

    Attributes:
        chain: the chain's parameters.
        time_step: discrete step [s].
        translational_damping: on each free ball's floating joint [N s/m] (0: true dynamics).
        angular_damping: on each free ball's floating joint [N m s].
        gravity: gravity along -z (else none).
        heart: the atrium, or None for free space.
        sheath: the sheath tube, or None (then ball 1 alone is held by its slide).
        p_WE: (3,) sheath exit [m] (taken from the heart when there is one).
        sheath_axis_W: (3,) unit insertion direction (taken from the heart when there is one).
        initial_inserted_length: [m].
        contact: contact parameters.
        feeder_gains: (kp [N/m], kd [N s/m]) of the feeder slide's PD actuator.
        plant_config: Drake's MultibodyPlantConfig (``chain_multibody_plant_config()``); its
            ``time_step`` is not read (``time_step`` above is the plant's step).
        wall_plane: () or (x, y, z, nx, ny, nz): a compliant-hydroelastic half-space whose
            surface passes through the point and whose outward normal is n (free space only;
            the statics counterpart is ``ChainStatics.solve(..., wall=...)``).
    """

    chain: BallChain = field(default_factory=BallChain)
    time_step: float = 1e-3
    translational_damping: float = 0.0
    angular_damping: float = 0.0
    gravity: bool = True
    heart: LeftAtrium | None = None
    sheath: SheathConfig | None = field(default_factory=SheathConfig)
    p_WE: tuple = (0.0, 0.0, 0.0)
    sheath_axis_W: tuple = (1.0, 0.0, 0.0)
    initial_inserted_length: float = 0.0
    contact: ContactConfig = field(default_factory=ContactConfig)
    feeder_gains: tuple = (2e4, 20.0)
    wall_plane: tuple = ()
    plant_config: MultibodyPlantConfig = field(default_factory=chain_multibody_plant_config)


def chain_for(scenario) -> BallChain:
    """The scenario's ball chain (``n_balls``, with the sleeve's bending forces or not)."""
    return BallChain(n_balls=scenario.n_balls, sleeve=Sleeve() if scenario.sleeve else None)


def chain_plant_config(scenario, heart) -> ChainPlantConfig:
    """The chain's configuration from the scenario (either engine's: ``ChainModel.config_for``).

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


@dataclass
class ChainPlant(ChainGeometry):
    """Handles to what ``add_chain_plant`` made (and the chain's geometry, ``ChainGeometry``)."""

    plant: object = None
    scene_graph: object = None
    ball_bodies: list = field(default_factory=list)
    feeder_joint: object = None
    feeder_instance: object = None

    def ball_positions(self, plant_context) -> np.ndarray:
        """Ball centres (n, 3) in world [m]."""
        poses = self.plant.get_body_poses_output_port().Eval(plant_context)
        return np.array([poses[int(b.index())].translation() for b in self.ball_bodies])


def _ball_properties(config: ChainPlantConfig) -> ProximityProperties:
    c = config.contact
    props = ProximityProperties()
    friction = CoulombFriction(c.friction, c.friction)
    AddContactMaterial(None, c.ball_point_stiffness, friction, props)
    props.AddProperty("material", "relaxation_time", float(c.relaxation_time or config.time_step))
    AddRigidHydroelasticProperties(c.ball_resolution_hint, props)
    return props


def _wall_properties(config: ChainPlantConfig, resolution_hint: float) -> ProximityProperties:
    c = config.contact
    props = ProximityProperties()
    AddContactMaterial(None, None, CoulombFriction(c.friction, c.friction), props)
    props.AddProperty("material", "relaxation_time", float(c.relaxation_time or config.time_step))
    AddCompliantHydroelasticProperties(resolution_hint, c.wall_hydroelastic_modulus, props)
    props.AddProperty("hydroelastic", "margin", float(c.hydroelastic_margin))
    return props


def _add_wall_plane(plant, config: ChainPlantConfig) -> None:
    """A compliant-hydroelastic half-space (a flat wall) anchored to the world."""
    values = np.asarray(config.wall_plane, dtype=float)
    if values.shape != (6,) or not np.all(np.isfinite(values)) or np.linalg.norm(values[3:]) == 0:
        raise UserInputError(f"wall_plane must be 6 finite numbers (point, non-zero normal), got {config.wall_plane}")
    if config.heart is not None:
        raise UserInputError("wall_plane is for free space: the heart has its own wall")
    c = config.contact
    props = ProximityProperties()
    AddContactMaterial(None, None, CoulombFriction(c.friction, c.friction), props)
    props.AddProperty("material", "relaxation_time", float(c.relaxation_time or config.time_step))
    AddCompliantHydroelasticPropertiesForHalfSpace(5e-3, c.wall_hydroelastic_modulus, props)
    props.AddProperty("hydroelastic", "margin", float(c.hydroelastic_margin))
    X_WH = RigidTransform(RotationMatrix(rotation_with_z_along(values[3:])), values[:3])
    world = plant.world_body()
    plant.RegisterCollisionGeometry(world, X_WH, HalfSpace(), "wall_plane", props)
    X_WV = X_WH.multiply(RigidTransform([0.0, 0.0, -0.5e-3]))
    plant.RegisterVisualGeometry(world, X_WV, Box(0.08, 0.08, 1e-3), "wall_plane", np.array([0.85, 0.35, 0.35, 0.35]))


def _add_sheath_cage(plant, config: ChainPlantConfig, p_WE, axis) -> None:
    """The sheath as a cage of rods (capsules) parallel to its axis, anchored to the world.

    A compliant-hydroelastic tube (measured: 14 ms a step against 1.2 ms without it, 16 balls)
    is slow because every ball inside it lies within the hydroelastic margin of its wall; rods
    touching the balls through point contact cost next to nothing and hold them as well (the
    gaps between rods, about 1.3 mm, are far narrower than a ball).
    """
    from pydrake.geometry import Capsule, Cylinder

    sheath = config.sheath
    chain = config.chain
    length = chain.n_balls * chain.ball_diameter + sheath.extra_length
    r_rod = sheath.wall_thickness / 2.0
    r_c = sheath.inner_diameter / 2.0 + r_rod  # rod centres: the rods' inner tangent is the bore
    props = ProximityProperties()
    c = config.contact
    AddContactMaterial(None, c.ball_point_stiffness, CoulombFriction(c.friction, c.friction), props)
    props.AddProperty("material", "relaxation_time", float(c.relaxation_time or config.time_step))
    # Rod k runs from the exit back along the axis; frame: z along the axis (Capsule's axis).
    R_WS = RotationMatrix(rotation_with_z_along(axis))
    centre = np.asarray(p_WE) - 0.5 * length * np.asarray(axis)
    e1, e2 = R_WS.matrix()[:, 0], R_WS.matrix()[:, 1]
    n_rods = sheath.n_rods
    world = plant.world_body()
    for k in range(n_rods):
        a = 2 * np.pi * k / n_rods
        p = centre + r_c * (np.cos(a) * e1 + np.sin(a) * e2)
        plant.RegisterCollisionGeometry(world, RigidTransform(R_WS, p), Capsule(r_rod, length),
                                        f"sheath_rod_{k + 1}", props)
    plant.RegisterVisualGeometry(world, RigidTransform(R_WS, centre),
                                 Cylinder(r_c + r_rod, length), "sheath",
                                 np.array([0.3, 0.5, 0.9, 0.3]))


def add_chain_plant(builder, config: ChainPlantConfig) -> ChainPlant:
    """Add the chain's MultibodyPlant and SceneGraph to ``builder`` (plant finalised).

    Args:
        builder: a DiagramBuilder.
        config: what to build.

    Returns:
        a ChainPlant with the handles (plant named "plant", scene graph "scene_graph").
    """
    chain = config.chain
    if chain.n_balls < 2:
        raise UserInputError("add_chain_plant: the chain needs at least 2 balls (ball 1 is the feeder ball)")
    if config.sheath is not None and config.sheath.inner_diameter <= chain.ball_diameter:
        raise UserInputError(
            f"sheath inner diameter {config.sheath.inner_diameter * 1e3:.2f} mm must exceed the ball "
            f"diameter {chain.ball_diameter * 1e3:.3f} mm")
    plant_config = copy.copy(config.plant_config)
    plant_config.time_step = config.time_step  # the step has one home (see ChainPlantConfig)
    plant, scene_graph = AddMultibodyPlant(plant_config, builder)
    plant.set_name("plant")
    scene_graph.set_name("scene_graph")
    # One gravity for statics and the plant (Drake's default is 9.81).
    plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, -GRAVITY if config.gravity else 0.0])

    heart = config.heart
    geometry = chain_geometry(config)  # the sheath exit, its axis and the feeder frame
    p_WE, axis, X_WF = geometry.p_WE, geometry.sheath_axis_W, geometry.X_WF
    d = chain.ball_diameter
    r = 0.5 * d
    inertia = SpatialInertia(chain.ball_mass, np.zeros(3), UnitInertia.SolidSphere(r))
    ball_props = _ball_properties(config)
    colors = [np.array([0.75, 0.75, 0.78, 1.0]), np.array([0.45, 0.45, 0.5, 1.0])]
    feeder_instance = plant.AddModelInstance("feeder")
    chain_instance = plant.AddModelInstance("chain")
    balls = []
    for i in range(chain.n_balls):
        instance = feeder_instance if i == 0 else chain_instance
        body = plant.AddRigidBody(f"ball_{i + 1}", instance, inertia)
        plant.RegisterCollisionGeometry(body, RigidTransform(), Sphere(r), f"ball_{i + 1}", ball_props)
        plant.RegisterVisualGeometry(body, RigidTransform(), Sphere(r), f"ball_{i + 1}", colors[i % 2])
        # A short marker along +x shows the dipole (north) direction.
        plant.RegisterVisualGeometry(body, RigidTransform([0.6 * r, 0, 0]), Sphere(0.45 * r),
                                     f"ball_{i + 1}_north", np.array([0.8, 0.1, 0.1, 1.0]))
        balls.append(body)

    # Ball 1 slides along the sheath axis: frame F has its x along the axis.
    slide_frame = plant.AddFrame(FixedOffsetFrame("feeder_slide_frame", plant.world_frame(), X_WF))
    feeder_joint = plant.AddJoint(PrismaticJoint(
        "feeder_slide", slide_frame, balls[0].body_frame(), [1.0, 0.0, 0.0]))
    actuator = plant.AddJointActuator("feeder", feeder_joint)
    actuator.set_controller_gains(PdControllerGains(p=config.feeder_gains[0], d=config.feeder_gains[1]))
    floating = []
    for i, body in enumerate(balls[1:], start=2):
        floating.append(plant.AddJoint(QuaternionFloatingJoint(
            f"ball_{i}_floating", plant.world_frame(), body.body_frame(),
            config.angular_damping, config.translational_damping)))

    if heart is not None:
        files = heart.write_files()
        wall_props = _wall_properties(config, resolution_hint=1.5e-3)
        world = plant.world_body()
        plant.RegisterCollisionGeometry(world, RigidTransform(), Mesh(str(files["vtk"])),
                                        "heart_wall", wall_props)
        plant.RegisterVisualGeometry(world, RigidTransform(), Mesh(str(files["obj"])),
                                     "heart_wall", np.array([0.85, 0.35, 0.35, 0.35]))
        tgt = np.array(TARGET_CENTRE_RGBA)
        for side, ring in heart.rings.items():
            for k, p in enumerate(ring.p_HT):
                plant.RegisterVisualGeometry(world, RigidTransform(p), Sphere(TARGET_CENTRE_RADIUS),
                                             f"target_{side}_{k + 1}", tgt)
    if config.wall_plane:
        _add_wall_plane(plant, config)
    if config.sheath is not None:
        _add_sheath_cage(plant, config, p_WE, axis)
    plant.Finalize()

    # The balls' BodyIndex values are the geometry's 1..n (the statics engine publishes at them).
    assert [b.index() for b in balls] == geometry.ball_body_indices
    handles = ChainPlant(config, p_WE, axis, X_WF, geometry.ball_body_indices, plant, scene_graph, balls,
                         feeder_joint, feeder_instance)
    s0 = config.initial_inserted_length
    if not 0.0 <= s0 <= handles.max_inserted_length():
        raise UserInputError(
            f"initial inserted length {s0 * 1e3:.1f} mm is outside 0..{handles.max_inserted_length() * 1e3:.1f} mm "
            f"(ball 1 must stay in the sheath)")
    feeder_joint.set_default_translation(s0)
    # Start in contact (a few um of overlap, about the equilibrium penetration): a pair that
    # starts apart is not a contact constraint yet, and 2 N of attraction closes it in one step.
    gap = -4e-6
    for i, joint in enumerate(floating, start=1):
        p = X_WF.translation() + (s0 + i * (d + gap)) * axis
        joint.SetDefaultPose(RigidTransform(X_WF.rotation(), p))
    return handles


class PlantChainModel(ChainModel):
    """The chain as a MultibodyPlant (``engine: plant``): ``add_chain_plant``'s plant and scene
    graph, ``magnetic_wrench`` (the one place the plant feels the field: body poses in, spatial
    forces out to the plant), the walls' force on the tip ball from the plant's contact results
    (``tip_wall_force``, a ``WallForceOnBall``) and the ball centres (``ball_positions``).

    Attributes (besides ``ChainModel``'s):
        handles: the ChainPlant; plant, scene_graph, ball_bodies, feeder_joint,
            feeder_instance: its parts.
        wrench: the MagneticWrenchSystem.
    """

    engine = "plant"
    config_for = staticmethod(chain_plant_config)

    def __init__(self, handles: ChainPlant, wrench: MagneticWrenchSystem, tip_force: WallForceOnBall,
                 centres: BallCentres, snaps: ConstantVectorSource):
        self.geometry = self.handles = handles
        self.plant, self.scene_graph, self.ball_bodies = handles.plant, handles.scene_graph, handles.ball_bodies
        self.feeder_joint, self.feeder_instance = handles.feeder_joint, handles.feeder_instance
        self.system = self.plant
        self.time_step = handles.config.time_step
        self.wrench = wrench
        self._tip_force, self._centres, self._snaps = tip_force, centres, snaps

    @classmethod
    def add_to(cls, builder, scenario, config: ChainPlantConfig, coupling: FieldCoupling) -> "PlantChainModel":
        """The plant (``add_chain_plant``), its wrench, the tip's wall force and the ball centres."""
        cp = add_chain_plant(builder, config)
        plant = cp.plant
        wrench = builder.AddSystem(MagneticWrenchSystem(
            config.chain, cp.ball_body_indices, field_source=coupling.field_source, base_direction_W=cp.sheath_axis_W,
            port_magnets=list(coupling.port_magnets), model=coupling.model))
        wrench.set_name("magnetic_wrench")
        builder.Connect(plant.get_body_poses_output_port(), wrench.get_body_poses_input_port())
        builder.Connect(wrench.get_spatial_forces_output_port(), plant.get_applied_spatial_force_input_port())
        tip_force = builder.AddSystem(WallForceOnBall(plant, cp.scene_graph.model_inspector(),
                                                      cp.ball_body_indices[-1]))
        tip_force.set_name("tip_wall_force")
        builder.Connect(plant.get_contact_results_output_port(), tip_force.get_contact_results_input_port())
        builder.Connect(plant.get_body_poses_output_port(), tip_force.get_body_poses_input_port())
        centres = builder.AddSystem(BallCentres(cp.ball_body_indices))
        centres.set_name("ball_positions")
        builder.Connect(plant.get_body_poses_output_port(), centres.get_body_poses_input_port())
        snaps = builder.AddSystem(ConstantVectorSource([0.0]))  # the plant integrates: it has no snap-throughs
        snaps.set_name("snap_throughs")
        return cls(cp, wrench, tip_force, centres, snaps)

    def get_magnet_states_input_port(self):
        return self.wrench.get_magnet_states_input_port()

    def get_feeder_state_input_port(self):
        return self.plant.get_desired_state_input_port(self.feeder_instance)

    def get_body_poses_output_port(self):
        return self.plant.get_body_poses_output_port()

    def get_ball_positions_output_port(self):
        return self._centres.get_output_port()

    def get_tip_wall_force_output_port(self):
        return self._tip_force.get_wall_force_output_port()

    def get_snap_throughs_output_port(self):
        return self._snaps.get_output_port()

    def add_geometry(self, builder):
        return self.scene_graph  # the plant registered its geometry (and the heart's, the sheath's) there

    def add_pin(self, builder, point: np.ndarray, stiffness: float):
        """The ``ForceSensorPin`` on the tip ball, into the plant's generalized forces."""

        pin = builder.AddSystem(ForceSensorPin(self.plant, self.ball_bodies[-1], point, stiffness))
        pin.set_name("force_sensor_pin")
        builder.Connect(self.get_body_poses_output_port(), pin.get_body_poses_input_port())
        builder.Connect(pin.get_generalized_force_output_port(), self.plant.get_applied_generalized_force_input_port())
        return pin

    def ball_positions(self, context) -> np.ndarray:
        return self.handles.ball_positions(subsystem_context(self.plant, context))

    def is_finite(self, context) -> bool:
        plant = self.plant
        return bool(np.all(np.isfinite(plant.GetPositions(context))) and np.all(np.isfinite(plant.GetVelocities(context))))

    def non_finite_part(self, context) -> str:
        for i, body in enumerate(self.ball_bodies):
            X = self.plant.EvalBodyPoseInWorld(context, body).GetAsMatrix34()
            V = self.plant.EvalBodySpatialVelocityInWorld(context, body).get_coeffs()
            if not (np.all(np.isfinite(X)) and np.all(np.isfinite(V))):
                part = "position" if not np.all(np.isfinite(X)) else "velocity"
                return f"ball {i + 1} ({part})"
        return "the feeder slide"
