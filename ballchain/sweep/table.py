"""A sweep's results table: ``table.parquet`` and ``table.csv`` written atomically, read back on resume."""

from __future__ import annotations

import json
import math
import os
import typing
from pathlib import Path
from typing import Callable, Sequence

from ballchain.infrastructure.errors import UserInputError, short_repr, quote_path
from ballchain.infrastructure.safe_files import atomic_path, check_output_dir

TABLE_PARQUET = "table.parquet"
TABLE_CSV = "table.csv"
MAX_TABLE_BYTES = 1_000_000_000  # a results table read back on resume (5000 points are a few MB)
META_COLUMNS = ("key", "experiment")
TAIL_COLUMNS = ("wall_time_s", "cpu_time_s", "worker", "error")


def _scalar(value):
    """A table cell: None, bool, int, float or str; anything else as JSON text."""
    import numpy as np

    if isinstance(value, np.generic):
        value = value.item()
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    from ballchain.infrastructure.safe_files import to_jsonable

    return json.dumps(to_jsonable(value), allow_nan=False, default=str)


def _atomic_write(path: Path, write: Callable[[str], None]) -> None:
    """``write(temporary path)`` next to ``path``, then renamed onto it (``safe_files.atomic_path``)."""
    with atomic_path(path) as tmp:
        write(str(tmp))


def _columns(rows: list[dict], first: Sequence[str]) -> list[str]:
    columns = list(first)
    for row in rows:
        columns += [k for k in row if k not in columns and k not in TAIL_COLUMNS]
    return columns + list(TAIL_COLUMNS)


def rows_to_table(rows: list[dict], first: Sequence[str] = ()):
    """A pyarrow Table of the rows (columns: ``first``, then in order of appearance, then the
    wall time, worker and error). A column whose values do not share a type is stored as text."""
    import pyarrow as pa

    columns = _columns(rows, list(META_COLUMNS) + list(first))
    arrays = {}
    for c in columns:
        values = [r.get(c) for r in rows]
        try:
            arrays[c] = pa.array(values)
        except (pa.ArrowInvalid, pa.ArrowTypeError):
            arrays[c] = pa.array([None if v is None else str(v) for v in values], pa.string())
    return pa.table(arrays)


def write_table(out: Path, rows: list[dict], first: Sequence[str] = ()) -> None:
    """Write ``out/table.parquet`` and ``out/table.csv`` atomically."""
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    table = rows_to_table(rows, first)
    _atomic_write(out / TABLE_PARQUET, lambda tmp: pq.write_table(table, tmp))
    _atomic_write(out / TABLE_CSV, lambda tmp: pacsv.write_csv(table, tmp))


def read_table(out: Path) -> list[dict]:
    """The rows of ``out/table.parquet`` (empty if there is none)."""
    import pyarrow.parquet as pq

    from ballchain.infrastructure.input_files import check_input_file

    path = Path(out) / TABLE_PARQUET
    if not path.exists():
        return []
    check_input_file(path, f"--out {quote_path(out)}: {TABLE_PARQUET}", MAX_TABLE_BYTES, "a sweep's table")
    return pq.read_table(path).to_pylist()


def read_table_csv(out: Path, experiment) -> list[dict]:
    """The rows of ``out/table.csv``, typed as the Parquet table is: the experiment's parameters
    by their fields' types, the key, seed, times, worker and error by theirs; the outputs as
    pyarrow infers them. Raises pyarrow's errors (or OSError) on a file that does not parse, and
    UserInputError on one that is not a regular file or larger than ``MAX_TABLE_BYTES``."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    arrow = {bool: pa.bool_(), int: pa.int64(), float: pa.float64(), str: pa.string()}
    types = {"key": pa.string(), "experiment": pa.string(), "seed": pa.int64(), "wall_time_s": pa.float64(),
             "cpu_time_s": pa.float64(), "worker": pa.string(), "error": pa.string()}
    types.update({name: arrow[t] for name, t in typing.get_type_hints(experiment.params).items()})
    from ballchain.infrastructure.input_files import check_input_file

    check_input_file(Path(out) / TABLE_CSV, f"--out {quote_path(out)}: {TABLE_CSV}", MAX_TABLE_BYTES,
                     "a sweep's table")
    table = pacsv.read_csv(Path(out) / TABLE_CSV,
                           convert_options=pacsv.ConvertOptions(column_types=types, strings_can_be_null=True))
    return table.to_pylist()


def _read_previous(out: Path, experiment) -> tuple[list[dict], str | None]:
    """The earlier rows in ``out`` and a one-line note when ``table.parquet`` was unreadable
    (truncated, corrupt): then the rows come from ``table.csv`` if it parses and holds the same
    points' keys, else the points run again; the unreadable file is kept beside it.

    Raises:
        UserInputError: ``table.parquet`` is a readable table but not a sweep's (no key column).
    """
    import pyarrow as pa

    parquet = out / TABLE_PARQUET
    try:
        rows = read_table(out)
    except (pa.ArrowException, OSError, ValueError) as err:
        reason = " ".join(str(err).split())[:120] or type(err).__name__
    else:
        if rows and not all(isinstance(r.get("key"), str) and r.get("experiment") for r in rows):
            raise UserInputError(f"--out {out}: its {TABLE_PARQUET} is not a sweep's table (no key or experiment "
                                 "column): use another folder")
        return rows, None
    aside = parquet.with_name(TABLE_PARQUET + ".unreadable")
    os.replace(parquet, aside)
    try:
        rows = read_table_csv(out, experiment)
        if not all(isinstance(r.get("key"), str) and r.get("experiment") for r in rows):
            raise ValueError("no key or experiment column")
        source = f"resumed from {TABLE_CSV} ({len(rows)} rows)"
    except (pa.ArrowException, OSError, ValueError):
        rows, source = [], f"{TABLE_CSV} is unreadable too: every point runs again"
    return rows, f"--out {out}: {TABLE_PARQUET} is unreadable ({reason}); {source}; the file is kept as {aside.name}"


def _check_out(out: Path) -> Path:
    """The results folder: checked writable (``safe_files.check_output_dir``), then created."""
    out = check_output_dir(out, "--out", names=(TABLE_PARQUET, TABLE_CSV, "sweep.json"))
    out.mkdir(parents=True, exist_ok=True)
    return out
