"""The Hall-sensor inversion compared: the paper's printed formula, the correct dipole inverse and
a refinement on the exact cylinder field (docs/design.md, 4.1).
"""

from __future__ import annotations

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


def inversion_comparison(
    D: float,
    theta_deg: np.ndarray,
    magnet: CylinderMagnet | SphereMagnet | None = None,
    azimuth_deg: float = 30.0,
    refine: bool = True,
) -> dict:
    """Direction error of three estimators against the true dipole direction, per off-axis angle.

    Args:
        D: sensor distance below the magnet centre along -z [m].
        theta_deg: (k,) angles between the dipole and the world z axis [deg].
        magnet: the actuation magnet (prototype cylinder by default).
        azimuth_deg: azimuth of the dipole about z [deg] (the cylinder is axisymmetric, so the
            errors do not depend on it; kept to show that).
        refine: also run the Gauss-Newton refinement (about 10 exact evaluations per angle).

    Returns:
        A dict of (k,) arrays [deg]: ``paper_formula_dipole`` (printed formula, dipole forward
        field), ``paper_formula_closed_form``, ``correct_inverse_dipole`` (correct inverse, dipole
        forward field: zero up to round-off), ``correct_inverse_exact`` (correct dipole inverse,
        exact cylinder forward field: what the dipole assumption costs), ``refined_exact``
        (Gauss-Newton on the exact model; NaN without ``refine``), and ``B_max_mT`` (largest
        |B| over the angles).
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
    return {
        "D_m": D,
        "theta_deg": np.rad2deg(theta),
        "paper_formula_dipole": deg(angle_between(paper_direction_formula(B_dip, D, moment), m_hat)),
        "paper_formula_closed_form": deg(paper_formula_angle_error(theta)),
        "correct_inverse_dipole": deg(angle_between(direction_from_field(B_dip, r), m_hat)),
        "correct_inverse_exact": deg(angle_between(est_exact, m_hat)),
        "paper_formula_exact": deg(angle_between(paper_direction_formula(B_exact, D, moment), m_hat)),
        "refined_exact": deg(angle_between(refined, m_hat)),
        "B_max_mT": float(np.linalg.norm(B_exact, axis=1).max() * 1e3),
    }
