"""Cross-checks of the dipole laws: gradients, energy derivatives, Newton's third law, magpylib."""

import numpy as np
import pytest
from magpylib.func import dipole_field as magpy_dipole_field
from magpylib.func import sphere_field

from ballchain.drake_models.dipole import (
    K_DIPOLE,
    DipoleFieldAtPoint,
    chain_interactions,
    dipole_field,
    dipole_field_gradient,
    energy_of_dipole,
    force_on_dipole,
    torque_on_dipole,
)
from ballchain.drake_models.params import BallChain

RNG = np.random.default_rng(7)


def test_on_axis_and_equatorial_field_by_hand():
    m = np.array([0.0, 0.0, 2.0])
    r = 0.1
    np.testing.assert_allclose(dipole_field([0, 0, r], m), [0, 0, 2 * K_DIPOLE * 2.0 / r**3], rtol=1e-14)
    np.testing.assert_allclose(dipole_field([r, 0, 0], m), [0, 0, -K_DIPOLE * 2.0 / r**3], rtol=1e-14)


def test_gradient_matches_central_differences_and_is_symmetric_traceless():
    r = RNG.normal(size=(20, 3)) * 0.05
    m = RNG.normal(size=(20, 3))
    G = dipole_field_gradient(r, m)
    h = 1e-7
    for b in range(3):
        e = np.zeros(3)
        e[b] = h
        fd = (dipole_field(r + e, m) - dipole_field(r - e, m)) / (2 * h)
        np.testing.assert_allclose(G[:, :, b], fd, rtol=1e-6, atol=1e-9 * np.abs(G).max())
    np.testing.assert_allclose(G, np.swapaxes(G, 1, 2), atol=1e-12 * np.abs(G).max())
    np.testing.assert_allclose(np.trace(G, axis1=1, axis2=2), 0, atol=1e-12 * np.abs(G).max())


def test_force_and_torque_are_minus_energy_derivatives():
    r = np.array([0.03, -0.01, 0.02])
    m_src = np.array([0.5, 1.0, -0.2])
    m = np.array([0.01, -0.02, 0.015])
    F = force_on_dipole(m, dipole_field_gradient(r, m_src))
    h = 1e-8
    fd = np.array(
        [
            -(energy_of_dipole(m, dipole_field(r + h * e, m_src)) - energy_of_dipole(m, dipole_field(r - h * e, m_src)))
            / (2 * h)
            for e in np.eye(3)
        ]
    )
    np.testing.assert_allclose(F, fd, rtol=1e-6)
    # Torque about axis k: -dU/dphi for a rotation of m about k.
    B = dipole_field(r, m_src)
    tau = torque_on_dipole(m, B)
    for k, axis in enumerate(np.eye(3)):
        phi = 1e-6
        m_rot = m + phi * np.cross(axis, m)
        dU = energy_of_dipole(m_rot, B) - energy_of_dipole(m, B)
        np.testing.assert_allclose(tau[k], -dU / phi, rtol=1e-4, atol=1e-12)


def test_matches_magpylib_dipole_and_exact_sphere():
    chain = BallChain()
    m = np.array([0.0, chain.dipole_moment, 0.0])
    points = RNG.normal(size=(30, 3)) * 0.02
    points += np.sign(points) * chain.ball_diameter  # keep outside the ball
    ours = dipole_field(points, m)
    np.testing.assert_allclose(ours, magpy_dipole_field("B", points, m), rtol=1e-8)
    # A uniformly magnetised sphere's outside field is exactly a dipole's.
    sphere = sphere_field("B", points, chain.ball_diameter, (0.0, chain.remanence, 0.0))
    np.testing.assert_allclose(ours, sphere, rtol=1e-6)


def _random_chain(n=7):
    p = np.cumsum(RNG.normal(size=(n, 3)), axis=0) * 4e-3
    m = RNG.normal(size=(n, 3)) * 0.02
    return p, m


def test_chain_interactions_match_pairwise_sums():
    p, m = _random_chain()
    U, F, B = chain_interactions(p, m)
    n = len(p)
    U_ref, F_ref, B_ref = 0.0, np.zeros((n, 3)), np.zeros((n, 3))
    for i in range(n):
        for j in range(n):
            if i == j:
                continue
            r = p[i] - p[j]
            B_ref[i] += dipole_field(r, m[j])
            F_ref[i] += force_on_dipole(m[i], dipole_field_gradient(r, m[j]))
            if j > i:
                U_ref += energy_of_dipole(m[i], dipole_field(r, m[j]))
    np.testing.assert_allclose(U, U_ref, rtol=1e-12)
    np.testing.assert_allclose(F, F_ref, rtol=1e-10, atol=1e-12 * np.abs(F_ref).max())
    np.testing.assert_allclose(B, B_ref, rtol=1e-10, atol=1e-12 * np.abs(B_ref).max())


