"""Omni-wheel kinematics: the derived wheel-to-magnet map against the paper's, with residuals.

Derives ``omega_wheels = (rho_a/rho_w) A omega_magnet`` (rows of A = -a_i^T) from rolling without
slip at each wheel contact (``drake_models/omniwheel.py``; docs/design.md, 4.2), shows the wheel
geometry that reproduces the paper's printed A, and measures the rolling-contact residual of the
derived map and of the paper's printed ``omega_a = (rho_a/rho_w) A omega_w`` (plus the half-fixes).
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.omniwheel import PAPER_A, OmniWheelGeometry, paper_forward_map


def run(*, samples: int = 1000, seed: int = 0) -> dict:
    """The report as a JSON-ready dict (see ``wheel_map_report``)."""
    return wheel_map_report(n_samples=samples, seed=seed)


def wheel_map_report(n_samples: int = 1000, seed: int = 0) -> dict:
    """Derived map against the paper's, with the rolling-contact residual of each convention.

    Args:
        n_samples: number of random wheel-speed vectors (standard normal, rad/s).
        seed: random seed.

    Returns:
        A JSON-ready dict: the geometry (contact azimuths/polar angles in deg), the derived ``A``,
        the forward matrix ``(rho_w/rho_a) A^-1``, the paper's ``A`` and its printed forward
        matrix, orthogonality/transposition checks, and the relative rolling residual
        ``max |residual| / (rho_w max|omega_w|)`` of each convention (derived, paper as printed,
        and the two single fixes: ratio only, A^T only).
    """
    g = OmniWheelGeometry()
    rng = np.random.default_rng(seed)
    omega_w = rng.normal(size=(n_samples, 3))
    scale = g.wheel_radius * np.abs(omega_w).max(axis=1)

    def rel_residual(omega_a: np.ndarray) -> float:
        return float((np.abs(g.rolling_residual(omega_a, omega_w)).max(axis=1) / scale).max())

    conventions = {
        "derived: omega_a = (rho_w/rho_a) A^-1 omega_w": g.sphere_angular_velocity(omega_w),
        "paper: omega_a = (rho_a/rho_w) A omega_w": paper_forward_map(omega_w, g),
        "paper ratio fixed only: (rho_w/rho_a) A omega_w": omega_w @ PAPER_A.T / g.ratio,
        "paper A^T only: (rho_a/rho_w) A^T omega_w": g.ratio * omega_w @ PAPER_A,
        "printed A with corrected convention: (rho_w/rho_a) A_paper^-1 omega_w": omega_w
        @ np.linalg.inv(PAPER_A).T
        / g.ratio,
    }
    # What the printed map does to a commanded rotation: a controller that inverts the paper's
    # forward map sends omega_w = (rho_w/rho_a) A_paper^-1 omega_des, and the real wheels then turn
    # the sphere at C omega_des with C = (rho_w/rho_a)^2 A^-1 A_paper^-1 (about a rotation).
    C = np.linalg.inv(g.A) @ np.linalg.inv(PAPER_A) / g.ratio**2
    U, S, Vt = np.linalg.svd(C)
    R_polar = U @ Vt
    n = g.contact_normals
    return {
        "wheel_radius_m": g.wheel_radius,
        "sphere_radius_m": g.sphere_radius,
        "ratio_rho_a_over_rho_w": g.ratio,
        "contact_azimuth_deg": np.rad2deg(np.arctan2(n[:, 1], n[:, 0])) % 360.0,
        "contact_polar_angle_from_nadir_deg": np.rad2deg(np.arccos(-n[:, 2])),
        "wheel_axes": g.wheel_axes,
        "A_derived_rows_minus_a": g.A,
        "A_paper": PAPER_A,
        "max_abs_A_derived_minus_paper": float(np.abs(g.A - PAPER_A).max()),
        "A_derived_is_orthogonal_max_error": float(np.abs(g.A @ g.A.T - np.eye(3)).max()),
        "det_A_derived": float(np.linalg.det(g.A)),
        "max_abs_A_minus_A_transpose": float(np.abs(g.A - g.A.T).max()),
        "inverse_map_wheels_from_sphere": g.ratio * g.A,
        "forward_map_sphere_from_wheels": np.linalg.inv(g.A) / g.ratio,
        "paper_forward_map": g.ratio * PAPER_A,
        "rolling_residual_relative": {k: rel_residual(v) for k, v in conventions.items()},
        "paper_map_commanded_axis_error_deg": float(
            np.rad2deg(np.arccos(np.clip((np.trace(R_polar) - 1.0) / 2.0, -1.0, 1.0)))
        ),
        "paper_map_speed_gain": [float(S.min()), float(S.max())],
        "n_samples": n_samples,
    }
