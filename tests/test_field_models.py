"""Exact (magpylib) vs point-dipole field of the prototype cylinder, and the exact model itself."""

import json
import math

import magpylib as magpy
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ballchain.cli import main as cli_main
from ballchain.drake_models.dipole import K_DIPOLE
from ballchain.experiments.field_models import (
    compare_field_models,
    on_axis_relative_error_coefficient,
)
from ballchain.drake_models.field_sources import MagnetSource
from ballchain.drake_models.params import CylinderMagnet

MAGNET = CylinderMagnet()
ROT = Rotation.from_euler("zyx", [35.0, -60.0, 20.0], degrees=True)
P_WM = np.array([0.10, -0.05, 0.20])


def _random_outside_points(n, rng, r_min=0.06, r_max=0.30):
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    radii = rng.uniform(r_min, r_max, size=(n, 1))  # r_min > bounding radius 42.6 mm
    return directions * radii


def _rotated_sources():
    exact = MagnetSource(MAGNET, P_WM, ROT.as_matrix(), model="exact")
    magpy_cyl = magpy.magnet.Cylinder(
        position=P_WM,
        orientation=ROT,
        dimension=(MAGNET.diameter, MAGNET.length),
        polarization=(0.0, 0.0, MAGNET.remanence),
    )
    return exact, magpy_cyl


def test_exact_model_matches_magpylib_object_api_rotated_and_translated():
    rng = np.random.default_rng(3)
    exact, magpy_cyl = _rotated_sources()
    p_W = P_WM + _random_outside_points(40, rng)
    np.testing.assert_allclose(exact.field(p_W), magpy_cyl.getB(p_W), rtol=1e-10, atol=1e-15)
    B, _ = exact.field_and_gradient(p_W)
    np.testing.assert_allclose(B, magpy_cyl.getB(p_W), rtol=1e-10, atol=1e-15)
    # The dipole is along the magnet's z axis, in world.
    np.testing.assert_allclose(exact.m_W / MAGNET.dipole_moment, ROT.as_matrix()[:, 2], atol=1e-15)


def test_exact_gradient_matches_fine_central_difference_and_is_symmetric_traceless():
    rng = np.random.default_rng(4)
    exact, magpy_cyl = _rotated_sources()
    p_W = P_WM + _random_outside_points(20, rng)
    _, G = exact.field_and_gradient(p_W)
    h = 1e-6  # finer than the model's 1e-5 step; through magpylib's object API, in world
    fd = np.stack(
        [(magpy_cyl.getB(p_W + h * e) - magpy_cyl.getB(p_W - h * e)) / (2 * h) for e in np.eye(3)], axis=-1
    )
    scale = np.abs(G).max(axis=(1, 2), keepdims=True)
    # Observed: about 3e-8 (the model's own truncation error (h/r)^2); a frame error would be O(1).
    assert np.all(np.abs(G - fd) <= 1e-6 * scale)
    assert np.all(np.abs(G - np.swapaxes(G, 1, 2)) <= 1e-6 * scale)
    assert np.all(np.abs(np.trace(G, axis1=1, axis2=2)) <= 1e-6 * scale[:, 0, 0])


def test_on_axis_exact_field_against_closed_form():
    # B_z(z) = (Br/2) [(z+l)/sqrt((z+l)^2+R^2) - (z-l)/sqrt((z-l)^2+R^2)], l = L/2.
    R, l, Br = MAGNET.diameter / 2, MAGNET.length / 2, MAGNET.remanence
    rows = compare_field_models(distances=[0.08, 0.12, 0.1651, 0.20], polar_angles_deg=[0.0])
    for row in rows:
        z = row.distance
        bz = Br / 2 * ((z + l) / math.hypot(z + l, R) - (z - l) / math.hypot(z - l, R))
        np.testing.assert_allclose(row.B_exact, [0.0, 0.0, bz], rtol=1e-10, atol=1e-15)
        np.testing.assert_allclose(row.B_dipole, [0, 0, 2 * K_DIPOLE * MAGNET.dipole_moment / z**3], rtol=1e-12)


def test_comparison_table_at_the_working_distances():
    rows = compare_field_models()
    assert [(r.distance, r.direction) for r in rows[:3]] == [(0.08, "axis"), (0.08, "45deg"), (0.08, "equator")]
    by = {(round(r.distance, 4), r.direction): r for r in rows}
    for r in rows:
        print(
            f"{r.distance * 100:6.2f} cm {r.direction:>7}: |B| {r.B_rel_error * 100:+6.2f} % "
            f"{r.B_angle_error_deg:5.2f} deg, |F| {r.F_rel_error * 100:+6.2f} % {r.F_angle_error_deg:5.2f} deg"
        )
        if r.direction in ("axis", "equator"):  # symmetry: both fields along the axis
            assert r.B_angle_error_deg < 1e-9 and r.F_angle_error_deg < 1e-6
    # The dipole overestimates on the axis and underestimates on the equator (L/D = 1/2 < sqrt(3)/2).
    for d in (0.08, 0.12, 0.1651, 0.2):
        assert by[(d, "axis")].B_rel_error > 0 > by[(d, "equator")].B_rel_error
    # Errors fall with distance in every direction.
    for direction in ("axis", "45deg", "equator"):
        errs = [abs(by[(d, direction)].B_rel_error) for d in (0.08, 0.12, 0.1651, 0.2)]
        angs = [by[(d, direction)].B_angle_error_deg for d in (0.08, 0.12, 0.1651, 0.2)]
        assert errs == sorted(errs, reverse=True)
        if direction == "45deg":
            assert angs == sorted(angs, reverse=True) and angs[-1] > 0.5
    # At the prototype's working distance the dipole is 5.5 % high on the axis (hand-checked
    # from the closed form above: 8.848 vs 8.383 mT) and the aligned-ball force 9.5 % high.
    assert by[(0.1651, "axis")].B_rel_error == pytest.approx(0.0555, abs=5e-4)
    assert by[(0.1651, "axis")].F_rel_error == pytest.approx(0.0955, abs=5e-4)


