"""Model-based steering (beyond the paper): a plan that visits every ablation target of a task
through contact equilibria pressing at least 10 gf, and its time.

At each target a MathematicalProgram (SNOPT) finds the smallest magnet turn from the previous
orientation, and the inserted length, whose equilibrium presses the tip on the wall within the
target's circle with at least ``--min-force`` gf, held by friction (``--friction``, by default
the simulation's contact coefficient). Task "left" is the paper's Task I (20 targets around the
left veins), "right" Task II (18 around the right veins); one prototype magnet 10 cm beyond the
right carina, as in the paper. Prints per-target forces and turns, and the plan's time beside
the operator's. ``--anatomy FILE`` plans on a user's anatomy file (``drake_models/anatomy.py``: a
segmented atrium or a bench phantom, its targets, sheath and magnet unit) instead: every target in
file order (``--task X``: only those named X_...).
"""

from __future__ import annotations

import argparse

from ballchain.commands._common import add_json_flag, float_in, int_in, path_arg, positive_int, print_json
from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.experiments import planner


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task", default=None,
                        help="which ring of targets of the procedural atrium: left or right (default: left); with "
                             "--anatomy, only the targets named TASK_... (default: all, in file order)")
    parser.add_argument("--anatomy", type=path_arg, default=None, metavar="FILE",
                        help="an anatomy file (YAML: mesh, length_unit, side, targets, sheath, magnets) to plan on")
    parser.add_argument("--targets", type=positive_int, default=None, help="only the first N targets (default: all)")
    parser.add_argument("--balls", type=int_in(2, 64), nargs="+", default=[12, 16],
                        help="inserted chain lengths to try (balls beyond the sheath, ball 1 included)")
    parser.add_argument("--min-force", type=float_in(0.0, 1000.0, lo_open=True), default=planner.MIN_FORCE_GF,
                        help="force each equilibrium must press [gf] (0..1000]")
    parser.add_argument("--friction", type=float_in(0.0, 10.0), default=None,
                        help="tip-wall friction coefficient, 0..10 (default: the simulation's contact model)")
    parser.add_argument("--grid", type=int_in(2, 64), default=4,
                        help="azimuth samples of the fallback search for the hardest-pressing orientation (2..64)")
    parser.add_argument("--refine", type=int_in(1, 2000), default=15,
                        help="Nelder-Mead evaluations of that search (1..2000)")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    if args.task is not None and args.anatomy is None and args.task not in planner.TASKS:
        raise UserInputError(f"--task must be left or right, got {short_repr(args.task)}")
    extra = {} if args.friction is None else {"friction": args.friction}
    data = planner.run(task=args.task, targets=args.targets, balls=tuple(args.balls), grid=args.grid,
                       refine=args.refine, min_force_gf=args.min_force, anatomy=args.anatomy, **extra)
    if args.json:
        print_json(data)
        return 0
    if data.anatomy is not None:
        a = data.anatomy
        print(f"anatomy {a['file']} ({a['side']} side, {len(a['targets'])} targets, magnet unit at "
              f"{a['magnets_mm'][0]} mm{' (the default place)' if a['magnets_default'] else ''})")
    for r in data.rows:
        force = (f"no plan: {r['reason']}" if not r["reached"] else
                 f"{r['force_gf']:6.2f} gf with {r['n_balls']} balls, turn {r['turn_deg']:6.1f} deg, "
                 f"friction needed {r['friction_needed']:.3f}, {r['offset_mm']:.2f} mm off centre, magnet "
                 f"dipole {[round(v, 3) for v in r['dipole_W']]} (world)")
        print(f"{r['target']:9s} {force}")
    s = data.summary
    human = "" if data.paper is None else f" (operator in the paper: {data.paper['human_time_s']:.0f} s)"
    print(f"{s.reached}/{s.targets} planned, {s.with_at_least_10_gf} with >= {data.min_force_gf:g} gf; plan "
          f"{s.plan_time_s:.1f} s{human}")
    return 0
