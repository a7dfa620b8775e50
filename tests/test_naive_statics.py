"""The SLSQP baseline (optimization.naive_statics): its derivatives, and that it reaches the same
minimum as ChainStatics (the reduced-coordinate Newton SQP)."""

import numpy as np
import pytest

from ballchain.experiments.statics_bench import blas_threads
from ballchain.drake_models.chain_energy import chain_energy
from ballchain.drake_models.field_sources import UniformField
from ballchain.drake_models.params import BallChain, Sleeve
from ballchain.optimization.naive_statics import NaiveStatics, solve_naive_statics
from ballchain.optimization.statics import ChainStatics

FIELD_T = 23e-3


@pytest.fixture(autouse=True, scope="module")
def _one_blas_thread():
    # Small dense problems: threaded BLAS only slows them down (and the CI shares 2 cores).
    with blas_threads(1):
        yield


def _random_x(problem: NaiveStatics, seed: int = 0) -> np.ndarray:
    """A generic point: perturbed straight chain, dipoles of non-unit length in all directions."""
    rng = np.random.default_rng(seed)
    n, d = problem.n, problem.d
    p = np.arange(n)[:, None] * d * np.array([1.0, 0.0, 0.0]) + 0.2 * d * rng.standard_normal((n, 3))
    m = rng.standard_normal((n, 3))
    return problem.pack(p, m)


def _central_differences(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    cols = []
    for k in range(len(x)):
        e = np.zeros_like(x)
        e[k] = h
        cols.append((np.atleast_1d(f(x + e)) - np.atleast_1d(f(x - e))) / (2 * h))
    return np.array(cols).T


@pytest.mark.parametrize("sleeve", [None, Sleeve()])
def test_constraint_jacobians_and_gradient_match_finite_differences(sleeve):
    chain = BallChain(n_balls=6, sleeve=sleeve)
    problem = NaiveStatics(chain, UniformField.in_plane(FIELD_T, np.radians(70.0)), gravity=True)
    x = _random_x(problem)
    # The constraints are quadratics in O(1) variables: central differences are exact up to
    # round-off (~1e-10 here).
    J_eq = problem.equality_jacobian(x)
    J_in = problem.inequality_jacobian(x)
    assert J_eq.shape == (2 * 5, problem.nx)
    assert J_in.shape == (len(problem.pair_i), problem.nx) == (10, problem.nx)
    np.testing.assert_allclose(J_eq, _central_differences(problem.equalities, x), rtol=0, atol=1e-8)
    np.testing.assert_allclose(J_in, _central_differences(problem.inequalities, x), rtol=0, atol=1e-8)
    # The scaled objective: O(1) values, central-difference truncation error O(h^2).
    _, grad = problem.objective(x)
    fd = _central_differences(lambda y: problem.objective(y)[0], x)[0]
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-7 * np.abs(fd).max())


def test_objective_is_the_chain_energy_and_ignores_dipole_length():
    chain = BallChain(n_balls=5)
    external = UniformField.in_plane(FIELD_T, np.radians(40.0))
    problem = NaiveStatics(chain, external)
    x = _random_x(problem, seed=3)
    p, m_hat = problem.configuration(x)
    U = chain_energy(chain, p, m_hat, external)[0]
    f, grad = problem.objective(x)
    assert f * problem.energy_scale == pytest.approx(U, rel=1e-14)
    # Normalised dipoles: scaling any m_i changes nothing, so the gradient is orthogonal to m_i.
    _, M = problem.unpack(x)
    g_m = grad[3 * problem.nf :].reshape(problem.nf, 3)
    np.testing.assert_allclose(np.einsum("ij,ij->i", g_m, M[1:]), 0.0, atol=1e-12 * np.abs(g_m).max())
    # E0 is the energy of two touching coaxial balls.
    pair = BallChain(n_balls=2)
    p2 = np.array([[0.0, 0.0, 0.0], [pair.ball_diameter, 0.0, 0.0]])
    U2 = chain_energy(pair, p2, np.tile([1.0, 0.0, 0.0], (2, 1)))[0]
    assert NaiveStatics(pair, None).energy_scale == pytest.approx(-U2, rel=1e-12)


def test_constraints_vanish_on_the_straight_chain():
    problem = NaiveStatics(BallChain(n_balls=7), None)
    n, d = problem.n, problem.d
    x = problem.pack(np.arange(n)[:, None] * d * np.array([1.0, 0.0, 0.0]), np.tile([1.0, 0.0, 0.0], (n, 1)))
    np.testing.assert_allclose(problem.equalities(x), 0.0, atol=1e-14)  # x / d round-off
    gaps = problem.inequalities(x)  # |j - i|^2 - 1 for j >= i + 2
    np.testing.assert_allclose(gaps, (problem.pair_j - problem.pair_i) ** 2 - 1.0, atol=1e-12)


@pytest.mark.parametrize("n_balls", [5, 8])
@pytest.mark.parametrize("angle_deg", [60.0, 90.0])
def test_baseline_reaches_the_newton_minimum(n_balls, angle_deg):
    chain = BallChain(n_balls=n_balls)
    external = UniformField.in_plane(FIELD_T, np.radians(angle_deg))
    newton = ChainStatics(chain).solve(external)
    baseline = solve_naive_statics(chain, external)
    assert newton.converged, newton.reason
    assert baseline.success, baseline.message
    assert baseline.max_violation < 1e-10
    # The same minimum: tip within 1e-6 m (measured: < 2e-8 m), energy within 1e-10 relative
    # (measured: < 1e-12), every ball within 1e-6 m, and the dipoles.
    np.testing.assert_allclose(baseline.tip_position, newton.tip_position, rtol=0, atol=1e-6)
    assert baseline.energy == pytest.approx(newton.energy, rel=1e-10)
    np.testing.assert_allclose(baseline.positions, newton.positions, rtol=0, atol=1e-6)
    np.testing.assert_allclose(baseline.dipoles, newton.dipoles, rtol=0, atol=1e-4)
    # Ball 1 held at the origin along +x; unit dipoles; adjacent balls touch.
    np.testing.assert_array_equal(baseline.positions[0], 0.0)
    np.testing.assert_array_equal(baseline.dipoles[0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(np.linalg.norm(baseline.dipoles, axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(np.diff(baseline.positions, axis=0), axis=1),
                               chain.ball_diameter, rtol=1e-9)
    # The baseline is a quasi-Newton method: it needs many more iterations than Newton.
    assert baseline.iterations > 5 * newton.iterations


def test_baseline_with_sleeve_and_gravity_reaches_the_newton_minimum():
    chain = BallChain(n_balls=5, sleeve=Sleeve())
    external = UniformField.in_plane(FIELD_T, np.radians(90.0))
    newton = ChainStatics(chain, gravity=True).solve(external)
    baseline = solve_naive_statics(chain, external, gravity=True)
    assert newton.converged and baseline.success
    assert newton.tip_position[2] < -1e-4  # sags under gravity
    np.testing.assert_allclose(baseline.tip_position, newton.tip_position, rtol=0, atol=1e-6)
    assert baseline.energy == pytest.approx(newton.energy, rel=1e-10)


def test_needs_two_balls():
    with pytest.raises(ValueError, match="at least 2 balls"):
        NaiveStatics(BallChain(n_balls=1), None)
    with pytest.raises(ValueError, match="both positions and dipoles"):
        NaiveStatics(BallChain(n_balls=3), None).solve(positions=np.zeros((3, 3)))
