"""Tip forces on the pulmonary veins (paper Table I) from statics with the tip held on a sensor.

For each vein, configuration (magnet on the right "1", left "2", or both) and sleeve option, the
magnet orientations that maximise the force the tip presses along the vein's axis are found by
optimisation (grid + Nelder-Mead over equilibria); each optimum is then simulated (the damped
chain in the same field, its tip held by a force-sensor pin, run to steady state), unless
``--no-dynamics``. Prints the model beside the paper's numbers and writes a CSV and a bar chart.
The experiment is ``ballchain.experiments.forces``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ballchain.commands._common import add_json_flag, int_in, path_arg, print_json
from ballchain.experiments import forces
from ballchain.experiments.forces import GRID, REFINE, VEINS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--veins", nargs="+", choices=VEINS, default=list(VEINS), help="which veins")
    parser.add_argument("--sleeve", choices=["no", "yes", "both"], default="both", help="sleeve cases")
    parser.add_argument("--grid", type=int_in(*GRID), default=8,
                        help=f"azimuth samples of the orientation grid ({GRID[0]}..{GRID[1]})")
    parser.add_argument("--refine", type=int_in(*REFINE), default=40,
                        help=f"Nelder-Mead evaluations after the grid ({REFINE[0]}..{REFINE[1]})")
    parser.add_argument("--no-dynamics", action="store_true",
                        help="statics only: skip the simulation of each optimum on the force-sensor pin")
    parser.add_argument("--out", type=path_arg, default=Path("results/forces"), help="folder for the CSV and PNG")
    parser.add_argument("--no-files", action="store_true", help="write no files")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    sleeves = {"no": (False,), "yes": (True,), "both": (False, True)}[args.sleeve]
    data = forces.run(veins=tuple(args.veins), sleeves=sleeves, grid=args.grid, refine_evaluations=args.refine,
                      out=None if args.no_files else args.out, dynamics=not args.no_dynamics)
    if args.json:
        print_json(data)
        return 0
    fmt = lambda v, spec: "-" if v is None else format(v, spec)  # noqa: E731
    print(f"{'vein':5s} {'config':6s} {'sleeve':6s} {'statics gf':>10s} {'sim gf':>9s} {'diff %':>7s} {'paper gf':>9s}")
    for r in data.rows:
        print(f"{r['vein']:5s} {r['config']:6s} {str(r['sleeve']):6s} {fmt(r['statics_gf'], '.2f'):>10s} "
              f"{fmt(r.get('dynamics_gf'), '.2f'):>9s} {fmt(r.get('statics_dynamics_diff_pct'), '+.2f'):>7s} "
              f"{r['paper_gf']:9.1f}"
              + ("" if r.get("dynamics_gf") is not None or r.get("dynamics_note") == "not simulated"
                 else f"  ({r.get('dynamics_note')})"))
    short = sum(r["refine_converged"] is False for r in data.rows)
    if short:
        print(f"note: on {short} of {len(data.rows)} rows the Nelder-Mead refinement stopped at its limit of "
              f"{args.refine} evaluations before converging: those forces may be below the optimum (raise --refine)")
    return 0
