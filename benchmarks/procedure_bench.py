"""CPU time of a whole procedure (issue 48): the ring's planning, cold and from the cache, and the
run with its plans given, with the force model's compiled held-tip path on and off in the same
process (``optimization.compiled_held_tip``; off: ``ChainStatics.solve`` on ``FieldSources``, the
code before issue 48, the same numbers).

``--planner-held-solve`` also times a cold plan as the planner makes it (its held-tip solves
through ``compiled_held_tip.held_solve``, its sources built without re-validation) against the
code before that wiring (``ChainStatics.solve`` and validated ``MagnetSource``s, put back for this
process only), alternating, and checks that the plans are the same, every array.

``--sensitivities`` times a cold plan as the planner makes it (the held tip's analytic
sensitivities, ``optimization.held_sensitivity``, and the warm starts their tangent predicts;
SNOPT's limit of 100 major iterations; the
hardest-press searches on the compiled held solve, each kept for the target's next force)
against the code before (forward differences, 60 iterations, ``ChainStatics.solve``, every
search made again: put back for this process only), alternating, and reports how far the plans
are apart (``dipoles_W``, ``J_m``, ``J_o``, ``force_N``: the largest difference and the target).

The machine is shared: every figure is process CPU time (``time.process_time``), each run
``--repeats`` times alternating the two paths, the median printed, and the ratio of the medians
taken in the same run. ``--profile`` prints the cProfile of one run (fast path) by internal time.

    python benchmarks/procedure_bench.py --task right --repeats 2
    python benchmarks/procedure_bench.py --targets 4 --dwell 2 --cold --profile --json out.json
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import statistics
import time

import numpy as np

from ballchain.drake_models.field_sources import FieldSources, MagnetSource, rotation_with_z_along
from ballchain.infrastructure.safe_files import atomic_write_text, check_output_file
from ballchain.drake_models.params import CylinderMagnet
from ballchain.experiments import planner, procedure
from ballchain.experiments import forces
from ballchain.optimization import compiled_held_tip, inverse_statics
from ballchain.optimization.statics import ChainStatics

RESULT_KEYS = ("reached", "in_window_fraction", "estimate_mean_abs_error_gf", "estimate_worst_error_gf",
               "sim_time_s")


def _run(args, plans, fast: bool):
    """One run with the plans given; returns (CPU s, the summary)."""
    saved = compiled_held_tip.HeldTipStatics._fast_ready
    if not fast:
        compiled_held_tip.HeldTipStatics._fast_ready = lambda self, m, t: False
    try:
        c0 = time.process_time()
        result = procedure.run(args.task, plans=plans, targets=args.targets, dwell_s=args.dwell, progress=False,
                               lesions=False)
        return time.process_time() - c0, result
    finally:
        compiled_held_tip.HeldTipStatics._fast_ready = saved


def _same_plans(a, b) -> bool:
    fields = ("p_WT", "n_W", "dipoles_W", "inserted_length", "basis_W", "J_m", "J_o", "force_N", "aim_offset")
    return len(a.plans) == len(b.plans) and a.missing == b.missing and all(
        p.name == q.name and all(np.array_equal(getattr(p, f), getattr(q, f)) for f in fields)
        for p, q in zip(a.plans, b.plans))


def _old_field_for(stand):
    """``planner._field_for`` before issue 48's wiring: a validated ``MagnetSource`` per direction."""
    magnet, p_M = CylinderMagnet(), stand.magnets["1"]
    return lambda m: FieldSources([MagnetSource(magnet, p_M, rotation_with_z_along(m.reshape(-1, 3)[0]))])


def _general_held(statics, external, warm_start, tip_target):
    return ChainStatics.solve(statics, external, warm_start, tip_target=tip_target)


