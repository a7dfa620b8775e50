"""Hall-sensor inversion (correct vs the paper's formula), the sensor and the estimator systems."""

from dataclasses import replace

import numpy as np
import pytest
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import VectorLogSink

from ballchain.drake_models.dipole import K_DIPOLE, dipole_field
from ballchain.experiments.hall_inversion import inversion_comparison
from ballchain.drake_models.dipole_inversion import (
    dipole_matrix,
    dipole_matrix_inverse,
    direction_from_field,
    moment_from_field,
    paper_direction_formula,
    paper_formula_angle_error,
)
from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.drake_models.params import CylinderMagnet, SphereMagnet
from ballchain.drake_models.vectors import angle_between
from ballchain.systems.hall_sensor import DipoleDirectionEstimator, HallSensor, HallSensorSpec, quantise_reading
from ballchain.systems.unit_config import MagnetUnitConfig

RNG = np.random.default_rng(3)
E3 = np.array([0.0, 0.0, 1.0])


def test_dipole_matrix_inverse_is_three_halves_uu_minus_identity():
    for _ in range(10):
        u = RNG.normal(size=3)
        u /= np.linalg.norm(u)
        np.testing.assert_allclose(dipole_matrix_inverse(u) @ dipole_matrix(u), np.eye(3), atol=1e-14)
        np.testing.assert_allclose(dipole_matrix_inverse(u), np.linalg.inv(dipole_matrix(u)), atol=1e-14)
    # The dipole matrix is not its own inverse (the paper's assumption).
    assert np.abs(dipole_matrix(E3) @ dipole_matrix(E3) - np.eye(3)).max() == pytest.approx(3.0)


def test_moment_from_field_inverts_the_shared_dipole_law():
    r = RNG.normal(size=(8, 3)) * 0.1
    m = RNG.normal(size=(8, 3)) * 50
    for ri, mi in zip(r, m):
        np.testing.assert_allclose(moment_from_field(dipole_field(ri, mi), ri), mi, rtol=1e-12)


def test_paper_formula_error_closed_form_and_worst_case():
    D, moment = 0.1, 199.1
    theta = np.deg2rad(np.linspace(0.0, 180.0, 721))
    m_hat = np.column_stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)])
    B = dipole_field(np.array([0.0, 0.0, -D]), moment * m_hat)
    numeric = angle_between(paper_direction_formula(B, D, moment), m_hat)
    np.testing.assert_allclose(numeric, paper_formula_angle_error(theta), atol=1e-12)
    # Worst at tan(theta) = 2 (63.43 deg): error = atan(3/4) = 36.87 deg.
    k = int(np.argmax(numeric))
    assert np.rad2deg(theta[k]) == pytest.approx(np.rad2deg(np.arctan(2.0)), abs=0.25)
    assert np.rad2deg(numeric.max()) == pytest.approx(np.rad2deg(np.arctan(0.75)), abs=1e-3)
    # Exact on the axis and across it.
    for deg in (0, 90, 180):
        assert np.rad2deg(numeric[deg * 4]) < 1e-9
    # And its "unit" vector has norm between 1 and 4 (M^2 m_hat), e.g. 4 on the axis.
    norms = np.linalg.norm(paper_direction_formula(B, D, moment), axis=1)
    assert norms[0] == pytest.approx(4.0, rel=1e-12)
    assert norms[360] == pytest.approx(1.0, rel=1e-12)


def test_correct_inverse_recovers_direction_for_any_offset():
    for _ in range(10):
        r = RNG.normal(size=3) * 0.1
        m_hat = RNG.normal(size=3)
        m_hat /= np.linalg.norm(m_hat)
        B = dipole_field(r, 120.0 * m_hat)
        np.testing.assert_allclose(direction_from_field(B, r), m_hat, atol=1e-12)


def test_dipole_assumption_cost_with_exact_cylinder():
    theta = np.array([0.0, 30.0, 63.43, 90.0, 150.0, 180.0])
    near = inversion_comparison(0.10, theta)
    far = inversion_comparison(1.0, theta)
    # Symmetry: on the axis and across it the dipole inverse is exact for the cylinder too.
    for i in (0, 3, 5):
        assert near.correct_inverse_exact[i] < 1e-6
    # At 10 cm from a 76 mm cylinder the dipole inverse is degrees off; far away it is not.
    assert 4.0 < near.correct_inverse_exact.max() < 8.0
    assert far.correct_inverse_exact.max() < 0.1
    # The cylinder's first correction beyond the dipole is the octupole, relative size (a/D)^2:
    # the error falls by 100x from 0.1 m to 1 m (at 30 deg).
    exponent = np.log10(near.correct_inverse_exact[1] / far.correct_inverse_exact[1])
    assert exponent == pytest.approx(2.0, abs=0.1)
    # Gauss-Newton on the exact model removes it; the paper's formula is far worse than both.
    assert near.refined_exact.max() < 1e-3
    assert near.paper_formula_exact.max() > 30.0
    # At 10 cm the field stays inside an MLX90393's +-50 mT.
    assert near.B_max_mT < 50.0
    # At rho_a + 6.5 mm = 50 mm it would read more than three times the range (176 mT on axis).
    assert inversion_comparison(0.05, [0.0, 90.0]).B_max_mT > 150.0


