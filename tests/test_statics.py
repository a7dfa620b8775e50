"""Statics cross-checks: hand-solved cases, derivatives, force/torque balance, both solvers."""

import numpy as np
import pytest
from scipy.optimize import brentq

from ballchain.drake_models.chain_energy import chain_energy
from ballchain.drake_models.dipole import K_DIPOLE
from ballchain.drake_models.field_sources import MagnetSource, UniformField
from ballchain.drake_models.params import GRAVITY, BallChain, CylinderMagnet, Sleeve
from ballchain.optimization.reduced_chain import ReducedChain
from ballchain.optimization.statics import (
    ChainStatics,
    StaticsError,
    rotation_path,
    solve_statics,
    tip_angle_deg,
)

B23 = 0.023


def field(deg, magnitude=B23):
    return UniformField.in_plane(magnitude, np.radians(deg))


def rotate_to(chain, deg, step=22.5, **kw):
    solver = ChainStatics(chain, **kw)
    return solver.continuation([field(a) for a in rotation_path(0.0, deg, step)])[-1]


@pytest.mark.parametrize("theta_deg", [30.0, 90.0, 150.0])
def test_two_balls_match_hand_solution(theta_deg):
    """Ball 2 at angle phi with dipole at psi: dU/dphi = 0 gives psi = 2 phi, then
    (k M^2 / 2 d^3) sin(2 phi) + M B sin(2 phi - theta) = 0."""
    chain = BallChain(n_balls=2)
    M, d, theta = chain.dipole_moment, chain.ball_diameter, np.radians(theta_deg)
    k = K_DIPOLE * M**2 / d**3
    phi = brentq(lambda f: 0.5 * k * np.sin(2 * f) + M * B23 * np.sin(2 * f - theta), 1e-9, theta / 2)
    result = rotate_to(chain, theta_deg)
    assert result.converged
    np.testing.assert_allclose(result.positions[1], d * np.array([np.cos(phi), np.sin(phi), 0]), atol=1e-12)
    np.testing.assert_allclose(result.dipoles[1], [np.cos(2 * phi), np.sin(2 * phi), 0], atol=1e-9)


def test_straight_chain_in_aligned_field_is_the_equilibrium_with_hand_energy():
    chain = BallChain(n_balls=7)
    result = ChainStatics(chain).solve(field(0.0))
    assert result.converged
    d, M, n = chain.ball_diameter, chain.dipole_moment, chain.n_balls
    np.testing.assert_allclose(result.positions[:, 0], d * np.arange(n), atol=1e-15)
    pair = sum(-2 * K_DIPOLE * M**2 / (d * (j - i)) ** 3 for i in range(n) for j in range(i + 1, n))
    np.testing.assert_allclose(result.terms.balls, pair, rtol=1e-12)
    np.testing.assert_allclose(result.terms.external, -n * M * B23, rtol=1e-12)


@pytest.mark.parametrize("sleeve", [False, True])
def test_reduced_derivatives_match_finite_differences(sleeve):
    rng = np.random.default_rng(3)
    chain = BallChain(n_balls=6, sleeve=Sleeve() if sleeve else None)
    magnet = MagnetSource.pointing(CylinderMagnet(), [0.02, 0.16, 0.03], [0.3, 1.0, 0.2])
    model = ReducedChain(chain, magnet, gravity=True)
    model.set_chart(rng.normal(size=(model.n_vectors, 3)))
    q = rng.normal(size=model.nq) * 0.05
    ev = model.evaluate(q, 2)
    h = 1e-6
    E = np.eye(model.nq)
    g_fd = np.array([(model.evaluate(q + h * e, 0).energy - model.evaluate(q - h * e, 0).energy) / (2 * h) for e in E])
    H_fd = np.array([(model.evaluate(q + h * e, 1).gradient - model.evaluate(q - h * e, 1).gradient) / (2 * h) for e in E])
    J_fd = np.array([(model.evaluate(q + h * e, 0).gaps - model.evaluate(q - h * e, 0).gaps) / (2 * h) for e in E]).T
    np.testing.assert_allclose(ev.gradient, g_fd, atol=1e-7 * np.abs(g_fd).max())
    np.testing.assert_allclose(ev.hessian, H_fd, atol=1e-6 * np.abs(H_fd).max())
    np.testing.assert_allclose(ev.jacobian, J_fd, atol=1e-7)
    np.testing.assert_allclose(ev.hessian, ev.hessian.T, atol=1e-10 * np.abs(H_fd).max())


