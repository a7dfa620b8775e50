"""The chain's energy in reduced coordinates (unit links and free dipoles, each in its chart),
with its exact gradient and Hessian: the Cartesian laws (``pair``, ``external``, ``gravity``,
``sleeve``) carried to the chart coordinates by the chain rule of ``optimization/reduced_chain.py``.

Memory is O(n^2): the pair sums run as loops, the Cartesian-to-link chain rule as suffix sums,
without pair-by-link incidence matrices.
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.dipole import K_DIPOLE
from ballchain.drake_models.kernels._common import (
    COINCIDENT,
    OK,
    TERM_BALLS,
    TERM_EXTERNAL,
    TERM_GRAVITY,
    TERM_SLEEVE,
    kernel,
)
from ballchain.drake_models.kernels.external import add_external
from ballchain.drake_models.kernels.gravity import add_gravity
from ballchain.drake_models.kernels.pair import pair_energy, pair_gradient_entry, pair_hessian_entry, pair_scalars
from ballchain.drake_models.kernels.sleeve import sleeve_energy

# Layout of ``reduced_energy``'s ``params`` (one array: fewer arguments to dispatch).
P_D, P_M, P_WEIGHT, P_KS, P_E0, P_BASE = 0, 1, 2, 3, 4, 5


def reduced_params(d: float, M: float, weight: float, k_s: float, E0: float, base) -> np.ndarray:
    """The ``params`` array of ``reduced_energy``: (d, M, weight, k_s, E0, base (3,))."""
    return np.concatenate([[d, M, weight, k_s, E0], np.asarray(base, dtype=float).reshape(3)])


@kernel
def reduced_energy(V, p, m_hat, B, G, dG, params, has_external, order):
    """The chain's energy/E0 with its exact gradient and Hessian in chart coordinates.

    Coordinates: K = 2L unit vectors (L = n - 1 links, then the L free dipoles), each in its
    chart (``chart_vectors``); q = (a_1..a_K, b_1..b_K), nq = 2K. The Cartesian derivatives are
    carried to the links by suffix sums (dU/du_l = d sum_{k>l} dU/dp_k) and to q through the
    per-vector chart Jacobians and curvatures, without incidence matrices.

    Args:
        V: ``chart_vectors`` at q (5, K, 3).
        p, m_hat: ``chain_configuration`` of w = V[0].
        B, G, dG: external field (n, 3), gradient (n, 3, 3), its derivative (n, 3, 3, 3) at p
            (dG is read only for ``order >= 2``; all ignored unless ``has_external``).
        params: ``reduced_params``: ball diameter d [m], dipole moment M [A m^2], a ball's
            weight [N] (0: no gravity), the sleeve's E I / d [J] (0: no sleeve), the energy
            scale E0 [J], the sheath axis (3,).
        order: 0 (energy), 1 (+ gradient), 2 (+ Hessian).

    Returns:
        ``(status, terms (4,) [J], gradient (nq,), hessian (nq, nq))`` (empty arrays below
        their order); gradient and Hessian of U / E0.
    """
    w = V[0]
    d, M, weight, k_s, E0 = params[P_D], params[P_M], params[P_WEIGHT], params[P_KS], params[P_E0]
    base = params[P_BASE:P_BASE + 3]
    n = p.shape[0]
    L = n - 1
    K = 2 * L
    nq = 2 * K
    terms = np.zeros(4)
    grad = np.zeros(nq if order >= 1 else 0)
    hess = np.empty((nq, nq) if order >= 2 else (0, 0))  # every entry written
    dU_dp = np.zeros((n, 3))
    dU_dm = np.zeros((n, 3))
    # Hessian blocks over the chart vectors, upper blocks only (the Hessian is symmetric): link-link
    # H_ll[l1, l2] (l1 <= l2), link-dipole H_lm[l, k - 1] (dipole of ball k >= 1), dipole-dipole
    # H_mm[k1 - 1, k2 - 1] (k1 <= k2). Before ``_slots_to_links`` H_ll and H_lm hold the
    # Cartesian blocks in the forms the link sums take (see there).
    Lh = L if order >= 2 else 0
    H_ll = np.zeros((Lh, Lh, 3, 3))
    H_lm = np.zeros((Lh, Lh, 3, 3))
    H_mm = np.zeros((Lh, Lh, 3, 3))
    status, U_b = _pairs_into_slots(p, m_hat, K_DIPOLE * M * M, order, dU_dp, dU_dm, H_ll, H_lm, H_mm)
    if status != OK:
        return status, terms, grad, hess
    terms[TERM_BALLS] = U_b
    if has_external:
        terms[TERM_EXTERNAL] = add_external(p, m_hat, M, B, G, dU_dp, dU_dm)
        if order >= 2:
            _external_into_slots(m_hat, M, G, dG, H_ll, H_lm)
    if weight != 0.0:
        terms[TERM_GRAVITY] = add_gravity(p, weight, dU_dp)
    # Links: dU/du_l = d sum_{k > l} dU/dp_k; prefix and suffix sums for the Hessian.
    dU_du = np.zeros((L, 3))
    if order >= 1:
        _points_to_links(dU_dp, d, dU_du)
    if order >= 2:
        _slots_to_links(H_ll, H_lm, d)
    if k_s > 0.0:
        status, U_s = sleeve_energy(w[:L], base, k_s, dU_du, H_ll, order)
        if status != OK:
            return status, terms, grad, hess
        terms[TERM_SLEEVE] = U_s
    if order < 1:
        return OK, terms, grad, hess
    inv_E0 = 1.0 / E0
    g_w = _chart_gradient(V, dU_du, dU_dm, inv_E0, grad)
    if order < 2:
        return OK, terms, grad, hess
    _chart_hessian(V, H_ll, H_lm, H_mm, g_w, inv_E0, hess)
    return OK, terms, grad, hess


@kernel
def _pairs_into_slots(p, m_hat, kk, order, dU_dp, dU_dm, H_ll, H_lm, H_mm):
    """The pair energy (pair constant kk = k M^2); its gradient added to ``dU_dp``, ``dU_dm``
    (``order >= 1``) and its Hessian blocks to ``H_ll``, ``H_lm``, ``H_mm`` (``order >= 2``),
    each entry added where it lands as it is computed (``pair``'s per-entry law, inlined: no
    3x3 blocks). One loop per order (``_pair_energies``, ``_pair_gradients``,
    ``_pair_hessians``): the lower orders' loops carry none of the higher orders' code.

    Pair (i, j), i < j, moves r = p_i - p_j by -d w_l for the links i <= l < j: its block
    d2e/dr2 lands on the link-link box [i, j)^2, kept as one block at ``H_ll[i, j - 1]``
    (``_slots_to_links`` sums the boxes); d2e/dr dm lands on the links [i, j) of a dipole's
    column, kept as the difference of two suffix sums (``H_lm[j - 1]`` less ``H_lm[i - 1]``).

    Returns:
        ``(status, U_b)``: status OK or COINCIDENT; U_b [J].
    """
    if order >= 2:
        return _pair_hessians(p, m_hat, kk, dU_dp, dU_dm, H_ll, H_lm, H_mm)
    if order == 1:
        return _pair_gradients(p, m_hat, kk, dU_dp, dU_dm)
    return _pair_energies(p, m_hat, kk)


@kernel
def _pair_energies(p, m_hat, kk):
    """``_pairs_into_slots`` of order 0."""
    n = p.shape[0]
    U_b = 0.0
    for i in range(n):
        x = (m_hat[i, 0], m_hat[i, 1], m_hat[i, 2])
        for j in range(i + 1, n):
            r = (p[i, 0] - p[j, 0], p[i, 1] - p[j, 1], p[i, 2] - p[j, 2])
            if r[0] * r[0] + r[1] * r[1] + r[2] * r[2] <= 0.0:
                return COINCIDENT, 0.0
            y = (m_hat[j, 0], m_hat[j, 1], m_hat[j, 2])
            U_b += pair_energy(kk, pair_scalars(r, x, y))
    return OK, U_b


@kernel
def _pair_gradients(p, m_hat, kk, dU_dp, dU_dm):
    """``_pairs_into_slots`` of order 1."""
    n = p.shape[0]
    U_b = 0.0
    for i in range(n):
        x = (m_hat[i, 0], m_hat[i, 1], m_hat[i, 2])
        for j in range(i + 1, n):
            r = (p[i, 0] - p[j, 0], p[i, 1] - p[j, 1], p[i, 2] - p[j, 2])
            if r[0] * r[0] + r[1] * r[1] + r[2] * r[2] <= 0.0:
                return COINCIDENT, 0.0
            y = (m_hat[j, 0], m_hat[j, 1], m_hat[j, 2])
            sc = pair_scalars(r, x, y)
            U_b += pair_energy(kk, sc)
            for c in range(3):
                gr, gx, gy = pair_gradient_entry(c, r, x, y, kk, sc)
                dU_dp[i, c] += gr
                dU_dp[j, c] -= gr
                dU_dm[i, c] += gx
                dU_dm[j, c] += gy
    return OK, U_b


@kernel
def _pair_hessians(p, m_hat, kk, dU_dp, dU_dm, H_ll, H_lm, H_mm):
    """``_pairs_into_slots`` of order 2."""
    n = p.shape[0]
    U_b = 0.0
    for i in range(n):
        x = (m_hat[i, 0], m_hat[i, 1], m_hat[i, 2])
        for j in range(i + 1, n):
            r = (p[i, 0] - p[j, 0], p[i, 1] - p[j, 1], p[i, 2] - p[j, 2])
            if r[0] * r[0] + r[1] * r[1] + r[2] * r[2] <= 0.0:
                return COINCIDENT, 0.0
            y = (m_hat[j, 0], m_hat[j, 1], m_hat[j, 2])
            sc = pair_scalars(r, x, y)
            U_b += pair_energy(kk, sc)
            for c in range(3):
                gr, gx, gy = pair_gradient_entry(c, r, x, y, kk, sc)
                dU_dp[i, c] += gr
                dU_dp[j, c] -= gr
                dU_dm[i, c] += gx
                dU_dm[j, c] += gy
            pj = j - 1  # j >= 1 always
            box, jj = H_ll[i, pj], H_lm[pj, pj]
            if i == 0:  # ball 0's dipole is fixed
                for a in range(3):
                    for b in range(3):
                        E, _, Ay, _ = pair_hessian_entry(a, b, r, x, y, kk, sc)
                        box[a, b] += E
                        jj[a, b] -= Ay
                continue
            pi = i - 1
            ji, ii, ij, mm = H_lm[pj, pi], H_lm[pi, pi], H_lm[pi, pj], H_mm[pi, pj]
            for a in range(3):
                for b in range(3):
                    E, Ax, Ay, D = pair_hessian_entry(a, b, r, x, y, kk, sc)
                    box[a, b] += E
                    jj[a, b] -= Ay
                    ji[a, b] -= Ax
                    ii[a, b] += Ax
                    ij[a, b] += Ay
                    mm[a, b] += D
    return OK, U_b


@kernel
def _external_into_slots(m_hat, M, G, dG, H_ll, H_lm):
    """Add the external field's per-ball Hessian blocks (``external_hessian_blocks``) of the free
    balls k >= 1 in the forms of ``_pairs_into_slots``: d2U/dp_k2 on the box [0, k)^2
    (``H_ll[0, k - 1]``), d2U/dp_k dm_k as the suffix sum from ``H_lm[k - 1, k - 1]``."""
    n = m_hat.shape[0]
    for k in range(1, n):
        for b in range(3):
            for c in range(3):
                acc = 0.0
                for a in range(3):
                    acc += m_hat[k, a] * dG[k, a, b, c]
                H_ll[0, k - 1, b, c] -= M * acc
                H_lm[k - 1, k - 1, b, c] -= M * G[k, c, b]


@kernel
def _points_to_links(dU_dp, d, dU_du):
    """``dU/du_l = d sum_{k > l} dU/dp_k`` (suffix sums), written into ``dU_du`` (L, 3)."""
    L = dU_du.shape[0]
    for c in range(3):
        acc = 0.0
        for l in range(L - 1, -1, -1):
            acc += dU_dp[l + 1, c]
            dU_du[l, c] = d * acc


@kernel
def _slots_to_links(H_ll, H_lm, d):
    """Carry the Cartesian blocks of ``_pairs_into_slots`` to the links, in place (upper blocks).

    Link-link: a block F at ``H_ll[i, c]`` (i <= c) stands for F on every (l1, l2) with
    i <= l1, l2 <= c; so ``H_ll[l1, l2] = d^2 sum_{i <= l1} sum_{c >= l2} F[i, c]`` (l1 <= l2:
    only upper blocks are read), a prefix sum down the rows then a suffix sum along them.
    Link-dipole: ``H_lm[l, t] = d sum_{s >= l} H_lm[s, t]``, a suffix sum down the rows."""
    L = H_ll.shape[0]
    for l1 in range(1, L):  # prefix sums down the rows (upper blocks)
        for l2 in range(l1, L):
            for a in range(3):
                for b in range(3):
                    H_ll[l1, l2, a, b] += H_ll[l1 - 1, l2, a, b]
    d2 = d * d
    for l1 in range(L):  # suffix sums along the rows, scaled by d^2
        for a in range(3):
            for b in range(3):
                H_ll[l1, L - 1, a, b] *= d2
        for l2 in range(L - 2, l1 - 1, -1):
            for a in range(3):
                for b in range(3):
                    H_ll[l1, l2, a, b] = d2 * H_ll[l1, l2, a, b] + H_ll[l1, l2 + 1, a, b]
    for t in range(L):  # link-dipole: suffix sums down the rows, scaled by d
        for a in range(3):
            for b in range(3):
                H_lm[L - 1, t, a, b] *= d
    for l in range(L - 2, -1, -1):
        for t in range(L):
            for a in range(3):
                for b in range(3):
                    H_lm[l, t, a, b] = d * H_lm[l, t, a, b] + H_lm[l + 1, t, a, b]


@kernel
def _chart_gradient(V, dU_du, dU_dm, inv_E0, grad):
    """The gradient of U / E0 in chart coordinates, written into ``grad`` (nq,); returns the
    gradient with respect to the K chart vectors (K, 3)."""
    dwa, dwb = V[1], V[2]
    L = dU_du.shape[0]
    K = 2 * L
    g_w = np.empty((K, 3))
    for s in range(K):
        for c in range(3):
            g_w[s, c] = dU_du[s, c] if s < L else dU_dm[s - L + 1, c]
    for s in range(K):
        ga = 0.0
        gb = 0.0
        for c in range(3):
            ga += g_w[s, c] * dwa[s, c]
            gb += g_w[s, c] * dwb[s, c]
        grad[s] = ga * inv_E0
        grad[K + s] = gb * inv_E0
    return g_w


@kernel
def _chart_hessian(V, H_ll, H_lm, H_mm, g_w, inv_E0, hess):
    """The Hessian of U / E0 in chart coordinates, written into ``hess`` (nq, nq): the chart
    vectors' upper blocks (``H_ll``, ``H_lm``, ``H_mm``) through the charts' Jacobians, mirrored,
    plus the charts' curvature."""
    w, dwa, dwb, daa, dab = V[0], V[1], V[2], V[3], V[4]
    K = w.shape[0]
    L = K // 2
    # Through the charts: H[(s, i), (t, j)] = J_i[:, s]^T Hw[i, j] J_j[:, t], J_i = [dwa_i, dwb_i],
    # for the upper blocks j >= i (the 3-vector products written out), and mirrored.
    for i in range(K):
        a0, a1, a2 = dwa[i, 0] * inv_E0, dwa[i, 1] * inv_E0, dwa[i, 2] * inv_E0
        b0, b1, b2 = dwb[i, 0] * inv_E0, dwb[i, 1] * inv_E0, dwb[i, 2] * inv_E0
        for j in range(i, K):
            if j < L:
                H = H_ll[i, j]
            elif i < L:
                H = H_lm[i, j - L]
            else:
                H = H_mm[i - L, j - L]
            x0, x1, x2 = dwa[j, 0], dwa[j, 1], dwa[j, 2]
            y0, y1, y2 = dwb[j, 0], dwb[j, 1], dwb[j, 2]
            va0 = H[0, 0] * x0 + H[0, 1] * x1 + H[0, 2] * x2
            va1 = H[1, 0] * x0 + H[1, 1] * x1 + H[1, 2] * x2
            va2 = H[2, 0] * x0 + H[2, 1] * x1 + H[2, 2] * x2
            vb0 = H[0, 0] * y0 + H[0, 1] * y1 + H[0, 2] * y2
            vb1 = H[1, 0] * y0 + H[1, 1] * y1 + H[1, 2] * y2
            vb2 = H[2, 0] * y0 + H[2, 1] * y1 + H[2, 2] * y2
            haa = a0 * va0 + a1 * va1 + a2 * va2
            hab = a0 * vb0 + a1 * vb1 + a2 * vb2
            hba = b0 * va0 + b1 * va1 + b2 * va2
            hbb = b0 * vb0 + b1 * vb1 + b2 * vb2
            hess[i, j] = haa
            hess[i, K + j] = hab
            hess[K + i, j] = hba
            hess[K + i, K + j] = hbb
            if j != i:
                hess[j, i] = haa
                hess[K + j, i] = hab
                hess[j, K + i] = hba
                hess[K + j, K + i] = hbb
    for i in range(K):  # the charts' curvature: g_w . d2w/dq2, per vector
        caa = 0.0
        cab = 0.0
        cbb = 0.0
        for c in range(3):
            caa += g_w[i, c] * daa[i, c]
            cab += g_w[i, c] * dab[i, c]
            cbb -= g_w[i, c] * w[i, c]
        hess[i, i] += caa * inv_E0
        hess[i, K + i] += cab * inv_E0
        hess[K + i, i] += cab * inv_E0
        hess[K + i, K + i] += cbb * inv_E0
