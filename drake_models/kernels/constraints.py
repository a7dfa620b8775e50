"""The reduced chain's constraints: the rigidity gaps ``c_ij = |p_j - p_i|^2 / d^2 - 1 >= 0`` of the
non-adjacent pairs (and a plane wall's rows), their Jacobian rows in chart coordinates, built
only for the rows asked for, and their curvature.

The numpy reference is ``optimization/reduced_chain.py``'s ``backend="numpy"``.
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.kernels._common import kernel


@kernel
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


@kernel
def pair_index(n, i, j):
    """Row of the non-adjacent pair (i, j), i < j - 1, in ``rigidity_gaps``' order."""
    # Rows before i: sum_{r < i} (n - 2 - r).
    return i * (n - 2) - i * (i - 1) // 2 + (j - i - 2)


@kernel
def pair_of_row(n, k):
    """(i, j) of row k of ``rigidity_gaps``."""
    i = 0
    while k >= n - 2 - i:
        k -= n - 2 - i
        i += 1
    return i, i + 2 + k


@kernel
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


@kernel
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


@kernel
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
