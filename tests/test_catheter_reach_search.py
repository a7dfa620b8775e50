"""The catheter's local reach search (``manual_catheter.reach_search``) and the distance from a
touch it minimises (``touch_miss``)."""

from __future__ import annotations

import numpy as np
import pytest

from ballchain.experiments import manual_catheter as mc
from ballchain.systems.target_contact import TOUCH_TOLERANCE, targets_touched


def test_touch_miss_is_zero_exactly_where_the_touch_test_touches():
    """Random tip centres around a tilted target: the miss is 0 where ``targets_touched`` says it
    touches, positive elsewhere; straight above the centre it is the height beyond the touch, and
    level with the wall beside the circle the lateral distance beyond it."""
    rng = np.random.default_rng(3)
    n = np.array([[0.3, -0.2, 0.9]])
    n /= np.linalg.norm(n)
    p_T = np.array([[0.01, -0.02, 0.03]])
    ball, target = 1.33e-3, 2.5e-3
    points = p_T + rng.uniform(-6e-3, 6e-3, (500, 3))
    for c in points:
        m = mc.touch_miss(c, p_T, n, ball, target)[0]
        assert (m == 0.0) == bool(targets_touched(c, p_T, n, ball, target)[0])
        assert m >= 0.0
    above = p_T[0] + 5e-3 * n[0]
    assert mc.touch_miss(above, p_T, n, ball, target)[0] == pytest.approx(5e-3 - ball - TOUCH_TOLERANCE, abs=1e-12)
    side = np.cross(n[0], [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    beside = p_T[0] + 4e-3 * side
    assert mc.touch_miss(beside, p_T, n, ball, target)[0] == pytest.approx(4e-3 - target, abs=1e-12)


@pytest.mark.slow
def test_reach_search_improves_on_the_grid_and_its_touch_is_real():
    """A coarse grid of the left ring (two twists, the knob at both ends, 20 mm pushes), then the
    local search on one of its targets: it starts at the grid's closest point, so it ends no
    farther than the grid came; a target it reports reachable, re-solved at the reported inputs
    by the same continuation and warm start, touches by the touch test itself."""
    from ballchain.drake_models.atrium_sdf import atrium_sdf
    from ballchain.optimization.rod_statics import RodStatics
    from ballchain.systems.station import atrium_for
    from ballchain.systems.target_contact import heart_targets

    heart = atrium_for(mc.scenario_for())
    grid = mc.reach_map("left", n_twist=2, n_knob=2, step=20e-3, heart=heart)
    missed = [r for r in grid if not r["reachable"]][:1]
    assert missed, "the coarse grid reaches every target: nothing to search"
    rows = mc.reach_search(grid, "left", only=[r["target"] for r in missed], max_solves=12, step=20e-3, heart=heart)
    assert [r["target"] for r in rows] == [r["target"] for r in missed]
    for row in rows:
        assert row["closest_mm"] <= row["grid_closest_mm"] + 1e-2
        assert row["reachable"] == (row["closest_mm"] == 0.0)
        assert 1 <= row["solves"] <= 12
    cat = mc.comparison_catheter()
    names, p_WT, n_W, radius = heart_targets(heart)
    rod = RodStatics(cat, heart.p_HE, heart.sheath_axis_H, atrium_sdf(heart))
    for row, start in zip(rows, missed):
        if not row["reachable"]:
            continue
        q0 = None
        for length in np.arange(10e-3, start["at"][0] * 1e-3 + 1e-9, 20e-3):
            q0 = rod.solve(length, np.radians(start["at"][1]), cat.curvature(start["at"][2]), q0=q0).q
        length, twist, knob = row["at"]
        sol = rod.solve(length * 1e-3, np.radians(twist), cat.curvature(knob), q0=q0)
        k = names.index(row["target"])
        # The reported inputs are rounded (0.1 mm, 0.1 deg, 1e-3): the touch within that.
        assert mc.touch_miss(sol.pose.tip_centre, p_WT[k:k + 1], n_W[k:k + 1], cat.radius, radius)[0] < 0.3e-3


@pytest.mark.slow
def test_reach_map_parts_combine_to_the_whole():
    """The map in two parts (a twist each), combined by the least distance and the summed
    touches, is the whole map (coarse: two twists, the knob at both ends, 40 mm pushes)."""
    from ballchain.systems.station import atrium_for

    heart = atrium_for(mc.scenario_for())
    kwargs = dict(n_twist=2, n_knob=2, step=40e-3, heart=heart)
    whole = mc.reach_map("left", **kwargs)
    parts = [mc.reach_map("left", twist_indices=[i], **kwargs) for i in (0, 1)]
    for row, a, b in zip(whole, *parts):
        assert row["closest_mm"] == min(a["closest_mm"], b["closest_mm"])
        assert row["touching"] == a["touching"] + b["touching"]
        assert row["at"] == min((a, b), key=lambda r: r["closest_mm"])["at"]
