"""The compiled chain kernels against the numpy reference (1e-12 relative) and finite differences.

"Relative" is to the largest entry of the reference array: pair forces inside a chain cancel
to small sums of terms of order 1 N, so an entry-wise relative test would measure the
reference's own round-off.
"""

import numpy as np
import pytest

from ballchain.drake_models import kernels as ck
from ballchain.drake_models.chain_energy import chain_energy as chain_energy_numpy
from ballchain.drake_models.chain_energy import field_energy
from ballchain.drake_models.field_sources import FieldSources, MagnetSource, UniformField
from ballchain.drake_models.params import BallChain, CylinderMagnet, Sleeve
from ballchain.optimization.reduced_chain import ReducedChain

RTOL = 1e-12


def assert_close(actual, reference, rtol=RTOL):
    reference = np.asarray(reference, dtype=float)
    assert np.shape(actual) == reference.shape
    if reference.size == 0:
        return
    scale = max(np.abs(reference).max(), 1e-300)
    np.testing.assert_allclose(np.asarray(actual), reference, rtol=0.0, atol=rtol * scale)


def random_chain_state(n, rng, d=3.175e-3):
    """A random non-overlapping-ish chain: touching neighbours, random bends and dipoles."""
    u = rng.normal(size=(n - 1, 3)) * 0.4 + np.array([1.0, 0.0, 0.0])
    u /= np.linalg.norm(u, axis=1)[:, None]
    p = np.vstack([np.zeros(3), d * np.cumsum(u, axis=0)])
    m = rng.normal(size=(n, 3))
    m /= np.linalg.norm(m, axis=1)[:, None]
    m[0] = [1.0, 0.0, 0.0]
    return p, m


FIELDS = {
    "none": lambda: None,
    "uniform": lambda: UniformField([0.012, 0.019, -0.004]),
    "magnet": lambda: MagnetSource.pointing(CylinderMagnet(), [0.02, 0.12, 0.05], [0.3, 1.0, 0.2]),
    "two magnets": lambda: FieldSources([
        MagnetSource.pointing(CylinderMagnet(), [0.02, 0.12, 0.05], [0.3, 1.0, 0.2]),
        MagnetSource.pointing(CylinderMagnet(), [-0.1, -0.08, 0.0], [1.0, 0.0, -0.5]),
    ]),
}
CASES = [
    (n, field, sleeve, gravity)
    for n, field, sleeve, gravity in [
        (2, "uniform", False, False),
        (2, "magnet", True, True),
        (3, "none", True, False),
        (3, "uniform", False, True),
        (16, "uniform", True, True),
        (16, "magnet", False, False),
        (16, "two magnets", True, True),
        (40, "magnet", True, True),
        (40, "uniform", False, False),
    ]
]


def ids(case):
    n, field, sleeve, gravity = case
    return f"n{n}-{field}-{'sleeve' if sleeve else 'bare'}-{'g' if gravity else 'nog'}"


@pytest.mark.parametrize("case", CASES, ids=ids)
def test_cartesian_energy_and_gradient_match_numpy(case):
    n, field, sleeve, gravity = case
    rng = np.random.default_rng(n)
    chain = BallChain(n_balls=n, sleeve=Sleeve() if sleeve else None)
    p, m = random_chain_state(n, rng)
    external = FIELDS[field]()
    base = np.array([1.0, 0.2, -0.1])
    U, dU_dp, dU_dm, terms = ck.chain_energy(chain, p, m, external, gravity, base)
    U_r, dU_dp_r, dU_dm_r, terms_r = chain_energy_numpy(chain, p, m, external, gravity, base)
    assert abs(U - U_r) <= RTOL * max(abs(terms_r.balls), abs(U_r))
    for part in ("balls", "external", "sleeve", "gravity"):
        assert abs(getattr(terms, part) - getattr(terms_r, part)) <= RTOL * max(abs(getattr(terms_r, part)), 1e-300)
    assert_close(dU_dp, dU_dp_r)
    assert_close(dU_dm, dU_dm_r)


