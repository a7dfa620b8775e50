"""The tip's Coulomb friction on the compliant wall (``rod_wall_friction.CompliantFrictionalRodStatics``,
issue 45, H12): the friction cone on the penalty's normal force N = k d, hand-solved on a plane.

A bent cantilever whose tip is pressed into a compliant plane (its free tip 3 mm beyond it), then
loaded at the tip along the plane: while the tip sticks the wall's stick rows take the whole load
at the loaded node, so the rod cannot change (tip, indentation and N = k d as before) for
F_t <= mu N; beyond it the tip slips with the wall's friction mu N against the slip, N the
penalty's k d at the slipped tip.
"""

from __future__ import annotations

import numpy as np
import pytest

from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.optimization.rod_statics import RodStatics
from ballchain.systems.catheter_station import SteerableCatheterSystem
from ballchain.systems.rod_wall_compliance import CompliantRodStatics
from ballchain.systems.rod_wall_friction import (CompliantFrictionalRodStatics, FrictionalRodStatics,
                                                 rod_statics_class)
from tests.test_catheter_wall_friction import AXIS, Plane, held_within_the_cone

MU, K = 0.2, 140.0


@pytest.fixture(scope="module")
def pressed():
    cat = SteerableCatheter(wall_mu=MU, wall_stiffness=K).validate()
    length, kappa = 40e-3, cat.curvature(0.5)
    free = RodStatics(cat, np.zeros(3), AXIS).solve(length, 0.0, kappa)
    tip = free.pose.tip_centre
    n = -np.array([tip[0], tip[1], 0.0]) / np.hypot(tip[0], tip[1])
    wall = Plane(n, -(n @ tip) - 3e-3 + cat.radius)
    rod = CompliantFrictionalRodStatics(cat, np.zeros(3), AXIS, wall)
    sol = rod.solve(length, 0.0, kappa, q0=free.q)
    assert sol.converged and sol.indentation[-1] > 0.1e-3 and not sol.hard_forces.any()
    assert sol.wall_forces[-1] == pytest.approx(K * sol.indentation[-1], rel=1e-9)  # N = k d
    # The same as the frictionless compliant wall on the first touch (nothing stuck yet).
    plain = CompliantRodStatics(cat, np.zeros(3), AXIS, wall).solve(length, 0.0, kappa, q0=free.q)
    assert np.linalg.norm(plain.pose.tip_centre - sol.pose.tip_centre) < 1e-9
    return cat, rod, sol, length, kappa, n


@pytest.mark.parametrize("t_name", ["axial", "lateral"])
def test_the_cone_on_the_penalty_s_normal_force(pressed, t_name):
    cat, rod, rest, length, kappa, n = pressed
    rod.anchors, rod.last_nodes = rest.anchors, rest.last_nodes
    N0 = float(rest.wall_forces[-1])
    t = AXIS if t_name == "axial" else np.cross(n, AXIS)
    assert abs(t @ n) < 1e-12
    for sol in held_within_the_cone(rod, rest, length, kappa, t, N0, MU):  # the penalty's N0 as the rigid wall's
        assert sol.indentation[-1] == pytest.approx(rest.indentation[-1], rel=1e-6)
    for frac in (1.02, 1.5):  # beyond it: slips along t, the friction mu k d against the slip
        sol = rod.solve(length, 0.0, kappa, q0=rest.q, force=frac * MU * N0 * t)
        assert sol.converged
        slip = sol.pose.tip_centre - rest.pose.tip_centre
        assert slip @ t > 1e-8
        N = K * sol.indentation[-1]
        assert sol.wall_forces[-1] == pytest.approx(N, rel=1e-9)
        assert np.linalg.norm(sol.friction[-1]) == pytest.approx(MU * N, rel=2e-3)
        assert sol.friction[-1] @ slip < 0
        assert abs(sol.friction[-1] @ n) < 1e-9


def test_the_catheter_s_wall_picks_its_statics(pressed):
    """Each combination of ``wall_mu`` and ``wall_stiffness`` its own statics, the station's too."""
    for mu, k, cls in ((0.0, 0.0, RodStatics), (MU, 0.0, FrictionalRodStatics), (0.0, K, CompliantRodStatics),
                       (MU, K, CompliantFrictionalRodStatics)):
        assert rod_statics_class(SteerableCatheter(wall_mu=mu, wall_stiffness=k).validate()) is cls
    cat = pressed[0]
    system = SteerableCatheterSystem(cat, np.zeros(3), AXIS, None, 20e-3)
    assert type(system.rod) is CompliantFrictionalRodStatics
