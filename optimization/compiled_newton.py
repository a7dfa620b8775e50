"""The statics' Newton SQP as one compiled call per equilibrium.

The same solver as ``statics.ChainStatics``'s Python ``_newton`` (the reference the tests hold
this one to), step for step: the Lagrangian's quadratic model with the last multipliers, the
dense dual active-set QP of the rows near contact (``kernels.dense_qp``), the null-space step
for a pinned tip, the l1 merit line search with its second-order correction, the
negative-curvature escape from saddle points, the chart re-centring near the poles and the same
convergence tests and failure reasons. The model it evaluates is the reduced chain
(``kernels.reduced``: pairs, external field, sleeve, gravity along -z) with, optionally, a tip
target, a plane wall, or the heart's wall and sheath rows (``kernels.heart_rows``) and gravity
along any direction of frame B.

The external field must be point dipoles and a uniform field (``field_arrays``): the kernel
evaluates it itself. Python prepares the arrays and reads the answer (``compiled_model``).

The model travels through the kernels as one tuple (``model_tuple``):
``(params, field_c, field_m, field_B0, field_r2, tip_target, wall, p_WB, R_WB, sdf_grid,
sdf_frame, sheath, settings, flags)``.
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.kernels._common import OK, kernel
from ballchain.drake_models.kernels.charts import (chain_configuration, chart_frames, chart_vectors,
                                                   configuration_vectors)
from ballchain.drake_models.kernels.constraints import (constraint_rows, links_hessian, rigidity_gaps,
                                                        rigidity_hessian)
from ballchain.drake_models.kernels.dense_qp import cho_solve, cholesky, dense_qp
from ballchain.drake_models.kernels.external import dipole_arrays
from ballchain.drake_models.kernels.heart_rows import heart_rows
from ballchain.drake_models.kernels.reduced import P_D, P_E0, reduced_energy

# settings: the solver's constants.
S_TOL, S_FEAS, S_MARGIN, S_MAX_STEP, S_HEART_WEIGHT, S_RADIUS = 0, 1, 2, 3, 4, 5
# flags: iteration limit and what the model holds.
F_MAX_ITER, F_EXTERNAL, F_PINNED, F_WALL, F_HEART = 0, 1, 2, 3, 4

# The QP's curvature when the Lagrangian's Hessian H is indefinite: H + rho s R'R for the first of
# these rho (s = max(1, max|H_ii|)) whose Cholesky succeeds, R first the step's rows that touch
# (gap at most TOUCHING, dimensionless), then all its rows. On the rows' tangent space the
# curvature stays H's own (the negative curvature of a chain pressed on the wall lies across the
# rows: docs/performance.md 18), so the step is the exact one there; a near row that does not
# touch may open, and keeps H's curvature along its normal unless that is what is indefinite.
CONVEXIFY = (1e-3, 1e-2, 1e-1, 1.0, 10.0)
TOUCHING = 1e-6

# Why the solve stopped (``REASONS`` in statics.py gives the reference's messages).
R_MINIMUM, R_MINIMUM_LINE, R_QP, R_SADDLE, R_LINE, R_LIMIT, R_FIELD, R_ENERGY = range(8)


@kernel
def evaluate(q, order, chart, model):
    """The model at q: ``(status, energy/E0, terms (4,) [J], gaps, gradient, Hessian,
    tip residual (3,), V, p, m_hat, v)`` (gradient and Hessian up to ``order``; v (2L, 3) the
    heart rows' gradients through the centres, empty without the heart). status: OK, the
    energy kernel's status, or -1 when a ball is too close to a field dipole."""
    params, fc, fm, fB0, fr2, tip, wall, p_WB, R_WB, grid, frame, sheath, settings, flags = model
    r0, t1, t2 = chart
    K = r0.shape[0]
    L = K // 2
    d, E0 = params[P_D], params[P_E0]
    V = chart_vectors(q, r0, t1, t2)
    p, m_hat = chain_configuration(V[0], L, d)
    n = L + 1
    has_ext = flags[F_EXTERNAL] == 1
    violation, B, G, dG = dipole_arrays(p, fc, fm, fB0, fr2, order >= 2)
    status, terms, grad, hess = reduced_energy(V, p, m_hat, B, G, dG, params, has_ext, order)
    if has_ext and violation >= 0:
        status = -1
    rig = rigidity_gaps(p, d)
    P = rig.shape[0]
    tip_res = np.zeros(3)
    if flags[F_HEART] == 1:
        values, v, _ = heart_rows(p[1:], p_WB, R_WB, grid, frame, sheath, settings[S_RADIUS], d, False)
        gaps = np.concatenate((rig, values))
        W = settings[S_HEART_WEIGHT]
        if W != 0.0:  # U_g = W sum_k z_W(p_k): per-link weights d (L - l) W R_WB^T z_W
            U_g = p_WB[2] * n
            for k in range(n):
                U_g += p[k, 0] * R_WB[2, 0] + p[k, 1] * R_WB[2, 1] + p[k, 2] * R_WB[2, 2]
            terms[3] = W * U_g
            W_g = np.empty((L, 3))
            for l in range(L):
                for c in range(3):
                    W_g[l, c] = d * (L - l) * W * R_WB[2, c]
            if order >= 1:
                for l in range(L):
                    grad[l] += (W_g[l] @ V[1, l]) / E0
                    grad[K + l] += (W_g[l] @ V[2, l]) / E0
            if order >= 2:
                hess += links_hessian(W_g, V) / E0
    else:
        v = np.zeros((0, 3))
        gaps = rig
        if flags[F_WALL] == 1:  # every free ball on the open side: n . (p - p0) / d >= 1/2
            gaps = np.empty(P + L)
            gaps[:P] = rig
            for k in range(L):
                gaps[P + k] = ((p[k + 1] - wall[:3]) @ wall[3:]) / d - 0.5
        if flags[F_PINNED] == 1:
            tip_res = (p[L] - tip) / d
    energy = (terms[0] + terms[1] + terms[2] + terms[3]) / E0
    return status, energy, terms, gaps, grad, hess, tip_res, V, p, m_hat, v


@kernel
def jacobian_rows(rows, ev, model):
    """The rows' Jacobian (len(rows), nq) at the evaluation ev."""
    V, p, v = ev[7], ev[8], ev[10]
    flags, wall, d = model[13], model[6], model[0][P_D]
    K = V.shape[1]
    L = K // 2
    P = L * (L - 1) // 2
    if flags[F_HEART] == 0:
        return constraint_rows(rows, p, V, d, wall[3:])
    out = np.zeros((rows.shape[0], 2 * K))
    for i in range(rows.shape[0]):
        k = rows[i]
        if k < P:
            out[i] = constraint_rows(rows[i:i + 1], p, V, d, wall[3:])[0]
            continue
        row = k - P
        v0, v1, v2 = v[row, 0], v[row, 1], v[row, 2]
        for l in range(row % L + 1):
            out[i, l] = v0 * V[1, l, 0] + v1 * V[1, l, 1] + v2 * V[1, l, 2]
            out[i, K + l] = v0 * V[2, l, 0] + v1 * V[2, l, 1] + v2 * V[2, l, 2]
    return out


@kernel
def tip_jacobian(V):
    """d(p_tip / d)/dq (3, nq) = sum_l dw_l/dq over the links."""
    K = V.shape[1]
    L = K // 2
    J = np.zeros((3, 2 * K))
    for l in range(L):
        for c in range(3):
            J[c, l] = V[1, l, c]
            J[c, K + l] = V[2, l, c]
    return J


@kernel
def constraint_hessian(rows, weights, ev, model):
    """``sum_k weights_k d2 c_k / dq2`` (nq, nq) over the rows at the evaluation ev."""
    V, p = ev[7], ev[8]
    params, p_WB, R_WB, grid, frame, sheath, settings, flags, wall = (
        model[0], model[7], model[8], model[9], model[10], model[11], model[12], model[13], model[6])
    d = params[P_D]
    K = V.shape[1]
    L = K // 2
    P = L * (L - 1) // 2
    rigid = rows < P
    H = rigidity_hessian(rows[rigid], weights[rigid], p, V, d)
    others = np.flatnonzero(~rigid)
    if others.size == 0:
        return H
    per_ball = np.zeros((L, 3))
    heart = flags[F_HEART] == 1
    if heart:
        _, v, M = heart_rows(p[1:], p_WB, R_WB, grid, frame, sheath, settings[S_RADIUS], d, True)
    else:
        v = np.zeros((L, 3))
        M = np.zeros((L, 3, 3))
        for k in range(L):
            v[k] = wall[3:]
    for i in others:
        row = rows[i] - P
        per_ball[row % L] += weights[i] * v[row]
    per_link = per_ball.copy()  # the chart's curvature: weights summed over the balls beyond
    for l in range(L - 2, -1, -1):
        per_link[l] += per_link[l + 1]
    H += links_hessian(per_link, V)
    if heart:
        for i in others:
            row = rows[i] - P
            _add_through_centre(H, weights[i] * M[row], V, row % L + 1)
    return H


@kernel
def _add_through_centre(H, M, V, links):
    """H += T' M T with T (3, nq) the centre's Jacobian over the first ``links`` links.

    The 3-vector products written out: as numpy calls (a BLAS call per product, 4 links^2 of
    them) they were most of the Lagrangian's Hessian in the heart (26 of 34 us for 12 links)."""
    K = V.shape[1]
    for s1 in range(2):
        for l1 in range(links):
            t0, t1, t2 = V[1 + s1, l1, 0], V[1 + s1, l1, 1], V[1 + s1, l1, 2]
            m0 = M[0, 0] * t0 + M[1, 0] * t1 + M[2, 0] * t2  # M' t
            m1 = M[0, 1] * t0 + M[1, 1] * t1 + M[2, 1] * t2
            m2 = M[0, 2] * t0 + M[1, 2] * t1 + M[2, 2] * t2
            row = s1 * K + l1
            for s2 in range(2):
                for l2 in range(links):
                    H[row, s2 * K + l2] += m0 * V[1 + s2, l2, 0] + m1 * V[1 + s2, l2, 1] + m2 * V[1 + s2, l2, 2]


@kernel
def infeasibility(ev, pinned):
    """The summed violation of an evaluation's rows (and of the tip target when pinned)."""
    total = 0.0
    for g in ev[3]:
        if g < 0.0:
            total -= g
    if pinned:
        total += np.abs(ev[6]).sum()
    return total


@kernel
def positive_definite(H):
    """``(ok, Hm, Lc, definite)``: H itself when it is positive definite (``definite``), else H
    with its eigenvalues replaced by max(|lambda|, 1e-10 max|lambda|); Lc its Cholesky factor
    (ok False: none)."""
    ok, Lc = cholesky(H)
    if ok:
        return True, H, Lc, True
    w, Vec = np.linalg.eigh(H)
    delta = 1e-10 * max(1.0, np.abs(w).max())
    Hm = (Vec * np.maximum(np.abs(w), delta)) @ Vec.T
    ok, Lc = cholesky(Hm)
    return ok, Hm, Lc, False


@kernel
def qp_curvature(H, Nt, N):
    """``(ok, Hm, Lc, definite)`` of the QP's curvature for the constraint rows N, of which the
    rows Nt touch (``statics._qp_curvature``): H itself when it is positive definite, else the
    first of H + rho s Nt'Nt, then of H + rho s N'N (s = max(1, max|H_ii|), rho in
    ``CONVEXIFY``) that is, else ``positive_definite(H)``'s eigenvalue flip."""
    ok, Lc = cholesky(H)
    if ok:
        return True, H, Lc, True
    s = max(1.0, np.abs(np.diag(H)).max())
    for k in range(2):
        if k == 1 and Nt.shape[0] == N.shape[0]:
            break  # every row touches: tried
        R = Nt if k == 0 else N
        C = R.T @ R
        for rho in CONVEXIFY:
            Hc = H + (rho * s) * C
            ok, Lc = cholesky(Hc)
            if ok:
                return True, Hc, Lc, False
    return positive_definite(H)


@kernel
def null_space(J):
    """Orthonormal basis (columns) of the null space of J (rank at 1e-10 of the largest
    singular value, or of 1)."""
    _, s, Vt = np.linalg.svd(J)
    top = s.max() if s.size else 0.0
    rank = 0
    for x in s:
        if x > 1e-10 * max(1.0, top):
            rank += 1
    return np.ascontiguousarray(Vt[rank:].T)


@kernel
def pinned_step(H, g, J, c):
    """``(ok, dq, lam, curvature)``: the step of min g'dq + dq'H dq / 2 subject to J dq + c = 0
    (the tip target's linearisation, J (m, nq) of full row rank) from its KKT system
    H dq - J'lam = -g, by the Schur complement of Hc = H + rho s J'J (s = max(1, max|H_ii|),
    rho the first of ``CONVEXIFY`` whose Cholesky succeeds): on J dq = -c, Hc's step is H's and
    its multipliers are lam - rho s J dq = lam + rho s c. A pinned chain's H is indefinite (the
    chain pressed by the magnets would buckle without the pin); it is positive definite on J's
    null space at a step the null-space method accepts as it is, and then some rho s J'J makes
    Hc positive definite (Finsler's lemma). The same step as ``newton_step``'s null-space one
    (round-off apart) for a third of its cost: two Cholesky factorisations instead of three
    SVDs and the null-space products (docs/performance.md, section 33). ok False (nothing
    computed): no rho worked, or J J' or the Schur complement is not positive definite: the
    caller takes the null-space step. curvature: v'H v for v = P dq, P the projector on J's
    null space: the null-space step's dq' Hm dq."""
    m, nq = J.shape
    s = 1.0
    for i in range(nq):
        s = max(s, abs(H[i, i]))
    JtJ = J.T @ J
    ok = False
    Lc = np.zeros((nq, nq))
    shift = 0.0
    for rho in CONVEXIFY:
        shift = rho * s
        ok, Lc = cholesky(H + shift * JtJ)
        if ok:
            break
    if not ok:
        return False, g, np.zeros(m), 0.0
    HiJt = np.empty((nq, m))
    for k in range(m):
        HiJt[:, k] = cho_solve(Lc, np.ascontiguousarray(J[k]))
    Hig = cho_solve(Lc, g)
    ok, Ls = cholesky(J @ HiJt)
    if not ok:
        return False, g, np.zeros(m), 0.0
    lam = cho_solve(Ls, J @ Hig - c)
    dq = HiJt @ lam - Hig
    ok, Lj = cholesky(J @ J.T)
    if not ok:
        return False, g, np.zeros(m), 0.0
    v = dq - J.T @ cho_solve(Lj, J @ dq)
    return True, dq, lam + shift * c, v @ (H @ v)


@kernel
def null_space_step(H, g, J, c):
    """``(dq, lam, curvature)`` of min g'dq + dq'H dq / 2 subject to J dq + c = 0 by the null
    space Z of J, Z'HZ made positive definite (``positive_definite``); curvature dq'Hm dq for the
    model's curvature Hm = Z Hz Z'. ``pinned_step``'s fallback; raises (a LinAlgError) when no
    positive definite Hz is found."""
    Z = null_space(J)
    dq_n = -(np.linalg.pinv(J) @ c)
    ok, Hz, Lz, _ = positive_definite(Z.T @ H @ Z)
    if not ok:
        raise np.linalg.LinAlgError("Matrix is not positive definite.")
    dq = dq_n - Z @ cho_solve(Lz, Z.T @ (g + H @ dq_n))
    Hm = Z @ Hz @ Z.T
    lam = np.linalg.lstsq(np.ascontiguousarray(J.T), g + H @ dq)[0]
    return dq, lam, dq @ (Hm @ dq)


@kernel
def newton_step(ev, H, near, pinned, lam_tip, model):
    """The Newton step at ev for the Lagrangian's Hessian H (``ChainStatics._newton_step``).

    Returns:
        ``(ok, dq, curvature, lam, lam_tip, definite)``: curvature is dq' Hm dq for the step's
        model curvature Hm (H made positive definite where it must be: on the tangent space of
        a pinned tip, the QP's ``qp_curvature``), the predicted decrease's quadratic term; ok
        False when the step's QP is infeasible; definite when H itself is positive definite;
        raises (a LinAlgError) when a system is singular.
    """
    g = ev[4]
    if pinned and near.size == 0:
        # Equality constraints only: the KKT step of the tip target, by the Schur complement of
        # H + rho s J'J (``pinned_step``), or else a null-space step, positive definite on the
        # tangent space.
        J = tip_jacobian(ev[7])
        ok, dq, lam_tip, curvature = pinned_step(H, g, J, ev[6])
        if not ok:
            dq, lam_tip, curvature = null_space_step(H, g, J, ev[6])
        return True, dq, curvature, np.zeros(0), lam_tip, False
    if near.size == 0:
        ok, Hm, Lc, definite = positive_definite(H)
        if not ok:
            raise np.linalg.LinAlgError("Matrix is not positive definite.")
        dq = -cho_solve(Lc, g)
        return True, dq, dq @ (Hm @ dq), np.zeros(0), lam_tip, definite
    n_in = near.size
    J = jacobian_rows(near, ev, model)
    gaps = ev[3]
    if pinned:
        N = np.vstack((J, tip_jacobian(ev[7])))
        c = np.concatenate((gaps[near], ev[6]))
    else:
        N = J
        c = gaps[near]
    touching = np.flatnonzero(c[:n_in] <= TOUCHING)
    Nt = np.vstack((J[touching], N[n_in:])) if pinned else np.ascontiguousarray(J[touching])
    ok, Hm, Lc, definite = qp_curvature(H, Nt, N)
    if not ok:
        raise np.linalg.LinAlgError("Matrix is not positive definite.")
    ok, dq, y = dense_qp(Lc, g, N, c, n_in, 200)
    if not ok:
        return False, dq, 0.0, y, lam_tip, definite
    lam_tip = y[n_in:].copy() if pinned else np.zeros(3)
    return True, dq, dq @ (Hm @ dq), y[:n_in].copy(), lam_tip, definite


@kernel
def negative_curvature(ev, H, near, lam, pinned, model):
    """``(saddle, direction)``: saddle False when H is positive semi-definite (up to 1e-7) on
    the tangent space of the active rows (multiplier above 1e-9, and the tip target when
    pinned): a local minimum. Else the tangent space's direction of most negative curvature."""
    nq = H.shape[0]
    active = near[lam > 1e-9]
    J = jacobian_rows(active, ev, model)
    if pinned:
        J = np.vstack((J, tip_jacobian(ev[7])))
    if J.shape[0] == 0:  # no active row: the whole space (Z = I)
        ok, _ = cholesky(H + 1e-7 * np.eye(nq))
        if ok:
            return False, np.zeros(nq)
        return True, np.ascontiguousarray(np.linalg.eigh(H)[1][:, 0])
    Z = null_space(J)
    Ht = Z.T @ H @ Z
    ok, _ = cholesky(Ht + 1e-7 * np.eye(Ht.shape[0]))
    if ok:
        return False, np.zeros(nq)
    _, Vec = np.linalg.eigh(Ht)
    return True, Z @ Vec[:, 0]


@kernel
def line_search(q, dq, ev, near, pinned, rho, merit0, slope, chart, model):
    """Backtracking on the l1 merit from q along dq (Armijo 1e-4), with a second-order
    correction of the full step onto curved rows (``statics._line_search``).

    Returns:
        ``(t, dq, trial)``: t below 1e-10 when there is no descent.
    """
    t = 1.0
    while True:
        trial = evaluate(q + t * dq, 2 if t == 1.0 else 0, chart, model)
        if trial[0] != OK:
            return t, dq, trial
        merit = trial[1] + rho * infeasibility(trial, pinned)
        if merit <= merit0 + 1e-4 * t * min(slope, 0.0) or t < 1e-10:
            break
        if t == 1.0 and (pinned or near.size):
            if pinned:  # the tip back on target (Maratos effect)
                correction = -(np.linalg.pinv(tip_jacobian(ev[7])) @ trial[6])
            else:  # the curved rows the full step violates
                rows = near[trial[3][near] < 0.0]
                correction = np.zeros(0)
                if rows.size:
                    correction = -(np.linalg.pinv(jacobian_rows(rows, ev, model)) @ trial[3][rows])
            if correction.size:
                corrected = evaluate(q + dq + correction, 2, chart, model)
                if corrected[0] != OK:
                    return t, dq, corrected
                if corrected[1] + rho * infeasibility(corrected, pinned) <= merit0 + 1e-4 * min(slope, 0.0):
                    return t, dq + correction, corrected
        t *= 0.5
    return t, dq, trial


@kernel
def lagrangian_hessian(ev, rows, weights, pinned, lam_tip, model):
    """The energy's Hessian less the rows' and the tip target's curvature times their
    multipliers: the SQP step's model."""
    H = ev[5]
    if rows.size:
        H = H - constraint_hessian(rows, weights, ev, model)
    if pinned and np.any(lam_tip != 0.0):
        W = np.empty((ev[7].shape[1] // 2, 3))
        for l in range(W.shape[0]):
            W[l] = lam_tip
        H = H - links_hessian(W, ev[7])
    return H


@kernel
def escape_direction(q, ev, H, near, lam, pinned, chart, model):
    """The saddle test and escape of a first-order point: ``(saddle, dq)`` (dq of length 0.1
    along the most negative curvature, towards lower energy)."""
    saddle, direction = negative_curvature(ev, H, near, lam, pinned, model)
    if not saddle:
        return False, direction
    dq = 0.1 * direction
    if evaluate(q - dq, 0, chart, model)[1] < evaluate(q + dq, 0, chart, model)[1]:
        dq = -dq
    return True, dq


@kernel
def recentre(q, chart, model):
    """Centre the chart (in place) on the configuration at q."""
    d = model[0][P_D]
    r0, t1, t2 = chart
    V = chart_vectors(q, r0, t1, t2)
    p, m_hat = chain_configuration(V[0], r0.shape[0] // 2, d)
    a, b, c = chart_frames(configuration_vectors(p, m_hat))
    r0[:] = a
    t1[:] = b
    t2[:] = c


@kernel
def newton(chart, model, rows0, weights0):
    """One equilibrium: the SQP iteration from q = 0 in the chart (centred on the warm start by
    the caller, re-centred in place near the poles), and the model at the answer. This is the
    one call per equilibrium: a singular system raises numpy's LinAlgError (the caller reports
    it as the reference does).

    Returns:
        ``(reason, status, iterations, rows, lam, lam_tip, p, m_hat, terms, gaps, v)``: an
        ``R_*`` reason; the evaluation's status when it is ``R_ENERGY`` or ``R_FIELD``; the
        multipliers of the rows ``rows`` near contact and of the tip target; the configuration,
        energy terms [J], rows' values and heart rows' gradients at the answer.
    """
    settings, flags = model[12], model[13]
    tol, feas, margin, max_step = settings[S_TOL], settings[S_FEAS], settings[S_MARGIN], settings[S_MAX_STEP]
    pinned = flags[F_PINNED] == 1
    K = chart[0].shape[0]
    q = np.zeros(2 * K)
    ev = evaluate(q, 2, chart, model)
    keep = rows0 < ev[3].shape[0]
    rows, lam_rows = rows0[keep], weights0[keep]
    lam_tip = np.zeros(3)
    rho = 1.0
    escapes = 0
    for iteration in range(1, flags[F_MAX_ITER] + 1):
        if ev[0] != OK:
            return _answer((R_FIELD if ev[0] < 0 else R_ENERGY), ev[0], iteration, rows, lam_rows, lam_tip, ev)
        g = ev[4]
        near = np.flatnonzero(ev[3] < margin)
        H = lagrangian_hessian(ev, rows, lam_rows, pinned, lam_tip, model)
        ok, dq, curvature, lam, lam_tip, definite = newton_step(ev, H, near, pinned, lam_tip, model)
        if not ok:
            return _answer(R_QP, OK, iteration, np.zeros(0, np.int64), np.zeros(0), lam_tip, ev)
        rows, lam_rows = near, lam
        violation = infeasibility(ev, pinned)
        stationarity = g.copy()
        if near.size:
            stationarity -= jacobian_rows(near, ev, model).T @ lam
        if pinned:
            stationarity -= tip_jacobian(ev[7]).T @ lam_tip
        worst = np.abs(stationarity).max()
        decrease = -(g @ dq) - 0.5 * curvature
        first_order = worst < tol or (abs(decrease) < 1e-14 * max(1.0, abs(ev[1])) and worst < 1e-6)
        if first_order and violation < feas:
            # H positive definite with no active row: H + 1e-7 I is too (the saddle test's answer).
            saddle, step = False, dq
            if not (definite and not pinned and not np.any(lam > 1e-9)):
                saddle, step = escape_direction(q, ev, H, near, lam, pinned, chart, model)
            if not saddle:
                return _answer(R_MINIMUM, OK, iteration, rows, lam_rows, lam_tip, ev)
            if escapes >= 10:
                return _answer(R_SADDLE, OK, iteration, rows, lam_rows, lam_tip, ev)
            escapes += 1
            dq = step
        big = np.abs(dq).max()
        if big > max_step:
            dq = dq * (max_step / big)
        for x in lam:
            rho = max(rho, 2.0 * x)
        for x in lam_tip:
            rho = max(rho, 2.0 * abs(x))
        merit0 = ev[1] + rho * violation
        slope = g @ dq - rho * violation
        t, dq, trial = line_search(q, dq, ev, near, pinned, rho, merit0, slope, chart, model)
        if trial[0] != OK:
            return _answer((R_FIELD if trial[0] < 0 else R_ENERGY), trial[0], iteration, rows, lam_rows, lam_tip, ev)
        if t < 1e-10:
            if worst < 1e3 * tol and violation < 1e-9:
                return _answer(R_MINIMUM_LINE, OK, iteration, rows, lam_rows, lam_tip, ev)
            return _answer(R_LINE, OK, iteration, rows, lam_rows, lam_tip, ev)
        q = q + t * dq
        if np.abs(q[K:]).max() > 1.2:  # close to the chart's poles: re-centre it
            recentre(q, chart, model)
            q = np.zeros(2 * K)
            rows, lam_rows, lam_tip = np.zeros(0, np.int64), np.zeros(0), np.zeros(3)
            ev = evaluate(q, 2, chart, model)
        elif trial[5].shape[0]:
            ev = trial
        else:
            ev = evaluate(q, 2, chart, model)
    return _answer(R_LIMIT, OK, flags[F_MAX_ITER], rows, lam_rows, lam_tip, ev)


@kernel
def _answer(reason, status, iterations, rows, lam, lam_tip, ev):
    """``newton``'s answer with the model's configuration, terms, rows and row gradients at it."""
    return reason, status, iterations, rows, lam, lam_tip, ev[8], ev[9], ev[2], ev[3], ev[10]
