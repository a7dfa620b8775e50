"""The quasi-static engine at haptic rate, and the statics' cost against chain length.

``run`` (``ballchain bench engine``): equilibria in contact along a recorded teleoperation path,
one per millisecond of path (``rate_hz``, 1 kHz by default), each warm-started from the last, as
a haptic loop would ask for them. The path is recorded from the station: the paper's
teleoperation set-up (``teleop_right_unit``: one rotating unit swept about +z by the scripted
joystick, the stepper feeder) with the chain inserted 32 to 38 mm (``PATH_INSERTION``) so that it
presses on the atrium's wall along the whole path; the engine's inputs (the feeder's desired state
and the magnet states) are sampled every 1/rate s of simulated time and the points where nothing
moved are dropped (the engine skips them). The path is then replayed through fresh engines
(``QuasiStaticEngine.replica``) with their input ports fixed point by point: one update is the
engine's periodic discrete update (the warm-started solve with its predictor, continuation and
snap-through check, and the state written) and the ``body_poses`` output evaluated, as a consumer
would read it. The compiled statics (``compiled=True``) and the Python reference
(``compiled=False``) are replayed in the same run, interleaved point by point (their order
alternating), each timed by ``clock`` (``cpu``: this process's CPU time, steadier on a shared
machine; ``wall``). Reported per solver: the median, 99th percentile and largest update time, the
achieved update rate (updates per second of solving back to back) and the share of updates
within the period; the speed-up is the ratio of the medians in the same run, and the two solvers'
ball positions are compared along the path. With ``freeze_gc`` (the command line's choice, as a
real-time loop would) the objects alive before the replay are frozen out of Python's garbage
collector (``chain_simulation.frozen_gc``): a full collection scans the station's ~170k objects
(tens of ms) and would land on whichever update allocates at the time.

``run_scaling`` (``ballchain bench scaling``): one equilibrium of 8, 16, 32 and 64 balls in a
23 mT field at 90 deg, in free space (the canonical problem) and pressed on a flat rigid wall
(``ChainStatics.solve(wall=...)``, the plane y = 60 % of the free equilibrium's reach), cold (from the
straight chain) and warm (from the equilibrium 2.5 deg before), compiled and reference,
interleaved; the table as CSV and markdown and a figure when ``out`` is given.

Benchmarks are scripts, not tests: the tests check the fields, never the times.
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ballchain.infrastructure.errors import UserInputError, check_in, short_repr
from ballchain.experiments._result import Result, optional
from ballchain.experiments.statics_bench import check_problem

PATH_SCENARIOS = ("teleop_right_unit", "teleop_two_units")
# The insertion of the recorded path: the chain on the atrium's wall all along (the scenario's own
# 20 -> 30 mm ramp leaves it free for half of the path).
PATH_INSERTION = "{initial: 0.032, final: 0.038, start_time: 0.05, speed: 0.01, feeder: true}"
SCALING_SIZES = (8, 16, 32, 64)
SOLVERS = ("compiled", "reference")  # ChainStatics(compiled=True) and compiled=False


def _clock(clock: str):
    if clock not in ("wall", "cpu"):
        raise UserInputError(f"--clock must be 'wall' or 'cpu', got {short_repr(clock)}")
    return time.process_time if clock == "cpu" else time.perf_counter


def _quantiles(samples_s, period_s: float | None = None) -> dict:
    """Median, 99th percentile, largest and mean [ms], the rate of solving back to back [Hz] and the
    share within ``period_s``."""
    t = 1e3 * np.asarray(samples_s, float)
    if len(t) == 0:
        return {"updates": 0}
    out = {"updates": int(len(t)), "median_ms": float(np.median(t)), "p99_ms": float(np.percentile(t, 99)),
           "max_ms": float(t.max()), "mean_ms": float(t.mean()), "achieved_rate_hz": float(1e3 / t.mean())}
    if period_s is not None:
        out["within_period"] = float(np.mean(t <= 1e3 * period_s))
    return out


# --- the haptic-rate replay ------------------------------------------------------------------------


@dataclass(kw_only=True)
class EngineBenchResult(Result):
    """What ``run`` returns (times in ms).

    Attributes:
        benchmark: "engine".
        scenario, insertion, path_s, rate_hz, clock: the run's settings (the path's scenario and
            insertion override, the recorded stretch of simulated time [s], the update rate [Hz]).
        path_points: the points replayed (inputs moved since the last point); skipped: the points
            where nothing moved.
        in_contact: share of the reference's equilibria with the wall pushing on a ball;
            median_wall_contacts: balls on the wall (median over the path).
        compiled, reference: per solver ``{"update": quantiles, "update_in_contact": quantiles,
            "solve": quantiles of the solves alone, "median_iterations", "failures"}``; the
            quantiles are ``updates``, ``median_ms``, ``p99_ms``, ``max_ms``, ``mean_ms``,
            ``achieved_rate_hz`` (1 / mean) and ``within_period`` (share of updates within 1/rate).
            reference is None when left out.
        gc_frozen: the replay ran with the garbage collector's old objects frozen.
        speedup_median, speedup_p99: reference / compiled, updates (same-run ratios).
        max_position_difference_m: largest ball-centre difference of the two solvers along the path.
        load_average_1min: before and after; cpu_count: the machine's.
    """

    benchmark: str = "engine"
    scenario: str
    insertion: str
    path_s: float
    rate_hz: float
    clock: str
    path_points: int
    skipped: int
    in_contact: float
    median_wall_contacts: float
    compiled: dict
    reference: dict | None
    gc_frozen: bool
    speedup_median: float | None
    speedup_p99: float | None
    max_position_difference_m: float | None
    load_average_1min: dict
    cpu_count: int | None


def _check_engine_inputs(scenario, path_s, rate_hz, clock) -> None:
    if scenario not in PATH_SCENARIOS:
        raise UserInputError(f"--scenario must be one of {', '.join(PATH_SCENARIOS)}, got {short_repr(scenario)}")
    check_in("--path-s", path_s, 1e-3, 1.0, unit="s")
    check_in("--rate-hz", rate_hz, 10.0, 1e4, unit="Hz")
    if path_s * rate_hz < 2:
        raise UserInputError(f"--path-s {path_s:g} s at --rate-hz {rate_hz:g} Hz is fewer than 2 updates")
    _clock(clock)


def record_path(scenario: str, path_s: float, rate_hz: float):
    """The engine's inputs along ``path_s`` s of the scenario (``PATH_INSERTION``), every 1/rate s.

    Returns:
        ``(engine, points, skipped)``: the station's engine (configured for the scenario), the
        points ``[(s [m], magnet states (6 k,)), ...]`` whose inputs moved since the last one (the
        first always), and the count of those dropped.
    """
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation, StationRunner

    sc = load_scenario(scenario, f"{{engine: statics, mode: quasi-static, insertion: {PATH_INSERTION}}}")
    cd = MakeStation(sc)
    engine = cd.chain.system  # the QuasiStaticEngine (engine: statics)
    runner = StationRunner(cd)
    points, skipped = [], 0
    for i in range(int(round(path_s * rate_hz)) + 1):
        failure = runner.advance_to(i / rate_hz)
        if failure is not None:
            raise RuntimeError(f"recording the path of {scenario}: {failure}")
        s, mags = engine._inputs(engine.GetMyContextFromRoot(runner.context))
        if points and s == points[-1][0] and np.array_equal(mags, points[-1][1]):
            skipped += 1
            continue
        points.append((s, np.array(mags)))
    return engine, points, skipped


class _Replay:
    """One solver's engine on the path: its own context, inputs fixed point by point."""

    def __init__(self, engine, compiled: bool, first, now):
        self.engine = engine.replica(compiled=compiled)
        self.engine.clock = now
        self.context = self.engine.CreateDefaultContext()
        self._set(first)
        self.engine.ExecuteInitializationEvents(self.context)
        del self.engine.solve_times[:], self.engine.iterations[:]
        self.times, self.contacts, self.positions = [], [], []

    def _set(self, point) -> None:
        s, mags = point
        self.engine.get_feeder_state_input_port().FixValue(self.context, [s, 0.0])
        if self.engine.get_magnet_states_input_port() is not None:
            self.engine.get_magnet_states_input_port().FixValue(self.context, mags)

    def update(self, point, now) -> None:
        """One timed update (inputs, the engine's discrete update, the poses read)."""
        engine, context = self.engine, self.context
        t0 = now()
        self._set(point)
        context.SetDiscreteState(engine.EvalUniquePeriodicDiscreteUpdate(context))
        engine.get_body_poses_output_port().Eval(context)
        self.times.append(now() - t0)
        r = engine.last_result
        self.contacts.append(0 if r is None else sum(bool(np.any(f)) for f in r.wall_forces_W.values()))
        self.positions.append(engine.ball_positions(context).copy())

    def summary(self, period: float) -> dict:
        contact = np.asarray(self.contacts) > 0
        times = np.asarray(self.times)
        iterations = self.engine.iterations
        return {"update": _quantiles(times, period), "update_in_contact": _quantiles(times[contact], period),
                "solve": _quantiles(self.engine.solve_times, period),
                "median_iterations": float(np.median(iterations)) if iterations else None,
                "failures": sum(e.kind == "solve failed" for e in self.engine.events)}


