"""The chain's physics as compiled kernels (numba): the one implementation the stack runs.

Every quantity here is the law of ``dipole.py`` (pair dipole energy, forces, torques and their
second derivatives), of ``chain_energy.py`` (the external field's energy ``-m . B``, the
sleeve's bending ``(E I / d) theta tan(theta / 2)`` per bend, gravity along -z) and the chain
rule of ``optimization/reduced_chain.py`` (link and dipole directions in a chart). Those numpy
implementations are kept as the tests' reference (``tests/test_chain_kernels.py`` holds the two
to 1e-12 relative); what statics, the wrench system, the planner and the experiments run is this
file.

Field sources stay Python objects (``field_sources.FieldSource``): the caller evaluates the
external flux density ``B`` (n, 3) [T], its gradient ``G[k, a, b] = dB_a / dp_b`` (n, 3, 3)
[T/m] and, for Hessians, ``dG[k, a, b, c] = d2 B_a / dp_b dp_c`` (n, 3, 3, 3) at the ball
centres and passes the arrays in; the kernels do the energy/force/torque/Hessian arithmetic.

Memory is O(n^2) for every entry point (no pair-by-link incidence matrices): the pair sums run
as loops, the Cartesian-to-link chain rule as suffix sums, and the rigidity Jacobian is built
only for the rows asked for.

Kernels are compiled on first use and cached on disk (``cache=True``, next to this file or in
``NUMBA_CACHE_DIR``): a machine pays the compilation once (``ballchain bench statics`` reports
the cost). A damaged cache file is recompiled with one line on stderr (``numba_cache``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ballchain.drake_models.dipole import K_DIPOLE
from ballchain.drake_models.numba_cache import guard_cache

# Energy parts, in the order of the kernels' ``terms`` arrays (EnergyTerms' fields).
TERM_BALLS, TERM_EXTERNAL, TERM_SLEEVE, TERM_GRAVITY = 0, 1, 2, 3

# Status codes of the kernels (raised as ValueError by the Python wrappers).
OK, COINCIDENT, FOLDED = 0, 1, 2


# --- pair interactions ---------------------------------------------------------------------------
@njit(cache=True)
def _pair_first(r, x, y, kk, grad_r, grad_x, grad_y):
    """Energy of one pair and its first derivatives (written into the 3-vectors given).

    ``e = kk (x . y / |r|^3 - 3 (x . r)(y . r) / |r|^5)`` with r = p_i - p_j, x, y the unit
    dipoles of i and j and kk = k M^2 (the pair energy of dipoles M x and M y).
    """
    r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
    s = 1.0 / r2
    ir = math.sqrt(s)
    ir3 = s * ir
    ir5 = ir3 * s
    ir7 = ir5 * s
    a = x[0] * r[0] + x[1] * r[1] + x[2] * r[2]
    b = y[0] * r[0] + y[1] * r[1] + y[2] * r[2]
    c = x[0] * y[0] + x[1] * y[1] + x[2] * y[2]
    for q in range(3):
        grad_r[q] = kk * (-3.0 * c * ir5 * r[q] - 3.0 * ir5 * (b * x[q] + a * y[q]) + 15.0 * a * b * ir7 * r[q])
        grad_x[q] = kk * (ir3 * y[q] - 3.0 * b * ir5 * r[q])
        grad_y[q] = kk * (ir3 * x[q] - 3.0 * a * ir5 * r[q])
    return kk * (c * ir3 - 3.0 * a * b * ir5)


@njit(cache=True)
def _pair_second(r, x, y, kk, E, Ax, Ay, D):
    """Second derivatives of one pair's energy (3x3 blocks written into E, Ax, Ay, D).

    E = d2e/dr2, Ax[a, b] = d2e / dr_a dx_b, Ay[a, b] = d2e / dr_a dy_b, D[a, b] = d2e / dx_a dy_b.
    """
    r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
    s = 1.0 / r2
    ir = math.sqrt(s)
    ir3 = s * ir
    ir5 = ir3 * s
    ir7 = ir5 * s
    ir9 = ir7 * s
    a = x[0] * r[0] + x[1] * r[1] + x[2] * r[2]
    b = y[0] * r[0] + y[1] * r[1] + y[2] * r[2]
    c = x[0] * y[0] + x[1] * y[1] + x[2] * y[2]
    diag = -3.0 * c * ir5 + 15.0 * a * b * ir7
    crr = 15.0 * c * ir7 - 105.0 * a * b * ir9
    for p in range(3):
        vp = b * x[p] + a * y[p]
        for q in range(3):
            vq = b * x[q] + a * y[q]
            rr = r[p] * r[q]
            E[p, q] = kk * (crr * rr - 3.0 * ir5 * (x[p] * y[q] + y[p] * x[q]) + 15.0 * ir7 * (vp * r[q] + r[p] * vq))
            Ax[p, q] = kk * (-3.0 * ir5 * (r[p] * y[q] + y[p] * r[q]) + 15.0 * b * ir7 * rr)
            Ay[p, q] = kk * (-3.0 * ir5 * (r[p] * x[q] + x[p] * r[q]) + 15.0 * a * ir7 * rr)
            D[p, q] = kk * (-3.0 * ir5 * rr)
        E[p, p] += kk * diag
        Ax[p, p] += kk * (-3.0 * ir5 * b)
        Ay[p, p] += kk * (-3.0 * ir5 * a)
        D[p, p] += kk * ir3


@njit(cache=True)
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


@njit(cache=True)
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


# --- external field, gravity ---------------------------------------------------------------------
@njit(cache=True)
def dipole_field_and_gradient(points, centres, moments, r2_min):
    """Flux density and gradient of point dipoles at points, summed over the dipoles.

    The law of ``dipole.dipole_field`` and ``dipole.dipole_field_gradient``:
    ``B = k (3 r (m . r) / r^5 - m / r^3)``,
    ``G[a, b] = 3 k / r^5 (m_a r_b + r_a m_b + (m . r) delta_ab - 5 (m . r) r_a r_b / r^2)``,
    r from the dipole to the point.

    Args:
        points: (n, 3) field points [m].
        centres: (k, 3) dipole positions [m]; moments: (k, 3) dipole moments [A m^2].
        r2_min: (k,) no point may be at a squared distance <= this from a centre [m^2].

    Returns:
        ``(violation, B (n, 3) [T], G (n, 3, 3) [T/m])``; ``violation`` is -1, or
        ``point * k + dipole`` of the first point too close to a dipole (B, G then incomplete).
    """
    n = points.shape[0]
    k = centres.shape[0]
    B = np.zeros((n, 3))
    G = np.zeros((n, 3, 3))
    r = np.empty(3)
    for i in range(n):
        for j in range(k):
            r2 = 0.0
            mr = 0.0
            for c in range(3):
                r[c] = points[i, c] - centres[j, c]
                r2 += r[c] * r[c]
                mr += moments[j, c] * r[c]
            if r2 <= r2_min[j] or r2 <= 0.0:
                return i * k + j, B, G
            inv_r2 = 1.0 / r2
            inv_r = math.sqrt(inv_r2)
            inv_r3 = inv_r2 * inv_r
            inv_r5 = inv_r3 * inv_r2
            for a in range(3):
                B[i, a] += K_DIPOLE * (3.0 * r[a] * mr * inv_r5 - moments[j, a] * inv_r3)
                for b in range(3):
                    g = moments[j, a] * r[b] + r[a] * moments[j, b] - 5.0 * mr * inv_r2 * r[a] * r[b]
                    if a == b:
                        g += mr
                    G[i, a, b] += 3.0 * K_DIPOLE * inv_r5 * g
    return -1, B, G



@njit(cache=True)
def _add_external(p, m_hat, M, B, G, dU_dp, dU_dm):
    """Add ``U_e = -M sum_k m_hat_k . B_k`` to the gradients; returns U_e [J]."""
    n = p.shape[0]
    U = 0.0
    for k in range(n):
        for a in range(3):
            U -= M * m_hat[k, a] * B[k, a]
            dU_dm[k, a] -= M * B[k, a]
            for b in range(3):
                dU_dp[k, b] -= M * G[k, a, b] * m_hat[k, a]
    return U


@njit(cache=True)
def external_hessian_blocks(m_hat, M, G, dG):
    """The external field's per-ball Hessian blocks.

    Args:
        m_hat: (n, 3) unit dipoles; M: dipole moment [A m^2].
        G: (n, 3, 3) field gradient [T/m]; dG: (n, 3, 3, 3) its derivative [T/m^2].

    Returns:
        ``(H_pp, H_pm)`` (n, 3, 3): ``d2U_e / dp_k dp_k`` and ``d2U_e / dp_k dm_hat_k``.
    """
    n = m_hat.shape[0]
    H_pp = np.zeros((n, 3, 3))
    H_pm = np.zeros((n, 3, 3))
    for k in range(n):
        for b in range(3):
            for c in range(3):
                acc = 0.0
                for a in range(3):
                    acc += m_hat[k, a] * dG[k, a, b, c]
                H_pp[k, b, c] = -M * acc
                H_pm[k, b, c] = -M * G[k, c, b]
    return H_pp, H_pm


# --- sleeve --------------------------------------------------------------------------------------
@njit(cache=True)
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


@njit(cache=True)
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


# --- Cartesian chain energy (the wrench system) --------------------------------------------------
@njit(cache=True)
def cartesian_energy(p, m_hat, M, B, G, has_external, weight, k_s, base):
    """The chain's energy U = U_b + U_e + U_s + U_g and its gradient in Cartesian coordinates.

    Args:
        p: (n, 3) ball centres [m]; m_hat: (n, 3) unit dipoles; M: dipole moment [A m^2].
        B, G: (n, 3), (n, 3, 3) external field and gradient at the centres (ignored unless
            ``has_external``).
        weight: a ball's weight [N] for gravity along -z (0: no gravity).
        k_s: the sleeve's E I / d [J] (0: no sleeve); base: (3,) unit sheath axis.

    Returns:
        ``(status, terms (4,) [J], dU_dp (n, 3) [J/m], dU_dm_hat (n, 3) [J])``. The force on
        ball i is ``-dU_dp[i]``, its torque ``m_hat_i x (-dU_dm_hat[i])``.
    """
    n = p.shape[0]
    terms = np.zeros(4)
    status, U_b, dU_dp, dU_dm = pair_energy_gradient(p, m_hat, M)
    if status != OK:
        return status, terms, dU_dp, dU_dm
    terms[TERM_BALLS] = U_b
    if has_external:
        terms[TERM_EXTERNAL] = _add_external(p, m_hat, M, B, G, dU_dp, dU_dm)
    if weight != 0.0:
        for k in range(n):
            terms[TERM_GRAVITY] += weight * p[k, 2]
            dU_dp[k, 2] += weight
    if k_s > 0.0 and n > 1:
        L = n - 1
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
            return status, terms, dU_dp, dU_dm
        terms[TERM_SLEEVE] = U_s
        for l in range(L):  # through u = l / |l|: dU/dl = (I - u u^T) dU/du / |l|
            dot = u[l, 0] * dU_du[l, 0] + u[l, 1] * dU_du[l, 1] + u[l, 2] * dU_du[l, 2]
            for q in range(3):
                g = (dU_du[l, q] - u[l, q] * dot) / lengths[l]
                dU_dp[l + 1, q] += g
                dU_dp[l, q] -= g
    return OK, terms, dU_dp, dU_dm


@njit(cache=True)
def cartesian_wrenches(p, m_hat, M, B, G, has_external, k_s, base):
    """Forces (n, 3) [N] and torques (n, 3) [N m] on the balls from ``cartesian_energy``
    (gravity excluded): ``F_i = -dU/dp_i``, ``tau_i = m_hat_i x (-dU/dm_hat_i)``.

    Returns:
        ``(status, F, tau)``.
    """
    status, _, dU_dp, dU_dm = cartesian_energy(p, m_hat, M, B, G, has_external, 0.0, k_s, base)
    n = p.shape[0]
    F = np.empty((n, 3))
    tau = np.empty((n, 3))
    for i in range(n):
        for c in range(3):
            F[i, c] = -dU_dp[i, c]
        tau[i, 0] = -(m_hat[i, 1] * dU_dm[i, 2] - m_hat[i, 2] * dU_dm[i, 1])
        tau[i, 1] = -(m_hat[i, 2] * dU_dm[i, 0] - m_hat[i, 0] * dU_dm[i, 2])
        tau[i, 2] = -(m_hat[i, 0] * dU_dm[i, 1] - m_hat[i, 1] * dU_dm[i, 0])
    return status, F, tau


# --- reduced (chart) coordinates -----------------------------------------------------------------
@njit(cache=True)
def chart_frames(w0):
    """Charts centred on the K vectors w0 (K, 3): (r0, t1, t2) each (K, 3).

    r0 = w0 / |w0|; t2 the z axis made orthogonal to r0 (the x axis where r0 is within about
    17 deg of z: |z - (r0 . z) r0| < 0.3); t1 = t2 x r0.
    """
    K = w0.shape[0]
    r0 = np.empty((K, 3))
    t1 = np.empty((K, 3))
    t2 = np.empty((K, 3))
    t = np.empty(3)
    for i in range(K):
        norm = math.sqrt(w0[i, 0] ** 2 + w0[i, 1] ** 2 + w0[i, 2] ** 2)
        for c in range(3):
            r0[i, c] = w0[i, c] / norm
        for c in range(3):
            t[c] = (1.0 if c == 2 else 0.0) - r0[i, c] * r0[i, 2]
        nt = math.sqrt(t[0] ** 2 + t[1] ** 2 + t[2] ** 2)
        if nt < 0.3:
            for c in range(3):
                t[c] = (1.0 if c == 0 else 0.0) - r0[i, c] * r0[i, 0]
            nt = math.sqrt(t[0] ** 2 + t[1] ** 2 + t[2] ** 2)
        for c in range(3):
            t2[i, c] = t[c] / nt
        t1[i, 0] = t2[i, 1] * r0[i, 2] - t2[i, 2] * r0[i, 1]
        t1[i, 1] = t2[i, 2] * r0[i, 0] - t2[i, 0] * r0[i, 2]
        t1[i, 2] = t2[i, 0] * r0[i, 1] - t2[i, 1] * r0[i, 0]
    return r0, t1, t2


@njit(cache=True)
def configuration_vectors(p, m_hat):
    """The K = 2(n-1) chart vectors of a configuration: unit links, then the free dipoles."""
    L = p.shape[0] - 1
    w = np.empty((2 * L, 3))
    for l in range(L):
        norm = 0.0
        for c in range(3):
            w[l, c] = p[l + 1, c] - p[l, c]
            norm += w[l, c] * w[l, c]
        norm = math.sqrt(norm)
        for c in range(3):
            w[l, c] /= norm
            w[L + l, c] = m_hat[l + 1, c]
    return w


@njit(cache=True)
def chart_vectors(q, r0, t1, t2):
    """The K unit vectors at chart coordinates q = (a_1..a_K, b_1..b_K) and their derivatives.

    ``w = cos b (cos a r0 + sin a t1) + sin b t2``.

    Returns:
        V (5, K, 3): ``V[0] = w``, ``V[1] = dw/da``, ``V[2] = dw/db``, ``V[3] = d2w/da2``,
        ``V[4] = d2w/dadb`` (and ``d2w/db2 = -w``).
    """
    K = r0.shape[0]
    V = np.empty((5, K, 3))
    for i in range(K):
        ca, sa = math.cos(q[i]), math.sin(q[i])
        cb, sb = math.cos(q[K + i]), math.sin(q[K + i])
        for c in range(3):
            in_plane = ca * r0[i, c] + sa * t1[i, c]
            tangent = -sa * r0[i, c] + ca * t1[i, c]
            V[0, i, c] = cb * in_plane + sb * t2[i, c]
            V[1, i, c] = cb * tangent
            V[2, i, c] = -sb * in_plane + cb * t2[i, c]
            V[3, i, c] = -cb * in_plane
            V[4, i, c] = -sb * tangent
    return V


@njit(cache=True)
def chain_configuration(w, L, d):
    """Ball centres (n, 3) [m] (ball 1 at the origin, p_k = d sum_{l<k} w_l) and unit dipoles
    (n, 3) (ball 1 along +x, then w_L..w_{K-1}) from the K = 2L chart vectors."""
    n = L + 1
    p = np.zeros((n, 3))
    m = np.zeros((n, 3))
    m[0, 0] = 1.0
    for k in range(1, n):
        for c in range(3):
            p[k, c] = p[k - 1, c] + d * w[k - 1, c]
            m[k, c] = w[L + k - 1, c]
    return p, m


@njit(cache=True)
def rigidity_gaps(p, d):
    """``c_ij = |p_j - p_i|^2 / d^2 - 1`` for every non-adjacent pair (i < j - 1), in the order
    of ``numpy.triu_indices(n, k=2)``."""
    n = p.shape[0]
    P = (n - 1) * (n - 2) // 2
    gaps = np.empty(P)
    k = 0
    inv_d2 = 1.0 / (d * d)
    for i in range(n):
        for j in range(i + 2, n):
            acc = 0.0
            for c in range(3):
                s = p[j, c] - p[i, c]
                acc += s * s
            gaps[k] = acc * inv_d2 - 1.0
            k += 1
    return gaps


# Layout of ``reduced_energy``'s ``params`` (one array: fewer arguments to dispatch).
P_D, P_M, P_WEIGHT, P_KS, P_E0, P_BASE = 0, 1, 2, 3, 4, 5


def reduced_params(d: float, M: float, weight: float, k_s: float, E0: float, base) -> np.ndarray:
    """The ``params`` array of ``reduced_energy``: (d, M, weight, k_s, E0, base (3,))."""
    return np.concatenate([[d, M, weight, k_s, E0], np.asarray(base, dtype=float).reshape(3)])


@njit(cache=True)
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
    w, dwa, dwb, daa, dab = V[0], V[1], V[2], V[3], V[4]
    d, M, weight, k_s, E0 = params[P_D], params[P_M], params[P_WEIGHT], params[P_KS], params[P_E0]
    base = params[P_BASE:P_BASE + 3]
    n = p.shape[0]
    L = n - 1
    K = 2 * L
    nq = 2 * K
    kk = K_DIPOLE * M * M
    terms = np.zeros(4)
    grad = np.zeros(nq if order >= 1 else 0)
    hess = np.zeros((nq, nq) if order >= 2 else (0, 0))
    dU_dp = np.zeros((n, 3))
    dU_dm = np.zeros((n, 3))
    # Hessian blocks over the chart vectors' slots: slot k-1 <- p_k (later summed into links),
    # slot L+k-1 <- m_hat_k (k >= 1; ball 1's position and dipole are fixed).
    Hw = np.zeros((K, K, 3, 3) if order >= 2 else (0, 0, 3, 3))
    r = np.empty(3)
    gr = np.empty(3)
    gx = np.empty(3)
    gy = np.empty(3)
    E = np.empty((3, 3))
    Ax = np.empty((3, 3))
    Ay = np.empty((3, 3))
    D = np.empty((3, 3))
    U_b = 0.0
    for i in range(n):
        for j in range(i + 1, n):
            for c in range(3):
                r[c] = p[i, c] - p[j, c]
            if r[0] * r[0] + r[1] * r[1] + r[2] * r[2] <= 0.0:
                return COINCIDENT, terms, grad, hess
            U_b += _pair_first(r, m_hat[i], m_hat[j], kk, gr, gx, gy)
            if order >= 1:
                for c in range(3):
                    dU_dp[i, c] += gr[c]
                    dU_dp[j, c] -= gr[c]
                    dU_dm[i, c] += gx[c]
                    dU_dm[j, c] += gy[c]
            if order >= 2:
                _pair_second(r, m_hat[i], m_hat[j], kk, E, Ax, Ay, D)
                pi, pj, mi, mj = i - 1, j - 1, L + i - 1, L + j - 1  # j >= 1 always
                for a in range(3):
                    for b in range(3):
                        Hw[pj, pj, a, b] += E[a, b]
                        Hw[pj, mj, a, b] -= Ay[a, b]
                        if i > 0:
                            Hw[pi, pi, a, b] += E[a, b]
                            Hw[pi, pj, a, b] -= E[a, b]
                            Hw[pj, pi, a, b] -= E[a, b]
                            Hw[pi, mi, a, b] += Ax[a, b]
                            Hw[pj, mi, a, b] -= Ax[a, b]
                            Hw[pi, mj, a, b] += Ay[a, b]
                            Hw[mi, mj, a, b] += D[a, b]
                            Hw[mj, mi, b, a] += D[a, b]
    terms[TERM_BALLS] = U_b
    if has_external:
        terms[TERM_EXTERNAL] = _add_external(p, m_hat, M, B, G, dU_dp, dU_dm)
        if order >= 2:
            for k in range(1, n):
                for b in range(3):
                    for c in range(3):
                        acc = 0.0
                        for a in range(3):
                            acc += m_hat[k, a] * dG[k, a, b, c]
                        Hw[k - 1, k - 1, b, c] -= M * acc
                        Hw[k - 1, L + k - 1, b, c] -= M * G[k, c, b]
    if weight != 0.0:
        for k in range(n):
            terms[TERM_GRAVITY] += weight * p[k, 2]
            dU_dp[k, 2] += weight
    # Links: dU/du_l = d sum_{k > l} dU/dp_k; the same suffix sums, twice, for the Hessian.
    dU_du = np.zeros((L, 3))
    if order >= 1:
        for c in range(3):
            acc = 0.0
            for l in range(L - 1, -1, -1):
                acc += dU_dp[l + 1, c]
                dU_du[l, c] = d * acc
    if order >= 2:
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
    if k_s > 0.0:
        status, U_s = sleeve_energy(w[:L], base, k_s, dU_du, Hw, order)
        if status != OK:
            return status, terms, grad, hess
        terms[TERM_SLEEVE] = U_s
    if order < 1:
        return OK, terms, grad, hess
    inv_E0 = 1.0 / E0
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
    if order < 2:
        return OK, terms, grad, hess
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
    return OK, terms, grad, hess


@njit(cache=True)
def pair_index(n, i, j):
    """Row of the non-adjacent pair (i, j), i < j - 1, in ``rigidity_gaps``' order."""
    # Rows before i: sum_{r < i} (n - 2 - r).
    return i * (n - 2) - i * (i - 1) // 2 + (j - i - 2)


