"""``ballchain ablation`` in clinical conditions (issue 44): the flags, the JSON's delivered power and
magnet peak, the refusals naming the flag."""

import json

import pytest

from ballchain.cli import main as cli_main
from ballchain.experiments import ablation_clinical


def test_done_command_reports_each_device(capsys):
    """The issue's command (coarse mesh, short dwell): each device's lesion, its delivered power below
    the set one (a limit holds), the magnet below its N52 limit less the margin (75 C)."""
    code = cli_main(["ablation", "--catheter-power-W", "30", "--duration-s", "6", "--contact-force-gf", "20",
                     "--irrigation", "open", "--blood-flow", "high", "--bath-temperature-C", "37", "--json",
                     "--mesh-mm", "0.3", "--no-files"])
    assert code == 0
    data = json.loads(capsys.readouterr().out)
    ball, cath = data["devices"]
    assert (ball["device"], cath["device"]) == ("ball_chain", "catheter")
    for d in (ball, cath):
        c = d["clinical"]
        assert d["omega_width_mm"] > 0 and d["omega_depth_mm"] > 0
        assert c["blood_flow"] == "high" and c["contact_force_gf"] == 20.0
        assert 0 < c["delivered_power_W"] <= c["set_power_W"] + 1e-9
        assert sum(c["limit_share"].values()) == pytest.approx(1.0)
    assert cath["clinical"]["irrigation"] == "open" and ball["clinical"]["irrigation"] == "none"
    assert ball["clinical"]["magnet_peak_C"] <= 75.0 + 1e-6 and cath["clinical"]["magnet_peak_C"] is None
    # 20 gf by Hertz: the ball 1.12 mm (lesion_surrogate's docstring), the smaller dome deeper.
    assert ball["indentation_mm"] == pytest.approx(1.12, abs=0.01)
    assert cath["indentation_mm"] > ball["indentation_mm"]


@pytest.mark.parametrize("flag,value", [("--blood-flow", "fast"), ("--irrigation", "closed"),
                                        ("--control", "impedance"), ("--contact-force-gf", "500"),
                                        ("--magnet-grade", "N99")])
def test_bad_clinical_flags_are_refused_by_name(capsys, flag, value):
    assert cli_main(["ablation", flag, value, "--no-files"]) == 2
    err = capsys.readouterr().err
    assert flag in err and err.count("\n") == 1


def test_bad_target_temperature_is_refused(capsys):
    assert cli_main(["ablation", "--control", "temperature", "--target-temperature-C", "120", "--no-files"]) == 2
    assert "--target-temperature-C" in capsys.readouterr().err


def test_clinical_flags_refuse_the_bench_sweeps(capsys):
    assert cli_main(["ablation", "--blood-flow", "low", "--map", "--no-files"]) == 2
    assert "--map" in capsys.readouterr().err


def test_indentation_follows_the_force_and_stays_in_range():
    assert ablation_clinical.indentation_mm_for("ball_chain", 10.0) < ablation_clinical.indentation_mm_for(
        "ball_chain", 20.0)
    assert ablation_clinical.indentation_mm_for("catheter", 100.0) == ablation_clinical.INDENTATION_RANGE_MM[1]
