"""The chain model: the ball chain's ``DeviceModel``, one interface for its two engines.

A ``ChainModel`` (``device_model.DeviceModel`` of ``device: ball_chain``) is the ball chain as Drake systems in a station diagram, with its field coupling
inside: the MultibodyPlant with its ``MagneticWrenchSystem`` (``chain_plant.PlantChainModel``,
``engine: plant``), or the ``QuasiStaticEngine`` (``quasi_static_engine.StaticsChainModel``,
``engine: statics``). Both have

========================  =======  ===================================================================
port                      size     what
========================  =======  ===================================================================
``magnet_states`` (in)    6 k      per port magnet its centre p_WM [m] and dipole direction (k >= 1)
``feeder_state`` (in)     2        the feeder slide's desired state (s [m], ds/dt [m/s])
``body_poses`` (out)      list     RigidTransform per BodyIndex (balls at ``ball_body_indices``)
``ball_positions`` (out)  3 n      the ball centres [m]
``tip_wall_force`` (out)  6        the wall's push on the tip ball f_W [N], then where it acts [m]
                                   (the tip's centre when nothing pushes)
``snap_throughs`` (out)   1        snap-throughs so far (the plant has none: 0)
``anatomy_offsets`` (out) 6        (statics with ``wall_motion`` only) the heart's and the wall's
                                   offsets [m]; None for a still anatomy
========================  =======  ===================================================================

and the same geometry (``ChainGeometry``: the sheath exit, the insertion axis, the feeder frame,
the balls' BodyIndex values 1..n), the same registration for Meshcat (``add_geometry``: the
SceneGraph the MeshcatVisualizer draws), and the same reading of their state: ``system`` (the
system whose context holds the chain), ``ball_positions``, ``is_finite``, ``failure``,
``events`` and ``solver_stats``.
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import LeafSystem

from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.field_sources import FieldSource, rotation_with_z_along
from ballchain.drake_models.params import CylinderMagnet, SphereMagnet
from ballchain.systems.device_model import DeviceModel
from ballchain.systems.meshcat_view import frame_scene

if TYPE_CHECKING:
    from ballchain.systems.chain_plant import ChainPlantConfig


def subsystem_context(system, context):
    """``system``'s own context from either the diagram's root context (what a Simulator holds,
    ``RunOutcome.context``) or ``system``'s own context (returned as it is)."""
    try:
        system.ValidateContext(context)
    except RuntimeError:
        return system.GetMyContextFromRoot(context)
    return context


@dataclass
class SnapThrough:
    """A snap-through of the quasi-static engine (its chain jumped to another equilibrium branch).

    Attributes:
        t_s: when [s]; jump_mm: the largest ball displacement over the step [mm]; detail: its text.
    """

    t_s: float
    jump_mm: float
    detail: str


@dataclass
class StaticsEngineStats:
    """The quasi-static engine's solves over a run (``engine: statics`` only).

    Attributes:
        solves: statics solves in the run.
        median_solve_ms, max_solve_ms: their wall time [ms] (None without a solve).
        median_iterations: Newton iterations per solve, median (None without a solve).
        snap_throughs: the snap-throughs, in time order.
        failures: the messages of the solves that failed.
    """

    solves: int
    median_solve_ms: float | None
    max_solve_ms: float | None
    median_iterations: float | None
    snap_throughs: list[SnapThrough]
    failures: list[str]


@dataclass
class ChainGeometry:
    """Where the chain sits, the same for both engines (``chain_geometry``).

    Attributes:
        config: the chain plant's configuration (the chain, the heart, the sheath, ...).
        p_WE: (3,) the sheath exit [m].
        sheath_axis_W: (3,) the unit insertion direction.
        X_WF: the feeder slide's fixed frame: ball 1 is at X_WF * (s, 0, 0).
        ball_body_indices: the balls' BodyIndex values (1..n, the plant's).
    """

    config: ChainPlantConfig
    p_WE: np.ndarray
    sheath_axis_W: np.ndarray
    X_WF: RigidTransform
    ball_body_indices: list

    @property
    def n_balls(self) -> int:
        return len(self.ball_body_indices)

    def max_inserted_length(self) -> float:
        """Largest inserted length that keeps ball 1 inside the sheath [m]."""
        return (self.n_balls - 1.0) * self.config.chain.ball_diameter

    def in_sheath(self, p_W: np.ndarray) -> np.ndarray:
        """Whether points (k, 3) lie inside the sheath tube (within its outer radius)."""
        sheath = self.config.sheath
        if sheath is None:
            return np.zeros(len(p_W), bool)
        rel = np.asarray(p_W) - self.p_WE
        along = rel @ self.sheath_axis_W
        radial = np.linalg.norm(rel - along[:, None] * self.sheath_axis_W, axis=1)
        return (along <= 0.5 * self.config.chain.ball_diameter) & (along >= -self.sheath_length()) & (
            radial <= 0.5 * sheath.inner_diameter + sheath.wall_thickness)

    def sheath_length(self) -> float:
        c = self.config
        return c.chain.n_balls * c.chain.ball_diameter + (c.sheath.extra_length if c.sheath else 0.0)


