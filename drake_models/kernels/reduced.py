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
    hess = np.zeros((nq, nq) if order >= 2 else (0, 0))
    dU_dp = np.zeros((n, 3))
    dU_dm = np.zeros((n, 3))
    # Hessian blocks over the chart vectors' slots: slot k-1 <- p_k (later summed into links),
    # slot L+k-1 <- m_hat_k (k >= 1; ball 1's position and dipole are fixed).
    Hw = np.zeros((K, K, 3, 3) if order >= 2 else (0, 0, 3, 3))
    status, U_b = _pairs_into_slots(p, m_hat, K_DIPOLE * M * M, order, dU_dp, dU_dm, Hw)
    if status != OK:
        return status, terms, grad, hess
    terms[TERM_BALLS] = U_b
    if has_external:
        terms[TERM_EXTERNAL] = add_external(p, m_hat, M, B, G, dU_dp, dU_dm)
        if order >= 2:
            _external_into_slots(m_hat, M, G, dG, Hw)
    if weight != 0.0:
        terms[TERM_GRAVITY] = add_gravity(p, weight, dU_dp)
    # Links: dU/du_l = d sum_{k > l} dU/dp_k; the same suffix sums, twice, for the Hessian.
    dU_du = np.zeros((L, 3))
    if order >= 1:
        _points_to_links(dU_dp, d, dU_du)
    if order >= 2:
        _slots_to_links(Hw, d, L)
    if k_s > 0.0:
        status, U_s = sleeve_energy(w[:L], base, k_s, dU_du, Hw, order)
        if status != OK:
            return status, terms, grad, hess
        terms[TERM_SLEEVE] = U_s
    if order < 1:
        return OK, terms, grad, hess
    inv_E0 = 1.0 / E0
    g_w = _chart_gradient(V, dU_du, dU_dm, inv_E0, grad)
    if order < 2:
        return OK, terms, grad, hess
    _chart_hessian(V, Hw, g_w, inv_E0, hess)
    return OK, terms, grad, hess


@kernel
def _pairs_into_slots(p, m_hat, kk, order, dU_dp, dU_dm, Hw):
    """The pair energy (pair constant kk = k M^2); its gradient added to ``dU_dp``, ``dU_dm``
    (``order >= 1``) and its Hessian blocks to the slots of ``Hw`` (``order >= 2``), each entry
    added where it lands as it is computed (``pair``'s per-entry law, inlined: no 3x3 blocks).

    Returns:
        ``(status, U_b)``: status OK or COINCIDENT; U_b [J].
    """
    n = p.shape[0]
    L = n - 1
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
            if order >= 1:
                for c in range(3):
                    gr, gx, gy = pair_gradient_entry(c, r, x, y, kk, sc)
                    dU_dp[i, c] += gr
                    dU_dp[j, c] -= gr
                    dU_dm[i, c] += gx
                    dU_dm[j, c] += gy
            if order >= 2:
                pi, pj, mi, mj = i - 1, j - 1, L + i - 1, L + j - 1  # j >= 1 always
                for a in range(3):
                    for b in range(3):
                        E, Ax, Ay, D = pair_hessian_entry(a, b, r, x, y, kk, sc)
                        Hw[pj, pj, a, b] += E
                        Hw[pj, mj, a, b] -= Ay
                        if i > 0:
                            Hw[pi, pi, a, b] += E
                            Hw[pi, pj, a, b] -= E
                            Hw[pj, pi, a, b] -= E
                            Hw[pi, mi, a, b] += Ax
                            Hw[pj, mi, a, b] -= Ax
                            Hw[pi, mj, a, b] += Ay
                            Hw[mi, mj, a, b] += D
                            Hw[mj, mi, b, a] += D
    return OK, U_b


@kernel
def _external_into_slots(m_hat, M, G, dG, Hw):
    """Add the external field's per-ball Hessian blocks (``external_hessian_blocks``) of the free
    balls k >= 1 to the slots of ``Hw``."""
    n = m_hat.shape[0]
    L = n - 1
    for k in range(1, n):
        for b in range(3):
            for c in range(3):
                acc = 0.0
                for a in range(3):
                    acc += m_hat[k, a] * dG[k, a, b, c]
                Hw[k - 1, k - 1, b, c] -= M * acc
                Hw[k - 1, L + k - 1, b, c] -= M * G[k, c, b]


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
def _slots_to_links(Hw, d, L):
    """Carry the Hessian blocks of the position slots to the links, in place: suffix sums down
    the link rows and along the link columns, scaled by d^2 (link-link) or d (link-dipole), and
    the dipole rows of the link columns as the transpose."""
    K = 2 * L
    for s2 in range(K):  # suffix sums down the link rows, every column
        for l in range(L - 2, -1, -1):
            for a in range(3):
                for b in range(3):
                    Hw[l, s2, a, b] += Hw[l + 1, s2, a, b]
    for l1 in range(L):  # and along the link columns of the link rows
        for l in range(L - 2, -1, -1):
            for a in range(3):
                for b in range(3):
                    Hw[l1, l, a, b] += Hw[l1, l + 1, a, b]
    d2 = d * d
    for l1 in range(L):
        for s2 in range(K):
            scale = d2 if s2 < L else d
            for a in range(3):
                for b in range(3):
                    Hw[l1, s2, a, b] *= scale
    for s1 in range(L, K):  # dipole rows of the link columns: the transpose
        for l in range(L):
            for a in range(3):
                for b in range(3):
                    Hw[s1, l, a, b] = Hw[l, s1, b, a]


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
def _chart_hessian(V, Hw, g_w, inv_E0, hess):
    """The Hessian of U / E0 in chart coordinates, written into ``hess`` (nq, nq): the chart
    vectors' blocks ``Hw`` through the charts' Jacobians, plus the charts' curvature."""
    w, dwa, dwb, daa, dab = V[0], V[1], V[2], V[3], V[4]
    K = w.shape[0]
    nq = 2 * K
    # Through the charts: H[(s, i), (t, j)] = J_i[:, s]^T Hw[i, j] J_j[:, t], J_i = [dwa_i, dwb_i].
    for i in range(K):
        for j in range(K):
            haa = 0.0
            hab = 0.0
            hba = 0.0
            hbb = 0.0
            for a in range(3):
                va = 0.0
                vb = 0.0
                for b in range(3):
                    h = Hw[i, j, a, b]
                    va += h * dwa[j, b]
                    vb += h * dwb[j, b]
                haa += dwa[i, a] * va
                hab += dwa[i, a] * vb
                hba += dwb[i, a] * va
                hbb += dwb[i, a] * vb
            hess[i, j] = haa
            hess[i, K + j] = hab
            hess[K + i, j] = hba
            hess[K + i, K + j] = hbb
    for i in range(K):  # the charts' curvature: g_w . d2w/dq2, per vector
        caa = 0.0
        cab = 0.0
        cbb = 0.0
        for c in range(3):
            caa += g_w[i, c] * daa[i, c]
            cab += g_w[i, c] * dab[i, c]
            cbb -= g_w[i, c] * w[i, c]
        hess[i, i] += caa
        hess[i, K + i] += cab
        hess[K + i, i] += cab
        hess[K + i, K + i] += cbb
    for i in range(nq):
        for j in range(nq):
            hess[i, j] *= inv_E0
