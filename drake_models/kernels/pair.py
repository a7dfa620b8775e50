"""The balls' mutual dipole energy: one pair's energy with its first and second derivatives,
and the sums over all pairs of a chain in Cartesian coordinates.

The law's one home is its per-entry functions (``pair_scalars``, ``pair_energy``,
``pair_gradient_entry``, ``pair_hessian_entry``), inlined where they are called: the reduced
energy's pair loops (``reduced._pairs_into_slots``, one per order) add each entry where it
lands, and ``_pair_first``/``_pair_second`` write them into 3-vectors and 3 x 3 blocks for
the sums here.

The law of ``dipole.py`` (``chain_interactions``, ``chain_interaction_hessian``), compiled.
"""

from __future__ import annotations

import math

import numpy as np

from ballchain.drake_models.dipole import K_DIPOLE
from ballchain.drake_models.kernels._common import COINCIDENT, OK, inline_kernel, kernel


@inline_kernel
def pair_scalars(r, x, y):
    """What one pair's energy and derivatives share: ``(s, ir3, ir5, ir7, a, b, c)`` with
    s = 1/|r|^2 [1/m^2], ir_k = 1/|r|^k [1/m^k], a = x . r, b = y . r [m], c = x . y, for
    r = p_i - p_j [m] and the unit dipoles x, y of i and j (3-vectors or 3-tuples)."""
    r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
    s = 1.0 / r2
    ir = math.sqrt(s)
    ir3 = s * ir
    ir5 = ir3 * s
    ir7 = ir5 * s
    a = x[0] * r[0] + x[1] * r[1] + x[2] * r[2]
    b = y[0] * r[0] + y[1] * r[1] + y[2] * r[2]
    c = x[0] * y[0] + x[1] * y[1] + x[2] * y[2]
    return s, ir3, ir5, ir7, a, b, c


@inline_kernel
def pair_energy(kk, sc):
    """One pair's energy [J] ``kk (x . y / |r|^3 - 3 (x . r)(y . r) / |r|^5)`` from its
    ``pair_scalars`` sc (kk = k M^2 [J m^3])."""
    _, ir3, ir5, _, a, b, c = sc
    return kk * (c * ir3 - 3.0 * a * b * ir5)


@inline_kernel
def pair_gradient_entry(q, r, x, y, kk, sc):
    """Component q of one pair's first derivatives: ``(de/dr_q [J/m], de/dx_q [J], de/dy_q [J])``."""
    _, ir3, ir5, ir7, a, b, c = sc
    return (kk * (-3.0 * c * ir5 * r[q] - 3.0 * ir5 * (b * x[q] + a * y[q]) + 15.0 * a * b * ir7 * r[q]),
            kk * (ir3 * y[q] - 3.0 * b * ir5 * r[q]),
            kk * (ir3 * x[q] - 3.0 * a * ir5 * r[q]))


@inline_kernel
def pair_hessian_entry(p, q, r, x, y, kk, sc):
    """Entry (p, q) of one pair's second derivatives: ``(d2e/dr_p dr_q [J/m^2],
    d2e/dr_p dx_q, d2e/dr_p dy_q [J/m], d2e/dx_p dy_q [J])``."""
    s, ir3, ir5, ir7, a, b, c = sc
    ir9 = ir7 * s
    vp = b * x[p] + a * y[p]
    vq = b * x[q] + a * y[q]
    rr = r[p] * r[q]
    e = kk * ((15.0 * c * ir7 - 105.0 * a * b * ir9) * rr - 3.0 * ir5 * (x[p] * y[q] + y[p] * x[q])
              + 15.0 * ir7 * (vp * r[q] + r[p] * vq))
    ax = kk * (-3.0 * ir5 * (r[p] * y[q] + y[p] * r[q]) + 15.0 * b * ir7 * rr)
    ay = kk * (-3.0 * ir5 * (r[p] * x[q] + x[p] * r[q]) + 15.0 * a * ir7 * rr)
    dd = kk * (-3.0 * ir5 * rr)
    if p == q:
        e += kk * (-3.0 * c * ir5 + 15.0 * a * b * ir7)
        ax += kk * (-3.0 * ir5 * b)
        ay += kk * (-3.0 * ir5 * a)
        dd += kk * ir3
    return e, ax, ay, dd


