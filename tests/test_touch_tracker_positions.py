"""The target tracker reads the tip ball's centre from ``ball_positions`` (issue 48), the same
floats as the tip's frame on ``body_poses`` it read before."""

import numpy as np
import pytest

from ballchain.systems.chain_scenario import load_scenario
from ballchain.systems.chain_simulation import MakeStation, run_station
from ballchain.systems.target_contact import TargetTouchTracker


@pytest.mark.parametrize("engine", ["statics", "plant"])
def test_tracker_reads_the_tip_centre_from_ball_positions(engine):
    overrides = "{engine: statics, mode: quasi-static}" if engine == "statics" else "{}"
    station = MakeStation(load_scenario("heart_wall_contact", overrides))
    tracker = station.target_touches
    assert tracker.get_body_poses_input_port() is None and tracker.get_ball_positions_input_port() is not None
    run = run_station(station, duration=0.3 if engine == "statics" else 0.01)
    assert run.failure is None
    tip_centre = tracker.get_ball_positions_input_port().Eval(tracker.GetMyContextFromRoot(run.context))[-3:]
    port = station.chain.get_body_poses_output_port()
    poses = port.Eval(port.get_system().GetMyContextFromRoot(run.context))
    assert np.array_equal(tip_centre, poses[station.chain.electrode.body_index].translation())  # bit for bit


def test_tracker_with_an_electrode_keeps_the_tip_frame():
    p_T, n_T = np.array([[0.0, 0.0, 0.02]]), np.array([[0.0, 0.0, -1.0]])
    with pytest.raises(ValueError, match="body_poses"):
        TargetTouchTracker(1, ["left_1"], p_T, n_T, 2.5e-3, 1e-3, 0.05, electrode_length=3.5e-3, n_positions=4)
