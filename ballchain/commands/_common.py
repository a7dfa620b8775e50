"""Helpers shared by the subcommands: JSON printing and argument checks."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

import numpy as np


def to_jsonable(value):
    """numpy arrays and scalars to plain Python, recursively; NaN and inf become None (null), so
    the JSON is valid (the JSON standard has no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, np.generic):
        return to_jsonable(value.item())
    if isinstance(value, Path):
        return str(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return to_jsonable({f.name: getattr(value, f.name) for f in dataclasses.fields(value)})
    if value is None or isinstance(value, (bool, int, str)):
        return value
    return str(value)  # anything else (a Drake object, ...): its text, so the JSON is always valid


def json_text(data) -> str:
    """The JSON text of ``data`` (``to_jsonable``: numpy to Python, non-finite numbers to null)."""
    return json.dumps(to_jsonable(data), indent=1, allow_nan=False)


def print_json(data) -> None:
    print(json_text(data))


def write_json(path, data) -> Path:
    """Write ``data`` as JSON to ``path`` atomically (see ``json_text``); returns the path."""
    from ballchain.drake_models.safe_files import atomic_write_text

    return atomic_write_text(path, json_text(data) + "\n")


def finite_float(text: str) -> float:
    """argparse type: a finite float."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def int_in(lo: int, hi: int):
    """argparse type factory: an integer in lo..hi (both included)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be in {lo}..{hi}, got {value}")
        return value

    parse.__name__ = f"integer in {lo}..{hi}"
    return parse


def float_in(lo: float, hi: float, *, lo_open: bool = False):
    """argparse type factory: a finite float in [lo, hi] (or (lo, hi] with ``lo_open``)."""

    def parse(text: str) -> float:
        value = finite_float(text)
        if value < lo or value > hi or (lo_open and value == lo):
            raise argparse.ArgumentTypeError(f"must be in {'(' if lo_open else '['}{lo:g}, {hi:g}], got {text}")
        return value

    parse.__name__ = f"number in {lo:g}..{hi:g}"
    return parse


def check_in(name: str, value, lo, hi, *, lo_open: bool = False, unit: str = "") -> None:
    """Raise UserInputError unless ``value`` is a finite number in [lo, hi] ((lo, hi] with lo_open).

    For the Python API of the commands (``run(...)``), which skips argparse's checks.
    """
    from ballchain.drake_models.errors import UserInputError

    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    ok = ok and math.isfinite(value) and lo <= value <= hi and not (lo_open and value == lo)
    if not ok:
        interval = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
        raise UserInputError(f"{name} must be a number in {interval}{' ' + unit if unit else ''}, got {value!r}")


def add_json_flag(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print the result as JSON on stdout")


def write_csv(path, rows: list[dict], fieldnames=None) -> Path:
    """Write dict rows as CSV to ``path`` atomically (extra keys ignored); returns the path."""
    import csv
    import io

    from ballchain.drake_models.safe_files import atomic_write_text

    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=list(fieldnames or (rows[0] if rows else [])),
                            extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    return atomic_write_text(path, buffer.getvalue())


def save_figure(fig, path, **kwargs) -> Path:
    """``fig.savefig`` to ``path`` atomically (the format from the path's suffix); returns the path."""
    from ballchain.drake_models.safe_files import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or "png", **kwargs)
    return path


def note_replacements(out, names, command: str) -> list[str]:
    """Say on stderr which of the files ``names`` in folder ``out`` already exist and are about
    to be replaced (one line); returns them."""
    import sys

    out = Path(out)
    existing = [n for n in names if (out / n).exists()]
    if existing:
        print(f"ballchain {command}: replacing {', '.join(existing)} in {out}", file=sys.stderr)
    return existing
