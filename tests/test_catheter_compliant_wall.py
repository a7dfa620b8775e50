"""The compliant atrial wall in the catheter rod's statics (``systems.rod_wall_compliance``, issue 45,
H10): hand-solved cases on a plane wall.

* Series springs: a straight 30 mm cantilever whose tip is pressed into a plane (tilted 30 deg
  so that only the tip sphere's centre meets it) by an interference delta0 along the plane's
  normal. The rod (compliance C along n, small deflection) and the wall (k) in series:
  d = delta0 / (1 + k C), N = k d. C from the continuous cantilever, L^3 cos^2 / (3 EI) for the
  force's bending share plus nothing axial (the rod is inextensible), L the tip centre's lever.
* The wall's force is the rod's load: the compliant equilibrium's wall force applied as a tip
  force in free space gives the same rod.
* The penalty's gradient (the rod's energy gradient in the joint angles) against central finite
  differences of the energy, and the node's force against -dE/dp.
* As k grows the solution tends to the rigid wall's, with an error that falls as 1/k; k = 0 is the
  rigid statics bit for bit; the hard limit holds beyond the cap.
"""

from __future__ import annotations

import numpy as np
import pytest

from ballchain.drake_models.steerable_catheter import MAX_WALL_STIFFNESS, SteerableCatheter
from ballchain.infrastructure.errors import UserInputError
from ballchain.optimization.rod_statics import RodStatics
from ballchain.systems.rod_wall_compliance import INDENTATION_CAP, CompliantRodStatics
from test_catheter_wall_friction import Plane

AXIS = np.array([0.0, 0.0, 1.0])
LENGTH = 30e-3
BETA = np.radians(30.0)  # the plane's tilt from the rod's axis: only the tip sphere's centre meets it


def _pressed(delta0: float):
    """The straight rod's free tip and a plane that the tip centre would indent by ``delta0``."""
    cat = SteerableCatheter().validate()
    free = RodStatics(cat, np.zeros(3), AXIS).solve(LENGTH, 0.0, 0.0)
    n = np.array([-np.cos(BETA), 0.0, -np.sin(BETA)])  # into the lumen, facing the tip's side
    tip = free.pose.tip_centre
    return cat, free, n, Plane(n, -(n @ tip) + cat.radius - delta0)


@pytest.mark.parametrize("k", [100.0, 140.0, 1000.0])
def test_series_springs_against_the_cantilever_closed_form(k):
    """d = delta0 / (1 + k C), C = L^3 cos(beta)^2 / (3 EI): within 3 % (the 3 mm joints'
    discretisation of the continuous cantilever, and the small-deflection theory at 0.3 mm on
    a 29 mm lever: under 1 %), and N = k d exactly (1e-12 relative)."""
    delta0 = 0.3e-3
    cat, free, n, wall = _pressed(delta0)
    sol = CompliantRodStatics(cat, np.zeros(3), AXIS, wall, stiffness=k).solve(LENGTH, 0.0, 0.0, q0=free.q)
    assert sol.converged
    assert not sol.indentation[:-1].any() and not sol.hard_forces.any()
    lever = free.pose.tip_centre[2]  # the tip sphere's centre from the exit (the rod straight along z)
    C = lever**3 * np.cos(BETA) ** 2 / (3.0 * cat.tip_EI)
    d = sol.indentation[-1]
    assert d == pytest.approx(delta0 / (1.0 + k * C), rel=0.03)
    assert sol.wall_forces[-1] == pytest.approx(k * d, rel=1e-12)
    # The geometry: the tip moved back along n by what the wall did not take.
    moved = (sol.pose.tip_centre - free.pose.tip_centre) @ n
    assert moved + d == pytest.approx(delta0, rel=2e-3)  # the tip's path is not quite along n (0.2 %)


def test_the_wall_force_is_the_load_the_rod_carries():
    """The compliant equilibrium's wall force N n applied as a tip force with no wall: the same rod
    (tip within 1e-9 m), and the exit's axial force the wall force's share along the axis."""
    cat, free, n, wall = _pressed(0.5e-3)
    rod = CompliantRodStatics(cat, np.zeros(3), AXIS, wall, stiffness=140.0)
    sol = rod.solve(LENGTH, 0.0, 0.0, q0=free.q)
    F = sol.wall_forces[-1] * n
    loaded = RodStatics(cat, np.zeros(3), AXIS).solve(LENGTH, 0.0, 0.0, q0=free.q, force=F)
    assert np.linalg.norm(loaded.pose.tip_centre - sol.pose.tip_centre) < 1e-9
    assert sol.base_force == pytest.approx(F @ AXIS, rel=1e-9)


