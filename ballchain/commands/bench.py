"""``ballchain bench statics|engine|scaling``: a thin adapter over ``ballchain.experiments.statics_bench``
(statics) and ``ballchain.experiments.engine_bench`` (engine: the quasi-static engine at 1 kHz along
a teleoperation path; scaling: solve time against chain length); their docstrings say what is
timed and how."""

from __future__ import annotations

import argparse

from ballchain.commands._common import add_json_flag, finite_float, int_in, path_arg, positive_int, print_json
from ballchain.infrastructure.errors import UserInputError
from ballchain.experiments.statics_bench import _OPTIONAL, StaticsBenchResult, run_statics

TARGETS = ("statics", "engine", "scaling")
# The flags each target reads (besides --clock, --no-progress, --json); any other given is refused.
_STATICS_FLAGS = ("balls", "field_mT", "angle_deg", "warm_offset_deg", "repeats", "baseline_ftol", "blas_threads",
                  "cases", "compile_cost")
_FLAGS = {
    "statics": _STATICS_FLAGS,
    "engine": ("scenario", "path_s", "rate_hz", "no_reference"),
    "scaling": ("sizes", "field_mT", "angle_deg", "warm_offset_deg", "repeats", "no_reference", "out"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("target", choices=TARGETS,
                        help="what to benchmark: statics (the chain's equilibrium solve against SLSQP), engine "
                             "(the quasi-static engine at 1 kHz along a teleoperation path, compiled vs Python "
                             "reference), scaling (solve time against chain length, free and on a wall)")
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
    parser.add_argument("--blas-threads", type=int_in(0, 256), default=1,
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
    parser.add_argument("--scenario", default="teleop_right_unit",
                        help="engine: the teleoperation scenario whose path is replayed (teleop_right_unit, "
                             "teleop_two_units; default teleop_right_unit)")
    parser.add_argument("--path-s", type=finite_float, default=0.7,
                        help="engine: simulated time of the recorded path [s] (default 0.7: the joystick's sweep)")
    parser.add_argument("--rate-hz", type=finite_float, default=1000.0,
                        help="engine: updates per simulated second (default 1000: one equilibrium per ms of path)")
    parser.add_argument("--sizes", default="8,16,32,64",
                        help="scaling: comma-separated chain lengths (default 8,16,32,64)")
    parser.add_argument("--no-reference", action="store_true",
                        help="engine, scaling: leave out the Python reference solver (compiled only)")
    parser.add_argument("--out", type=path_arg, default=None,
                        help="scaling: write scaling.csv, scaling.md and scaling.png into this folder")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    add_json_flag(parser)
    parser.set_defaults(_defaults={dest: parser.get_default(dest) for flags in _FLAGS.values() for dest in flags})


def _check_flags(args: argparse.Namespace) -> None:
    """A flag of another target given with this one is refused (it would be ignored)."""
    for dest, default in args._defaults.items():
        if dest not in _FLAGS[args.target] and getattr(args, dest) != default:
            raise UserInputError(f"--{dest.replace('_', '-')} does not apply to bench {args.target} "
                                 f"(its flags: {', '.join('--' + f.replace('_', '-') for f in _FLAGS[args.target])})")


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
    print(f"  newton compiled, cold, back to back: {out.cold_back_to_back_median_ms:.2f} ms (the same solve "
          f"repeated: above, each solve follows another solver, which leaves the caches cold)")
    if out.speedup_cold is not None:
        print(f"  speedup (baseline / newton cold): {out.speedup_cold:.1f}x (back to back "
              f"{out.speedup_cold_back_to_back:.1f}x), warm: {out.speedup_warm:.1f}x")
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


def _print_engine(out) -> None:
    clock = "CPU" if out.clock == "cpu" else "wall"
    print(f"engine along {out.scenario}'s path (insertion {out.insertion}), {out.path_s:g} s at {out.rate_hz:g} Hz: "
          f"{out.path_points} points ({out.skipped} unchanged skipped), {100 * out.in_contact:.0f} % in contact "
          f"(median {out.median_wall_contacts:g} balls on the wall); update times, {clock}:")
    for name in ("compiled", "reference"):
        r = getattr(out, name)
        if r is None:
            continue
        u, s = r["update"], r["solve"]
        print(f"  {name:<10s} median {u['median_ms']:7.3f} ms  p99 {u['p99_ms']:7.3f}  max {u['max_ms']:7.3f}  "
              f"rate {u['achieved_rate_hz']:7.0f} Hz  "
              f"within {1e3 / out.rate_hz:g} ms: {100 * u['within_period']:.1f} %  "
              f"(solve alone: median {s['median_ms']:.3f} ms; {r['median_iterations']:g} iterations; "
              f"{r['failures']} failures)")
    if out.speedup_median is not None:
        print(f"  reference / compiled (same run): median {out.speedup_median:.1f}x, p99 {out.speedup_p99:.1f}x; "
              f"largest ball difference {out.max_position_difference_m:.1e} m")


def _print_scaling(out) -> None:
    from ballchain.experiments.engine_bench import scaling_markdown

    print(f"statics solve against chain length, {out.field_mT:g} mT at {out.angle_deg:g} deg, median of "
          f"{out.repeats} ({'CPU' if out.clock == 'cpu' else 'wall'} time):")
    print(scaling_markdown(out), end="")
    for path in out.files or ():
        print(f"  wrote {path}")


def _run_other(args: argparse.Namespace) -> int:
    from ballchain.experiments import engine_bench

    if args.target == "engine":
        out = engine_bench.run(scenario=args.scenario, path_s=args.path_s, rate_hz=args.rate_hz, clock=args.clock,
                               reference=not args.no_reference, progress=not args.no_progress, freeze_gc=True)
    else:
        out = engine_bench.run_scaling(sizes=args.sizes, field_mT=args.field_mT, angle_deg=args.angle_deg,
                                       warm_offset_deg=args.warm_offset_deg, repeats=args.repeats, clock=args.clock,
                                       reference=not args.no_reference, out=args.out,
                                       progress=not args.no_progress)
    if args.json:
        print_json(out)
    elif args.target == "engine":
        _print_engine(out)
    else:
        _print_scaling(out)
    return 0


def main(args: argparse.Namespace) -> int:
    _check_flags(args)
    if args.target != "statics":
        return _run_other(args)
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
