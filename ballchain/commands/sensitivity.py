"""The sensorless force estimate under mismatch (issue 43): the procedure's autonomous navigator
in a world it does not know, each perturbation alone at its published magnitude and all together
(``experiments/world_sensitivity.py``; the perturbations and their sources: docs/guide/world.md).

Prints per ring and condition the targets reached, the estimate's error over the dwells and the
fraction of the dwells in the force window; ``--json`` the whole result; ``--cache FILE`` keeps
every finished run there (a run stopped resumes from it); ``--out DIR`` writes the result to
``DIR/sensitivity.json``, which ``ballchain reproduce --out OUT`` lays out as its "world
sensitivity" section when DIR is ``OUT/sensitivity`` (``reproduce/sensitivity.py``).
"""

from __future__ import annotations

import argparse

from ballchain.commands._common import add_json_flag, float_in, int_in, path_arg, positive_int, print_json
from ballchain.experiments import world_sensitivity
from ballchain.infrastructure.safe_files import check_output_dir, write_json


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ring", choices=(*world_sensitivity.RINGS, "both"), default="both",
                        help="the ring: right (one unit), left (two units) or both")
    parser.add_argument("--seeds", type=int_in(1, 100), default=3, help="seeds per condition (0..N-1)")
    parser.add_argument("--targets", type=positive_int, default=6,
                        help="the first N targets of each ring (a whole ring costs tens of CPU seconds a run)")
    parser.add_argument("--dwell", type=float_in(0.0, 120.0, lo_open=True), default=10.0,
                        help="the RF time at each target [s]")
    parser.add_argument("--only", choices=world_sensitivity.CONDITIONS, nargs="+", default=None, metavar="CONDITION",
                        help="only these conditions, among: " + ", ".join(world_sensitivity.CONDITIONS) +
                             " (default: none, each perturbation alone, all)")
    parser.add_argument("--scales", type=float_in(0.0, 10.0, lo_open=True), nargs="+", default=(), metavar="S",
                        help="more rows: every perturbation at S times its magnitude (e.g. 0.25 0.5 2)")
    parser.add_argument("--cache", type=path_arg, default=None, metavar="FILE",
                        help="keep every finished run in this JSON file and resume from it")
    parser.add_argument("--out", type=path_arg, default=None, metavar="DIR",
                        help="write the result to DIR/sensitivity.json (the report reads OUT/sensitivity/sensitivity.json)")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    rings = world_sensitivity.RINGS if args.ring == "both" else (args.ring,)
    if args.out is not None:  # before the runs: a folder that cannot be written is said now
        check_output_dir(args.out, "--out", names=("sensitivity.json",))
    result = world_sensitivity.run(rings, tuple(range(args.seeds)), targets=args.targets, dwell_s=args.dwell,
                                   conditions=tuple(args.only or world_sensitivity.CONDITIONS), scales=tuple(args.scales),
                                   cache=args.cache)
    if args.out is not None:
        write_json(args.out / "sensitivity.json", result.to_dict())
    if args.json:
        print_json(result)
        return 0
    print(f"{'ring':6s} {'condition':21s} {'magnitude':>10s} {'reached':>8s} {'|error| gf':>10s} "
          f"{'worst gf':>9s} {'in window':>9s} {'> TactiCath':>11s}")
    for r in result.rows:
        err = "-" if r["estimate_mean_abs_error_gf"] is None else f"{r['estimate_mean_abs_error_gf']:.2f}"
        worst = "-" if r["estimate_worst_error_gf"] is None else f"{r['estimate_worst_error_gf']:.2f}"
        inside = "-" if r["in_window_fraction"] is None else f"{100 * r['in_window_fraction']:.0f}%"
        worse = "-" if r["worse_than_tacticath"] is None else f"{100 * r['worse_than_tacticath']:.0f}%"
        print(f"{r['ring']:6s} {r['condition']:21s} {r['magnitude'] or '':>10s} {r['reached']:>3d}/{r['targets']:<4d} "
              f"{err:>10s} {worst:>9s} {inside:>9s} {worse:>11s}")
    print(f"{len(result.runs)} runs, {result.settings['cpu_time_s']} CPU s (the first {args.targets} targets, "
          f"{args.dwell:g} s dwells)")
    if args.out is not None:
        print(f"written: {args.out / 'sensitivity.json'}")
    return 0
