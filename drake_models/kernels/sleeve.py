"""The sleeve's bending energy: ``(E I / d) theta tan(theta / 2)`` per bend between consecutive
links (the first against the sheath axis), with its derivatives with respect to the unit links,
and carried to the ball centres for the Cartesian energy.

The law of ``chain_energy.sleeve_bending`` (and of the sleeve term of ``chain_energy.chain_energy``),
compiled.
"""

from __future__ import annotations

import math

import numpy as np

from ballchain.drake_models.kernels._common import FOLDED, OK, kernel


@kernel
def _bend(a, b):
    """(cos, theta, h = theta / sin theta) of the bend between unit vectors a and b."""
    c = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    c = min(1.0, max(-1.0, c))
    s0 = a[1] * b[2] - a[2] * b[1]
    s1 = a[2] * b[0] - a[0] * b[2]
    s2 = a[0] * b[1] - a[1] * b[0]
    s = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    theta = math.atan2(s, c)
    h = theta / math.sin(theta) if theta > 0.0 else 1.0
    return c, theta, h


@kernel
def sleeve_energy(u, base, k_s, dU_du, H_uu, order):
    """The sleeve's bending energy over unit links u (L, 3), clamped along ``base`` (3,).

    Each bend between consecutive links (the first between ``base`` and u_0) of angle theta
    stores ``k_s theta tan(theta / 2)`` (k_s = E I / d [J]), written as a function of the
    cosine c = u_a . u_b, so the derivatives are unprojected ones.

    Args:
        u: (L, 3) unit link directions; base: (3,) sheath axis; k_s: E I / d [J].
        dU_du: (L, 3) gradient, added to when ``order >= 1``.
        H_uu: (L, L, 3, 3) Hessian blocks, added to when ``order >= 2``.
        order: 0, 1 or 2.

    Returns:
        ``(status, U)``: status OK or FOLDED (a bend of 180 deg).
    """
    L = u.shape[0]
    U = 0.0
    for t in range(L):
        a = base if t == 0 else u[t - 1]
        b = u[t]
        c, theta, h = _bend(a, b)
        if theta > math.pi - 1e-6:
            return FOLDED, 0.0
        U += k_s * theta * math.tan(0.5 * theta)
        if order < 1:
            continue
        f1 = k_s * (-(1.0 + h) / (1.0 + c))
        for q in range(3):
            dU_du[t, q] += f1 * a[q]
            if t > 0:
                dU_du[t - 1, q] += f1 * b[q]
        if order < 2:
            continue
        # d2f/dc2 = [(sin t - t cos t) / sin^3 t (1 + c) + (1 + h)] / (1 + c)^2, the ratio -> 1/3.
        if theta < 1e-3:
            ratio = 1.0 / 3.0 + theta * theta / 30.0
        else:
            st = math.sin(theta)
            ratio = (st - theta * math.cos(theta)) / (st * st * st)
        f2 = k_s * (ratio * (1.0 + c) + (1.0 + h)) / ((1.0 + c) * (1.0 + c))
        for p in range(3):
            for q in range(3):
                H_uu[t, t, p, q] += f2 * a[p] * a[q]
                if t > 0:
                    H_uu[t - 1, t - 1, p, q] += f2 * b[p] * b[q]
                    H_uu[t - 1, t, p, q] += f2 * b[p] * a[q]
                    H_uu[t, t - 1, q, p] += f2 * b[p] * a[q]
            if t > 0:
                H_uu[t - 1, t, p, p] += f1
                H_uu[t, t - 1, p, p] += f1
    return OK, U


@kernel
def add_sleeve(p, base, k_s, dU_dp):
    """Add the sleeve's bending energy over the links of the centres p (n, 3) to ``dU_dp``.

    Args:
        p: (n, 3) ball centres [m], n >= 2; base: (3,) unit sheath axis; k_s: E I / d [J].
        dU_dp: (n, 3) gradient [J/m], added to (unless the status is FOLDED).

    Returns:
        ``(status, U_s)``: status OK or FOLDED; U_s [J].
    """
    L = p.shape[0] - 1
    u = np.empty((L, 3))
    lengths = np.empty(L)
    for l in range(L):
        acc = 0.0
        for q in range(3):
            u[l, q] = p[l + 1, q] - p[l, q]
            acc += u[l, q] * u[l, q]
        lengths[l] = math.sqrt(acc)
        for q in range(3):
            u[l, q] /= lengths[l]
    dU_du = np.zeros((L, 3))
    status, U_s = sleeve_energy(u, base, k_s, dU_du, np.zeros((0, 0, 3, 3)), 1)
    if status != OK:
        return status, 0.0
    for l in range(L):  # through u = l / |l|: dU/dl = (I - u u^T) dU/du / |l|
        dot = u[l, 0] * dU_du[l, 0] + u[l, 1] * dU_du[l, 1] + u[l, 2] * dU_du[l, 2]
        for q in range(3):
            g = (dU_du[l, q] - u[l, q] * dot) / lengths[l]
            dU_dp[l + 1, q] += g
            dU_dp[l, q] -= g
    return OK, U_s
