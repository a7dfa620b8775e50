"""Hall-sensor inversion: the actuation magnet's dipole direction from the field at one sensor.

For a point dipole ``m`` and a sensor at ``r`` from its centre, ``B = (k |m| / |r|^3) M(r_hat)
m_hat`` with ``k = mu0 / (4 pi)`` and the dipole matrix ``M(u) = 3 u u^T - I`` (this is
``dipole.dipole_field`` rewritten; the code always calls that function for forward fields).

``M(u)`` has eigenvalue 2 along ``u`` and -1 across it, so it is *not* its own inverse:

    M(u)^-1 = (1/2) u u^T - (I - u u^T) = (3/2) u u^T - I,

check: ``(3 u u^T - I)((3/2) u u^T - I) = (9/2 - 3 - 3/2) u u^T + I = I``. Hence

    m = (|r|^3 / k) ((3/2) r_hat r_hat^T - I) B.

The paper (Section IV-B) prints ``m_hat = (4 pi D^3 / (mu0 |m|)) (3 e3 e3^T - I) B``, i.e. it
applies ``M`` instead of ``M^-1``. That returns ``M^2 m_hat`` (eigenvalues 4 along ``e3``, 1
across): with ``theta`` the angle between ``m_hat`` and the sensor axis, the printed formula
yields ``atan(tan(theta)/4)`` instead of ``theta``, exact only on the axis (0, 180 deg) and across
it (90 deg), worst at ``tan(theta) = 2`` (63.43 deg) where it is 36.87 deg off, and its norm is
not 1 (between 1 and 4). See ``paper_formula_angle_error`` (and ``ballchain.experiments.hall_inversion``).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ballchain.drake_models.dipole import K_DIPOLE
from ballchain.drake_models.field_sources import MagnetSource
from ballchain.drake_models.params import CylinderMagnet, SphereMagnet
from ballchain.drake_models.vectors import perpendicular_basis

E3 = np.array([0.0, 0.0, 1.0])


def _unit(v: np.ndarray, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if not np.all(np.isfinite(v)) or np.any(n == 0.0):
        raise ValueError(f"{what} must be finite and non-zero")
    return v / n


def dipole_matrix(u: np.ndarray) -> np.ndarray:
    """``3 u u^T - I`` (3, 3) for a unit vector u (3,)."""
    u = _unit(u, "u")
    return 3.0 * np.outer(u, u) - np.eye(3)


def dipole_matrix_inverse(u: np.ndarray) -> np.ndarray:
    """``(3 u u^T - I)^-1 = (3/2) u u^T - I`` (3, 3) for a unit vector u (3,)."""
    u = _unit(u, "u")
    return 1.5 * np.outer(u, u) - np.eye(3)


class FieldInversion:
    """The exact inverse of the point-dipole law for one sensor offset r (3,) [m]: what depends
    on r alone (its length and the matrix ``(3/2) u u^T - I``) computed once, for a sensor read
    at every sample; the same floats as ``moment_from_field`` and ``direction_from_field``,
    which build one per call."""

    def __init__(self, r: np.ndarray) -> None:
        r = np.asarray(r, dtype=float)
        dist = float(np.linalg.norm(r))
        if not np.isfinite(dist) or dist == 0.0:
            raise ValueError("sensor offset r must be finite and non-zero")
        self._scale = dist**3 / K_DIPOLE
        self._M = dipole_matrix_inverse(r / dist)

    @property
    def scale(self) -> float:
        """``|r|^3 / k`` [A m^2 / T]."""
        return self._scale

    @property
    def matrix(self) -> np.ndarray:
        """A copy of ``(3/2) u u^T - I`` (3, 3), u = r / |r|."""
        return self._M.copy()

    def moment(self, B: np.ndarray) -> np.ndarray:
        """The dipole (..., 3) [A m^2] that makes the field B (..., 3) [T] at the offset."""
        return self._scale * np.einsum("ij,...j->...i", self._M, B)

    def direction(self, B: np.ndarray) -> np.ndarray:
        """The unit dipole direction (..., 3) that makes the field B (..., 3) [T] at the offset."""
        return _unit(self.moment(B), "estimated moment")


def moment_from_field(B: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Exact inverse of the point-dipole law: the dipole (..., 3) [A m^2] that makes B at r.

    Args:
        B: (..., 3) flux density at the sensor [T].
        r: (3,) vector from the dipole to the sensor [m].

    Returns:
        (..., 3) dipole moment [A m^2]; ``moment_from_field(dipole_field(r, m), r) == m``.
    """
    return FieldInversion(r).moment(B)