def _ball_forces_and_torques(chain, result, external, gravity=False):
    """Total force and torque on every ball from the energy's gradient (one source of truth)."""
    _, dU_dp, dU_dm, _ = chain_energy(chain, result.positions, result.dipoles, external, gravity)
    return -dU_dp, np.cross(result.dipoles, -dU_dm)


@pytest.mark.parametrize("n_balls,deg,gravity", [(8, 90.0, False), (12, 135.0, True), (16, 180.0, False)])
def test_equilibrium_balances_forces_and_moments_on_every_sub_chain(n_balls, deg, gravity):
    """Frictionless spheres in contact push along the line of centres, so for every k the
    field forces and torques on balls k+1..n have zero moment about the centre of ball k, and
    every free dipole feels no torque."""
    chain = BallChain(n_balls=n_balls)
    ext = field(deg)
    solver = ChainStatics(chain, gravity=gravity)
    result = solver.continuation([field(a) for a in rotation_path(0, deg, 22.5)])[-1]
    assert result.converged and not result.pair_forces
    F, tau = _ball_forces_and_torques(chain, result, ext, gravity)
    scale = 6 * K_DIPOLE * chain.dipole_moment**2 / chain.ball_diameter**4 * chain.ball_diameter
    np.testing.assert_allclose(tau[1:], 0.0, atol=1e-8 * scale)
    p = result.positions
    for k in range(n_balls - 1):
        moment = np.sum(np.cross(p[k + 1 :] - p[k], F[k + 1 :]) + tau[k + 1 :], axis=0)
        np.testing.assert_allclose(moment, 0.0, atol=1e-8 * scale)
    # Newton's third law inside the chain: internal forces cancel, so the net force on the
    # whole chain is the external (here uniform: zero) field force plus gravity.
    weight = np.array([0.0, 0.0, -GRAVITY * chain.ball_mass * n_balls]) if gravity else np.zeros(3)
    np.testing.assert_allclose(F.sum(axis=0), weight, atol=1e-10 * scale)


def test_newton_and_snopt_reach_the_same_minimum():
    chain = BallChain(n_balls=6)
    newton = rotate_to(chain, 90.0, method="newton")
    snopt = rotate_to(chain, 90.0, method="snopt")
    assert newton.converged and snopt.converged
    np.testing.assert_allclose(newton.positions, snopt.positions, atol=1e-7)
    np.testing.assert_allclose(newton.energy, snopt.energy, rtol=1e-9)


def test_cold_start_in_antiparallel_field_leaves_the_saddle():
    """The straight chain in a field along -x is an equilibrium, but unstable: the solver must
    not report it as converged."""
    chain = BallChain(n_balls=6)
    result = ChainStatics(chain).solve(field(180.0))
    assert result.converged
    assert np.linalg.norm(result.positions[-1, 1:]) > chain.ball_diameter
    straight = ChainStatics(chain).solve(field(0.0))
    E_straight, _, _, _ = chain_energy(chain, straight.positions, straight.dipoles, field(180.0))
    assert result.energy < E_straight


