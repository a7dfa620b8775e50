"""The quasi-static engine's per-update arithmetic as compiled kernels: the work around the solve
that numpy did in many small calls (each a few microseconds of overhead for a few dozen flops).

Each kernel computes the very floats of the numpy expression it replaces (the same operations in
the same order; ``tests/test_engine_bench.py`` holds them to it exactly), so the engine's states
are those of the numpy code, bit for bit.
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.kernels._common import kernel


@kernel
def ball_frames(directions, centres):
    """(k, 3, 4) poses [R_WB | p_WB] of balls at ``centres`` (k, 3) [m] with x along
    ``directions`` (k, 3) (``quasi_static_engine.ball_frames``: x the unit direction, y the unit
    vector along helper x x with the helper e_x, or e_y when |x_0| >= 0.9, z = x x y)."""
    n = directions.shape[0]
    out = np.empty((n, 3, 4))
    for k in range(n):
        d0, d1, d2 = directions[k, 0], directions[k, 1], directions[k, 2]
        s = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        x0, x1, x2 = d0 / s, d1 / s, d2 / s
        if abs(x0) < 0.9:  # e_x x x = (0, -x2, x1), numpy's cross formula term for term
            y0, y1, y2 = 0.0 * x2 - 0.0 * x1, 0.0 * x0 - 1.0 * x2, 1.0 * x1 - 0.0 * x0
        else:  # e_y x x = (x2, 0, -x0)
            y0, y1, y2 = 1.0 * x2 - 0.0 * x1, 0.0 * x0 - 0.0 * x2, 0.0 * x1 - 1.0 * x0
        t = np.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
        y0, y1, y2 = y0 / t, y1 / t, y2 / t
        out[k, 0, 0], out[k, 1, 0], out[k, 2, 0] = x0, x1, x2
        out[k, 0, 1], out[k, 1, 1], out[k, 2, 1] = y0, y1, y2
        out[k, 0, 2] = x1 * y2 - x2 * y1
        out[k, 1, 2] = x2 * y0 - x0 * y2
        out[k, 2, 2] = x0 * y1 - x1 * y0
        out[k, 0, 3], out[k, 1, 3], out[k, 2, 3] = centres[k, 0], centres[k, 1], centres[k, 2]
    return out
