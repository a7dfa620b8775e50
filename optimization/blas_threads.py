"""BLAS and LAPACK on one thread around the statics' solves.

The statics' matrices are small (60 x 60 at 16 balls, 250 x 250 at 64): OpenBLAS's threads only
add overhead, and on a shared machine they wait for each other. The quasi-static engine runs every
update inside ``one_blas_thread``, and so does every compiled solve (``compiled_model``): a
64-ball solve called from a user's script took 35 CPU-ms outside the limit against 3.6 within it
(docs/performance.md).
"""

from __future__ import annotations

_BLAS = None


class _OneThread:
    """The context of ``one_blas_thread``: each BLAS library not on one thread already is set to
    one on entry and back on exit (the engine enters it once per update: one ctypes call per
    library when nothing needs changing, instead of threadpoolctl's limiter and its queries).

    ``libraries``: ``(get_num_threads, set_num_threads)`` per library (``_thread_calls``)."""

    def __init__(self, libraries):
        self._libraries = libraries
        self._restore: list = []

    def __enter__(self):
        for get, set_ in self._libraries:
            threads = get()
            if threads != 1:
                set_(1)
                self._restore.append((set_, threads))
        return self

    def __exit__(self, *exc):
        while self._restore:
            set_, threads = self._restore.pop()
            set_(threads)
        return False


def _thread_calls(lib) -> tuple:
    """``(get_num_threads, set_num_threads)`` of a threadpoolctl controller: OpenBLAS's own
    functions for its pthreads build (what threadpoolctl calls, without its Python around them:
    a solve called from a script enters and leaves the limit, and after other work that Python
    cost 30 us of a 0.3 ms solve), else the controller's methods."""
    if type(lib).__name__ == "OpenBLASController" and getattr(lib, "threading_layer", None) == "pthreads":
        get_symbol = getattr(lib, "_get_symbol", None)
        if get_symbol is not None:
            get, set_ = get_symbol("openblas_get_num_threads"), get_symbol("openblas_set_num_threads")
            if get is not None and set_ is not None:
                return get, set_
    return lib.get_num_threads, lib.set_num_threads


def one_blas_thread():
    """A context in which BLAS/LAPACK run on one thread (threadpoolctl). The statics' matrices
    are 60 x 60: threads only add overhead, and on a shared machine they wait for each other
    (measured here: numpy's eigh of 56 x 56 took 44 ms with OpenBLAS's threads, 0.3 ms on one;
    its Cholesky 0.26 ms against 0.05 ms)."""
    global _BLAS
    if _BLAS is None:
        # numba's compiled np.linalg (the compiled statics' Cholesky and solves) calls LAPACK
        # through scipy's OpenBLAS, a second library that numpy's does not load: loaded here, so
        # that the controller (a snapshot of the libraries loaded) limits it too. Unlimited, its
        # threads take over from 32 balls on (measured: a 32-ball solve 10 times slower in CPU time).
        import scipy.linalg.cython_lapack  # noqa: F401
        from threadpoolctl import ThreadpoolController

        _BLAS = [_thread_calls(lib) for lib in ThreadpoolController().lib_controllers if lib.user_api == "blas"]
    return _OneThread(_BLAS)