@njit(cache=True)
def pair_of_row(n, k):
    """(i, j) of row k of ``rigidity_gaps``."""
    i = 0
    while k >= n - 2 - i:
        k -= n - 2 - i
        i += 1
    return i, i + 2 + k


@njit(cache=True)
def constraint_rows(rows, p, V, d, normal):
    """Rows of the constraints' Jacobian with respect to q (len(rows), nq).

    Rows below P = (n-1)(n-2)/2 are the rigidity gaps (``rigidity_gaps``' order):
    ``dc/dq = (2/d) S . dw_l/dq`` for the links l = i..j-1 spanned by the pair. Rows P + b - 1
    are the wall rows ``n . p_b / d - const`` of ball b (linear in the links l < b).
    """
    dwa, dwb = V[1], V[2]
    n = p.shape[0]
    L = n - 1
    K = 2 * L
    P = (n - 1) * (n - 2) // 2
    out = np.zeros((rows.shape[0], 2 * K))
    S = np.empty(3)
    for r_ in range(rows.shape[0]):
        k = rows[r_]
        if k < P:
            i, j = pair_of_row(n, k)
            for c in range(3):
                S[c] = (2.0 / d) * (p[j, c] - p[i, c])
            lo, hi = i, j
        else:
            for c in range(3):
                S[c] = normal[c]
            lo, hi = 0, k - P + 1
        for l in range(lo, hi):
            out[r_, l] = S[0] * dwa[l, 0] + S[1] * dwa[l, 1] + S[2] * dwa[l, 2]
            out[r_, K + l] = S[0] * dwb[l, 0] + S[1] * dwb[l, 1] + S[2] * dwb[l, 2]
    return out


