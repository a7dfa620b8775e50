"""Workspace of the chain with one rotating magnet 16.51 cm away (paper Fig. workspace_results).

Prints the half-workspace areas with and without sleeve and the tip-to-tip distance beside the
paper's 3345 mm^2, 2939 mm^2 (12 % less) and about 8 mm; writes a plot of the tip curves and
the data as CSV.
"""

from __future__ import annotations

import argparse
import csv
import io
from pathlib import Path

from ballchain.commands._common import add_json_flag, finite_float, note_replacements, print_json, save_figure
from ballchain.drake_models.errors import UserInputError
from ballchain.drake_models.safe_files import atomic_write_text, check_output_dir
from ballchain.experiments import workspace


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--step-deg", type=finite_float, default=5.0, help="magnet rotation step [deg]")
    parser.add_argument("--distance-cm", type=finite_float, default=16.51, help="magnet to insertion point [cm]")
    parser.add_argument("--out", type=Path, default=Path("results/workspace"), help="folder for the files")
    parser.add_argument("--no-files", action="store_true", help="write no files")
    add_json_flag(parser)


def write_files(data: dict, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    note_replacements(out, ["workspace_tips.csv", "workspace.png"], "workspace")
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "workspace_tips.csv"
    f = io.StringIO(newline="")
    writer = csv.writer(f)
    writer.writerow(["n_balls", "sleeve", "side", "tip_x_mm", "tip_y_mm", "tip_z_mm"])
    for (n, sleeve, side), tips in data["curves"].items():
        for tip in tips:
            writer.writerow([n, sleeve, side, *tip])
    atomic_write_text(csv_path, f.getvalue())
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.5), sharex=True, sharey=True)
    balls = sorted({k[0] for k in data["curves"]})
    for ax, n in zip(axes, balls):
        for sleeve, style in ((False, "-"), (True, "--")):
            for side in (1, -1):
                tips = data["curves"][(n, sleeve, side)]
                ax.plot(tips[:, 0], tips[:, 1], style, color="C0" if side > 0 else "C1",
                        label=f"{'sleeve' if sleeve else 'bare'}, {'+y' if side > 0 else '-y'} side")
        ax.plot([0], [0], "ks")
        ax.set_title(f"{n} balls")
        ax.set_aspect("equal")
        ax.set_xlabel("x [mm]")
    axes[0].set_ylabel("y [mm] (magnet towards -y)")
    axes[-1].legend(fontsize=7)
    fig.suptitle("Tip positions as the magnet turns (16.51 cm away)")
    fig.tight_layout()
    png = out / "workspace.png"
    save_figure(fig, png, dpi=110)
    plt.close(fig)
    return [str(csv_path), str(png)]


def run(*, step_deg: float = 5.0, distance_cm: float = 16.51, out: Path | None = None, progress: bool = True) -> dict:
    if not (isinstance(step_deg, (int, float)) and 0.5 <= step_deg <= 45):
        raise UserInputError(f"--step-deg must be in [0.5, 45], got {step_deg}")
    if not (isinstance(distance_cm, (int, float)) and 10 < distance_cm <= 100):
        raise UserInputError(f"--distance-cm must be in (10, 100] cm (closer, the magnet would touch the "
                             f"chain), got {distance_cm}")
    if out is not None:  # before the work
        check_output_dir(out, "--out")
    data = workspace.run(step_deg=step_deg, distance=distance_cm / 100.0, progress=progress)
    if out is not None:
        data["files"] = write_files(data, Path(out))
    return data


def main(args: argparse.Namespace) -> int:
    data = run(step_deg=args.step_deg, distance_cm=args.distance_cm, out=None if args.no_files else args.out)
    public = {k: v for k, v in data.items() if k != "curves"}
    if args.json:
        print_json(public)
        return 0
    s, p = data["summary"], data["paper"]
    print(f"half workspace, bare:   {s['half_area_bare_mm2']:7.0f} mm^2 (paper {p['half_area_bare_mm2']:.0f})")
    print(f"half workspace, sleeve: {s['half_area_sleeve_mm2']:7.0f} mm^2 (paper {p['half_area_sleeve_mm2']:.0f})")
    print(f"reduction: {s['reduction_pct']:.1f} % (paper {p['reduction_pct']:.0f} %); tip-to-tip "
          f"{s['tip_to_tip_max_mm']:.1f} mm (paper about {p['tip_to_tip_mm']:.0f})")
    return 0