def run(*, scenario: str = "teleop_right_unit", path_s: float = 0.7, rate_hz: float = 1000.0, clock: str = "wall",
        reference: bool = True, progress: bool = True, freeze_gc: bool = False) -> EngineBenchResult:
    """Replay a recorded teleoperation path at ``rate_hz`` through the engine, compiled and reference.

    Args:
        scenario: one of ``PATH_SCENARIOS`` (with ``PATH_INSERTION``).
        path_s: simulated time of the path [s] (the scripted joystick sweeps from 0.1 to 0.7 s).
        rate_hz: updates per simulated second (one equilibrium per 1/rate s of path).
        clock: "cpu" (this process's CPU time) or "wall".
        reference: also replay the Python reference (``compiled=False``), interleaved.
        progress: a tqdm bar on stderr.
        freeze_gc: freeze the garbage collector's old objects for the replay (a process-wide
            switch: for a program that owns its process).

    Returns:
        An ``EngineBenchResult``.

    Raises:
        UserInputError: bad arguments (before any work).
    """
    _check_engine_inputs(scenario, path_s, rate_hz, clock)
    now = _clock(clock)
    from tqdm import tqdm

    from ballchain.systems.chain_simulation import frozen_gc
    from ballchain.systems.quasi_static_engine import _one_blas_thread

    load_before = os.getloadavg()
    engine, points, skipped = record_path(scenario, path_s, rate_hz)
    solvers = SOLVERS if reference else SOLVERS[:1]
    with _one_blas_thread(), frozen_gc(freeze_gc):
        replays = {name: _Replay(engine, name == "compiled", points[0], now) for name in solvers}
        for i, point in enumerate(tqdm(points[1:], desc="bench engine", unit="update", file=sys.stderr,
                                       disable=not progress, leave=False)):
            for name in solvers if i % 2 == 0 else solvers[::-1]:
                replays[name].update(point, now)
    period = 1.0 / rate_hz
    out = {name: r.summary(period) for name, r in replays.items()}
    judge = replays[solvers[-1]]
    ratio = None
    if reference:
        a, b = out["compiled"]["update"], out["reference"]["update"]
        ratio = (b["median_ms"] / a["median_ms"], b["p99_ms"] / a["p99_ms"])
    difference = None if not reference else float(max(
        np.abs(p - q).max() for p, q in zip(replays["compiled"].positions, replays["reference"].positions)))
    return EngineBenchResult(
        scenario=scenario, insertion=PATH_INSERTION, path_s=path_s, rate_hz=rate_hz, clock=clock,
        path_points=len(points), skipped=skipped,
        in_contact=float(np.mean(np.asarray(judge.contacts) > 0)),
        median_wall_contacts=float(np.median(judge.contacts)),
        compiled=out["compiled"], reference=out.get("reference"), gc_frozen=freeze_gc,
        speedup_median=None if ratio is None else ratio[0], speedup_p99=None if ratio is None else ratio[1],
        max_position_difference_m=difference,
        load_average_1min={"before": load_before[0], "after": os.getloadavg()[0]}, cpu_count=os.cpu_count())


