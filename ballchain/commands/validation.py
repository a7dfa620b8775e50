"""Model validation (paper Fig. 11): 5..10 balls, 23 mT at 0..180 deg, three field models.

Uniform field (the paper's model), the prototype cylinder as a point dipole and with its exact
field; prints how far the models' tips are apart beside the paper's measured errors. The
experiment is ``ballchain.experiments.model_validation``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ballchain.commands._common import add_json_flag, finite_float, path_arg, print_json
from ballchain.experiments import model_validation


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--field-mT", type=finite_float, default=23.0, help="field at the chain's base [mT]")
    parser.add_argument("--out", type=path_arg, default=Path("results/validation"), help="folder for the CSV")
    parser.add_argument("--no-files", action="store_true", help="write no files")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    data = model_validation.run(field_T=args.field_mT * 1e-3, out=None if args.no_files else args.out)
    if args.json:
        print_json(data)
        return 0
    for key, value in data.summary.to_dict().items():
        print(f"{key:45s} {value:8.2f}")
    print("paper:", data.paper)
    return 0
