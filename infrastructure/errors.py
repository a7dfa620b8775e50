"""The project's error types, importable from every layer.

``UserInputError`` is the user's mistake (a bad flag, scenario field, parameter or file): the
``ballchain`` command reports it as one line naming the field, the value and what is allowed,
with exit status 2. Anything else that escapes is a bug and stays a traceback.
"""

from __future__ import annotations

import re


def caused_by_interrupt(err: BaseException) -> bool:
    """Whether ``err`` is Ctrl-C, or an error raised because of it: a KeyboardInterrupt that lands
    inside a compiled call (a numba dispatcher, a Drake callback) comes back wrapped, e.g. as
    "SystemError: ... returned a result with an exception set", with the interrupt as its context.
    Drake's SNOPT keeps only the text of an exception raised in a cost or constraint: a
    RuntimeError "Exception while evaluating SNOPT costs and constraints: 'StopRequest: 15..."
    (pybind11's "<type>: <message>" of the interrupt), without the interrupt as its context."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, KeyboardInterrupt):
            return True
        if isinstance(err, RuntimeError) and _WRAPPED_INTERRUPT.search(str(err)):
            return True
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return False


# pybind11's text of a Python exception that C++ caught (Drake's solvers quote it in their own)
_WRAPPED_INTERRUPT = re.compile(
    r"^Exception while evaluating \w+ costs and constraints: '(?:KeyboardInterrupt|StopRequest):")


MAX_QUOTED = 80  # characters of a user's value quoted in a message
MAX_PATH_QUOTED = 160  # characters of a file name quoted in a message: whole, unless longer (then cut in the middle)


def short_repr(value, limit: int = MAX_QUOTED) -> str:
    """``repr(value)`` cut to ``limit`` characters (with "..." and the full length), for quoting a
    user's value in a one-line message: a value that expanded (a YAML alias bomb, a huge list)
    must not turn the message into megabytes. Never raises, whatever ``value`` is."""
    try:
        text = repr(value)
    except Exception:  # noqa: BLE001 - a broken __repr__ of a user's object
        text = f"<{type(value).__name__}>"
    text = " ".join(text.split())
    if len(text) <= limit:
        return text
    tail = (limit - 3) // 2  # both ends kept: a path's file name is at its end
    return f"{text[:limit - 3 - tail]}...{text[len(text) - tail:]} ({len(text)} characters)"


def quote_path(path) -> str:
    """A file or folder name for a one-line message: quoted whole up to ``MAX_PATH_QUOTED``
    characters (a user needs the whole name to act on it), else cut in the middle as
    ``short_repr`` cuts. Never raises."""
    try:
        text = str(path)
    except Exception:  # noqa: BLE001
        return short_repr(path)
    return short_repr(text, MAX_PATH_QUOTED)


class StopRequest(KeyboardInterrupt):
    """A request to stop from outside, raised where Ctrl-C raises ``KeyboardInterrupt``: the
    ``ballchain`` command turns SIGINT, SIGTERM and SIGHUP into it, so every path that keeps what
    finished on Ctrl-C (a replay, the sections of a report, the rows of a sweep) keeps it for a
    ``kill``, a time limit or a closed terminal too. ``signum`` is the signal's number."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = int(signum)


class OutputError(Exception):
    """A result file could not be written (the disk is full, a name is too long, the place is
    not writable...): reported as one line naming the file and the reason, exit status 1. The
    file's earlier content, if any, is unchanged (the writes are atomic)."""


class ResourceLimitError(Exception):
    """The machine's limit on open files, processes or memory stops the run (``ulimit -n``,
    ``-u``, ``-v``): one line naming the limit, its value and what to do, exit status 1 (the input
    is valid; the same command runs where the limit is higher). See ``resource_limits``."""


class UserInputError(ValueError):
    """Bad input from the user: reported as one line, exit status 2.

    The message names the field (flag, scenario key or parameter), the value and what is allowed.
    """


class NonFiniteSignal(RuntimeError):
    """A system received (or computed) NaN or inf: the message names the system, the port (or
    the quantity), the element and the simulated time. Raised inside a Drake system's
    calculation so that the simulator stops at once (an error-controlled integrator would
    otherwise shrink its step forever on a NaN derivative)."""


def check_finite_input(system, port, context, value=None):
    """``port.Eval(context)`` (or ``value``) as a numpy array, or NonFiniteSignal naming it.

    Args:
        system: the LeafSystem (its name is used).
        port: the input port (its name is used).
        context: the system's context (its time is used).
        value: the already evaluated value, to avoid a second Eval.
    """
    import math

    import numpy as np

    x = port.Eval(context) if value is None else value
    # The fast path runs in every derivative evaluation: on a few numbers, plain floats are
    # about 20 times cheaper than a numpy ufunc.
    if isinstance(x, np.ndarray) and all(map(math.isfinite, x.tolist())):
        return x
    x = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(x)):
        bad = np.flatnonzero(~np.isfinite(x.reshape(-1)))
        raise NonFiniteSignal(
            f"{system.get_name()}: input port '{port.get_name()}' is not finite at t = {context.get_time():.6g} s "
            f"(element {int(bad[0])} of {x.size}: {x.reshape(-1)[bad[0]]}; value {np.round(x, 6).tolist()})")
    return x


def check_in(name: str, value, lo, hi, *, lo_open: bool = False, unit: str = "") -> None:
    """Raise UserInputError unless ``value`` is a finite number in [lo, hi] ((lo, hi] with lo_open).

    For the Python API of the experiments (``run(...)``), which skips argparse's checks.
    """
    import math

    import numpy as np

    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    # An integer is finite (math.isfinite would convert it to a float: OverflowError beyond 1e308).
    ok = ok and (isinstance(value, (int, np.integer)) or math.isfinite(value))
    ok = ok and lo <= value <= hi and not (lo_open and value == lo)
    if not ok:
        interval = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
        raise UserInputError(f"{name} must be a number in {interval}{' ' + unit if unit else ''}, got {short_repr(value)}")


def require_finite_fields(obj, allow_inf=()) -> None:
    """Every number of a parameter dataclass (also inside tuples/lists) is finite, else a
    UserInputError naming ``Class.field`` and the value. Bools and strings are skipped; the
    fields named in ``allow_inf`` may be +-inf ("no limit") but not NaN."""
    import dataclasses
    import math
    import numbers

    def bad(value) -> bool:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            if isinstance(value, (tuple, list)):
                return any(bad(v) for v in value)
            return False
        return not (isinstance(value, numbers.Integral) or math.isfinite(value))  # ints: no float conversion

    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if bad(value) and not (f.name in allow_inf and not math.isnan(value)):
            raise UserInputError(f"{type(obj).__name__}.{f.name} must be finite, got {short_repr(value)}")
