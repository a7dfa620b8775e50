"""A sweep spec: its typed schema, loading and checks (``load_spec``), and the key of one run (``point_key``)."""

from __future__ import annotations

import codecs
import dataclasses
import hashlib
import itertools
import json
import math
import os
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.infrastructure.safe_files import register_input

SPEC_KEYS = ("experiment", "description", "grid", "points", "seeds")
DEFAULT_MAX_POINTS = 5000  # runs (points x seeds) a spec may hold unless --max-points raises it


@dataclass
class SweepSpec:
    """A loaded, checked sweep spec.

    Attributes:
        experiment: a name in ``ballchain.experiments.studies.EXPERIMENTS``.
        description: one line.
        points: the parameter sets (each a dataclass instance of the experiment's ``params``),
            the grid's product first, then the explicit ones.
        seeds: every point runs once per seed.
        source: the file it came from (or "<inline>").
    """

    experiment: str
    description: str
    points: list
    seeds: list[int]
    source: str = "<inline>"

    def tasks(self) -> list[tuple[Any, int]]:
        """(params, seed) of every run, in the table's order (points outer, seeds inner)."""
        return [(p, s) for p in self.points for s in self.seeds]


def _schema(experiment) -> type:
    """The typed spec schema of one experiment (for ``yaml_load_typed``)."""
    hints = typing.get_type_hints(experiment.params)
    Grid = dataclasses.make_dataclass(
        f"{experiment.params.__name__}Grid",
        [(f.name, list[hints[f.name]], field(default_factory=list)) for f in dataclasses.fields(experiment.params)])
    return dataclasses.make_dataclass(f"{experiment.params.__name__}Sweep", [
        ("experiment", str, ""), ("description", str, ""),
        ("grid", Grid, field(default_factory=Grid)),
        ("points", list[experiment.params], field(default_factory=list)),
        ("seeds", list[int], field(default_factory=lambda: [0])),
    ])


def load_spec(source: str | Path, *, text: str | None = None, max_points: int = DEFAULT_MAX_POINTS) -> SweepSpec:
    """Load and check a sweep spec (a YAML file, or ``text``).

    Args:
        source: the spec file (or a label for ``text``).
        text: inline YAML instead of reading ``source``.
        max_points: the most runs (points x seeds) the spec may hold (``--max-points``).

    Raises:
        UserInputError: an unreadable, binary or non-UTF-8 file, YAML that ``safe_yaml`` refuses,
            an unknown experiment, an unknown field, a value of the wrong type, an empty grid or
            field list, more runs than ``max_points`` (counted before the grid is expanded), or a
            value the experiment's command refuses; the message names the field (and the point).
    """
    from ballchain.infrastructure.safe_yaml import load_typed, load_yaml

    if not isinstance(source, (str, os.PathLike)) or not str(source).strip():
        raise UserInputError(f"load_spec source must be a spec file's name (or a label with text=...), "
                             f"got {short_repr(source)}")
    if text is not None and not isinstance(text, str):
        raise UserInputError(f"load_spec text must be the spec's YAML text, got {type(text).__name__}")
    label = str(source)
    where = f"sweep spec {short_repr(label)}"
    if isinstance(max_points, bool) or not isinstance(max_points, int) or max_points < 1:
        raise UserInputError(f"--max-points must be an integer >= 1, got {short_repr(max_points)}")
    raw = load_yaml(_read_spec_text(Path(source), where) if text is None else text, where)
    experiment = _spec_experiment(raw, where)
    hints = typing.get_type_hints(experiment.params)
    grid = _spec_grid(raw, hints, where, experiment.name)
    points = _spec_points(raw, hints, where, experiment.name)
    seeds = _spec_seeds(raw, where)
    n_grid = math.prod(len(values) for values in grid.values()) if grid else 0
    runs = (n_grid + len(points)) * len(seeds)
    if runs > max_points:
        raise UserInputError(f"{where}: {runs} runs ({n_grid} grid points + {len(points)} points, times {len(seeds)} "
                             f"seed(s)) exceed the limit of {max_points}: split the study, or raise --max-points")
    typed = load_typed(raw, _schema(experiment), where)
    axes = [f.name for f in dataclasses.fields(experiment.params) if f.name in grid]
    product = [experiment.params(**dict(zip(axes, combo)))
               for combo in itertools.product(*(getattr(typed.grid, a) for a in axes))] if axes else []
    all_points = product + list(typed.points)
    _check_point_values(experiment, all_points, len(product), axes, where)
    keys = [point_key(experiment.name, p, s) for p in all_points for s in seeds]
    if len(set(keys)) != len(keys):
        raise UserInputError(f"{where}: the same point appears twice (grid and points overlap)")
    return SweepSpec(experiment.name, typed.description, all_points, list(seeds), label)


