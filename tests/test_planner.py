"""Model-based steering: the teleoperation stand and a short plan."""

import numpy as np
import pytest

from ballchain.drake_models.params import BallChain
from ballchain.experiments import planner


def test_teleop_stand_targets_lie_a_ball_radius_inside_the_wall(heart):
    atrium = heart
    d = BallChain().ball_diameter
    stand = planner.teleop_stand(atrium, "right", d)
    assert len(stand.targets) == 18
    for name, (p_S, axis_S) in stand.targets.items():
        p_H = stand.p_HE + stand.R_HS @ p_S
        assert atrium.contains(p_H[None, :])[0], name
        # Pressing along the axis by a ball radius reaches the endocardial ellipsoid.
        q = p_H + 0.5 * d * (stand.R_HS @ axis_S)
        np.testing.assert_allclose(np.sum((q / atrium.semi_axes) ** 2), 1.0, atol=1e-9)
    p_HM = stand.p_HE + stand.R_HS @ stand.magnets["1"]
    np.testing.assert_allclose(np.linalg.norm(p_HM - atrium.carinas["right"]), 0.10, rtol=1e-12)


@pytest.mark.slow
def test_short_plan_presses_every_target_and_times_the_turns():
    data = planner.run(task="right", targets=2, balls=(16,), grid=3, refine=4, progress=False)
    assert [r["reached"] for r in data.rows] == [True, True], [r["reason"] for r in data.rows]
    for r in data.rows:
        assert r["force_gf"] >= 10.0 * (1 - 1e-4)
        # The plan's own test (``min_turn_orientation``): |F_t| <= mu F_n + 1e-3 F_min.
        assert r["friction_needed"] <= data.friction + 1e-3 * data.min_force_gf / r["force_gf"]
        assert r["offset_mm"] <= data.target_radius_mm * (1 + 1e-6)
    turns = np.radians([r["turn_deg"] for r in data.rows])
    np.testing.assert_allclose(data.summary.magnet_turn_time_s, turns.sum() / 0.5)
    # The first turn starts from the magnet's neutral direction, the second from the first plan.
    a, b = (np.array(r["dipole"]) for r in data.rows)
    np.testing.assert_allclose(turns[1], np.arccos(np.clip(a @ b, -1, 1)), atol=1e-9)
    assert data.summary.insertion_time_s == 0.0  # one length only


@pytest.mark.slow
def test_a_reached_row_carries_no_reason_from_a_length_that_failed():
    """Two balls cannot press the target, sixteen can: the row is reached and gives no reason
    (it carried the 2-ball failure's)."""
    data = planner.run(task="right", targets=1, balls=(2, 16), grid=3, refine=4, progress=False)
    (row,) = data.rows
    assert row["reached"] and row["n_balls"] == 16 and row["reason"] == "", row
