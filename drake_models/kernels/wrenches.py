"""The chain's energy and wrenches in Cartesian coordinates: the ball-ball pairs, the external
field, gravity and the sleeve summed, and the forces and torques on the balls (the wrench system).

The law of ``chain_energy.chain_energy`` (and of ``F = -dU/dp``, ``tau = m_hat x -dU/dm_hat``),
compiled; the parts are the kernels of ``pair``, ``external``, ``gravity`` and ``sleeve``.
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.kernels._common import (
    OK,
    EnergyTerms,
    TERM_BALLS,
    TERM_EXTERNAL,
    TERM_GRAVITY,
    TERM_SLEEVE,
    check_status,
    kernel,
)
from ballchain.drake_models.kernels.external import add_external, external_arrays
from ballchain.drake_models.kernels.gravity import add_gravity
from ballchain.drake_models.kernels.pair import pair_energy_gradient
from ballchain.drake_models.kernels.sleeve import add_sleeve
from ballchain.drake_models.params import GRAVITY


@kernel
def cartesian_energy(p, m_hat, M, B, G, has_external, weight, k_s, base):
    """The chain's energy U = U_b + U_e + U_s + U_g and its gradient in Cartesian coordinates.

    Args:
        p: (n, 3) ball centres [m]; m_hat: (n, 3) unit dipoles; M: dipole moment [A m^2].
        B, G: (n, 3), (n, 3, 3) external field and gradient at the centres (ignored unless
            ``has_external``).
        weight: a ball's weight [N] for gravity along -z (0: no gravity).
        k_s: the sleeve's E I / d [J] (0: no sleeve); base: (3,) unit sheath axis.

    Returns:
        ``(status, terms (4,) [J], dU_dp (n, 3) [J/m], dU_dm_hat (n, 3) [J])``. The force on
        ball i is ``-dU_dp[i]``, its torque ``m_hat_i x (-dU_dm_hat[i])``.
    """
    n = p.shape[0]
    terms = np.zeros(4)
    status, U_b, dU_dp, dU_dm = pair_energy_gradient(p, m_hat, M)
    if status != OK:
        return status, terms, dU_dp, dU_dm
    terms[TERM_BALLS] = U_b
    if has_external:
        terms[TERM_EXTERNAL] = add_external(p, m_hat, M, B, G, dU_dp, dU_dm)
    if weight != 0.0:
        terms[TERM_GRAVITY] = add_gravity(p, weight, dU_dp)
    if k_s > 0.0 and n > 1:
        status, U_s = add_sleeve(p, base, k_s, dU_dp)
        if status != OK:
            return status, terms, dU_dp, dU_dm
        terms[TERM_SLEEVE] = U_s
    return OK, terms, dU_dp, dU_dm


@kernel
def cartesian_wrenches(p, m_hat, M, B, G, has_external, k_s, base):
    """Forces (n, 3) [N] and torques (n, 3) [N m] on the balls from ``cartesian_energy``
    (gravity excluded): ``F_i = -dU/dp_i``, ``tau_i = m_hat_i x (-dU/dm_hat_i)``.

    Returns:
        ``(status, F, tau)``.
    """
    status, _, dU_dp, dU_dm = cartesian_energy(p, m_hat, M, B, G, has_external, 0.0, k_s, base)
    n = p.shape[0]
    F = np.empty((n, 3))
    tau = np.empty((n, 3))
    for i in range(n):
        for c in range(3):
            F[i, c] = -dU_dp[i, c]
        tau[i, 0] = -(m_hat[i, 1] * dU_dm[i, 2] - m_hat[i, 2] * dU_dm[i, 1])
        tau[i, 1] = -(m_hat[i, 2] * dU_dm[i, 0] - m_hat[i, 0] * dU_dm[i, 2])
        tau[i, 2] = -(m_hat[i, 0] * dU_dm[i, 1] - m_hat[i, 1] * dU_dm[i, 0])
    return status, F, tau


def chain_energy(chain, p, m_hat, external=None, gravity: bool = False, base_direction=(1.0, 0.0, 0.0)):
    """Total potential energy of a chain configuration and its gradient (the compiled kernel).

    Same arguments and results as the numpy reference ``chain_energy.chain_energy``.

    Args:
        chain: the chain's parameters (sleeve bending included when ``chain.sleeve``).
        p: (n, 3) ball centres [m].
        m_hat: (n, 3) unit dipole directions.
        external: the external FieldSource, or None.
        gravity: include gravity (along -z).
        base_direction: sheath axis, for the sleeve's first bend.

    Returns:
        ``(U, dU_dp, dU_dm_hat, terms)``: U [J], gradients (n, 3) [J/m] and [J], EnergyTerms.
    """
    p = np.ascontiguousarray(p, dtype=float)
    m_hat = np.ascontiguousarray(m_hat, dtype=float)
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(m_hat))):
        raise ValueError("chain_energy: positions or dipoles are not finite (NaN or inf)")
    has_ext, B, G, _ = external_arrays(external, p)
    base = np.asarray(base_direction, dtype=float).reshape(3)
    base = base / np.linalg.norm(base)
    k_s = chain.sleeve.bending_stiffness / chain.ball_diameter if chain.sleeve is not None else 0.0
    weight = chain.ball_mass * GRAVITY if gravity else 0.0
    status, t, dU_dp, dU_dm = cartesian_energy(p, m_hat, chain.dipole_moment, B, G, has_ext, weight, k_s, base)
    check_status(status, "chain_energy")
    terms = EnergyTerms(float(t[0]), float(t[1]), float(t[2]), float(t[3]))
    return terms.total, dU_dp, dU_dm, terms


def chain_wrenches(chain, p, m_hat, external=None, base_direction=(1.0, 0.0, 0.0)):
    """Forces (n, 3) [N] and torques (n, 3) [N m] on the balls from the chain's magnetic and
    sleeve energy (gravity excluded): ``F_i = -dU/dp_i``, ``tau_i = m_hat_i x (-dU/dm_hat_i)``.

    Args:
        chain: the chain's parameters (sleeve included when ``chain.sleeve``).
        p: (n, 3) ball centres [m]; m_hat: (n, 3) unit dipoles.
        external: the external FieldSource, or None.
        base_direction: (3,) sheath axis for the sleeve's first bend.
    """
    p = np.ascontiguousarray(p, dtype=float)
    m_hat = np.ascontiguousarray(m_hat, dtype=float)
    if not (np.isfinite(p).all() and np.isfinite(m_hat).all()):
        raise ValueError("chain_wrenches: positions or dipoles are not finite (NaN or inf)")
    has_ext, B, G, _ = external_arrays(external, p)
    base = np.asarray(base_direction, dtype=float).reshape(3)
    base = base / np.linalg.norm(base)
    k_s = chain.sleeve.bending_stiffness / chain.ball_diameter if chain.sleeve is not None else 0.0
    status, F, tau = cartesian_wrenches(p, m_hat, chain.dipole_moment, B, G, has_ext, k_s, base)
    check_status(status, "chain_wrenches")
    return F, tau