@njit(cache=True)
def rigidity_hessian(rows, weights, p, V, d):
    """``sum_k weights_k d2 c_k / dq2`` (nq, nq) over rigidity rows k (``rigidity_gaps``' order).

    ``c = |S|^2 / d^2 - 1`` with ``S = d sum_{l in span} w_l``, so
    ``d2c/dq2 = (2/d^2) J_S^T J_S + (2/d^2) S . d2S/dq2``.
    """
    w, dwa, dwb, daa, dab = V[0], V[1], V[2], V[3], V[4]
    n = p.shape[0]
    L = n - 1
    K = 2 * L
    H = np.zeros((2 * K, 2 * K))
    S = np.empty(3)
    for r_ in range(rows.shape[0]):
        i, j = pair_of_row(n, rows[r_])
        wt = weights[r_]
        for c in range(3):
            S[c] = p[j, c] - p[i, c]
        for l1 in range(i, j):
            for l2 in range(i, j):
                aa = 0.0
                ab = 0.0
                ba = 0.0
                bb = 0.0
                for c in range(3):
                    aa += dwa[l1, c] * dwa[l2, c]
                    ab += dwa[l1, c] * dwb[l2, c]
                    ba += dwb[l1, c] * dwa[l2, c]
                    bb += dwb[l1, c] * dwb[l2, c]
                H[l1, l2] += wt * 2.0 * aa
                H[l1, K + l2] += wt * 2.0 * ab
                H[K + l1, l2] += wt * 2.0 * ba
                H[K + l1, K + l2] += wt * 2.0 * bb
            s_aa = 0.0
            s_ab = 0.0
            s_bb = 0.0
            for c in range(3):
                s_aa += daa[l1, c] * S[c]
                s_ab += dab[l1, c] * S[c]
                s_bb -= w[l1, c] * S[c]
            H[l1, l1] += wt * (2.0 / d) * s_aa
            H[l1, K + l1] += wt * (2.0 / d) * s_ab
            H[K + l1, l1] += wt * (2.0 / d) * s_ab
            H[K + l1, K + l1] += wt * (2.0 / d) * s_bb
    return H


