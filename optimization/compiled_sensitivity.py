"""The held equilibrium's sensitivity to the magnets' moments: the compiled columns of the
Lagrangian's mixed derivative (issue 48).

The external energy ``U_e = -M sum_k m_hat_k . B(p_k)`` is linear in every source's moment, and
a point dipole's flux density is linear in its moment, so ``d(grad_q U / E0) / d m_j,c`` (the
moment of source j along axis c) is the chart gradient of the external energy under source j
alone with the unit moment e_c: the laws of ``kernels.external`` (``dipole_field_and_gradient``,
``add_external``) carried to the chart by the chain rule of ``kernels.reduced``
(``_points_to_links``, ``_chart_gradient``), the very kernels the solve's gradient runs.
``kkt_solve`` solves the KKT system around them (``held_sensitivity`` builds it), checking it
is regular first.

Kept apart from the Python glue (``held_sensitivity``): numba's cache of a kernel is stamped with
its file (and the kernels' package), so editing the glue does not recompile this.
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.kernels._common import kernel
from ballchain.drake_models.kernels.dense_qp import cholesky
from ballchain.drake_models.kernels.external import add_external, dipole_field_and_gradient
from ballchain.drake_models.kernels.reduced import P_D, P_E0, P_M, _chart_gradient, _points_to_links

# ``kkt_solve``'s status: solved, or why the system is not regular.
KKT_OK, KKT_RANK, KKT_CURVATURE, KKT_SINGULAR = 0, 1, 2, 3


@kernel
def moment_columns(V, p, m_hat, params, centres, r2_min):
    """The mixed derivatives ``d(grad_q U / E0) / d m`` at the configuration (p, m_hat).

    Args:
        V: ``chart_vectors`` (5, K, 3) at the configuration's chart coordinates.
        p, m_hat: (n, 3) the configuration (``chain_configuration`` of V[0]).
        params: ``reduced_params`` (the ball diameter, the balls' moment M, E0).
        centres: (k, 3) the point dipoles' centres [m]; r2_min: (k,) their bounding spheres'
            squared radii [m^2].

    Returns:
        ``(violation, C (nq, 3k))``: column ``3 j + c`` is the derivative with respect to source
        j's moment along axis c [per A m^2]; violation -1, or ``ball * k + j`` of the first ball
        inside source j's bounding sphere (C then incomplete).
    """
    d, M, E0 = params[P_D], params[P_M], params[P_E0]
    n = p.shape[0]
    L = n - 1
    nq = 4 * L
    k = centres.shape[0]
    C = np.zeros((nq, 3 * k))
    centre = np.empty((1, 3))
    unit = np.empty((1, 3))
    r2 = np.empty(1)
    dU_dp = np.empty((n, 3))
    dU_dm = np.empty((n, 3))
    dU_du = np.empty((L, 3))
    column = np.empty(nq)
    inv_E0 = 1.0 / E0
    for j in range(k):
        for e in range(3):
            centre[0, e] = centres[j, e]
        r2[0] = r2_min[j]
        for c in range(3):
            for e in range(3):
                unit[0, e] = 1.0 if e == c else 0.0
            violation, B, G = dipole_field_and_gradient(p, centre, unit, r2)
            if violation >= 0:
                return violation * k + j, C
            dU_dp[:] = 0.0
            dU_dm[:] = 0.0
            add_external(p, m_hat, M, B, G, dU_dp, dU_dm)
            _points_to_links(dU_dp, d, dU_du)
            _chart_gradient(V, dU_du, dU_dm, inv_E0, column)
            for i in range(nq):
                C[i, 3 * j + c] = column[i]
    return -1, C


@kernel
def kkt_solve(H, A, top, bottom, rank_tol, definite_tol):
    """``(status, x (nq, m), y (r, m))`` solving ``[H A'; A 0] [x; y] = [top; bottom]`` for a
    symmetric H (nq, nq) and A (r, nq), r <= nq, when the system is regular; status
    ``KKT_RANK`` when A's smallest singular value is at most ``rank_tol`` times its largest (or
    1), ``KKT_CURVATURE`` when H is not positive definite on A's null space by a margin
    (``H_t - definite_tol max(1, max_i H_t,ii) I`` has no Cholesky factor, H_t = Z' H Z),
    ``KKT_SINGULAR`` when LAPACK finds the matrix singular all the same (x, y then empty)."""
    nq = H.shape[0]
    r = A.shape[0]
    m = top.shape[1]
    none = np.zeros((0, m))
    _, s, Vt = np.linalg.svd(A)
    if not s[r - 1] > rank_tol * max(1.0, s[0]):
        return KKT_RANK, none, none
    Z = np.ascontiguousarray(Vt[r:].T)
    Ht = Z.T @ H @ Z
    scale = 1.0
    for i in range(Ht.shape[0]):
        scale = max(scale, abs(Ht[i, i]))
    for i in range(Ht.shape[0]):
        Ht[i, i] -= definite_tol * scale
    ok, _ = cholesky(Ht)
    if not ok:
        return KKT_CURVATURE, none, none
    K = np.zeros((nq + r, nq + r))
    rhs = np.empty((nq + r, m))
    for i in range(nq):
        for j in range(nq):
            K[i, j] = H[i, j]
        for j in range(r):
            K[i, nq + j] = A[j, i]
            K[nq + j, i] = A[j, i]
        for j in range(m):
            rhs[i, j] = top[i, j]
    for i in range(r):
        for j in range(m):
            rhs[nq + i, j] = bottom[i, j]
    try:
        solution = np.linalg.solve(K, rhs)
    except Exception:  # numba's LinAlgError: a singular matrix
        return KKT_SINGULAR, none, none
    return KKT_OK, np.ascontiguousarray(solution[:nq]), np.ascontiguousarray(solution[nq:])
