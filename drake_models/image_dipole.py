"""A point dipole near a magnetically soft half-space: the image law and the attraction it gives.

Used to size one candidate explanation of Table I's gap (effect (b) of ``ballchain/experiments/table1_effects.py``): a steel pin or
sensor body attracting the chain's magnetic tip ball.

Derivation. Outside a linear half-space of relative permeability mu_r (no free currents) the
field is H = -grad(phi). A magnetic point charge q at height h above the surface has, seen from
outside, an image charge q' = -k q at the mirror point, with k = (mu_r - 1) / (mu_r + 1) (the
same problem as a charge near a dielectric, with mu in place of epsilon); for mu_r -> inf
(soft iron), k = 1 and phi = 0 on the surface: the field enters the iron perpendicularly.
A dipole is a pair (+q at r + delta/2, -q at r - delta/2, m = q delta). Its images are
-k q at M (r + delta/2) and +k q at M (r - delta/2), with the mirror M = I - 2 n n^T, so the
image dipole sits at the mirror point with

    m' = sum q_i r_i = -k M m = k (2 (m . n) n - m):

the normal component kept, the tangential components flipped (a superconductor, mu_r = 0,
k = -1, gives the opposite). The iron's field outside is the image's field, so the force on the
real dipole is the image field's gradient force ``G' m`` (``dipole.force_on_dipole``), and the
interaction energy is half the dipole-image energy, U = -(1/2) m . B'(r) (the image is induced:
moving the dipole by dh moves the image by -dh, doubling the rate, which the 1/2 undoes).
Limits: a dipole normal to the surface at height h sees a coaxial head-to-tail image at 2h and
is pulled with 6 k mu0 m^2 / (4 pi (2h)^4) = 3 k mu0 m^2 / (32 pi h^4); a dipole parallel to it
sees an antiparallel side-by-side image and is pulled with half that.

SI units throughout.
"""

from __future__ import annotations

import math

import numpy as np

from ballchain.drake_models.dipole import dipole_field, dipole_field_gradient, force_on_dipole


def image_factor(mu_r: float) -> float:
    """k = (mu_r - 1) / (mu_r + 1) of a half-space of relative permeability ``mu_r`` (inf: 1)."""
    if not (mu_r >= 0):  # also rejects NaN
        raise ValueError(f"mu_r must be >= 0 (inf for soft iron), got {mu_r!r}")
    return 1.0 if math.isinf(mu_r) else (mu_r - 1.0) / (mu_r + 1.0)


def _plane(point, normal) -> tuple[np.ndarray, np.ndarray]:
    p0 = np.asarray(point, dtype=float).reshape(3)
    n = np.asarray(normal, dtype=float).reshape(3)
    norm = np.linalg.norm(n)
    if not (np.all(np.isfinite(p0)) and np.isfinite(norm) and norm > 0):
        raise ValueError(f"the half-space needs a finite point and a non-zero normal, got {point}, {normal}")
    return p0, n / norm


def image_dipole(p, m, point, normal, mu_r: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
    """The image of dipoles in the half-space behind the plane (``point``, ``normal``).

    Args:
        p: (..., 3) dipole positions, on the side the normal points to [m].
        m: (..., 3) dipole moments [A m^2].
        point: (3,) a point of the surface [m].
        normal: (3,) the surface's normal, pointing out of the material (towards the dipoles).
        mu_r: the material's relative permeability (inf: soft iron).

    Returns:
        ``(p_image, m_image)``, each (..., 3).
    """
    p0, n = _plane(point, normal)
    p = np.asarray(p, dtype=float)
    m = np.asarray(m, dtype=float)
    height = (p - p0) @ n
    if np.any(height <= 0):
        raise ValueError("a dipole lies on or behind the material's surface")
    k = image_factor(mu_r)
    p_image = p - 2.0 * height[..., None] * n
    m_image = k * (2.0 * (m @ n)[..., None] * n - m)
    return p_image, m_image


def image_force(p, m, point, normal, mu_r: float = math.inf) -> np.ndarray:
    """Force the half-space exerts on each dipole: the gradient force of its own image [N].

    Only each dipole's own image (one dipole, or dipoles far apart); for a chain, sum the field
    gradients of all images at each ball.
    """
    p = np.asarray(p, dtype=float)
    m = np.asarray(m, dtype=float)
    p_image, m_image = image_dipole(p, m, point, normal, mu_r)
    return force_on_dipole(m, dipole_field_gradient(p - p_image, m_image))


def image_energy(p, m, point, normal, mu_r: float = math.inf) -> np.ndarray:
    """Interaction energy of each dipole with the half-space, -(1/2) m . B_image [J]."""
    p = np.asarray(p, dtype=float)
    m = np.asarray(m, dtype=float)
    p_image, m_image = image_dipole(p, m, point, normal, mu_r)
    return -0.5 * np.einsum("...i,...i->...", m, dipole_field(p - p_image, m_image))


def normal_attraction(moment: float, height: float, angle_to_normal: float = 0.0, mu_r: float = math.inf) -> float:
    """Pull towards the surface of a dipole of size ``moment`` at ``height``, tilted ``angle_to_normal``
    [rad] from the normal [N] (positive: attractive). 3 k mu0 m^2 / (32 pi h^4) along the normal."""
    m = moment * np.array([math.sin(angle_to_normal), 0.0, math.cos(angle_to_normal)])
    f = image_force(np.array([0.0, 0.0, height]), m, np.zeros(3), np.array([0.0, 0.0, 1.0]), mu_r)
    return float(-f[2])
