"""The quasi-static engine's per-update arithmetic as compiled kernels: the work around the solve
that numpy did in many small calls (each a few microseconds of overhead for a few dozen flops).

Each kernel computes the very floats of the numpy expression it replaces (the same operations in
the same order; ``tests/test_engine_bench.py`` holds them to it exactly), so the engine's states
are those of the numpy code, bit for bit. The continuation's arithmetic on a magnet or two
(``magnet_moves``, ``interpolate_magnets``) is plain Python floats: too little work for a
compiled call's dispatch.
"""

from __future__ import annotations

from math import isfinite, sqrt

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


# --- plain floats ------------------------------------------------------------------------------
# The continuation's per-step arithmetic on a magnet or two: numpy's per-call cost (about a
# microsecond a call, a dozen calls a step) for a few flops. Each function repeats the numpy
# expression's operations in its order on Python floats (IEEE: the same rounding), and returns
# None where the expression would divide by zero or meet a non-finite number: the caller then
# evaluates the numpy expression itself (``tests/test_engine_steps.py`` holds them to it).


def magnet_moves(mag0, mag1) -> tuple[list[float], float] | None:
    """The magnets' turn and travel between two ``magnet_states`` (6 k,): each magnet's cosine of
    its turn clipped to [-1, 1] and the largest centre travel [m], the floats of

        a, b = mag0.reshape(-1, 6), mag1.reshape(-1, 6)
        cos = np.einsum("ij,ij->i", a[:, 3:], b[:, 3:]) / (_norms(a[:, 3:]) * _norms(b[:, 3:]))
        np.minimum(np.maximum(cos, -1.0), 1.0), float(_norms(a[:, :3] - b[:, :3]).max())

    (numpy's ``einsum`` sums a 3-vector's products as (x0 y0 + x2 y2) + x1 y1, ``_norms`` the
    squares left to right). The arccosine stays numpy's (it is not the C library's). None for a
    zero-length direction or a non-finite result (the expression's NaN and inf semantics)."""
    a, b = mag0.tolist(), mag1.tolist()
    if not a or len(a) != len(b) or len(a) % 6:
        return None
    cosines, travel, total = [], 0.0, 0.0
    for j in range(0, len(a), 6):
        p0, p1, p2, x0, x1, x2 = a[j:j + 6]
        q0, q1, q2, y0, y1, y2 = b[j:j + 6]
        scale = sqrt((x0 * x0 + x1 * x1) + x2 * x2) * sqrt((y0 * y0 + y1 * y1) + y2 * y2)
        if scale == 0.0:
            return None
        c = ((x0 * y0 + x2 * y2) + x1 * y1) / scale
        cosines.append(min(max(c, -1.0), 1.0))
        d0, d1, d2 = p0 - q0, p1 - q1, p2 - q2
        t = sqrt((d0 * d0 + d1 * d1) + d2 * d2)
        travel = t if t > travel else travel
        total += c + t
    return (cosines, travel) if isfinite(total) else None


def interpolate_magnets(mag0, mag1, f: float) -> list[float] | None:
    """``magnet_states`` a fraction f of the way from mag0 to mag1 (6 k,): centres linear,
    directions normalised, the floats of

        a, b = mag0.reshape(-1, 6), mag1.reshape(-1, 6)
        out = (1 - f) * a + f * b
        out[:, 3:] /= _norms(out[:, 3:])[:, None]

    None for a zero-length direction (the expression's 0 / 0)."""
    g = 1 - f
    out = [g * x + f * y for x, y in zip(mag0.tolist(), mag1.tolist())]
    for j in range(3, len(out), 6):
        x0, x1, x2 = out[j:j + 3]
        n = sqrt((x0 * x0 + x1 * x1) + x2 * x2)
        if n == 0.0:
            return None
        out[j:j + 3] = x0 / n, x1 / n, x2 / n
    return out