def test_gradient_is_the_energy_derivative():
    """The penalty's gradient against central differences of the energy (1e-6 relative), and the
    wall's force on the node against -dE/dp of k d^2 / 2 (1e-6 relative)."""
    cat, free, n, wall = _pressed(1.0e-3)
    rod = CompliantRodStatics(cat, np.zeros(3), AXIS, wall, stiffness=140.0)
    rng = np.random.default_rng(3)
    q = free.q + 1e-3 * rng.standard_normal(len(free.q))
    j0 = rod.first_free(LENGTH)

    def total(x):
        return rod.energy(x, j0, 0.0, LENGTH) + rod.wall_energy(rod.pose(x, LENGTH, 0.0))

    g = rod.gradient(q, LENGTH, 0.0, 0.0)
    eps = 1e-7
    fd = np.array([(total(q + eps * e) - total(q - eps * e)) / (2 * eps) for e in np.eye(len(q))])
    assert rod.indentation(rod.pose(q, LENGTH, 0.0))[0][-1] > 0.5e-3
    assert np.linalg.norm(g - fd) <= 1e-6 * np.linalg.norm(fd)
    # The force on the tip node: -d/dp (k d(p)^2 / 2), d = r - sdf(p).
    p = rod.pose(q, LENGTH, 0.0).tip_centre

    def node_energy(x):
        d = max(cat.radius - float(wall(x[None], gradient=False)[0]), 0.0)
        return 0.5 * rod.k * d * d

    fd_p = -np.array([(node_energy(p + eps * e) - node_energy(p - eps * e)) / (2 * eps) for e in np.eye(3)])
    f = rod.wall_reactions(rod.pose(q, LENGTH, 0.0))[-1]
    assert np.linalg.norm(f - fd_p) <= 1e-6 * np.linalg.norm(fd_p)


def test_a_stiff_wall_tends_to_the_rigid_one_as_one_over_k():
    """At k = 1e4, 1e5 and 1e6 N/m: the tip's offset from the rigid wall's within 2 N / k (the
    indentation N / k), the force within 2 N k_rod / k of the rigid wall's (k_rod its stiffness along
    n), both tolerances scaling as 1/k; and the offset falls tenfold per decade of k (5 %)."""
    cat, free, n, wall = _pressed(0.5e-3)
    rigid = RodStatics(cat, np.zeros(3), AXIS, wall).solve(LENGTH, 0.0, 0.0, q0=free.q)
    N = float(rigid.wall_forces[-1])
    k_rod = N / 0.5e-3  # the rod's stiffness along n (the rigid wall's force over its interference)
    errors = []
    for k in (1e4, 1e5, MAX_WALL_STIFFNESS):
        sol = CompliantRodStatics(cat, np.zeros(3), AXIS, wall, stiffness=k).solve(LENGTH, 0.0, 0.0, q0=free.q)
        assert sol.converged
        assert abs(sol.wall_forces[-1] - N) <= 2.0 * N * k_rod / k
        offset = np.linalg.norm(sol.pose.tip_centre - rigid.pose.tip_centre)
        assert offset <= 2.0 * N / k
        errors.append(offset)
    assert errors[0] / errors[1] == pytest.approx(10.0, rel=0.05)
    assert errors[1] / errors[2] == pytest.approx(10.0, rel=0.05)


def test_zero_stiffness_is_the_rigid_statics_bit_for_bit():
    cat, free, n, wall = _pressed(0.5e-3)
    for q0 in (None, free.q):
        rigid = RodStatics(cat, np.zeros(3), AXIS, wall).solve(LENGTH, 0.1, cat.curvature(0.4), q0=q0)
        zero = CompliantRodStatics(cat, np.zeros(3), AXIS, wall, stiffness=0.0).solve(LENGTH, 0.1, cat.curvature(0.4),
                                                                                       q0=q0)
        assert np.array_equal(rigid.q, zero.q)
        assert np.array_equal(rigid.wall_forces, zero.wall_forces)
        assert rigid.base_torque == zero.base_torque and rigid.base_force == zero.base_force


def test_the_hard_limit_holds_beyond_the_cap():
    """A wall the tip would indent by 8 mm at a soft k: the tip stops at the cap (within 1e-6 m),
    the compliant share k cap, the rest carried by the hard limit; without it (a cap beyond the
    push) the tip goes deeper."""
    cat, free, n, wall = _pressed(8e-3)
    sol = CompliantRodStatics(cat, np.zeros(3), AXIS, wall, stiffness=10.0).solve(LENGTH, 0.0, 0.0, q0=free.q)
    assert sol.converged
    assert sol.indentation[-1] == pytest.approx(INDENTATION_CAP, abs=1e-6)
    assert sol.hard_forces[-1] > 0.0
    assert sol.wall_forces[-1] == pytest.approx(sol.hard_forces[-1] + 10.0 * sol.indentation[-1], rel=1e-12)
    deep = CompliantRodStatics(cat, np.zeros(3), AXIS, wall, stiffness=10.0, cap=20e-3).solve(LENGTH, 0.0, 0.0,
                                                                                             q0=free.q)
    assert deep.indentation[-1] > INDENTATION_CAP + 1e-3


