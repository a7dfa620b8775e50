"""Coulomb friction where the catheter's rod touches the wall (``systems.rod_wall_friction``, issue
45): hand-solved cases on a plane wall.

* A bent cantilever whose tip rests on a plane, then loaded at the tip along the plane: while the
  tip sticks the rod's state cannot change (the wall takes the whole load), so the tip holds
  exactly while F_t <= mu N0 and slips beyond it, where the wall's friction is mu N against the
  slip.
* A rod pushed into a plane it meets at an incidence alpha (the reaction along the rod's axis):
  it catches when tan(alpha) < mu (the tip held, the rod buckling behind it at about its Euler
  load) and slides when tan(alpha) > mu, as on the frictionless wall.
"""

from __future__ import annotations

import numpy as np
import pytest

from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.infrastructure.errors import UserInputError
from ballchain.optimization.rod_statics import RodStatics
from ballchain.systems.rod_wall_friction import FrictionalRodStatics, tangent_basis

AXIS = np.array([0.0, 0.0, 1.0])
MU = 0.2


class Plane:
    """sdf(p) = n . p + c (n the unit normal into the lumen), gradient n, no curvature."""

    def __init__(self, n, c: float) -> None:
        self.n, self.c = np.asarray(n, float) / np.linalg.norm(n), float(c)

    def __call__(self, p, gradient: bool = True, hessian: bool = False):
        p = np.atleast_2d(p)
        v = p @ self.n + self.c
        if not gradient and not hessian:
            return v
        g = np.tile(self.n, (len(p), 1))
        return (v, g, np.zeros((len(p), 3, 3))) if hessian else (v, g)


def _step(rod, sol):
    """The next update's contact state from ``sol`` (what the catheter's state keeps)."""
    rod.anchors, rod.last_nodes = sol.anchors, sol.last_nodes


@pytest.fixture(scope="module")
def resting():
    """A 40 mm rod at half knob whose tip rests on a plane (the free tip 3 mm beyond it)."""
    cat = SteerableCatheter(wall_mu=MU).validate()
    length, kappa = 40e-3, cat.curvature(0.5)
    free = RodStatics(cat, np.zeros(3), AXIS).solve(length, 0.0, kappa)
    tip = free.pose.tip_centre
    n = -np.array([tip[0], tip[1], 0.0]) / np.hypot(tip[0], tip[1])  # facing the bend
    wall = Plane(n, -(n @ tip) - 3e-3 + cat.radius)
    rod = FrictionalRodStatics(cat, np.zeros(3), AXIS, wall)
    sol = rod.solve(length, 0.0, kappa, q0=free.q)
    assert sol.converged and sol.wall_forces[-1] > 0.1 and not sol.wall_forces[:-1].any()
    return cat, rod, sol, length, kappa, n


def held_within_the_cone(rod, rest, length, kappa, t, N0, mu):
    """The tip pushed along t with half and 0.98 of mu N0 from the resting solve ``rest``: held
    (the rod unchanged within 1e-9 m), the friction the push's opposite and the normal force N0;
    returns the two solves."""
    sols = []
    for frac in (0.5, 0.98):  # below the cone: held, the wall takes the load, the rod unchanged
        F = frac * mu * N0
        sol = rod.solve(length, 0.0, kappa, q0=rest.q, force=F * t)
        assert sol.converged
        assert np.linalg.norm(sol.pose.tip_centre - rest.pose.tip_centre) < 1e-9
        assert np.allclose(sol.friction[-1], -F * t, atol=1e-6 * N0)
        assert sol.wall_forces[-1] == pytest.approx(N0, rel=1e-6)
        sols.append(sol)
    return sols


@pytest.mark.parametrize("t_name", ["axial", "lateral"])
def test_tip_sticks_up_to_mu_times_the_normal_force_and_slips_beyond(resting, t_name):
    cat, rod, rest, length, kappa, n = resting
    _step(rod, rest)
    N0 = float(rest.wall_forces[-1])
    t = AXIS if t_name == "axial" else np.cross(n, AXIS)
    assert abs(t @ n) < 1e-12
    for sol in held_within_the_cone(rod, rest, length, kappa, t, N0, MU):
        assert sol.anchors[rod.n_joints] == pytest.approx(rest.anchors[rod.n_joints], abs=1e-15)
    for frac in (1.02, 1.5):  # beyond it: slips along t, the friction mu N against the slip
        sol = rod.solve(length, 0.0, kappa, q0=rest.q, force=frac * MU * N0 * t)
        assert sol.converged
        slip = sol.pose.tip_centre - rest.pose.tip_centre
        assert slip @ t > 1e-8
        assert np.linalg.norm(sol.friction[-1]) == pytest.approx(MU * sol.wall_forces[-1], rel=2e-3)
        assert sol.friction[-1] @ slip < 0
        assert abs(sol.friction[-1] @ n) < 1e-9
        assert np.linalg.norm(sol.anchors[rod.n_joints] - sol.pose.tip_centre) < 1e-12  # sticks where it ended