def direction_from_field(B: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Unit dipole direction (..., 3) from the field B (..., 3) [T] at offset r (3,) [m] (correct inverse)."""
    return FieldInversion(r).direction(B)


def neutral_direction(p_WM: np.ndarray, p_W_target: np.ndarray, b_hat_W: np.ndarray) -> np.ndarray:
    """Dipole direction (3,) that makes the field at p_W_target point along b_hat_W (dipole model).

    The neutral configuration aligns the field at the chain with its feeding direction; the
    dipole that does it follows from the inverse dipole law.
    """
    r = np.asarray(p_W_target, dtype=float) - np.asarray(p_WM, dtype=float)
    return direction_from_field(np.asarray(b_hat_W, dtype=float), r)


def paper_direction_formula(B: np.ndarray, D: float, moment: float) -> np.ndarray:
    """The paper's printed ``(4 pi D^3 / (mu0 |m|)) (3 e3 e3^T - I) B`` (..., 3), not normalised.

    Kept only to measure how wrong it is; never use it for control.
    """
    return (D**3 / (K_DIPOLE * moment)) * np.einsum("ij,...j->...i", dipole_matrix(E3), B)


def paper_formula_angle_error(theta: np.ndarray) -> np.ndarray:
    """Closed form of the printed formula's direction error [rad] at off-axis angle theta [rad].

    The formula returns the direction at ``atan2(sin(theta), 4 cos(theta))`` from the sensor
    axis instead of ``theta``.
    """
    theta = np.asarray(theta, dtype=float)
    return np.abs(theta - np.arctan2(np.sin(theta), 4.0 * np.cos(theta)))


def refine_direction(
    B_measured: np.ndarray,
    field_of_direction: Callable[[np.ndarray], np.ndarray],
    m_hat0: np.ndarray,
    max_iterations: int = 20,
    h: float = 1e-6,
    tol: float = 1e-10,
) -> np.ndarray:
    """Gauss-Newton fit of a dipole direction to one field sample with any forward model.

    Used with the exact cylinder field (magpylib), where no closed-form inverse exists; start
    from the dipole inverse. The direction is parametrised in the tangent plane of the current
    estimate (2 unknowns, 3 measurements).

    Args:
        B_measured: (3,) measured flux density [T].
        field_of_direction: maps a unit direction (3,) to the predicted flux density (3,) [T].
        m_hat0: (3,) initial unit direction.
        max_iterations: Gauss-Newton iteration limit (near the magnet, e.g. 50 mm from the
            prototype, the dipole start is up to 36 deg off and needs about 10).
        h: finite-difference step on the sphere [rad].
        tol: stop when the update is smaller than this [rad].

    Returns:
        (3,) unit direction.
    """
    m = _unit(m_hat0, "m_hat0")
    for _ in range(max_iterations):
        x, y = perpendicular_basis(m)
        t1, t2 = -x, -y  # the tangent directions (and so the forward differences) as always
        B0 = field_of_direction(m)
        J = np.column_stack(
            [(field_of_direction(_unit(m + h * t, "m")) - B0) / h for t in (t1, t2)]
        )
        step, *_ = np.linalg.lstsq(J, B_measured - B0, rcond=None)
        m = _unit(m + step[0] * t1 + step[1] * t2, "m")
        if np.hypot(step[0], step[1]) < tol:
            break
    return m


def sensor_field(
    magnet: CylinderMagnet | SphereMagnet, D: float, m_hat: np.ndarray, model: str
) -> np.ndarray:
    """Field (3,) [T] at the sensor ``D`` below a magnet at the origin pointing along m_hat."""
    source = MagnetSource.pointing(magnet, np.zeros(3), m_hat, model)
    return source.field(np.array([[0.0, 0.0, -D]]))[0]