def test_dipole_and_exact_converge_like_inverse_square():
    distances = [0.4, 0.8, 1.6]
    rows = compare_field_models(distances=distances, polar_angles_deg=[0.0, 45.0, 90.0])
    table = {(r.distance, r.direction): r for r in rows}
    for direction, attr in [
        ("axis", "B_rel_error"),
        ("equator", "B_rel_error"),
        ("axis", "F_rel_error"),
        ("equator", "F_rel_error"),
        ("45deg", "B_angle_error_deg"),
        ("45deg", "F_angle_error_deg"),
    ]:
        e = [abs(getattr(table[(d, direction)], attr)) for d in distances]
        ratios = [e[0] / e[1], e[1] / e[2]]
        # (a/r)^2: doubling r quarters the error (1/r would give 2, 1/r^3 would give 8).
        assert all(3.8 < q < 4.2 for q in ratios), (direction, attr, ratios)
    # On the axis the leading coefficient is 1.5 R^2 - L^2/2 (expansion of the closed form).
    c = on_axis_relative_error_coefficient(MAGNET)
    # R = L = 38.1 mm for the prototype: c = 1.5 R^2 - R^2 / 2 = (38.1 mm)^2.
    assert c == pytest.approx(0.0381**2, rel=1e-12)
    assert table[(1.6, "axis")].B_rel_error * 1.6**2 == pytest.approx(c, rel=2e-3)


@pytest.mark.parametrize("model", ["dipole", "exact"])
def test_points_inside_the_magnet_raise(model):
    source = MagnetSource(MAGNET, P_WM, ROT.as_matrix(), model=model)
    inside_M = np.array([0.03, 0.0, 0.015])  # radial 30 < 38.1 mm, |z| 15 < 19.05 mm
    p_W = P_WM + ROT.as_matrix() @ inside_M
    with pytest.raises(ValueError, match="inside the CylinderMagnet"):
        source.field(np.array([P_WM + [0.2, 0, 0], p_W]))
    with pytest.raises(ValueError, match="inside the CylinderMagnet"):
        source.field_and_gradient(p_W)


def test_comparison_rejects_inside_and_bad_inputs():
    with pytest.raises(ValueError, match="inside the CylinderMagnet"):
        compare_field_models(distances=[0.015])  # on the axis inside the 38.1 mm length
    with pytest.raises(ValueError, match="positive finite"):
        compare_field_models(distances=[float("nan")])
    with pytest.raises(ValueError, match=r"\[0, 180\]"):
        compare_field_models(polar_angles_deg=[200.0])


# ----------------------------------------------------------------------------------------- CLI


def test_cli_json(capsys):
    assert cli_main(["field-models", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["rows"]) == 12
    assert {r["direction"] for r in out["rows"]} == {"axis", "45deg", "equator"}
    assert sorted({r["distance_cm"] for r in out["rows"]}) == pytest.approx([8.0, 12.0, 16.51, 20.0])
    row = next(r for r in out["rows"] if r["distance_cm"] == pytest.approx(16.51) and r["direction"] == "axis")
    assert row["B_exact_magnitude_mT"] == pytest.approx(8.383, abs=1e-3)
    assert row["B_dipole_magnitude_mT"] == pytest.approx(8.848, abs=1e-3)
    assert row["B_rel_error_percent"] == pytest.approx(5.55, abs=0.05)
    assert out["magnet"]["dipole_moment_Am2"] == pytest.approx(199.1, abs=0.1)


def test_cli_table(capsys):
    assert cli_main(["field-models", "--distances-cm", "16.51", "--angles-deg", "45"]) == 0
    text = capsys.readouterr().out
    assert "45deg" in text and "16.51" in text


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--distances-cm", "1"], "inside the CylinderMagnet"),
        (["--distances-cm", "nan"], "--distances-cm"),
        (["--distances-cm", "-5"], "--distances-cm"),
        (["--angles-deg", "181"], "--angles-deg"),
        (["--ball-diameter-mm", "0"], "--ball-diameter-mm"),
    ],
)
def test_cli_bad_input_exits_2(capsys, flags, message):
    rc = cli_main(["field-models", "--json", *flags])
    captured = capsys.readouterr()
    assert rc == 2
    assert captured.out == ""
    assert message in captured.err and "Traceback" not in captured.err
    assert captured.err.count("\n") == 1