def test_wall_stiffness_is_validated():
    for bad in (-1.0, 2 * MAX_WALL_STIFFNESS, float("nan")):
        with pytest.raises(UserInputError, match="wall_stiffness"):
            SteerableCatheter(wall_stiffness=bad).validate()
    # Both together: the tip's friction on the compliant wall (H12, ``test_catheter_compliant_friction``).
    assert SteerableCatheter(wall_stiffness=100.0, wall_mu=0.2).validate().wall_mu == 0.2
    assert SteerableCatheter(wall_stiffness=140.0).validate().wall_stiffness == 140.0


def test_the_station_uses_the_compliant_wall():
    from ballchain.systems.catheter_station import SteerableCatheterSystem

    cat, free, n, wall = _pressed(1.0e-3)
    system = SteerableCatheterSystem(SteerableCatheter(wall_stiffness=140.0), np.zeros(3), AXIS, wall,
                                     initial_length=LENGTH)
    assert isinstance(system.rod, CompliantRodStatics) and system.rod.k == 140.0
    assert type(SteerableCatheterSystem(SteerableCatheter(), np.zeros(3), AXIS, wall,
                                        initial_length=LENGTH).rod) is RodStatics


def test_the_plan_presses_the_wall_by_the_target_contact_force_only_when_compliant():
    """``sheath_plan.press_depth``: 0 on the rigid wall, the target contact force's indentation
    (20 gf / k) on a compliant one, held to the cap on a soft one."""
    from ballchain.drake_models.wall_motion import CONTACT_FORCE
    from ballchain.systems.sheath_plan import press_depth

    assert press_depth(SteerableCatheter()) == 0.0
    assert press_depth(SteerableCatheter(wall_stiffness=140.0)) == pytest.approx(CONTACT_FORCE / 140.0, rel=1e-15)
    assert press_depth(SteerableCatheter(wall_stiffness=10.0)) == INDENTATION_CAP


def test_the_sheath_advanced_to_the_wall_presses_it_within_the_target_contact_force():
    """The plan's settings advanced to the wall (``SheathPlan._to_wall``, compliant wall only): the
    catheter's shortest (6 mm, straight) held by the rod's statics through the sheath's deflection
    sweep presses the wall with at most the target contact force (20 gf) in total, where the rigid
    wall takes newtons at some of them; the rigid wall's plan has none of these settings."""
    from ballchain.drake_models.atrium_sdf import atrium_sdf
    from ballchain.drake_models.sheath import SteerableSheath
    from ballchain.drake_models.wall_motion import CONTACT_FORCE
    from ballchain.experiments import manual_catheter as mc
    from ballchain.optimization.rod_statics import frame_along
    from ballchain.systems.sheath_plan import PLAN_ADVANCES, SheathPlan
    from ballchain.systems.station import atrium_for
    from ballchain.systems.target_contact import heart_targets

    heart = atrium_for(mc.scenario_for())
    sdf, sheath = atrium_sdf(heart), SteerableSheath().validate()
    axis = np.asarray(heart.sheath_axis_H, float)
    R_S = frame_along(axis)
    p_S = np.asarray(heart.p_HE, float) - sheath.nominal_advance * axis
    radius = heart_targets(heart)[3]
    grid = {sheath.nominal_advance, *PLAN_ADVANCES, sheath.max_advance}
    rigid = SheathPlan(sheath, mc.comparison_catheter(), p_S, R_S, sdf, radius, min_out=6e-3)
    assert all(c[0][0] in grid for c in rigid.candidates)
    cat = mc.comparison_catheter()
    cat.wall_stiffness = 140.0
    plan = SheathPlan(sheath, cat.validate(), p_S, R_S, sdf, radius, min_out=6e-3)
    walled = [c[0] for c in plan.candidates if c[0][0] not in grid]
    assert len(walled) >= 20
    worst = {}
    for k, model in ((140.0, CompliantRodStatics), (0.0, RodStatics)):
        c = mc.comparison_catheter()
        c.wall_stiffness = k
        rod = model(c.validate(), heart.p_HE, axis, sdf)
        worst[k] = []
        for advance, rotation, deflection in walled[::4]:
            q, most = None, 0.0
            for d in np.linspace(0.0, deflection, 7)[1:]:
                rod.p_E, rod.R_E, _ = sheath.exit_pose(p_S, R_S, advance, rotation, d)
                rod._last_pose = None
                sol = rod.solve(6e-3, 0.0, 0.0, q0=q)
                q, most = sol.q, max(most, float(sol.wall_forces.sum()))
            worst[k].append(most)
    assert max(worst[140.0]) <= CONTACT_FORCE
    assert max(worst[0.0]) > 1.0  # the same placements on the rigid wall: newtons
