"""``ballchain bench statics``: a thin adapter over ``ballchain.experiments.statics_bench`` (its
docstring says what is timed and how)."""

from __future__ import annotations

import argparse

from ballchain.commands._common import add_json_flag, finite_float, non_negative_int, positive_int, print_json
from ballchain.experiments.statics_bench import _OPTIONAL, StaticsBenchResult, run_statics

TARGETS = ("statics",)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("target", choices=TARGETS, help="what to benchmark: statics (the chain's equilibrium solve)")
    parser.add_argument("--balls", type=positive_int, default=16, help="number of balls, >= 2 (default 16)")
    parser.add_argument("--field-mT", type=finite_float, default=23.0, help="uniform field magnitude [mT] (default 23)")
    parser.add_argument("--angle-deg", type=finite_float, default=90.0,
                        help="field angle from +x towards +y [deg] (default 90)")
    parser.add_argument("--warm-offset-deg", type=finite_float, default=2.5,
                        help="warm solves start from the equilibrium at angle minus this [deg] (default 2.5)")
    parser.add_argument("--repeats", type=positive_int, default=5, help="timed solves per case (default 5)")
    parser.add_argument("--baseline-ftol", type=finite_float, default=1e-12,
                        help="SLSQP tolerance on the scaled energy (default 1e-12: tight enough to reach "
                             "the same minimum)")
    parser.add_argument("--blas-threads", type=non_negative_int, default=1,
                        help="limit OpenBLAS to this many threads during the run; 0 leaves it alone (default 1)")
    parser.add_argument("--cases", default=",".join(_OPTIONAL),
                        help="comma-separated baselines to time besides the Newton solve on the kernels: "
                             f"any of {', '.join(_OPTIONAL)} (default all; leave out snopt and baseline "
                             "for long chains)")
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                        help="time the solves by wall time (default) or by this process's CPU time "
                             "(steadier on a machine shared with other jobs)")
    parser.add_argument("--compile-cost", action="store_true",
                        help="also time the kernels' first run in a fresh process, with an empty numba "
                             "cache and with the cache (a few tens of seconds)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    add_json_flag(parser)


# --- BLAS threads ---------------------------------------------------------------------------------


def _print_statics(out: StaticsBenchResult) -> None:
    print(f"statics of {out.n_balls} balls, {out.field_mT:g} mT at {out.angle_deg:g} deg "
          f"(warm start from {out.warm_start_angle_deg:g} deg), {out.repeats} repeats, "
          f"median {'CPU' if out.clock == 'cpu' else 'wall'} time:")
    it = out.iterations
    rows = (
        ("newton compiled, cold", out.cold_median_ms, it["newton_cold"]),
        ("newton compiled, warm", out.warm_median_ms, it["newton_warm"]),
        ("newton (Python), cold", out.python_cold_median_ms, it["python_cold"]),
        ("newton (Python), warm", out.python_warm_median_ms, it["python_warm"]),
        ("newton (numpy), cold", out.numpy_cold_median_ms, it["numpy_cold"]),
        ("newton (numpy), warm", out.numpy_warm_median_ms, it["numpy_warm"]),
        ("snopt, cold", out.snopt_cold_median_ms, it["snopt_cold"]),
        ("snopt, warm", out.snopt_warm_median_ms, it["snopt_warm"]),
        ("SLSQP baseline, cold", out.baseline_median_ms, it["baseline"]),
    )
    for name, ms, iters in rows:
        if ms is not None:
            print(f"  {name:<22s} {ms:10.2f} ms   {iters:5d} iterations")
    if out.speedup_cold is not None:
        print(f"  speedup (baseline / newton cold): {out.speedup_cold:.1f}x, warm: {out.speedup_warm:.1f}x")
    if out.compiled_speedup_cold is not None:
        print(f"  compiled vs Python solver (same kernels): cold {out.compiled_speedup_cold:.1f}x, "
              f"warm {out.compiled_speedup_warm:.1f}x")
    if out.kernel_speedup_cold is not None:
        print(f"  compiled vs Python solver on the numpy reference: cold {out.kernel_speedup_cold:.1f}x, "
              f"warm {out.kernel_speedup_warm:.1f}x")
    if out.contact is not None:
        c, py = out.contact["compiled"], out.contact["python"]
        print(f"  in contact (16 balls in the atrium, {out.contact['solves']} warm solves, "
              f"{out.contact['in_contact']} of each pass touching): compiled median {c['median_ms']:.2f} ms, "
              f"p99 {c['p99_ms']:.2f}, max {c['max_ms']:.2f}; Python {py['median_ms']:.2f} / {py['p99_ms']:.2f} / "
              f"{py['max_ms']:.2f} ms: {out.contact['speedup_median']:.1f}x (largest position difference "
              f"{out.contact['max_position_diff_m']:.1e} m)")
    if out.compile_cost is not None:
        c = out.compile_cost
        print(f"  kernels' first run in a fresh process: {c['empty_cache_s']:.1f} s with an empty numba cache, "
              f"{c['cached_s']:.2f} s cached (compilation {c['compile_s']:.1f} s wall, {c['compile_cpu_s']:.1f} s "
              "CPU, once per machine)")
    same = out.same_minimum
    worst_tip = max(v["tip_diff_m"] for k, v in same.items() if isinstance(v, dict) and "tip_diff_m" in v)
    worst_e = max(v["energy_diff_rel"] for k, v in same.items() if isinstance(v, dict) and "energy_diff_rel" in v)
    print(f"  same minimum: {'yes' if same['ok'] else 'NO'} (largest tip difference {worst_tip:.2e} m, "
          f"energy {worst_e:.2e} relative)")
    differ = [k for k, v in same.items() if isinstance(v, dict) and v.get("ok") is False]
    if differ:
        print(f"  not at the Newton cold minimum: {', '.join(differ)} (a saddle or another local minimum; "
              "times are not comparable)")


def main(args: argparse.Namespace) -> int:
    if args.target == "statics":
        out = run_statics(
            n_balls=args.balls,
            field_mT=args.field_mT,
            angle_deg=args.angle_deg,
            warm_offset_deg=args.warm_offset_deg,
            repeats=args.repeats,
            baseline_ftol=args.baseline_ftol,
            blas_threads_limit=args.blas_threads,
            progress=not args.no_progress,
            cases=args.cases,
            measure_compile_cost=args.compile_cost,
            clock=args.clock,
        )
        if args.json:
            print_json(out)
        else:
            _print_statics(out)
    return 0
