"""The steerable catheter's rod statics and sheath friction against closed-form cases."""

from __future__ import annotations

import numpy as np
import pytest

from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.steerable_catheter import CoulombChain, SteerableCatheter
from ballchain.optimization.rod_statics import RodStatics

AXIS = np.array([1.0, 0.0, 0.0])


def _uniform(EI=1e-3, length=80e-3, h=2e-3):
    """A rod of one stiffness over its modelled length (the deflectable segment covering it)."""
    # A thin rod (0.02 mm): the tip sphere's centre is the rod's end within 1e-5 m.
    cat = SteerableCatheter(diameter=2e-5, lumen_diameter=1e-5, tip_EI=EI, flexural_modulus=1.0, braid_wires=0,
                            deflectable_length=length, model_length=length, segment_length=h)
    rod = RodStatics(cat, np.zeros(3), AXIS)
    rod.EI[:] = EI
    rod.GJ[:] = cat.tip_GJ
    return cat, rod


def test_cantilever_tip_deflection_matches_beam_theory():
    """A small tip force F on a clamped rod of length L: delta = F L^3 / (3 EI) (the midpoint rule's
    error is O(h^2): 4e-4 of it at 40 joints; the geometric nonlinearity (delta/L)^2 ~ 1e-6)."""
    EI, L = 1e-3, 80e-3
    cat, rod = _uniform(EI, L, 2e-3)
    F = 1e-3 * 3 * EI / L**2  # delta / L = 1e-3
    sol = rod.solve(L, 0.0, 0.0, force=[0.0, F, 0.0])
    assert sol.converged
    tip = sol.pose.tip_centre + cat.radius * sol.pose.tip_direction
    delta = tip[1]
    assert delta == pytest.approx(F * L**3 / (3 * EI), rel=2e-3)
    # The tip's slope F L^2 / (2 EI).
    assert sol.pose.tip_direction[1] == pytest.approx(F * L**2 / (2 * EI), rel=2e-3)


def test_tendon_gives_a_constant_curvature_arc():
    """A commanded curvature kappa over the whole free rod, no load: a circular arc of radius
    1 / kappa from the exit (the joints' polygon within O((kappa h)^2) of the arc)."""
    L = 60e-3
    cat, rod = _uniform(1e-3, L, 2e-3)
    kappa = np.pi / 2 / L  # a quarter turn
    sol = rod.solve(L, 0.0, kappa)
    assert sol.converged
    tip = sol.pose.tip_centre + cat.radius * sol.pose.tip_direction
    R = 1.0 / kappa
    # The arc starts along x at the origin and bends towards the sheath frame's material x.
    x_mat = rod.R_E[:, 0]
    expected = R * np.sin(kappa * L) * AXIS + R * (1 - np.cos(kappa * L)) * x_mat
    assert np.linalg.norm(tip - expected) < 1e-3 * L
    assert sol.pose.tip_direction @ x_mat == pytest.approx(1.0, abs=1e-9)  # turned by 90 degrees
    # Every node on the circle of radius R about the centre R x_mat.
    centre = R * x_mat
    radii = np.linalg.norm(sol.pose.nodes[:-1] - centre, axis=1)
    assert np.abs(radii - R).max() < 1e-3 * R


def test_torsion_of_a_straight_rod():
    """A torque T about the axis at the tip: twist T L / GJ, no bending."""
    L = 60e-3
    cat, rod = _uniform(1e-3, L, 2e-3)
    GJ = cat.tip_GJ
    T = 0.2 * GJ / L  # 0.2 rad of twist
    sol = rod.solve(L, 0.0, 0.0, torque=T * AXIS)
    assert sol.converged
    twist = sol.q.reshape(-1, 3)[:, 2].sum()
    assert twist == pytest.approx(T * L / GJ, rel=1e-9)
    assert np.abs(sol.q.reshape(-1, 3)[:, :2]).max() < 1e-12
    # The shaft's own twist at the exit turns the whole rod rigidly: the same tip frame as
    # twisting the joints by the same total.
    sol2 = rod.solve(L, T * L / GJ, 0.0)
    assert np.allclose(sol2.pose.R_tip, sol.pose.R_tip, atol=1e-9)


def test_energy_gradient_matches_finite_differences():
    """The gradient (elastic part and a tip force's virtual work) against central differences of
    E(q) - f . p_tip(q) at a generic bent and twisted configuration."""
    cat = SteerableCatheter()
    rod = RodStatics(cat, np.zeros(3), [0.3, 0.2, 1.0])
    length, phi, kappa = 70e-3, 0.4, 30.0
    j0 = rod.first_free(length)
    rng = np.random.default_rng(3)
    q = rod.rest(j0, kappa) + 0.05 * rng.standard_normal(3 * (rod.n_joints - j0))
    f = np.array([0.01, -0.02, 0.015])

    def total(x):
        return rod.energy(x, j0, kappa, length) - f @ rod.pose(x, length, phi).tip_centre

    g = rod.gradient(q, length, phi, kappa, force=f)
    eps = 1e-6
    fd = np.array([(total(q + eps * e) - total(q - eps * e)) / (2 * eps) for e in np.eye(len(q))])
    scale = np.abs(g).max()
    assert np.abs(fd - g).max() < 1e-6 * scale


def test_wall_stops_the_rod_and_pushes_back():
    """A plane wall across the tendon's arc: every node stays a radius inside, the wall pushes."""
    cat, rod = _uniform(1e-3, 60e-3, 2e-3)
    x_mat = rod.R_E[:, 0]
    wall_at = 15e-3

    def sdf(p, gradient=True, hessian=False):
        values, grads = wall_at - p @ x_mat, np.tile(-x_mat, (len(p), 1))
        return (values, grads, np.zeros((len(p), 3, 3))) if hessian else (values, grads)

    rod.sdf = sdf
    sol = rod.solve(60e-3, 0.0, np.pi / 60e-3)  # a half turn would reach 38 mm along x_mat
    assert sol.converged
    assert (wall_at - sol.pose.nodes @ x_mat).min() > cat.radius - 1e-9
    assert sol.wall_forces.max() > 0


