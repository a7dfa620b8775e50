"""Helpers shared by the subcommands: JSON printing and argument checks."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

import numpy as np

# Re-exported for the commands: they live below the CLI layer so that experiments can use them.
from ballchain.drake_models.errors import check_in
from ballchain.drake_models.safe_files import save_figure, write_csv

__all__ = ["add_json_flag", "check_in", "finite_float", "float_in", "int_in", "json_text", "non_negative_int",
           "positive_int", "print_json", "save_figure", "to_jsonable", "write_csv", "write_json"]


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


def add_json_flag(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
