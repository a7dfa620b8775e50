"""The held tip's Newton step (issue 48, docs/performance.md section 33): the Schur step of
H + rho s J'J (``compiled_newton.pinned_step``) against the null-space step it replaced
(``compiled_newton.null_space_step``, still its fallback), compiled both, on the first Newton
steps of the held-tip solves a procedure run makes (the navigator's looks, and the planner's
when its plans are not cached; captured); the numpy
reference's null-space step (``statics._null_space_step``) for scale.

Per step, the median wall time of ``--repeats`` calls (process CPU time is not fine enough for
one step), then the median over the steps: compare the ratio from one run, not the absolute
times (the machine is shared). Both steps solve the same KKT system: the largest relative KKT
residual of each (the stationarity g + H dq - J'lam against its terms' size, the pin J dq + c in
ball diameters) and the median difference of the two steps; a step's component along a flat direction of the tangent
space (the chain's symmetry about the field) is set by round-off in either, so the largest
difference of the steps themselves says little.

    python benchmarks/pinned_step_bench.py --targets 2 --repeats 5
    python benchmarks/pinned_step_bench.py --json out.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

from ballchain.experiments import procedure
from ballchain.infrastructure.safe_files import atomic_write_text, check_output_file
from ballchain.optimization import compiled_held_tip
from ballchain.optimization.compiled_newton import (evaluate, lagrangian_hessian, null_space_step, pinned_step,
                                                    tip_jacobian)
from ballchain.optimization.statics import _null_space_step


def capture(task: str, targets: int, limit: int) -> list:
    """The (chart, model tuple) of the first ``limit`` compiled held-tip solves of a procedure run
    (``targets`` targets, 1 s dwells), copied as the solve received them."""
    seen = []
    original = compiled_held_tip.newton

    def spy(chart, model, rows, weights):
        if len(seen) < limit:
            seen.append((tuple(c.copy() for c in chart), model))
        return original(chart, model, rows, weights)

    compiled_held_tip.newton = spy
    try:
        procedure.run(task, targets=targets, dwell_s=1.0, progress=False, lesions=False)
    finally:
        compiled_held_tip.newton = original
    return seen


def problems(captured: list) -> list:
    """(H, g, J, c) of each captured solve's first Newton step (at its warm start, no multipliers)."""
    out = []
    for chart, model in captured:
        ev = evaluate(np.zeros(2 * chart[0].shape[0]), 2, chart, model)
        H = lagrangian_hessian(ev, np.zeros(0, np.int64), np.zeros(0), True, np.zeros(3), model)
        out.append((H, ev[4], tip_jacobian(ev[7]), ev[6]))
    return out


def _median_time(fn, args, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _kkt_residual(H, g, J, c, dq, lam) -> tuple[float, float]:
    """(the stationarity g + H dq - J'lam relative to its terms' size, the pin's J dq + c in the
    chain's units: ball diameters, the unit of the solver's feasibility tolerance, 1e-12)."""
    Hdq, Jlam = H @ dq, J.T @ lam
    stationarity = np.abs(g + Hdq - Jlam).max() / max(np.abs(g).max(), np.abs(Hdq).max(), np.abs(Jlam).max())
    return float(stationarity), float(np.abs(J @ dq + c).max())


def run(task: str = "right", targets: int = 2, limit: int = 200, repeats: int = 5) -> dict:
    steps = problems(capture(task, targets, limit))
    if not steps:
        raise RuntimeError("the run made no compiled held-tip solve")
    pinned_step(*steps[0])  # compiled (or loaded) before the timing
    null_space_step(*steps[0])
    rows = {"null-space (numpy)": [], "null-space (compiled)": [], "Schur (compiled)": []}
    differences = []
    residual = {"null-space": [0.0, 0.0], "Schur": [0.0, 0.0]}  # [stationarity, pin]
    for H, g, J, c in steps:
        ok, dq, lam, _ = pinned_step(H, g, J, c)
        if not ok:  # no rho: the solver takes the null-space step there too
            continue
        dq0, lam0, _ = null_space_step(H, g, J, c)
        differences.append(float(np.abs(dq - dq0).max() / np.abs(dq0).max()))
        for name, (step, multipliers) in (("Schur", (dq, lam)), ("null-space", (dq0, lam0))):
            residual[name] = np.maximum(residual[name], _kkt_residual(H, g, J, c, step, multipliers)).tolist()
        rows["null-space (numpy)"].append(_median_time(_null_space_step, (H, g, J, c), repeats))
        rows["null-space (compiled)"].append(_median_time(null_space_step, (H, g, J, c), repeats))
        rows["Schur (compiled)"].append(_median_time(pinned_step, (H, g, J, c), repeats))
    if not differences:
        raise RuntimeError("no captured step was taken by the Schur step")
    medians = {k: statistics.median(v) * 1e6 for k, v in rows.items()}
    return {"task": task, "steps": len(steps), "schur_steps": len(differences), "nq": int(steps[0][0].shape[0]),
            "median_us": {k: round(v, 2) for k, v in medians.items()},
            "ratio": round(medians["null-space (compiled)"] / medians["Schur (compiled)"], 3),
            "largest_stationarity": {k: v[0] for k, v in residual.items()},
            "largest_pin_residual": {k: v[1] for k, v in residual.items()},
            "median_step_difference": statistics.median(differences)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="right", choices=("left", "right"))
    parser.add_argument("--targets", type=int, default=2, help="targets of the run whose solves are captured")
    parser.add_argument("--steps", type=int, default=200, help="at most this many held-tip solves captured")
    parser.add_argument("--repeats", type=int, default=5, help="calls per step (their median wall time)")
    parser.add_argument("--json", default=None, help="also write the figures to this file")
    args = parser.parse_args(argv)
    if args.targets < 1 or args.steps < 1 or args.repeats < 1:
        parser.error("--targets, --steps and --repeats must be positive")
    out = check_output_file(args.json, "--json") if args.json else None
    result = run(args.task, args.targets, args.steps, args.repeats)
    print(f"{result['steps']} held-tip first steps ({result['schur_steps']} by the Schur step), nq = {result['nq']}")
    for name, us in result["median_us"].items():
        print(f"  {name:20s} {us:9.2f} us (median)")
    st, pin = result["largest_stationarity"], result["largest_pin_residual"]
    print(f"  compiled null-space / Schur: {result['ratio']}x; largest stationarity (relative): null-space "
          f"{st['null-space']:.1e}, Schur {st['Schur']:.1e}; pin (ball diameters): null-space {pin['null-space']:.1e}, "
          f"Schur {pin['Schur']:.1e}; median step difference {result['median_step_difference']:.1e}")
    if out is not None:
        atomic_write_text(out, json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
