"""Omni-wheel kinematics of the actuation unit: three wheels rolling a sphere (the magnet housing).

Derivation (docs/design.md, 4.2). The sphere (radius ``rho_a``) is centred at the origin
of the unit frame and sits on three omni-wheels (radius ``rho_w``). Wheel ``i`` touches the
sphere at ``c_i = rho_a n_i`` (``n_i`` the unit outward normal of the sphere at the contact, so
the wheel centre is ``(rho_a + rho_w) n_i``) and spins about its unit axis ``a_i`` (``a_i . n_i =
0``) at the angular velocity ``omega_w,i`` (right-hand rule about ``a_i``).

* Rim velocity of wheel ``i`` at the contact: ``omega_w,i a_i x (c_i - centre_i) =
  omega_w,i a_i x (-rho_w n_i) = rho_w omega_w,i d_i`` with the driving direction
  ``d_i = n_i x a_i``.
* Surface velocity of the sphere at the contact: ``omega_a x c_i = rho_a omega_a x n_i``.
* The rollers on the rim let the sphere slide freely along ``a_i``; along ``n_i`` both velocities
  vanish; so rolling without slip is the one scalar condition per wheel
  ``d_i . (omega_a x c_i) = rho_w omega_w,i``. Because
  ``d_i . (omega_a x n_i) = omega_a . (n_i x d_i) = omega_a . (n_i (n_i . a_i) - a_i) =
  -a_i . omega_a``, it reads

      omega_w = (rho_a / rho_w) A omega_a,     A = [-a_1^T; -a_2^T; -a_3^T]     (inverse map)
      omega_a = (rho_w / rho_a) A^-1 omega_w                                      (forward map)

So the paper's matrix ``A`` (rows ``-a_i^T``) is right, but it maps the *sphere's* angular
velocity to the *wheels'*, and the ratio is ``rho_a/rho_w`` in that direction; the paper's
``omega_a = (rho_a/rho_w) A omega_w`` swaps both. The map depends on the axes only, not on
where along the great circle ``a_i . n = 0`` each wheel touches.

Geometry that reproduces the printed A: its rows are ``(sqrt(2/3) cos phi_i, sqrt(2/3) sin
phi_i, -1/sqrt(3))`` with ``phi_i = 0, 120, 240 deg`` (0.8165, 0.5774 printed as 0.82, 0.58), i.e.
three mutually orthogonal wheel axes, each tilted 54.74 deg from the vertical. The wheels sit
under the sphere at azimuths ``phi_i + 180 deg`` and 35.26 deg from the nadir, each axis tangent
to the sphere along its meridian (pointing up), so each wheel pushes the sphere's surface
horizontally along its circle of latitude. With orthogonal axes ``A`` is orthogonal
(``A^-1 = A^T``), so the paper's ``A`` in place of ``A^-1`` is the transpose mistake.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from ballchain.infrastructure.errors import UserInputError

# Printed in the paper (Section III), 2 decimals.
PAPER_A = np.array(
    [
        [0.82, 0.0, -0.58],
        [-0.41, 0.71, -0.58],
        [-0.41, -0.71, -0.58],
    ]
)
_PAPER_A_INV = np.linalg.inv(PAPER_A)
PAPER_WHEEL_RADIUS = 48e-3  # rho_w [m]
PAPER_SPHERE_RADIUS = 43.5e-3  # rho_a, effective radius of the magnet housing [m]

# Polar angle of the contacts from the nadir for mutually orthogonal axes: acos(sqrt(2/3)).
ORTHOGONAL_CONTACT_POLAR_ANGLE = float(np.arccos(np.sqrt(2.0 / 3.0)))  # 35.26 deg [rad]


def _unit_rows(v: np.ndarray, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=float).reshape(3, 3)
    norms = np.linalg.norm(v, axis=1)
    if not np.all(np.isfinite(v)) or np.any(norms == 0.0):
        raise UserInputError(f"{what} must be three finite non-zero vectors, got {v.tolist()}")
    return v / norms[:, None]


@dataclass(frozen=True)
class OmniWheelGeometry:
    """Three omni-wheels under a sphere, all vectors in the unit frame (origin at the sphere centre).

    Attributes:
        wheel_axes: (3, 3) row i is the unit spin axis a_i of wheel i.
        contact_normals: (3, 3) row i is the unit outward sphere normal n_i at wheel i's contact.
        wheel_radius: rho_w [m].
        sphere_radius: rho_a [m].
    """

    wheel_axes: np.ndarray = field(default_factory=lambda: prototype_wheel_axes())
    contact_normals: np.ndarray = field(default_factory=lambda: contacts_below(prototype_wheel_axes()))
    wheel_radius: float = PAPER_WHEEL_RADIUS
    sphere_radius: float = PAPER_SPHERE_RADIUS

    def __post_init__(self) -> None:
        a = _unit_rows(self.wheel_axes, "OmniWheelGeometry.wheel_axes")
        n = _unit_rows(self.contact_normals, "OmniWheelGeometry.contact_normals")
        object.__setattr__(self, "wheel_axes", a)
        object.__setattr__(self, "contact_normals", n)
        for name in ("wheel_radius", "sphere_radius"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise UserInputError(f"OmniWheelGeometry.{name} must be positive, got {value!r}")
        if np.any(np.abs(np.einsum("ij,ij->i", a, n)) > 1e-9):
            raise UserInputError("OmniWheelGeometry: each wheel axis must be tangent to the sphere (a_i . n_i = 0)")
        if abs(np.linalg.det(a)) < 1e-6:
            raise UserInputError("OmniWheelGeometry: wheel axes are coplanar; the sphere is not fully actuated")

    @property
    def A(self) -> np.ndarray:
        """(3, 3) rows -a_i^T: ``omega_w = (rho_a/rho_w) A omega_a``."""
        return -self.wheel_axes

    @property
    def ratio(self) -> float:
        """rho_a / rho_w (0.906 for the prototype)."""
        return self.sphere_radius / self.wheel_radius

    @property
    def contact_points(self) -> np.ndarray:
        """(3, 3) contact points c_i [m]."""
        return self.sphere_radius * self.contact_normals

    @property
    def driving_directions(self) -> np.ndarray:
        """(3, 3) unit driving directions d_i = n_i x a_i (the rim velocity direction)."""
        return np.cross(self.contact_normals, self.wheel_axes)

    def wheel_speeds(self, omega_a: np.ndarray) -> np.ndarray:
        """Inverse map: wheel angular velocities (..., 3) [rad/s] that roll the sphere at omega_a (..., 3)."""
        return self.ratio * np.einsum("ij,...j->...i", self.A, np.asarray(omega_a, dtype=float))

    def sphere_angular_velocity(self, omega_w: np.ndarray) -> np.ndarray:
        """Forward map: sphere angular velocity (..., 3) [rad/s] from wheel speeds (..., 3) [rad/s]."""
        return np.einsum("ij,...j->...i", self._A_inv, np.asarray(omega_w, dtype=float)) / self.ratio

    @cached_property
    def _A_inv(self) -> np.ndarray:
        return np.linalg.inv(self.A)

    @property
    def A_inv(self) -> np.ndarray:
        """A copy of ``A^-1`` (3, 3), the forward map's matrix (``sphere_angular_velocity``)."""
        return self._A_inv.copy()

    def rolling_residual(self, omega_a: np.ndarray, omega_w: np.ndarray) -> np.ndarray:
        """Slip velocity along each wheel's driving direction (..., 3) [m/s].

        ``d_i . (omega_a x c_i) - rho_w omega_w,i``: zero when every wheel rolls without slip.
        """
        omega_a = np.asarray(omega_a, dtype=float)
        omega_w = np.asarray(omega_w, dtype=float)
        v_sphere = np.cross(omega_a[..., None, :], self.contact_points)  # (..., 3 wheels, 3)
        return np.einsum("ij,...ij->...i", self.driving_directions, v_sphere) - self.wheel_radius * omega_w


