"""Each kernel file's public kernels against its numpy reference, one law at a time (1e-12 of
each reference array's largest entry, as in test_chain_kernels.py, which checks the sums).

pair: ``dipole.chain_interactions``; external: ``dipole.energy_of_dipole`` / ``force_on_dipole``;
sleeve: ``chain_energy.sleeve_bending``; gravity: ``chain_energy.field_energy``; charts and
constraints: ``ReducedChain(backend="numpy")`` and ``numpy.triu_indices``.
"""

import numpy as np
import pytest

from ballchain.drake_models import kernels as ck
from ballchain.drake_models.chain_energy import field_energy, sleeve_bending
from ballchain.drake_models.dipole import chain_interactions, energy_of_dipole, force_on_dipole
from ballchain.drake_models.field_sources import MagnetSource
from ballchain.drake_models.params import GRAVITY, BallChain, CylinderMagnet, Sleeve
from ballchain.optimization.reduced_chain import ReducedChain
from test_chain_kernels import assert_close, random_chain_state

RTOL = 1e-12


@pytest.mark.parametrize("n", [2, 3, 16, 40])
def test_pair_energy_gradient_matches_chain_interactions(n):
    chain = BallChain(n_balls=n)
    p, m = random_chain_state(n, np.random.default_rng(300 + n))
    M = chain.dipole_moment
    status, U, dU_dp, dU_dm = ck.pair_energy_gradient(p, m, M)
    U_r, F_r, B_r = chain_interactions(p, M * m)
    assert status == ck.OK
    assert abs(U - U_r) <= RTOL * abs(U_r)
    assert_close(dU_dp, -F_r)
    assert_close(dU_dm, -M * B_r)
    status, *_ = ck.pair_energy_gradient(np.zeros((n, 3)), m, M)
    assert status == ck.COINCIDENT


def test_add_external_matches_the_dipole_energy_in_a_field():
    """U_e = -M sum m_hat . B, dU/dp = -(force on M m_hat), dU/dm_hat = -M B, added to what is there."""
    n = 16
    chain = BallChain(n_balls=n)
    p, m = random_chain_state(n, np.random.default_rng(31))
    magnet = MagnetSource.pointing(CylinderMagnet(), [0.02, 0.12, 0.05], [0.3, 1.0, 0.2])
    has_ext, B, G, _ = ck.external_arrays(magnet, p)
    assert has_ext
    M = chain.dipole_moment
    start_p, start_m = np.random.default_rng(32).normal(size=(2, n, 3))
    dU_dp, dU_dm = start_p.copy(), start_m.copy()
    U = ck.add_external(p, m, M, B, G, dU_dp, dU_dm)
    U_r = energy_of_dipole(M * m, B).sum()
    assert abs(U - U_r) <= RTOL * np.abs(energy_of_dipole(M * m, B)).max()
    assert_close(dU_dp - start_p, -force_on_dipole(M * m, G))
    assert_close(dU_dm - start_m, -M * B)


@pytest.mark.parametrize("n", [2, 16])
def test_add_gravity_matches_field_energy(n):
    chain = BallChain(n_balls=n)
    p, m = random_chain_state(n, np.random.default_rng(40 + n))
    p[:, 2] += 0.01  # every ball above z = 0: a sum of like-signed terms
    terms, dU_dp_r, _ = field_energy(chain, p, m, None, gravity=True)
    _, dU_dp, _ = field_energy(chain, p, m, None, gravity=False)
    U = ck.add_gravity(p, chain.ball_mass * GRAVITY, dU_dp)
    assert abs(U - terms.gravity) <= RTOL * abs(terms.gravity)
    assert_close(dU_dp, dU_dp_r)


def _links(p):
    links = np.diff(p, axis=0)
    lengths = np.linalg.norm(links, axis=1)
    return links / lengths[:, None], lengths


