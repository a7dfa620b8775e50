"""Potential energy of a ball chain, U = U_b + U_e + U_s + U_g, with its analytic gradient.

This is the paper's energy (Section II) with its slips corrected (docs/design.md, 4.4):

* U_b: every pair of balls, through ``dipole.chain_interactions``.
* U_e: each ball in the external field, ``-m_i . B(p_i)``.
* U_s: the sleeve, one circular arc per bend between consecutive links. A bend of angle theta
  (theta = atan2(|u_a x u_b|, u_a . u_b), the norm of the cross product) spans the contact
  points d/2 either side of the ball, so its radius of curvature is rho = (d/2) cot(theta/2)
  (a radius, not an arc length), its length rho theta and its energy
  E I theta / (2 rho) = (E I / d) theta tan(theta / 2)  (-> E I theta^2 / (2 d) for small theta).
  The first bend is between the sheath axis (``base_direction``) and the first link: the
  sleeve is clamped in the sheath.
* U_g: ``sum_i mass g z_i`` with gravity along -z, so the energy rises with height (the
  paper's ``mu_i g^T p_i`` has the opposite sign if g is the downward acceleration vector).

Forces and torques on the balls follow from the same function: ``F_i = -dU/dp_i`` and, for a
ball whose dipole direction is m_hat_i, ``tau_i = m_hat_i x (-dU/dm_hat_i)``.
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.dipole import chain_interaction_hessian, chain_interactions
from ballchain.drake_models.field_sources import FieldSource, field_gradient_derivative
from ballchain.drake_models.kernels import EnergyTerms
from ballchain.drake_models.params import GRAVITY, BallChain


def sleeve_bending(u: np.ndarray, base_direction: np.ndarray, stiffness_over_d: float, hessian: bool = False):
    """Bending energy of the sleeve over a chain of unit link directions.

    The energy is written as a function of the cosines c = u_a . u_b of consecutive links, so
    its gradient and Hessian are those of f(c) (unprojected on the unit sphere).

    Args:
        u: (L, 3) unit link directions, from ball 1 to the tip.
        base_direction: (3,) unit direction of the sheath that clamps the sleeve at ball 1.
        stiffness_over_d: E I / d [J].
        hessian: also return the Hessian.

    Returns:
        ``(U, dU_du)`` or ``(U, dU_du, H)``: energy [J], gradient (L, 3), Hessian (L, 3, L, 3).
    """
    links = np.vstack([base_direction, u])
    a, b = links[:-1], links[1:]
    c = np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)
    s = np.linalg.norm(np.cross(a, b), axis=1)
    theta = np.arctan2(s, c)
    if np.any(theta > np.pi - 1e-6):
        raise ValueError("sleeve_bending: a bend of 180 deg (chain folded onto itself)")
    U = stiffness_over_d * float(np.sum(theta * np.tan(0.5 * theta)))
    # f(theta) = theta tan(theta/2) as a function of c = cos(theta):
    # df/dc = -(1 + h) / (1 + c) with h = theta / sin(theta) = 1 / sinc(theta / pi).
    h = 1.0 / np.sinc(theta / np.pi)
    dfdc = -(1.0 + h) / (1.0 + c)
    w = stiffness_over_d * dfdc[:, None]
    dU_dlinks = np.zeros_like(links)
    dU_dlinks[:-1] += w * b
    dU_dlinks[1:] += w * a
    if not hessian:
        return U, dU_dlinks[1:]
    # d2f/dc2 = [(sin t - t cos t) / sin^3 t (1 + c) + (1 + h)] / (1 + c)^2; the first ratio
    # tends to 1/3 (series below 1e-3 rad).
    small = theta < 1e-3
    st = np.where(small, 1.0, np.sin(theta))
    ratio = np.where(small, 1.0 / 3.0 + theta**2 / 30.0, (st - theta * np.cos(theta)) / st**3)
    d2fdc2 = (ratio * (1.0 + c) + (1.0 + h)) / (1.0 + c) ** 2
    nl = links.shape[0]
    H = np.zeros((nl, 3, nl, 3))
    idx = np.arange(nl - 1)
    f2 = stiffness_over_d * d2fdc2[:, None, None]
    f1 = stiffness_over_d * dfdc[:, None, None]
    H[idx, :, idx, :] += f2 * (b[:, :, None] * b[:, None, :])
    H[idx + 1, :, idx + 1, :] += f2 * (a[:, :, None] * a[:, None, :])
    cross = f2 * (b[:, :, None] * a[:, None, :]) + f1 * np.eye(3)
    H[idx, :, idx + 1, :] += cross
    H[idx + 1, :, idx, :] += cross.transpose(0, 2, 1)
    return U, dU_dlinks[1:], H[1:, :, 1:, :]


def field_energy(
    chain: BallChain,
    p: np.ndarray,
    m_hat: np.ndarray,
    external: FieldSource | None = None,
    gravity: bool = False,
    hessian: bool = False,
):
    """The magnetic (ball-ball and external) and gravitational energy, without the sleeve.

    Args:
        chain, p, m_hat, external, gravity: as in ``chain_energy``.
        hessian: also return second derivatives.

    Returns:
        ``(terms, dU_dp, dU_dm_hat)`` and, with ``hessian``, ``(H_pp, H_pm, H_mm)`` each
        (n, 3, n, 3) with respect to positions and (unnormalised) dipole directions.
    """
    M = chain.dipole_moment
    terms = EnergyTerms()
    if hessian:
        U_b, F, B_int, H_pp, H_pm, H_mm = chain_interaction_hessian(p, M * m_hat)
        H_pm = H_pm * M
        H_mm = H_mm * (M * M)
    else:
        U_b, F, B_int = chain_interactions(p, M * m_hat)
    terms.balls = U_b
    dU_dp = -F
    dU_dm = -M * B_int
    if external is not None:
        B, G = external.field_and_gradient(p)
        terms.external = -M * float(np.einsum("ij,ij->", m_hat, B))
        dU_dp = dU_dp - M * np.einsum("kab,ka->kb", G, m_hat)
        dU_dm = dU_dm - M * B
        if hessian:
            n = p.shape[0]
            idx = np.arange(n)
            dG = field_gradient_derivative(external, p)
            H_pp[idx, :, idx, :] -= M * np.einsum("ka,kabc->kbc", m_hat, dG)
            H_pm[idx, :, idx, :] -= M * G.transpose(0, 2, 1)
    if gravity:
        weight = chain.ball_mass * GRAVITY
        terms.gravity = weight * float(p[:, 2].sum())
        dU_dp = dU_dp.copy()
        dU_dp[:, 2] += weight
    if hessian:
        return terms, dU_dp, dU_dm, (H_pp, H_pm, H_mm)
    return terms, dU_dp, dU_dm


def chain_energy(
    chain: BallChain,
    p: np.ndarray,
    m_hat: np.ndarray,
    external: FieldSource | None = None,
    gravity: bool = False,
    base_direction=(1.0, 0.0, 0.0),
):
    """Total potential energy of a chain configuration and its gradient.

    Args:
        chain: the chain's parameters (sleeve bending is included when ``chain.sleeve``).
        p: (n, 3) ball centres [m].
        m_hat: (n, 3) unit dipole directions.
        external: the external field source, or None.
        gravity: include gravity (along -z).
        base_direction: sheath axis, for the sleeve's first bend.

    Returns:
        ``(U, dU_dp, dU_dm_hat, terms)``: U [J], gradients (n, 3) [J/m] and [J], and the parts.
    """
    p = np.asarray(p, dtype=float)
    m_hat = np.asarray(m_hat, dtype=float)
    terms, dU_dp, dU_dm = field_energy(chain, p, m_hat, external, gravity)
    if chain.sleeve is not None and p.shape[0] > 1:
        links = np.diff(p, axis=0)
        lengths = np.linalg.norm(links, axis=1)
        u = links / lengths[:, None]
        base = np.asarray(base_direction, dtype=float)
        base = base / np.linalg.norm(base)
        U_s, dU_du = sleeve_bending(u, base, chain.sleeve.bending_stiffness / chain.ball_diameter)
        terms.sleeve = U_s
        # Through u = l / |l|: dU/dl = (I - u u^T) dU/du / |l|.
        dU_dl = (dU_du - u * np.einsum("ij,ij->i", u, dU_du)[:, None]) / lengths[:, None]
        dU_dp = dU_dp.copy()
        dU_dp[1:] += dU_dl
        dU_dp[:-1] -= dU_dl
    return terms.total, dU_dp, dU_dm, terms
