"""Small vector geometry used across the layers: the angle between vectors, perpendicular axes.

One home for each rule, so that the systems, the statics and the experiments measure an angle
(or pick an axis across a vector) the same way.
"""

from __future__ import annotations

import numpy as np


def angle_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle [rad] between vectors (..., 3), robust near 0 and pi (atan2 of |u x v| and u . v).

    Args:
        u, v: (..., 3) vectors, any length (broadcast against each other).

    Returns:
        (...) angles in [0, pi] [rad] (a float for two (3,) vectors).
    """
    u = np.asarray(u, dtype=float)
    v = np.asarray(v, dtype=float)
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.einsum("...i,...i->...", u, v))


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
