"""Omni-wheel kinematics: derived from rolling contact, checked against the paper's printed A."""

import numpy as np
import pytest

from ballchain.experiments.wheels import wheel_map_report
from ballchain.drake_models.omniwheel import (
    PAPER_A,
    OmniWheelGeometry,
    contacts_below,
    paper_forward_map,
    prototype_wheel_axes,
)

RNG = np.random.default_rng(11)


def contact_slip_velocity(g: OmniWheelGeometry, omega_a, omega_w):
    """Relative velocity sphere-minus-wheel at each contact, from positions (no driving direction).

    Wheel centre i sits at (rho_a + rho_w) n_i; its rim point at the contact moves at
    omega_w,i a_i x (c_i - centre_i); the sphere's point moves at omega_a x c_i.
    """
    c = g.contact_points
    centres = (g.sphere_radius + g.wheel_radius) * g.contact_normals
    v_wheel = omega_w[:, None] * np.cross(g.wheel_axes, c - centres)
    v_sphere = np.cross(omega_a, c)
    return v_sphere - v_wheel


def test_derived_A_reproduces_the_printed_A_to_its_rounding():
    g = OmniWheelGeometry()
    # Printed to 2 decimals: every entry within half a unit of the last digit.
    np.testing.assert_allclose(g.A, PAPER_A, atol=0.005, rtol=0)
    # Mutually orthogonal axes: A orthogonal, so A^-1 = A^T.
    np.testing.assert_allclose(g.A @ g.A.T, np.eye(3), atol=1e-14)


def test_prototype_geometry_wheels_below_the_sphere_axes_tangent():
    g = OmniWheelGeometry()
    n = g.contact_normals
    np.testing.assert_allclose(np.einsum("ij,ij->i", g.wheel_axes, n), 0.0, atol=1e-15)
    # All three contacts 35.26 deg from the nadir, 120 deg apart in azimuth.
    np.testing.assert_allclose(-n[:, 2], np.sqrt(2.0 / 3.0), rtol=1e-14)
    az = np.sort(np.rad2deg(np.arctan2(n[:, 1], n[:, 0])) % 360.0)
    np.testing.assert_allclose(az, [60.0, 180.0, 300.0], atol=1e-9)
    # Driving directions horizontal (along the circles of latitude).
    np.testing.assert_allclose(g.driving_directions[:, 2], 0.0, atol=1e-15)


def test_inverse_map_rolls_without_slip_from_contact_positions():
    g = OmniWheelGeometry()
    for _ in range(20):
        omega_a = RNG.normal(size=3)
        omega_w = g.wheel_speeds(omega_a)
        v_rel = contact_slip_velocity(g, omega_a, omega_w)
        # The rollers let the contact slide along the wheel axis only; everything else must vanish.
        free = np.einsum("ij,ij->i", v_rel, g.wheel_axes)[:, None] * g.wheel_axes
        np.testing.assert_allclose(v_rel - free, 0.0, atol=1e-15)


def test_forward_map_inverts_inverse_map_and_residual_is_zero():
    g = OmniWheelGeometry()
    omega_w = RNG.normal(size=(50, 3))
    omega_a = g.sphere_angular_velocity(omega_w)
    np.testing.assert_allclose(g.wheel_speeds(omega_a), omega_w, rtol=1e-12, atol=1e-12)
    assert np.abs(g.rolling_residual(omega_a, omega_w)).max() < 1e-16


def test_paper_forward_map_violates_rolling_contact():
    g = OmniWheelGeometry()
    omega_w = RNG.normal(size=(50, 3))
    res = np.abs(g.rolling_residual(paper_forward_map(omega_w, g), omega_w))
    scale = g.wheel_radius * np.abs(omega_w).max(axis=1)
    # Slip of tens of percent of the rim speed: not a rounding effect.
    assert (res.max(axis=1) / scale).max() > 0.3


def test_pure_rotation_about_vertical_by_hand():
    g = OmniWheelGeometry()
    w = 2.0
    # a_i . e3 = 1/sqrt(3) for all wheels: omega_w,i = -(rho_a/rho_w) w / sqrt(3), all equal.
    expected = -(43.5 / 48.0) * w / np.sqrt(3.0) * np.ones(3)
    np.testing.assert_allclose(g.wheel_speeds([0, 0, w]), expected, rtol=1e-14)
    np.testing.assert_allclose(g.sphere_angular_velocity(expected), [0, 0, w], atol=1e-14)


def test_map_does_not_depend_on_where_on_the_great_circle_the_wheel_touches():
    a = prototype_wheel_axes()
    n_low = contacts_below(a)
    # Rotate each contact about its axis by 20 deg: still tangent, a different touch point.
    n_other = np.array(
        [np.cos(0.35) * n + np.sin(0.35) * np.cross(ai, n) for ai, n in zip(a, n_low)]
    )
    g1 = OmniWheelGeometry(wheel_axes=a, contact_normals=n_low)
    g2 = OmniWheelGeometry(wheel_axes=a, contact_normals=n_other)
    omega_a = RNG.normal(size=3)
    np.testing.assert_allclose(g1.wheel_speeds(omega_a), g2.wheel_speeds(omega_a), rtol=1e-14)
    assert np.abs(g2.rolling_residual(omega_a, g2.wheel_speeds(omega_a))).max() < 1e-16


def test_report_residuals_and_axis_error_of_paper_map():
    report = wheel_map_report(n_samples=200, seed=1)
    res = report.rolling_residual_relative
    assert res["derived: omega_a = (rho_w/rho_a) A^-1 omega_w"] < 1e-14
    assert res["paper: omega_a = (rho_a/rho_w) A omega_w"] > 0.3
    # The printed (rounded) A itself is fine once used the right way round: < 1 % slip.
    assert res["printed A with corrected convention: (rho_w/rho_a) A_paper^-1 omega_w"] < 0.01
    # Commanding through the paper's map turns about an axis off by the rotation angle of
    # (A^T)^2 for the exact A; the printed rounding moves it by well under a degree.
    A = OmniWheelGeometry().A
    R = A.T @ A.T
    exact_angle = np.rad2deg(np.arccos((np.trace(R) - 1.0) / 2.0))
    assert report.paper_map_commanded_axis_error_deg == pytest.approx(exact_angle, abs=0.5)
    assert exact_angle > 20.0


def test_bad_geometry_is_rejected():
    with pytest.raises(ValueError, match="tangent"):
        OmniWheelGeometry(contact_normals=np.tile([0.0, 0.0, -1.0], (3, 1)))
    with pytest.raises(ValueError, match="coplanar"):
        axes = np.array([[1.0, 0, 0], [0, 1.0, 0], [1.0, 1.0, 0]])
        OmniWheelGeometry(wheel_axes=axes, contact_normals=np.tile([0.0, 0.0, -1.0], (3, 1)))
    with pytest.raises(ValueError, match="wheel_radius"):
        OmniWheelGeometry(wheel_radius=-1.0)