def chain_geometry(config: ChainPlantConfig) -> ChainGeometry:
    """The chain's geometry: the sheath exit and axis from the heart (or ``p_WE``,
    ``sheath_axis_W`` in free space), the feeder frame F (x along the axis, ball 1's centre at
    p_WE - (n - 1/2) d u for s = 0) and the BodyIndex values 1..n of the balls."""
    heart = config.heart
    if heart is not None:
        p_WE, axis = heart.p_HE.copy(), heart.sheath_axis_H.copy()
    else:
        p_WE = np.asarray(config.p_WE, float)
        axis = np.asarray(config.sheath_axis_W, float)
        axis = axis / np.linalg.norm(axis)
    n, d = config.chain.n_balls, config.chain.ball_diameter
    R_WF = RotationMatrix(rotation_with_z_along(axis)[:, [2, 0, 1]])  # columns: x = axis
    X_WF = RigidTransform(R_WF, p_WE - (n - 0.5) * d * axis)
    return ChainGeometry(config, p_WE, axis, X_WF, [BodyIndex(i + 1) for i in range(n)])


@dataclass
class FieldCoupling:
    """What the chain feels besides its own dipoles: the fixed field and the port magnets.

    Attributes:
        field_source: the fixed external FieldSource, or None.
        port_magnets: the magnets whose states come in on ``magnet_states`` (one per unit).
        model: "dipole" or "exact", the port magnets' field model.
    """

    field_source: FieldSource | None
    port_magnets: list[CylinderMagnet | SphereMagnet]
    model: str = "dipole"


class BallCentres(LeafSystem):
    """The ball centres (3 n) [m] from a ``body_poses`` list (the plant's ``ball_positions``).

    Input ports: body_poses (abstract list[RigidTransform]). Output ports: ball_positions (3 n).
    """

    def __init__(self, ball_body_indices):
        super().__init__()
        self._indices = [int(i) for i in ball_body_indices]
        self._poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        self.DeclareVectorOutputPort("ball_positions", 3 * len(self._indices), self._calc,
                                     prerequisites_of_calc={self.all_input_ports_ticket()})

    def get_body_poses_input_port(self):
        return self._poses

    def _calc(self, context, output):
        poses = self._poses.Eval(context)
        output.SetFromVector(np.concatenate([poses[i].translation() for i in self._indices]))


