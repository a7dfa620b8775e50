"""The closed-loop reconfiguration study, small: noise, 5 % slip, exact field, antiparallel start."""

import numpy as np
import pytest

from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.experiments.wheels import wheel_map_report
from ballchain.systems.actuation_station import StationOptions
from ballchain.systems.unit_config import right_unit
from ballchain.systems.reconfiguration import ReconfigurationController
from ballchain.experiments.reconfiguration import run_reconfiguration, run_reconfiguration_study


# Three closed-loop runs with noise and the exact field: the quick tier runs one closed loop
# (the antiparallel start, below) and the paper's wheel map.
@pytest.mark.slow
def test_small_study_converges_every_run_including_antiparallel():
    result = run_reconfiguration_study(runs=3, seed=3, slip=0.05, noise=True, field_model="exact")
    assert result.runs == 3
    assert result.converged == 3
    assert result.max_final_error_deg < 1.0
    assert 0.0 < result.median_time_s <= result.max_time_s < 15.0
    assert len(result.final_error_deg) == 3


def test_antiparallel_run_leaves_the_stall_point_and_error_decreases():
    m_c = np.array([-1.0, 0.0, 0.0])  # neutral for the right unit, field along +x at the origin
    run = run_reconfiguration(rotation_with_z_along(-m_c), unit=right_unit(slip=0.05, sensor_noise=False),
                              options=StationOptions())
    assert run.initial_error_deg == 180.0
    assert run.done and run.final_error_deg < 1.0
    err = run.error_deg
    # Leaves 180 deg within 0.3 s and then falls (allowing for stepper quantisation wiggles).
    assert err[np.searchsorted(run.t, 0.3)] < 179.0
    assert np.all(np.diff(err) < 0.2)


def test_paper_wheel_map_still_converges_in_closed_loop_but_turns_off_axis():
    # The printed map composes with the true kinematics to a 26.6 deg rotation (< 90 deg), so
    # feedback still converges; the first commanded step shows the axis error.
    R0 = rotation_with_z_along([0.0, 0.6, 0.8])
    run = run_reconfiguration(R0, unit=right_unit(slip=0.0, sensor_noise=False, wheel_map="paper"),
                              options=StationOptions())
    assert run.done and run.final_error_deg < 1.0
    ctrl = ReconfigurationController([-1.0, 0.0, 0.0], wheel_map="paper", max_wheel_speed=100.0)
    ctx = ctrl.CreateDefaultContext()
    m = R0[:, 2]
    ctrl.get_input_port(0).FixValue(ctx, m)
    wanted = ctrl.desired_angular_velocity(m)
    actual = ctrl.GetOutputPort("omega_desired_W").Eval(ctx)  # what the real wheels make of it
    off_axis = np.rad2deg(np.arccos(wanted @ actual / np.linalg.norm(wanted) / np.linalg.norm(actual)))
    # A rotation by theta turns a vector by at most theta (exactly theta across its axis); here
    # the commanded axis is nearly across it.
    theta = wheel_map_report(n_samples=10).paper_map_commanded_axis_error_deg
    assert 20.0 < off_axis <= theta + 1e-9