def _cold_plan(args, before: bool):
    """A cold plan (CPU s, plans); ``before``: the planner's held solves through ``ChainStatics.solve``
    and its sources validated per solve (the code before the wiring, for this process only)."""
    saved = inverse_statics.held_solve, planner._field_for
    if before:
        inverse_statics.held_solve, planner._field_for = _general_held, _old_field_for
    try:
        c0 = time.process_time()
        plans = procedure.plan_ring(args.task, targets=args.targets, cache=False)
        return time.process_time() - c0, plans
    finally:
        inverse_statics.held_solve, planner._field_for = saved


PLAN_FIELDS = ("dipoles_W", "J_m", "J_o", "force_N")


def _plan_differences(a, b) -> dict:
    """The largest absolute difference of each of ``PLAN_FIELDS`` between two ring plans (the
    same targets), with the target where it is."""
    if [p.name for p in a.plans] != [p.name for p in b.plans]:
        return {"same_targets": False}
    out: dict = {"same_targets": True}
    for f in PLAN_FIELDS:
        gaps = [(float(np.max(np.abs(np.asarray(getattr(p, f)) - np.asarray(getattr(q, f))))), p.name)
                for p, q in zip(a.plans, b.plans)]
        worst = max(gaps)
        out[f] = {"max_abs": worst[0], "target": worst[1],
                  "median_target_max_abs": statistics.median(g for g, _ in gaps) if gaps else None}
    return out


def _sensitivities_before():
    """Put back, for this process, the planner before issue 48's sensitivities: the held tip's
    forward differences, SNOPT's 60 major iterations, the hardest-press searches on
    ``ChainStatics.solve`` and made again for every force. Returns the undo."""
    saved = (inverse_statics.HeldTip.value_and_jacobian, inverse_statics.min_turn_orientation,
             planner.min_turn_orientation, forces.held_solve, planner._hardest_press)
    vj, turn = saved[0], saved[1]

    def fd(self, x, step=1e-5, method="fd"):
        return vj(self, x, step, method)

    def sixty(*args, major_iterations=60, **kwargs):
        return turn(*args, major_iterations=major_iterations, **kwargs)

    inverse_statics.HeldTip.value_and_jacobian = fd
    inverse_statics.min_turn_orientation = planner.min_turn_orientation = sixty
    forces.held_solve = _general_held
    planner._hardest_press = lambda chain, stand, name, grid, refine: planner.max_normal_force(
        chain, stand, name, ("1",), grid, refine)

    def undo():
        (inverse_statics.HeldTip.value_and_jacobian, inverse_statics.min_turn_orientation,
         planner.min_turn_orientation, forces.held_solve, planner._hardest_press) = saved
    return undo


def _cold_plan_sensitivities(args, before: bool):
    """A cold plan (CPU s, plans), ``before``: with ``_sensitivities_before``'s code."""
    undo = _sensitivities_before() if before else (lambda: None)
    planner._HARDEST.clear()  # no search kept from another plan
    try:
        c0 = time.process_time()
        plans = procedure.plan_ring(args.task, targets=args.targets, cache=False)
        return time.process_time() - c0, plans
    finally:
        undo()


