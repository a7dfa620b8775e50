"""Equilibrium shape of a chain in a uniform field, reached by rotating the field from +x.

The canonical problem of docs/design.md (2.3): ball 1 held at the origin with its dipole along +x,
the field in the x-y plane at ``--field-angle-deg`` from +x, reached by continuation from the
straight chain in steps of at most ``--step-deg`` (as a rotating magnet moves the chain).
The experiment is ``ballchain.experiments.statics_shape``.
"""

from __future__ import annotations

import argparse

from ballchain.commands._common import add_json_flag, float_in, int_in, print_json
from ballchain.experiments.statics_shape import MAX_BALLS, MAX_FIELD_MT, MIN_STEP_DEG, run


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--balls", type=int_in(1, MAX_BALLS), default=16, help=f"number of balls (1..{MAX_BALLS})")
    parser.add_argument("--field-mT", type=float_in(0.0, MAX_FIELD_MT), default=23.0,
                        help=f"field magnitude [mT] (0..{MAX_FIELD_MT:g})")
    parser.add_argument("--field-angle-deg", type=float_in(-360.0, 360.0), default=90.0,
                        help="field angle from +x towards +y [deg] (-360..360)")
    parser.add_argument("--step-deg", type=float_in(MIN_STEP_DEG, 90.0), default=22.5,
                        help=f"largest continuation step of the field angle [deg] ({MIN_STEP_DEG:g}..90)")
    parser.add_argument("--gravity", action="store_true", help="gravity along -z")
    parser.add_argument("--sleeve", action="store_true", help="Dragon Skin sleeve (E = 0.15 MPa)")
    parser.add_argument("--method", choices=["newton", "snopt"], default="newton",
                        help="statics solver")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    data = run(balls=args.balls, field_mT=args.field_mT, field_angle_deg=args.field_angle_deg,
               step_deg=args.step_deg, gravity=args.gravity, sleeve=args.sleeve, method=args.method)
    if args.json:
        print_json(data)
        return 0
    tip = data.positions_mm[-1]
    angle = "-" if data.tip_angle_deg is None else f"{data.tip_angle_deg:.3f} deg"
    print(f"{args.balls} balls, {args.field_mT} mT at {args.field_angle_deg} deg: tip at "
          f"({tip[0]:.2f}, {tip[1]:.2f}, {tip[2]:.2f}) mm, tip angle {angle}, "
          f"energy {data.energy_J:.4e} J ({data.reason}, {data.solve_time_s * 1e3:.1f} ms)")
    return 0
