"""Chain statics: the equilibrium shape as the minimum of the chain's energy.

The canonical problem (docs/design.md, 2.3): ball 1 is held by the sheath at the origin with its
dipole along +x; balls 2..n are free (position and dipole direction, frictionless, no twist),
each touching its predecessor, no two balls closer than d. ``optimization.reduced_chain`` writes
it in reduced coordinates (link and dipole directions in a chart centred on the warm start), with
the exact energy, gradient and Hessian from ``drake_models.chain_energy``.

Two solvers of the same problem:

* ``"newton"`` (default): a second-order SQP. Each step minimises the quadratic model of the
  energy (the Lagrangian's exact Hessian H; where H is indefinite, H + rho s N'N when that is
  positive definite for a rho of ``CONVEXIFY``, with N the step's rows that touch, then all its
  rows, so that the curvature along the rows is H's own, else H with its negative eigenvalues
  flipped) subject to the linearised rigidity constraints of the pairs that are near contact;
  when a pair is near, the step is a QP, solved by a dense
  dual active-set method (``dense_qp``, default) or posed as a Drake MathematicalProgram and
  solved by Clarabel (``qp="clarabel"``; about 10 times slower here, the program being rebuilt
  every step): its multipliers are the contact forces. Otherwise it is a Cholesky solve. An l1 merit line search globalises it; a negative-curvature step leaves
  saddle points (the straight chain in an antiparallel field is one), and "converged" means the
  KKT conditions hold and the reduced Hessian is positive semi-definite: a verified local minimum.
  With ``wall_constraints.HeartConstraints`` the same solver holds the chain in the heart: the
  atrium's wall and the sheath are rows of the QP (frictionless: their multipliers are the
  normal pushes on every ball).
* ``"snopt"``: the whole problem as one MathematicalProgram (energy cost with analytic gradient,
  rigidity as a vector constraint) solved by SNOPT. A quasi-Newton reference: about 50 times
  slower here, since it needs tens of iterations that each pass through Drake's AutoDiff
  bindings.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Iterable, Literal

import numpy as np
from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue, InitializeAutoDiff
from pydrake.solvers import (
    ClarabelSolver,
    MathematicalProgram,
    SnoptSolver,
    SolverOptions,
)

from ballchain.drake_models.chain_energy import EnergyTerms
from ballchain.drake_models.kernels import chain_energy
from ballchain.drake_models.field_sources import FieldSource, UniformField, require_field_source
from ballchain.drake_models.params import BallChain
from ballchain.drake_models.vectors import angle_between
from ballchain.infrastructure.arg_checks import (as_plane, as_vector, require_bool, require_int, require_positive,
                                                 require_type)
from ballchain.infrastructure.errors import UserInputError
from ballchain.optimization import compiled_model
from ballchain.optimization.compiled_newton import CONVEXIFY, TOUCHING
from ballchain.optimization.reduced_chain import X_AXIS, ReducedChain, answer_verdict
from ballchain.optimization.wall_constraints import ConstrainedChain, HeartConstraints

Method = Literal["newton", "snopt"]

_SNOPT_MESSAGES = {
    1: "optimality conditions satisfied",
    3: "requested accuracy could not be achieved",
    13: "nonlinear infeasibilities minimized",
    31: "iteration limit reached",
    32: "major iteration limit reached",
    41: "current point cannot be improved",
    42: "singular basis",
}


class StaticsError(RuntimeError):
    """A statics solve that did not converge, with the reason."""


@dataclass
class StaticsResult:
    """An equilibrium of the chain (or the last iterate of a failed solve).

    Attributes:
        positions: (n, 3) ball centres [m], ball 1 at the origin.
        dipoles: (n, 3) unit dipole directions, ball 1 along +x.
        energy: total potential energy [J].
        terms: the energy's parts.
        converged: whether the solver certified a (local) minimum.
        reason: the solver's message (why it stopped).
        solver: solver name.
        iterations: Newton iterations, or energy evaluations for SNOPT.
        solve_time: wall time of the solve [s].
        max_violation: largest rigidity-constraint violation, ``|p_i - p_j| < d``, [m] (0 if none).
        pair_forces: ``{(i, j): force [N]}`` between non-adjacent balls i, j (0-based) that touch
            at the equilibrium: the rigidity constraints' multipliers.
        tip_reaction: (3,) force [N] that a tip target exerts on the tip ball (the tip
            constraint's multiplier); zero without a target. The chain presses on the target
            with minus this.
        wall_forces: ``{i: force [N]}`` the wall pushes on ball i (0-based) along its normal.
        wall_forces_W: with ``HeartConstraints``: ``{i: f_W (3,) [N]}`` the atrium's wall
            pushes on ball i of the sub-chain (frictionless: along the wall's normal).
        sheath_forces_W: likewise the sheath's lip and bore.
        positions_W, dipoles_W: with ``HeartConstraints``: the configuration in world.
        multipliers: ``{row: multiplier}`` of the rows near contact at the solution (scaled
            units); a warm start carrying them starts the next solve's model with them.
    """

    positions: np.ndarray
    dipoles: np.ndarray
    energy: float
    terms: EnergyTerms
    converged: bool
    reason: str
    solver: str
    iterations: int
    solve_time: float
    max_violation: float = 0.0
    pair_forces: dict = field(default_factory=dict)
    tip_reaction: np.ndarray = field(default_factory=lambda: np.zeros(3))
    wall_forces: dict = field(default_factory=dict)
    wall_forces_W: dict = field(default_factory=dict)
    sheath_forces_W: dict = field(default_factory=dict)
    positions_W: np.ndarray | None = None
    dipoles_W: np.ndarray | None = None
    multipliers: dict = field(default_factory=dict)

    @property
    def tip_position(self) -> np.ndarray:
        return self.positions[-1]

    @property
    def tip_dipole(self) -> np.ndarray:
        return self.dipoles[-1]

    def link_directions(self) -> np.ndarray:
        """(n-1, 3) unit vectors from each ball to the next."""
        links = np.diff(self.positions, axis=0)
        return links / np.linalg.norm(links, axis=1)[:, None]


def straight_chain(chain: BallChain, direction=X_AXIS) -> tuple[np.ndarray, np.ndarray]:
    """The straight chain along ``direction`` from the origin, all dipoles along it."""
    direction = np.asarray(direction, dtype=float)
    direction = direction / np.linalg.norm(direction)
    n = chain.n_balls
    positions = np.arange(n)[:, None] * chain.ball_diameter * direction
    return positions, np.tile(direction, (n, 1))


def tip_angle_deg(result: StaticsResult, field_direction) -> float:
    """Angle between the tip ball's dipole and a field direction [deg]."""
    require_type(result, StaticsResult, "result", "a StaticsResult")
    as_vector(field_direction, "field_direction", nonzero=True)
    f = np.asarray(field_direction, dtype=float)
    return float(np.degrees(angle_between(result.tip_dipole, f / np.linalg.norm(f))))




def dense_qp(H: np.ndarray, g: np.ndarray, A: np.ndarray, b: np.ndarray, E: np.ndarray | None = None,
             e: np.ndarray | None = None, max_iterations: int = 200):
    """min 1/2 x' H x + g' x  s.t.  A x + b >= 0  and  E x + e = 0, for a positive definite H.

    Solved in the dual: with x = H^-1 (A' lam + E' mu - g) the multipliers minimise
    1/2 y' M y + y' (c - N H^-1 g) over y = (lam >= 0, mu free), N = [A; E], M = N H^-1 N',
    c = (b, e): a small bound-constrained QP (as many unknowns as rows near contact) solved by
    a Lawson-Hanson active set (exact, finite). One Cholesky factorisation of H. The dual is
    regularised by delta = 1e-13 trace(M) (dependent rows); when that alone leaves a row below
    the tolerance (H nearly singular: trace(M) huge), the dual is refined on the free set
    (``_refined``) before the rows are called infeasible.

    Returns:
        ``(x, lam, mu)``, or ``(None, None, None)`` when the constraints are infeasible (the
        dual is unbounded) or the active set cycles.
    """
    n_in = len(b)
    n_eq = 0 if E is None else len(e)
    N = A if n_eq == 0 else np.vstack([A, E])
    c = b if n_eq == 0 else np.concatenate([b, e])
    # numpy's Cholesky and solves: scipy's cho_factor/solve_triangular measured 25 times slower
    # on these 60 x 60 matrices here.
    Lc = np.linalg.cholesky(H)
    Hinv_g = np.linalg.solve(Lc.T, np.linalg.solve(Lc, g))
    if len(c) == 0:
        return -Hinv_g, np.zeros(0), np.zeros(0)
    Y = np.linalg.solve(Lc, N.T)  # L^-1 N'
    M = Y.T @ Y
    delta = 1e-13 * max(1.0, float(np.trace(M)))
    M += delta * np.eye(len(M))  # dependent rows: a unique dual
    r = c - N @ Hinv_g
    m = len(c)
    y = np.zeros(m)
    free = np.zeros(m, bool)
    free[n_in:] = True  # equality multipliers are never bounded
    for _ in range(max_iterations):
        # Minimise over the free set with the bound ones at zero.
        while True:
            z = np.zeros(m)
            F = np.flatnonzero(free)
            if len(F):
                z[F] = np.linalg.solve(M[np.ix_(F, F)], -r[F])
            bad = free[:n_in] & (z[:n_in] < 0.0)
            if not np.any(bad):
                y = z
                break
            # Step from y towards z until the first inequality multiplier reaches zero.
            idx = np.flatnonzero(bad)
            alpha = np.min(y[idx] / (y[idx] - z[idx]))
            y = y + alpha * (z - y)
            free[:n_in] &= ~(y[:n_in] <= 1e-14 * max(1.0, np.abs(y).max()))
            y[:n_in][~free[:n_in]] = 0.0
        w = -(M @ y + r)  # the dual's negative gradient: positive where a bound should be freed
        w[free] = 0.0
        w[n_in:] = 0.0
        j = int(np.argmax(w))
        if w[j] <= 1e-12 * max(1.0, np.abs(r).max()):
            if not np.all(np.isfinite(y)) or np.abs(y).max() > 1e12:
                return None, None, None
            x = np.linalg.solve(Lc.T, np.linalg.solve(Lc, N.T @ y - g))
            floor = -1e-8 * max(1.0, np.abs(b).max())
            if n_in and (A @ x + b).min() < floor:
                # The regularisation leaves each free row at -delta y_i, not 0: more than the
                # tolerance when H is nearly singular (a soft mode makes trace(M) huge). Refined
                # against the unregularised dual on the free set, a feasible set's rows close
                # (an infeasible one's stay violated); only then infeasible.
                y = _refined(M, r, y, free, n_in, delta)
                if y is None:
                    return None, None, None
                x = np.linalg.solve(Lc.T, np.linalg.solve(Lc, N.T @ y - g))
                if (A @ x + b).min() < floor:
                    return None, None, None  # infeasible: the regularised dual stops at a violation
            return x, y[:n_in], y[n_in:]
        free[j] = True
    return None, None, None


def _refined(M: np.ndarray, r: np.ndarray, y: np.ndarray, free: np.ndarray, n_in: int,
             delta: float) -> np.ndarray | None:
    """``dense_qp``'s dual y refined on the free set F towards the unregularised system
    (M - delta I)_FF y_F = -r_F (M regularised by delta): three rounds of iterative
    refinement with the regularised matrix, each shrinking the error by about
    delta / (delta + the eigenvalue). None when a refined inequality multiplier (the first
    ``n_in``) turns negative or y is not finite."""
    F = np.flatnonzero(free)
    y = y.copy()
    MF = M[np.ix_(F, F)]
    for _ in range(3):
        y[F] += np.linalg.solve(MF, -(r[F] + MF @ y[F] - delta * y[F]))
    if not np.all(np.isfinite(y)) or np.any(y[:n_in] < 0.0):
        return None
    return y


def _positive_definite(H: np.ndarray, floor: float = 1e-10) -> np.ndarray:
    """H itself when it is positive definite, else H with its eigenvalues replaced by
    max(|lambda|, floor * max|lambda|) (negative curvature flipped, flat directions lifted)."""
    try:
        np.linalg.cholesky(H)
        return H
    except np.linalg.LinAlgError:
        pass
    w, V = np.linalg.eigh(H)
    delta = floor * max(1.0, float(np.abs(w).max()))
    return (V * np.maximum(np.abs(w), delta)) @ V.T


def _qp_curvature(H: np.ndarray, Nt: np.ndarray, N: np.ndarray) -> np.ndarray:
    """The QP's curvature for the constraint rows N, of which the rows Nt touch: H itself when it
    is positive definite, else the first of H + rho s Nt'Nt, then of H + rho s N'N
    (s = max(1, max|H_ii|), rho in ``CONVEXIFY``) that is, else ``_positive_definite(H)``
    (``compiled_newton.qp_curvature`` is the compiled twin)."""
    try:
        np.linalg.cholesky(H)
        return H
    except np.linalg.LinAlgError:
        pass
    s = max(1.0, float(np.abs(np.diag(H)).max()))
    for R in ([Nt] if len(Nt) == len(N) else [Nt, N]):
        C = R.T @ R
        for rho in CONVEXIFY:
            Hc = H + (rho * s) * C
            try:
                np.linalg.cholesky(Hc)
                return Hc
            except np.linalg.LinAlgError:
                pass
    return _positive_definite(H)


def _set_tip_target_and_wall(model: ReducedChain, tip_target, wall) -> None:
    """Pin the model's tip at ``tip_target`` (or not) and place its plane ``wall`` (or none)."""
    model.tip_target = None if tip_target is None else np.asarray(tip_target, dtype=float).reshape(3)
    if model.tip_target is not None and not np.all(np.isfinite(model.tip_target)):
        raise UserInputError(f"tip target must be finite, got {tip_target}")
    if wall is None:
        model.wall = None
    else:
        point, normal = (np.asarray(v, dtype=float).reshape(3) for v in wall)
        if not (np.all(np.isfinite(point)) and np.all(np.isfinite(normal)) and np.linalg.norm(normal) > 0):
            raise UserInputError(f"wall must be a finite point and a non-zero normal, got {wall}")
        model.wall = (point, normal / np.linalg.norm(normal))
        if point @ model.wall[1] > -0.5 * model.d:
            raise UserInputError("the wall cuts ball 1 (held at the origin): move it beyond half a ball")


def _infeasibility(e, pinned: bool) -> float:
    """The summed violation of an evaluation's rows (and of the tip target when ``pinned``)."""
    tip = float(np.abs(e.tip_residual).sum()) if pinned else 0.0
    return float(np.maximum(0.0, -e.gaps).sum()) + tip


def _negative_curvature(ev, H, near, lam, pinned: bool, nq: int):
    """None when H is positive semi-definite (up to 1e-7) on the tangent space of the active rows
    (multiplier above 1e-9, and the tip target when ``pinned``): a local minimum. Else
    ``(Z, V)``: the tangent space's basis and the eigenvectors of H on it, the most negative first."""
    active = near[lam > 1e-9] if len(near) else near
    rows = [ev.jacobian[active]] + ([ev.tip_jacobian] if pinned else [])
    J_active = np.vstack(rows)
    Z = _null_space(J_active) if len(J_active) else np.eye(nq)
    H_tangent = Z.T @ H @ Z
    try:  # positive semi-definite up to 1e-7: a local minimum (cheap test first)
        np.linalg.cholesky(H_tangent + 1e-7 * np.eye(len(H_tangent)))
        return None
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(H_tangent)
    return Z, V


def _line_search(model: ReducedChain, q, dq, ev, near, pinned: bool, rho: float, merit0: float, slope: float):
    """Backtracking on the l1 merit ``energy + rho * infeasibility`` along dq from q (Armijo,
    1e-4), with a second-order correction of the full step onto curved rows.

    Returns:
        ``(t, dq, trial)``: the step length (below 1e-10: no descent), the step (corrected or
        not) and the evaluation there (with derivatives when the full step was taken).
    """
    t = 1.0
    while True:
        # The full step is usually taken: evaluate it with derivatives for the next
        # iteration; shorter trials only need the energy.
        trial = model.evaluate(q + t * dq, 2 if t == 1.0 else 0)
        merit = trial.energy + rho * _infeasibility(trial, pinned)
        if merit <= merit0 + 1e-4 * t * min(slope, 0.0) or t < 1e-10:
            break
        if t == 1.0 and pinned:
            # Second-order correction: the full step leaves the tip off target by the
            # constraint's curvature (Maratos effect); project it back before shortening.
            correction = -np.linalg.pinv(ev.tip_jacobian) @ trial.tip_residual
            corrected = model.evaluate(q + dq + correction, 2)
            if corrected.energy + rho * _infeasibility(corrected, pinned) <= merit0 + 1e-4 * min(slope, 0.0):
                dq, trial = dq + correction, corrected
                break
        if t == 1.0 and not pinned and len(near):
            # The same for the inequality rows the full step violates (a ball pressed
            # on a curved wall): the linearised row is met, the curved one is not.
            rows = near[trial.gaps[near] < 0.0]
            if len(rows):
                correction = -np.linalg.pinv(ev.jacobian[rows]) @ trial.gaps[rows]
                corrected = model.evaluate(q + dq + correction, 2)
                if corrected.energy + rho * _infeasibility(corrected, pinned) <= merit0 + 1e-4 * min(slope, 0.0):
                    dq, trial = dq + correction, corrected
                    break
        t *= 0.5
    return t, dq, trial


MAX_BALLS = 200  # dense Hessians: 200 balls take about 0.5 GB


class ChainStatics:
    """Equilibria of one chain, reusable across solves (warm starts, continuation).

    Args:
        chain: the chain (with or without sleeve).
        gravity: include gravity along -z.
        method: "newton" (second-order SQP, default) or "snopt" (quasi-Newton reference).
        tolerance: stationarity tolerance on the scaled energy gradient (energy in units of the
            pair energy of two touching balls, angles in rad).
        max_iterations: Newton iteration limit.
        qp: the Newton steps' QP solver, "dense" (active set) or "clarabel".
        compiled: run the whole Newton solve (with the dense QP) as one compiled call
            (``optimization.compiled_newton``); False runs the Python solver, the reference
            the compiled one is held to.
    """

    contact_margin = 0.3  # pairs with |p_i - p_j|^2 / d^2 - 1 below this enter the step's QP
    feasibility_tolerance = 1e-12  # largest summed row violation (dimensionless) of a solution
    max_step = 0.5  # largest change of any chart angle in one Newton step [rad]

    def __init__(
        self,
        chain: BallChain,
        gravity: bool = False,
        method: Method = "newton",
        tolerance: float = 1e-8,
        max_iterations: int = 200,
        qp: str = "dense",
        compiled: bool = True,
    ):
        require_type(chain, BallChain, "ChainStatics chain", "a BallChain")
        if chain.n_balls > MAX_BALLS:
            raise UserInputError(f"ChainStatics solves chains of up to {MAX_BALLS} balls (its Hessians are dense: "
                                 f"about 0.5 GB at {MAX_BALLS}), got {chain.n_balls}")
        require_bool(gravity, "ChainStatics gravity")
        require_bool(compiled, "ChainStatics compiled")
        require_positive(tolerance, "ChainStatics tolerance")
        require_int(max_iterations, "ChainStatics max_iterations", 1)
        if method not in ("newton", "snopt"):
            raise UserInputError(f"method must be 'newton' or 'snopt', got {method!r}")
        if qp not in ("dense", "clarabel"):
            raise UserInputError(f"qp must be 'dense' or 'clarabel', got {qp!r}")
        self.qp = qp
        self.compiled = compiled
        self._constrained: ConstrainedChain | None = None
        self.chain = chain
        self.gravity = gravity
        self.method = method
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        self._qp_solver = ClarabelSolver()
        self._model: ReducedChain | None = None
        self._straight = None  # (chain, p0, m0, [its chart]): the cold start, see _straight_chain
        self._free_parts = None  # (model, settings, model_parts) of the free chain (compiled_model.run)
        if method == "snopt":
            self._snopt = SnoptSolver()
            if not self._snopt.available() or not self._snopt.enabled():
                raise RuntimeError("SNOPT is not available in this Drake build")
            self._snopt_options = SolverOptions()
            sid = self._snopt.solver_id()
            self._snopt_options.SetOption(sid, "Major iterations limit", 2000)
            self._snopt_options.SetOption(sid, "Iterations limit", 100000)
            self._snopt_options.SetOption(sid, "Major optimality tolerance", 1e-8)
            self._snopt_options.SetOption(sid, "Major feasibility tolerance", 1e-10)

    # --- public API --------------------------------------------------------------------------
    def solve(self, external: FieldSource | None, warm_start: StaticsResult | None = None,
              tip_target=None, wall=None, constraints: HeartConstraints | None = None) -> StaticsResult:
        """The equilibrium reached from ``warm_start`` (the straight chain if None).

        Args:
            external: external field source (uniform field, magnets, or a sum), or None.
            warm_start: a previous result of the same chain.
            tip_target: (3,) point [m] where the tip ball's centre is held (a force sensor or a
                target touching the tip); the result's ``tip_reaction`` is the force it exerts.
                Newton method only.
            wall: ``(point (3,), normal (3,))`` of a rigid frictionless plane the balls stay on
                the normal's side of; ``wall_forces`` are its pushes. Newton method only.
            constraints: the chain in the heart (``wall_constraints.HeartConstraints``): the
                canonical problem placed at the held ball in the sheath, the external field
                given in world, gravity along -z_W, the atrium's wall and the sheath as rows;
                ``wall_forces_W``/``sheath_forces_W`` are their pushes and ``positions_W`` the
                configuration in world (``positions`` stay in the base frame, for warm starts).
                Newton method only; not with ``wall`` or ``tip_target``.

        Returns:
            The result; check ``converged`` (or use ``solve_or_raise``).

        Example:
            Eight balls in a 23 mT field at 45 deg: free, with the tip held 2 mm towards -y, and against a
            wall at y = 10 mm::

                >>> import numpy as np, ballchain as bc
                >>> statics = bc.ChainStatics(bc.BallChain(n_balls=8))
                >>> field = bc.UniformField.in_plane(0.023, np.radians(45.0))
                >>> free = statics.solve(field)
                >>> free.converged, [round(1e3 * float(v), 1) for v in free.tip_position[:2]]  # [mm]
                (True, [17.6, 12.9])
                >>> held = statics.solve(field, free, tip_target=free.tip_position + [0.0, -0.002, 0.0])
                >>> [round(float(v), 3) for v in held.tip_reaction[:2]]  # the target's push on the tip [N]
                [-0.137, -0.117]
                >>> wall = statics.solve(field, free, wall=([0.0, 0.010, 0.0], [0.0, -1.0, 0.0]))
                >>> {i: round(f, 4) for i, f in wall.wall_forces.items()}  # ball (0-based): the wall's push [N]
                {7: 0.0449}
        """
        require_field_source(external, "external", allow_none=True)
        if warm_start is not None:
            require_type(warm_start, StaticsResult, "warm_start", "a StaticsResult or None")
        if tip_target is not None:
            as_vector(tip_target, "tip_target", unit="m")
        if wall is not None:
            as_plane(wall, "wall")
        if constraints is not None:
            require_type(constraints, HeartConstraints, "constraints", "a HeartConstraints or None")
        chain = self.chain
        start = time.perf_counter()
        if warm_start is None:
            p0, m0 = self._straight_chain()
        else:
            p0, m0 = warm_start.positions, warm_start.dipoles
            if p0.shape != (chain.n_balls, 3):
                raise UserInputError(f"warm start has {p0.shape[0]} balls, the chain has {chain.n_balls}")
        # The field where the balls are: the constraints' external field is given in world and
        # the warm start in the base frame.
        p_field = p0 if constraints is None else constraints.to_world(p0, m0)[0]
        bad_field = _non_finite_field(external, p_field)
        if bad_field is not None:  # never solve on a NaN field: it used to "converge" to NaN energy
            U, _, _, terms = chain_energy(chain, p0, m0, None, self.gravity)
            return StaticsResult(p0.copy(), m0.copy(), float("nan"), terms, False, bad_field,
                                 self.method, 0, time.perf_counter() - start)
        if chain.n_balls == 1:
            U, _, _, terms = chain_energy(chain, p0, m0, external, self.gravity)
            return StaticsResult(p0.copy(), m0.copy(), U, terms, True, "single ball: held by the sheath",
                                 "none", 0, time.perf_counter() - start)
        if constraints is not None:
            if self.method != "newton" or wall is not None or tip_target is not None:
                raise ValueError("constraints (the heart) are solved by the 'newton' method, without wall or tip_target")
            if self._constrained is None:
                self._constrained = ConstrainedChain(chain)
            model = self._constrained
            model.set_constraints(constraints)
            external = constraints.external_in_base(external, chain)
        else:
            if self._model is None:  # built once: pair tables and chain-rule matrices
                self._model = ReducedChain(chain, external, self.gravity)
            model = self._model
        model.external = external
        _set_tip_target_and_wall(model, tip_target, wall)
        lam0 = getattr(warm_start, "multipliers", None) if constraints is not None else None
        if self.compiled and self.method == "newton" and self.qp == "dense" and model.backend == "kernel":
            answer = compiled_model.run(self, model, external, p0, m0, lam0, constraints,
                                        self._straight[3] if warm_start is None else None)
            if answer is not None:  # else a field or wall the kernels do not evaluate: Python's
                converged, reason, iterations, lam_near, lam_tip, p, m_hat, t, gaps, v = answer
                return self._assemble(model, p, m_hat, EnergyTerms(*t.tolist()), gaps, converged, reason,
                                      iterations, lam_near, lam_tip, constraints, start, v)
        model.chart_from_configuration(p0, m0)
        lam_tip = np.zeros(3)
        if self.method == "newton":
            try:
                q, converged, reason, iterations, lam_near, lam_tip = self._newton(model, lam0)
            except np.linalg.LinAlgError as err:  # a step's system singular in floating point
                # Not an equilibrium: reported like any other failure (from the warm start).
                q, converged, iterations, lam_near = np.zeros(model.nq), False, 0, {}
                reason = f"Newton step: {err} (a singular Hessian or constraint system)"
        else:
            if model.tip_target is not None or model.wall is not None:
                raise UserInputError("tip targets and walls are solved by the 'newton' method only")
            q, converged, reason, iterations, lam_near = self._snopt_solve(model)
        return self._result(model, q, converged, reason, iterations, lam_near, lam_tip, constraints, start)

    def _result(self, model, q, converged: bool, reason: str, iterations: int, lam_near: dict, lam_tip,
                constraints: HeartConstraints | None, start: float) -> StaticsResult:
        """The StaticsResult of the solver's answer q: configuration, energy, the constraints'
        violation (which can overrule ``converged``) and the multipliers as forces [N]."""
        ev = model.evaluate(q, 0)
        p, m_hat = model.configuration(q)
        return self._assemble(model, p, m_hat, ev.terms, ev.gaps, converged, reason, iterations, lam_near,
                              lam_tip, constraints, start, None if constraints is None else q)

    def _assemble(self, model, p, m_hat, terms: EnergyTerms, row_gaps, converged: bool, reason: str,
                  iterations: int, lam_near: dict, lam_tip, constraints: HeartConstraints | None, start: float,
                  rows_at) -> StaticsResult:
        """The StaticsResult of an answer's configuration (p, m_hat), energy terms and rows' values
        (``Evaluation.gaps``); ``rows_at`` the heart rows' gradients v (2L, 3) or the chart
        coordinates to find them at (with ``constraints``)."""
        P = model.n_pairs
        converged, reason, max_violation = answer_verdict(model, p, m_hat, terms.total, row_gaps, converged, reason)
        pair_forces = {
            (int(model.pair_i[k]), int(model.pair_j[k])): 2.0 * lam * model.energy_scale / model.d
            for k, lam in lam_near.items()
            if lam > 1e-12 and k < P
        }
        wall_forces = {k - P + 1: lam * model.energy_scale / model.d for k, lam in lam_near.items()
                       if lam > 1e-12 and k >= P}
        extra = {}
        if constraints is not None:
            wall_W, sheath_W = (model.forces_at(rows_at, lam_near) if rows_at.ndim == 1
                                else model.forces_of_rows(rows_at, lam_near))
            wall_forces = {k: float(np.linalg.norm(f)) for k, f in wall_W.items()}
            p_W, m_W = constraints.to_world(p, m_hat)
            extra = dict(wall_forces_W=wall_W, sheath_forces_W=sheath_W, positions_W=p_W, dipoles_W=m_W)
        qp_name = "dense active-set QP steps" if self.qp == "dense" else "Clarabel QP steps"
        return StaticsResult(
            positions=p,
            dipoles=m_hat,
            energy=terms.total,
            terms=terms,
            converged=converged,
            reason=reason,
            solver=f"{self.method} ({qp_name if self.method == 'newton' else 'MathematicalProgram: SNOPT'})",
            iterations=iterations,
            solve_time=time.perf_counter() - start,
            max_violation=max_violation,
            pair_forces=pair_forces,
            multipliers=dict(lam_near),
            tip_reaction=model.energy_scale / model.d * np.asarray(lam_tip, dtype=float),
            wall_forces=wall_forces,
            **extra,
        )

    def _straight_chain(self) -> tuple[np.ndarray, np.ndarray]:
        """``straight_chain(self.chain)``, built once per chain: the cold start, which the solvers
        only read (a result holds a copy; its chart is remembered beside it,
        ``compiled_model.run``). Not marked read-only: numba compiles a second specialisation of
        every kernel it reaches for read-only arrays (``test_compile_structure``)."""
        cached = self._straight
        if cached is None or cached[0] is not self.chain:
            cached = self._straight = (self.chain, *straight_chain(self.chain), [None])
        return cached[1], cached[2]

    def solve_or_raise(self, external: FieldSource | None, warm_start: StaticsResult | None = None,
                       tip_target=None, wall=None, constraints: HeartConstraints | None = None) -> StaticsResult:
        """Like ``solve`` but raises StaticsError, saying why, when the solve did not converge."""
        result = self.solve(external, warm_start, tip_target, wall, constraints)
        if not result.converged:
            raise StaticsError(
                f"statics of {self.chain.n_balls} balls did not converge: {result.reason} "
                f"(after {result.iterations} iterations, {result.solve_time:.3f} s)"
            )
        return result

    def continuation(
        self,
        fields: Iterable[FieldSource | None],
        warm_start: StaticsResult | None = None,
        raise_on_failure: bool = True,
    ) -> list[StaticsResult]:
        """Solve along a sequence of fields, each warm-started from the previous equilibrium.

        This is how a rotating magnet moves the real chain: slowly, from one equilibrium to the
        next. The first solve starts from ``warm_start`` (the straight chain if None).
        """
        if isinstance(fields, (str, bytes)) or not hasattr(fields, "__iter__") \
                or hasattr(fields, "field_and_gradient"):
            raise UserInputError("continuation fields must be a sequence of field sources, got "
                                 f"{type(fields).__name__}")
        results = []
        current = warm_start
        for external in fields:
            current = (self.solve_or_raise if raise_on_failure else self.solve)(external, current)
            results.append(current)
        return results

    # --- Newton SQP -----------------------------------------------------------------------------
    def _qp_step(self, H, g, gaps, J, tip_residual=None, tip_jacobian=None):
        """min 1/2 dq' H dq + g' dq s.t. gaps + J dq >= 0 and tip_residual + J_tip dq = 0."""
        if self.qp == "dense":
            dq, lam, lam_tip = dense_qp(H, g, J, gaps, tip_jacobian, tip_residual)
            if dq is None:
                return None, None, None
            return dq, lam, (lam_tip if tip_residual is not None else np.zeros(3))
        prog = MathematicalProgram()
        x = prog.NewContinuousVariables(len(g), "dq")
        prog.AddQuadraticCost(H, g, x, is_convex=True)
        binding = prog.AddLinearConstraint(J, -gaps, np.full(len(gaps), np.inf), x) if len(gaps) else None
        tip = prog.AddLinearEqualityConstraint(tip_jacobian, -tip_residual, x) if tip_residual is not None else None
        result = self._qp_solver.Solve(prog)
        if not result.is_success():
            return None, None, None
        lam = np.maximum(result.GetDualSolution(binding), 0.0) if binding is not None else np.zeros(0)
        lam_tip = result.GetDualSolution(tip) if tip is not None else np.zeros(3)
        return result.GetSolution(x), lam, lam_tip

    def _newton(self, model: ReducedChain, lam0: dict | None = None):
        """Second-order SQP; returns (q, converged, reason, iterations, pair multipliers, tip multipliers)."""
        q = np.zeros(model.nq)
        ev = model.evaluate(q, 2)
        rho = 1.0
        escapes = 0
        # The warm start's multipliers (same rows: the same sub-chain in the heart) put the
        # constraints' curvature in the first step's model: about one iteration less.
        lam_near: dict[int, float] = {} if not lam0 else {k: v for k, v in lam0.items() if k < len(ev.gaps)}
        lam_tip = np.zeros(3)
        pinned = model.tip_target is not None
        K = model.n_vectors
        for iteration in range(1, self.max_iterations + 1):
            g, H = ev.gradient, ev.hessian
            near = np.flatnonzero(ev.gaps < self.contact_margin)
            # SQP: the step's quadratic model is the Lagrangian's, with the last multipliers.
            if lam_near:
                pairs = np.array(list(lam_near))
                H = H - model.constraint_hessian(q, pairs, np.array(list(lam_near.values())))
            if pinned and np.any(lam_tip):
                H = H - model.tip_hessian(q, lam_tip)
            dq, Hm, lam, lam_tip = self._newton_step(ev, H, g, near, pinned, lam_tip)
            if dq is None:
                return q, False, "QP step infeasible (rigidity or tip constraints)", iteration, {}, lam_tip
            lam_near = dict(zip(near.tolist(), lam.tolist()))
            violation = _infeasibility(ev, pinned)
            stationarity = g - (ev.jacobian[near].T @ lam if len(near) else 0.0)
            if pinned:
                stationarity = stationarity - ev.tip_jacobian.T @ lam_tip
            # Stationary: the KKT residual is below tolerance, or the Newton step's predicted
            # decrease is at round-off (flat directions, e.g. symmetry about the field axis).
            decrease = -float(g @ dq) - 0.5 * float(dq @ Hm @ dq)
            first_order = np.abs(stationarity).max() < self.tolerance or (
                abs(decrease) < 1e-14 * max(1.0, abs(ev.energy)) and np.abs(stationarity).max() < 1e-6
            )
            if first_order and violation < self.feasibility_tolerance:
                # First-order point: check curvature on the active constraints' tangent space.
                tangent = _negative_curvature(ev, H, near, lam, pinned, model.nq)
                if tangent is None:
                    return (q, True, "local minimum (KKT and second-order conditions)", iteration,
                            lam_near, lam_tip)
                if escapes >= 10:
                    return q, False, "stuck at a saddle point", iteration, lam_near, lam_tip
                escapes += 1
                Z, V = tangent
                dq = 0.1 * (Z @ V[:, 0])
                if model.evaluate(q - dq, 0).energy < model.evaluate(q + dq, 0).energy:
                    dq = -dq
            big = np.abs(dq).max()
            if big > self.max_step:
                dq *= self.max_step / big
            multipliers = np.concatenate([lam, np.abs(lam_tip)])
            if len(multipliers):
                rho = max(rho, 2.0 * float(multipliers.max()))
            merit0 = ev.energy + rho * violation
            slope = float(g @ dq) - rho * violation
            t, dq, trial = _line_search(model, q, dq, ev, near, pinned, rho, merit0, slope)
            if t < 1e-10:
                if np.abs(stationarity).max() < 1e3 * self.tolerance and violation < 1e-9:
                    return (q, True, "local minimum (stationary within line-search precision)", iteration,
                            lam_near, lam_tip)
                return q, False, "line search failed (no descent)", iteration, lam_near, lam_tip
            q = q + t * dq
            if np.abs(q[K:]).max() > 1.2:  # close to the chart's poles: re-centre it
                p, m_hat = model.configuration(q)
                model.chart_from_configuration(p, m_hat)
                q = np.zeros(model.nq)
                lam_near, lam_tip = {}, np.zeros(3)
                ev = model.evaluate(q, 2)
            else:
                ev = trial if trial.hessian is not None else model.evaluate(q, 2)
        return (q, False, f"iteration limit ({self.max_iterations}) reached", self.max_iterations,
                lam_near, lam_tip)

    def _newton_step(self, ev, H, g, near, pinned: bool, lam_tip):
        """The Newton step at ``ev`` for the Lagrangian's Hessian H and gradient g.

        Returns:
            ``(dq, Hm, lam, lam_tip)``: the step, the model's curvature (H made positive
            definite), the multipliers of the rows ``near`` and of the tip target (``lam_tip``
            as given when neither is in play); dq is None when the step's QP is infeasible.
        """
        if pinned and not len(near):
            # Equality constraints only: a null-space step. Only the curvature along the
            # constraints' tangent space matters, so only that part is made positive definite.
            J = ev.tip_jacobian
            Z = _null_space(J)
            dq_n = -np.linalg.pinv(J) @ ev.tip_residual
            Hz = _positive_definite(Z.T @ H @ Z)
            dq = dq_n - Z @ np.linalg.solve(Hz, Z.T @ (g + H @ dq_n))
            Hm = Z @ Hz @ Z.T  # the model's curvature, for the predicted decrease
            lam, lam_tip = np.zeros(0), np.linalg.lstsq(J.T, g + H @ dq, rcond=None)[0]
        elif len(near) or pinned:
            tip = [ev.tip_jacobian] if pinned else []
            N = np.vstack([ev.jacobian[near]] + tip)
            Nt = np.vstack([ev.jacobian[near[ev.gaps[near] <= TOUCHING]]] + tip)
            Hm = _qp_curvature(H, Nt, N)
            dq, lam, lam_tip = self._qp_step(Hm, g, ev.gaps[near], ev.jacobian[near],
                                             ev.tip_residual, ev.tip_jacobian)
        else:
            Hm = _positive_definite(H)
            dq, lam = -np.linalg.solve(Hm, g), np.zeros(0)
        return dq, Hm, lam, lam_tip

    # --- SNOPT reference ------------------------------------------------------------------------
    def _snopt_solve(self, model: ReducedChain):
        prog = MathematicalProgram()
        q = prog.NewContinuousVariables(model.nq, "q")
        cache: dict = {}
        counter = [0]

        def evaluate(x):
            value = ExtractValue(x).reshape(-1)
            key = value.tobytes()
            if cache.get("key") != key:
                cache["key"], cache["ev"] = key, model.evaluate(value, 1)
                counter[0] += 1
            return value, cache["ev"]

        def cost(x):
            _, ev = evaluate(x)
            if x.dtype == float:
                return ev.energy
            return AutoDiffXd(ev.energy, ev.gradient @ ExtractGradient(x))

        def rigidity(x):
            _, ev = evaluate(x)
            if x.dtype == float:
                return ev.gaps
            return InitializeAutoDiff(ev.gaps, ev.jacobian @ ExtractGradient(x)).reshape(-1)

        prog.AddCost(cost, q, description="energy")
        n_pairs = len(model.pair_i)
        binding = None
        if n_pairs:
            binding = prog.AddConstraint(rigidity, np.zeros(n_pairs), np.full(n_pairs, np.inf), q,
                                         description="rigidity")
        prog.AddBoundingBoxConstraint(-1.5, 1.5, q[model.n_vectors :])
        result = self._snopt.Solve(prog, np.zeros(model.nq), self._snopt_options)
        info = result.get_solver_details().info
        lam = {}
        if binding is not None:
            duals = result.GetDualSolution(binding)
            lam = {k: float(v) for k, v in enumerate(duals) if v > 0}
        return (result.GetSolution(q), info == 1, _SNOPT_MESSAGES.get(info, f"SNOPT info {info}"),
                counter[0], lam)


def _null_space(J: np.ndarray, rtol: float = 1e-10) -> np.ndarray:
    """Orthonormal basis (columns) of the null space of J."""
    _, s, Vt = np.linalg.svd(J)
    rank = int((s > rtol * max(1.0, s.max() if len(s) else 0.0)).sum())
    return Vt[rank:].T


def solve_statics(
    chain: BallChain,
    external: FieldSource | None,
    gravity: bool = False,
    warm_start: StaticsResult | None = None,
    method: Method = "newton",
) -> StaticsResult:
    """One equilibrium of ``chain`` in ``external`` (see ChainStatics.solve); raises if not converged."""
    return ChainStatics(chain, gravity=gravity, method=method).solve_or_raise(external, warm_start)


MAX_CONTINUATION_STEPS = 10_000


def _non_finite_field(external, p: np.ndarray) -> str | None:
    """Why the external field is unusable at the balls p (n, 3) (a reason string), or None."""
    if external is None:
        return None
    if isinstance(external, UniformField):  # the same B everywhere, no gradient: B is the answer
        finite = np.all(np.isfinite(np.asarray(external.B_W, float)))
        return None if finite else "the external field is not finite (NaN or inf) at ball 1"
    B, G = external.field_and_gradient(p)  # a source that refuses the points says why (raises)
    bad = ~(np.all(np.isfinite(np.reshape(B, (len(p), -1))), axis=1)
            & np.all(np.isfinite(np.reshape(G, (len(p), -1))), axis=1))
    if np.any(bad):
        return f"the external field is not finite (NaN or inf) at ball {int(np.argmax(bad)) + 1}"
    return None


def rotation_path(start_deg: float, stop_deg: float, step_deg: float) -> np.ndarray:
    """Field angles from start to stop (inclusive) in steps of at most ``step_deg`` [deg]."""
    if not (np.isfinite(step_deg) and step_deg > 0) or not (np.isfinite(start_deg) and np.isfinite(stop_deg)):
        raise UserInputError(f"continuation angles must be finite and the step positive, got {start_deg}, "
                             f"{stop_deg}, step {step_deg}")
    steps = abs(stop_deg - start_deg) / step_deg
    if steps > MAX_CONTINUATION_STEPS:  # bounded work (a 1e-12 deg step once asked for 655 TiB)
        raise UserInputError(f"continuation step {step_deg:g} deg gives {steps:.3g} steps from {start_deg:g} to "
                             f"{stop_deg:g} deg, more than {MAX_CONTINUATION_STEPS}: use a larger step")
    n = max(1, int(np.ceil(steps - 1e-9)))
    return np.linspace(start_deg, stop_deg, n + 1)


def uniform_field_equilibrium(
    chain: BallChain,
    B_W,
    gravity: bool = False,
    wall=None,
    step_deg: float = 22.5,
) -> StaticsResult:
    """The equilibrium reached by turning a uniform field of magnitude |B_W| from +x to B_W.

    The field turns about +x cross B_W in steps of at most ``step_deg`` (continuation from the
    straight chain, as a rotating magnet would move it); raises StaticsError if a step fails.
    """
    B = as_vector(B_W, "B_W", unit="T")
    solver = ChainStatics(chain, gravity=gravity)
    magnitude = float(np.linalg.norm(B))
    if magnitude == 0.0:
        return solver.solve_or_raise(None, wall=wall)
    b_hat = B / magnitude
    axis = np.cross(X_AXIS, b_hat)
    sin_angle, cos_angle = float(np.linalg.norm(axis)), float(X_AXIS @ b_hat)
    axis = axis / sin_angle if sin_angle > 1e-12 else np.array([0.0, 0.0, 1.0])
    result = None
    for angle in np.radians(rotation_path(0.0, np.degrees(np.arctan2(sin_angle, cos_angle)), step_deg)):
        # Rodrigues: +x turned by ``angle`` about ``axis``.
        direction = (np.cos(angle) * X_AXIS + np.sin(angle) * np.cross(axis, X_AXIS)
                     + (1.0 - np.cos(angle)) * (axis @ X_AXIS) * axis)
        result = solver.solve_or_raise(UniformField(magnitude * direction), result, wall=wall)
    return result