# --- scaling with the chain's length ---------------------------------------------------------------


@dataclass(kw_only=True)
class ScalingBenchResult(Result):
    """What ``run_scaling`` returns.

    Attributes:
        benchmark: "scaling".
        sizes, field_mT, angle_deg, warm_offset_deg, repeats, clock: the run's settings.
        rows: one per (balls, case "free"/"contact", start "cold"/"warm"): ``compiled_ms`` and
            ``reference_ms`` (medians; None when left out), ``speedup`` (reference / compiled, same
            run), Newton ``iterations`` of each, ``wall_contacts`` (balls on the wall) and
            ``max_position_difference_m`` between the two solvers' equilibria.
        files: the CSV, markdown and PNG written (with ``out``).
    """

    benchmark: str = "scaling"
    sizes: list
    field_mT: float
    angle_deg: float
    warm_offset_deg: float
    repeats: int
    clock: str
    rows: list
    files: list | None = optional()


def _check_scaling_inputs(sizes, repeats, clock) -> tuple[int, ...]:
    if isinstance(sizes, str):
        try:
            sizes = tuple(int(x) for x in sizes.split(",") if x.strip())
        except ValueError:
            raise UserInputError(f"--sizes must be comma-separated integers, got {short_repr(sizes)}") from None
    sizes = tuple(sizes)
    if not sizes or any(isinstance(n, bool) or not isinstance(n, int) or not 2 <= n <= 128 for n in sizes):
        raise UserInputError(f"--sizes must be integers in 2..128, got {short_repr(sizes)}")
    if isinstance(repeats, bool) or not isinstance(repeats, int) or not 1 <= repeats <= 1000:
        raise UserInputError(f"--repeats must be an integer in 1..1000, got {short_repr(repeats)}")
    _clock(clock)
    return sizes