def prototype_wheel_axes() -> np.ndarray:
    """(3, 3) exact wheel axes whose ``-a_i^T`` rows the paper prints (rounded) as A."""
    phi = np.deg2rad([0.0, 120.0, 240.0])
    s, c = np.sqrt(2.0 / 3.0), 1.0 / np.sqrt(3.0)
    return np.column_stack([-s * np.cos(phi), -s * np.sin(phi), np.full(3, c)])


def contacts_below(wheel_axes: np.ndarray) -> np.ndarray:
    """(3, 3) lowest contact normals compatible with the axes: n_i = unit(-e3 + (a_i . e3) a_i).

    That is the point of the great circle ``a_i . n = 0`` nearest the nadir, where a wheel under
    the sphere touches it (the wheel's plane then contains the vertical through its centre).
    """
    a = _unit_rows(wheel_axes, "wheel_axes")
    n = -np.array([0.0, 0.0, 1.0])[None, :] + a[:, 2:3] * a
    norms = np.linalg.norm(n, axis=1)
    if np.any(norms < 1e-9):
        raise UserInputError("a vertical wheel axis has no contact below the sphere")
    return n / norms[:, None]


def paper_forward_map(omega_w: np.ndarray, geometry: OmniWheelGeometry | None = None) -> np.ndarray:
    """The paper's printed forward map ``omega_a = (rho_a/rho_w) A_paper omega_w`` (for comparison only)."""
    g = geometry or OmniWheelGeometry()
    return g.ratio * np.einsum("ij,...j->...i", PAPER_A, np.asarray(omega_w, dtype=float))


def paper_inverse_matrix() -> np.ndarray:
    """A copy of the paper's printed ``A^-1`` (3, 3), the matrix of ``paper_wheel_speeds``."""
    return _PAPER_A_INV.copy()


def paper_wheel_speeds(omega_a: np.ndarray, geometry: OmniWheelGeometry | None = None) -> np.ndarray:
    """Wheel speeds (..., 3) [rad/s] that the paper's printed map would command for omega_a (..., 3).

    The inverse of ``paper_forward_map``: what a controller built on the printed map sends.
    """
    g = geometry or OmniWheelGeometry()
    return np.einsum("ij,...j->...i", _PAPER_A_INV, np.asarray(omega_a, dtype=float)) / g.ratio
