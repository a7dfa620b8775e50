"""Helpers shared by the subcommands: JSON printing and argument checks."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

# Re-exported for the commands: they live below the CLI layer so that experiments can use them.
from ballchain.infrastructure.errors import check_in
from ballchain.infrastructure.safe_files import json_text, save_figure, to_jsonable, write_csv, write_json

__all__ = ["YamlOnce", "add_json_flag", "check_in", "path_arg", "finite_float", "float_in", "int_in", "json_text", "non_negative_int",
           "positive_int", "print_json", "run_status", "save_figure", "to_jsonable", "write_csv", "write_json"]


def print_json(data) -> None:
    print(json_text(data))


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


def path_arg(text: str) -> Path:
    """argparse type: a file or folder name. An empty name is refused: ``Path("")`` is the
    current folder, where a run would write its files unasked."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"must be a file or folder name, got {text!r}")
    return Path(text)


def add_json_flag(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print the result as JSON on stdout")


class YamlOnce(argparse.Action):
    """argparse action of an inline-YAML flag (``--set``): given twice, the run is refused (argparse
    would keep the last mapping and drop the first's fields without a word)."""

    def __call__(self, parser, namespace, values, option_string=None):
        earlier = getattr(namespace, self.dest, None)
        if earlier is not None:
            parser.error(f"{option_string} given twice ({earlier!r} and {values!r}); give every field in one "
                         "mapping, e.g. --set '{n_balls: 10, duration: 2.0}'")
        setattr(namespace, self.dest, values)


def run_status(failure: str | None, command: str) -> int:
    """The exit status of a task run (``teleop``, ``procedure``): 1, with the failure on stderr,
    when the simulation stopped (the watchdog or the solver ended it: the results printed are
    those up to then), as ``simulate`` does; else 0."""
    if not failure:
        return 0
    print(f"ballchain {command}: simulation stopped: {failure}", file=sys.stderr)
    return 1