@njit(cache=True)
def links_hessian(W, V):
    """``sum_l W_l . d2 w_l / dq2`` (2K, 2K) for per-link weight vectors W (L, 3)."""
    w, daa, dab = V[0], V[3], V[4]
    K = w.shape[0]
    H = np.zeros((2 * K, 2 * K))
    for l in range(W.shape[0]):
        aa = 0.0
        ab = 0.0
        bb = 0.0
        for c in range(3):
            aa += daa[l, c] * W[l, c]
            ab += dab[l, c] * W[l, c]
            bb -= w[l, c] * W[l, c]
        H[l, l] = aa
        H[l, K + l] = ab
        H[K + l, l] = ab
        H[K + l, K + l] = bb
    return H


# --- Python wrappers -----------------------------------------------------------------------------
_STATUS_MESSAGES = {
    COINCIDENT: "two balls coincide (zero separation)",
    FOLDED: "a sleeve bend of 180 deg (chain folded onto itself)",
}


def check_status(status: int, what: str) -> None:
    """Raise ValueError, naming ``what``, for a kernel's non-OK status."""
    if status != OK:
        raise ValueError(f"{what}: {_STATUS_MESSAGES.get(int(status), f'kernel status {status}')}")


_ZEROS: dict = {}


def _zeros(shape) -> np.ndarray:
    """A cached array of zeros (the kernels only read their field inputs)."""
    z = _ZEROS.get(shape)
    if z is None:
        z = _ZEROS[shape] = np.zeros(shape)
    return z


