"""The Newton steps' QP, ``dense_qp`` (a dual active-set method on a dense positive definite
Hessian), the numpy reference; ``optimization.statics`` re-exports it. ``compiled_dense_qp``: the
same law by the compiled kernels (``kernels.dense_qp``), with ``dense_qp``'s signature and
returns, for the catheter rod's SQP (``rod_statics``, ``systems.rod_wall_friction``).
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.kernels.dense_qp import cholesky as _cholesky
from ballchain.drake_models.kernels.dense_qp import dense_qp as _compiled_qp


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


def compiled_dense_qp(H: np.ndarray, g: np.ndarray, A: np.ndarray, b: np.ndarray, E: np.ndarray | None = None,
                      e: np.ndarray | None = None, max_iterations: int = 200):
    """``dense_qp``'s problem, arguments and returns, solved by the compiled kernels: LAPACK's
    Cholesky factor of H (``kernels.dense_qp.cholesky``) and the kernel's dual active set, whose
    solves with the factor are triangular (the reference's ``np.linalg.solve`` factorises the
    triangle again, by LU). The same law; the floats agree within round-off, not bit for bit
    (``tests/test_rod_qp.py``). Raises ``numpy.linalg.LinAlgError`` when H is not positive
    definite, as the reference's Cholesky does."""
    ok, Lc = _cholesky(np.asarray(H, float))
    if not ok:
        raise np.linalg.LinAlgError("Matrix is not positive definite.")
    b = np.asarray(b, float)
    n_in = len(b)
    if E is None or len(e) == 0:
        N, c = np.ascontiguousarray(A, float).reshape(n_in, len(g)), b
    else:
        N, c = np.vstack([A, E]).astype(float), np.concatenate([b, np.asarray(e, float)])
    ok, x, y = _compiled_qp(Lc, np.asarray(g, float), N, c, n_in, max_iterations)
    if not ok:
        return None, None, None
    return x, y[:n_in], y[n_in:]


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