def test_gravity_sags_the_chain_and_costs_energy_in_the_right_direction():
    chain = BallChain(n_balls=16)
    sagging = rotate_to(chain, 90.0, gravity=True)
    assert sagging.converged
    assert sagging.positions[-1, 2] < -1e-6  # gravity along -z pulls the tip down
    assert sagging.terms.gravity < 0.0
    flat = rotate_to(chain, 90.0)
    # A ball weighs 1/1800 of the pair attraction, but the 16-ball lever sags a few mm
    # (3.2 mm measured): small against the chain's 50.8 mm, and the plan view barely moves.
    assert abs(sagging.positions[-1, 2]) < 0.1 * chain.length
    np.testing.assert_allclose(sagging.positions[:, :2], flat.positions[:, :2], atol=0.05 * chain.length)


def test_sleeve_stiffens_the_chain():
    bare = rotate_to(BallChain(n_balls=10), 90.0)
    sleeved = rotate_to(BallChain(n_balls=10, sleeve=Sleeve()), 90.0)
    stiff = rotate_to(BallChain(n_balls=10, sleeve=Sleeve(youngs_modulus=1.5e6)), 90.0)
    assert sleeved.converged and stiff.converged
    assert sleeved.terms.sleeve > 0.0
    # Bending less: the tip ends up further along the insertion axis.
    assert bare.positions[-1, 0] < sleeved.positions[-1, 0] < stiff.positions[-1, 0]


def test_folded_chain_contact_force_balances_the_tip():
    """Three balls in an antiparallel field fold into a triangle: ball 3 rests on ball 1. The
    rigidity multiplier is that contact force: with it, the tip's field force must point along
    the line to ball 2 (the only other push on a frictionless tip), and the tip feel no torque."""
    chain = BallChain(n_balls=3)
    result = rotate_to(chain, 180.0)
    assert result.converged
    assert set(result.pair_forces) == {(0, 2)}
    p = result.positions
    np.testing.assert_allclose(np.linalg.norm(p[2] - p[0]), chain.ball_diameter, rtol=1e-9)
    F, tau = _ball_forces_and_torques(chain, result, field(180.0))
    n02 = (p[2] - p[0]) / chain.ball_diameter
    n12 = (p[2] - p[1]) / chain.ball_diameter
    push = F[2] + result.pair_forces[(0, 2)] * n02
    # 1e-6 relative: the solver stops at a scaled KKT residual of 1e-8..1e-6.
    np.testing.assert_allclose(np.cross(push, n12), 0.0, atol=1e-6 * np.linalg.norm(F[2]))
    assert result.pair_forces[(0, 2)] > 0.1  # a real push (about 1 N), not round-off
    torque_scale = K_DIPOLE * chain.dipole_moment**2 / chain.ball_diameter**3
    np.testing.assert_allclose(tau[1:], 0.0, atol=1e-6 * torque_scale)


@pytest.mark.parametrize("offset_mm", [(1.0, 0.0, 0.0), (-3.0, 2.0, 0.0), (0.0, -2.0, 1.5)])
def test_tip_held_on_a_target_reaction_balances_the_chain(offset_mm):
    """The tip multiplier is the target's push: with it added to the tip's forces, the field
    forces and torques on every sub-chain have zero moment about the ball before it."""
    chain = BallChain(n_balls=10)
    ext = field(90.0)
    solver = ChainStatics(chain)
    free = rotate_to(chain, 90.0)
    pinned_in_place = solver.solve(ext, free, tip_target=free.tip_position)
    assert pinned_in_place.converged
    np.testing.assert_allclose(pinned_in_place.tip_reaction, 0.0, atol=1e-9)
    target = free.tip_position + 1e-3 * np.array(offset_mm)
    result = solver.solve(ext, free, tip_target=target)
    assert result.converged
    np.testing.assert_allclose(result.tip_position, target, atol=1e-12)
    assert np.linalg.norm(result.tip_reaction) > 1e-3  # a real push, N
    F, tau = _ball_forces_and_torques(chain, result, ext)
    F[-1] += result.tip_reaction
    p = result.positions
    scale = np.abs(F).max() * chain.ball_diameter
    for k in range(chain.n_balls - 1):
        moment = np.sum(np.cross(p[k + 1 :] - p[k], F[k + 1 :]) + tau[k + 1 :], axis=0)
        np.testing.assert_allclose(moment, 0.0, atol=1e-9 * scale)


