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

``StaticsResult`` and ``StaticsError`` live in ``statics_result``, ``dense_qp`` in
``active_set_qp``, the line search and the continuation's ``rotation_path`` in ``statics_steps``
(all re-exported here), the SNOPT reference's program in ``statics_snopt``.
"""

from __future__ import annotations

import time
from typing import Iterable

import numpy as np
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
from ballchain.infrastructure.arg_checks import (as_plane, as_vector, require_bool, require_int, require_positive,
                                                 require_type)
from ballchain.infrastructure.errors import UserInputError
from ballchain.optimization import compiled_model
from ballchain.optimization.active_set_qp import _refined, dense_qp  # noqa: F401 (re-exported)
from ballchain.optimization.compiled_newton import CONVEXIFY, TOUCHING
from ballchain.optimization.reduced_chain import X_AXIS, ReducedChain, answer_verdict
from ballchain.optimization.statics_snopt import _SNOPT_MESSAGES, snopt_solve  # noqa: F401
from ballchain.optimization.statics_result import (  # noqa: F401 (re-exported)
    Method,
    StaticsError,
    StaticsResult,
    straight_chain,
    tip_angle_deg,
)
from ballchain.optimization.statics_steps import (  # noqa: F401 (re-exported)
    MAX_CONTINUATION_STEPS,
    _infeasibility,
    _line_search,
    _non_finite_field,
    _pinned_step,
    _set_tip_target_and_wall,
    rotation_path,
)
from ballchain.optimization.wall_constraints import ConstrainedChain, HeartConstraints

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


MAX_BALLS = 200  # dense Hessians: 200 balls take about 0.5 GB


MAX_TOLERANCE = 1e-3
"""The loosest stationarity tolerance ``ChainStatics`` takes (the engine uses 1e-6, the statics 1e-8)."""


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
        if tolerance > MAX_TOLERANCE:  # a looser one calls any point stationary: a result that is not one
            raise UserInputError(f"ChainStatics tolerance must be in (0, {MAX_TOLERANCE:g}] (on the scaled energy "
                                 f"gradient), got {tolerance!r}")
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
            dq, curvature, lam, lam_tip = self._newton_step(ev, H, g, near, pinned, lam_tip)
            if dq is None:
                return q, False, "QP step infeasible (rigidity or tip constraints)", iteration, {}, lam_tip
            lam_near = dict(zip(near.tolist(), lam.tolist()))
            violation = _infeasibility(ev, pinned)
            stationarity = g - (ev.jacobian[near].T @ lam if len(near) else 0.0)
            if pinned:
                stationarity = stationarity - ev.tip_jacobian.T @ lam_tip
            # Stationary: the KKT residual is below tolerance, or the Newton step's predicted
            # decrease is at round-off (flat directions, e.g. symmetry about the field axis).
            decrease = -float(g @ dq) - 0.5 * curvature
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
            ``(dq, curvature, lam, lam_tip)``: the step, dq' Hm dq for the model's curvature Hm
            (H made positive definite where it must be), the multipliers of the rows ``near`` and of the tip target (``lam_tip``
            as given when neither is in play); dq is None when the step's QP is infeasible.
        """
        if pinned and not len(near):
            # Equality constraints only: the KKT step by the Schur complement of H + rho s J'J
            # (``_pinned_step``), else a null-space step. Only the curvature along the
            # constraints' tangent space matters, so only that part is made positive definite.
            J = ev.tip_jacobian
            step = _pinned_step(H, g, J, ev.tip_residual) or _null_space_step(H, g, J, ev.tip_residual)
            dq, lam_tip, curvature = step
            return dq, curvature, np.zeros(0), lam_tip
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
        return dq, (None if dq is None else float(dq @ Hm @ dq)), lam, lam_tip

    # --- SNOPT reference ------------------------------------------------------------------------
    def _snopt_solve(self, model: ReducedChain):
        return snopt_solve(self._snopt, self._snopt_options, model)


def _null_space_step(H: np.ndarray, g: np.ndarray, J: np.ndarray, c: np.ndarray):
    """``(dq, lam, curvature)`` of min g'dq + dq'H dq / 2 subject to J dq + c = 0 by the null
    space Z of J, Z'HZ made positive definite (``_positive_definite``); curvature dq'Hm dq for
    the model's curvature Hm = Z Hz Z' (the predicted decrease's). ``_pinned_step``'s fallback."""
    Z = _null_space(J)
    dq_n = -np.linalg.pinv(J) @ c
    Hz = _positive_definite(Z.T @ H @ Z)
    dq = dq_n - Z @ np.linalg.solve(Hz, Z.T @ (g + H @ dq_n))
    Hm = Z @ Hz @ Z.T
    return dq, np.linalg.lstsq(J.T, g + H @ dq, rcond=None)[0], float(dq @ Hm @ dq)


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
