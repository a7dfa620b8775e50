"""The quasi-static engine's helpers: ball frames (x along the dipole) for the published poses,
the rows' norms, and ``EngineEvent`` (a snap-through or a failed solve). ``quasi_static_engine``
re-exports them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.systems.engine_kernels import ball_frames as _ball_frames


def _norms(rows: np.ndarray) -> np.ndarray:
    """The rows' Euclidean norms, as ``np.linalg.norm(rows, axis=1)`` computes them (the square
    root of the summed squares: the same floats) without its wrapper's cost."""
    return np.sqrt(np.add.reduce(rows * rows, axis=1))


def rotation_with_x_along(direction) -> np.ndarray:
    """R_WB whose first column is the unit vector along ``direction`` (a ball's dipole is +x)."""
    return rotation_with_z_along(direction)[:, [2, 0, 1]]


def rotations_with_x_along(directions: np.ndarray) -> np.ndarray:
    """(k, 3, 3) rotations whose first columns are the unit vectors along ``directions`` (k, 3)
    (``rotation_with_x_along`` for all balls at once: the engine publishes every ball's pose per
    update). The cross products are written out by components (numpy's ``cross`` formula, the
    same floating-point results) to save its per-call overhead."""
    return ball_frames(directions, np.zeros_like(directions))[:, :, :3]


def ball_frames(directions: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(k, 3, 4) poses [R_WB | p_WB] of balls at ``centres`` (k, 3) [m] with x along
    ``directions`` (k, 3): one array for all balls (``RigidTransform.MakeUnchecked`` of each row
    is its pose). Compiled (``engine_kernels.ball_frames``): the floats of ``rotation_with_x_along``
    per ball, in one call per update."""
    return _ball_frames(np.ascontiguousarray(directions, float), np.ascontiguousarray(centres, float))


@dataclass
class EngineEvent:
    """Something the engine reports: a snap-through or a failed solve."""

    time: float
    kind: str  # "snap-through" or "solve failed"
    jump: float  # largest ball displacement over the step [m]
    detail: str = ""
