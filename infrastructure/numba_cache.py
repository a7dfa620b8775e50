"""numba's on-disk cache of compiled kernels, made to heal itself.

A kernel compiled with ``@njit(cache=True)`` is stored as an index file (``<name>-<line>.pyXY.nbi``)
and data files (``...nbc``) in ``__pycache__`` next to its source, or under ``$NUMBA_CACHE_DIR``.
numba reads them on the kernel's first call of a process and raises on a file it cannot
unpickle (truncated by a full disk or a killed copy, edited): every later run would fail the same
way. ``guard_cache`` makes such a load forget the kernel's cache files, say so in one line on
stderr and compile afresh (numba then writes new files). A kernel missing from the cache is
compiled by a child process while a ``ballchain`` command runs (``kernel_compiler``: a stop can
end that), then loaded from the cache.
"""

from __future__ import annotations

import sys
from pathlib import Path

from ballchain.infrastructure import kernel_compiler
from ballchain.infrastructure.errors import caused_by_interrupt


def _cache_files(cache) -> list[Path]:
    """The index and data files of one kernel's cache (every signature)."""
    index = Path(cache._cache_file._index_path)
    stem = index.name[: -len(".nbi")]
    return [index, *sorted(index.parent.glob(f"{stem}.*.nbc"))]


def _guard(dispatcher) -> None:
    cache = dispatcher._cache
    load = cache.load_overload

    def load_overload(sig, target_context):
        data = load_healed(sig, target_context)
        # Not in the cache: inside a ``ballchain`` command a child process compiles it into the
        # cache, where a stop can end the wait (``kernel_compiler``); then it is loaded from there.
        if data is None and kernel_compiler.compiled_elsewhere(dispatcher, sig, target_context):
            data = load_healed(sig, target_context)
        return data  # None: numba compiles the kernel here and saves it

    def load_healed(sig, target_context):
        try:
            return load(sig, target_context)
        except Exception as err:  # noqa: BLE001 - whatever unpickling a damaged file raises
            if caused_by_interrupt(err):
                raise
            files = _cache_files(cache)
            try:  # which file: the index, or (the index being readable) this signature's data
                name = cache._cache_file._load_index().get(cache._index_key(sig, target_context.codegen()))
                damaged = files[0].with_name(name) if name else files[0]
            except Exception:  # noqa: BLE001
                damaged = files[0]
            for path in files:
                path.unlink(missing_ok=True)
            print(f"ballchain: cache file {damaged} (compiled {dispatcher.py_func.__qualname__}) was damaged "
                  f"({type(err).__name__}); recompiled", file=sys.stderr)
            return None  # numba compiles the kernel and saves it again

    cache.load_overload = load_overload


def guard_kernel(dispatcher):
    """Guard one cached numba kernel (a dispatcher of ``njit(cache=True)``); returns it."""
    cache = getattr(dispatcher, "_cache", None)
    if hasattr(getattr(cache, "_cache_file", None), "_index_path") and hasattr(dispatcher, "py_func"):
        _guard(dispatcher)
    return dispatcher


def guard_cache(namespace: dict) -> None:
    """Guard every cached numba kernel in a module's ``namespace`` (call it with ``globals()``
    after the kernels are defined)."""
    for value in list(namespace.values()):
        guard_kernel(value)
