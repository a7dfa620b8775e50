"""What the statics tests share."""

from dataclasses import fields

import numpy as np


def assert_same_statics(a, b) -> None:
    """Two StaticsResults equal field by field, bit for bit (the solve time aside)."""
    for f in fields(a):
        if f.name != "solve_time":
            x, y = getattr(a, f.name), getattr(b, f.name)
            assert (np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y), f.name
