"""Omni-wheel kinematics: the derived wheel-to-magnet map against the paper's, with residuals.

Derives ``omega_wheels = (rho_a/rho_w) A omega_magnet`` (rows of A = -a_i^T) from rolling without
slip at each wheel contact (``drake_models/omniwheel.py``; docs/design.md, 4.2), shows the wheel
geometry that reproduces the paper's printed A, and measures the rolling-contact residual of the
derived map and of the paper's printed ``omega_a = (rho_a/rho_w) A omega_w`` (plus the half-fixes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ballchain.infrastructure.arg_checks import require_int
from ballchain.drake_models.omniwheel import PAPER_A, OmniWheelGeometry, paper_forward_map
from ballchain.experiments._result import Result


@dataclass
class WheelsResult(Result):
    """What ``run`` (``wheel_map_report``) returns.

    Attributes:
        wheel_radius_m, sphere_radius_m: rho_w and rho_a [m]; ratio_rho_a_over_rho_w: their ratio.
        contact_azimuth_deg, contact_polar_angle_from_nadir_deg: the wheel contacts, shape (3,).
        wheel_axes: the wheels' axes (rows), shape (3, 3).
        A_derived_rows_minus_a: the derived A (rows -a_i^T), (3, 3); A_paper: the paper's, (3, 3).
        max_abs_A_derived_minus_paper, A_derived_is_orthogonal_max_error, det_A_derived,
            max_abs_A_minus_A_transpose: checks of A.
        inverse_map_wheels_from_sphere: (rho_a/rho_w) A; forward_map_sphere_from_wheels:
            (rho_w/rho_a) A^-1; paper_forward_map: the paper's printed (rho_a/rho_w) A; (3, 3) each.
        rolling_residual_relative: {convention: max |residual| / (rho_w max|omega_w|)}.
        paper_map_commanded_axis_error_deg: the axis error of a rotation commanded through the
            paper's map [deg]; paper_map_speed_gain: [min, max] of its speed gain.
        n_samples: random wheel-speed vectors used.
    """

    wheel_radius_m: float
    sphere_radius_m: float
    ratio_rho_a_over_rho_w: float
    contact_azimuth_deg: np.ndarray
    contact_polar_angle_from_nadir_deg: np.ndarray
    wheel_axes: np.ndarray
    A_derived_rows_minus_a: np.ndarray
    A_paper: np.ndarray
    max_abs_A_derived_minus_paper: float
    A_derived_is_orthogonal_max_error: float
    det_A_derived: float
    max_abs_A_minus_A_transpose: float
    inverse_map_wheels_from_sphere: np.ndarray
    forward_map_sphere_from_wheels: np.ndarray
    paper_forward_map: np.ndarray
    rolling_residual_relative: dict
    paper_map_commanded_axis_error_deg: float
    paper_map_speed_gain: list
    n_samples: int


def run(*, samples: int = 1000, seed: int = 0) -> WheelsResult:
    """The report (see ``wheel_map_report``)."""
    require_int(samples, "samples", 1, 10_000_000)
    require_int(seed, "seed", 0)
    return wheel_map_report(n_samples=samples, seed=seed)


def wheel_map_report(n_samples: int = 1000, seed: int = 0) -> WheelsResult:
    """Derived map against the paper's, with the rolling-contact residual of each convention.

    Args:
        n_samples: number of random wheel-speed vectors (standard normal, rad/s).
        seed: random seed.

    Returns:
        A ``WheelsResult``: the geometry (contact azimuths/polar angles in deg), the derived ``A``,
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
    return WheelsResult(
        wheel_radius_m=g.wheel_radius,
        sphere_radius_m=g.sphere_radius,
        ratio_rho_a_over_rho_w=g.ratio,
        contact_azimuth_deg=np.rad2deg(np.arctan2(n[:, 1], n[:, 0])) % 360.0,
        contact_polar_angle_from_nadir_deg=np.rad2deg(np.arccos(-n[:, 2])),
        wheel_axes=g.wheel_axes,
        A_derived_rows_minus_a=g.A,
        A_paper=PAPER_A,
        max_abs_A_derived_minus_paper=float(np.abs(g.A - PAPER_A).max()),
        A_derived_is_orthogonal_max_error=float(np.abs(g.A @ g.A.T - np.eye(3)).max()),
        det_A_derived=float(np.linalg.det(g.A)),
        max_abs_A_minus_A_transpose=float(np.abs(g.A - g.A.T).max()),
        inverse_map_wheels_from_sphere=g.ratio * g.A,
        forward_map_sphere_from_wheels=np.linalg.inv(g.A) / g.ratio,
        paper_forward_map=g.ratio * PAPER_A,
        rolling_residual_relative={k: rel_residual(v) for k, v in conventions.items()},
        paper_map_commanded_axis_error_deg=float(
            np.rad2deg(np.arccos(np.clip((np.trace(R_polar) - 1.0) / 2.0, -1.0, 1.0)))
        ),
        paper_map_speed_gain=[float(S.min()), float(S.max())],
        n_samples=n_samples,
    )
