"""Benchmarks: medians of repeated solves and a ratio against a baseline measured in the same run.

``ballchain bench statics``: the equilibrium of an n-ball chain in a uniform field, solved by
``ChainStatics`` (Newton SQP in reduced coordinates, and its SNOPT reference) cold (from the
straight chain, no continuation) and warm (from the equilibrium at the field angle minus
``--warm-offset-deg``), against the naive SLSQP formulation of
``optimization.naive_statics`` from the straight chain. Every solver must reach the same minimum
(energy and tip position against the Newton cold solve); the differences are printed.

Wall times are measured around each ``solve`` call (``time.perf_counter``), after one untimed
round, with the cases interleaved so that a burst of load from another process hits them all.
The problems are tiny (at most a few hundred unknowns), so multithreaded BLAS only adds
synchronisation: by default the loaded OpenBLAS libraries are limited to one thread for the run
(``--blas-threads``; 0 leaves them alone). Benchmarks are scripts, not tests: the
tests check the fields' correctness, never the times.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import time

import numpy as np

from ballchain.commands._common import add_json_flag, finite_float, non_negative_int, positive_int, print_json
from ballchain.drake_models.errors import UserInputError

TARGETS = ("statics",)

# The agreement required of every solver with the Newton cold solve.
ENERGY_RTOL = 1e-9
TIP_ATOL_M = 1e-6

_CASES = ("newton_cold", "newton_warm", "snopt_cold", "snopt_warm", "baseline")


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
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    add_json_flag(parser)


# --- BLAS threads ---------------------------------------------------------------------------------
@contextlib.contextmanager
def blas_threads(n: int):
    """Limit the loaded BLAS libraries to ``n`` threads inside the block (``n = 0``: unchanged).

    Yields ``{library: threads in use}`` (what the solves ran with).
    """
    from threadpoolctl import ThreadpoolController

    controller = ThreadpoolController()
    with contextlib.ExitStack() as stack:
        if n > 0:
            stack.enter_context(controller.limit(limits=n, user_api="blas"))
        yield {info["filepath"].rsplit("/", 1)[-1]: info["num_threads"]
               for info in ThreadpoolController().info() if info["user_api"] == "blas"}


# --- statics ----------------------------------------------------------------------------------------
def _same_minimum(reference, other) -> dict:
    energy_diff = float(other.energy - reference.energy)
    tip_diff = float(np.linalg.norm(other.tip_position - reference.tip_position))
    return {
        "energy_diff_J": energy_diff,
        "energy_diff_rel": abs(energy_diff) / abs(reference.energy),
        "tip_diff_m": tip_diff,
        "max_position_diff_m": float(np.abs(other.positions - reference.positions).max()),
        "ok": bool(abs(energy_diff) <= ENERGY_RTOL * abs(reference.energy) and tip_diff <= TIP_ATOL_M),
    }


def _spread(samples_ms: list[float]) -> float:
    """(max - min) / median of a series: a rough noise figure."""
    return float((max(samples_ms) - min(samples_ms)) / np.median(samples_ms))


def run_statics(
    *,
    n_balls: int = 16,
    field_mT: float = 23.0,
    angle_deg: float = 90.0,
    warm_offset_deg: float = 2.5,
    repeats: int = 5,
    baseline_ftol: float = 1e-12,
    blas_threads_limit: int = 1,
    progress: bool = True,
) -> dict:
    """Time ``ChainStatics`` (newton, snopt; cold, warm) against the SLSQP baseline.

    Args:
        n_balls: chain length (>= 2).
        field_mT: uniform field magnitude [mT] (> 0).
        angle_deg: field angle from +x towards +y [deg].
        warm_offset_deg: warm solves start from the (Newton, cold) equilibrium at
            ``angle_deg - warm_offset_deg`` [deg].
        repeats: timed solves per case (>= 1), after one untimed round.
        baseline_ftol: SLSQP's tolerance on the scaled energy.
        blas_threads_limit: OpenBLAS threads during the run (0: unchanged).
        progress: show a tqdm bar on stderr.

    Returns:
        A JSON-able dict: medians [ms] (``cold_median_ms``, ``warm_median_ms`` for Newton,
        ``snopt_*``, ``baseline_median_ms``), ``speedup_cold`` (baseline / Newton cold), every
        sample, ``iterations`` per case, ``converged`` per case, ``same_minimum`` (each solver
        against the Newton cold solve), and the run's conditions.

    Raises:
        UserInputError: bad arguments.
    """
    if isinstance(n_balls, bool) or not isinstance(n_balls, int) or not 2 <= n_balls <= 64:
        # the SLSQP baseline's pairwise constraints grow as n^2: 64 balls already take minutes
        raise UserInputError(f"--balls must be an integer >= 2 and <= 64 (ball 1 is held), got {n_balls!r}")
    if not (math.isfinite(field_mT) and field_mT > 0):
        raise UserInputError(f"--field-mT must be a positive finite number, got {field_mT}")
    if not (math.isfinite(angle_deg) and math.isfinite(warm_offset_deg)):
        raise UserInputError("--angle-deg and --warm-offset-deg must be finite")
    if not isinstance(repeats, int) or not 1 <= repeats <= 1000:
        raise UserInputError(f"--repeats must be an integer in 1..1000, got {repeats!r}")
    if not (math.isfinite(baseline_ftol) and baseline_ftol > 0):
        raise UserInputError(f"--baseline-ftol must be a positive finite number, got {baseline_ftol}")

    from tqdm import tqdm

    from ballchain.drake_models.field_sources import UniformField
    from ballchain.drake_models.params import BallChain
    from ballchain.optimization.naive_statics import NaiveStatics
    from ballchain.optimization.statics import ChainStatics

    chain = BallChain(n_balls=n_balls)
    B = field_mT * 1e-3
    external = UniformField.in_plane(B, math.radians(angle_deg))
    warm_angle = angle_deg - warm_offset_deg
    external_warm = UniformField.in_plane(B, math.radians(warm_angle))
    newton = ChainStatics(chain, method="newton")
    snopt = ChainStatics(chain, method="snopt")

    load_before = os.getloadavg()
    bar = tqdm(total=1 + (repeats + 1) * len(_CASES), desc=f"bench statics ({n_balls} balls)", unit="solve",
               file=sys.stderr, disable=not progress, leave=False)
    with blas_threads(blas_threads_limit) as threads_in_use:
        warm_start = newton.solve(external_warm)
        bar.update()
        solves = {
            "newton_cold": lambda: newton.solve(external),
            "newton_warm": lambda: newton.solve(external, warm_start),
            "snopt_cold": lambda: snopt.solve(external),
            "snopt_warm": lambda: snopt.solve(external, warm_start),
            "baseline": lambda: NaiveStatics(chain, external, ftol=baseline_ftol).solve(),
        }
        samples: dict[str, list[float]] = {case: [] for case in _CASES}
        last = {}
        for round_ in range(repeats + 1):  # round 0 is untimed (first-call costs)
            # Rotate the order so that no case always runs first (or right after SLSQP).
            order = _CASES[round_ % len(_CASES):] + _CASES[: round_ % len(_CASES)]
            for case in order:
                t0 = time.perf_counter()
                result = solves[case]()
                elapsed = time.perf_counter() - t0
                if round_ > 0:
                    samples[case].append(1e3 * elapsed)
                last[case] = result
                bar.update()
    bar.close()
    load_after = os.getloadavg()

    reference = last["newton_cold"]
    medians = {case: float(np.median(samples[case])) for case in _CASES}
    same = {case: _same_minimum(reference, last[case]) for case in _CASES if case != "newton_cold"}
    converged = {case: bool(last[case].converged) for case in _CASES if case != "baseline"}
    converged["baseline"] = bool(last["baseline"].success)
    converged["warm_start"] = bool(warm_start.converged)
    baseline = last["baseline"]
    return {
        "benchmark": "statics",
        "n_balls": n_balls,
        "field_mT": field_mT,
        "angle_deg": angle_deg,
        "warm_start_angle_deg": warm_angle,
        "repeats": repeats,
        "cold_median_ms": medians["newton_cold"],
        "warm_median_ms": medians["newton_warm"],
        "snopt_cold_median_ms": medians["snopt_cold"],
        "snopt_warm_median_ms": medians["snopt_warm"],
        "baseline_median_ms": medians["baseline"],
        "speedup_cold": medians["baseline"] / medians["newton_cold"],
        "speedup_warm": medians["baseline"] / medians["newton_warm"],
        "speedup_cold_vs_snopt": medians["snopt_cold"] / medians["newton_cold"],
        "same_minimum": {
            "reference": "newton_cold",
            "tolerance": {"energy_rel": ENERGY_RTOL, "tip_m": TIP_ATOL_M},
            **same,
            "ok": all(v["ok"] for v in same.values()),
        },
        "converged": converged,
        "iterations": {
            "newton_cold": last["newton_cold"].iterations,
            "newton_warm": last["newton_warm"].iterations,
            "snopt_cold": last["snopt_cold"].iterations,
            "snopt_warm": last["snopt_warm"].iterations,
            "baseline": baseline.iterations,
            "baseline_evaluations": baseline.evaluations,
        },
        "iterations_note": "Newton: SQP iterations; SNOPT: energy evaluations; baseline: SLSQP iterations",
        "energy_J": reference.energy,
        "tip_position_mm": 1e3 * reference.tip_position,
        "baseline": {"ftol": baseline_ftol, "message": baseline.message,
                     "max_violation": baseline.max_violation},
        "samples_ms": samples,
        "spread": {case: _spread(samples[case]) for case in _CASES},
        "spread_note": "(max - min) / median of each case's samples",
        "blas_threads": threads_in_use,
        "load_average_1min": {"before": load_before[0], "after": load_after[0]},
        "cpu_count": os.cpu_count(),
    }


def _print_statics(out: dict) -> None:
    print(f"statics of {out['n_balls']} balls, {out['field_mT']:g} mT at {out['angle_deg']:g} deg "
          f"(warm start from {out['warm_start_angle_deg']:g} deg), {out['repeats']} repeats, median wall time:")
    it = out["iterations"]
    rows = (
        ("newton, cold", out["cold_median_ms"], it["newton_cold"]),
        ("newton, warm", out["warm_median_ms"], it["newton_warm"]),
        ("snopt, cold", out["snopt_cold_median_ms"], it["snopt_cold"]),
        ("snopt, warm", out["snopt_warm_median_ms"], it["snopt_warm"]),
        ("SLSQP baseline, cold", out["baseline_median_ms"], it["baseline"]),
    )
    for name, ms, iters in rows:
        print(f"  {name:<22s} {ms:10.2f} ms   {iters:5d} iterations")
    print(f"  speedup (baseline / newton cold): {out['speedup_cold']:.1f}x, warm: {out['speedup_warm']:.1f}x")
    same = out["same_minimum"]
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
        )
        if args.json:
            print_json(out)
        else:
            _print_statics(out)
    return 0
