"""Checks of the Python API's arguments: one line at the top of a public constructor or function.

Each raises ``UserInputError`` naming the argument, the value (``errors.short_repr``) and what is
allowed, so that a wrong shape or type from a script or a notebook fails where it was passed, not
as a numpy broadcasting error three layers down. (The command line and the scenario files check
their own fields; these are for callers of the library.)
"""

from __future__ import annotations

import math

import numpy as np

from ballchain.infrastructure.errors import UserInputError, short_repr


def _holds_booleans(value) -> bool:
    """Whether ``value`` (an array, or nested lists and tuples) holds True or False: numpy would
    read them as 1 and 0 (``UniformField([True, False, False])`` a 1 T field)."""
    if isinstance(value, np.ndarray):
        return value.dtype == bool or (value.dtype == object and any(_holds_booleans(v) for v in value.flat))
    if isinstance(value, (list, tuple)):
        return any(_holds_booleans(v) for v in value)
    return isinstance(value, (bool, np.bool_))


def as_vector(value, name: str, size: int = 3, *, nonzero: bool = False, unit: str = "") -> np.ndarray:
    """``value`` as a float array of ``size`` finite numbers (a copy), else UserInputError.

    Args:
        value: a sequence or array of numbers.
        name: the argument's name, as the caller wrote it.
        size: how many numbers.
        nonzero: refuse the zero vector (a direction or a normal).
        unit: the unit named in the message (e.g. "m", "T").
    """
    allowed = f"{size} finite numbers{' [' + unit + ']' if unit else ''}{' (non-zero)' if nonzero else ''}"
    if isinstance(value, (str, bytes, dict)) or value is None or _holds_booleans(value):
        raise UserInputError(f"{name} must be {allowed}, got {short_repr(value)}")
    try:
        x = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise UserInputError(f"{name} must be {allowed}, got {short_repr(value)}") from None
    if x.shape != (size,):
        raise UserInputError(f"{name} must be {allowed}, got {short_repr(value)} (shape {x.shape})")
    if not np.all(np.isfinite(x)) or (nonzero and not np.any(x)):
        raise UserInputError(f"{name} must be {allowed}, got {short_repr(value)}")
    return x