@pytest.mark.parametrize("case", CASES[:7], ids=ids)
def test_cartesian_hessian_blocks_match_numpy(case):
    """Pair Hessian blocks plus the external field's per-ball blocks vs chain_interaction_hessian."""
    n, field, _, gravity = case
    rng = np.random.default_rng(10 + n)
    chain = BallChain(n_balls=n)
    p, m = random_chain_state(n, rng)
    external = FIELDS[field]()
    _, _, _, (H_pp_r, H_pm_r, H_mm_r) = field_energy(chain, p, m, external, gravity, hessian=True)
    status, H_pp, H_pm, H_mm = ck.pair_hessian(p, m, chain.dipole_moment)
    assert status == ck.OK
    has_ext, _, G, dG = ck.external_arrays(external, p, hessian=True)
    if has_ext:
        E_pp, E_pm = ck.external_hessian_blocks(m, chain.dipole_moment, G, dG)
        idx = np.arange(n)
        H_pp[idx, :, idx, :] += E_pp
        H_pm[idx, :, idx, :] += E_pm
    assert_close(H_pp, H_pp_r)
    assert_close(H_pm, H_pm_r)
    assert_close(H_mm, H_mm_r)


def _models(n, field, sleeve, gravity, seed):
    chain = BallChain(n_balls=n, sleeve=Sleeve() if sleeve else None)
    external = FIELDS[field]()
    kernel = ReducedChain(chain, external, gravity)
    numpy_ = ReducedChain(chain, external, gravity, backend="numpy")
    rng = np.random.default_rng(seed)
    w0 = rng.normal(size=(kernel.n_vectors, 3))
    w0[: n - 1] += [2.0, 0.0, 0.0]  # mostly along +x: balls stay apart
    w0[3 % kernel.n_vectors] = [0.0, 0.05, 1.0]  # one vector near the z pole: the chart's x branch
    for model in (kernel, numpy_):
        model.set_chart(w0)
    q = rng.normal(size=kernel.nq) * 0.1
    return kernel, numpy_, q, rng


@pytest.mark.parametrize("case", CASES, ids=ids)
def test_reduced_evaluation_matches_numpy(case):
    """Energy, terms, gaps, gradient, Jacobian and Hessian in chart coordinates, orders 0..2."""
    n, field, sleeve, gravity = case
    kernel, numpy_, q, _ = _models(n, field, sleeve, gravity, seed=100 + n)
    for order in (0, 1, 2):
        a, b = kernel.evaluate(q, order), numpy_.evaluate(q, order)
        assert abs(a.energy - b.energy) <= RTOL * max(abs(b.terms.balls / kernel.energy_scale), abs(b.energy))
        assert_close(a.gaps, b.gaps)
        if order >= 1:
            assert_close(a.gradient, b.gradient)
            assert_close(np.asarray(a.jacobian), b.jacobian)
        if order >= 2:
            assert_close(a.hessian, b.hessian)
    p_k, m_k = kernel.configuration(q)
    p_n, m_n = numpy_.configuration(q)
    assert_close(p_k, p_n)
    assert_close(m_k, m_n)


