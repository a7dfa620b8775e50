"""The core subcommands print the documented JSON and fail cleanly on bad input."""

import json

import numpy as np
import pytest

from ballchain.cli import main


def run_json(capsys, *argv):
    code = main(list(argv) + ["--json"])
    out = capsys.readouterr().out
    assert code == 0
    return json.loads(out)


def test_statics_json_has_the_documented_fields(capsys):
    data = run_json(capsys, "statics", "--balls", "5", "--field-mT", "23", "--field-angle-deg", "90")
    for key in ("positions_mm", "dipoles", "tip_angle_deg", "energy_J", "converged", "solver", "solve_time_s"):
        assert key in data
    p = np.array(data["positions_mm"])
    assert p.shape == (5, 3) and data["converged"]
    np.testing.assert_allclose(np.linalg.norm(np.diff(p, axis=0), axis=1), 3.175, rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(data["dipoles"], axis=1), 1.0, rtol=1e-12)


def test_statics_gravity_and_sleeve_flags_change_the_shape(capsys):
    plain = run_json(capsys, "statics", "--balls", "8")
    sagging = run_json(capsys, "statics", "--balls", "8", "--gravity")
    sleeved = run_json(capsys, "statics", "--balls", "8", "--sleeve")
    assert sagging["positions_mm"][-1][2] < 0.0 == plain["positions_mm"][-1][2]
    assert sleeved["positions_mm"][-1][0] > plain["positions_mm"][-1][0]


@pytest.mark.parametrize(
    "argv,message",
    [
        (["statics", "--balls", "0"], "--balls"),
        (["statics", "--balls", "-3"], "--balls"),
        (["statics", "--field-mT", "nan"], "--field-mT"),
        (["statics", "--field-mT", "-5"], "--field-mT"),
        (["statics", "--step-deg", "0"], "--step-deg"),
        (["alignment", "--max-balls", "0"], "--max-balls"),
    ],
)
def test_bad_arguments_exit_2_with_a_message_and_no_traceback(capsys, argv, message):
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own validation
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2
    assert message in err
    assert "Traceback" not in err


def test_alignment_writes_csv_and_figures(capsys, tmp_path):
    data = run_json(capsys, "alignment", "--max-balls", "4", "--step-deg", "90", "--out", str(tmp_path))
    assert {(r["n_balls"], r["field_angle_deg"]) for r in data["rows"]} == {
        (n, a) for n in range(1, 5) for a in (0.0, 90.0, 180.0)
    }
    one_ball = [r for r in data["rows"] if r["n_balls"] == 1]
    # A single ball is held by the sheath: its dipole stays along +x whatever the field.
    np.testing.assert_allclose([r["tip_angle_deg"] for r in one_ball], [0.0, 90.0, 180.0], atol=1e-9)
    for name in ("alignment.csv", "alignment.png", "alignment_shapes.png"):
        assert (tmp_path / name).stat().st_size > 0


def test_alignment_prints_a_headed_table_and_its_summary_in_words(capsys):
    from ballchain.cli import main

    assert main(["alignment", "--max-balls", "3", "--step-deg", "90", "--no-files"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("Angle between the tip's dipole and the 23 mT field [deg]")
    assert lines[1].split() == ["balls", "|", "0", "90", "180"] and lines[2].startswith("------+")
    assert [line.split()[0] for line in lines[3:6]] == ["1", "2", "3"]
    assert lines[6] == "largest tip angle of chains longer than 10 balls: - (at 180 deg: -; the paper: < 1.4 deg)"


@pytest.mark.slow
def test_reproduce_quick_writes_the_report(capsys, tmp_path):
    data = run_json(capsys, "reproduce", "--quick", "--out", str(tmp_path))
    report = (tmp_path / "report.md").read_text()
    assert "paper" in report and "119" in report
    html = (tmp_path / "report.html").read_text()
    assert html.count("data:image/png;base64") >= 2
    assert "figure missing" not in html  # every figure the report names is embedded
    assert set(data["experiments"]) == {"alignment", "sizing", "field models", "workspace", "model validation",
                                        "tip forces", "Table I effects and clinical design", "model-based steering",
                                        "teleoperation", "robotic vs manual", "ablation", "ablation procedure",
                                        "world sensitivity"}
    assert "Simulated ablation procedure" in report and "procedure_forces.png" in report
    assert "model simulation [gf]" in report and "Run time" in report
    assert "ferromagnetic pin" in report and "two N52 spheres of 119 mm" in report
    for mapping in ("world", "catheter"):  # the Meshcat replays of the teleoperation runs
        assert (tmp_path / "replays" / f"teleop_right_{mapping}.html").stat().st_size > 100_000


@pytest.mark.parametrize("command,flag", [("statics", "--balls"), ("simulate", "--scenario"), ("forces", "--veins")])
def test_subcommand_help_lists_its_arguments(capsys, command, flag):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    assert flag in capsys.readouterr().out


@pytest.mark.slow
def test_simulate_reports_the_statics_tip_error_where_the_chain_settles(capsys):
    data = run_json(capsys, "simulate", "--scenario", "free_space_wall")
    assert 0.0 < data["statics_tip_error_mm"] < 0.5  # the tip's indentation into the wall
    data = run_json(capsys, "simulate", "--scenario", "heart_no_field", "--duration", "0.005")
    assert data["statics_tip_error_mm"] is None


@pytest.mark.slow
def test_reproduce_on_two_workers_gives_the_serial_sections(tmp_path):
    """``--workers 2`` runs the sections on a Dask LocalCluster: the same data, the same report order."""
    import json

    from ballchain import reproduce

    names = ["sizing", "field models"]
    serial = reproduce.run(out=tmp_path / "serial", quick=True, sections=names)
    parallel = reproduce.run(out=tmp_path / "parallel", quick=True, sections=names, workers=2)
    assert list(parallel["experiments"]) == list(serial["experiments"]) == names
    for slug in ("sizing", "field_models"):
        a = json.loads((tmp_path / "serial" / "sections" / f"{slug}.json").read_text())
        b = json.loads((tmp_path / "parallel" / "sections" / f"{slug}.json").read_text())
        assert a == b
    md_s = (tmp_path / "serial" / "report.md").read_text().split("## Run time")[0]
    md_p = (tmp_path / "parallel" / "report.md").read_text().split("## Run time")[0]
    assert md_s == md_p
