"""The chain in the heart's constraint rows: the atrium's wall and the sheath, per free ball.

The law of ``optimization/wall_constraints.py``'s ``ConstrainedChain._rows`` (its reference),
compiled. Frame B: the held ball's centre, +x along the sheath axis. For each free ball k
(centre p_k in B) two dimensionless rows, each ``c >= 0``:

* wall: ``c = (sdf(p_WB + R_WB p_k) - r) / d`` (the atrium's B-spline distance, ``sdf``), except
  for a ball in the sheath's bore when there is a sheath (behind the exit plane and within r_c
  of the axis: the bore holds it; a ball curled back beside the sheath has its wall row);
* sheath: ``c = g / d^2``, ``g = (rho - r_c)^2 + max(a, 0)^2 - (r + r_lip)^2``, a the centre's
  distance past the exit plane, rho its (smoothed) distance from the axis.

Rows without a constraint hold 10 (far from active). Each row's derivatives are given through
the ball's centre: ``dc/dq = v_k . sum_{l<k} dw_l/dq`` (p_k = d sum_{l<k} w_l) and the part of
``d2c/dq2`` through the centre ``T_k^T M_k T_k``.
"""

from __future__ import annotations

import math

import numpy as np

from ballchain.drake_models.kernels._common import kernel
from ballchain.drake_models.kernels.sdf import bspline_sdf


@kernel
def heart_rows(p_free, p_WB, R_WB, sdf_grid, sdf_frame, sheath, r, d, hessian):
    """The wall and sheath rows of the free balls.

    Args:
        p_free: (L, 3) the free balls' centres in B [m].
        p_WB: (3,) the held ball's centre in world [m]; R_WB: (3, 3) frame B in world.
        sdf_grid: the atrium's padded node values (``AtriumSDF``; empty: no wall rows).
        sdf_frame: (7,) the grid's origin (3,) [m], spacing [m] and shape (3,).
        sheath: (5,) ``(has_sheath, a_E, r_c, reach, eps)``: 1 or 0, the exit plane along x_B
            [m], the lip's centre radius R + r_lip [m], ``r + r_lip`` [m] and the smoothing of
            rho on the axis [m].
        r, d: ball radius and diameter [m].
        hessian: whether to fill M.

    Returns:
        ``(values (2L,), v (2L, 3), M (2L, 3, 3))``: wall rows first, then sheath rows.
    """
    L = p_free.shape[0]
    values = np.full(2 * L, 10.0)
    v = np.zeros((2 * L, 3))
    M = np.zeros((2 * L, 3, 3))
    has_sheath = sheath[0] > 0.0
    a_E, r_c = sheath[1], sheath[2]
    if sdf_grid.size > 0:
        p_W = np.empty((L, 3))
        for k in range(L):
            for a in range(3):
                p_W[k, a] = p_WB[a] + R_WB[a, 0] * p_free[k, 0] + R_WB[a, 1] * p_free[k, 1] \
                    + R_WB[a, 2] * p_free[k, 2]
        s, grad, hess = bspline_sdf(sdf_grid, sdf_frame[0:3], sdf_frame[3], sdf_frame[4:7], p_W,
                                    2 if hessian else 1)
        for k in range(L):
            if (has_sheath and not p_free[k, 0] > a_E
                    and p_free[k, 1] * p_free[k, 1] + p_free[k, 2] * p_free[k, 2] < r_c * r_c):
                continue  # still in the bore: the sheath holds it
            values[k] = (s[k] - r) / d
            for b in range(3):
                v[k, b] = grad[k, 0] * R_WB[0, b] + grad[k, 1] * R_WB[1, b] + grad[k, 2] * R_WB[2, b]
            if hessian:
                for a in range(3):
                    for b in range(3):
                        acc = 0.0
                        for i in range(3):
                            for j in range(3):
                                acc += R_WB[i, a] * hess[k, i, j] * R_WB[j, b]
                        M[k, a, b] = d * acc
    if has_sheath:
        _sheath_rows(p_free, sheath, r, d, hessian, values, v, M)
    return values, v, M


@kernel
def _sheath_rows(p_free, sheath, r, d, hessian, values, v, M):
    """The sheath rows (``heart_rows``), written into rows L..2L-1 of values, v and M."""
    L = p_free.shape[0]
    a_E, r_c, reach, eps = sheath[1], sheath[2], sheath[3], sheath[4]
    for k in range(L):
        a = p_free[k, 0] - a_E
        y, z = p_free[k, 1], p_free[k, 2]
        rho = math.sqrt(y * y + z * z + eps * eps)
        ap = max(a, 0.0)
        g = (rho - r_c) ** 2 + ap * ap - reach * reach
        values[L + k] = g / (d * d)
        f = (rho - r_c) / rho
        v[L + k, 0] = 2.0 * ap / d
        v[L + k, 1] = 2.0 * f * y / d
        v[L + k, 2] = 2.0 * f * z / d
        if hessian:
            M[L + k, 0, 0] = 2.0 if a > 0 else 0.0
            e1, e2 = y / rho, z / rho
            M[L + k, 1, 1] = 2.0 * (e1 * e1 + f * (1.0 - e1 * e1))
            M[L + k, 2, 2] = 2.0 * (e2 * e2 + f * (1.0 - e2 * e2))
            M[L + k, 1, 2] = 2.0 * (e1 * e2 - f * e1 * e2)
            M[L + k, 2, 1] = M[L + k, 1, 2]