@pytest.mark.parametrize("n", [3, 16, 40])
def test_constraint_tip_and_links_hessians_match_numpy(n):
    kernel, numpy_, q, rng = _models(n, "uniform", True, False, seed=200 + n)
    P = kernel.n_pairs
    pairs = rng.choice(P, size=min(P, 25), replace=False)
    weights = rng.normal(size=len(pairs))
    assert_close(kernel.constraint_hessian(q, pairs, weights), numpy_.constraint_hessian(q, pairs, weights))
    tip_w = rng.normal(size=3)
    assert_close(kernel.tip_hessian(q, tip_w), numpy_.tip_hessian(q, tip_w))
    W = rng.normal(size=(kernel.n_links, 3))
    assert_close(kernel.links_hessian(q, W), numpy_.links_hessian(q, W))
    # A plane wall's rows (the numpy reference's own wall branch) and the Jacobian rows asked one by one.
    for model in (kernel, numpy_):
        model.wall = (np.array([0.0, 0.0, -0.05]), np.array([0.0, 0.0, 1.0]))
        model.tip_target = np.array([0.01, 0.02, 0.0])
    rows = np.concatenate([pairs[:5], P + np.arange(min(4, n - 1))])
    w_rows = rng.normal(size=len(rows))
    assert_close(kernel.constraint_hessian(q, rows, w_rows), numpy_.constraint_hessian(q, rows, w_rows))
    a, b = kernel.evaluate(q, 2), numpy_.evaluate(q, 2)
    assert_close(a.gaps, b.gaps)
    assert_close(a.jacobian[rows], b.jacobian[rows])
    assert_close(a.jacobian[int(rows[-1])], b.jacobian[int(rows[-1])])
    assert_close(a.jacobian[rows, 1:7], b.jacobian[rows, 1:7])
    assert_close(a.jacobian[a.gaps < 1.0], b.jacobian[b.gaps < 1.0])
    assert_close(a.tip_residual, b.tip_residual)
    assert_close(a.tip_jacobian, b.tip_jacobian)


@pytest.mark.parametrize("sleeve", [False, True])
def test_kernel_gradient_and_hessian_match_finite_differences(sleeve):
    """Central differences of the kernel's own energy and gradient (independent of the numpy path)."""
    kernel, _, q, _ = _models(7, "magnet", sleeve, True, seed=7)
    ev = kernel.evaluate(q, 2)
    h = 1e-6
    E = np.eye(kernel.nq)
    g_fd = np.array([(kernel.evaluate(q + h * e, 0).energy - kernel.evaluate(q - h * e, 0).energy) / (2 * h)
                     for e in E])
    H_fd = np.array([(kernel.evaluate(q + h * e, 1).gradient - kernel.evaluate(q - h * e, 1).gradient) / (2 * h)
                     for e in E])
    J_fd = np.array([(kernel.evaluate(q + h * e, 0).gaps - kernel.evaluate(q - h * e, 0).gaps) / (2 * h)
                     for e in E]).T
    np.testing.assert_allclose(ev.gradient, g_fd, atol=1e-7 * np.abs(g_fd).max())
    np.testing.assert_allclose(ev.hessian, H_fd, atol=1e-6 * np.abs(H_fd).max())
    np.testing.assert_allclose(np.asarray(ev.jacobian), J_fd, atol=1e-7)
    np.testing.assert_allclose(ev.hessian, ev.hessian.T, atol=1e-12 * np.abs(H_fd).max())
    # The rigidity Hessian against differences of the Jacobian rows.
    rows = np.arange(kernel.n_pairs)
    weights = np.linspace(-1.0, 1.0, len(rows))
    Hc = kernel.constraint_hessian(q, rows, weights)
    Hc_fd = np.array([(weights @ kernel.evaluate(q + h * e, 1).jacobian[rows]
                       - weights @ kernel.evaluate(q - h * e, 1).jacobian[rows]) / (2 * h) for e in E])
    np.testing.assert_allclose(Hc, Hc_fd, atol=1e-6 * np.abs(Hc_fd).max())


def test_kernels_raise_on_coincident_balls_and_folded_sleeve():
    chain = BallChain(n_balls=3, sleeve=Sleeve())
    m = np.tile([1.0, 0.0, 0.0], (3, 1))
    with pytest.raises(ValueError, match="coincide"):
        ck.chain_energy(chain, np.zeros((3, 3)), m)
    d = chain.ball_diameter
    folded = np.array([[0.0, 0, 0], [d, 0, 0], [0.0, 0, 0.0]]) + np.array([[0, 0, 0], [0, 0, 0], [0, 1e-12, 0]])
    with pytest.raises(ValueError, match="180 deg"):
        ck.chain_energy(chain, folded, m)
    with pytest.raises(ValueError, match="not finite"):
        ck.chain_energy(chain, np.full((3, 3), np.nan), m)


