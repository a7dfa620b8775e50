"""Equilibrium shape of a chain in a uniform field, reached by rotating the field from +x.

The canonical problem of docs/design.md (2.3): ball 1 held at the origin with its dipole along +x,
the field in the x-y plane at ``--field-angle-deg`` from +x, reached by continuation from the
straight chain in steps of at most ``--step-deg`` (as a rotating magnet moves the chain).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from ballchain.infrastructure.errors import UserInputError, check_in, short_repr
from ballchain.drake_models.field_sources import MAX_FIELD_T, UniformField
from ballchain.drake_models.params import BallChain, Sleeve
from ballchain.experiments._result import Result
from ballchain.optimization.statics import MAX_BALLS, ChainStatics, rotation_path, tip_angle_deg

MAX_FIELD_MT = MAX_FIELD_T * 1e3  # the API's bound (field_sources.MAX_FIELD_T) in the flags' unit
MIN_STEP_DEG = 0.1  # at most 7200 continuation steps over the widest angle


@dataclass
class StaticsShapeResult(Result):
    """What ``run`` returns: the last equilibrium of the continuation.

    Attributes:
        positions_mm: ball centres [mm], shape (n, 3).
        dipoles: unit dipole directions, shape (n, 3).
        tip_angle_deg: angle between the field and the tip dipole [deg] (None without a field).
        energy_J: the chain's energy at the equilibrium [J].
        converged, reason, solver, iterations, solve_time_s: the last solve's report (time in s).
        continuation_steps: number of field angles solved; continuation_time_s: their total
            solve time [s].
    """

    positions_mm: np.ndarray
    dipoles: np.ndarray
    tip_angle_deg: float | None
    energy_J: float
    converged: bool
    reason: str
    solver: str
    iterations: int
    solve_time_s: float
    continuation_steps: int
    continuation_time_s: float


FLAGS = {"balls": "--balls", "field_mT": "--field-mT", "field_angle_deg": "--field-angle-deg", "step_deg": "--step-deg"}


def check_inputs(*, balls, field_mT, field_angle_deg, step_deg, names: dict = FLAGS) -> None:
    """The ranges of ``run``'s inputs (the command's flags, a sweep's fields: ``names`` maps each
    argument to the name the message uses); raises UserInputError naming it."""
    if isinstance(balls, bool) or not isinstance(balls, (int, np.integer)) or not 1 <= balls <= MAX_BALLS:
        raise UserInputError(f"{names['balls']} must be an integer in 1..{MAX_BALLS}, got {short_repr(balls)}")
    check_in(names["field_mT"], field_mT, 0.0, MAX_FIELD_MT, unit="mT")
    check_in(names["field_angle_deg"], field_angle_deg, -360.0, 360.0, unit="deg")
    check_in(names["step_deg"], step_deg, MIN_STEP_DEG, 90.0, unit="deg")


def run(*, balls: int, field_mT: float, field_angle_deg: float, step_deg: float = 22.5,
        gravity: bool = False, sleeve: bool = False, method: str = "newton") -> StaticsShapeResult:
    """The equilibrium after turning the field from +x to ``field_angle_deg`` (continuation).

    Args:
        balls: number of balls (1..MAX_BALLS).
        field_mT: field magnitude [mT] (0..MAX_FIELD_MT).
        field_angle_deg: field angle from +x towards +y [deg] (-360..360).
        step_deg: largest continuation step [deg] (MIN_STEP_DEG..90).
        gravity: gravity along -z.
        sleeve: with the Dragon Skin sleeve.
        method: "newton" or "snopt".

    Returns:
        A ``StaticsShapeResult``.

    Raises:
        UserInputError: a value out of range, named by its flag (before any solve).
    """
    check_inputs(balls=balls, field_mT=field_mT, field_angle_deg=field_angle_deg, step_deg=step_deg)
    if method not in ("newton", "snopt"):
        raise UserInputError(f"--method must be 'newton' or 'snopt', got {method!r}")
    chain = BallChain(n_balls=balls, sleeve=Sleeve() if sleeve else None)
    solver = ChainStatics(chain, gravity=gravity, method=method)
    angles = rotation_path(0.0, field_angle_deg, step_deg)
    # Progress only for long continuations (a few hundred solves take seconds).
    results = solver.continuation(
        UniformField.in_plane(field_mT * 1e-3, np.radians(angle))
        for angle in tqdm(angles, desc="statics", unit="step", disable=len(angles) < 200, file=sys.stderr))
    result = results[-1]
    total_time = sum(step.solve_time for step in results)
    direction = [np.cos(np.radians(field_angle_deg)), np.sin(np.radians(field_angle_deg)), 0.0]
    return StaticsShapeResult(
        positions_mm=result.positions * 1e3,
        dipoles=result.dipoles,
        tip_angle_deg=tip_angle_deg(result, direction) if field_mT > 0 else None,
        energy_J=result.energy,
        converged=result.converged,
        reason=result.reason,
        solver=result.solver,
        iterations=result.iterations,
        solve_time_s=result.solve_time,
        continuation_steps=len(angles),
        continuation_time_s=total_time,
    )
