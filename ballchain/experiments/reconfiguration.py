"""Closed-loop reconfiguration study: many random starts, noise on, wheel slip, one unit.

Each run builds the station (one unit, reconfiguration mode), starts the magnet at a seeded
uniformly random orientation (run 0: exactly antiparallel to the neutral direction, where the
paper's law stalls), simulates until the controller's ``done`` latches (or ``t_max``), holds
``settle_s`` longer with the wheels stopped, and measures the *true* angle between the magnet's
dipole and the neutral direction (not the sensor's estimate).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import EventStatus
from tqdm import tqdm

from ballchain.infrastructure.arg_checks import require_bool, require_choice, require_int, require_positive
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.drake_models.vectors import angle_between
from ballchain.experiments._result import Result, not_in_json
from ballchain.systems.actuation_station import StationOptions, make_actuation_station, unit_system
from ballchain.systems.randomness import MAX_SEED
from ballchain.systems.rotating_magnet_unit import rotation_from_quaternion
from ballchain.systems.unit_config import MagnetUnitConfig, right_unit


@dataclass
class ReconfigurationRun(Result):
    """What ``run_reconfiguration`` returns: one closed-loop run.

    Attributes:
        done: the controller's ``done`` latched before t_max.
        time_s: when it latched (or t_max) [s].
        initial_error_deg: the true angle to neutral at the start [deg].
        final_error_deg: the true angle after settling [deg].
        t: the sensor sample times [s], shape (k,); error_deg: the true angle at each (k,) [deg];
            measured_error_deg: the controller's estimate at each (k,) [deg].
    """

    done: bool
    time_s: float
    initial_error_deg: float
    final_error_deg: float
    t: np.ndarray
    error_deg: np.ndarray
    measured_error_deg: np.ndarray


@dataclass
class ReconfigurationStudyResult(Result):
    """What ``run_reconfiguration_study`` (``run``) returns.

    Attributes:
        runs: number of runs; converged: runs done with a true final error below the tolerance.
        max_final_error_deg [deg]; median_time_s, max_time_s: time to done [s].
        antiparallel_time_s: run 0's (the antiparallel start's) time to done [s].
        slip, sensor_noise, field_model, wheel_map: the settings.
        final_error_deg, time_s: per run, lists of length ``runs``.
        traces: per run, its ``ReconfigurationRun`` (the true and measured angle over time, for a
            figure; run 0 is the antiparallel start); never in the JSON.
    """

    runs: int
    converged: int
    max_final_error_deg: float
    median_time_s: float
    max_time_s: float
    antiparallel_time_s: float
    slip: float
    sensor_noise: bool
    field_model: str
    wheel_map: str
    final_error_deg: list
    time_s: list
    traces: list | None = not_in_json()


def random_rotations(n: int, seed: int) -> np.ndarray:
    """(n, 3, 3) rotations uniformly distributed on SO(3) (normalised Gaussian quaternions)."""
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return np.array([rotation_from_quaternion(qi) for qi in q])


def run_reconfiguration(
    R_WM0: np.ndarray,
    *,
    unit: MagnetUnitConfig,
    options: StationOptions,
    t_max: float = 15.0,
    settle_s: float = 0.2,
) -> ReconfigurationRun:
    """One closed-loop run from R_WM0 (3, 3); returns a ``ReconfigurationRun``."""
    diagram = make_actuation_station([unit], options)
    n = unit.name
    context = diagram.CreateDefaultContext()
    diagram.GetInputPort(f"{n}.joystick").FixValue(context, np.zeros(3))
    diagram.GetInputPort(f"{n}.mode").FixValue(context, [1.0])
    magnet = unit_system(diagram, n, "magnet")
    magnet.set_orientation(magnet.GetMyMutableContextFromRoot(context), R_WM0)
    m_c = unit_system(diagram, n, "controller").m_c_W
    m_port = diagram.GetOutputPort(f"{n}.m_W")
    done_port = diagram.GetOutputPort(f"{n}.done")
    meas_port = diagram.GetOutputPort(f"{n}.angle_error")

    def true_error(ctx) -> float:
        return float(np.rad2deg(angle_between(m_port.Eval(ctx), m_c)))

    log_t, log_err, log_meas = [], [], []
    dt_log = 1.0 / options.sensor_spec.sample_rate_hz

    def monitor(ctx):
        t = ctx.get_time()
        if not log_t or t - log_t[-1] >= dt_log - 1e-9:
            log_t.append(t)
            log_err.append(true_error(ctx))
            log_meas.append(float(np.rad2deg(meas_port.Eval(ctx)[0])))
        if done_port.Eval(ctx)[0] > 0.5:
            return EventStatus.ReachedTermination(diagram, "reconfiguration done")
        return EventStatus.Succeeded()

    simulator = Simulator(diagram, context)
    simulator.set_monitor(monitor)
    simulator.Initialize()
    initial = true_error(context)
    simulator.AdvanceTo(t_max)
    done = bool(done_port.Eval(context)[0] > 0.5)
    t_done = context.get_time()
    simulator.clear_monitor()
    simulator.AdvanceTo(t_done + settle_s)
    return ReconfigurationRun(
        done=done,
        time_s=t_done,
        initial_error_deg=initial,
        final_error_deg=true_error(context),
        t=np.array(log_t),
        error_deg=np.array(log_err),
        measured_error_deg=np.array(log_meas),
    )


MAX_RUNS = 10_000
MAX_T_MAX = 600.0  # [s] of simulated time per run


def check_study_inputs(*, runs, seed, slip, noise, field_model, wheel_map, tolerance_deg, t_max) -> None:
    """Raise UserInputError, naming the argument, for what ``run_reconfiguration_study`` cannot
    take: before the first run, as the command checks its flags."""
    require_int(runs, "runs", 1, MAX_RUNS)
    require_int(seed, "seed", 0, MAX_SEED - int(runs))  # run k's sensor noise is seeded seed + k
    require_bool(noise, "noise")
    require_choice(field_model, ("dipole", "exact"), "field_model")
    require_choice(wheel_map, ("derived", "paper"), "wheel_map")
    require_positive(slip, "slip", allow_zero=True)
    if slip >= 1.0:
        raise UserInputError(f"slip must be in [0, 1) (a wheel's slip fraction), got {slip:g}")
    for name, value, hi, unit in (("tolerance_deg", tolerance_deg, 180.0, "deg"), ("t_max", t_max, MAX_T_MAX, "s")):
        require_positive(value, name)
        if value > hi:
            raise UserInputError(f"{name} must be in (0, {hi:g}] {unit}, got {value:g}")


def run_reconfiguration_study(
    *,
    runs: int = 100,
    seed: int = 0,
    slip: float = 0.05,
    noise: bool = True,
    field_model: str = "exact",
    wheel_map: str = "derived",
    tolerance_deg: float = 1.0,
    t_max: float = 15.0,
    progress: bool | Callable[[int], None] | None = None,
) -> ReconfigurationStudyResult:
    """The closed-loop study: seeded random starts, run 0 exactly antiparallel to neutral.

    Args:
        runs: number of runs (>= 1).
        seed: seed of the initial orientations and of the sensor noise (run k uses seed + k).
        slip: wheel slip fraction.
        noise: Hall sensor noise on.
        field_model: the magnet's true field seen by the sensor, "dipole" or "exact" (the
            estimator always inverts the dipole law).
        wheel_map: controller conversion, "derived" or "paper".
        tolerance_deg: a run has converged if its true final error is below this [deg].
        t_max: time limit of a run [s].
        progress: True for a progress bar on stderr, or a function called with 1 after each run
            (e.g. a tqdm bar's ``update``); None or False: none.

    Returns:
        A ``ReconfigurationStudyResult``.
    """
    check_study_inputs(runs=runs, seed=seed, slip=slip, noise=noise, field_model=field_model, wheel_map=wheel_map,
                       tolerance_deg=tolerance_deg, t_max=t_max)
    unit = right_unit(model=field_model, slip=slip, sensor_noise=noise, wheel_map=wheel_map)
    base = StationOptions()
    # The neutral direction the controller is built with (same computation as in the station).
    m_c = unit_system(make_actuation_station([unit], base), unit.name, "controller").m_c_W
    starts = list(random_rotations(runs, seed))
    starts[0] = rotation_with_z_along(-m_c)  # exactly antiparallel: the law's stall point
    finals, times, traces, converged = [], [], [], 0
    bar = tqdm(total=runs, desc="reconfigure", unit="run", file=sys.stderr, disable=progress is not True)
    for k, R0 in enumerate(starts):
        result = run_reconfiguration(R0, unit=unit, options=replace(base, seed=seed + k), t_max=t_max)
        ok = result.done and result.final_error_deg < tolerance_deg
        converged += int(ok)
        finals.append(result.final_error_deg)
        times.append(result.time_s)
        traces.append(result)
        bar.update(1)
        if callable(progress):
            progress(1)
    bar.close()
    return ReconfigurationStudyResult(
        runs=runs,
        converged=converged,
        max_final_error_deg=float(np.max(finals)),
        median_time_s=float(np.median(times)),
        max_time_s=float(np.max(times)),
        antiparallel_time_s=float(times[0]),
        slip=slip,
        sensor_noise=noise,
        field_model=field_model,
        wheel_map=wheel_map,
        final_error_deg=finals,
        time_s=times,
        traces=traces,
    )


run = run_reconfiguration_study
"""The experiment's entry point (``ballchain reconfigure``), as in every experiment module."""
