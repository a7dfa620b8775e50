"""Tip forces on the pulmonary veins (paper Table I) from statics with the tip held on a sensor.

For each vein, configuration (magnet on the right "1", left "2", or both) and sleeve option, the
magnet orientations that maximise the force the tip presses along the vein's axis are found by
optimisation (grid + Nelder-Mead over equilibria). Prints the model beside the paper's numbers
and writes a CSV and a bar chart.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from ballchain.commands._common import add_json_flag, positive_int, print_json
from ballchain.experiments import forces

VEINS = ("LSPV", "LIPV", "RSPV", "RIPV")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--veins", nargs="+", choices=VEINS, default=list(VEINS), help="which veins")
    parser.add_argument("--sleeve", choices=["no", "yes", "both"], default="both", help="sleeve cases")
    parser.add_argument("--grid", type=positive_int, default=8, help="azimuth samples of the orientation grid")
    parser.add_argument("--refine", type=positive_int, default=40, help="Nelder-Mead evaluations after the grid")
    parser.add_argument("--out", type=Path, default=Path("results/forces"), help="folder for the CSV and PNG")
    parser.add_argument("--no-files", action="store_true", help="write no files")
    add_json_flag(parser)


def write_files(data: dict, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    out.mkdir(parents=True, exist_ok=True)
    path = out / "forces.csv"
    keys = ["vein", "config", "sleeve", "statics_gf", "paper_gf", "n_balls", "superposition_gf"]
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(data["rows"])
    rows = data["rows"]
    labels = [f"{r['vein']} {r['config']}{' S' if r['sleeve'] else ''}" for r in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(6, 0.45 * len(rows)), 4))
    ax.bar(x - 0.2, [r["paper_gf"] for r in rows], 0.4, label="paper (measured)")
    ax.bar(x + 0.2, [r["statics_gf"] or 0.0 for r in rows], 0.4, label="model (statics)")
    ax.set_xticks(x, labels, rotation=70, fontsize=7)
    ax.set_ylabel("tip force [gf]")
    ax.set_yscale("log")
    ax.legend()
    ax.set_title("Tip force on the veins: paper vs model (S = sleeve)")
    fig.tight_layout()
    png = out / "forces.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return [str(path), str(png)]


def run(*, veins=VEINS, sleeve: str = "both", grid: int = 8, refine: int = 40, out: Path | None = None,
        progress: bool = True) -> dict:
    sleeves = {"no": (False,), "yes": (True,), "both": (False, True)}[sleeve]
    data = forces.run(veins=tuple(veins), sleeves=sleeves, grid=grid, refine_evaluations=refine, progress=progress)
    if out is not None:
        data["files"] = write_files(data, Path(out))
    return data


def main(args: argparse.Namespace) -> int:
    data = run(veins=args.veins, sleeve=args.sleeve, grid=args.grid, refine=args.refine,
               out=None if args.no_files else args.out)
    if args.json:
        print_json(data)
        return 0
    print(f"{'vein':5s} {'config':6s} {'sleeve':6s} {'model gf':>9s} {'paper gf':>9s}")
    for r in data["rows"]:
        model = "-" if r["statics_gf"] is None else f"{r['statics_gf']:9.2f}"
        print(f"{r['vein']:5s} {r['config']:6s} {str(r['sleeve']):6s} {model:>9s} {r['paper_gf']:9.1f}")
    return 0
