"""The procedure experiment and command: bad input before any work, a quick smoke run, and (slow)
the whole right ring with every target reached and pressed inside the force window."""

import json

import numpy as np
import pytest

from ballchain.cli import main as cli_main
from ballchain.infrastructure.errors import UserInputError
from ballchain.experiments import procedure


@pytest.mark.parametrize("argv, message", [
    (["--task", "middle"], "--task must be left or right"),
    (["--navigator", "joystick"], "invalid choice"),
    (["--latency", "0.03"], "whole number of samples"),
    (["--rate", "0"], "--rate"),
    (["--noise", "-1"], "--noise"),
    (["--force", "50"], "window"),
    (["--dwell", "nan"], "--dwell"),
])
def test_bad_flags_fail_before_any_work(argv, message, capsys):
    try:
        code = cli_main(["procedure", *argv, "--json"])
    except SystemExit as stop:  # argparse's own checks
        code = stop.code
    assert code == 2
    assert message in capsys.readouterr().err


def test_bad_arguments_name_the_argument():
    with pytest.raises(UserInputError, match="navigator"):
        procedure.run("right", navigator="robot")
    with pytest.raises(UserInputError, match="targets"):
        procedure.run("right", targets=0)
    with pytest.raises(UserInputError, match="seed"):
        procedure.run("right", seed=-1)


def test_smoke_one_target(tmp_path, capsys):
    """The command on the right ring's first target with a 1 s dwell: reached, the dwell recorded,
    the true force inside the window, its lesion, the result file and the ring map written."""
    assert cli_main(["procedure", "--task", "right", "--targets", "1", "--dwell", "1", "--json",
                     "--out", str(tmp_path)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data == json.loads((tmp_path / "procedure.json").read_text())
    (row,) = data["rows"]
    assert row["reached"] and row["dwell_s"] == pytest.approx(1.0, abs=0.051)
    assert 10.0 <= row["force_true_min_gf"] and row["force_true_max_gf"] <= 40.0
    point = row["point"]
    assert point["name"] == "right_1" and np.linalg.norm(point["n_W"]) == pytest.approx(1.0)
    assert point["force_N"] > 0 and point["duration_s"] == row["dwell_s"]
    assert data["summary"]["reached"] == 1 and data["summary"]["failure"] is None
    # Its lesion (the surrogate at the dwell's force and duration) and the one-lesion ring.
    (lesion,) = data["lesions"]
    assert lesion["name"] == "right_1" and lesion["duration_s"] == row["dwell_s"] and lesion["width_mm"] > 0
    assert lesion["power_W"] == pytest.approx(point["power_W"], abs=1e-4) and lesion["magnet_ok"]
    assert data["ring"]["order"] == ["right_1"] and (tmp_path / "ring.png").stat().st_size > 0


@pytest.mark.slow
def test_whole_right_ring_every_target_reached():
    result = procedure.run("right", progress=False)
    s = result.summary
    assert s["failure"] is None
    assert s["reached"] == s["targets"] == 18, [r["target"] for r in result.rows if not r["reached"]]
    assert s["in_window_fraction"] > 0.95


def test_operator_dwell_is_checked_and_units_two_needs_auto():
    from ballchain.systems.simulated_operator import OperatorParams

    with pytest.raises(UserInputError, match="dwell"):
        OperatorParams(dwell=-1.0).validate()
    with pytest.raises(UserInputError, match="units 'two'"):
        procedure.run("left", "operator", units="two")
    with pytest.raises(UserInputError, match="units"):
        procedure.run("left", units="three")


@pytest.mark.slow
def test_the_navigator_holds_the_force_on_a_moving_wall():
    """Respiration (5 mm, 0.25 Hz) and the heart beat (1 mm, 1.2 Hz) at their defaults, on the
    quasi-static engine: the first three right-ring targets reached and every dwell sample inside
    the 10-40 gf window. The estimator's model knows nothing of the motion (its wall is the still
    one): its worst error stays below 2.5 gf, a quarter of the 10 gf between the command (20 gf)
    and the window's floor, which is the margin the hold relies on."""
    result = procedure.run("right", targets=3, overrides="{engine: statics, wall_motion: {enabled: true}}",
                           progress=False, lesions=False)
    s = result.summary
    assert s["failure"] is None
    assert s["reached"] == s["targets"] == 3
    assert s["in_window_fraction"] == 1.0
    assert s["estimate_worst_error_gf"] < 2.5


@pytest.mark.slow
def test_a_user_anatomy_with_two_units_every_target_reached(tmp_path, capsys):
    """``procedure --anatomy FILE`` without --task takes all the file's targets in file order: a
    faceted ellipsoid (binary STL, millimetres) with four targets near the procedural left ring's
    left_1, left_6, left_11 and left_16, two magnet places (the two-unit station's): each target
    planned with both units and reached, the force held inside the window."""
    from anatomy_helpers import lumen_anatomy

    path = lumen_anatomy(tmp_path, magnets="[[-58.96, -104.82, 0.0], [104.99, -65.62, 0.0]]")
    assert cli_main(["procedure", "--anatomy", str(path), "--dwell", "1", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["task"] is None and len(data["settings"]["units"]) == 2
    assert [r["target"] for r in data["rows"]] == ["L1", "L2", "L3", "L4"]
    assert data["summary"]["not_planned"] == [] and data["summary"]["failure"] is None
    assert data["summary"]["reached"] == 4, [(r["target"], r["reason"]) for r in data["rows"]]
    assert data["summary"]["in_window_fraction"] >= 0.95