def test_chain_forces_are_minus_energy_gradient_and_obey_newtons_third_law():
    p, m = _random_chain()
    U, F, B = chain_interactions(p, m)
    h = 1e-9
    for i in range(len(p)):
        for k in range(3):
            dp = np.zeros_like(p)
            dp[i, k] = h
            fd = (chain_interactions(p + dp, m)[0] - chain_interactions(p - dp, m)[0]) / (2 * h)
            np.testing.assert_allclose(F[i, k], -fd, rtol=1e-5, atol=1e-9 * np.abs(F).max())
            dm = np.zeros_like(m)
            dm[i, k] = 1e-7
            fdm = (chain_interactions(p, m + dm)[0] - chain_interactions(p, m - dm)[0]) / 2e-7
            np.testing.assert_allclose(-B[i, k], fdm, rtol=1e-5, atol=1e-9 * np.abs(B).max())
    # Internal forces sum to zero; internal torques about the origin (r x F + m x B) sum to zero.
    np.testing.assert_allclose(F.sum(axis=0), 0, atol=1e-12 * np.abs(F).max())
    total_moment = np.cross(p, F).sum(axis=0) + np.cross(m, B).sum(axis=0)
    np.testing.assert_allclose(total_moment, 0, atol=1e-10 * np.abs(np.cross(p, F)).max())


def test_touching_balls_numbers_from_design():
    chain = BallChain()
    d, M = chain.ball_diameter, chain.dipole_moment
    np.testing.assert_allclose(M, 0.0192, rtol=5e-3)
    np.testing.assert_allclose(chain.ball_mass, 0.126e-3, rtol=5e-3)
    p = np.array([[0, 0, 0], [d, 0, 0]])
    m = np.array([[M, 0, 0], [M, 0, 0]])
    U, F, B = chain_interactions(p, m)
    # Coaxial attraction 6 k M^2 / d^4 (about 2.2 N); field 2 k M / d^3 (about 0.12 T).
    np.testing.assert_allclose(-F[1, 0], 6 * K_DIPOLE * M**2 / d**4, rtol=1e-12)
    assert 2.0 < -F[1, 0] < 2.4
    np.testing.assert_allclose(B[1, 0], 2 * K_DIPOLE * M / d**3, rtol=1e-12)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_input_is_rejected(bad):
    with pytest.raises(ValueError, match="not finite"):
        dipole_field([bad, 0, 0], [0, 0, 1])
    with pytest.raises(ValueError, match="not finite"):
        chain_interactions(np.array([[0, 0, 0], [bad, 0, 0]]), np.ones((2, 3)))


def test_coincident_points_are_rejected():
    with pytest.raises(ValueError, match="same position"):
        chain_interactions(np.zeros((2, 3)), np.ones((2, 3)))
    with pytest.raises(ValueError, match="coincides"):
        dipole_field([0, 0, 0], [0, 0, 1])


def test_field_at_a_fixed_point_is_the_law_bit_for_bit():
    """``DipoleFieldAtPoint(r)(m)`` is ``dipole_field(r[None], m)[0]`` (a source's field at one
    point, ``MagnetSource.field``): the same floats, for offsets from a millimetre to a metre and
    moments turning, scaled and with zero components. (The law on a 1-D ``r`` can differ in the
    last bit: numpy's ``x**3`` of a scalar and of an array take different paths.)"""
    rng = np.random.default_rng(3)
    for scale in (1e-3, 0.03, 1.0):
        for r in rng.normal(size=(40, 3)) * scale:
            at_point = DipoleFieldAtPoint(r)
            m = rng.normal(size=(25, 3)) * rng.choice([1e-3, 1.0, 50.0], size=(25, 1))
            m[:5, rng.integers(3)] = 0.0
            for moment in m:
                assert np.array_equal(at_point(moment), dipole_field(r[None], moment)[0])
    with pytest.raises(ValueError, match="coincides"):
        DipoleFieldAtPoint(np.zeros(3))
    with pytest.raises(ValueError, match="not finite"):
        DipoleFieldAtPoint([np.nan, 0.0, 0.0])
