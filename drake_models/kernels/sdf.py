"""The atrium's signed distance between the nodes of its grid: a quadratic B-spline of the node
values (C1: value, gradient and Hessian are derivatives of one function), compiled.

The law of ``atrium_sdf.AtriumSDF.reference``; ``AtriumSDF`` calls it, and so do the statics'
wall rows (``heart_rows``).
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.kernels._common import kernel


@kernel
def bspline_sdf(padded, origin, spacing, shape, P, order):
    """Quadratic B-spline of the node values at points P (k, 3): the compiled form of the numpy
    reference in ``AtriumSDF.reference`` (same weights, same clamping); order 0, 1 or 2.

    Args:
        padded: the node values with one node of edge padding; origin (3,), spacing [m] and
            shape (3,) (as floats) of the unpadded grid.

    Returns:
        ``(sdf (k,), grad (k, 3), hess (k, 3, 3))`` (zeros above ``order``).
    """
    k = P.shape[0]
    sdf = np.zeros(k)
    grad = np.zeros((k, 3))
    hess = np.zeros((k, 3, 3))
    w = np.empty((3, 3))
    dw = np.empty((3, 3))
    d2 = np.array([1.0, -2.0, 1.0]) / spacing**2
    i0 = np.empty(3, np.int64)
    for n in range(k):
        for a in range(3):
            x = (P[n, a] - origin[a]) / spacing
            x = min(max(x, 0.0), shape[a] - 1.0)
            i0[a] = int(np.rint(x))
            u = x - i0[a]
            w[a, 0] = 0.5 * (0.5 - u) ** 2
            w[a, 1] = 0.75 - u * u
            w[a, 2] = 0.5 * (0.5 + u) ** 2
            dw[a, 0] = (u - 0.5) / spacing
            dw[a, 1] = -2.0 * u / spacing
            dw[a, 2] = (u + 0.5) / spacing
        for i in range(3):
            for j in range(3):
                for l in range(3):
                    v = padded[i0[0] + i, i0[1] + j, i0[2] + l]
                    sdf[n] += w[0, i] * w[1, j] * w[2, l] * v
                    if order >= 1:
                        grad[n, 0] += dw[0, i] * w[1, j] * w[2, l] * v
                        grad[n, 1] += w[0, i] * dw[1, j] * w[2, l] * v
                        grad[n, 2] += w[0, i] * w[1, j] * dw[2, l] * v
                    if order >= 2:
                        hess[n, 0, 0] += d2[i] * w[1, j] * w[2, l] * v
                        hess[n, 1, 1] += w[0, i] * d2[j] * w[2, l] * v
                        hess[n, 2, 2] += w[0, i] * w[1, j] * d2[l] * v
                        hess[n, 0, 1] += dw[0, i] * dw[1, j] * w[2, l] * v
                        hess[n, 0, 2] += dw[0, i] * w[1, j] * dw[2, l] * v
                        hess[n, 1, 2] += w[0, i] * dw[1, j] * dw[2, l] * v
        hess[n, 1, 0] = hess[n, 0, 1]
        hess[n, 2, 0] = hess[n, 0, 2]
        hess[n, 2, 1] = hess[n, 1, 2]
    return sdf, grad, hess