def external_arrays(external, p: np.ndarray, hessian: bool = False):
    """(has_external, B (n, 3), G (n, 3, 3), dG (n, 3, 3, 3)) of a FieldSource (or None) at p.

    dG (from ``field_sources.field_gradient_derivative``) only when ``hessian``; zeros otherwise.
    The zero arrays are shared between calls (the kernels only read them): do not write to them.
    """
    from ballchain.drake_models.field_sources import UniformField, field_gradient_derivative

    n = p.shape[0]
    if external is None:
        return False, _zeros((n, 3)), _zeros((n, 3, 3)), _zeros((n, 3, 3, 3))
    if isinstance(external, UniformField):  # the same field everywhere: no gradient
        B = np.empty((n, 3))
        B[:] = external.B_W
        return True, B, _zeros((n, 3, 3)), _zeros((n, 3, 3, 3))
    B, G = external.field_and_gradient(p)
    dG = field_gradient_derivative(external, p) if hessian else np.zeros((n, 3, 3, 3))
    return True, np.ascontiguousarray(B, dtype=float), np.ascontiguousarray(G, dtype=float), \
        np.ascontiguousarray(dG, dtype=float)


def chain_energy(chain, p, m_hat, external=None, gravity: bool = False, base_direction=(1.0, 0.0, 0.0)):
    """Total potential energy of a chain configuration and its gradient (the compiled kernel).

    Same arguments and results as the numpy reference ``chain_energy.chain_energy``.

    Args:
        chain: the chain's parameters (sleeve bending included when ``chain.sleeve``).
        p: (n, 3) ball centres [m].
        m_hat: (n, 3) unit dipole directions.
        external: the external FieldSource, or None.
        gravity: include gravity (along -z).
        base_direction: sheath axis, for the sleeve's first bend.

    Returns:
        ``(U, dU_dp, dU_dm_hat, terms)``: U [J], gradients (n, 3) [J/m] and [J], EnergyTerms.
    """
    from ballchain.drake_models.chain_energy import EnergyTerms
    from ballchain.drake_models.params import GRAVITY

    p = np.ascontiguousarray(p, dtype=float)
    m_hat = np.ascontiguousarray(m_hat, dtype=float)
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(m_hat))):
        raise ValueError("chain_energy: positions or dipoles are not finite (NaN or inf)")
    has_ext, B, G, _ = external_arrays(external, p)
    base = np.asarray(base_direction, dtype=float).reshape(3)
    base = base / np.linalg.norm(base)
    k_s = chain.sleeve.bending_stiffness / chain.ball_diameter if chain.sleeve is not None else 0.0
    weight = chain.ball_mass * GRAVITY if gravity else 0.0
    status, t, dU_dp, dU_dm = cartesian_energy(p, m_hat, chain.dipole_moment, B, G, has_ext, weight, k_s, base)
    check_status(status, "chain_energy")
    terms = EnergyTerms(float(t[0]), float(t[1]), float(t[2]), float(t[3]))
    return terms.total, dU_dp, dU_dm, terms


