"""``ballchain alignment``: tip-to-field alignment against chain length (paper Fig. 5).

Prints the tip angle of every chain length at every field angle, or ``--json``; the study, its
CSV and its figures are ``ballchain.experiments.alignment``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ballchain.commands._common import add_json_flag, float_in, int_in, path_arg, print_json
from ballchain.experiments.alignment import MAX_BALLS, run
from ballchain.experiments.statics_shape import MAX_FIELD_MT


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--max-balls", type=int_in(1, MAX_BALLS), default=16, help=f"longest chain (1..{MAX_BALLS})")
    parser.add_argument("--field-mT", type=float_in(0.0, MAX_FIELD_MT, lo_open=True), default=23.0,
                        help=f"field magnitude [mT] (0..{MAX_FIELD_MT:g}]")
    parser.add_argument("--step-deg", type=float_in(0.5, 90.0), default=22.5, help="field angle step [deg] (0.5..90)")
    parser.add_argument("--sleeve", action="store_true", help="with the Dragon Skin sleeve")
    parser.add_argument("--out", type=path_arg, default=Path("results/alignment"),
                        help="folder for the CSV and PNG files")
    parser.add_argument("--no-files", action="store_true", help="write no files")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    data = run(max_balls=args.max_balls, field_mT=args.field_mT, step_deg=args.step_deg,
               sleeve=args.sleeve, out=None if args.no_files else args.out)
    if args.json:
        print_json({"rows": data.rows, "summary": data.summary, "files": data.files or []})
        return 0
    angles = sorted({r["field_angle_deg"] for r in data.rows})
    print(f"Angle between the tip's dipole and the {args.field_mT:g} mT field [deg], by chain length (rows) "
          "and field angle from +x (columns)")
    print(f"{'balls':>5s} | " + "  ".join(f"{a:>6g}" for a in angles))
    print("-" * 6 + "+" + "-" * (8 * len(angles)))
    for n in sorted({r["n_balls"] for r in data.rows}):
        vals = [r["tip_angle_deg"] for r in data.rows if r["n_balls"] == n]
        print(f"{n:5d} | " + "  ".join(f"{v:6.2f}" for v in vals))
    s = data.summary
    fmt = lambda v: "-" if v is None else f"{v:.2f} deg"  # noqa: E731
    print(f"largest tip angle of chains longer than 10 balls: {fmt(s.max_tip_angle_deg_beyond_10_balls)} "
          f"(at 180 deg: {fmt(s.max_tip_angle_deg_beyond_10_balls_at_180deg)}; the paper: < {s.paper_claim_deg:g} deg)")
    for path in data.files or []:
        print(f"wrote {path}")
    return 0