@pytest.mark.parametrize("n", [2, 3, 16, 40])
def test_sleeve_energy_matches_sleeve_bending(n):
    """Energy, gradient and Hessian over the unit links (orders 0, 1, 2), and a fold refused."""
    chain = BallChain(n_balls=n, sleeve=Sleeve())
    p, _ = random_chain_state(n, np.random.default_rng(50 + n))
    u, _ = _links(p)
    base = np.array([1.0, 0.2, -0.1]) / np.linalg.norm([1.0, 0.2, -0.1])
    k_s = chain.sleeve.bending_stiffness / chain.ball_diameter
    U_r, g_r, H_r = sleeve_bending(u, base, k_s, hessian=True)
    L = n - 1
    for order in (0, 1, 2):
        g = np.zeros((L, 3))
        H = np.zeros((L, L, 3, 3) if order >= 2 else (0, 0, 3, 3))
        status, U = ck.sleeve_energy(u, base, k_s, g, H, order)
        assert status == ck.OK
        assert abs(U - U_r) <= RTOL * abs(U_r)
        if order >= 1:
            assert_close(g, g_r)
        if order >= 2:
            assert_close(H.transpose(0, 2, 1, 3), H_r)
    folded = u.copy()
    folded[0] = -base
    status, _ = ck.sleeve_energy(folded, base, k_s, np.zeros((L, 3)), np.zeros((0, 0, 3, 3)), 1)
    assert status == ck.FOLDED


@pytest.mark.parametrize("n", [2, 16])
def test_add_sleeve_matches_sleeve_bending_through_the_links(n):
    """The sleeve on the ball centres: sleeve_bending's dU/du carried through u = l / |l|."""
    chain = BallChain(n_balls=n, sleeve=Sleeve())
    p, _ = random_chain_state(n, np.random.default_rng(60 + n))
    base = np.array([1.0, 0.0, 0.0])
    k_s = chain.sleeve.bending_stiffness / chain.ball_diameter
    u, lengths = _links(p)
    U_r, dU_du = sleeve_bending(u, base, k_s)
    dU_dl = (dU_du - u * np.einsum("ij,ij->i", u, dU_du)[:, None]) / lengths[:, None]
    dU_dp_r = np.zeros((n, 3))
    dU_dp_r[1:] += dU_dl
    dU_dp_r[:-1] -= dU_dl
    dU_dp = np.zeros((n, 3))
    status, U = ck.add_sleeve(p, base, k_s, dU_dp)
    assert status == ck.OK
    assert abs(U - U_r) <= RTOL * abs(U_r)
    assert_close(dU_dp, dU_dp_r)


def test_chart_kernels_match_numpy():
    """configuration_vectors, chart_vectors (w and its first and second derivatives) and
    chain_configuration against the numpy reference's charts."""
    n = 12
    chain = BallChain(n_balls=n)
    kernel, numpy_ = ReducedChain(chain, None, False), ReducedChain(chain, None, False, backend="numpy")
    rng = np.random.default_rng(70)
    p, m = random_chain_state(n, rng)
    u, _ = _links(p)
    assert_close(ck.configuration_vectors(p, m), np.vstack([u, m[1:]]))
    for model in (kernel, numpy_):
        model.chart_from_configuration(p, m)
    q = rng.normal(size=kernel.nq) * 0.2
    V = ck.chart_vectors(q, kernel.r0, kernel.t1, kernel.t2)
    w, dw_da, dw_db, in_plane, (ca, sa, cb, sb) = numpy_.unit_vectors(q)
    assert_close(V[0], w)
    assert_close(V[1], dw_da)
    assert_close(V[2], dw_db)
    assert_close(V[3], -cb * in_plane)
    assert_close(V[4], -sb * (-sa * numpy_.r0 + ca * numpy_.t1))
    p_k, m_k = ck.chain_configuration(V[0], n - 1, chain.ball_diameter)
    p_n, m_n = numpy_.configuration(q)
    assert_close(p_k, p_n)
    assert_close(m_k, m_n)


@pytest.mark.parametrize("n", [3, 4, 9])
def test_rigidity_rows_follow_triu_indices(n):
    """pair_of_row and pair_index against numpy.triu_indices(n, k=2), and rigidity_gaps in that order."""
    i, j = np.triu_indices(n, k=2)
    for k in range(len(i)):
        assert ck.pair_of_row(n, k) == (i[k], j[k])
        assert ck.pair_index(n, i[k], j[k]) == k
    p, _ = random_chain_state(n, np.random.default_rng(80 + n))
    d = 3.175e-3
    assert_close(ck.rigidity_gaps(p, d), np.sum((p[j] - p[i]) ** 2, axis=1) / d**2 - 1.0)
