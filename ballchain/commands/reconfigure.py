"""Closed-loop axis reconfiguration study (paper Section IV-B) on the simulated actuation unit.

Seeded random initial magnet orientations (the first exactly antiparallel to the neutral
direction, where the paper's law stalls), Hall-sensor noise on, wheel slip, the prototype
cylinder's exact field at the sensor and the correct dipole inverse in the estimator. Every run
must end within the tolerance of the neutral direction (true angle, not the estimate). The
experiment is ``ballchain.experiments.reconfiguration``.
"""

from __future__ import annotations

import argparse

from ballchain.commands._common import add_json_flag, finite_float, float_in, int_in, non_negative_int, print_json
from ballchain.experiments.reconfiguration import MAX_RUNS, MAX_T_MAX

# The five figures the study reports (the per-run lists stay out of the JSON).
SUMMARY_KEYS = ("runs", "converged", "max_final_error_deg", "median_time_s", "max_time_s")


def _slip(text: str) -> float:
    value = finite_float(text)
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f"must be in [0, 1), got {text}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--runs", type=int_in(1, MAX_RUNS), default=100, help=f"number of runs, 1..{MAX_RUNS} (default 100)")
    parser.add_argument("--seed", type=non_negative_int, default=0,
                        help="seed of initial orientations and noise, >= 0 (default 0)")
    parser.add_argument("--slip", type=_slip, default=0.05, help="wheel slip fraction in [0, 1) (default 0.05)")
    parser.add_argument("--no-noise", action="store_true", help="switch the Hall sensor noise off")
    parser.add_argument(
        "--field-model",
        choices=("dipole", "exact"),
        default="exact",
        help="true field of the magnet at the sensor (default exact cylinder)",
    )
    parser.add_argument(
        "--wheel-map",
        choices=("derived", "paper"),
        default="derived",
        help="wheel-speed conversion in the controller (default derived)",
    )
    parser.add_argument(
        "--tolerance-deg", type=float_in(0.0, 180.0, lo_open=True), default=1.0, help="convergence tolerance on the true error [deg] (default 1)"
    )
    parser.add_argument("--t-max", type=float_in(0.0, MAX_T_MAX, lo_open=True), default=15.0,
                        help="time limit of one run [s], (0, 600] (default 15)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    from ballchain.experiments import reconfiguration

    result = reconfiguration.run(
        runs=args.runs,
        seed=args.seed,
        slip=args.slip,
        noise=not args.no_noise,
        field_model=args.field_model,
        wheel_map=args.wheel_map,
        tolerance_deg=args.tolerance_deg,
        t_max=args.t_max,
        progress=not args.no_progress,
    )
    summary = {k: getattr(result, k) for k in SUMMARY_KEYS}
    if args.json:
        print_json(summary)
    else:
        print(
            f"{summary['converged']}/{summary['runs']} runs converged within {args.tolerance_deg} deg; "
            f"max final error {summary['max_final_error_deg']:.3f} deg; time to done: median "
            f"{summary['median_time_s']:.2f} s, max {summary['max_time_s']:.2f} s "
            f"(antiparallel start {result.antiparallel_time_s:.2f} s)"
        )
    return 0 if summary["converged"] == summary["runs"] else 1
