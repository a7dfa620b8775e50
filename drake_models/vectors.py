"""Small vector geometry used across the layers: the angle between vectors, perpendicular axes.

One home for each rule, so that the systems, the statics and the experiments measure an angle
(or pick an axis across a vector) the same way.
"""

from __future__ import annotations

import numpy as np


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b (..., 3) for float vectors (..., 3), broadcast: ``np.cross``'s products and differences
    in its order (the same floats, bit for bit), without its axis handling, which costs 12 us on
    two 3-vectors (20 times the arithmetic; the control loops of the units and the catheter
    mapping take cross products at every update). Two (3,) vectors take their plain-float path.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.shape == (3,) and b.shape == (3,):
        a0, a1, a2 = a.tolist()
        b0, b1, b2 = b.tolist()
        return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def angle_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle [rad] between vectors (..., 3), robust near 0 and pi (atan2 of |u x v| and u . v).

    Args:
        u, v: (..., 3) vectors, any length (broadcast against each other).

    Returns:
        (...) angles in [0, pi] [rad] (a float for two (3,) vectors).
    """
    u = np.asarray(u, dtype=float)
    v = np.asarray(v, dtype=float)
    return np.arctan2(np.linalg.norm(cross(u, v), axis=-1), np.einsum("...i,...i->...", u, v))


def perpendicular_basis(z_hat) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (x, y), each (3,), with (x, y, z_hat) a right-handed orthonormal frame.

    ``x = h x z_hat`` normalised, ``y = z_hat x x``, with the helper ``h`` the world x axis unless
    ``z_hat`` lies within about 26 deg of it (then the world y axis), so the cross product is
    never small.

    Args:
        z_hat: (3,) unit vector (normalised by the caller, which usually needs it too).
    """
    z = np.asarray(z_hat, dtype=float)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return x, np.cross(z, x)


def perpendicular_axis(v: np.ndarray) -> np.ndarray:
    """A fixed unit vector perpendicular to v (3,): v crossed with the world axis least aligned."""
    v = np.asarray(v, dtype=float)
    e = np.eye(3)[int(np.argmin(np.abs(v)))]
    w = np.cross(v, e)
    return w / np.linalg.norm(w)