class ChainModel(DeviceModel):
    """The ball chain's DeviceModel in a station diagram: the interface both engines implement.

    Its bodies are the balls, its tip the tip ball.

    Built by a subclass's ``add_to`` (``add_to_station``: the chain's configuration from the
    scenario, then ``add_to``); the station reads the chain only through this interface.

    Attributes:
        geometry: the chain's geometry (its attributes are also this model's: ``config``,
            ``p_WE``, ``sheath_axis_W``, ``X_WF``, ``ball_body_indices``, ...).
        system: the Drake system whose context holds the chain's state (the plant, the engine).
        time_step: the chain's step [s] (the plant's step, or the engine's period).
        move_period: the chain moves only at updates this far apart [s] (the engine's period),
            or 0 when it moves at every step (the plant): checking more often finds nothing new.
            A model with a period reports an update that leaves its state non-finite through
            ``failure`` at once: the watchdog reads its state only at its checks.
    """

    device = "ball_chain"
    engine: str  # the scenario's ``engine`` this model is
    geometry: ChainGeometry
    system: LeafSystem
    time_step: float
    move_period: float = 0.0
    diagram_name = "chain_in_heart"

    @classmethod
    @abstractmethod
    def add_to(cls, builder, scenario, config: ChainPlantConfig, coupling: FieldCoupling) -> ChainModel:
        """Add the chain and its field coupling to ``builder`` (the ``scenario``'s engine settings)."""

    @staticmethod
    @abstractmethod
    def config_for(scenario, heart) -> ChainPlantConfig:
        """The chain's configuration from the scenario (``chain_plant.chain_plant_config``)."""

    @classmethod
    def add_to_station(cls, builder, scenario, heart, coupling: FieldCoupling, params=None) -> ChainModel:
        """The chain's configuration (``config_for``), its insertion checked against the sheath,
        then ``add_to``.

        Raises:
            UserInputError: an insertion length outside what the sheath holds.
        """
        config = cls.config_for(scenario, heart)
        s_max = chain_geometry(config).max_inserted_length()
        ins = scenario.insertion
        for what, s in (("initial", ins.initial), ("final", ins.final)):
            if not 0.0 <= s <= s_max:
                raise UserInputError(
                    f"insertion.{what} = {s * 1e3:.1f} mm is outside 0..{s_max * 1e3:.1f} mm for "
                    f"{config.chain.n_balls} balls (ball 1 must stay in the sheath)")
        return cls.add_to(builder, scenario, config, coupling)

    # --- the geometry --------------------------------------------------------------------------
    @property
    def config(self) -> ChainPlantConfig:
        return self.geometry.config

    @property
    def p_WE(self) -> np.ndarray:
        return self.geometry.p_WE

    @property
    def sheath_axis_W(self) -> np.ndarray:
        return self.geometry.sheath_axis_W

    @property
    def X_WF(self) -> RigidTransform:
        return self.geometry.X_WF

    @property
    def ball_body_indices(self) -> list:
        return self.geometry.ball_body_indices

    @property
    def n_balls(self) -> int:
        return self.geometry.n_balls

    def max_inserted_length(self) -> float:
        """Largest inserted length that keeps ball 1 inside the sheath [m]."""
        return self.geometry.max_inserted_length()

    def in_sheath(self, p_W: np.ndarray) -> np.ndarray:
        """Whether points (k, 3) [m] lie inside the sheath tube (within its outer radius)."""
        return self.geometry.in_sheath(p_W)

    def sheath_length(self) -> float:
        """The sheath's length [m]: the chain's length and the sheath's extra length."""
        return self.geometry.sheath_length()

    # --- the geometry as a device ---------------------------------------------------------------
    @property
    def body_indices(self) -> list:
        return self.geometry.ball_body_indices

    @property
    def tip_radius(self) -> float:
        return 0.5 * self.config.chain.ball_diameter

    @property
    def start_point(self) -> np.ndarray:
        """The sheath exit in the heart; ball 1's initial centre in free space (the canonical
        statics origin)."""
        if self.config.heart is not None:
            return self.p_WE
        return self.X_WF.multiply(np.array([self.config.initial_inserted_length, 0.0, 0.0]))

    @property
    def length(self) -> float:
        return self.config.chain.length

    @property
    def initial_inserted_length(self) -> float:
        return self.config.initial_inserted_length

    def fed_chain(self):
        """The chain the feeder pushes (``params.BallChain``)."""
        return self.config.chain

    def neighbour_gaps(self, p_W: np.ndarray) -> np.ndarray:
        """The gaps between neighbouring balls' surfaces [m] (negative: overlap)."""
        return np.linalg.norm(np.diff(p_W, axis=0), axis=1) - self.config.chain.ball_diameter

    # --- ports ----------------------------------------------------------------------------------
    @abstractmethod
    def get_magnet_states_input_port(self):
        """``magnet_states`` (6 k), or None without port magnets."""

    @abstractmethod
    def get_feeder_state_input_port(self):
        """The slide's desired state (s, ds/dt) (2)."""

    @abstractmethod
    def get_body_poses_output_port(self):
        """``body_poses``: abstract list[RigidTransform] indexed by BodyIndex."""

    @abstractmethod
    def get_ball_positions_output_port(self):
        """``ball_positions`` (3 n) [m]."""

    @abstractmethod
    def get_tip_wall_force_output_port(self):
        """``tip_wall_force`` (6): f_W [N] on the tip ball, then where it acts [m]."""

    @abstractmethod
    def get_snap_throughs_output_port(self):
        """``snap_throughs`` (1): snap-throughs so far."""

    @abstractmethod
    def add_geometry(self, builder):
        """The SceneGraph the chain's (and the heart's, the sheath's) illustration geometry is
        registered with, for a MeshcatVisualizer (added to ``builder`` when needed)."""

    def add_visualizer(self, builder, meshcat, scenario, heart, targets):
        """``meshcat_visualizer`` (``scenario.visualization``) on ``add_geometry``'s SceneGraph,
        the camera on the atrium (or the free chain's reach)."""
        vis = scenario.visualization
        params = MeshcatVisualizerParams(publish_period=vis.publish_period, default_color=vis.default_illustration_color,
                                         delete_on_initialization_event=vis.delete_on_initialization_event,
                                         enable_alpha_slider=vis.enable_alpha_sliders)
        visualizer = MeshcatVisualizer.AddToBuilder(builder, self.add_geometry(builder), meshcat, params)
        visualizer.set_name("meshcat_visualizer")
        frame_scene(meshcat, heart, self.config.chain.length, self.p_WE)
        return visualizer

    def add_pin(self, builder, point: np.ndarray, stiffness: float):
        """A force-sensor pin on the tip ball (``force_sensor_pin``): only a model with forces can
        hold one (the scenario's validation refuses a pin on the others)."""
        raise TypeError(f"the {self.engine!r} chain model cannot hold a force-sensor pin")

    # --- the state ------------------------------------------------------------------------------
    @abstractmethod
    def ball_positions(self, context) -> np.ndarray:
        """Ball centres (n, 3) [m] from ``system``'s context or the diagram's root context."""

    def body_positions(self, context) -> np.ndarray:
        """The bodies' centres (n, 3) [m], the tip last: the ball centres."""
        return self.ball_positions(context)

    @abstractmethod
    def is_finite(self, context) -> bool:
        """Whether the chain's state in ``system``'s context is finite."""

    @abstractmethod
    def non_finite_part(self, context) -> str:
        """Which part of the state is not finite (for a failure message)."""

    def solver_stats(self) -> StaticsEngineStats | None:
        """The statics solves of the run (None: no solver)."""
        return None