def test_tip_caught_on_a_steep_wall_and_sliding_on_a_shallow_one():
    """A rod (knob 0.1, 30 mm) pushed 1 mm in 0.2 mm steps into a plane facing its tip, tilted
    by alpha: tan(alpha) = mu / 2 catches it (held within 1e-8 m while the rod buckles at its
    Euler load, pi^2 EI / (0.7 L)^2 for a clamped-pinned column: several N), tan(alpha) = 2 mu
    slides it as the frictionless wall does."""
    length = 30e-3
    moved = {}
    for ratio in (0.5, 2.0):
        for mu in (0.0, MU):
            cat = SteerableCatheter(wall_mu=mu).validate()
            kappa = cat.curvature(0.1)
            free = RodStatics(cat, np.zeros(3), AXIS).solve(length, 0.0, kappa)
            d = free.pose.tip_direction
            side = np.cross(d, [1.0, 0.0, 0.0])
            side /= np.linalg.norm(side)
            alpha = np.arctan(ratio * MU)
            n = -np.cos(alpha) * d + np.sin(alpha) * side
            wall = Plane(n, -(n @ free.pose.tip_centre) + cat.radius)
            rod = FrictionalRodStatics(cat, np.zeros(3), AXIS, wall)
            sol = rod.solve(length, 0.0, kappa, q0=free.q)
            _step(rod, sol)
            start = sol.pose.tip_centre.copy()
            for k in range(1, 6):
                sol = rod.solve(length + k * 0.2e-3, 0.0, kappa, q0=sol.q)
                assert sol.converged
                _step(rod, sol)
            moved[ratio, mu] = (np.linalg.norm(sol.pose.tip_centre - start), float(sol.wall_forces[-1]),
                                np.linalg.norm(sol.friction[-1]))
    held, force, friction = moved[0.5, MU]
    assert held < 1e-8
    euler = np.pi**2 * SteerableCatheter().tip_EI / (0.7 * length) ** 2
    assert 0.5 * euler < force < 1.5 * euler
    assert friction <= MU * force * (1 + 1e-9)
    assert moved[0.5, 0.0][0] > 1e-3  # frictionless: it slides a mm
    assert moved[2.0, MU][0] > 1e-3 and moved[2.0, MU][0] == pytest.approx(moved[2.0, 0.0][0], rel=0.01)


def test_no_friction_is_the_frictionless_statics():
    """wall_mu 0: the same joint angles, bit for bit, as RodStatics."""
    cat = SteerableCatheter().validate()
    wall = Plane([0.0, 1.0, 0.0], 8e-3)
    a = RodStatics(cat, np.zeros(3), AXIS, wall).solve(60e-3, 0.3, cat.curvature(1.0))
    b = FrictionalRodStatics(cat, np.zeros(3), AXIS, wall).solve(60e-3, 0.3, cat.curvature(1.0))
    assert a.wall_forces.any()
    assert np.array_equal(a.q, b.q) and a.base_torque == b.base_torque and b.anchors == {}


def test_tangent_basis_and_bad_coefficient():
    for n in ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.3, -0.4, 0.5]):
        T = tangent_basis(n)
        assert np.allclose(T @ T.T, np.eye(2), atol=1e-12) and np.allclose(T @ n, 0.0, atol=1e-12)
    with pytest.raises(UserInputError, match="wall_mu"):
        SteerableCatheter(wall_mu=-0.1).validate()


def test_the_catheter_keeps_its_tip_stuck_between_updates():
    """The catheter system's state carries the anchors from one update to the next (its copy
    too): pushed 0.2 mm a step into a plane facing its tip (tilted by tan(alpha) = mu / 2, where
    the rod's statics hold it, above), the tip stays where it first stuck while the rod bows."""
    import copy

    from ballchain.systems.catheter_station import SteerableCatheterSystem

    cat = SteerableCatheter(wall_mu=MU).validate()
    length, knob = 30e-3, 0.1
    free = RodStatics(cat, np.zeros(3), AXIS).solve(length, 0.0, cat.curvature(knob))
    d = free.pose.tip_direction
    side = np.cross(d, [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    alpha = np.arctan(0.5 * MU)
    n = -np.cos(alpha) * d + np.sin(alpha) * side
    wall = Plane(n, -(n @ free.pose.tip_centre) + cat.radius - 0.1e-3)
    system = SteerableCatheterSystem(cat, np.zeros(3), AXIS, wall, initial_length=length)
    st = system._start()
    system._solve(st, 0.0, 0.0, knob)
    tip = system.rod.n_joints
    first = st.anchors[tip].copy()
    clone = copy.deepcopy(st)
    assert clone.anchors is not st.anchors and np.array_equal(clone.anchors[tip], first)
    for k in range(1, 5):
        system._solve(st, k * 0.2e-3, 0.0, knob)
        assert np.linalg.norm(st.nodes[-1] - first) < 1e-8
        assert np.array_equal(st.anchors[tip], first)
