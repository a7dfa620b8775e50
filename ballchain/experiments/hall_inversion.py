"""The Hall-sensor inversion compared: the paper's printed formula, the correct dipole inverse and
a refinement on the exact cylinder field (docs/design.md, 4.1).

``run`` compares them at a few sensor distances over the off-axis angles (the actuation
notebook's figure); ``inversion_comparison`` is one distance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ballchain.drake_models.dipole import dipole_field
from ballchain.drake_models.dipole_inversion import (
    direction_from_field,
    paper_direction_formula,
    paper_formula_angle_error,
    refine_direction,
    sensor_field,
)
from ballchain.drake_models.params import CylinderMagnet, SphereMagnet
from ballchain.drake_models.vectors import angle_between
from ballchain.infrastructure.arg_checks import require_bool
from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.experiments._result import Result


@dataclass
class InversionComparison(Result):
    """What ``inversion_comparison`` returns: direction errors per off-axis angle, (k,) arrays [deg].

    Attributes:
        D_m: the sensor's distance below the magnet centre [m].
        theta_deg: the angles between the dipole and the world z axis [deg].
        paper_formula_dipole: the printed formula on the dipole forward field.
        paper_formula_closed_form: the same in closed form.
        correct_inverse_dipole: the correct inverse on the dipole field (zero up to round-off).
        correct_inverse_exact: the correct dipole inverse on the exact cylinder field (what the
            dipole assumption costs).
        paper_formula_exact: the printed formula on the exact field.
        refined_exact: Gauss-Newton on the exact model (NaN without ``refine``).
        B_max_mT: the largest |B| at the sensor over the angles [mT].
    """

    D_m: float
    theta_deg: np.ndarray
    paper_formula_dipole: np.ndarray
    paper_formula_closed_form: np.ndarray
    correct_inverse_dipole: np.ndarray
    correct_inverse_exact: np.ndarray
    paper_formula_exact: np.ndarray
    refined_exact: np.ndarray
    B_max_mT: float


def inversion_comparison(
    D: float,
    theta_deg: np.ndarray,
    magnet: CylinderMagnet | SphereMagnet | None = None,
    azimuth_deg: float = 30.0,
    refine: bool = True,
) -> InversionComparison:
    """Direction error of three estimators against the true dipole direction, per off-axis angle.

    Args:
        D: sensor distance below the magnet centre along -z [m].
        theta_deg: (k,) angles between the dipole and the world z axis [deg].
        magnet: the actuation magnet (prototype cylinder by default).
        azimuth_deg: azimuth of the dipole about z [deg] (the cylinder is axisymmetric, so the
            errors do not depend on it; kept to show that).
        refine: also run the Gauss-Newton refinement (about 10 exact evaluations per angle).

    Returns:
        An ``InversionComparison`` of (k,) arrays [deg].
    """
    magnet = magnet or CylinderMagnet()
    theta = np.deg2rad(np.asarray(theta_deg, dtype=float))
    phi = np.deg2rad(azimuth_deg)
    m_hat = np.column_stack(
        [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]
    )
    r = np.array([0.0, 0.0, -D])
    moment = magnet.dipole_moment
    B_dip = dipole_field(r, moment * m_hat)
    B_exact = np.array([sensor_field(magnet, D, m, "exact") for m in m_hat])
    est_exact = direction_from_field(B_exact, r)

    def model(m):
        return sensor_field(magnet, D, m, "exact")

    if refine:
        refined = np.array([refine_direction(B, model, m0) for B, m0 in zip(B_exact, est_exact)])
    else:
        refined = np.full_like(m_hat, np.nan)
    deg = np.rad2deg
    return InversionComparison(
        D_m=D,
        theta_deg=np.rad2deg(theta),
        paper_formula_dipole=deg(angle_between(paper_direction_formula(B_dip, D, moment), m_hat)),
        paper_formula_closed_form=deg(paper_formula_angle_error(theta)),
        correct_inverse_dipole=deg(angle_between(direction_from_field(B_dip, r), m_hat)),
        correct_inverse_exact=deg(angle_between(est_exact, m_hat)),
        paper_formula_exact=deg(angle_between(paper_direction_formula(B_exact, D, moment), m_hat)),
        refined_exact=deg(angle_between(refined, m_hat)),
        B_max_mT=float(np.linalg.norm(B_exact, axis=1).max() * 1e3),
    )


DISTANCES_MM = (60.0, 80.0, 100.0)  # the sensor below the magnet centre [mm]: the notebook's three


@dataclass
class HallInversionResult(Result):
    """What ``run`` returns: the three estimators' direction errors at each sensor distance.

    Attributes:
        distances_mm: the sensor distances below the magnet centre [mm].
        theta_deg: the angles between the dipole and the sensor axis, (k,) [deg].
        comparisons: one ``InversionComparison`` per distance, in order.
        paper_formula_max_error_deg: the printed formula's largest error on the dipole field, per
            distance [deg] (the same at every distance: it depends on the angle only).
        correct_inverse_exact_max_error_deg: the correct dipole inverse's largest error on the
            exact cylinder field, per distance [deg] (what the dipole assumption costs there).
        B_max_mT: the largest |B| at the sensor, per distance [mT].
    """

    distances_mm: list
    theta_deg: np.ndarray
    comparisons: list
    paper_formula_max_error_deg: list
    correct_inverse_exact_max_error_deg: list
    B_max_mT: list


def run(*, distances_mm=DISTANCES_MM, theta_step_deg: float = 2.5, refine: bool = False) -> HallInversionResult:
    """The Hall-sensor inversion compared at each sensor distance, for angles 0..180 deg.

    Args:
        distances_mm: sensor distances below the prototype cylinder's centre [mm], each in
            [40, 1000] (the cylinder's half length is 19.05 mm: closer, the sensor sits at its face).
        theta_step_deg: the step of the angle between the dipole and the sensor axis [deg], in
            (0, 90] and dividing 180.
        refine: also run the Gauss-Newton refinement on the exact model (slower).

    Returns:
        A ``HallInversionResult``.
    """
    if isinstance(distances_mm, (int, float)):
        distances_mm = (distances_mm,)
    try:
        distances = [float(d) for d in distances_mm]
    except (TypeError, ValueError):
        raise UserInputError(f"distances_mm must be a list of numbers [mm], got {short_repr(distances_mm)}") from None
    if not distances or not all(math.isfinite(d) and 40.0 <= d <= 1000.0 for d in distances):
        raise UserInputError(f"distances_mm must be one or more distances in [40, 1000] mm, got {short_repr(distances_mm)}")
    number = isinstance(theta_step_deg, (int, float)) and not isinstance(theta_step_deg, bool)
    steps = 180.0 / theta_step_deg if number and theta_step_deg > 0 else math.nan
    if not (math.isfinite(steps) and theta_step_deg <= 90.0 and abs(steps - round(steps)) < 1e-9):
        raise UserInputError(f"theta_step_deg must be in (0, 90] deg and divide 180, got {short_repr(theta_step_deg)}")
    require_bool(refine, "refine")
    theta = np.linspace(0.0, 180.0, int(round(steps)) + 1)
    comparisons = [inversion_comparison(1e-3 * d, theta, refine=refine) for d in distances]
    return HallInversionResult(
        distances_mm=distances,
        theta_deg=theta,
        comparisons=comparisons,
        paper_formula_max_error_deg=[float(c.paper_formula_dipole.max()) for c in comparisons],
        correct_inverse_exact_max_error_deg=[float(c.correct_inverse_exact.max()) for c in comparisons],
        B_max_mT=[c.B_max_mT for c in comparisons],
    )
