"""Sweep executor speed-up: a small grid of the design study serially, on 1 and on 2 workers.

The points are solve-bound (statics of the chain held on a vein's pin, the magnets' orientation
optimised: a few seconds each). The three executors run the same points in the same run,
interleaved (serial, 1 worker, 2 workers, serial, ...) so that load from other jobs on the
machine falls on all of them; each LocalCluster is started and warmed (its workers have imported
the experiment) before the clock starts and closed after, so the times are the sweep's own and
no idle scheduler shares the serial run's process. Prints
medians, the speed-ups against the serial run, the machine's load average, and checks that the
three tables hold the same numbers. ``--reproduce`` also times ``reproduce --quick``'s sections
serially and through ``run_sections`` on 2 workers.

    python benchmarks/sweep_bench.py [--repeats 3] [--points 8] [--reproduce] [--json]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import statistics
import tempfile
import time
from pathlib import Path

SPEC = """
experiment: design
grid:
  ball_diameter_mm: [3.175]
  magnet: [cylinder, sphere119]
  distance_cm: [16.51, 22.0]
  vein: [LSPV, LIPV, RSPV, RIPV]
  config: ["1"]
  grid: [6]
  refine_evaluations: [20]
"""


def _warm(client) -> None:
    """Every worker imports the experiment's modules (pydrake, the statics) before timing."""
    def imports():
        import ballchain.experiments.forces  # noqa: F401
        import ballchain.experiments.studies  # noqa: F401
        return os.getpid()

    client.run(imports)


def _numbers(rows):
    return [(r["key"], r["force_gf"], r["error"]) for r in rows]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=3, help="runs of each executor (medians)")
    parser.add_argument("--points", type=int, default=8, help="design points (at most 16)")
    parser.add_argument("--reproduce", action="store_true", help="also time reproduce --quick's sections")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args()

    from distributed import Client, LocalCluster

    from ballchain.sweep import SweepSpec, load_spec, read_table, run_sweep

    full = load_spec("<bench>", text=SPEC)
    spec = SweepSpec(full.experiment, "benchmark", full.points[: args.points], [0])
    times = {"serial": [], "1 worker": [], "2 workers": []}
    loads, tables, point_seconds, busiest_cpu = [], {}, {}, {}

    def timed(name, client):
        with tempfile.TemporaryDirectory() as out:
            loads.append(os.getloadavg()[0])
            start = time.perf_counter()
            run_sweep(spec, out, workers=0 if client is None else None, client=client, progress=False, figure=False)
            times[name].append(time.perf_counter() - start)
            rows = read_table(Path(out))
            tables.setdefault(name, []).append(_numbers(rows))
            point_seconds.setdefault(name, []).append(sum(r["wall_time_s"] for r in rows))
            # The busiest worker's CPU seconds: the sweep's length on a machine nobody shares.
            per_worker = {}
            for r in rows:
                per_worker[r["worker"]] = per_worker.get(r["worker"], 0.0) + r["cpu_time_s"]
            busiest_cpu.setdefault(name, []).append(max(per_worker.values()))

    for _ in range(args.repeats):
        timed("serial", None)  # no cluster alive meanwhile: its scheduler would share this process
        for n in (1, 2):
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address=None, silence_logs=logging.ERROR)
            with Client(cluster) as client:
                _warm(client)
                timed(f"{n} worker{'s' if n > 1 else ''}", client)
            cluster.close()
    medians = {k: statistics.median(v) for k, v in times.items()}
    result = {
        "points": len(spec.points),
        "seconds": times, "median_s": medians,
        "speedup_1_worker": medians["serial"] / medians["1 worker"],
        "speedup_2_workers": medians["serial"] / medians["2 workers"],
        "two_vs_one_worker": medians["1 worker"] / medians["2 workers"],
        "load_average_1min": {"min": min(loads), "median": statistics.median(loads), "max": max(loads)},
        "cores": len(os.sched_getaffinity(0)),
        "point_seconds_median": {k: statistics.median(v) for k, v in point_seconds.items()},
        "busiest_worker_cpu_s_median": {k: statistics.median(v) for k, v in busiest_cpu.items()},
        "same_numbers": all(t == tables["serial"][0] for runs in tables.values() for t in runs),
    }
    cpu = result["busiest_worker_cpu_s_median"]
    result["cpu_speedup_2_workers"] = cpu["serial"] / cpu["2 workers"]
    if args.reproduce:
        result["reproduce"] = _bench_reproduce()
    if args.json:
        print(json.dumps(result, indent=1))
        return
    print(f"{result['points']} design points, {args.repeats} runs each, {result['cores']} cores, "
          f"load average {result['load_average_1min']['median']:.1f} (median; "
          f"{result['load_average_1min']['min']:.1f}-{result['load_average_1min']['max']:.1f})")
    for name, m in medians.items():
        print(f"  {name:10s} median {m:6.1f} s  (runs: {', '.join(f'{t:.1f}' for t in times[name])}; "
              f"sum of the points' own times {result['point_seconds_median'][name]:.1f} s)")
    print(f"  speed-up: 1 worker {result['speedup_1_worker']:.2f}x, 2 workers {result['speedup_2_workers']:.2f}x "
          f"(2 vs 1 worker {result['two_vs_one_worker']:.2f}x); same numbers: {result['same_numbers']}")
    print(f"  CPU seconds of the busiest worker: serial {cpu['serial']:.1f}, 1 worker {cpu['1 worker']:.1f}, "
          f"2 workers {cpu['2 workers']:.1f}: {result['cpu_speedup_2_workers']:.2f}x with 2 workers on an unshared "
          "machine (less the scheduling overhead)")
    if args.reproduce:
        r = result["reproduce"]
        print(f"  reproduce --quick sections: serial {r['serial_s']:.1f} s, 2 workers {r['parallel_s']:.1f} s, "
              f"speed-up {r['speedup']:.2f}x; same tables: {r['same_sections']}")


def _bench_reproduce() -> dict:
    """reproduce --quick's sections, serial then on 2 workers (one run each: minutes)."""
    from ballchain import reproduce
    from ballchain.sweep import run_sections

    def tables(runs):
        from ballchain.report import Table

        return [[b.rows for b in r.value[0].blocks if isinstance(b, Table)] for r in runs]

    out = {}
    with tempfile.TemporaryDirectory() as a, tempfile.TemporaryDirectory() as b:
        start = time.perf_counter()
        serial = run_sections(reproduce.EXPERIMENTS, a, quick=True, workers=1)
        out["serial_s"] = time.perf_counter() - start
        start = time.perf_counter()
        parallel = run_sections(reproduce.EXPERIMENTS, b, quick=True, workers=2)
        out["parallel_s"] = time.perf_counter() - start
        out["per_section_s"] = {r.name: [r.seconds, p.seconds] for r, p in zip(serial, parallel)}
        # Tables carry timings (compute time, wall time) in some sections: compare the rest.
        out["same_sections"] = [s.value[0].title for s in serial] == [p.value[0].title for p in parallel]
        out["tables_equal"] = {r.name: x == y for r, x, y in zip(serial, tables(serial), tables(parallel))}
    out["speedup"] = out["serial_s"] / out["parallel_s"]
    return out


if __name__ == "__main__":
    main()
