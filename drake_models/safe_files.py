"""Result files that are never half-written, and output paths checked before any work.

Every results writer (report, CSV, JSON, PNG, HTML) writes through ``atomic_path``: the data go
to a temporary file in the destination's folder, which replaces the destination with
``os.replace`` only once it is complete. A run killed part-way leaves either the old file or the
new one, never a truncated file that looks whole. ``check_output_file`` / ``check_output_dir``
are called by the commands before they compute, so an unwritable ``--out`` or ``--html`` is
refused at once instead of after the run.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

from ballchain.drake_models.errors import UserInputError

TEMP_SUFFIX = ".partial"
_UMASK = os.umask(0o022)
os.umask(_UMASK)  # read once: mkstemp makes 0600 files, results get the usual 0666 & ~umask


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path``; on success it replaces ``path`` atomically.

    The temporary file is removed when the block raises (also on KeyboardInterrupt), so nothing
    half-written is left behind. The folder is created when missing.

    Example:
        with atomic_path(out / "forces.png") as tmp:
            fig.savefig(tmp, format="png")
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def _first_existing_parent(path: Path) -> Path:
    p = path
    while not p.exists():
        if p.parent == p:
            break
        p = p.parent
    return p


def check_output_dir(path, what: str) -> Path:
    """Check that ``path`` is (or can be created as) a writable folder, without creating it.

    Args:
        path: the folder.
        what: the flag or field named in the message (e.g. "--out").

    Raises:
        UserInputError: it is a file, or it (or its nearest existing parent) is not writable.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UserInputError(f"{what} {str(path)!r} is a file, not a folder")
    base = _first_existing_parent(path.absolute())
    if not base.is_dir():
        raise UserInputError(f"{what} {str(path)!r}: {str(base)!r} is a file, so the folder cannot be created")
    if not os.access(base, os.W_OK | os.X_OK):
        raise UserInputError(f"{what} {str(path)!r}: folder {str(base)!r} is not writable")
    try:  # os.access says yes to root even on a read-only file system: try it
        with tempfile.TemporaryFile(dir=base, prefix=".ballchain_probe"):
            pass
    except OSError as err:
        raise UserInputError(f"{what} {str(path)!r}: cannot write in {str(base)!r} ({err.strerror})") from None
    return path


def check_output_file(path, what: str) -> Path:
    """Check that the file ``path`` can be written (its folder exists or can be created).

    Raises:
        UserInputError: it is a folder, a read-only file, or in an unwritable place.
    """
    path = Path(path)
    if path.is_dir():
        raise UserInputError(f"{what} {str(path)!r} is a folder; give a file name")
    if path.exists() and not os.access(path, os.W_OK):
        raise UserInputError(f"{what} {str(path)!r} exists and is not writable")
    try:
        check_output_dir(path.parent, what)
    except UserInputError:
        base = _first_existing_parent(path.absolute().parent)
        if base.exists() and not base.is_dir():
            raise UserInputError(f"{what} {str(path)!r}: {str(base)!r} is a file, so the folder cannot "
                                 "be created") from None
        raise
    return path


def write_csv(path, rows: list[dict], fieldnames=None) -> Path:
    """Write dict rows as CSV to ``path`` atomically (extra keys ignored); returns the path."""
    import csv
    import io

    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=list(fieldnames or (rows[0] if rows else [])),
                            extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    return atomic_write_text(path, buffer.getvalue())


def agg_pyplot():
    """``matplotlib.pyplot`` on the Agg backend: figures for files, no display needed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path, **kwargs) -> Path:
    """``fig.savefig`` to ``path`` atomically (the format from the path's suffix), then close the
    figure (a results writer has no further use for it); returns the path."""
    import matplotlib.pyplot as plt

    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format=path.suffix.lstrip(".") or "png", **kwargs)
    finally:
        plt.close(fig)
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


OMIT_IF_NONE = "omit_if_none"
"""Dataclass field metadata key: a field marked ``{OMIT_IF_NONE: True}`` is left out of the JSON
while its value is None (an optional part of a result, e.g. the files written only with ``out``)."""

NOT_IN_JSON = "not_in_json"
"""Dataclass field metadata key: a field marked ``{NOT_IN_JSON: True}`` is never in the JSON (a
working object a result keeps for its figures, e.g. the simulated fields)."""


def optional_field(**kwargs):
    """A dataclass field that defaults to None and is left out of the JSON (``to_jsonable``)
    while None (``OMIT_IF_NONE``): for the parts of a result that exist only in some runs, so that
    the JSON keeps the keys it had when results were dicts."""
    return dataclasses.field(default=None, metadata={OMIT_IF_NONE: True}, **kwargs)


def to_jsonable(value):
    """numpy arrays and scalars to plain Python, recursively; NaN and inf become None (null), so
    the JSON is valid (the JSON standard has no NaN). A dataclass becomes the dict of its fields
    in their order (fields marked ``OMIT_IF_NONE`` left out while None, ``NOT_IN_JSON`` always)."""
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
        return to_jsonable({f.name: getattr(value, f.name) for f in dataclasses.fields(value)
                            if not (f.metadata.get(NOT_IN_JSON)
                                    or (f.metadata.get(OMIT_IF_NONE) and getattr(value, f.name) is None))})
    if value is None or isinstance(value, (bool, int, str)):
        return value
    return str(value)  # anything else (a Drake object, ...): its text, so the JSON is always valid


def json_text(data) -> str:
    """The JSON text of ``data`` (``to_jsonable``: numpy to Python, non-finite numbers to null)."""
    return json.dumps(to_jsonable(data), indent=1, allow_nan=False)


def write_json(path, data) -> Path:
    """Write ``data`` as JSON to ``path`` atomically (see ``json_text``); returns the path."""
    return atomic_write_text(path, json_text(data) + "\n")
