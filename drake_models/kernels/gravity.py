"""Gravity along -z: ``U_g = W sum_k z_k`` for balls of weight W, compiled.

The law of the gravity term of ``chain_energy.field_energy``.
"""

from __future__ import annotations

from ballchain.drake_models.kernels._common import kernel


@kernel
def add_gravity(p, weight, dU_dp):
    """Add gravity's gradient (``weight`` along +z at every ball) to ``dU_dp``; returns U_g [J].

    Args:
        p: (n, 3) ball centres [m]; weight: a ball's weight [N].
        dU_dp: (n, 3) gradient [J/m], added to.
    """
    U = 0.0
    for k in range(p.shape[0]):
        U += weight * p[k, 2]
        dU_dp[k, 2] += weight
    return U
