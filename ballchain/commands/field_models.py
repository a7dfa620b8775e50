"""Point dipole vs exact (magpylib) field of the prototype cylinder magnet.

At each distance from the magnet centre and each direction (on the axis, at 45 deg, on the
equator): |B| of both models, the dipole's relative magnitude error and angle error, and the same
for the force on one ball aligned with the field (what the field gradient does to the chain),
plus the relative Frobenius error of the gradient itself. The experiment is
``ballchain.experiments.field_models``.
"""

from __future__ import annotations

import argparse
import math

from ballchain.commands._common import add_json_flag, print_json
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.params import BALL_DIAMETER_RANGE, BallChain
from ballchain.experiments.field_models import DEFAULT_DISTANCES, DEFAULT_POLAR_ANGLES_DEG, run


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--distances-cm",
        type=float,
        nargs="+",
        default=[r * 1e2 for r in DEFAULT_DISTANCES],
        help="distances from the magnet centre [cm] (default 8 12 16.51 20)",
    )
    parser.add_argument(
        "--angles-deg",
        type=float,
        nargs="+",
        default=list(DEFAULT_POLAR_ANGLES_DEG),
        help="polar angles from the magnetisation axis, 0..180 [deg] (default 0 45 90)",
    )
    parser.add_argument(
        "--ball-diameter-mm",
        type=float,
        default=BallChain().ball_diameter * 1e3,
        help="diameter of the aligned ball whose force is compared [mm] (default 3.175)",
    )
    add_json_flag(parser)


def _print_table(out) -> None:
    m = out.magnet
    print(
        f"cylinder {m['diameter_mm']:g} x {m['length_mm']:g} mm, Br {m['remanence_T']:g} T "
        f"(|m| = {m['dipole_moment_Am2']:.1f} A m^2); force on one {out.ball_diameter_mm:g} mm ball"
    )
    header = (
        f"{'r_cm':>6} {'dir':>7} {'|B|dip_mT':>10} {'|B|ex_mT':>10} {'dB_%':>7} {'angB_deg':>8} "
        f"{'dG_%':>7} {'|F|dip_gf':>10} {'|F|ex_gf':>10} {'dF_%':>7} {'angF_deg':>8}"
    )
    print(header)
    for r in out.rows:
        print(
            f"{r['distance_cm']:6.2f} {r['direction']:>7} {r['B_dipole_magnitude_mT']:10.4g} "
            f"{r['B_exact_magnitude_mT']:10.4g} {r['B_rel_error_percent']:7.2f} {r['B_angle_error_deg']:8.3f} "
            f"{r['gradient_rel_error_percent']:7.2f} {r['force_dipole_magnitude_gf']:10.4g} "
            f"{r['force_exact_magnitude_gf']:10.4g} {r['force_rel_error_percent']:7.2f} "
            f"{r['force_angle_error_deg']:8.3f}"
        )
    print(
        f"on-axis asymptote: dB/B ~ {out.on_axis_rel_error_asymptote_cm2:.2f} cm^2 / r^2 "
        "(rel error = (dipole - exact)/exact)"
    )


def main(args: argparse.Namespace) -> int:
    for d in args.distances_cm:
        if not (math.isfinite(d) and d > 0):
            raise UserInputError(f"--distances-cm must be positive finite numbers, got {d}")
    for a in args.angles_deg:
        if not (math.isfinite(a) and 0.0 <= a <= 180.0):
            raise UserInputError(f"--angles-deg must lie in [0, 180], got {a}")
    lo_mm = 1e3 * BALL_DIAMETER_RANGE[0]  # what a BallChain may be
    if not (math.isfinite(args.ball_diameter_mm) and lo_mm <= args.ball_diameter_mm <= 50):
        raise UserInputError(f"--ball-diameter-mm must be in [{lo_mm:g}, 50] mm, got {args.ball_diameter_mm}")
    for d in args.distances_cm:
        if d > 1000:
            raise UserInputError(f"--distances-cm must be at most 1000 cm, got {d}")
    out = run(
        distances_m=[d * 1e-2 for d in args.distances_cm],
        angles_deg=args.angles_deg,
        ball=BallChain(ball_diameter=args.ball_diameter_mm * 1e-3),
    )
    if args.json:
        print_json(out)
    else:
        _print_table(out)
    return 0