def _scaling_problems(n: int, field_mT: float, angle_deg: float, warm_offset_deg: float) -> dict:
    """The two problems of an n-ball chain: ``{case: (solve(statics, field, warm) -> result, fields)}``
    with ``fields = (at the angle, at the warm start's angle)``."""
    from ballchain.drake_models.field_sources import UniformField
    from ballchain.drake_models.params import BallChain
    from ballchain.optimization.statics import ChainStatics

    B = 1e-3 * field_mT
    fields = (UniformField.in_plane(B, math.radians(angle_deg)),
              UniformField.in_plane(B, math.radians(angle_deg - warm_offset_deg)))
    reach = ChainStatics(BallChain(n_balls=n), compiled=False).solve(fields[0]).positions[:, 1].max()
    wall = (np.array([0.0, 0.6 * reach, 0.0]), np.array([0.0, -1.0, 0.0]))  # the chain on the -y side
    return {"free": (lambda statics, field, warm: statics.solve(field, warm), fields),
            "contact": (lambda statics, field, warm: statics.solve(field, warm, wall=wall), fields)}


def _scaling_rows(n: int, field_mT, angle_deg, warm_offset_deg, repeats: int, solvers, now) -> list[dict]:
    """The four rows (free/contact x cold/warm) of an n-ball chain, the solvers interleaved."""
    from ballchain.drake_models.params import BallChain
    from ballchain.optimization.statics import ChainStatics

    chain = BallChain(n_balls=n)
    statics = {name: ChainStatics(chain, compiled=name == "compiled") for name in solvers}
    rows = []
    for case, (solve, (field, field_warm)) in _scaling_problems(n, field_mT, angle_deg, warm_offset_deg).items():
        warm = {name: solve(statics[name], field_warm, None) for name in solvers}
        samples = {(name, start): [] for name in solvers for start in ("cold", "warm")}
        last = {}
        for round_ in range(repeats + 1):  # round 0 untimed (first-call costs)
            for name in solvers if round_ % 2 == 0 else solvers[::-1]:
                for start in ("cold", "warm"):
                    t0 = now()
                    last[name, start] = solve(statics[name], field, None if start == "cold" else warm[name])
                    if round_ > 0:
                        samples[name, start].append(now() - t0)
        for start in ("cold", "warm"):
            ms = {name: 1e3 * float(np.median(samples[name, start])) for name in solvers}
            result = last[solvers[0], start]
            rows.append({
                "n_balls": n, "case": case, "start": start,
                "compiled_ms": ms["compiled"], "reference_ms": ms.get("reference"),
                "speedup": ms["reference"] / ms["compiled"] if "reference" in ms else None,
                "compiled_iterations": result.iterations,
                "reference_iterations": last["reference", start].iterations if "reference" in ms else None,
                "converged": all(last[name, start].converged for name in solvers),
                "wall_contacts": sum(f > 0 for f in result.wall_forces.values()),
                "max_position_difference_m": float(np.abs(
                    result.positions - last["reference", start].positions).max()) if "reference" in ms else None})
    return rows


