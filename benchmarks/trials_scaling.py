"""The trials study beyond one machine (issue 48, item 5): its scaling table and a cluster estimate.

Runs ``ballchain trials`` on the same arms and seeds with ``--workers 0`` (serial, in the
command's process) and with LocalClusters of 1 and 2 worker processes (each worker process
stands in for a node), each into a fresh folder, and measures:

- the command's wall time and CPU time (its own and its worker processes', ``RUSAGE_CHILDREN``);
- every run's own CPU and wall time (the study's table: ``cpu_time_s``, ``wall_time_s``);
- the scheduler's overhead: the round trip of a no-op task on a 2-worker LocalCluster of the
  project's executor, and the cluster's start and stop.

From those it estimates the study on N nodes: the fixed cost (the command's start, the plans, the
cluster's start and stop, a worker's warm-up taken from the 1-worker row), plus the makespan of the
serial runs' wall times scheduled longest first on N workers, plus the per-task overhead. The estimate is a model, printed beside the measured rows
it can be checked against (N = 1, 2).

The machine is shared and has 2 cores: wall times move with the load (printed with each row);
CPU times move less. Quote the ratios of one run.

    python benchmarks/trials_scaling.py --seeds 4 --arms robotic_right procedure_right_auto --json out.json
"""

from __future__ import annotations

