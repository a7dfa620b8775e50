"""Model validation (paper Fig. model_results): 5..10 balls, 23 mT at 0..180 deg, three field models.

Uniform field (the paper's model), the prototype cylinder as a point dipole and with its exact
field; prints how far the models' tips are apart beside the paper's measured errors.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ballchain.commands._common import add_json_flag, finite_float, note_replacements, print_json, write_csv
from ballchain.drake_models.errors import UserInputError
from ballchain.drake_models.safe_files import check_output_dir
from ballchain.experiments import model_validation


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--field-mT", type=finite_float, default=23.0, help="field at the chain's base [mT]")
    parser.add_argument("--out", type=Path, default=Path("results/validation"), help="folder for the CSV")
    parser.add_argument("--no-files", action="store_true", help="write no files")
    add_json_flag(parser)


def run(*, field_mT: float = 23.0, out: Path | None = None, progress: bool = True, balls=range(5, 11)) -> dict:
    if not (isinstance(field_mT, (int, float)) and 0 < field_mT <= 1000):
        raise UserInputError(f"--field-mT must be in (0, 1000] mT, got {field_mT}")
    if out is not None:  # before the work
        check_output_dir(out, "--out")
    data = model_validation.run(field_T=field_mT * 1e-3, progress=progress, balls=balls)
    if out is not None:
        out = Path(out)
        note_replacements(out, ["validation.csv"], "validation")
        out.mkdir(parents=True, exist_ok=True)
        path = write_csv(out / "validation.csv", data["differences"])
        data["files"] = [str(path)]
    return data


def main(args: argparse.Namespace) -> int:
    data = run(field_mT=args.field_mT, out=None if args.no_files else args.out)
    if args.json:
        print_json(data)
        return 0
    for key, value in data["summary"].items():
        print(f"{key:45s} {value:8.2f}")
    print("paper:", data["paper"])
    return 0
