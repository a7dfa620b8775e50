"""Model-based steering (beyond the paper): the magnet orientation and inserted length that hold
the tip on each ablation target hardest, and the time of a plan that visits them in order.

Task "left" is the paper's Task I (20 targets around the left veins), "right" Task II (18 around
the right veins); one prototype magnet 10 cm beyond the right carina, as in the paper. Prints
per-target forces beside the 10 gf an ablation needs, and the plan's time beside the operator's.
"""

from __future__ import annotations

import argparse

from ballchain.commands._common import add_json_flag, positive_int, print_json
from ballchain.experiments import planner


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task", choices=["left", "right"], default="left", help="which ring of targets")
    parser.add_argument("--targets", type=positive_int, default=None, help="only the first N targets")
    parser.add_argument("--balls", type=positive_int, nargs="+", default=[12, 16],
                        help="inserted chain lengths to try (balls beyond the sheath, ball 1 included)")
    parser.add_argument("--grid", type=positive_int, default=4, help="azimuth samples of the orientation grid")
    parser.add_argument("--refine", type=positive_int, default=15, help="Nelder-Mead evaluations")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    if any(n < 2 for n in args.balls):
        raise ValueError(f"--balls must be >= 2 each, got {args.balls}")
    data = planner.run(task=args.task, targets=args.targets, balls=tuple(args.balls), grid=args.grid,
                       refine=args.refine)
    if args.json:
        print_json(data)
        return 0
    for r in data["rows"]:
        force = "unreached" if not r["reached"] else f"{r['force_gf']:6.2f} gf with {r['n_balls']} balls"
        print(f"{r['target']:9s} {force}")
    s = data["summary"]
    print(f"{s['reached']}/{s['targets']} reached, {s['with_at_least_10_gf']} with >= 10 gf; plan "
          f"{s['plan_time_s']:.1f} s (operator in the paper: {data['paper']['human_time_s']:.0f} s)")
    return 0
