"""Workspace of the chain with one rotating magnet 16.51 cm away (paper Fig. 9).

Prints the half-workspace areas with and without sleeve and the tip-to-tip distance beside the
paper's 3345 mm^2, 2939 mm^2 (12 % less) and about 8 mm; writes a plot of the tip curves and
the data as CSV. The experiment is ``ballchain.experiments.workspace``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ballchain.commands._common import add_json_flag, finite_float, path_arg, print_json
from ballchain.experiments import workspace


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--step-deg", type=finite_float, default=5.0, help="magnet rotation step [deg]")
    parser.add_argument("--distance-cm", type=finite_float, default=workspace.DISTANCE * 100, help="magnet to insertion point [cm]")
    parser.add_argument("--out", type=path_arg, default=Path("results/workspace"), help="folder for the files")
    parser.add_argument("--no-files", action="store_true", help="write no files")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    data = workspace.run(step_deg=args.step_deg, distance=args.distance_cm / 100.0,
                         out=None if args.no_files else args.out)
    if args.json:
        print_json(data.public())
        return 0
    s, p = data.summary, data.paper
    print(f"half workspace, bare:   {s.half_area_bare_mm2:7.0f} mm^2 (paper {p['half_area_bare_mm2']:.0f})")
    print(f"half workspace, sleeve: {s.half_area_sleeve_mm2:7.0f} mm^2 (paper {p['half_area_sleeve_mm2']:.0f})")
    print(f"reduction: {s.reduction_pct:.1f} % (paper {p['reduction_pct']:.0f} %); tip-to-tip "
          f"{s.tip_to_tip_max_mm:.1f} mm (paper about {p['tip_to_tip_mm']:.0f})")
    return 0
