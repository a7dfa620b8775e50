"""Results computed once and kept on disk, keyed by their content (issue 48; issue 45, H13).

The generic part of the caches of plans: the autonomous navigator's ring plans
(``experiments.plan_cache``) and the manual hand's sheath plans (``systems.sheath_plan_cache``).
A result is a function of numbers (the inputs its computation reads, not the names they come by)
and of the source of the code that computes it; ``content_key`` hashes both (``numbers``: floats
exactly, by their hex form; ``code_hash``: the source files of a list of packages and modules,
found where they are installed, not imported), so another input or other code is another key and
never reuses another's result.

``cached_arrays`` keeps a result as one ``.npz`` of arrays in a folder of the per-user cache
(``model_files.cache_dir``), signed like every cached model file (``model_files.cached_files``:
an HMAC-SHA256 with this user's key), written atomically, and read without pickles; its content
is checked again on reading (its key, then the caller's shapes and finite numbers). A damaged,
foreign or unreadable entry is never trusted: it is recomputed and written again (one line on
stderr).
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
from pathlib import Path
from typing import Callable, TypeVar

import numpy as np

from ballchain.drake_models import model_files
from ballchain.infrastructure.errors import UserInputError

T = TypeVar("T")


def code_hash(packages=(), modules=()) -> str:
    """A SHA-256 of the source files of ``packages`` (every module of each, sorted) and then of
    ``modules`` (dotted names), found where they are installed, not imported."""
    digest = hashlib.sha256()
    paths = []
    for name in packages:
        (root,) = importlib.util.find_spec(name).submodule_search_locations  # found, not imported
        paths += [(f"{name}/{p.name}", p) for p in sorted(Path(root).glob("*.py"))]
    paths += [(name, Path(importlib.util.find_spec(name).origin)) for name in modules]
    for name, path in paths:
        digest.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def numbers(value):
    """``value`` as JSON numbers, exactly: floats by their hex form (no rounding), arrays and
    tuples as nested lists, dicts by their keys as strings."""
    if isinstance(value, np.ndarray):
        return [numbers(v) for v in value.tolist()] if value.ndim else numbers(value.item())
    if isinstance(value, (list, tuple)):
        return [numbers(v) for v in value]
    if isinstance(value, dict):
        return {str(k): numbers(v) for k, v in value.items()}
    if isinstance(value, (bool, np.bool_)) or value is None or isinstance(value, str):
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    return float(value).hex()


def content_key(content: dict) -> str:
    """A SHA-256 of ``content`` (``numbers`` of it, as JSON with sorted keys): a cache key."""
    return hashlib.sha256(json.dumps(numbers(content), sort_keys=True).encode()).hexdigest()


def cached_arrays(directory: Path, file: str, key: str, compute: Callable[[], T], store: Callable[[T], dict],
                  load: Callable[[object], T], what: str) -> tuple[T, bool]:
    """The result of ``key`` from ``directory / file``, or ``compute()``d and stored there.

    Args:
        directory: the entry's folder (made when missing; its ``model_files.SIGNATURES`` signs it).
        file: the ``.npz``'s name in it.
        key: the result's key (``content_key``): stored as the array ``key`` and checked on reading.
        compute: () -> the result.
        store: the result -> its arrays (a dict of name -> array; its ``key``, if any, is replaced
            by ``key``).
        load: the stored arrays (an ``np.load`` of the file) -> the result; raises ValueError
            (or KeyError, TypeError) when they are not a result of the expected shape.
        what: the entry's name in the stderr line of a damaged entry ("cached plan").

    Returns:
        (the result, whether a stored entry answered: else it was computed here).

    Raises:
        UserInputError: the entry was damaged, recomputed, and still cannot be read back.
    """
    computed: list = []

    def write(tmp: dict) -> None:
        result = compute()
        computed.append(result)
        with open(tmp["data"], "wb") as f:
            np.savez(f, **{**store(result), "key": np.array(key)})

    for attempt in range(2):
        paths = model_files.cached_files(directory, {"data": file}, write)
        if computed:
            return computed[0], False
        try:  # signed by this user: still checked, never unpickled
            with np.load(paths["data"], allow_pickle=False) as data:
                if str(data["key"]) != key:
                    raise ValueError("another key")
                return load(data), True
        except (OSError, ValueError, KeyError, TypeError, EOFError) as err:
            if attempt:
                raise UserInputError(f"the {what} {paths['data']} cannot be rewritten ({err})") from None
            model_files.report_rebuilt(paths["data"], what)
            (directory / model_files.SIGNATURES).unlink(missing_ok=True)  # recomputed on the second pass
    raise AssertionError("unreachable")