def test_quantise_reading_clips_and_rounds():
    spec = HallSensorSpec(range_T=0.05, lsb_T=(1e-6, 1e-6, 2e-6))
    out = quantise_reading([0.07, -1.3e-6, 3.1e-6], spec)
    np.testing.assert_allclose(out, [0.05, -1e-6, 4e-6], rtol=1e-12)


def _sensor_diagram(unit, spec, noise, seed=0):
    builder = DiagramBuilder()
    sensor = builder.AddSystem(HallSensor(replace(unit, sensor_noise=noise), spec=spec, seed=seed))
    log = builder.AddSystem(VectorLogSink(3))
    builder.Connect(sensor.get_output_port(0), log.get_input_port(0))
    builder.ExportInput(sensor.GetInputPort("X_WM"), "X_WM")
    return builder.Build(), sensor, log


def test_hall_sensor_ports_and_equatorial_reading_by_hand():
    unit = MagnetUnitConfig(p_WM=[0.0, 0.0, 0.0], sensor_noise=False)
    assert unit.sensor_distance == 0.1
    sensor = HallSensor(unit)
    assert sensor.get_name() == "right_unit.hall_sensor"
    assert sensor.num_input_ports() == 1 and sensor.get_input_port(0).get_name() == "X_WM"
    assert sensor.num_output_ports() == 1
    assert sensor.get_output_port(0).get_name() == "B_sensor_T" and sensor.get_output_port(0).size() == 3
    diagram, sensor, _ = _sensor_diagram(unit, HallSensorSpec(), noise=False)
    ctx = diagram.CreateDefaultContext()
    R = rotation_with_z_along([1.0, 0.0, 0.0])  # dipole along +x, across the sensor axis
    diagram.get_input_port(0).FixValue(ctx, RigidTransform(RotationMatrix(R), np.zeros(3)))
    sim = Simulator(diagram, ctx)
    sim.AdvanceTo(0.05)
    # Equatorial dipole field: B = -k |m| / D^3 x_hat, within one LSB.
    expected = -K_DIPOLE * CylinderMagnet().dipole_moment / 0.1**3 * np.array([1.0, 0.0, 0.0])
    B = sensor.get_output_port(0).Eval(sensor.GetMyContextFromRoot(ctx))
    np.testing.assert_allclose(B, expected, atol=1.5e-6)


def test_hall_sensor_samples_at_rate_with_seeded_noise_and_saturates():
    unit = MagnetUnitConfig(p_WM=[0.0, 0.0, 0.0], shape="sphere")
    assert unit.magnet == SphereMagnet() and unit.sensor_distance == 0.1
    spec = HallSensorSpec(noise_std_T=20e-6, sample_rate_hz=200.0, lsb_T=(0.0, 0.0, 0.0))
    readings = []
    for seed in (5, 5, 6):
        diagram, sensor, log = _sensor_diagram(unit, spec, noise=True, seed=seed)
        ctx = diagram.CreateDefaultContext()
        R = rotation_with_z_along([1.0, 0.0, 0.0])
        diagram.get_input_port(0).FixValue(ctx, RigidTransform(RotationMatrix(R), np.zeros(3)))
        sim = Simulator(diagram, ctx)
        sim.AdvanceTo(1.0)
        data = log.FindLog(sim.get_context()).data()
        readings.append(data)
    # Sphere of 119 mm at 0.1 m: |B| = k m / D^3 = 0.139 T > 50 mT range, so x saturates.
    np.testing.assert_allclose(readings[0][0], -0.05)
    # y and z see only noise (true field zero): std within 15 % of 20 uT over ~200 samples,
    # the same for the same seed and different for another.
    y = np.unique(readings[0][1])
    assert 150 <= len(y) <= 202
    assert np.std(y) == pytest.approx(20e-6, rel=0.15)
    np.testing.assert_array_equal(readings[0], readings[1])
    assert not np.array_equal(readings[0][1], readings[2][1])


def test_estimator_ports_and_output_by_hand():
    unit = MagnetUnitConfig(p_WM=[0.0, 0.0, 0.0])
    assert unit.sensor_distance == 0.1
    est = DipoleDirectionEstimator(unit)
    assert est.get_name() == "right_unit.estimator"
    assert [est.get_input_port(0).get_name(), est.get_output_port(0).get_name()] == ["B_sensor_T", "m_hat_W"]
    ctx = est.CreateDefaultContext()
    # On-axis field (0, 0, b) with the sensor below: M^-1 = diag(-1, -1, 1/2) -> m along +z.
    # A field (b, 0, b): M^-1 B = (-b, 0, b/2) -> direction (-2, 0, 1)/sqrt(5).
    est.get_input_port(0).FixValue(ctx, [0.01, 0.0, 0.01])
    np.testing.assert_allclose(est.get_output_port(0).Eval(ctx), np.array([-2.0, 0.0, 1.0]) / np.sqrt(5), atol=1e-15)
    est.get_input_port(0).FixValue(ctx, np.zeros(3))
    np.testing.assert_array_equal(est.get_output_port(0).Eval(ctx), np.zeros(3))
