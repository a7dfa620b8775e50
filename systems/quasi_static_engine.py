"""The quasi-static engine: the chain held at its equilibrium, one warm-started solve per period.

Where the MultibodyPlant integrates heavily damped dynamics at 1 ms steps until the chain
settles, ``QuasiStaticEngine`` solves for the settled shape directly (``optimization.statics``
with the atrium's wall and the sheath as constraints, ``optimization.wall_constraints``): a
discrete update every ``period`` (the scenario's ``statics_period``, 50 ms by default) finds the equilibrium for the current magnet
states and insertion, warm-started from the last one. When the inputs moved far since the last
update (a magnet turned more than ``max_angle_step`` or the feeder moved more than
``max_insertion_step``) the update walks there in smaller steps (continuation), as the real chain
follows a slowly turning magnet. A step whose equilibrium jumps by more than ``snap_distance``
is refined; a jump that survives a 16 times finer step is a snap-through (the equilibrium
branch ended), counted on the ``snap_throughs`` output and listed in ``events``.

Each solve starts from the linear extrapolation of the last step (a secant predictor), with the
last solution's multipliers in its quadratic model; if it fails, from the last equilibrium, then
once from the straight chain. The solves run with BLAS on one thread (``_one_blas_thread``).

The engine assumes what the statics assume: frictionless contacts (ball-ball, wall, sheath) and
no dynamics. The plant stays the reference and the dynamics engine (``engine: plant``).

``StaticsChainModel`` is the engine behind the station's chain-model interface
(``chain_model.ChainModel``, the plant's is ``chain_plant.PlantChainModel``): the same ports
(``body_poses`` indexed by the plant's BodyIndex values, ``ball_positions``, ``tip_wall_force``,
``snap_throughs``), and ``EngineGeometry`` draws the balls in Meshcat through a SceneGraph of
their own.

``QuasiStaticEngine`` lives in ``engine_system``, ``EngineGeometry`` in ``engine_geometry``, the
ball frames and ``EngineEvent`` in ``engine_frames``: all re-exported here.
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.atrium_sdf import atrium_sdf
from ballchain.optimization.blas_threads import one_blas_thread as _one_blas_thread  # noqa: F401
from ballchain.optimization.wall_constraints import PlaneSDF, SheathGeometry
from ballchain.systems.chain_plant import chain_plant_config
from ballchain.systems.chain_model import (
    ChainGeometry,
    ChainModel,
    FieldCoupling,
    SnapThrough,
    StaticsEngineStats,
    chain_geometry,
    subsystem_context,
)
from ballchain.systems.engine_frames import (  # noqa: F401 (re-exported)
    EngineEvent,
    _norms,
    ball_frames,
    rotation_with_x_along,
    rotations_with_x_along,
)
from ballchain.systems.engine_geometry import EngineGeometry
from ballchain.systems.engine_system import QuasiStaticEngine
from ballchain.systems.world_apply import (apply_world_statics, magnet_errors, monitor_offsets, perturbed_exit,
                                          perturbed_wall)


class StaticsChainModel(ChainModel):
    """The chain as the ``QuasiStaticEngine`` (``engine: statics``): the wall is the atrium's SDF
    or a flat ``wall_plane``, the sheath its bore; drawn by ``EngineGeometry``.

    Attributes (besides ``ChainModel``'s):
        engine_system: the QuasiStaticEngine (also ``system``).
        sheath: its SheathGeometry, or None.
    """

    engine = "statics"
    config_for = staticmethod(chain_plant_config)

    def __init__(self, geometry: ChainGeometry, engine: QuasiStaticEngine, sheath: SheathGeometry | None):
        self.geometry = geometry
        self.system = self.engine_system = engine
        self.sheath = sheath
        self.time_step = self.move_period = engine.period

    @classmethod
    def add_to(cls, builder, scenario, config, coupling: FieldCoupling) -> StaticsChainModel:
        """The engine, solving every ``scenario.statics_period`` (warmed up here, not in the timed run),
        in the scenario's world (``world_apply``: nothing changes without one)."""

        config, coupling, world = apply_world_statics(scenario, config, coupling)
        geometry = chain_geometry(config)
        sdf = None
        if config.heart is not None:

            sdf = atrium_sdf(config.heart)
        elif config.wall_plane:
            w = np.asarray(config.wall_plane, float)
            sdf = PlaneSDF(w[:3], w[3:])
        p_WE = geometry.p_WE
        if world is not None:  # the world's wall and sheath exit
            sdf, p_WE = perturbed_wall(sdf, world, p_WE), perturbed_exit(p_WE, geometry.sheath_axis_W, world)
        sheath = None
        if config.sheath is not None:
            sheath = SheathGeometry(p_WE, geometry.sheath_axis_W, 0.5 * config.sheath.inner_diameter,
                                    0.5 * config.sheath.wall_thickness)
        engine = builder.AddSystem(QuasiStaticEngine(
            config.chain, geometry.ball_body_indices, p_WE, geometry.sheath_axis_W, sdf=sdf, sheath=sheath,
            field_source=coupling.field_source, port_magnets=coupling.port_magnets, model=coupling.model,
            gravity=config.gravity, period=scenario.statics_period,
            initial_inserted_length=config.initial_inserted_length, wall_motion=scenario.wall_motion.law()))
        engine.set_name("quasi_static_engine")
        engine.warm_up()  # compiled kernels and solvers loaded at build time, not in the timed run
        model = cls(geometry, engine, sheath)
        model.world, model.world_exit = world, p_WE  # for the monitor (``anatomy_offsets``)
        if world is not None and coupling.port_magnets:  # the units' magnets where the world has them
            errors = builder.AddSystem(magnet_errors(world, len(coupling.port_magnets)))
            builder.Connect(errors.get_output_port(), engine.get_magnet_states_input_port())
            model.magnet_states_input = errors.get_input_port()
        return model

    def get_magnet_states_input_port(self):
        port = getattr(self, "magnet_states_input", None)  # the world's magnet errors (``add_to``), if any
        return port if port is not None else self.engine_system.get_magnet_states_input_port()

    def get_feeder_state_input_port(self):
        return self.engine_system.get_feeder_state_input_port()

    def get_body_poses_output_port(self):
        return self.engine_system.get_body_poses_output_port()

    def get_ball_positions_output_port(self):
        return self.engine_system.get_ball_positions_output_port()

    def get_tip_wall_force_output_port(self):
        return self.engine_system.get_tip_wall_force_output_port()

    def get_snap_throughs_output_port(self):
        return self.engine_system.get_snap_throughs_output_port()

    def get_anatomy_offsets_output_port(self):
        return self.engine_system.get_anatomy_offsets_output_port()

    def add_geometry(self, builder):
        """A SceneGraph of the engine's own, with ``engine_geometry`` posing the balls in it."""
        from pydrake.geometry import SceneGraph

        scene_graph = builder.AddSystem(SceneGraph())
        scene_graph.set_name("scene_graph")
        geometry = builder.AddSystem(EngineGeometry(
            scene_graph, self.ball_body_indices, 0.5 * self.config.chain.ball_diameter, self.config.heart,
            self.sheath, self.sheath_length() if self.config.sheath is not None else 0.0,
            moving_anatomy=self.engine_system.wall_motion is not None))
        geometry.set_name("engine_geometry")
        builder.Connect(self.get_body_poses_output_port(), geometry.get_body_poses_input_port())
        if self.engine_system.wall_motion is not None:
            builder.Connect(self.engine_system.get_anatomy_offsets_output_port(),
                            geometry.get_anatomy_offsets_input_port())
        builder.Connect(geometry.get_geometry_pose_output_port(), scene_graph.get_source_pose_port(geometry.source_id))
        return scene_graph

    def ball_positions(self, context) -> np.ndarray:
        return self.engine_system.ball_positions(subsystem_context(self.engine_system, context))

    def anatomy_offsets(self, context) -> tuple[np.ndarray, np.ndarray] | None:
        engine = self.engine_system
        motion = None
        if engine.wall_motion is not None:
            t = engine.wall_time(subsystem_context(engine, context))
            motion = engine.wall_motion.heart_offset(t), engine.wall_motion.wall_offset(t)
        world = getattr(self, "world", None)
        if world is None:
            return motion
        # The world's sheath and wall (``world_apply``): the wall's offset per ball (its scale).
        return monitor_offsets(world, self.p_WE, self.world_exit, self.ball_positions(context), motion)

    def is_finite(self, context) -> bool:
        # Checked every step by the watchdog: the array's own ``all`` (not np.all's wrapper).
        return bool(np.isfinite(self.engine_system.state_vector(context)).all())

    def non_finite_part(self, context) -> str:
        bad = np.flatnonzero(~np.all(np.isfinite(self.ball_positions(context)), axis=1))
        return f"ball {bad[0] + 1} (position)" if len(bad) else "the engine's state"

    @property
    def failure(self) -> str | None:
        return self.engine_system.failure

    def clear_failure(self) -> None:
        self.engine_system.failure = None

    @property
    def events(self) -> list[EngineEvent]:
        return self.engine_system.events

    def solver_stats(self) -> StaticsEngineStats:
        engine = self.engine_system
        solves = np.array(engine.solve_times)
        return StaticsEngineStats(
            solves=int(len(solves)),
            median_solve_ms=round(float(np.median(solves)) * 1e3, 3) if len(solves) else None,
            max_solve_ms=round(float(solves.max()) * 1e3, 3) if len(solves) else None,
            median_iterations=float(np.median(engine.iterations)) if engine.iterations else None,
            snap_throughs=[SnapThrough(t_s=round(e.time, 4), jump_mm=round(e.jump * 1e3, 3), detail=e.detail)
                           for e in engine.events if e.kind == "snap-through"],
            failures=[e.detail for e in engine.events if e.kind == "solve failed"])