def test_large_chain_evaluates_with_quadratic_memory():
    """A 300-ball chain's order-2 evaluation: the pair-by-link incidence (O(n^3), 300 MB here)
    is never built, and asking for a few Jacobian rows builds only those."""
    chain = BallChain(n_balls=300)
    model = ReducedChain(chain, UniformField([0.0, 0.023, 0.0]), gravity=True)
    model.chart_from_configuration(*random_chain_state(300, np.random.default_rng(1)))
    ev = model.evaluate(np.zeros(model.nq), 2)
    assert ev.hessian.shape == (model.nq, model.nq)
    assert model._pair_links is None and model._C3_matrix is None
    assert ev.jacobian.shape == (model.n_pairs, model.nq)
    assert ev.jacobian[np.array([0, model.n_pairs - 1])].shape == (2, model.nq)
    np.testing.assert_allclose(ev.hessian, ev.hessian.T, atol=1e-9 * np.abs(ev.hessian).max())


def test_dipole_field_kernel_matches_the_numpy_law():
    """dipole_field_and_gradient (the wrench system's and MagnetSource's dipole field) vs
    dipole.dipole_field / dipole_field_gradient summed over three dipoles, and its refusal."""
    from ballchain.drake_models.dipole import dipole_field, dipole_field_gradient

    rng = np.random.default_rng(5)
    points = rng.normal(size=(16, 3)) * 0.02
    centres = rng.normal(size=(3, 3)) * 0.05 + np.array([0.0, 0.15, 0.0])
    moments = rng.normal(size=(3, 3)) * 100.0
    violation, B, G = ck.dipole_field_and_gradient(points, centres, moments, np.full(3, 0.01**2))
    assert violation == -1
    r = points[:, None, :] - centres[None, :, :]
    assert_close(B, dipole_field(r, moments).sum(axis=1))
    assert_close(G, dipole_field_gradient(r, moments).sum(axis=1))
    magnet = MagnetSource.pointing(CylinderMagnet(), centres[0], moments[0])
    B1, G1 = magnet.field_and_gradient(points)
    assert_close(B1, dipole_field(points - centres[0], magnet.m_W))
    assert_close(G1, dipole_field_gradient(points - centres[0], magnet.m_W))
    too_close = points.copy()
    too_close[4] = centres[2] + 0.005
    violation, _, _ = ck.dipole_field_and_gradient(too_close, centres, moments, np.full(3, 0.01**2))
    assert divmod(int(violation), 3) == (4, 2)


def test_chart_frames_match_numpy():
    """The kernel's charts (both branches: near the z pole and away) vs the numpy reference's."""
    rng = np.random.default_rng(9)
    chain = BallChain(n_balls=12)
    kernel, numpy_ = ReducedChain(chain, None, False), ReducedChain(chain, None, False, backend="numpy")
    p, m = random_chain_state(12, rng)
    m[3] = [0.05, 0.0, 1.0]
    m[3] /= np.linalg.norm(m[3])
    for model in (kernel, numpy_):
        model.chart_from_configuration(p, m)
    for name in ("r0", "t1", "t2"):
        assert_close(getattr(kernel, name), getattr(numpy_, name))
    assert abs(kernel.t2[kernel.n_links + 2, 0]) > 0.5  # the pole branch was taken


@pytest.mark.parametrize("sleeve", [False, True])
def test_chain_wrenches_match_the_numpy_energy_gradient(sleeve):
    """The wrench system's forces and torques: -dU/dp and m_hat x -dU/dm_hat of the numpy energy."""
    rng = np.random.default_rng(21)
    chain = BallChain(n_balls=16, sleeve=Sleeve() if sleeve else None)
    p, m = random_chain_state(16, rng)
    external = FIELDS["two magnets"]()
    base = np.array([1.0, 0.1, 0.0])
    F, tau = ck.chain_wrenches(chain, p, m, external, base)
    _, dU_dp, dU_dm, _ = chain_energy_numpy(chain, p, m, external, False, base)
    assert_close(F, -dU_dp)
    assert_close(tau, np.cross(m, -dU_dm))