def _read_spec_text(path: Path, where: str) -> str:
    """A spec file's text: UTF-8 (a BOM is skipped), or UTF-16 with its BOM (as some Windows
    editors save); a binary file or another encoding is refused."""
    from ballchain.infrastructure.input_files import read_input_file
    from ballchain.infrastructure.safe_yaml import MAX_BYTES

    data = read_input_file(path, where, MAX_BYTES, "a spec file (YAML)")
    register_input(path, "sweep spec")  # the sweep's outputs may not replace it
    try:
        if data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
            return data.decode("utf-16")
        if b"\0" in data:
            raise UserInputError(f"{where} is a binary file, not YAML text (save the spec as UTF-8 text)")
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise UserInputError(f"{where} is not UTF-8 text (byte {err.start} is not): save it as UTF-8") from None


def _spec_experiment(raw, where: str):
    """The spec's experiment, once the top level is a mapping of known keys."""
    from ballchain.experiments.studies import EXPERIMENTS

    if raw is None:
        raise UserInputError(f"{where} is empty: give a mapping with keys {SPEC_KEYS}")
    if not isinstance(raw, dict):
        raise UserInputError(f"{where}: must be a mapping with keys {SPEC_KEYS}, got a {type(raw).__name__}")
    unknown = [k for k in raw if k not in SPEC_KEYS]
    if unknown:
        raise UserInputError(f"{where}: unknown field(s) {short_repr(unknown)}; allowed: {SPEC_KEYS}")
    for key in ("experiment", "description"):
        if key in raw and not isinstance(raw[key], str):
            raise UserInputError(f"{where}: {key} must be a string, got {short_repr(raw[key])}")
    name = raw.get("experiment")
    if name not in EXPERIMENTS:
        raise UserInputError(f"{where}: experiment must be one of {sorted(EXPERIMENTS)}, got {short_repr(name)}")
    return EXPERIMENTS[name]


def _spec_field(key, hints: dict, where: str, name: str, at: str) -> None:
    if key not in hints:
        raise UserInputError(f"{where}: {at} is not a field of experiment {name!r}; fields: {list(hints)}")


def _spec_grid(raw: dict, hints: dict, where: str, name: str) -> dict:
    """The grid: field -> non-empty list of values, each of the field's type."""
    from ballchain.systems.chain_scenario import check_value

    grid = raw.get("grid")
    if grid is None:
        return {}
    if not isinstance(grid, dict):
        raise UserInputError(f"{where}: grid must be a mapping of field -> list of values, got {short_repr(grid)}")
    for key, values in grid.items():
        _spec_field(key, hints, where, name, f"grid.{key}")
        if not isinstance(values, list):
            raise UserInputError(f"{where}: grid.{key} must be a list of values, got {short_repr(values)}")
        if not values:
            raise UserInputError(f"{where}: grid.{key} is empty (give at least one value)")
        for k, v in enumerate(values):
            check_value(v, hints[key], f"grid.{key}[{k}]", where)
    return grid


def _spec_points(raw: dict, hints: dict, where: str, name: str) -> list:
    """The explicit points: mappings of field -> value of the field's type."""
    from ballchain.systems.chain_scenario import check_value

    points = raw.get("points")
    if points is None:
        points = []
    if not isinstance(points, list):
        raise UserInputError(f"{where}: points must be a list of parameter sets, got {short_repr(points)}")
    for k, point in enumerate(points):
        if not isinstance(point, dict):
            raise UserInputError(f"{where}: points[{k}] must be a mapping of field -> value, got {short_repr(point)}")
        for key, v in point.items():
            _spec_field(key, hints, where, name, f"points[{k}].{key}")
            check_value(v, hints[key], f"points[{k}].{key}", where)
    if not raw.get("grid") and not points:
        raise UserInputError(f"{where}: the grid is empty and there are no points "
                             f"(give grid: {{field: [values]}} or points: [{{field: value}}])")
    return points


def _spec_seeds(raw: dict, where: str) -> list[int]:
    """Distinct seeds, each in the range the operator's tremor takes (``teleop.check_seed``)."""
    from ballchain.experiments.teleop import check_seed
    from ballchain.systems.chain_scenario import check_value

    seeds = raw.get("seeds", [0])
    if not isinstance(seeds, list) or not seeds:
        raise UserInputError(f"{where}: seeds must be a non-empty list of integers, got {short_repr(seeds)}")
    for k, s in enumerate(seeds):
        check_value(s, int, f"seeds[{k}]", where)
        check_seed(s, f"{where}: seeds[{k}]")
    if len(set(seeds)) != len(seeds):
        raise UserInputError(f"{where}: seeds has duplicates: {short_repr(seeds)}")
    return seeds


def _check_point_values(experiment, points: list, n_grid: int, axes: list[str], where: str) -> None:
    """Every point against the experiment's check (the rules of its command's flags)."""
    if experiment.check is None:
        return
    for k, p in enumerate(points):
        try:
            experiment.check(p)
        except UserInputError as err:
            if k < n_grid:
                values = ", ".join(f"{a}={short_repr(getattr(p, a))}" for a in axes)
                at = f"grid point {k + 1} of {n_grid} ({values})"
            else:
                at = f"points[{k - n_grid}]"
            raise UserInputError(f"{where}: {at}: {err}") from None


def point_key(experiment: str, params, seed: int) -> str:
    """A stable 16-hex-digit key of one run: the experiment, its parameters and its seed."""
    payload = json.dumps({"experiment": experiment, "params": dataclasses.asdict(params), "seed": seed},
                         sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()[:16]