import argparse
import csv
import heapq
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ballchain.infrastructure.safe_files import atomic_write_text, check_output_file


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _trials(out: Path, workers: int, seeds: int, arms: list[str], targets: int | None) -> dict:
    """One ``ballchain trials`` command; its wall and CPU time and its table's rows."""
    exe = Path(sys.executable).with_name("ballchain")
    cmd = [str(exe), "trials", "--out", str(out), "--seeds", str(seeds), "--arms", *arms, "--workers", str(workers),
           "--no-progress"]
    if targets is not None:
        cmd += ["--targets", str(targets)]
    load = os.getloadavg()[0]
    c0, t0 = _children_cpu(), time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
    with open(out / "table.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    bad = [r["key"] for r in rows if r.get("error")]
    if bad:
        raise RuntimeError(f"runs failed: {bad}")
    return {"workers": workers, "wall_s": wall, "cpu_s": cpu, "load": load,
            "run_cpu_s": [float(r["cpu_time_s"]) for r in rows], "run_wall_s": [float(r["wall_time_s"]) for r in rows]}


def _scheduler_overhead(tasks: int) -> dict:
    """A 2-worker LocalCluster of the project's executor: its start and stop, and a no-op task's round trip."""
    from ballchain.executor import Executor

    t0 = time.perf_counter()
    with Executor(workers=2) as ex:
        started = time.perf_counter() - t0
        ex.client.gather(ex.client.map(abs, range(8)))  # the workers warm
        t1 = time.perf_counter()
        for i in range(tasks):  # one at a time: the latency a run's result waits for
            ex.client.submit(abs, -i, pure=False).result()
        serial = (time.perf_counter() - t1) / tasks
        t2 = time.perf_counter()
        ex.client.gather(ex.client.map(abs, range(-tasks, 0), pure=False))
        mapped = (time.perf_counter() - t2) / tasks
        t3 = time.perf_counter()
    stopped = time.perf_counter() - t3
    return {"cluster_start_s": started, "cluster_stop_s": stopped, "task_round_trip_s": serial,
            "task_throughput_s": mapped, "tasks": tasks}


def makespan(walls: list[float], n: int) -> float:
    """The runs' wall times scheduled longest first on n workers: the last worker's finish."""
    finish = [0.0] * n
    for w in sorted(walls, reverse=True):
        heapq.heapreplace(finish, finish[0] + w)
    return max(finish)


def warm_up(rows: list[dict], overhead: dict) -> float:
    """A worker's own start (its process, imports and compiled kernels, the plans it is sent): the
    1-worker row's wall time less the serial row's and the cluster's start, stop and round trips
    (0 without a 1-worker row)."""
    serial = next(r for r in rows if r["workers"] == 0)
    one = next((r for r in rows if r["workers"] == 1), None)
    if one is None:
        return 0.0
    n = len(serial["run_wall_s"])
    return max(0.0, one["wall_s"] - serial["wall_s"] - overhead["cluster_start_s"] - overhead["cluster_stop_s"]
               - n * overhead["task_round_trip_s"])


def estimate(rows: list[dict], overhead: dict, nodes: int) -> float:
    """The study's wall time on ``nodes`` workers (each on a core of its own): the serial command's
    fixed cost (its wall time less its runs'), the cluster's start and stop, a worker's warm-up
    (``warm_up``: the workers start side by side), the makespan of the serial runs' wall times and
    each run's round trip."""
    serial = next(r for r in rows if r["workers"] == 0)
    fixed = serial["wall_s"] - sum(serial["run_wall_s"])
    runs = serial["run_wall_s"]
    return (fixed + overhead["cluster_start_s"] + overhead["cluster_stop_s"] + warm_up(rows, overhead)
            + makespan(runs, nodes) + len(runs) * overhead["task_round_trip_s"] / nodes)


def report(args_arms, seeds: int, rows: list[dict], overhead: dict, nodes) -> dict:
    """Print the tables; return the estimates."""
    serial = next(r for r in rows if r["workers"] == 0)
    n_runs = len(serial["run_cpu_s"])
    print(f"trials: {len(args_arms)} arm(s) x {seeds} seed(s) = {n_runs} runs; arms {' '.join(args_arms)}")
    print(f"per run (serial): CPU median {statistics.median(serial['run_cpu_s']):.2f} s, "
          f"sum {sum(serial['run_cpu_s']):.1f} s; wall sum {sum(serial['run_wall_s']):.1f} s, "
          f"longest {max(serial['run_wall_s']):.1f} s")
    print(f"scheduler (2-worker LocalCluster): start {overhead['cluster_start_s']:.2f} s, stop "
          f"{overhead['cluster_stop_s']:.2f} s, a no-op task's round trip {1e3 * overhead['task_round_trip_s']:.2f} ms, "
          f"mapped {1e3 * overhead['task_throughput_s']:.2f} ms a task; a worker's warm-up "
          f"{warm_up(rows, overhead):.1f} s (from the 1-worker row)")
    print("\n| workers | wall [s] | CPU, command + workers [s] | runs' CPU [s] | load | speed-up (wall) | estimate [s] |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        est = "-" if r["workers"] == 0 else f"{estimate(rows, overhead, r['workers']):.1f}"
        print(f"| {r['workers'] or 'serial'} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {sum(r['run_cpu_s']):.1f} | "
              f"{r['load']:.1f} | {serial['wall_s'] / r['wall_s']:.2f}x | {est} |")
    print("\n| nodes | estimated wall [s] | per run [s] |")
    print("|---:|---:|---:|")
    estimates = {n: estimate(rows, overhead, n) for n in nodes}
    for n, e in estimates.items():
        print(f"| {n} | {e:.1f} | {e / n_runs:.2f} |")
    return estimates


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=4, help="seeds 0..N-1 per arm (default: 4)")
    parser.add_argument("--arms", nargs="+", default=["robotic_right", "procedure_right_auto"])
    parser.add_argument("--targets", type=int, default=None, help="first N targets (default: whole tasks)")
    parser.add_argument("--workers", type=int, nargs="+", default=[0, 1, 2], help="the rows (0: serial)")
    parser.add_argument("--nodes", type=int, nargs="+", default=[1, 2, 4, 8, 16, 40],
                        help="the estimate's cluster sizes")
    parser.add_argument("--tasks", type=int, default=200, help="no-op tasks for the scheduler's overhead")
    parser.add_argument("--json", type=Path, default=None, help="write the figures here (atomically)")
    parser.add_argument("--from-json", type=Path, default=None, help="print the tables of a saved --json (no runs)")
    args = parser.parse_args(argv)
    if args.seeds < 1 or args.tasks < 1 or 0 not in args.workers or min(args.workers) < 0:
        parser.error("--seeds and --tasks must be at least 1, and --workers non-negative and including 0 "
                     "(the estimate's base)")
    if min(args.nodes) < 1 or (args.targets is not None and args.targets < 1):
        parser.error(f"--nodes and --targets must be at least 1, got {args.nodes} and {args.targets}")
    if args.from_json is not None and not args.from_json.is_file():
        parser.error(f"--from-json {args.from_json}: no such file")
    if args.json is not None:
        check_output_file(args.json, "--json")

    if args.from_json is not None:  # the tables again from a saved measurement
        saved = json.loads(args.from_json.read_text())
        report(saved["arms"], saved["seeds"], saved["rows"], saved["overhead"], args.nodes)
        return 0
    root = Path(tempfile.mkdtemp(prefix="trials_scaling_"))
    try:
        rows = [_trials(root / f"w{w}", w, args.seeds, args.arms, args.targets) for w in args.workers]
    finally:
        shutil.rmtree(root, ignore_errors=True)
    overhead = _scheduler_overhead(args.tasks)
    estimates = report(args.arms, args.seeds, rows, overhead, args.nodes)
    if args.json is not None:
        atomic_write_text(args.json, json.dumps({"arms": args.arms, "seeds": args.seeds, "targets": args.targets,
                                                 "rows": rows, "overhead": overhead,
                                                 "estimates": {str(k): v for k, v in estimates.items()}}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
