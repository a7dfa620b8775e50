"""Inverse statics: magnet orientations that press the chain's tip on a wall target.

The forward problem (``statics``) gives the equilibrium for given magnets. Here the tip ball's
centre is held at a point on the target (a ball radius off the wall, within the target's
circle) and the unknowns are the magnets' dipole directions and where in the circle the tip
touches. ``HeldTip`` gives the force the tip presses on the wall at that held equilibrium,
split into the normal part and the tangential part: an implicit function of the unknowns
(each evaluation a warm-started ``ChainStatics`` solve, so it follows the branch the real chain
follows when the magnets turn slowly).

A held equilibrium is a real contact equilibrium only if the wall can supply the tangential
part: friction. ``min_turn_orientation`` is the MathematicalProgram of one planning step:

    minimise    sum_j |m_j - m_j^prev|^2              (the magnets' turn from where they are)
    subject to  |m_j|^2 = 1                            (dipole directions)
                |o|^2 <= r^2                           (touch point o within the target circle)
                F_n(m, o) >= F_min                     (the tip presses at least F_min)
                |F_t| <= mu F_n                        (Coulomb friction holds the tip)

solved by SNOPT. The constraint gradients are the held equilibrium's sensitivities
(``held_sensitivity``: the implicit function theorem on its KKT system, one linear solve),
forward differences of warm-started equilibria where that does not apply. The answer
is re-checked by turning the magnets from the start to it in small steps (the branch the chain
follows); "feasible" means that re-checked equilibrium meets every constraint.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue, InitializeAutoDiff
from pydrake.solvers import MathematicalProgram, SnoptSolver, SolverOptions

from ballchain.drake_models.field_sources import FieldSource, require_field_source
from ballchain.drake_models.kernels import chain_configuration, chart_vectors
from ballchain.infrastructure.arg_checks import as_rows, as_vector, require_int, require_positive, require_type
from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.optimization.compiled_held_tip import held_solve
from ballchain.optimization.held_sensitivity import pressing_sensitivity
from ballchain.optimization.statics import ChainStatics, StaticsResult

FieldFor = Callable[[np.ndarray], FieldSource]  # (k, 3) unit dipole directions -> external field


def pin_tip(solver: ChainStatics, external: FieldSource, target: np.ndarray, start: StaticsResult | None,
            steps: int = 8) -> StaticsResult | None:
    """The equilibrium with the tip moved from where it is onto ``target`` in ``steps`` (homotopy).

    Each step is warm-started from the last, as a hand would move the tip. Returns None when a
    step does not converge (no held equilibrium on this branch).
    """
    require_type(solver, ChainStatics, "pin_tip solver", "a ChainStatics")
    require_field_source(external, "pin_tip external", allow_none=True)
    as_vector(target, "pin_tip target", unit="m")
    if start is not None:
        require_type(start, StaticsResult, "pin_tip start", "a StaticsResult or None")
    require_int(steps, "pin_tip steps", 1)
    current = start if start is not None else solver.solve(external)
    if not current.converged:
        return None
    origin = current.tip_position.copy()
    for s in np.linspace(0.0, 1.0, steps + 1)[1:]:
        current = held_solve(solver, external, current, origin + s * (np.asarray(target) - origin))
        if not current.converged:
            return None
    return current


def _predicted(solver: ChainStatics, tangent, x) -> StaticsResult | None:
    """The held equilibrium at x predicted to first order from ``tangent`` = (an equilibrium,
    its x, dq/dx, its chart): a warm start (None when the step in the chart is beyond 1 rad)."""
    base, x0, T, chart = tangent
    dq = T @ (np.asarray(x, float) - x0)
    if not np.all(np.abs(dq) <= 1.0):
        return None
    V = chart_vectors(dq, *chart)
    p, m = chain_configuration(V[0], base.positions.shape[0] - 1, solver.chain.ball_diameter)
    return StaticsResult(p, m, float("nan"), base.terms, True, "", "newton", 0, 0.0)


def _unit_rows(m: np.ndarray) -> np.ndarray:
    m = np.asarray(m, dtype=float).reshape(-1, 3)
    norms = np.linalg.norm(m, axis=1, keepdims=True)
    if np.any(norms == 0) or not np.all(np.isfinite(m)):
        raise UserInputError(f"dipole directions must be finite and non-zero, got {m.tolist()}")
    return m / norms


class HeldTip:
    """The tip held on a wall target, as a function of x = (stacked dipole directions, o).

    Args:
        solver: statics of the chain (its ``max_iterations`` bounds the effort per evaluation).
        field_for: (k, 3) dipole directions -> the external field.
        centre: (3,) the tip ball's centre when it touches the target's centre [m] (a ball
            radius off the wall).
        axis: (3,) unit wall normal pointing into the wall (the direction the tip presses).
        home: the held equilibrium at the starting unknowns (the warm start of the first
            evaluation, the fallback when a warm start from the last fails).
        n_magnets: k.

    The touch point's offset o (2,) [m] is along ``basis[:, 1:]``, two unit vectors in the wall.

    ``predict`` (False by default): an evaluation right after an analytic Jacobian is first solved
    from the configuration its tangent (``held_sensitivity.pressing_sensitivity``'s dq/dx)
    predicts, then from the last equilibrium and home as always: SNOPT's next point takes 3-4
    Newton steps instead of 5 (issue 48: a sixth of a cold plan). Off by default: from a
    predicted start the held solve can land on another branch of equilibria than the one the
    last Jacobian described, and SNOPT's model of the constraint breaks; on a user anatomy's
    two-unit target (``tests/test_procedure.py``'s four-target lumen, its third target) the
    15 gf program from the hardest press then ran into SNOPT's iteration limit (389
    evaluations) where without the prediction it answers in 94, and the target was planned
    at 10 gf, below the navigator's window.
    """

    def __init__(self, solver: ChainStatics, field_for: FieldFor, centre, axis, home: StaticsResult,
                 n_magnets: int = 1):
        require_type(solver, ChainStatics, "HeldTip solver", "a ChainStatics")
        if not callable(field_for):
            raise UserInputError("HeldTip field_for must be a function of the dipole directions, got "
                                 f"{short_repr(field_for)}")
        as_vector(centre, "HeldTip centre", unit="m")
        as_vector(axis, "HeldTip axis", nonzero=True)
        require_type(home, StaticsResult, "HeldTip home", "a StaticsResult")
        require_int(n_magnets, "HeldTip n_magnets", 1)
        self.solver = solver
        self.field_for = field_for
        self.centre = np.asarray(centre, dtype=float).reshape(3)
        n = np.asarray(axis, dtype=float).reshape(3)
        n = n / np.linalg.norm(n)
        u = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        self.basis = np.column_stack([n, u, np.cross(n, u)])
        self.k = n_magnets
        self.home = home
        self._last = home
        self.evaluations = 0
        self.jacobians = {"analytic": 0, "fd": 0}
        self._tangent = None  # (equilibrium, its x, dq/dx, its chart) of the last analytic Jacobian

    predict = False  # warm-start from the last analytic Jacobian's first-order prediction (see above)

    @property
    def axis(self) -> np.ndarray:
        return self.basis[:, 0]

    def split(self, x) -> tuple[np.ndarray, np.ndarray]:
        x = np.asarray(x, dtype=float).reshape(-1)
        return _unit_rows(x[: 3 * self.k]), x[3 * self.k:]

    def tip_point(self, offset) -> np.ndarray:
        return self.centre + self.basis[:, 1:] @ np.asarray(offset, dtype=float)

    def restart(self) -> None:
        """Warm-start the next evaluation from ``home`` (not from the last one)."""
        self._last = self.home

    def equilibrium(self, x) -> StaticsResult | None:
        """The held equilibrium at x, or None when none converges near the last or home (nor
        near the last tangent's prediction, ``predict``)."""
        m, offset = self.split(x)
        external = self.field_for(m)
        target = self.tip_point(offset)
        self._at = (external, target)  # the field and target of the last equilibrium (its Jacobian's)
        self.evaluations += 1
        starts = (self._last, self.home)
        if self.predict and self._tangent is not None and self._tangent[0] is self._last:
            guess = _predicted(self.solver, self._tangent, x)
            if guess is not None:
                starts = (guess, self._last, self.home)
        for start in starts:
            result = held_solve(self.solver, external, start, target)  # solver.solve's answer (issue 48)
            if result.converged:
                self._last = result
                return result
        return None

    def pressing(self, x) -> tuple[np.ndarray | None, StaticsResult | None]:
        """(F_n, F_u, F_v) [N], the force the tip presses on the wall in ``basis``, and the
        equilibrium; (None, None) without a held equilibrium."""
        result = self.equilibrium(x)
        if result is None:
            return None, None
        return self.basis.T @ (-result.tip_reaction), result

    def value_and_jacobian(self, x, step: float = 1e-5,
                           method: str = "analytic") -> tuple[np.ndarray | None, np.ndarray]:
        """``pressing`` and its Jacobian (3, len(x)) with respect to the raw x (the direction rows
        before ``split`` makes them unit).

        ``method``: "analytic" (default): the implicit function theorem on the held equilibrium's
        KKT system (``held_sensitivity.pressing_jacobian``: one linear solve), falling back to
        forward differences where that law does not apply (a field the kernels do not evaluate,
        a singular KKT system); "fd": forward differences (``step`` for the directions, ``1e-3
        step`` m for o: 3k + 2 more held solves, each warm-started at x: off by 1e-5 to 4e-5 of
        the Jacobian's norm on the right ring's targets, since a solve a step away stops after one
        Newton step whose multiplier is an estimate; the analytic one is within 2e-9 of central
        differences of converged solves, ``tests/test_held_sensitivity.py``). ``jacobians``
        counts the Jacobians of each kind.
        """
        if method not in ("analytic", "fd"):
            raise UserInputError(f"HeldTip.value_and_jacobian method must be 'analytic' or 'fd', got "
                                 f"{short_repr(method)}")
        x = np.asarray(x, dtype=float).reshape(-1)
        f0, base = self.pressing(x)
        J = np.zeros((3, x.size))
        if base is None:
            return None, J
        if method == "analytic":
            external, target = self._at
            out = pressing_sensitivity(self.solver, external, base, target, x[: 3 * self.k].reshape(-1, 3), self.basis)
            if out is not None:
                self.jacobians["analytic"] += 1
                self._tangent = (base, x.copy(), out[1], out[2])
                return f0, out[0]
        self.jacobians["fd"] += 1
        for i in range(x.size):
            dx = x.copy()
            dx[i] += step * (1.0 if i < 3 * self.k else 1e-3)  # o in m: 1e-8 m steps
            self._last = base
            fi, _ = self.pressing(dx)
            if fi is not None:
                J[:, i] = (fi - f0) / (dx[i] - x[i])
        self._last = base
        return f0, J


@dataclass
class OrientationPlan:
    """One planning step's answer.

    Attributes:
        feasible: the re-checked equilibrium meets every constraint.
        dipoles: (k, 3) unit dipole directions.
        offset: (2,) touch point's offset from the target centre [m].
        force_N: the normal force at the re-checked equilibrium [N] (None if none).
        friction_needed: |F_t| / F_n there (None if none).
        turn_rad: (k,) each magnet's turn from its previous direction [rad].
        result: the re-checked held equilibrium (None if none).
        solver_status: SNOPT's result code and info, or what the re-check found.
        evaluations: equilibrium solves the program used.
    """

    feasible: bool
    dipoles: np.ndarray
    offset: np.ndarray
    force_N: float | None
    friction_needed: float | None
    turn_rad: np.ndarray
    result: StaticsResult | None
    solver_status: str
    evaluations: int


def min_turn_orientation(held: HeldTip, m_start, m_previous, min_force: float, target_radius: float,
                         friction: float = 0.0, major_iterations: int = 100) -> OrientationPlan:
    """The smallest turn of the magnets from ``m_previous`` that presses the target hard enough.

    Args:
        held: the held tip of this target; ``held.home`` is the equilibrium at ``m_start``
            with the tip on the target's centre.
        m_start: (k, 3) initial guess of the dipole directions.
        m_previous: (k, 3) where the magnets point now.
        min_force: F_min [N], > 0.
        target_radius: r [m], >= 0: the touch point may be this far from the target's centre.
        friction: mu >= 0 of the tip on the wall (0: frictionless, |F_t| = 0).
        major_iterations: SNOPT's major iteration limit. The optimum is flat along the target
            circle and SNOPT creeps along it with the friction cone active; on the right ring's
            first target 16 balls were feasible after 25 iterations (94.3 deg turn, 33
            evaluations; 93.6 deg converged after 211) but 12 balls needed 60 (96.7 deg) with
            forward-difference gradients. With the analytic ones (issue 48) SNOPT's path
            differs: 16 balls converge within 60 (93.59 deg, 271 evaluations; the differences
            stopped there at 93.95 deg), 12 balls need between 60 and 100 (96.68 deg, 310
            evaluations, the answer of the differences): the limit is 100, an iteration
            costing about a sixth of what it did.

    Returns:
        an OrientationPlan (``feasible`` False: no orientation met the constraints; ``dipoles``
        is then SNOPT's last iterate).
    """
    require_type(held, HeldTip, "held", "a HeldTip")
    as_rows(m_start, "m_start", held.k, nonzero=True)
    as_rows(m_previous, "m_previous", held.k, nonzero=True)
    require_positive(min_force, "min_force", "N")
    require_positive(target_radius, "target_radius", "m", allow_zero=True)
    require_positive(friction, "friction", allow_zero=True)
    require_int(major_iterations, "major_iterations", 1)
    if not min_force > 0 or target_radius < 0 or friction < 0:
        raise UserInputError(f"need min_force > 0 N, target_radius >= 0 m, friction >= 0; got "
                         f"{min_force}, {target_radius}, {friction}")
    m_prev = _unit_rows(m_previous)
    m0 = _unit_rows(m_start)
    k = m_prev.shape[0]
    if m0.shape != m_prev.shape or k != held.k:
        raise UserInputError(f"m_start {m0.shape} and m_previous {m_prev.shape} must both be ({held.k}, 3)")
    prog = MathematicalProgram()
    m = prog.NewContinuousVariables(3 * k, "m")
    w = prog.NewContinuousVariables(2, "w")  # the touch point's offset in target radii: o = r w
    x = np.concatenate([m, w])
    for j in range(k):
        mj = m[3 * j: 3 * j + 3]
        unit = mj[0] * mj[0] + mj[1] * mj[1] + mj[2] * mj[2] == 1.0
        prog.AddConstraint(unit).evaluator().set_description(f"unit dipole {j + 1}")
    prog.AddConstraint(w[0] * w[0] + w[1] * w[1] <= 1.0).evaluator().set_description("touch within the circle")
    prog.AddBoundingBoxConstraint(-1.0, 1.0, m)
    prog.AddBoundingBoxConstraint(-1.0, 1.0, w)  # SNOPT keeps bounds at every iterate
    prog.AddQuadraticErrorCost(np.eye(3 * k), m_prev.reshape(-1), m)
    scale = 1.0 / min_force  # constraints in units of the asked force

    def constraint_values(F):  # [F_n, (mu F_n)^2 - |F_t|^2] in units of the asked force
        return np.array([scale * F[0], scale**2 * ((friction * F[0]) ** 2 - F[1] ** 2 - F[2] ** 2)])

    def constraint_jacobian(F, J):
        return np.vstack([scale * J[0], scale**2 * 2 * (friction**2 * F[0] * J[0] - F[1] * J[1] - F[2] * J[2])])

    n_rows = 2
    failed = np.array([-1e3, -1e3])

    to_held = np.concatenate([np.ones(3 * k), np.full(2, target_radius)])  # (m, w) -> (m, o)

    def contact(xv):
        if xv.dtype == float:
            F, _ = held.pressing(to_held * xv)
            return failed if F is None else constraint_values(F)
        value = ExtractValue(xv).reshape(-1)
        F, J = held.value_and_jacobian(to_held * value)
        J = J * to_held
        if F is None:
            return InitializeAutoDiff(failed, np.zeros((n_rows, xv.size)) @ ExtractGradient(xv)).reshape(-1)
        return InitializeAutoDiff(constraint_values(F), constraint_jacobian(F, J) @ ExtractGradient(xv)).reshape(-1)

    prog.AddConstraint(contact, np.array([1.0, 0.0]), np.full(2, np.inf), x,
                       description="tip presses >= F_min, inside the friction cone")
    snopt = SnoptSolver()
    options = SolverOptions()
    options.SetOption(snopt.solver_id(), "Major iterations limit", major_iterations)
    options.SetOption(snopt.solver_id(), "Major optimality tolerance", 1e-4)
    options.SetOption(snopt.solver_id(), "Major feasibility tolerance", 1e-5)
    evaluations_before = held.evaluations
    out = snopt.Solve(prog, np.concatenate([m0.reshape(-1), np.zeros(2)]), options)
    dipoles = _unit_rows(out.GetSolution(m))
    w_value = out.GetSolution(w)
    offset = target_radius * w_value / max(1.0, float(np.linalg.norm(w_value)))  # onto the circle (SNOPT: 1e-5)
    status = f"{out.get_solution_result().name} (info {out.get_solver_details().info})"
    # Re-check by turning the magnets and sliding the touch point from the start in small steps:
    # the branch the chain follows.
    held.restart()
    F, result = None, None
    for s in np.linspace(0.0, 1.0, 6)[1:]:
        F, result = held.pressing(np.concatenate([((1.0 - s) * m0 + s * dipoles).reshape(-1), s * offset]))
        if result is None:
            break
    turn = np.arccos(np.clip(np.sum(dipoles * m_prev, axis=1), -1.0, 1.0))
    feasible, friction_needed = False, None
    if result is not None:
        friction_needed = float(np.hypot(F[1], F[2]) / F[0]) if F[0] > 0 else np.inf
        feasible = (F[0] >= min_force * (1.0 - 1e-4) and np.linalg.norm(offset) <= target_radius * (1.0 + 1e-6)
                    and np.hypot(F[1], F[2]) <= friction * F[0] + 1e-3 * min_force)
    return OrientationPlan(feasible, dipoles, offset, None if result is None else float(F[0]), friction_needed,
                           turn, result, status, held.evaluations - evaluations_before)


def max_force_orientation(held: HeldTip, m_start, target_radius: float, friction: float,
                          force_scale: float, major_iterations: int = 30,
                          recheck_steps: int = 5, max_evaluations: int = 400) -> OrientationPlan:
    """The magnet directions that press the target hardest inside the friction cone.

    The MathematicalProgram of ``min_turn_orientation`` with the force as the cost:

        maximise    F_n(m, o)
        subject to  |m_j|^2 = 1,  |o|^2 <= r^2,  |F_t| <= mu F_n

    solved by SNOPT from ``m_start`` (with ``held.home`` its held equilibrium), the gradients
    ``HeldTip.value_and_jacobian``'s. The answer is re-checked by turning the
    magnets from the start to it in ``recheck_steps`` steps (the branch the chain follows).

    Args:
        held: the held tip of this target.
        m_start: (k, 3) initial dipole directions.
        target_radius: r [m], >= 0 (0: the tip held on the centre, as on a sensor pin).
        friction: mu >= 0 of the tip on the wall.
        force_scale: a typical force [N] (the cost and constraints are scaled by it).
        major_iterations: SNOPT's major iteration limit.
        recheck_steps: steps of the re-check.
        max_evaluations: equilibria the program may solve; beyond them every evaluation returns
            the last values with zero gradient, so SNOPT stops (where held equilibria keep
            failing, each failed one costs two full solves).

    Returns:
        an OrientationPlan; ``force_N`` is the re-checked normal force, ``feasible`` whether
        that equilibrium is inside the cone (``turn_rad`` is the turn from ``m_start``).
    """
    require_type(held, HeldTip, "held", "a HeldTip")
    as_rows(m_start, "m_start", held.k, nonzero=True)
    require_positive(target_radius, "target_radius", "m", allow_zero=True)
    require_positive(friction, "friction", allow_zero=True)
    require_positive(force_scale, "force_scale", "N")
    for name, value in (("major_iterations", major_iterations), ("recheck_steps", recheck_steps),
                        ("max_evaluations", max_evaluations)):
        require_int(value, name, 1)
    if not force_scale > 0 or target_radius < 0 or friction < 0:
        raise ValueError(f"need force_scale > 0 N, target_radius >= 0 m, friction >= 0; got "
                         f"{force_scale}, {target_radius}, {friction}")
    m0 = _unit_rows(m_start)
    k = m0.shape[0]
    if k != held.k:
        raise ValueError(f"m_start has {k} rows, the held tip has {held.k} magnets")
    prog = MathematicalProgram()
    m = prog.NewContinuousVariables(3 * k, "m")
    w = prog.NewContinuousVariables(2, "w")  # o = r w
    x = np.concatenate([m, w])
    for j in range(k):
        mj = m[3 * j: 3 * j + 3]
        prog.AddConstraint(mj[0] * mj[0] + mj[1] * mj[1] + mj[2] * mj[2] == 1.0).evaluator().set_description(
            f"unit dipole {j + 1}")
    prog.AddConstraint(w[0] * w[0] + w[1] * w[1] <= 1.0).evaluator().set_description("touch within the circle")
    prog.AddBoundingBoxConstraint(-1.0, 1.0, m)
    prog.AddBoundingBoxConstraint(-1.0, 1.0, w)
    to_held = np.concatenate([np.ones(3 * k), np.full(2, target_radius)])
    before = held.evaluations
    cost, cone = _force_cost_and_cone(held, to_held, 1.0 / force_scale, friction, max_evaluations)
    prog.AddCost(cost, x, description="minus the normal force")
    prog.AddConstraint(cone, np.zeros(1), np.full(1, np.inf), x, description="inside the friction cone")
    snopt = SnoptSolver()
    options = SolverOptions()
    options.SetOption(snopt.solver_id(), "Major iterations limit", major_iterations)
    options.SetOption(snopt.solver_id(), "Major optimality tolerance", 1e-4)
    options.SetOption(snopt.solver_id(), "Major feasibility tolerance", 1e-5)
    out = snopt.Solve(prog, np.concatenate([m0.reshape(-1), np.zeros(2)]), options)
    dipoles = _unit_rows(out.GetSolution(m))
    w_value = out.GetSolution(w)
    offset = target_radius * w_value / max(1.0, float(np.linalg.norm(w_value)))
    status = f"{out.get_solution_result().name} (info {out.get_solver_details().info})"
    if held.evaluations - before > max_evaluations:
        status += f", stopped after {max_evaluations} equilibria"
    return _recheck_max_force(held, m0, dipoles, offset, recheck_steps, friction, force_scale, status, before)


def _force_cost_and_cone(held: HeldTip, to_held, scale: float, friction: float, max_evaluations: int):
    """``max_force_orientation``'s cost (minus the normal force) and friction-cone constraint
    for SNOPT, in units of the force scale (``scale`` = 1 / force_scale), over x = (m, w): one
    held equilibrium per point (``to_held`` maps x to the held tip's (m, o)), its Jacobian when
    SNOPT asks for gradients; beyond ``max_evaluations`` equilibria, the last values with zero
    gradient."""
    cache: dict = {}
    before = held.evaluations

    def evaluate(value, with_jacobian):  # SNOPT asks for the cost and the cone at the same points
        key = value.tobytes()
        if held.evaluations - before > max_evaluations and "F" in cache:
            J = cache["J"]
            return cache["F"], None if J is None else np.zeros_like(J)
        if cache.get("key") != key or (with_jacobian and cache["J"] is None):
            if with_jacobian:
                F, J = held.value_and_jacobian(to_held * value)
                J = None if F is None else J * to_held
            else:
                (F, _), J = held.pressing(to_held * value), None
            cache.update(key=key, F=F, J=J)
        return cache["F"], cache["J"]

    def cost(xv):
        if xv.dtype == float:
            F, _ = evaluate(np.asarray(xv, float), False)
            return 1e3 if F is None else -scale * F[0]
        value = ExtractValue(xv).reshape(-1)
        F, J = evaluate(value, True)
        if F is None:
            return AutoDiffXd(1e3, np.zeros(xv.size) @ ExtractGradient(xv))
        return AutoDiffXd(-scale * F[0], -scale * J[0] @ ExtractGradient(xv))

    def cone(xv):  # (mu F_n)^2 - |F_t|^2 >= 0, in units of the force scale
        if xv.dtype == float:
            F, _ = evaluate(np.asarray(xv, float), False)
            return np.array([-1e3]) if F is None else np.array([scale**2 * ((friction * F[0]) ** 2 - F[1] ** 2 - F[2] ** 2)])
        value = ExtractValue(xv).reshape(-1)
        F, J = evaluate(value, True)
        if F is None:
            return InitializeAutoDiff(np.array([-1e3]), np.zeros((1, xv.size)) @ ExtractGradient(xv)).reshape(-1)
        row = scale**2 * 2 * (friction**2 * F[0] * J[0] - F[1] * J[1] - F[2] * J[2])
        return InitializeAutoDiff(np.array([scale**2 * ((friction * F[0]) ** 2 - F[1] ** 2 - F[2] ** 2)]),
                                  row[None, :] @ ExtractGradient(xv)).reshape(-1)

    return cost, cone


def _recheck_max_force(held: HeldTip, m0, dipoles, offset, recheck_steps: int, friction: float,
                       force_scale: float, status: str, before: int) -> OrientationPlan:
    """``max_force_orientation``'s answer re-checked: the magnets turned from m0 to ``dipoles``
    and the touch point slid to ``offset`` in ``recheck_steps`` steps (the branch the chain
    follows); the plan of that equilibrium (``before``: the held tip's evaluations at the start)."""
    held.restart()
    F, result = None, None
    for s in np.linspace(0.0, 1.0, recheck_steps + 1)[1:]:
        F, result = held.pressing(np.concatenate([((1.0 - s) * m0 + s * dipoles).reshape(-1), s * offset]))
        if result is None:
            break
    turn = np.arccos(np.clip(np.sum(dipoles * m0, axis=1), -1.0, 1.0))
    feasible, friction_needed, force = False, None, None
    if result is not None:
        force = float(F[0])
        friction_needed = float(np.hypot(F[1], F[2]) / F[0]) if F[0] > 0 else np.inf
        feasible = F[0] > 0 and np.hypot(F[1], F[2]) <= friction * F[0] + 1e-3 * force_scale
    return OrientationPlan(feasible, dipoles, offset, force, friction_needed, turn, result, status,
                           held.evaluations - before)


def _direction(angles) -> np.ndarray:
    az, el = angles
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def _angles(u) -> np.ndarray:
    return np.array([np.arctan2(u[1], u[0]), np.arcsin(np.clip(u[2], -1.0, 1.0))])


def max_force_penalised(held: HeldTip, m_start, target_radius: float, friction: float, force_scale: float,
                        evaluations: int = 80, penalty: float = 10.0):
    """A derivative-free companion of ``max_force_orientation`` that starts from outside the cone.

    Nelder-Mead over each magnet's (azimuth, elevation) and the touch point w (o = r w) on the
    exact penalty ``F_n - penalty * max(0, |F_t| - mu F_n)``, each evaluation warm-started from
    the best held equilibrium so far. SNOPT started outside the cone often walks to a feasible
    point that presses almost nothing; this finds the cone's best region first.

    Returns:
        ``(dipoles (k, 3), equilibrium, F (3,) in held.basis [N])`` of the best evaluation.
    """
    require_type(held, HeldTip, "held", "a HeldTip")
    as_rows(m_start, "m_start", held.k, nonzero=True)
    require_positive(target_radius, "target_radius", "m", allow_zero=True)
    require_positive(friction, "friction", allow_zero=True)
    require_positive(force_scale, "force_scale", "N")
    require_int(evaluations, "evaluations", 1)
    require_positive(penalty, "penalty", allow_zero=True)
    from scipy.optimize import minimize

    m0 = _unit_rows(m_start)
    k = m0.shape[0]
    F0, _ = held.pressing(np.concatenate([m0.reshape(-1), np.zeros(2)]))
    best = {"value": -np.inf, "m": m0, "result": held.home, "F": F0}

    def objective(x):
        m = np.array([_direction(x[2 * j: 2 * j + 2]) for j in range(k)])
        w = x[2 * k:]
        w_norm = float(np.linalg.norm(w))
        held._last = best["result"]
        F, result = held.pressing(np.concatenate([m.reshape(-1), target_radius * w / max(1.0, w_norm)]))
        if F is None:
            return 1e3
        value = F[0] - penalty * max(0.0, float(np.hypot(F[1], F[2])) - friction * F[0]) - 1e-3 * max(0.0, w_norm - 1.0)
        if value > best["value"]:
            best.update(value=value, m=m, result=result, F=F)
        return -value / force_scale

    x0 = np.concatenate([np.concatenate([_angles(u) for u in m0]), np.zeros(2)])
    minimize(objective, x0, method="Nelder-Mead", options={"maxfev": evaluations, "xatol": 1e-3, "fatol": 1e-6})
    return best["m"], best["result"], best["F"]
