"""The catheter's reach map (the device's side of a missed target): its rows agree with the touch
test."""

from __future__ import annotations

import pytest

from ballchain.infrastructure.errors import UserInputError
from ballchain.experiments import manual_catheter as mc


@pytest.mark.slow
def test_reach_map_rows_agree_with_the_touch_test():
    """A coarse map of the left ring (two twists, the knob at both ends, 20 mm pushes): a row per
    target; a target some grid point touches is 0 mm from a touch, one none touches is farther."""
    rows = mc.reach_map("left", n_twist=2, n_knob=2, step=20e-3)
    assert [r["target"] for r in rows] == [f"left_{k}" for k in range(1, len(rows) + 1)]
    for r in rows:
        assert r["reachable"] == (r["touching"] > 0)
        assert (r["closest_mm"] == 0.0) == r["reachable"]
        assert r["at"] is not None and 10 <= r["at"][0] <= 120


def test_reach_map_bad_task():
    with pytest.raises(UserInputError, match="task"):
        mc.reach_map("middle")