@kernel
def _pair_first(r, x, y, kk, grad_r, grad_x, grad_y):
    """Energy of one pair and its first derivatives (written into the 3-vectors given).

    ``e = kk (x . y / |r|^3 - 3 (x . r)(y . r) / |r|^5)`` with r = p_i - p_j, x, y the unit
    dipoles of i and j and kk = k M^2 (the pair energy of dipoles M x and M y).
    """
    sc = pair_scalars(r, x, y)
    for q in range(3):
        grad_r[q], grad_x[q], grad_y[q] = pair_gradient_entry(q, r, x, y, kk, sc)
    return pair_energy(kk, sc)


@kernel
def _pair_second(r, x, y, kk, E, Ax, Ay, D):
    """Second derivatives of one pair's energy (3x3 blocks written into E, Ax, Ay, D).

    E = d2e/dr2, Ax[a, b] = d2e / dr_a dx_b, Ay[a, b] = d2e / dr_a dy_b, D[a, b] = d2e / dx_a dy_b.
    """
    sc = pair_scalars(r, x, y)
    for p in range(3):
        for q in range(3):
            E[p, q], Ax[p, q], Ay[p, q], D[p, q] = pair_hessian_entry(p, q, r, x, y, kk, sc)


@kernel
def pair_energy_gradient(p, m_hat, M):
    """Mutual dipole energy of n balls and its gradient, all pairs.

    Args:
        p: (n, 3) ball centres [m].
        m_hat: (n, 3) unit dipole directions.
        M: the balls' dipole moment [A m^2].

    Returns:
        ``(status, U, dU_dp, dU_dm_hat)``: status OK or COINCIDENT; U [J]; (n, 3) [J/m] and
        (n, 3) [J] (``dU/dm_hat_i = -M B_i``, B_i the field of the others at ball i).
    """
    n = p.shape[0]
    kk = K_DIPOLE * M * M
    dU_dp = np.zeros((n, 3))
    dU_dm = np.zeros((n, 3))
    r = np.empty(3)
    gr = np.empty(3)
    gx = np.empty(3)
    gy = np.empty(3)
    U = 0.0
    for i in range(n):
        for j in range(i + 1, n):
            for q in range(3):
                r[q] = p[i, q] - p[j, q]
            if r[0] * r[0] + r[1] * r[1] + r[2] * r[2] <= 0.0:
                return COINCIDENT, 0.0, dU_dp, dU_dm
            U += _pair_first(r, m_hat[i], m_hat[j], kk, gr, gx, gy)
            for q in range(3):
                dU_dp[i, q] += gr[q]
                dU_dp[j, q] -= gr[q]
                dU_dm[i, q] += gx[q]
                dU_dm[j, q] += gy[q]
    return OK, U, dU_dp, dU_dm


@kernel
def pair_hessian(p, m_hat, M):
    """Second derivatives of the mutual dipole energy, in Cartesian coordinates.

    Args:
        p, m_hat, M: as in ``pair_energy_gradient``.

    Returns:
        ``(status, H_pp, H_pm, H_mm)``, each (n, 3, n, 3): ``H_pp[i, :, j, :] = d2U/dp_i dp_j``,
        ``H_pm[i, :, j, :] = d2U/dp_i dm_hat_j``, ``H_mm[i, :, j, :] = d2U/dm_hat_i dm_hat_j``.
    """
    n = p.shape[0]
    kk = K_DIPOLE * M * M
    H_pp = np.zeros((n, 3, n, 3))
    H_pm = np.zeros((n, 3, n, 3))
    H_mm = np.zeros((n, 3, n, 3))
    r = np.empty(3)
    E = np.empty((3, 3))
    Ax = np.empty((3, 3))
    Ay = np.empty((3, 3))
    D = np.empty((3, 3))
    for i in range(n):
        for j in range(i + 1, n):
            for q in range(3):
                r[q] = p[i, q] - p[j, q]
            if r[0] * r[0] + r[1] * r[1] + r[2] * r[2] <= 0.0:
                return COINCIDENT, H_pp, H_pm, H_mm
            _pair_second(r, m_hat[i], m_hat[j], kk, E, Ax, Ay, D)
            for a in range(3):
                for b in range(3):
                    H_pp[i, a, i, b] += E[a, b]
                    H_pp[j, a, j, b] += E[a, b]
                    H_pp[i, a, j, b] -= E[a, b]
                    H_pp[j, a, i, b] -= E[a, b]
                    H_pm[i, a, i, b] += Ax[a, b]
                    H_pm[j, a, i, b] -= Ax[a, b]
                    H_pm[i, a, j, b] += Ay[a, b]
                    H_pm[j, a, j, b] -= Ay[a, b]
                    H_mm[i, a, j, b] += D[a, b]
                    H_mm[j, b, i, a] += D[a, b]
    return OK, H_pp, H_pm, H_mm
