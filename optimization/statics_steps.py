"""The statics' Newton SQP helpers: placing a tip target and a plane wall on the model, the held
tip's Schur step, the rows' infeasibility and the l1-merit line search (``optimization.statics`` re-exports them), and the
continuation's field paths and the field check (``rotation_path``, ``_non_finite_field``).
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.field_sources import UniformField
from ballchain.infrastructure.errors import UserInputError
from ballchain.optimization.compiled_newton import CONVEXIFY
from ballchain.optimization.reduced_chain import ReducedChain


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


def _pinned_step(H: np.ndarray, g: np.ndarray, J: np.ndarray, c: np.ndarray):
    """``(dq, lam, curvature)`` of min g'dq + dq'H dq / 2 subject to J dq + c = 0 by the Schur
    complement of H + rho s J'J (``compiled_newton.pinned_step``, the same rule), or None:
    no rho of ``CONVEXIFY`` makes it positive definite, or J J' or the Schur complement is not
    (the caller takes the null-space step)."""
    s = max(1.0, float(np.abs(np.diag(H)).max()))
    JtJ = J.T @ J
    for rho in CONVEXIFY:
        shift = rho * s
        try:
            L = np.linalg.cholesky(H + shift * JtJ)
        except np.linalg.LinAlgError:
            continue
        break
    else:
        return None
    def cho_solve(L, b):  # (L L')^-1 b
        return np.linalg.solve(L.T, np.linalg.solve(L, b))

    HiJt, Hig = cho_solve(L, J.T), cho_solve(L, g)
    try:
        lam = cho_solve(np.linalg.cholesky(J @ HiJt), J @ Hig - c)
        dq = HiJt @ lam - Hig
        v = dq - J.T @ cho_solve(np.linalg.cholesky(J @ J.T), J @ dq)
    except np.linalg.LinAlgError:
        return None
    return dq, lam + shift * c, float(v @ H @ v)
