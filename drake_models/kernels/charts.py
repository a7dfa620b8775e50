"""The charts of the reduced coordinates: each of the K = 2(n-1) unit vectors (the links, then
the free dipoles) written as ``w(a, b) = cos b (cos a r0 + sin a t1) + sin b t2`` around its chart
centre r0, and the chain's configuration from those vectors.

The numpy reference is ``optimization/reduced_chain.py``'s ``backend="numpy"``.
"""

from __future__ import annotations

import math

import numpy as np

from ballchain.drake_models.kernels._common import kernel


@kernel
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


@kernel
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


@kernel
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


@kernel
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
