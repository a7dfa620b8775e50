"""``QuasiStaticEngine``: the chain held at its equilibrium, one warm-started solve per period
(``quasi_static_engine`` describes it, re-exports it and holds its ``StaticsChainModel``).
"""

from __future__ import annotations

import time
from dataclasses import replace
from math import ceil, isfinite

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from ballchain.infrastructure.arg_checks import as_vector, require_bool, require_type
from ballchain.infrastructure.errors import UserInputError, caused_by_interrupt
from ballchain.drake_models.params import BallChain
from ballchain.drake_models.wall_motion import WallMotion
from ballchain.optimization.blas_threads import one_blas_thread as _one_blas_thread
from ballchain.optimization.compiled_model import HeartAnswer, HeartSolve
from ballchain.optimization.statics import ChainStatics, StaticsError, StaticsResult, straight_chain
from ballchain.optimization.wall_constraints import HeartConstraints, SheathGeometry, base_ball, base_rotation
from ballchain.systems.engine_frames import EngineEvent, _norms, ball_frames
from ballchain.systems.engine_kernels import interpolate_magnets, magnet_moves
from ballchain.systems.magnetic_wrench import external_field_source


class QuasiStaticEngine(LeafSystem):
    """The chain at its equilibrium for the current magnet dipoles and insertion.

    Input ports:
        feeder_desired_state: (2) the feeder slide's desired state (s [m], ds/dt [m/s]), as the
            plant's feeder input (only s is used: the chain follows the feeder quasi-statically).
        magnet_states: (6 k, only with port magnets) centre p_WM [m] and dipole direction per
            magnet, as ``MagneticWrenchSystem``'s.

    Output ports:
        body_poses: abstract list[RigidTransform] indexed by BodyIndex (``ball_body_indices``;
            the others identity): each ball's centre, x along its dipole.
        tip_wall_force: (6) the wall's push on the tip ball f_W [N] and its contact point [m]
            (the tip's centre minus a radius along the push; the centre when there is none).
        ball_positions: (3 n) the ball centres [m].
        snap_throughs: (1) snap-throughs so far.
        anatomy_offsets: (6, only with ``wall_motion``) where the last solve placed the heart and
            the sheath (``heart_offset``) and the wall (``wall_offset``) [m]: the chain's state is
            held between updates, and what is drawn or tested against it must be the anatomy
            it was solved for.

    State (discrete, updated every ``period``): ball centres (3 n), dipoles (3 n), the tip's
    wall force and contact point (6), the insertion and magnet states of the last solve, the
    snap-through and failure counts, the last step's change of the equilibrium (6 n) and its
    size (1) for the next step's predictor.

    Args:
        chain: the chain (sleeve included when ``chain.sleeve``).
        ball_body_indices: the BodyIndex values the balls' poses are published at.
        p_WE: (3,) sheath exit (free space: where ball 1's slide puts it at s = 0 plus
            (n - 1/2) d, see ``chain_plant``) [m].
        axis_W: (3,) insertion direction.
        sdf: the wall (``atrium_sdf.AtriumSDF`` or ``wall_constraints.PlaneSDF``), or None.
        sheath: SheathGeometry, or None (then only ball 1 is held, at its slide's position).
        field_source: the fixed external FieldSource, or None.
        port_magnets: the magnets on ``magnet_states``.
        model: "dipole" or "exact" (port magnets).
        gravity: gravity along -z.
        period: [s].
        initial_inserted_length: s at t = 0 [m].
        max_angle_step: largest magnet turn per continuation step [rad].
        max_insertion_step: largest feeder move per continuation step [m].
        snap_distance: a ball moving further in one step marks a possible snap-through [m].
        compiled: solve with the compiled statics (``ChainStatics(compiled=True)``, default);
            False: the Python solver, the reference.
        wall_motion: a ``drake_models.wall_motion.WallMotion``, or None (the anatomy still). Each
            update places the heart for its time t (a moving constraint): the sheath's exit and
            the sheath by ``heart_offset(t)`` (respiration), the wall by ``wall_offset(t)``
            (respiration and the heart beat); the field sources stay. The continuation walks
            the placement from the last update's time with the other inputs, at most
            ``max_insertion_step`` of travel per step. A still motion (both amplitudes 0) is
            None: the engine is then today's, state for state.
    """

    def __init__(self, chain: BallChain, ball_body_indices, p_WE, axis_W, sdf=None,
                 sheath: SheathGeometry | None = None, field_source=None, port_magnets=(), model: str = "dipole",
                 gravity: bool = True, period: float = 0.02, initial_inserted_length: float = 0.0,
                 max_angle_step: float = np.radians(1.0), max_insertion_step: float = 1e-3,
                 snap_distance: float = 1.5e-3, compiled: bool = True, wall_motion=None):
        super().__init__()
        require_type(chain, BallChain, "QuasiStaticEngine chain", "a BallChain")
        require_bool(compiled, "QuasiStaticEngine compiled")
        ball_body_indices = [int(i) for i in ball_body_indices]  # also for replica(): an iterator is read once
        # What replica() rebuilds the engine from.
        self._arguments = dict(
            chain=chain, ball_body_indices=ball_body_indices, p_WE=p_WE, axis_W=axis_W, sdf=sdf, sheath=sheath,
            field_source=field_source, port_magnets=port_magnets, model=model, gravity=gravity, period=period,
            initial_inserted_length=initial_inserted_length, max_angle_step=max_angle_step,
            max_insertion_step=max_insertion_step, snap_distance=snap_distance, compiled=compiled,
            wall_motion=wall_motion)
        if wall_motion is not None:

            require_type(wall_motion, WallMotion, "QuasiStaticEngine wall_motion", "a WallMotion or None")
        self.wall_motion = None if wall_motion is None or wall_motion.still else wall_motion
        self.compiled = compiled
        as_vector(p_WE, "QuasiStaticEngine p_WE", unit="m")
        as_vector(axis_W, "QuasiStaticEngine axis_W", nonzero=True)
        if not period > 0:
            raise UserInputError(f"QuasiStaticEngine: period must be > 0 s, got {period}")
        self.chain = chain
        n = chain.n_balls
        self._n = n
        self._d = chain.ball_diameter
        self._indices = [int(i) for i in ball_body_indices]
        self._p_WE = np.asarray(p_WE, float)
        axis = np.asarray(axis_W, float)
        self._axis = axis / np.linalg.norm(axis)
        self._R_WB = base_rotation(self._axis)
        self._sdf = sdf
        self._sheath = sheath
        self._field_source = field_source
        self._port_magnets = list(port_magnets)
        self._port_moments = np.array([m.dipole_moment for m in self._port_magnets])
        self._port_radii = np.array([m.bounding_radius for m in self._port_magnets])
        self._model = model
        self._gravity = gravity
        self.period = period
        self._s0 = float(initial_inserted_length)
        self.max_angle_step = max_angle_step
        self.max_insertion_step = max_insertion_step
        self.snap_distance = snap_distance
        self._solvers: dict[int, ChainStatics] = {}
        self._last_constraints = None  # (s, (k, HeartConstraints)) of the last solve
        # The last solution's multipliers per sub-chain size: a warm start for the next solve's
        # quadratic model only (the solution does not depend on them).
        self._multipliers: dict[int, dict] = {}
        # Stationarity tolerance on the scaled energy gradient: 1e-6 instead of the statics'
        # 1e-8 saves one Newton iteration of ~3 per warm solve; the shape moves by ~1e-6 rad.
        self.tolerance = 1e-6
        # The last ball in the bore is free (its dipole turns, as in the plant); the one behind
        # it is held (wall_constraints.base_ball).
        self.free_in_bore = 1
        self.events: list[EngineEvent] = []
        self.failure: str | None = None  # the first failed update (the monitor stops the run)
        self.solve_times: list[float] = []  # time of every statics solve [s], by ``clock``
        self.clock = time.perf_counter  # wall time; a benchmark may set time.process_time
        self.iterations: list[int] = []
        self.last_result = None  # the last solve's StaticsResult (wall contacts, multipliers)
        self._lean: dict[int, HeartSolve] = {}  # per sub-chain size: the compiled solve's short path
        self._warm = None  # the warm-up's (field source, s, equilibrium, solve times, iterations)
        km = 6 * len(self._port_magnets)
        self._slices = {}
        offset = 0
        for name, size in (("p", 3 * n), ("m", 3 * n), ("tip", 6), ("s", 1), ("magnets", km), ("snaps", 1),
                           ("failures", 1), ("dp", 3 * n), ("dm", 3 * n), ("u", 1),
                           ("wall_t", 0 if self.wall_motion is None else 1)):  # the wall's time of the last solve
            self._slices[name] = slice(offset, offset + size)
            offset += size
        x0 = np.zeros(offset)
        p0, m0 = self.straight(self._s0)
        x0[self._slices["p"]] = p0.ravel()
        x0[self._slices["m"]] = m0.ravel()
        x0[self._slices["tip"]][3:] = p0[-1]
        x0[self._slices["s"]] = self._s0
        self._state_index = self.DeclareDiscreteState(BasicVector(x0))
        self._declare_ports(n, km)
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)

    def _declare_ports(self, n: int, km: int) -> None:
        self._feeder_port = self.DeclareVectorInputPort("feeder_desired_state", 2)
        self._magnet_port = self.DeclareVectorInputPort("magnet_states", km) if km else None
        size = max(self._indices) + 1
        # The published list: identities (bodies that are not balls) with the balls' poses set per
        # update; balls on consecutive BodyIndex values are set as one slice.
        self._poses = [RigidTransform() for _ in range(size)]
        first = self._indices[0]
        self._ball_slice = (slice(first, first + n) if self._indices == list(range(first, first + n)) else None)
        self._body_poses_port = self.DeclareAbstractOutputPort(
            "body_poses", lambda: AbstractValue.Make(list(self._poses)), self._calc_body_poses,
            prerequisites_of_calc={self.xd_ticket()})
        self._tip_force_port = self.DeclareVectorOutputPort(
            "tip_wall_force", 6, self._calc_tip_force, prerequisites_of_calc={self.xd_ticket()})
        self._positions_port = self.DeclareVectorOutputPort(
            "ball_positions", 3 * n, self._calc_positions, prerequisites_of_calc={self.xd_ticket()})
        self._snaps_port = self.DeclareVectorOutputPort(
            "snap_throughs", 1, self._calc_snaps, prerequisites_of_calc={self.xd_ticket()})
        self._anatomy_port = None
        if self.wall_motion is not None:
            self._anatomy_port = self.DeclareVectorOutputPort(
                "anatomy_offsets", 6, self._calc_anatomy_offsets, prerequisites_of_calc={self.xd_ticket()})

    # --- ports ----------------------------------------------------------------------------------
    def replica(self, **changes) -> QuasiStaticEngine:
        """A new engine with this one's arguments, except ``changes`` (e.g. ``compiled=False``)."""
        return QuasiStaticEngine(**{**self._arguments, **changes})

    def warm_up(self) -> None:
        """One untimed solve (the initial insertion, the fixed field only): loads the compiled
        kernels' caches and the solvers before a timed run. Leaves no trace in the reports; its
        answer is kept for the initialisation (``_initial_equilibrium``)."""
        n_solves, events = len(self.solve_times), list(self.events)
        self._warm = None
        try:
            with _one_blas_thread():
                answer = self._equilibrium(self._s0, None)
            # Kept for the initialisation, which solves the same problem when no magnet is on a
            # port (``_initial_equilibrium``): the solve is deterministic, its answer the same.
            self._warm = (self._field_source, self._s0, answer, self.solve_times[n_solves:],
                          self.iterations[n_solves:])
        except Exception as err:  # noqa: BLE001 - a warm-up only; the run reports real failures
            if caused_by_interrupt(err):  # Ctrl-C inside a compiled call comes back wrapped: still Ctrl-C
                raise KeyboardInterrupt from err
        del self.solve_times[n_solves:], self.iterations[n_solves:]
        self.events = events

    def get_feeder_state_input_port(self):
        return self._feeder_port

    def get_magnet_states_input_port(self):
        return self._magnet_port

    def get_body_poses_output_port(self):
        return self._body_poses_port

    def get_tip_wall_force_output_port(self):
        return self._tip_force_port

    def get_ball_positions_output_port(self):
        return self._positions_port

    def get_snap_throughs_output_port(self):
        return self._snaps_port

    def get_anatomy_offsets_output_port(self):
        """The ``anatomy_offsets`` port (None without wall motion)."""
        return self._anatomy_port

    # --- geometry of the insertion ------------------------------------------------------------
    def straight(self, s: float, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Every ball on the sheath axis at inserted length s (the feeder's positions) [m], with
        the sheath placed for time t (``wall_motion``)."""
        along = s - (self._n - 0.5 - np.arange(self._n)) * self._d
        return self._placement(t)[0] + along[:, None] * self._axis, np.tile(self._axis, (self._n, 1))

    def _placement(self, t: float):
        """(p_WE, sdf, sheath) placed for time t: the heart's offset moves the sheath, the wall's
        the wall (``wall_motion``); the rest pose without motion."""
        if self.wall_motion is None:
            return self._p_WE, self._sdf, self._sheath
        h = self.wall_motion.heart_offset(t)
        sdf = None if self._sdf is None else self._sdf.translated(self.wall_motion.wall_offset(t))
        sheath = None if self._sheath is None else replace(self._sheath, p_WE=self._sheath.p_WE + h)
        return self._p_WE + h, sdf, sheath

    def _constraints(self, s: float, t: float = 0.0) -> tuple[int, HeartConstraints]:
        """The held ball and the rows at inserted length s and the wall's time t (the last ones
        again while both stay)."""
        if self._last_constraints is not None and self._last_constraints[0] == (s, t):
            return self._last_constraints[1]
        self._last_constraints = ((s, t), self._new_constraints(s, t))
        return self._last_constraints[1]

    def _new_constraints(self, s: float, t: float = 0.0) -> tuple[int, HeartConstraints]:
        p_WE, sdf, sheath = self._placement(t)
        if sheath is not None:
            k, a = base_ball(self._n, s, self._d, self.free_in_bore)
            p_WB = p_WE + a * self._axis
        else:  # only ball 1 is held, by its slide
            k, p_WB = 0, self.straight(s, t)[0][0]
        return k, HeartConstraints(p_WB, self._R_WB, sdf, sheath, n_behind=k, gravity=self._gravity)

    def ball_positions(self, context) -> np.ndarray:
        """Ball centres (n, 3) [m] in this engine's context."""
        x = context.get_discrete_state(self._state_index).get_value()
        return x[self._slices["p"]].reshape(-1, 3)

    def state_vector(self, context) -> np.ndarray:
        return context.get_discrete_state(self._state_index).get_value()

    # --- solving --------------------------------------------------------------------------------
    def _field(self, magnets: np.ndarray | None):
        return external_field_source(self._field_source, self._port_magnets, self._port_moments, self._port_radii,
                                     magnets, self._model)

    def equilibrium(self, s: float, magnets: np.ndarray | None, p_W: np.ndarray | None = None,
                    m_W: np.ndarray | None = None, predicted=None,
                    t: float = 0.0) -> tuple[np.ndarray, np.ndarray, StaticsResult | None, int]:
        """The equilibrium at inserted length s and magnet states (``_equilibrium``), its result a
        ``StaticsResult``."""
        p, m, result, k = self._equilibrium(s, magnets, p_W, m_W, predicted, t)
        return p, m, (result.result() if isinstance(result, HeartAnswer) else result), k

    def _equilibrium(self, s: float, magnets: np.ndarray | None, p_W: np.ndarray | None = None,
                     m_W: np.ndarray | None = None, predicted=None, t: float = 0.0):
        """The equilibrium at inserted length s and magnet states, warm-started from the world
        configuration (p_W, m_W) (None: the straight chain), or first from ``predicted``
        ((p, m), the continuation's extrapolation) when given; one cold restart on failure.
        The wall and the sheath are placed for time t (``wall_motion``; no effect without it).

        Returns:
            ``(p_W (n, 3), m_W (n, 3), result or None (no free ball), k)``: the result a
            ``StaticsResult`` or the compiled path's ``HeartAnswer`` (its ``result()`` the
            former); raises StaticsError when the restart fails too.
        """

        k, c = self._constraints(s, t)
        if k >= self._n - 1:
            p, m = self.straight(s, t)
            return p, m, None, k
        n_sub = self._n - k
        solver = self._solvers.get(n_sub)
        if solver is None:
            solver = self._solvers[n_sub] = ChainStatics(self.chain.with_balls(n_sub), gravity=self._gravity,
                                                         tolerance=self.tolerance, compiled=self.compiled)
            # Rows met to 1e-9 of a ball diameter (3 pm) rather than 1e-12: one Newton
            # iteration less (the last one only certifies round-off).
            solver.feasibility_tolerance = 1e-9
            if self.compiled:
                self._lean[n_sub] = HeartSolve(solver)
        lean = self._lean.get(n_sub)
        if lean is not None and not lean.usable():
            lean = None

        def warm_base(p, m):
            """(p_B, unit m_B) of the sub-chain from a world configuration."""
            pB, mB = c.to_base(p[k:], m[k:])
            return pB, mB / _norms(mB)[:, None]

        def warm_from(p, m):
            if p is None:
                return None
            return StaticsResult(*warm_base(p, m), 0.0, None, True,
                                 "warm start", "", 0, 0.0, multipliers=self._multipliers.get(n_sub, {}))

        field = self._field(magnets)
        start = self.clock()
        starts = ([] if predicted is None else [predicted]) + [(p_W, m_W)] + ([(None, None)] if p_W is not None else [])
        for p0, m0 in starts:  # the prediction, the last equilibrium, then one cold restart
            result = None
            if lean is not None:  # the same solve with less around it (HeartSolve), where it applies
                # ChainStatics.solve's start: the straight chain without multipliers (a cold restart)
                pB, mB = straight_chain(solver.chain) if p0 is None else warm_base(p0, m0)
                lam0 = None if p0 is None else self._multipliers.get(n_sub, {})
                result = lean.solve(field, c, pB, mB, lam0)
            if result is None:
                result = solver.solve(field, warm_from(p0, m0), constraints=c)
            if result.converged:
                break
        self.solve_times.append(self.clock() - start)
        if result.converged:
            self._multipliers[n_sub] = result.multipliers
        self.iterations.append(result.iterations)
        self.last_result = result
        if not result.converged:
            raise StaticsError(f"statics in the heart did not converge at s = {s * 1e3:.2f} mm: {result.reason}")
        p, m = c.full_configuration(result.positions, result.dipoles, self._d)
        return p, m, result, k

    @property
    def last_result(self) -> StaticsResult | None:
        """The last solve's ``StaticsResult`` (wall contacts, multipliers)."""
        result = self._last_result
        return result.result() if isinstance(result, HeartAnswer) else result

    @last_result.setter
    def last_result(self, result) -> None:
        self._last_result = result

    def _tip_force(self, p: np.ndarray, result) -> list[float]:
        """(6,) the wall's push on the tip ball and its contact point: the floats of
        ``p[-1] - 0.5 * d * f / |f|`` (the centre without a push) on plain floats."""
        c0, c1, c2 = p[-1].tolist()
        if result is not None:
            if isinstance(result, HeartAnswer):
                f = result.tip_wall_force_W()
            else:
                f = result.wall_forces_W.get(result.positions.shape[0] - 1)
            size = 0.0 if f is None else float(np.linalg.norm(f))
            if size > 0:
                f0, f1, f2 = np.asarray(f, float).tolist()
                h = 0.5 * self._d
                return [f0, f1, f2, c0 - h * f0 / size, c1 - h * f1 / size, c2 - h * f2 / size]
        return [0.0, 0.0, 0.0, c0, c1, c2]

    def _step_size(self, s0, s1, mag0, mag1, times=(0.0, 0.0)) -> float:
        """How far the inputs move, in continuation steps (the largest of the feeder's travel,
        the magnets' turn and their travel, and the wall's and the sheath's travel between the
        ``times`` (t0, t1), over their per-step limits)."""
        u = abs(s1 - s0) / self.max_insertion_step
        if self.wall_motion is not None:
            u = max(u, self._wall_travel(*times) / self.max_insertion_step)
        if mag0 is not None and len(mag0):
            moves = magnet_moves(mag0, mag1)  # plain floats, the same as numpy's below
            if moves is None:  # a zero-length direction or a non-finite number: numpy's semantics
                a, b = mag0.reshape(-1, 6), mag1.reshape(-1, 6)
                cos = np.einsum("ij,ij->i", a[:, 3:], b[:, 3:]) / (_norms(a[:, 3:]) * _norms(b[:, 3:]))
                moves = np.minimum(np.maximum(cos, -1.0), 1.0), float(_norms(a[:, :3] - b[:, :3]).max())
            u = max(u, float(np.arccos(np.asarray(moves[0], float)).max()) / self.max_angle_step, moves[1] / 5e-3)
        return u

    def _wall_travel(self, t0: float, t1: float) -> float:
        """How far the wall or the sheath moves from time t0 to t1 (the larger) [m]."""
        w = self.wall_motion
        return float(max(np.linalg.norm(w.heart_offset(t1) - w.heart_offset(t0)),
                         np.linalg.norm(w.wall_offset(t1) - w.wall_offset(t0))))

    def _walk(self, t, s0, s1, mag0, mag1, p, m, depth=0, motion=None, times=(0.0, 0.0)):
        """Continuation from (s0, mag0) with equilibrium (p, m) to (s1, mag1), the wall and the
        sheath from their places at ``times[0]`` to those at ``times[1]`` (``wall_motion``).

        ``motion``: (dp, dm, u) the last step's change of the equilibrium and its size
        (``_step_size``); each step starts from the linear extrapolation (a secant predictor),
        which saves Newton iterations while the magnets turn or the feeder moves steadily.
        Returns (p, m, result, motion).
        """
        # As many steps as the largest of the moves over its per-step limit asks for (the
        # ceiling of the largest ratio is the largest of the ratios' ceilings).
        u = self._step_size(s0, s1, mag0, mag1, times)
        steps = max(1, ceil(u) if isfinite(u) else int(np.ceil(u)))  # (np.ceil's error past the floats)
        result = None
        u_step = u / steps
        s_prev, f_prev = s0 + 0.0 * (s1 - s0), 0.0
        t0, t1 = times
        tau_prev = t0
        for j in range(1, steps + 1):
            f = j / steps
            s = s0 + f * (s1 - s0)
            tau = t0 + f * (t1 - t0)  # the wall's time (t0 = t1 without motion)
            mag = None if mag0 is None else self._interpolate(mag0, mag1, f)
            predicted = None
            if motion is not None and motion[2] > 0 and u_step > 0:
                ratio = min(u_step / motion[2], 2.0)
                predicted = (p + ratio * motion[0], m + ratio * motion[1])
            p_new, m_new, result, _ = self._equilibrium(s, mag, p, m, predicted, t=tau)
            dp = p_new - p  # (the jump's and the predictor's: one subtraction)
            jump = float(_norms(dp).max() - abs(s - s_prev))
            if self.wall_motion is not None:  # the chain rides on the moving anatomy: not a jump
                jump -= self._wall_travel(tau_prev, tau)
            if jump > self.snap_distance:
                if depth < 4:  # refine: a smooth path moves less over a shorter step
                    mag_prev = None if mag0 is None else self._interpolate(mag0, mag1, f_prev)
                    p_new, m_new, result, _ = self._walk(t, s_prev, s, mag_prev, mag, p, m, depth + 1,
                                                         times=(tau_prev, tau))
                elif steps == 1:
                    self.events.append(EngineEvent(t, "snap-through", jump + abs(s - s_prev),
                                                   f"inserted length {s * 1e3:.2f} mm"))
                motion = None  # no extrapolation across a jump
            else:
                motion = (dp, m_new - m, u_step)
            p, m = p_new, m_new
            s_prev, f_prev, tau_prev = s, f, tau
        return p, m, result, motion

    @staticmethod
    def _interpolate(a: np.ndarray, b: np.ndarray, f: float) -> np.ndarray:
        out = interpolate_magnets(a, b, f)  # plain floats, the same as numpy's below
        if out is not None:
            return np.array(out)
        a, b = a.reshape(-1, 6), b.reshape(-1, 6)
        out = (1 - f) * a + f * b  # centres: linear; directions: normalised (a short arc)
        out[:, 3:] /= _norms(out[:, 3:])[:, None]
        return out.ravel()

    def _inputs(self, context):
        s = float(self._feeder_port.Eval(context)[0])
        mags = None if self._magnet_port is None else np.array(self._magnet_port.Eval(context))
        return s, mags

    def _initialize(self, context, discrete_state):
        s, mags = self._inputs(context)
        t = context.get_time() if self.wall_motion is not None else 0.0
        p, m, result = self._initial_equilibrium(s, mags, t)
        self._store(discrete_state, context, p, m, result, s, mags, new_snaps=0, new_failures=0)
        return EventStatus.Succeeded()

    def _initial_equilibrium(self, s: float, mags, t: float = 0.0):
        """The equilibrium at the start (from the straight chain): the warm-up's answer when it
        solved this very problem (the same insertion and field, no port magnets, a still
        anatomy), recorded as a solve again (its time and iterations) with the warm-up's
        multipliers kept; else solved (at time ``t`` of a moving anatomy)."""
        warm = self._warm
        if (warm is not None and mags is None and self.wall_motion is None and warm[0] is self._field_source
                and warm[1] == s):
            p, m, result, k = warm[2]
            self._constraints(s)
            self.solve_times.extend(warm[3])
            self.iterations.extend(warm[4])
            if result is not None:
                self._multipliers[self._n - k] = result.multipliers
                self.last_result = result
            return p, m, result
        with _one_blas_thread():
            p, m, result, _ = self._equilibrium(s, mags, t=t)
        return p, m, result

    def _update(self, context, discrete_state):

        x = self.state_vector(context)
        s, mags = self._inputs(context)
        sl = self._slices
        s_last = float(x[sl["s"].start])
        mags_last = None if mags is None else x[sl["magnets"]]
        t = context.get_time()
        times = (0.0, 0.0) if self.wall_motion is None else (float(x[sl["wall_t"].start]), t)
        # (np.array_equal on plain floats: a NaN differs from itself in both)
        if s == s_last and (mags is None or mags.tolist() == mags_last.tolist()) and times[0] == times[1]:
            # Nothing moved: the chain stays where it is (and the next move starts afresh).
            # discrete_state holds the current state: only the step size changes.
            discrete_state.get_mutable_vector(self._state_index).get_mutable_value()[sl["u"]] = 0.0
            return EventStatus.Succeeded()
        n_events = len(self.events)
        motion = None
        u_last = float(x[sl["u"].start])
        if u_last > 0:
            motion = (x[sl["dp"]].reshape(-1, 3), x[sl["dm"]].reshape(-1, 3), u_last)
        try:
            with _one_blas_thread():
                p, m, result, motion = self._walk(t, s_last, s, mags_last, mags, x[sl["p"]].reshape(-1, 3),
                                                  x[sl["m"]].reshape(-1, 3), motion=motion, times=times)
        except StaticsError as err:  # keep the last equilibrium, report it (the watchdog stops)
            # Not EventStatus.Failed(self, ...): formatting a Python system's failure message
            # crashes pydrake 1.51 (NiceTypeName without the GIL); the monitor fails instead.
            self.events.append(EngineEvent(t, "solve failed", 0.0, str(err)))
            self.failure = f"quasi-static engine at t = {t:.4f} s: {err}"
            return EventStatus.Succeeded()
        snaps = sum(e.kind == "snap-through" for e in self.events[n_events:])  # this update's
        self._store(discrete_state, context, p, m, result, s, mags, snaps, 0, motion)
        return EventStatus.Succeeded()

    def _store(self, discrete_state, context, p, m, result, s, mags, new_snaps, new_failures, motion=None):
        """Writes the update into ``discrete_state`` in place (it holds the current state)."""
        x = discrete_state.get_mutable_vector(self._state_index).get_mutable_value()
        sl = self._slices
        if motion is None:
            x[sl["u"]] = 0.0
        else:
            x[sl["dp"]] = motion[0].ravel()
            x[sl["dm"]] = motion[1].ravel()
            x[sl["u"]] = motion[2]
        x[sl["p"]] = p.ravel()
        x[sl["m"]] = m.ravel()
        x[sl["tip"]] = self._tip_force(p, result)
        x[sl["s"]] = s
        if mags is not None:
            x[sl["magnets"]] = mags
        if self.wall_motion is not None:
            x[sl["wall_t"]] = context.get_time()
        if new_snaps:  # (counts: adding 0 leaves them as they are)
            x[sl["snaps"]] += new_snaps
        if new_failures:
            x[sl["failures"]] += new_failures
        if not np.isfinite(x).all() and self.failure is None:
            # The watchdog looks at the state only at its checks (the chain moves only here):
            # a non-finite update is reported at once, as a failure (ChainModel.move_period).
            self.failure = f"quasi-static engine at t = {context.get_time():.4f} s: a non-finite state"

    # --- outputs ---------------------------------------------------------------------------------
    def _calc_body_poses(self, context, output):
        x = self.state_vector(context)
        X = ball_frames(x[self._slices["m"]].reshape(-1, 3), x[self._slices["p"]].reshape(-1, 3))
        poses = list(self._poses)  # a new list: a consumer may hold the last one
        if self._ball_slice is not None:
            poses[self._ball_slice] = map(RigidTransform.MakeUnchecked, X)
        else:
            for index, X_i in zip(self._indices, X):
                poses[index] = RigidTransform.MakeUnchecked(X_i)
        output.set_value(poses)

    def _calc_tip_force(self, context, output):
        output.SetFromVector(self.state_vector(context)[self._slices["tip"]])

    def _calc_positions(self, context, output):
        output.SetFromVector(self.state_vector(context)[self._slices["p"]])

    def _calc_snaps(self, context, output):
        output.SetFromVector(self.state_vector(context)[self._slices["snaps"]])

    def wall_time(self, context) -> float:
        """The time the last solve placed the anatomy for [s] (0 without wall motion)."""
        return float(self.state_vector(context)[self._slices["wall_t"]][0]) if self.wall_motion is not None else 0.0

    def _calc_anatomy_offsets(self, context, output):
        t = self.wall_time(context)
        output.SetFromVector(np.concatenate([self.wall_motion.heart_offset(t), self.wall_motion.wall_offset(t)]))
