"""What every kernel file shares: the ``kernel`` decorator (numba, cached on disk), the energy
parts' order in the ``terms`` arrays (and ``EnergyTerms``, their values), and the status codes
with their messages.

Numba's on-disk cache (``cache=True``: ``__pycache__`` next to the source file, or
``NUMBA_CACHE_DIR``) keys a compiled kernel on its own file's content only, while a kernel
carries the compiled code of the kernels it calls from other files. ``kernel`` therefore stamps
every kernel's cache with the content of the whole package: editing any kernel file recompiles
them all, and a stale callee is never loaded from disk. A kernel defined outside the package
(the compiled Newton solver of ``optimization``) is stamped with its own file as well.
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass
from pathlib import Path

from numba import njit, types
from numba.core.caching import (
    CompileResultCacheImpl,
    FunctionCache,
    InTreeCacheLocator,
    UserProvidedCacheLocator,
    UserWideCacheLocator,
)

from ballchain.drake_models.kernels import _blas_order
from ballchain.infrastructure.numba_cache import guard_kernel

# Energy parts, in the order of the kernels' ``terms`` arrays (EnergyTerms' fields).
TERM_BALLS, TERM_EXTERNAL, TERM_SLEEVE, TERM_GRAVITY = 0, 1, 2, 3


@dataclass
class EnergyTerms:
    """The energy's parts [J] (re-exported by ``chain_energy``, its numpy reference's home)."""

    balls: float = 0.0
    external: float = 0.0
    sleeve: float = 0.0
    gravity: float = 0.0

    @property
    def total(self) -> float:
        return self.balls + self.external + self.sleeve + self.gravity

# Status codes of the kernels (raised as ValueError by the Python wrappers).
OK, COINCIDENT, FOLDED = 0, 1, 2

_STATUS_MESSAGES = {
    COINCIDENT: "two balls coincide (zero separation)",
    FOLDED: "a sleeve bend of 180 deg (chain folded onto itself)",
}


def check_status(status: int, what: str) -> None:
    """Raise ValueError, naming ``what``, for a kernel's non-OK status."""
    if status != OK:
        raise ValueError(f"{what}: {_STATUS_MESSAGES.get(int(status), f'kernel status {status}')}")


_PACKAGE = Path(__file__).resolve().parent


def _package_stamp(own_file: str | None = None) -> str:
    """SHA-256 of every source file of this package (names and contents, in name order), and of
    ``own_file`` when it lies outside the package (a kernel of another package that calls these)."""
    files = sorted(_PACKAGE.glob("*.py"))
    if own_file is not None and Path(own_file).resolve().parent != _PACKAGE:
        files.append(Path(own_file))
    return _hash_files(tuple((str(f), f.stat().st_mtime_ns, f.stat().st_size) for f in files))


@functools.lru_cache(maxsize=None)
def _hash_files(files: tuple) -> str:
    """The hash of the files named in ``files`` ((path, mtime, size) each: a changed file re-hashes)."""
    digest = hashlib.sha256()
    for path, _, _ in files:
        digest.update(Path(path).name.encode())
        digest.update(Path(path).read_bytes())
    return digest.hexdigest()


class _PackageStamp:
    """A cache locator whose freshness stamp is the package's, not the function's file's. numba
    reads it once, when the kernel is defined (its module imported): a process that keeps running
    after a kernel file was edited saves what it compiled under the stamp of the code it
    imported, which a process importing the edited files does not load."""

    def get_source_stamp(self):
        # With how this process's BLAS sums (``_blas_order``): the kernels mirror it.
        return _package_stamp(getattr(self, "_py_file", None)) + ":" + _blas_order.ORDER


class _UserProvidedLocator(_PackageStamp, UserProvidedCacheLocator):
    pass


class _InTreeLocator(_PackageStamp, InTreeCacheLocator):
    pass


class _UserWideLocator(_PackageStamp, UserWideCacheLocator):
    pass


class _PackageCacheImpl(CompileResultCacheImpl):
    # numba's own order: NUMBA_CACHE_DIR, then __pycache__ next to the file, then the user's cache.
    _locator_classes = [_UserProvidedLocator, _InTreeLocator, _UserWideLocator]


class _PackageCache(FunctionCache):
    _impl_class = _PackageCacheImpl


def _without_literals(dispatcher):
    """Make the kernels that call ``dispatcher`` type their calls with the arguments' plain types.

    numba types a constant argument of a compiled caller (``evaluate(q, 2, ...)``,
    ``heart_rows(..., False)``) as a literal and compiles the callee once per literal value seen,
    each specialisation with its own copy of everything the callee calls: the solve's ``evaluate``
    would be compiled three times (orders 0, 2 and a variable), ``_answer`` six (one per reason).
    Typed as int64 and bool, each kernel is compiled once, for every caller; the constants are
    converted at the call, and the code run is the same (the literal only let numba drop branches).
    """
    get_call_template = dispatcher.get_call_template

    def plain_call_template(args, kws):
        return get_call_template(tuple(types.unliteral(a) for a in args),
                                 {k: types.unliteral(v) for k, v in kws.items()})

    dispatcher.get_call_template = plain_call_template
    return dispatcher


def kernel(py_func):
    """``numba.njit`` with the on-disk cache stamped by the whole package's sources, healed when a
    cache file is damaged (``numba_cache.guard_kernel``), and compiled once whatever constants its
    compiled callers pass (``_without_literals``)."""
    return _compiled(py_func)


def inline_kernel(py_func):
    """``kernel`` whose body numba inlines into its compiled callers (``inline="always"``): the
    few scalar lines a pair loop runs per entry, where a call costs more than the arithmetic and
    hides the shared subexpressions from the compiler. Called from Python it runs as ``kernel``."""
    return _compiled(py_func, inline="always")


def _compiled(py_func, **options):
    dispatcher = njit(cache=True, **options)(py_func)
    if dispatcher is py_func:  # NUMBA_DISABLE_JIT=1 (a debugging switch): the kernels run as Python
        return py_func
    dispatcher._cache = _PackageCache(py_func)  # what ``cache=True`` set, with the package stamp
    _without_literals(dispatcher)
    return guard_kernel(dispatcher)  # a damaged cache file is recompiled, not a traceback on every run
