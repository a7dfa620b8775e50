"""Omni-wheel kinematics: the derived wheel-to-magnet map against the paper's, with residuals.

Derives ``omega_wheels = (rho_a/rho_w) A omega_magnet`` (rows of A = -a_i^T) from rolling without
slip at each wheel contact, shows the wheel geometry that reproduces the paper's printed A, and
measures the rolling-contact residual of the derived map and of the paper's printed
``omega_a = (rho_a/rho_w) A omega_w`` (plus the two half-fixes). The experiment is
``ballchain.experiments.wheels``.
"""

from __future__ import annotations

import argparse

import numpy as np

from ballchain.commands._common import add_json_flag, int_in, non_negative_int, print_json
from ballchain.experiments import wheels


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--samples", type=int_in(1, 1_000_000), default=1000,
        help="random wheel-speed vectors for the residual, 1..1e6 (default 1000)"
    )
    parser.add_argument("--seed", type=non_negative_int, default=0, help="random seed of the samples, >= 0 (default 0)")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    report = wheels.run(samples=args.samples, seed=args.seed)
    if args.json:
        print_json(report)
        return 0
    np.set_printoptions(precision=4, suppress=True)
    print("wheel geometry (unit frame, origin at the sphere centre):")
    print(f"  contact azimuths [deg]: {np.asarray(report.contact_azimuth_deg)}")
    print(f"  contact polar angle from nadir [deg]: {np.asarray(report.contact_polar_angle_from_nadir_deg)}")
    print(f"derived A (rows -a_i^T):\n{np.asarray(report.A_derived_rows_minus_a)}")
    print(f"paper A:\n{np.asarray(report.A_paper)}")
    print(f"max |A_derived - A_paper| = {report.max_abs_A_derived_minus_paper:.4f} (print rounding)")
    print("inverse map omega_w = (rho_a/rho_w) A omega_a; forward map omega_a = (rho_w/rho_a) A^-1 omega_w")
    print(f"forward map:\n{np.asarray(report.forward_map_sphere_from_wheels)}")
    print("relative rolling-contact residual, max over samples:")
    for name, value in report.rolling_residual_relative.items():
        print(f"  {value:10.3e}  {name}")
    print(
        f"a rotation commanded through the paper's map turns about an axis "
        f"{report.paper_map_commanded_axis_error_deg:.1f} deg off"
    )
    return 0