def chain_wrenches(chain, p, m_hat, external=None, base_direction=(1.0, 0.0, 0.0)):
    """Forces (n, 3) [N] and torques (n, 3) [N m] on the balls from the chain's magnetic and
    sleeve energy (gravity excluded): ``F_i = -dU/dp_i``, ``tau_i = m_hat_i x (-dU/dm_hat_i)``.

    Args:
        chain: the chain's parameters (sleeve included when ``chain.sleeve``).
        p: (n, 3) ball centres [m]; m_hat: (n, 3) unit dipoles.
        external: the external FieldSource, or None.
        base_direction: (3,) sheath axis for the sleeve's first bend.
    """
    p = np.ascontiguousarray(p, dtype=float)
    m_hat = np.ascontiguousarray(m_hat, dtype=float)
    if not (np.isfinite(p).all() and np.isfinite(m_hat).all()):
        raise ValueError("chain_wrenches: positions or dipoles are not finite (NaN or inf)")
    has_ext, B, G, _ = external_arrays(external, p)
    base = np.asarray(base_direction, dtype=float).reshape(3)
    base = base / np.linalg.norm(base)
    k_s = chain.sleeve.bending_stiffness / chain.ball_diameter if chain.sleeve is not None else 0.0
    status, F, tau = cartesian_wrenches(p, m_hat, chain.dipole_moment, B, G, has_ext, k_s, base)
    check_status(status, "chain_wrenches")
    return F, tau


