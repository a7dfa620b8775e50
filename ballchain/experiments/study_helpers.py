"""The sweep studies' common parts: ``Experiment`` (a sweepable experiment) and the checks and
figure helpers its point functions share. ``studies`` re-exports them.
"""

# No ``from __future__ import annotations``: pydrake's yaml_load_typed reads the parameter
# dataclasses' field types as objects, not strings (as in systems/chain_scenario.py).
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ballchain.infrastructure.errors import UserInputError, short_repr


@dataclass(frozen=True)
class Experiment:
    """A sweepable experiment.

    Attributes:
        name: the spec's ``experiment``.
        params: a dataclass of scalar fields (bool, int, float, str) with defaults.
        point: ``point(params, seed) -> {output name: scalar}``; lists/dicts are stored as JSON.
        check: ``check(params)`` raises UserInputError naming the field (before the sweep).
        figure: ``figure(rows, out_dir) -> Path`` from the table's rows (dicts), or a line (str)
            saying why this grid gives no figure; or None (the study has no figure).
        summary: ``summary(rows) -> dict`` of headline numbers, or None.
        description: one line.
        typical_s: a point's typical CPU time [s] on one core, for the estimate printed before a
            sweep starts (an earlier table's own times replace it when there is one).
        shown: the output columns that ``ballchain sweep`` prints in its short table.
        outputs: {output column: its meaning and unit}, every column ``point`` returns (the sweep
            reference in the docs is generated from it; a test checks that it is complete).
    """

    name: str
    params: type
    point: Callable
    check: Callable | None = None
    figure: Callable | None = None
    summary: Callable | None = None
    description: str = ""
    typical_s: float = 1.0
    shown: tuple = ()  # the outputs the sweep command prints in its short table (default: the first few)
    outputs: dict = dataclasses.field(default_factory=dict)  # {output column: what it is, with its unit}


def _one_of(name: str, value, allowed) -> None:
    if value not in allowed:
        raise UserInputError(f"{name} must be one of {tuple(allowed)}, got {short_repr(value)}")


def _positive(name: str, value, *, zero_ok: bool = False) -> None:
    if not (value >= 0 if zero_ok else value > 0):
        raise UserInputError(f"{name} must be {'>= 0' if zero_ok else '> 0'}, got {short_repr(value)}")


def _ok(rows):
    return [r for r in rows if r.get("error") is None]


def _savefig(fig, path: Path) -> Path:
    """Save a figure atomically (a temporary file in the folder, then ``os.replace``)."""
    from ballchain.infrastructure.safe_files import save_figure

    return save_figure(fig, path, dpi=120, bbox_inches="tight")
