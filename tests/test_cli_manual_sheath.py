"""``ballchain teleop --device steerable_catheter --sheath ... --wall-stiffness ...`` (issue 45, H12):
thin adapters to ``manual_catheter.run(sheath=..., catheter=SteerableCatheter(wall_stiffness=...))``."""

import json

import pytest

from ballchain.cli import main
from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.experiments import manual_catheter as mc

TIMING = ("wall_time_s", "build_time_s", "realtime_factor", "realtime_factor_cpu", "cpu_time_s")


def _cli(capsys, *argv):
    code = main(["teleop", "--device", "steerable_catheter", "--task", "right", "--targets", "1", *argv, "--json"])
    out = capsys.readouterr().out
    assert code == 0
    return json.loads(out)


def _untimed(data: dict) -> dict:
    data = json.loads(json.dumps(data))
    for key in TIMING:
        data["summary"].pop(key, None)
    return data


def test_sheath_and_wall_stiffness_flags_reach_the_run(capsys):
    """The flags give the run ``manual_catheter.run`` gives with the same sheath and catheter (the
    same JSON apart from timing), and the JSON says which sheath and wall it had."""
    data = _cli(capsys, "--sheath", "steerable", "--wall-stiffness", "0.14")
    assert data["settings"]["sheath"].startswith("steerable")
    assert data["settings"]["wall_stiffness_N_per_m"] == pytest.approx(140.0, rel=1e-12)
    assert data["settings"]["peak_wall_force_N"] >= 0.0
    direct = mc.run(task="right", targets=1, sheath="steerable",
                    catheter=SteerableCatheter(wall_stiffness=140.0).validate())
    from ballchain.commands._common import print_json

    print_json(direct)
    assert _untimed(data) == _untimed(json.loads(capsys.readouterr().out))


def test_the_defaults_are_the_comparison_s_manual_arm_and_zero_is_the_rigid_wall(capsys):
    """No flags: the steerable sheath on the 0.14 N/mm wall (``manual_catheter.MANUAL_SHEATH``,
    ``MANUAL_WALL_STIFFNESS``), the same run as with those flags; ``--sheath fixed --wall-stiffness
    0``: the fixed sheath on the rigid wall (no wall figures in the JSON)."""
    data = _cli(capsys)
    assert data["settings"]["sheath"].startswith("steerable") and mc.MANUAL_SHEATH == "steerable"
    assert data["settings"]["wall_stiffness_N_per_m"] == mc.MANUAL_WALL_STIFFNESS == 140.0
    flags = _cli(capsys, "--sheath", "steerable", "--wall-stiffness", "0.14")
    assert _untimed(flags) == _untimed(data)
    fixed = _cli(capsys, "--sheath", "fixed", "--wall-stiffness", "0")
    assert fixed["settings"]["sheath"].startswith("fixed") and "wall_stiffness_N_per_m" not in fixed["settings"]


@pytest.mark.parametrize("argv,flag", [
    (["--device", "steerable_catheter", "--sheath", "bent"], "--sheath"),
    (["--device", "steerable_catheter", "--wall-stiffness", "-0.1"], "--wall-stiffness"),
    (["--device", "steerable_catheter", "--wall-stiffness", "2000"], "--wall-stiffness"),
    (["--device", "steerable_catheter", "--wall-stiffness", "nan"], "--wall-stiffness"),
    (["--sheath", "steerable"], "--sheath"),
    (["--wall-stiffness", "0.14"], "--wall-stiffness"),
])
def test_bad_sheath_flags_are_one_line_naming_the_flag(capsys, argv, flag):
    try:
        code = main(["teleop", *argv])
    except SystemExit as exc:  # argparse's own check (a number)
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and flag in err and "\n" not in err.strip()
