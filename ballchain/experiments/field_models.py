"""Point-dipole vs exact (magpylib) field of a cylindrical magnet, as data a report can reuse.

Both models come from :class:`MagnetSource` (``model="dipole"`` and ``model="exact"``), so this
compares exactly what the simulation uses. The magnet sits at the origin magnetised along +z;
field points lie in the x-z plane at a polar angle from the axis (0 deg: on the axis, 90 deg: on
the equator). Besides the flux density it compares the force on a small ball whose dipole is
aligned with each model's own field, ``F = G (|m_ball| B / |B|)``, which is what the gradient
does to the chain.

For an axially magnetised cylinder of radius R and length L the quadrupole vanishes by symmetry,
so the dipole's relative error falls like (a/r)^2; on the axis it is
``(1.5 R^2 - L^2 / 2) / z^2 + O(z^-4)`` (zero for L/D = sqrt(3)/2; the prototype has L/D = 1/2).

SI inside (m, T, T/m, N).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ballchain.infrastructure.arg_checks import as_number_list, require_type
from ballchain.drake_models import paper
from ballchain.drake_models.dipole import force_on_dipole
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.field_sources import MagnetSource
from ballchain.drake_models.params import BallChain, CylinderMagnet, gram_force
from ballchain.drake_models.vectors import angle_between
from ballchain.experiments._result import Result

DEFAULT_DISTANCES = (0.08, 0.12, paper.WORKING_DISTANCE, 0.20)
"""Distances from the magnet centre [m] (16.51 cm is the prototype's working distance)."""

DEFAULT_POLAR_ANGLES_DEG = (0.0, 45.0, 90.0)
"""On the axis, at 45 deg, on the equator [deg]."""

DIRECTION_NAMES = {0.0: "axis", 45.0: "45deg", 90.0: "equator"}


@dataclass(frozen=True)
class FieldModelComparison:
    """Dipole vs exact at one field point.

    Attributes:
        distance: from the magnet centre [m].
        polar_angle_deg: from the magnetisation axis [deg].
        p_M: (3,) field point in the magnet frame [m].
        B_dipole, B_exact: (3,) flux density [T].
        B_rel_error: (|B_dipole| - |B_exact|) / |B_exact| [-] (positive: the dipole overestimates).
        B_angle_error_deg: angle between B_dipole and B_exact [deg].
        G_rel_error: ||G_dipole - G_exact||_F / ||G_exact||_F of the gradient [-].
        F_dipole, F_exact: (3,) force on a ball aligned with that model's field [N].
        F_rel_error: (|F_dipole| - |F_exact|) / |F_exact| [-].
        F_angle_error_deg: angle between F_dipole and F_exact [deg].
    """

    distance: float
    polar_angle_deg: float
    p_M: np.ndarray
    B_dipole: np.ndarray
    B_exact: np.ndarray
    B_rel_error: float
    B_angle_error_deg: float
    G_rel_error: float
    F_dipole: np.ndarray
    F_exact: np.ndarray
    F_rel_error: float
    F_angle_error_deg: float

    @property
    def direction(self) -> str:
        """"axis", "45deg", "equator" or the angle as text."""
        return DIRECTION_NAMES.get(float(self.polar_angle_deg), f"{self.polar_angle_deg:g}deg")


def compare_field_models(
    magnet: CylinderMagnet = CylinderMagnet(),
    distances: Sequence[float] = DEFAULT_DISTANCES,
    polar_angles_deg: Sequence[float] = DEFAULT_POLAR_ANGLES_DEG,
    ball: BallChain = BallChain(),
) -> list[FieldModelComparison]:
    """Compare the point-dipole and exact fields of ``magnet`` on a grid of distance x direction.

    Args:
        magnet: the cylinder (the prototype N52 76.2 x 38.1 mm by default).
        distances: distances from the magnet centre [m], each positive.
        polar_angles_deg: angles from the magnetisation axis [deg], each in [0, 180].
        ball: the ball whose aligned force is compared (its dipole moment is used) [-].

    Returns:
        One comparison per (distance, angle), distances outer, angles inner.

    Raises:
        ValueError: a distance is not positive and finite, an angle out of range, or a point lies
            inside the magnet (from :class:`MagnetSource`).
    """
    distances = [float(r) for r in distances]
    angles = [float(a) for a in polar_angles_deg]
    if not distances or not angles:
        raise UserInputError("need at least one distance and one polar angle")
    for r in distances:
        if not (math.isfinite(r) and r > 0):
            raise UserInputError(f"distances must be positive finite numbers of metres, got {r!r}")
    for a in angles:
        if not (math.isfinite(a) and 0.0 <= a <= 180.0):
            raise UserInputError(f"polar angles must lie in [0, 180] deg, got {a!r}")
    grid = [(r, a) for r in distances for a in angles]
    p = np.array([[r * math.sin(math.radians(a)), 0.0, r * math.cos(math.radians(a))] for r, a in grid])
    dipole = MagnetSource(magnet, np.zeros(3), model="dipole")
    exact = MagnetSource(magnet, np.zeros(3), model="exact")
    B_d, G_d = dipole.field_and_gradient(p)
    B_e, G_e = exact.field_and_gradient(p)
    m_ball = ball.dipole_moment
    F_d = force_on_dipole(m_ball * B_d / np.linalg.norm(B_d, axis=1, keepdims=True), G_d)
    F_e = force_on_dipole(m_ball * B_e / np.linalg.norm(B_e, axis=1, keepdims=True), G_e)
    nB_d, nB_e = np.linalg.norm(B_d, axis=1), np.linalg.norm(B_e, axis=1)
    nF_d, nF_e = np.linalg.norm(F_d, axis=1), np.linalg.norm(F_e, axis=1)
    G_err = np.linalg.norm(G_d - G_e, axis=(1, 2)) / np.linalg.norm(G_e, axis=(1, 2))
    B_ang = np.degrees(angle_between(B_d, B_e))
    F_ang = np.degrees(angle_between(F_d, F_e))
    return [
        FieldModelComparison(
            distance=r,
            polar_angle_deg=a,
            p_M=p[i],
            B_dipole=B_d[i],
            B_exact=B_e[i],
            B_rel_error=float((nB_d[i] - nB_e[i]) / nB_e[i]),
            B_angle_error_deg=float(B_ang[i]),
            G_rel_error=float(G_err[i]),
            F_dipole=F_d[i],
            F_exact=F_e[i],
            F_rel_error=float((nF_d[i] - nF_e[i]) / nF_e[i]),
            F_angle_error_deg=float(F_ang[i]),
        )
        for i, (r, a) in enumerate(grid)
    ]


def on_axis_relative_error_coefficient(magnet: CylinderMagnet = CylinderMagnet()) -> float:
    """Leading coefficient c of the dipole's on-axis relative field error, c / z^2 [m^2].

    From the exact on-axis field ``B_z = (Br/2)[(z+l)/sqrt((z+l)^2+R^2) - (z-l)/sqrt((z-l)^2+R^2)]``
    (l = L/2) expanded in 1/z: ``c = 1.5 R^2 - 2 l^2``.
    """
    R = magnet.diameter / 2.0
    half = magnet.length / 2.0
    return 1.5 * R**2 - 2.0 * half**2


@dataclass
class FieldModelsResult(Result):
    """What ``run`` returns (edge units: cm, mm, mT, gf, %, deg).

    Attributes:
        magnet: {diameter_mm, length_mm, remanence_T, dipole_moment_Am2} of the cylinder.
        ball_diameter_mm: the ball whose aligned force is compared.
        on_axis_rel_error_asymptote_cm2: c of the on-axis relative error c / r^2 [cm^2].
        rows: one per (distance, polar angle): fields [mT] (3-vectors and magnitudes), their
            relative [%] and angle [deg] errors, the gradient's error [%], the aligned ball's
            forces [gf] and their errors.
        notes: how the errors are defined.
    """

    magnet: dict
    ball_diameter_mm: float
    on_axis_rel_error_asymptote_cm2: float
    rows: list
    notes: list


def run(*, distances_m, angles_deg, ball: BallChain, magnet: CylinderMagnet = CylinderMagnet()) -> FieldModelsResult:
    """The comparison of ``compare_field_models`` in edge units (cm, mT, gf, %, deg).

    Args:
        distances_m: distances from the magnet centre [m].
        angles_deg: polar angles from the magnetisation axis [deg], in [0, 180].
        ball: the ball whose aligned force is compared.
        magnet: the cylinder.

    Returns:
        A ``FieldModelsResult``.
    """
    as_number_list(distances_m, "distances_m", 0.0, 10.0, lo_open=True, unit="m")
    as_number_list(angles_deg, "angles_deg", 0.0, 180.0, unit="deg")
    require_type(ball, BallChain, "ball", "a BallChain")
    require_type(magnet, CylinderMagnet, "magnet", "a CylinderMagnet")
    rows = compare_field_models(magnet, distances_m, angles_deg, ball)
    return FieldModelsResult(
        magnet={
            "diameter_mm": magnet.diameter * 1e3,
            "length_mm": magnet.length * 1e3,
            "remanence_T": magnet.remanence,
            "dipole_moment_Am2": magnet.dipole_moment,
        },
        ball_diameter_mm=ball.ball_diameter * 1e3,
        on_axis_rel_error_asymptote_cm2=on_axis_relative_error_coefficient(magnet) * 1e4,
        rows=[
            {
                "distance_cm": row.distance * 1e2,
                "polar_angle_deg": row.polar_angle_deg,
                "direction": row.direction,
                "B_dipole_mT": row.B_dipole * 1e3,
                "B_exact_mT": row.B_exact * 1e3,
                "B_dipole_magnitude_mT": float(math.hypot(*row.B_dipole)) * 1e3,
                "B_exact_magnitude_mT": float(math.hypot(*row.B_exact)) * 1e3,
                "B_rel_error_percent": row.B_rel_error * 1e2,
                "B_angle_error_deg": row.B_angle_error_deg,
                "gradient_rel_error_percent": row.G_rel_error * 1e2,
                "force_dipole_gf": [gram_force(f) for f in row.F_dipole],
                "force_exact_gf": [gram_force(f) for f in row.F_exact],
                "force_dipole_magnitude_gf": gram_force(float(math.hypot(*row.F_dipole))),
                "force_exact_magnitude_gf": gram_force(float(math.hypot(*row.F_exact))),
                "force_rel_error_percent": row.F_rel_error * 1e2,
                "force_angle_error_deg": row.F_angle_error_deg,
            }
            for row in rows
        ],
        notes=[
            "rel error = (|dipole| - |exact|) / |exact|: positive means the dipole overestimates",
            "force: on one ball whose dipole is aligned with each model's own field, F = G m_hat |m_ball|",
            "exact: magpylib closed-form cylinder field; its gradient by central differences (MagnetSource)",
        ],
    )
