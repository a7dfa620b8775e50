"""Per-step cost breakdown of the station (chain in the heart + actuation units) over one second.

Two measurements of the same scenario, each on a freshly built diagram:

1. Exclusive wall time per group of systems: every Python system callback (output calculations,
   discrete updates, derivatives, publishes, the monitor) is wrapped with a timer that subtracts
   the time of the callbacks it triggers through its input ports, so each millisecond is counted
   once, in the group of the system that spent it. What is left of the total is C++: the plant
   (dynamics, SAP contact, hydroelastic geometry queries), the integrator and the framework.
   With the quasi-static engine (``--set "{engine: statics}"``) its statics solves are a group of
   their own (``statics_solve``: ``ChainStatics.solve``) and ``engine`` is the rest of the
   engine's updates and outputs (continuation, bookkeeping, poses) and its geometry's poses.
2. cProfile of the same second (the top functions by internal time), as a cross-check; its
   overhead inflates Python-heavy code, so its shares are not the real ones.

Prints JSON: the un-profiled real-time factor, the per-step breakdown in microseconds, and the
cProfile top list.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import pstats
import time
from collections import defaultdict

GROUPS = {
    "wrench": ("ballchain.systems.magnetic_wrench", ("MagneticWrenchSystem",)),
    "monitor": ("ballchain.systems.chain_simulation", ("ChainMonitor",)),
    "engine": ("ballchain.systems.quasi_static_engine", ("QuasiStaticEngine", "EngineGeometry")),
}
ACTUATION = {
    "ballchain.systems.rotating_magnet_unit": ("RotatingMagnetUnit",),
    "ballchain.systems.omni_wheel_drive": ("OmniWheelDrive",),
    "ballchain.systems.hall_sensor": ("HallSensor", "DipoleDirectionEstimator"),
    "ballchain.systems.reconfiguration": ("ReconfigurationController",),
    "ballchain.systems.teleoperation": ("TeleoperationMapper", "ModeSwitch"),
    "ballchain.systems.feeder": ("Feeder",),
    "ballchain.systems.actuation_unit": ("ActuationUnit",),
}
CALLBACK_PREFIXES = ("_calc", "_update", "_sample", "_initial_sample", "_publish", "DoCalcTimeDerivatives",
                     "__call__")


class ExclusiveTimer:
    """Wraps class methods so that each call's time, minus its nested wrapped calls, is summed
    per group."""

    def __init__(self):
        self.totals = defaultdict(float)
        self.calls = defaultdict(int)
        self._stack: list[list[float]] = []
        self._saved = []

    def wrap(self, cls, group: str) -> None:
        for name in list(vars(cls)):
            if not name.startswith(CALLBACK_PREFIXES) or not callable(getattr(cls, name)):
                continue
            original = getattr(cls, name)
            self._saved.append((cls, name, original))
            setattr(cls, name, self._timed(original, group))

    def wrap_method(self, cls, name: str, group: str) -> None:
        """Time one method of ``cls`` (e.g. ``ChainStatics.solve``) in ``group``."""
        original = getattr(cls, name)
        self._saved.append((cls, name, original))
        setattr(cls, name, self._timed(original, group))

    def _timed(self, fn, group):
        timer = self

        def wrapper(*args, **kwargs):
            timer._stack.append([time.perf_counter(), 0.0])
            try:
                return fn(*args, **kwargs)
            finally:
                start, nested = timer._stack.pop()
                elapsed = time.perf_counter() - start
                timer.totals[group] += elapsed - nested
                timer.calls[group] += 1
                if timer._stack:
                    timer._stack[-1][1] += elapsed

        return wrapper

    def restore(self) -> None:
        for cls, name, original in reversed(self._saved):
            setattr(cls, name, original)
        self._saved.clear()


def _classes(module_name: str, names) -> list:
    import importlib

    module = importlib.import_module(module_name)
    return [getattr(module, n) for n in names]


def _build(scenario_name: str, overrides: str | None):
    from pydrake.systems.analysis import Simulator

    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import ChainMonitor, MakeStation

    scenario = load_scenario(scenario_name, overrides)
    cd = MakeStation(scenario)
    simulator = Simulator(cd.diagram)
    simulator.set_monitor(ChainMonitor(cd))
    simulator.Initialize()
    return scenario, simulator


def run(*, scenario: str = "teleop_right_unit", overrides: str | None = None, duration: float = 1.0,
        top: int = 15, by_system: bool = False) -> dict:
    """Profile ``duration`` simulated seconds of a scenario; returns the breakdown (see module).
    With ``by_system`` the actuation units' systems are a group each (by class name)."""
    # 1. Un-profiled real-time factor.
    sc, simulator = _build(scenario, overrides)
    start = time.perf_counter()
    simulator.AdvanceTo(duration)
    wall_plain = time.perf_counter() - start
    n_steps = int(round(duration / sc.effective_time_step))

    # 2. Exclusive time per group of systems.
    timer = ExclusiveTimer()
    for cls in _classes(*GROUPS["wrench"]):
        timer.wrap(cls, "wrench")
    for module, names in ACTUATION.items():
        for cls in _classes(module, names):
            timer.wrap(cls, cls.__name__ if by_system else "actuation")
    for cls in _classes(*GROUPS["monitor"]):
        timer.wrap(cls, "monitor")
    for cls in _classes(*GROUPS["engine"]):
        timer.wrap(cls, "engine")
    from ballchain.optimization.statics import ChainStatics

    timer.wrap_method(ChainStatics, "solve", "statics_solve")
    try:
        sc, simulator = _build(scenario, overrides)
        timer.totals.clear()
        timer.calls.clear()
        start = time.perf_counter()
        simulator.AdvanceTo(duration)
        wall_timed = time.perf_counter() - start
    finally:
        timer.restore()
    python = sum(timer.totals.values())
    per_step = {k: round(v / n_steps * 1e6, 1) for k, v in sorted(timer.totals.items())}
    per_step["plant_contact_framework_cpp"] = round((wall_timed - python) / n_steps * 1e6, 1)
    per_step["total"] = round(wall_timed / n_steps * 1e6, 1)
    integrator = simulator.get_integrator()

    # 3. cProfile cross-check.
    sc, simulator = _build(scenario, overrides)
    profile = cProfile.Profile()
    profile.enable()
    simulator.AdvanceTo(duration)
    profile.disable()
    stream = io.StringIO()
    pstats.Stats(profile, stream=stream).sort_stats("tottime").print_stats(top)
    lines = [ln for ln in stream.getvalue().splitlines() if ln.strip()][-top:]
    return {
        "scenario": scenario,
        "overrides": overrides,
        "duration_s": duration,
        "time_step_s": sc.effective_time_step,
        "n_steps": n_steps,
        "realtime_factor": round(duration / wall_plain, 3),
        "realtime_factor_with_timers": round(duration / wall_timed, 3),
        "us_per_step": per_step,
        "share": {k: round(v / per_step["total"], 3) for k, v in per_step.items() if k != "total"},
        "python_callbacks_per_step": {k: round(v / n_steps, 1) for k, v in sorted(timer.calls.items())},
        "integrator_steps": integrator.get_num_steps_taken(),
        "derivative_evaluations": integrator.get_num_derivative_evaluations(),
        "cprofile_top_tottime": lines,
    }


def main() -> None:
    from threadpoolctl import threadpool_limits

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--scenario", default="teleop_right_unit", help="scenario name")
    parser.add_argument("--set", dest="overrides", default=None, help="inline YAML overrides")
    parser.add_argument("--duration", type=float, default=1.0, help="simulated time [s]")
    parser.add_argument("--top", type=int, default=15, help="cProfile functions to list")
    parser.add_argument("--by-system", action="store_true",
                        help="each actuation system (magnet, drive, Hall sensor, ...) a group of its own")
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                        help="cpu: every timer counts the process's CPU time (time.process_time)")
    args = parser.parse_args()
    if args.clock == "cpu":  # as ab_compare's children: on a shared machine wall time measures the others
        time.perf_counter = time.process_time
    with threadpool_limits(limits=1, user_api="blas"):  # as the CLI does
        result = run(scenario=args.scenario, overrides=args.overrides, duration=args.duration, top=args.top,
                     by_system=args.by_system)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