def test_friction_windup_hand_solved():
    """One element: the handle winds it up to static / k, then each slip drops the windup to
    kinetic / k; the distal node jumps by (static - kinetic) / k (stick-slip)."""
    k, Ts, Tk = 2.0, 0.3, 0.2
    chain = CoulombChain(1, k, Ts, Tk)
    x = chain.initial()
    distal, windups = [], []
    for handle in np.linspace(0.0, 0.4, 401):
        x, _ = chain.step(x, handle)
        distal.append(x[-1])
        windups.append(chain.windup(x))
    distal, windups = np.array(distal), np.array(windups)
    # Stuck until the handle reaches Ts / k = 0.15 rad.
    first = np.flatnonzero(distal > 0)[0]
    assert np.linspace(0.0, 0.4, 401)[first] == pytest.approx(Ts / k, abs=1e-3 + 1e-12)
    # Each slip starts at the first handle step past the static limit (0.001 rad steps) and ends
    # with the windup at kinetic / k: the jump is the windup before it less kinetic / k.
    slips = np.flatnonzero(np.diff(distal) > 0) + 1
    assert len(slips) >= 4
    before = windups[slips - 1] + 0.001  # the handle moved 0.001 rad before the slip
    assert np.allclose(distal[slips] - distal[slips - 1], before - Tk / k, rtol=1e-9)
    assert np.all((before > Ts / k) & (before <= Ts / k + 0.001 + 1e-12))
    assert np.allclose(windups[slips], Tk / k, rtol=1e-9)
    assert windups.max() <= Ts / k + 1e-12
    assert windups[first] == pytest.approx(Tk / k, rel=1e-9)
    # Backwards: the windup unwinds through zero to -Ts / k before the distal node moves back.
    top = distal[-1]
    for handle in np.linspace(0.4, 0.4 - 2 * Ts / k + 0.01, 50):
        x, _ = chain.step(x, handle)
    assert x[-1] == pytest.approx(top)


def test_friction_chain_of_many_elements_holds_the_total_static_capacity():
    """n elements, plain Coulomb friction (kinetic = static): the distal end first moves when the
    handle's lead reaches the sum of the elements' stretches, element j carrying the friction of
    the n - j + 1 nodes after it: sum_i i Ts / k = n (n + 1) / 2 Ts / k."""
    n, k, Ts, Tk = 5, 4.0, 0.1, 0.1
    chain = CoulombChain(n, k, Ts, Tk)
    x = chain.initial()
    lead = n * (n + 1) / 2 * Ts / k
    for handle in np.linspace(0.0, lead * 0.999, 200):
        x, _ = chain.step(x, handle)
    assert x[-1] == 0.0
    x, _ = chain.step(x, lead * 1.001)
    assert x[-1] > 0.0


def test_catheter_constants_and_bad_input():
    cat = SteerableCatheter().validate()
    assert cat.diameter == pytest.approx(2.667e-3, rel=1e-3)
    assert cat.tip_EI == pytest.approx(4.3e-4, rel=0.01)
    assert cat.curvature(1.0) * cat.deflectable_length == pytest.approx(np.pi)
    assert cat.curvature(-1.0) * cat.deflectable_length == pytest.approx(-np.radians(120))
    with pytest.raises(UserInputError, match="mu_kinetic"):
        SteerableCatheter(mu_static=0.1, mu_kinetic=0.2).validate()
    with pytest.raises(UserInputError, match="lumen_diameter"):
        SteerableCatheter(lumen_diameter=3e-3).validate()


def test_wall_hessian_matches_finite_differences():
    """sum lam d^2 sdf(p_m(q)) / dq^2 against central differences of the rows' gradients, for a
    curved wall (a sphere's signed distance) and a bent, twisted rod."""
    cat = SteerableCatheter()
    centre, radius = np.array([0.03, 0.01, 0.0]), 0.04

    def sdf(p, gradient=True, hessian=False):
        rel = np.atleast_2d(p) - centre
        d = np.linalg.norm(rel, axis=1)
        n = rel / d[:, None]
        hess = (np.eye(3)[None] - n[:, :, None] * n[:, None, :]) / d[:, None, None]
        return (radius - d, -n, -hess) if hessian else (radius - d, -n)

    rod = RodStatics(cat, np.zeros(3), AXIS, sdf)
    length, phi = 50e-3, 0.3
    j0 = rod.first_free(length)
    q = 0.1 * np.random.default_rng(5).standard_normal(3 * (rod.n_joints - j0))
    m = len(rod.pose(q, length, phi).nodes)
    lam = np.zeros(m)
    lam[[3, m // 2, m - 1]] = [0.5, 1.0, 2.0]

    def rows_gradient(x):
        pose = rod.pose(x, length, phi)
        _, grads = sdf(pose.nodes)
        return np.einsum("m,mi,mij->j", lam, grads, pose.J)

    W = rod.wall_hessian(rod.pose(q, length, phi), lam)
    eps = 1e-6
    fd = np.array([(rows_gradient(q + eps * e) - rows_gradient(q - eps * e)) / (2 * eps) for e in np.eye(len(q))])
    assert np.abs(W - W.T).max() < 1e-12 * np.abs(W).max()
    assert np.abs(fd - W).max() < 1e-6 * np.abs(W).max()