def as_array(value, name: str, shape: tuple, *, integer: bool = False) -> np.ndarray:
    """``value`` as a finite array of ``shape`` (-1: any length), else UserInputError.

    With ``integer``, the values must be whole numbers (returned as int64).
    """
    allowed = f"an array of shape ({', '.join('k' if s == -1 else str(s) for s in shape)})" \
        + (" of integers" if integer else " of finite numbers")
    if isinstance(value, (str, bytes, dict)) or value is None or _holds_booleans(value):
        raise UserInputError(f"{name} must be {allowed}, got {short_repr(value)}")
    try:
        x = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise UserInputError(f"{name} must be {allowed}, got {short_repr(value)}") from None
    if x.ndim != len(shape) or any(s != -1 and s != n for s, n in zip(shape, x.shape)):
        raise UserInputError(f"{name} must be {allowed}, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise UserInputError(f"{name} must be {allowed}, got non-finite values")
    if integer:
        if np.any(x != np.round(x)) or (x.size and np.abs(x).max() >= 2.0**62):
            raise UserInputError(f"{name} must be {allowed}, got {short_repr(value)}")
        return x.astype(np.int64)
    return x


def require_type(value, types, name: str, what: str | None = None):
    """``value`` when it is an instance of ``types`` (a type or a tuple), else UserInputError
    saying what is expected (``what``, default the types' names)."""
    if isinstance(value, types):
        return value
    expected = what or " or ".join(t.__name__ for t in (types if isinstance(types, tuple) else (types,)))
    raise UserInputError(f"{name} must be {expected}, got {type(value).__name__} {short_repr(value)}")


def require_choice(value, choices, name: str) -> str:
    """``value`` when it is one of the strings ``choices``, else UserInputError listing them."""
    if isinstance(value, str) and value in choices:
        return value
    raise UserInputError(f"{name} must be one of {', '.join(repr(c) for c in choices)}; got {short_repr(value)}")


def require_bool(value, name: str) -> bool:
    """``value`` when it is True or False (numpy's too), else UserInputError."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise UserInputError(f"{name} must be True or False, got {short_repr(value)}")


def require_int(value, name: str, lo: int, hi: int | None = None) -> int:
    """``value`` when it is an integer (not a bool) in [lo, hi], else UserInputError."""
    ok = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
    if ok and lo <= value and (hi is None or value <= hi):
        return int(value)
    allowed = f"an integer >= {lo}" if hi is None else f"an integer in {lo}..{hi}"
    raise UserInputError(f"{name} must be {allowed}, got {short_repr(value)}")


def require_positive(value, name: str, unit: str = "", allow_zero: bool = False) -> float:
    """``value`` when it is a finite number > 0 (>= 0 with ``allow_zero``), else UserInputError."""
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    if ok and math.isfinite(value) and (value > 0 or (allow_zero and value == 0)):
        return float(value)
    allowed = f"a finite number {'>= 0' if allow_zero else '> 0'}{' [' + unit + ']' if unit else ''}"
    raise UserInputError(f"{name} must be {allowed}, got {short_repr(value)}")


def as_plane(value, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``value`` as a plane ``(point (3,) [m], unit normal (3,))``, else UserInputError."""
    if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__len__") or len(value) != 2:
        raise UserInputError(f"{name} must be a (point, normal) pair of 3-vectors, got {short_repr(value)}")
    point = as_vector(value[0], f"{name} point", unit="m")
    normal = as_vector(value[1], f"{name} normal", nonzero=True)
    return point, normal / np.linalg.norm(normal)


def as_rows(value, name: str, rows: int, size: int = 3, *, nonzero: bool = False) -> np.ndarray:
    """``value`` as ``rows`` finite ``size``-vectors (rows, size); given as (rows, size) or flat
    (rows * size,), else UserInputError. With ``nonzero`` no row may be the zero vector."""
    allowed = f"{rows} row(s) of {size} finite numbers{' (each non-zero)' if nonzero else ''}"
    x = as_array(value, name, (-1,) if np.ndim(value) == 1 else (-1, size)) \
        if not isinstance(value, (str, bytes, dict)) and value is not None and np.ndim(value) in (1, 2) else None
    if x is None or x.size != rows * size:
        raise UserInputError(f"{name} must be {allowed}, got {short_repr(value)}")
    x = x.reshape(rows, size)
    if nonzero and np.any(~np.any(x, axis=1)):
        raise UserInputError(f"{name} must be {allowed}, got {short_repr(value)}")
    return x


def as_int_list(value, name: str, lo: int, hi: int | None = None) -> list[int]:
    """``value`` (a sequence or range of integers, at least one) as a list, each in [lo, hi],
    else UserInputError."""
    allowed = f"a non-empty list of integers >= {lo}" if hi is None else f"a non-empty list of integers in {lo}..{hi}"
    try:
        items = list(value) if not isinstance(value, (str, bytes, dict)) else None
    except TypeError:
        items = None
    ok = bool(items) and all(isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))
                             and lo <= v and (hi is None or v <= hi) for v in items)
    if not ok:
        raise UserInputError(f"{name} must be {allowed}, got {short_repr(value)}")
    return [int(v) for v in items]


def as_number_list(value, name: str, lo: float, hi: float, *, lo_open: bool = False, unit: str = "") -> list[float]:
    """``value`` (a sequence of finite numbers, at least one) as a list of floats, each in [lo, hi]
    ((lo, hi] with ``lo_open``), else UserInputError."""
    interval = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]{' ' + unit if unit else ''}"
    try:
        items = list(value) if not isinstance(value, (str, bytes, dict)) else None
    except TypeError:
        items = None
    number = (int, float, np.integer, np.floating)
    ok = bool(items) and all(isinstance(v, number) and not isinstance(v, (bool, np.bool_)) and math.isfinite(v)
                             and lo <= v <= hi and not (lo_open and v == lo) for v in items)
    if not ok:
        raise UserInputError(f"{name} must be a non-empty list of numbers in {interval}, got {short_repr(value)}")
    return [float(v) for v in items]
