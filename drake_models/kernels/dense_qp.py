"""The Newton steps' linear algebra, compiled: a Cholesky factorisation that says whether the
matrix is positive definite, and the dense dual active-set QP of the statics' SQP.

The law of ``optimization/statics.py``'s ``dense_qp`` (its reference): for a positive definite
H, ``min 1/2 x' H x + g' x  s.t.  A x + b >= 0  and  E x + e = 0`` in the dual, the multipliers
minimising ``1/2 y' M y + y' (c - N H^-1 g)`` over ``y = (lam >= 0, mu free)``,
``N = [A; E]``, ``M = N H^-1 N'``, by a Lawson-Hanson active set.
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.kernels._common import kernel


@kernel
def cholesky(H):
    """``(ok, L)``: the lower Cholesky factor of H (n, n), ok False (L of zeros) when H is not
    positive definite: LAPACK's factorisation failed, or left a pivot that is not > 0 (a NaN:
    OpenBLAS's ``potrf`` lets one through).

    LAPACK's blocked ``potrf`` (numba's ``np.linalg.cholesky``, reading H's lower triangle as
    the reference's numpy call does): an unblocked loop here cost 4 times as much at 252 x 252
    (64 balls), where it was most of a Newton iteration."""
    n = H.shape[0]
    try:
        L = np.linalg.cholesky(H)
    except Exception:  # numba's LinAlgError: "Matrix is not positive definite."
        return False, np.zeros((n, n))
    for j in range(n):
        if not L[j, j] > 0.0:
            return False, np.zeros((n, n))
    return True, L


@kernel
def forward(L, B):
    """L^-1 B for lower triangular L and B (n, m)."""
    n, m = B.shape
    X = np.empty((n, m))
    for c in range(m):
        for i in range(n):
            s = B[i, c]
            for k in range(i):
                s -= L[i, k] * X[k, c]
            X[i, c] = s / L[i, i]
    return X


@kernel
def cho_solve(L, b):
    """H^-1 b for H = L L' and b (n,)."""
    n = b.shape[0]
    y = np.empty(n)
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    x = np.empty(n)
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return x


@kernel
def dense_qp(Lc, g, N, c, n_in, max_iterations):
    """The QP's step for H = Lc Lc' (Lc from ``cholesky``), rows N (m, nq) = [A; E] with
    constants c = (b, e), the first ``n_in`` rows inequalities.

    Returns:
        ``(ok, x, y)``: the step and the multipliers (lam then mu); ok False when the rows are
        infeasible (the dual unbounded or a violation left), or the active set cycles.
    """
    m = N.shape[0]
    Hinv_g = cho_solve(Lc, g)
    if m == 0:
        return True, -Hinv_g, np.zeros(0)
    Y = forward(Lc, np.ascontiguousarray(N.T))
    M = Y.T @ Y
    tr = 0.0
    for i in range(m):
        tr += M[i, i]
    delta = 1e-13 * max(1.0, tr)
    for i in range(m):
        M[i, i] += delta  # dependent rows: a unique dual
    r = c - N @ Hinv_g
    y = np.zeros(m)
    free = np.zeros(m, np.bool_)
    free[n_in:] = True  # equality multipliers are never bounded
    r_scale = 1e-12 * max(1.0, np.abs(r).max())
    for _ in range(max_iterations):
        y = _free_minimum(M, r, y, free, n_in)
        w = -(M @ y + r)  # the dual's negative gradient: positive where a bound should be freed
        j = -1
        best = -np.inf
        for i in range(n_in):
            if not free[i] and w[i] > best:
                best, j = w[i], i
        if j < 0 or best <= r_scale:
            if not np.all(np.isfinite(y)) or np.abs(y).max() > 1e12:
                return False, Hinv_g, y
            x = cho_solve(Lc, N.T @ y - g)
            if n_in > 0 and _violation(N, c, x, n_in):
                # The regularisation leaves each free row at -delta y_i, not 0: more than the
                # tolerance when H is nearly singular (a soft mode makes trace(M) huge). Refined
                # against the unregularised dual on the free set, a feasible set's rows close
                # (an infeasible one's stay violated); only then infeasible.
                ok, y = _refined(M, r, y, free, n_in, delta)
                if not ok:
                    return False, x, y
                x = cho_solve(Lc, N.T @ y - g)
                if _violation(N, c, x, n_in):
                    return False, x, y  # infeasible: the regularised dual stops at a violation
            return True, x, y
        free[j] = True
    return False, Hinv_g, y


@kernel
def _free_minimum(M, r, y, free, n_in):
    """Minimise the dual over the free set with the bound ones at zero, stepping back to the
    first inequality multiplier that reaches zero (Lawson-Hanson's inner loop); updates free."""
    m = M.shape[0]
    while True:
        z = np.zeros(m)
        F = np.flatnonzero(free)
        if F.size:
            MF = np.empty((F.size, F.size))
            rF = np.empty(F.size)
            for a in range(F.size):
                rF[a] = -r[F[a]]
                for b in range(F.size):
                    MF[a, b] = M[F[a], F[b]]
            zF = np.linalg.solve(MF, rF)
            for a in range(F.size):
                z[F[a]] = zF[a]
        alpha = np.inf
        for i in range(n_in):
            if free[i] and z[i] < 0.0:
                alpha = min(alpha, y[i] / (y[i] - z[i]))
        if alpha == np.inf:
            return z
        y = y + alpha * (z - y)
        y_max = np.abs(y).max()
        for i in range(n_in):
            if free[i] and y[i] <= 1e-14 * max(1.0, y_max):
                free[i] = False
            if not free[i]:
                y[i] = 0.0


@kernel
def _violation(N, c, x, n_in):
    """Whether an inequality row of the step x is below -1e-8 max(1, |c|) (``dense_qp``'s test)."""
    viol = np.inf
    b_max = 1.0
    for i in range(n_in):
        viol = min(viol, N[i] @ x + c[i])
        b_max = max(b_max, abs(c[i]))
    return viol < -1e-8 * b_max


@kernel
def _refined(M, r, y, free, n_in, delta):
    """``(ok, y)``: the dual y refined on the free set towards the unregularised system
    (``statics._refined``: three rounds of iterative refinement with the regularised M_FF); ok
    False when a refined inequality multiplier turns negative or y is not finite."""
    F = np.flatnonzero(free)
    y = y.copy()
    MF = np.empty((F.size, F.size))
    for a in range(F.size):
        for b in range(F.size):
            MF[a, b] = M[F[a], F[b]]
    yF = np.empty(F.size)
    for a in range(F.size):
        yF[a] = y[F[a]]
    for _ in range(3):
        res = np.empty(F.size)
        MyF = MF @ yF
        for a in range(F.size):
            res[a] = -(r[F[a]] + MyF[a] - delta * yF[a])
        yF = yF + np.linalg.solve(MF, res)
    for a in range(F.size):
        y[F[a]] = yF[a]
    if not np.all(np.isfinite(y)):
        return False, y
    for i in range(n_in):
        if y[i] < 0.0:
            return False, y
    return True, y