def run_scaling(*, sizes=SCALING_SIZES, field_mT: float = 23.0, angle_deg: float = 90.0,
                warm_offset_deg: float = 2.5, repeats: int = 5, clock: str = "wall", reference: bool = True,
                out: Path | None = None, progress: bool = True) -> ScalingBenchResult:
    """Solve time against chain length, free and on a wall, cold and warm, compiled vs reference.

    Args:
        sizes: chain lengths (balls), or a comma-separated string.
        field_mT, angle_deg: the uniform field (in the x-y plane, from +x).
        warm_offset_deg: warm solves start from the equilibrium at ``angle_deg`` minus this.
        repeats: timed solves per row and solver (after one untimed round).
        clock: "cpu" or "wall".
        reference: also time the Python reference (``compiled=False``).
        out: a folder for scaling.csv, scaling.md and scaling.png (None: nothing written).
        progress: a tqdm bar on stderr.

    Raises:
        UserInputError: bad arguments (before any work).
    """
    sizes = _check_scaling_inputs(sizes, repeats, clock)
    check_problem(field_mT, angle_deg, warm_offset_deg)
    now = _clock(clock)
    if out is not None:
        from ballchain.infrastructure.safe_files import check_output_dir

        out = check_output_dir(out, "--out", names=("scaling.csv", "scaling.md", "scaling.png"))
    from tqdm import tqdm

    from ballchain.systems.quasi_static_engine import _one_blas_thread

    solvers = SOLVERS if reference else SOLVERS[:1]
    rows = []
    with _one_blas_thread():
        for n in tqdm(sizes, desc="bench scaling", unit="size", file=sys.stderr, disable=not progress, leave=False):
            rows += _scaling_rows(n, field_mT, angle_deg, warm_offset_deg, repeats, solvers, now)
    result = ScalingBenchResult(sizes=list(sizes), field_mT=field_mT, angle_deg=angle_deg,
                                warm_offset_deg=warm_offset_deg, repeats=repeats, clock=clock, rows=rows)
    if out is not None:
        result.files = write_scaling_files(result, Path(out))
    return result


def scaling_markdown(result: ScalingBenchResult) -> str:
    """The scaling table in markdown (medians in ms, the same-run ratio)."""
    lines = [f"| balls | case | start | compiled [ms] | reference [ms] | ratio | iterations | wall contacts |",
             "|---:|---|---|---:|---:|---:|---:|---:|"]
    for r in result.rows:
        ref = "" if r["reference_ms"] is None else f"{r['reference_ms']:.2f}"
        ratio = "" if r["speedup"] is None else f"{r['speedup']:.1f}x"
        lines.append(f"| {r['n_balls']} | {r['case']} | {r['start']} | {r['compiled_ms']:.3f} | {ref} | {ratio} | "
                     f"{r['compiled_iterations']} | {r['wall_contacts']} |")
    return "\n".join(lines) + "\n"


def write_scaling_files(result: ScalingBenchResult, out: Path) -> list[str]:
    """scaling.csv, scaling.md and scaling.png in ``out``; returns their paths."""
    from ballchain.infrastructure.safe_files import agg_pyplot, atomic_write_text, save_figure, write_csv

    out.mkdir(parents=True, exist_ok=True)
    csv_path = write_csv(out / "scaling.csv", result.rows)
    md_path = atomic_write_text(out / "scaling.md", scaling_markdown(result))
    plt = agg_pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8), sharey=True)
    for ax, case in zip(axes, ("free", "contact")):
        for solver, style in (("compiled", "-"), ("reference", "--")):
            for start, marker in (("cold", "o"), ("warm", "s")):
                pts = [(r["n_balls"], r[f"{solver}_ms"]) for r in result.rows
                       if r["case"] == case and r["start"] == start and r[f"{solver}_ms"] is not None]
                if pts:
                    ax.plot(*zip(*pts), style, marker=marker, ms=4, label=f"{solver}, {start}")
        ax.axhline(1.0, color="k", lw=0.8, ls=":")
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_xticks(result.sizes, [str(n) for n in result.sizes])
        ax.set_xlabel("balls in the chain")
        ax.set_title("free space" if case == "free" else "pressed on a flat wall")
    axes[0].set_ylabel(f"median solve time [ms, {'CPU' if result.clock == 'cpu' else 'wall'}]")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"Statics solve against chain length ({result.field_mT:g} mT at {result.angle_deg:g} deg)",
                 fontsize=10)
    fig.tight_layout()
    png = save_figure(fig, out / "scaling.png", dpi=120)
    return [str(csv_path), str(md_path), str(png)]
