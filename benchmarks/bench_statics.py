"""Statics benchmark: ChainStatics (Newton, SNOPT; cold and warm) against the naive SLSQP baseline.

A thin script over ``ballchain.commands.bench.run_statics`` (the one implementation, also run by
``ballchain bench statics``). Prints the result as JSON: median wall times [ms], the speedup of
the Newton solve over the baseline measured in the same run, iterations, and the differences of
every solver's minimum from the Newton cold solve.
"""

from __future__ import annotations

import argparse

from ballchain.commands._common import finite_float, non_negative_int, positive_int, print_json
from ballchain.commands.bench import run_statics


def run(
    *,
    n_balls: int = 16,
    field_mT: float = 23.0,
    angle_deg: float = 90.0,
    warm_offset_deg: float = 2.5,
    repeats: int = 5,
    baseline_ftol: float = 1e-12,
    blas_threads: int = 1,
    progress: bool = True,
) -> dict:
    """The benchmark's data (see ``ballchain.commands.bench.run_statics``)."""
    return run_statics(
        n_balls=n_balls,
        field_mT=field_mT,
        angle_deg=angle_deg,
        warm_offset_deg=warm_offset_deg,
        repeats=repeats,
        baseline_ftol=baseline_ftol,
        blas_threads_limit=blas_threads,
        progress=progress,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--balls", type=positive_int, default=16, help="number of balls, >= 2 (default 16)")
    parser.add_argument("--field-mT", type=finite_float, default=23.0, help="uniform field magnitude [mT] (default 23)")
    parser.add_argument("--angle-deg", type=finite_float, default=90.0, help="field angle from +x towards +y [deg]")
    parser.add_argument("--warm-offset-deg", type=finite_float, default=2.5,
                        help="warm solves start from the equilibrium at angle minus this [deg] (default 2.5)")
    parser.add_argument("--repeats", type=positive_int, default=5, help="timed solves per case (default 5)")
    parser.add_argument("--baseline-ftol", type=finite_float, default=1e-12,
                        help="SLSQP tolerance on the scaled energy (default 1e-12)")
    parser.add_argument("--blas-threads", type=non_negative_int, default=1,
                        help="limit OpenBLAS to this many threads; 0 leaves it alone (default 1)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    args = parser.parse_args()
    print_json(run(
        n_balls=args.balls,
        field_mT=args.field_mT,
        angle_deg=args.angle_deg,
        warm_offset_deg=args.warm_offset_deg,
        repeats=args.repeats,
        baseline_ftol=args.baseline_ftol,
        blas_threads=args.blas_threads,
        progress=not args.no_progress,
    ))


if __name__ == "__main__":
    main()
