"""The paper's experiments: set-up cross-checks and short runs of workspace and model validation."""

import json

import numpy as np
import pytest

from ballchain.cli import main
from ballchain.experiments import model_validation, workspace
from ballchain.experiments.magnet_poses import (
    field_angle_for_magnet_angle,
    magnet_angle_for_field_angle,
    side_magnet_for_field,
)


@pytest.mark.parametrize("theta_deg", [0.0, 45.0, 90.0, 135.0, 180.0, -60.0])
def test_side_magnet_makes_the_wanted_field_at_the_base(theta_deg):
    theta = np.radians(theta_deg)
    source = side_magnet_for_field(theta, 0.023)
    B = source.field([[0.0, 0.0, 0.0]])[0]
    np.testing.assert_allclose(B, 0.023 * np.array([np.cos(theta), np.sin(theta), 0.0]), atol=1e-12)
    np.testing.assert_allclose(field_angle_for_magnet_angle(magnet_angle_for_field_angle(theta)),
                               np.arctan2(np.sin(theta), np.cos(theta)), atol=1e-12)


def test_polygon_area_by_hand():
    square = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], dtype=float)
    assert workspace.polygon_area(square) == pytest.approx(4.0, rel=1e-15)
    t = np.linspace(0, 2 * np.pi, 2001)[:-1]
    circle = np.column_stack([np.cos(t), np.sin(t)])
    assert workspace.polygon_area(circle) == pytest.approx(np.pi, rel=1e-5)


def test_workspace_short_run_sleeve_shrinks_it():
    data = workspace.run(balls=(6, 9), step_deg=15.0, progress=False)
    rows = {(r["n_balls"], r["sleeve"]): r for r in data.rows}
    for n in (6, 9):
        assert 0.0 < rows[(n, True)]["half_area_mm2"] < rows[(n, False)]["half_area_mm2"]
    assert rows[(9, False)]["half_area_mm2"] > rows[(6, False)]["half_area_mm2"]
    # Every tip stays on the chain's reach: |tip| <= (n - 1) d.
    for (n, sleeve, side), tips in data.curves.items():
        assert np.all(np.linalg.norm(tips, axis=1) <= (n - 1) * 3.175 + 1e-9)


def test_model_validation_short_run():
    data = model_validation.run(balls=(6,), angles_deg=(0.0, 90.0), progress=False)
    assert {(r["model"], r["field_angle_deg"]) for r in data.rows} == {
        (m, a) for m in ("uniform", "dipole", "exact") for a in (0.0, 90.0)
    }
    uniform0 = [r for r in data.rows if r["model"] == "uniform" and r["field_angle_deg"] == 0.0][0]
    assert uniform0["tip_angle_deg"] == pytest.approx(0.0, abs=1e-9)  # straight chain, aligned field
    for d in data.differences:
        # Dipole and exact cylinder differ by a few per cent at 10 cm: a few degrees at most.
        assert 0.0 <= d["dipole_vs_exact_angle_deg"] < 5.0
        assert d["dipole_vs_exact_tip_mm"] < 2.0


def test_workspace_command_json_and_bad_input(capsys, tmp_path):
    assert main(["workspace", "--step-deg", "30", "--out", str(tmp_path), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert {"half_area_bare_mm2", "half_area_sleeve_mm2", "reduction_pct", "tip_to_tip_max_mm"} <= set(data["summary"])
    assert (tmp_path / "workspace.png").stat().st_size > 0
    assert main(["workspace", "--distance-cm", "5"]) == 2
    assert "--distance-cm" in capsys.readouterr().err