def test_failure_is_reported_not_hidden():
    chain = BallChain(n_balls=10)
    solver = ChainStatics(chain, max_iterations=1)
    result = solver.solve(field(90.0))
    assert not result.converged
    assert "iteration limit" in result.reason
    with pytest.raises(StaticsError, match="did not converge"):
        ChainStatics(chain, max_iterations=1).solve_or_raise(field(90.0))


def test_bad_input_is_rejected():
    with pytest.raises(ValueError, match="n_balls"):
        BallChain(n_balls=0)
    with pytest.raises(ValueError, match="n_balls"):
        BallChain(n_balls=-3)
    with pytest.raises(ValueError, match="finite"):
        UniformField([np.nan, 0, 0])
    with pytest.raises(ValueError, match="warm start"):
        ChainStatics(BallChain(n_balls=4)).solve(field(0.0), ChainStatics(BallChain(n_balls=3)).solve(field(0.0)))
    with pytest.raises(ValueError, match="inside"):
        # A magnet placed on the chain.
        solve_statics(BallChain(n_balls=3), MagnetSource.pointing(CylinderMagnet(), [0.003, 0, 0], [1, 0, 0]))


def test_long_chains_align_their_tip_with_the_field():
    """The paper's premise: beyond about 10 balls the tip dipole follows the field."""
    for n in (12, 16):
        result = rotate_to(BallChain(n_balls=n), 90.0)
        assert tip_angle_deg(result, [0, 1, 0]) < 1.4


def test_wall_forces_balance_the_chain_and_keep_it_out():
    chain = BallChain(n_balls=8)
    wall = (np.array([0.0, 0.012, 0.0]), np.array([0.0, -1.0, 0.0]))
    solver = ChainStatics(chain)
    result = None
    for angle in rotation_path(0.0, 90.0, 22.5):
        result = solver.solve_or_raise(field(angle), result, wall=wall)
    p = result.positions
    assert np.all((p[1:] - wall[0]) @ wall[1] >= 0.5 * chain.ball_diameter - 1e-12)
    assert list(result.wall_forces) == [7] and result.wall_forces[7] > 0.05  # the tip pushes, N
    F, tau = _ball_forces_and_torques(chain, result, field(90.0))
    F[7] += result.wall_forces[7] * wall[1]
    scale = np.abs(F).max() * chain.ball_diameter
    for k in range(chain.n_balls - 1):
        moment = np.sum(np.cross(p[k + 1 :] - p[k], F[k + 1 :]) + tau[k + 1 :], axis=0)
        # 1e-7: the solver stops at a scaled KKT residual of 1e-8 (6e-9 relative seen here).
        np.testing.assert_allclose(moment, 0.0, atol=1e-7 * scale)
    with pytest.raises(ValueError, match="cuts ball 1"):
        solver.solve(field(0.0), wall=(np.array([0.001, 0, 0]), np.array([1.0, 0, 0])))


def test_uniform_field_equilibrium_turns_the_field_from_x():
    from ballchain.optimization.statics import uniform_field_equilibrium

    chain = BallChain(n_balls=6)
    planar = uniform_field_equilibrium(chain, [0.0, 0.023, 0.0])
    np.testing.assert_allclose(planar.positions, rotate_to(chain, 90.0).positions, atol=1e-9)
    # Out of plane: the same shape turned about x into the x-z plane.
    tilted = uniform_field_equilibrium(chain, [0.0, 0.0, 0.023])
    np.testing.assert_allclose(tilted.positions[:, [0, 2]], planar.positions[:, [0, 1]], atol=1e-9)
    np.testing.assert_allclose(tilted.positions[:, 1], 0.0, atol=1e-12)
