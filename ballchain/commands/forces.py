"""Tip forces on the pulmonary veins (paper Table I) from statics with the tip held on a sensor.

For each vein, configuration (magnet on the right "1", left "2", or both) and sleeve option, the
magnet orientations that maximise the force the tip presses along the vein's axis are found by
optimisation (grid + Nelder-Mead over equilibria); each optimum is then simulated (the damped
chain in the same field, its tip held by a force-sensor pin, run to steady state), unless
``--no-dynamics``. Prints the model beside the paper's numbers and writes a CSV and a bar chart.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ballchain.commands._common import (
    add_json_flag, check_in, int_in, note_replacements, print_json, save_figure, write_csv,
)
from ballchain.drake_models.errors import UserInputError
from ballchain.drake_models.safe_files import check_output_dir
from ballchain.experiments import forces

VEINS = ("LSPV", "LIPV", "RSPV", "RIPV")
# One azimuth is no search (--grid 1 once reported a negative "optimum"; an optimum that does not
# press is now reported as none); the caps bound the work (each evaluation is a statics solve).
GRID = (2, 64)
REFINE = (1, 2000)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--veins", nargs="+", choices=VEINS, default=list(VEINS), help="which veins")
    parser.add_argument("--sleeve", choices=["no", "yes", "both"], default="both", help="sleeve cases")
    parser.add_argument("--grid", type=int_in(*GRID), default=8,
                        help=f"azimuth samples of the orientation grid ({GRID[0]}..{GRID[1]})")
    parser.add_argument("--refine", type=int_in(*REFINE), default=40,
                        help=f"Nelder-Mead evaluations after the grid ({REFINE[0]}..{REFINE[1]})")
    parser.add_argument("--no-dynamics", action="store_true",
                        help="statics only: skip the simulation of each optimum on the force-sensor pin")
    parser.add_argument("--out", type=Path, default=Path("results/forces"), help="folder for the CSV and PNG")
    parser.add_argument("--no-files", action="store_true", help="write no files")
    add_json_flag(parser)


def write_files(data: dict, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    note_replacements(out, ["forces.csv", "forces.png"], "forces")
    out.mkdir(parents=True, exist_ok=True)
    path = out / "forces.csv"
    keys = ["vein", "config", "sleeve", "statics_gf", "dynamics_gf", "statics_dynamics_diff_pct", "paper_gf",
            "statics_lateral_gf", "dynamics_lateral_gf", "n_balls", "superposition_gf", "dynamics_note"]
    write_csv(path, data["rows"], keys)
    rows = data["rows"]
    labels = [f"{r['vein']} {r['config']}{' S' if r['sleeve'] else ''}" for r in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(6, 0.45 * len(rows)), 4))
    simulated = any(r.get("dynamics_gf") is not None for r in rows)
    width = 0.27 if simulated else 0.4
    shift = width if simulated else 0.5 * width
    ax.bar(x - shift, [r["paper_gf"] for r in rows], width, label="paper (measured)")
    ax.bar(x + (0.0 if simulated else shift), [r["statics_gf"] or 0.0 for r in rows], width, label="model (statics)")
    if simulated:  # the statics optima simulated on the force-sensor pin (a missing one: no bar)
        ax.bar(x + width, [r.get("dynamics_gf") or 0.0 for r in rows], width, label="simulation")
    ax.set_xticks(x, labels, rotation=70, fontsize=7)
    ax.set_ylabel("tip force [gf]")
    ax.set_yscale("log")
    ax.legend()
    ax.set_title("Tip force on the veins: paper vs model (S = sleeve)")
    fig.tight_layout()
    png = out / "forces.png"
    save_figure(fig, png, dpi=110)
    plt.close(fig)
    return [str(path), str(png)]


def run(*, veins=VEINS, sleeve: str = "both", grid: int = 8, refine: int = 40, out: Path | None = None,
        progress: bool = True, dynamics: bool = True) -> dict:
    """Run the Table I study (see the module docstring); writes the files into ``out``.

    Raises:
        UserInputError: an unknown vein or sleeve option, a grid or refine out of range, or an
            unwritable ``out`` (checked before any work).
    """
    if not veins or any(v not in VEINS for v in veins):
        raise UserInputError(f"--veins must be among {', '.join(VEINS)}, got {list(veins)}")
    if sleeve not in ("no", "yes", "both"):
        raise UserInputError(f"--sleeve must be 'no', 'yes' or 'both', got {sleeve!r}")
    check_in("--grid", grid, *GRID)
    check_in("--refine", refine, *REFINE)
    if out is not None:
        check_output_dir(out, "--out")
    sleeves = {"no": (False,), "yes": (True,), "both": (False, True)}[sleeve]
    data = forces.run(veins=tuple(veins), sleeves=sleeves, grid=grid, refine_evaluations=refine, progress=progress,
                      dynamics=dynamics)
    if out is not None:
        data["files"] = write_files(data, Path(out))
    return data


def main(args: argparse.Namespace) -> int:
    data = run(veins=args.veins, sleeve=args.sleeve, grid=args.grid, refine=args.refine,
               out=None if args.no_files else args.out, dynamics=not args.no_dynamics)
    if args.json:
        print_json(data)
        return 0
    fmt = lambda v, spec: "-" if v is None else format(v, spec)  # noqa: E731
    print(f"{'vein':5s} {'config':6s} {'sleeve':6s} {'statics gf':>10s} {'sim gf':>9s} {'diff %':>7s} {'paper gf':>9s}")
    for r in data["rows"]:
        print(f"{r['vein']:5s} {r['config']:6s} {str(r['sleeve']):6s} {fmt(r['statics_gf'], '.2f'):>10s} "
              f"{fmt(r.get('dynamics_gf'), '.2f'):>9s} {fmt(r.get('statics_dynamics_diff_pct'), '+.2f'):>7s} "
              f"{r['paper_gf']:9.1f}"
              + ("" if r.get("dynamics_gf") is not None or r.get("dynamics_note") == "not simulated"
                 else f"  ({r.get('dynamics_note')})"))
    return 0
