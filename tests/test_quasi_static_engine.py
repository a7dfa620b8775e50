"""The statics in the heart (wall and sheath rows, frictionless multipliers) and the quasi-static
engine against the MultibodyPlant."""

import numpy as np
import pytest

from ballchain.drake_models.chain_energy import chain_energy
from ballchain.drake_models.field_sources import MagnetSource
from ballchain.drake_models.params import BallChain, CylinderMagnet
from ballchain.optimization.statics import ChainStatics, dense_qp
from ballchain.optimization.wall_constraints import (
    ConstrainedChain,
    HeartConstraints,
    SheathGeometry,
    base_rotation,
    sheath_split,
)


@pytest.fixture(scope="module")
def heart():
    from ballchain.drake_models.heart import LeftAtrium

    return LeftAtrium()


@pytest.fixture(scope="module")
def sdf(heart):
    from ballchain.drake_models.atrium_sdf import atrium_sdf

    return atrium_sdf(heart)


def _left_magnet(heart):
    u = np.array([1.0, 0.0, 0.0])
    return MagnetSource.pointing(CylinderMagnet(), heart.p_HP + 0.1651 * u, [0.0, -1.0, 0.0], "dipole")


def _constraints(heart, sdf, s, n=16, d=3.175e-3):
    k, a = sheath_split(n, s, d)
    sheath = SheathGeometry(heart.p_HE, heart.sheath_axis_H, 1.8e-3, 0.3e-3)
    return k, HeartConstraints(heart.p_HE + a * heart.sheath_axis_H, base_rotation(heart.sheath_axis_H), sdf,
                               sheath, n_behind=k, gravity=True)


def test_sheath_split_follows_the_feeder():
    d = 3.175e-3
    # At s = 0 the tip's centre is half a ball behind the exit: everything is held.
    assert sheath_split(16, 0.0, d) == (15, pytest.approx(-0.5 * d))
    k, a = sheath_split(16, 0.02, d)
    assert k == 9 and -d < a <= 0.0
    assert np.isclose(0.02 - (16 - 0.5 - k) * d, a)


def test_dense_qp_matches_the_kkt_conditions():
    rng = np.random.default_rng(0)
    n, m = 12, 7
    A0 = rng.normal(size=(n, n))
    H = A0 @ A0.T + n * np.eye(n)
    g = rng.normal(size=n)
    A = rng.normal(size=(m, n))
    b = rng.normal(size=m)
    E = rng.normal(size=(2, n))
    e = rng.normal(size=2)
    x, lam, mu = dense_qp(H, g, A, b, E, e)
    np.testing.assert_allclose(H @ x + g - A.T @ lam - E.T @ mu, 0.0, atol=1e-9)
    assert np.all(A @ x + b >= -1e-9) and np.all(lam >= 0)
    np.testing.assert_allclose(lam * (A @ x + b), 0.0, atol=1e-9)  # complementarity
    np.testing.assert_allclose(E @ x + e, 0.0, atol=1e-9)
    # Infeasible rows (x_0 >= 1 and x_0 <= -1) are reported, not hidden.
    A2 = np.zeros((2, n))
    A2[0, 0], A2[1, 0] = 1.0, -1.0
    assert dense_qp(H, g, A2, np.array([-1.0, -1.0]))[0] is None


def test_row_derivatives_match_finite_differences(heart, sdf):
    chain = BallChain(n_balls=16)
    k, c = _constraints(heart, sdf, 0.024)
    model = ConstrainedChain(chain.with_balls(16 - k))
    model.set_constraints(c)
    model.external = c.external_in_base(_left_magnet(heart), chain)
    rng = np.random.default_rng(3)
    p0 = np.arange(16 - k)[:, None] * chain.ball_diameter * np.array([1.0, 0.0, 0.0])
    model.chart_from_configuration(p0, np.tile([1.0, 0.0, 0.0], (16 - k, 1)))
    q = 0.05 * rng.normal(size=model.nq)
    ev = model.evaluate(q, 2)
    h = 1e-6
    rows = np.arange(model.n_pairs, len(ev.gaps))
    for j in rng.choice(model.nq, 8, replace=False):
        e = np.zeros(model.nq)
        e[j] = h
        plus, minus = model.evaluate(q + e, 1), model.evaluate(q - e, 1)
        np.testing.assert_allclose(ev.gradient[j], (plus.energy - minus.energy) / (2 * h), rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(ev.jacobian[rows, j], (plus.gaps[rows] - minus.gaps[rows]) / (2 * h),
                                   rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(ev.hessian[:, j], (plus.gradient - minus.gradient) / (2 * h), rtol=1e-5, atol=1e-5)
        weights = rng.uniform(0.1, 1.0, len(rows))
        Hc = model.constraint_hessian(q, rows, weights)
        fd = (plus.jacobian[rows].T @ weights - minus.jacobian[rows].T @ weights) / (2 * h)
        np.testing.assert_allclose(Hc[:, j], fd, rtol=1e-4, atol=1e-4)


@pytest.mark.slow
def test_heart_statics_multipliers_balance_every_sub_chain(heart, sdf):
    """In contact with the wall, the frictionless wall and sheath pushes (the multipliers) with
    the magnetic forces and gravity leave every sub-chain beyond a held or free ball in moment
    balance about that ball's centre, and every free dipole without torque; the free balls stay
    a radius inside the lumen."""
    chain = BallChain(n_balls=16)
    d = chain.ball_diameter
    source = _left_magnet(heart)
    k, c = _constraints(heart, sdf, 0.027)
    result = ChainStatics(chain.with_balls(16 - k), gravity=True).solve_or_raise(source, constraints=c)
    assert result.wall_forces_W, "the chain should touch the wall"
    p, m = c.full_configuration(result.positions, result.dipoles, d)
    _, dU_dp, dU_dm, _ = chain_energy(chain, p, m, source, gravity=True, base_direction=heart.sheath_axis_H)
    F, tau = -dU_dp, np.cross(m, -dU_dm)
    for b, f in list(result.wall_forces_W.items()) + list(result.sheath_forces_W.items()):
        F[k + b] += f
    # The wall pushes along the inward normal (frictionless).
    for b, f in result.wall_forces_W.items():
        n = sdf(p[k + b][None])[1][0]
        np.testing.assert_allclose(f / np.linalg.norm(f), n / np.linalg.norm(n), atol=1e-9)
    assert np.all(sdf(p[k + 1:], gradient=False) >= 0.5 * d - 1e-7 * d)
    scale = np.abs(F[k:]).max() * d
    np.testing.assert_allclose(tau[k + 1:], 0.0, atol=1e-6 * scale)
    for j in range(k, 15):
        moment = np.sum(np.cross(p[j + 1:] - p[j], F[j + 1:]) + tau[j + 1:], axis=0)
        np.testing.assert_allclose(moment, 0.0, atol=1e-6 * scale)