def warm_up() -> None:
    """Compile (or load from the cache) every kernel the stack runs, on a 4-ball chain."""
    from ballchain.drake_models.field_sources import UniformField
    from ballchain.drake_models.params import BallChain, Sleeve
    from ballchain.optimization.reduced_chain import ReducedChain

    chain = BallChain(n_balls=4, sleeve=Sleeve())
    d = chain.ball_diameter
    p = d * np.array([[0.0, 0, 0], [1, 0, 0], [1.8, 0.6, 0], [2.2, 1.5, 0.1]])
    m = np.tile([1.0, 0.0, 0.0], (4, 1))
    chain_energy(chain, p, m, UniformField([0.0, 0.02, 0.0]), gravity=True)
    chain_wrenches(chain, p, m, UniformField([0.0, 0.02, 0.0]))
    pair_hessian(p, m, chain.dipole_moment)
    dipole_field_and_gradient(p, np.array([[0.0, 0.2, 0.0]]), np.array([[0.0, 1.0, 0.0]]), np.zeros(1))
    model = ReducedChain(chain, UniformField([0.0, 0.02, 0.0]), gravity=True)
    model.chart_from_configuration(p, m)
    q = np.zeros(model.nq)
    ev = model.evaluate(q, 2)
    ev.jacobian[np.arange(len(ev.gaps))]
    model.constraint_hessian(q, np.array([0]), np.array([1.0]))
    model.tip_hessian(q, np.ones(3))


guard_cache(globals())  # a damaged cache file is recompiled, not a traceback on every run