def _alternate(args, cold_plan, names: tuple[str, str], label: str):
    """``cold_plan(args, before)`` ``args.repeats`` times, the code before and now alternating:
    ({name: [CPU s]}, the last plans before, the last plans now)."""
    pairs = {name: [] for name in names}
    for _ in range(args.repeats):
        for name, before in zip(names, (True, False)):
            cpu, plans = cold_plan(args, before)
            pairs[name].append(cpu)
            if before:
                old = plans
        print(f"cold plan: {names[0]} {pairs[names[0]][-1]:.2f}, {label} {cpu:.2f} CPU-s", flush=True)
    return pairs, old, plans


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="right")
    parser.add_argument("--targets", type=int, default=None)
    parser.add_argument("--dwell", type=float, default=procedure.DWELL_S)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--cold", action="store_true", help="also time a cold plan (no cache: tens of CPU-s)")
    parser.add_argument("--planner-held-solve", action="store_true",
                        help="also cold plans as wired and as before the wiring, alternating")
    parser.add_argument("--sensitivities", action="store_true",
                        help="also cold plans with the analytic sensitivities and with the forward differences, "
                             "alternating")
    parser.add_argument("--no-runs", action="store_true", help="the planning only")
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    if args.repeats < 1 or (args.targets is not None and args.targets < 1) or not args.dwell > 0:
        parser.error(f"--repeats and --targets must be at least 1 and --dwell positive, got {args.repeats}, "
                     f"{args.targets} and {args.dwell}")
    if args.json:  # the output checked before the minutes of measuring
        check_output_file(args.json, "--json")
    out: dict = {"task": args.task, "targets": args.targets, "dwell_s": args.dwell}
    if args.cold:
        c0 = time.process_time()
        cold = procedure.plan_ring(args.task, targets=args.targets, cache=False)
        out["plan_cold_cpu_s"] = time.process_time() - c0
    plans = procedure.plan_ring(args.task, targets=args.targets)  # stores them (or reads them)
    c0 = time.process_time()
    plans = procedure.plan_ring(args.task, targets=args.targets)
    out["plan_warm_cpu_s"] = time.process_time() - c0
    out["plan_warm_cached"] = plans.cached
    if args.cold:
        out["cold_equals_cached"] = _same_plans(cold, plans)
    if args.planner_held_solve:
        pairs, before, held = _alternate(args, _cold_plan, ("before", "held_solve"), "wired")
        out["planner_cold_cpu_s"] = {k: statistics.median(v) for k, v in pairs.items()}
        out["planner_cold_runs_cpu_s"] = pairs
        out["planner_held_solve_speed_up"] = statistics.median(pairs["before"]) / statistics.median(pairs["held_solve"])
        out["planner_held_solve_same_plans"] = _same_plans(before, held) and _same_plans(before, plans)
    if args.sensitivities:
        pairs, before, after = _alternate(args, _cold_plan_sensitivities, ("differences", "analytic"), "analytic")
        out["sensitivities_cold_cpu_s"] = {k: statistics.median(v) for k, v in pairs.items()}
        out["sensitivities_cold_runs_cpu_s"] = pairs
        out["sensitivities_speed_up"] = (statistics.median(pairs["differences"])
                                         / statistics.median(pairs["analytic"]))
        out["sensitivities_plans_apart"] = _plan_differences(before, after)
        out["sensitivities_missing"] = {"differences": list(before.missing), "analytic": list(after.missing)}
    if not args.no_runs:
        times: dict = {"fast": [], "general": []}
        summaries = {}
        for _ in range(args.repeats):
            for name, fast in (("general", False), ("fast", True)):
                cpu, result = _run(args, plans, fast)
                times[name].append(cpu)
                summaries[name] = {k: result.summary.get(k) for k in RESULT_KEYS}
                summaries[name]["rows"] = [(r["target"], r.get("force_true_mean_gf"), r.get("estimate_mean_error_gf"))
                                           for r in result.rows]
                print(f"{name:8s} run: {cpu:6.2f} CPU-s ({result.summary['sim_time_s']} s simulated)", flush=True)
        out.update({f"run_{k}_cpu_s": statistics.median(v) for k, v in times.items()})
        out["runs_cpu_s"] = times
        out["speed_up"] = out["run_general_cpu_s"] / out["run_fast_cpu_s"]
        out["same_results"] = summaries["fast"] == summaries["general"]
        out["summary"] = {k: v for k, v in summaries["fast"].items() if k != "rows"}
    if args.profile:
        prof = cProfile.Profile()
        prof.enable()
        _run(args, plans, True)
        prof.disable()
        pstats.Stats(prof).sort_stats("tottime").print_stats(25)
    print(json.dumps({k: v for k, v in out.items() if k != "runs_cpu_s"}, indent=1))
    if args.json:
        atomic_write_text(args.json, json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
