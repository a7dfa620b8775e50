"""The procedure on a moving wall: the ``--wall-motion`` and ``--set`` flags' bad input (one line,
exit 2, before any work), the overrides checked with the engine the run uses (the quasi-static
engine the hand-over gives the teleoperation stations, not the scenario file's plant), and (slow)
a short stretch of the right ring under respiration and the heart beat through the command."""

import json

import numpy as np
import pytest

from ballchain.cli import main as cli_main
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.params import BallChain, CylinderMagnet
from ballchain.drake_models.wall_motion import WallMotion
from ballchain.experiments import procedure, teleop
from ballchain.systems.tip_force_estimator import TipForceEstimator
from ballchain.systems.chain_scenario import load_scenario, parse_overrides

MOVING = "{wall_motion: {enabled: true}}"


@pytest.mark.parametrize("argv, message", [
    (["--wall-motion", "sideways"], "argument --wall-motion: invalid choice: 'sideways'"),
    (["--wall-motion", "on", "--set", MOVING], "--wall-motion on and --set wall_motion"),
    (["--set", "{engine: plant, wall_motion: {enabled: true}}"], "wall_motion needs engine: statics"),
    (["--set", "{mode: dynamics, wall_motion: {enabled: true}}"], "mode dynamics runs only on the plant"),
    (["--set", "{wall_motion: {enabled: true, cardiac: {amplitude: 0.5}}}"], "wall_motion.cardiac.amplitude"),
    (["--set", "{wall_motion: {enable: true}}"], "enable"),
    (["--set", "[1"], "--set is not valid YAML"),
    (["--navigator", "operator", "--track-sheath"], "--track-sheath needs navigator auto"),
])
def test_bad_motion_flags_fail_in_one_line_before_any_work(argv, message, capsys, monkeypatch):
    def no_work(*args, **kwargs):
        raise AssertionError("the plan started before the flags were checked")

    monkeypatch.setattr(procedure, "target_plans", no_work)
    try:
        code = cli_main(["procedure", "--targets", "1", *argv, "--json"])
    except SystemExit as stop:  # argparse's own checks
        code = stop.code
    err = capsys.readouterr().err
    assert code == 2
    assert message in err
    assert len(err.strip().splitlines()) == 1


def test_a_bad_choice_through_the_experiment_names_the_flag():
    with pytest.raises(UserInputError, match="--wall-motion must be one of off, on, respiration, beat"):
        procedure.run("right", wall_motion="tremor")


@pytest.mark.parametrize("name", ["teleop_right_unit", "teleop_two_units"])
def test_wall_motion_is_checked_with_the_engine_of_the_hand_over(name):
    """The teleoperation scenarios' file says ``engine: plant``, on which a moving wall is refused;
    the hand-over runs them on the quasi-static engine, and the overrides are checked with it."""
    with pytest.raises(UserInputError, match="wall_motion needs engine: statics"):
        load_scenario(name, MOVING)  # the file's engine: what the check saw before the fix
    scenario = teleop.load_for_hand_over(name, MOVING)
    assert scenario.engine == teleop.DEFAULT_ENGINE == "statics"
    assert scenario.wall_motion.law() == WallMotion.default()
    with pytest.raises(UserInputError, match="got 'plant'"):
        teleop.load_for_hand_over(name, "{engine: plant, wall_motion: {enabled: true}}")


@pytest.mark.parametrize("overrides", [None, "{statics_period: 0.025}", "{mode: dynamics}", "{engine: plant}"])
def test_the_hand_over_gives_the_same_station_as_before(overrides):
    """Checking with the hand-over's engine changes no scenario: the loaded-then-handed-over
    station is the one of the file's engine loaded then handed over, field for field."""
    for name in ("teleop_right_unit", "teleop_two_units"):
        before = teleop.hand_over(load_scenario(name, overrides), "world", None, parse_overrides(overrides))
        after = teleop.hand_over(teleop.load_for_hand_over(name, overrides), "world", None,
                                 parse_overrides(overrides))
        assert repr(after) == repr(before)


def test_each_choice_moves_what_it_names():
    default = WallMotion.default()
    assert procedure.with_wall_motion("{n_balls: 10}", "off") == "{n_balls: 10}"
    assert procedure.with_wall_motion(None, "off") is None
    laws = {choice: teleop.load_for_hand_over("teleop_right_unit", procedure.with_wall_motion(
        "{statics_period: 0.025}", choice)).wall_motion.law() for choice in ("on", "respiration", "beat")}
    assert laws["on"] == default
    assert laws["respiration"].respiratory == default.respiratory and laws["respiration"].cardiac.amplitude == 0.0
    assert laws["beat"].cardiac == default.cardiac and laws["beat"].respiratory.amplitude == 0.0
    kept = teleop.load_for_hand_over("teleop_right_unit", procedure.with_wall_motion("{statics_period: 0.025}", "on"))
    assert kept.statics_period == 0.025  # the other overrides stay


def test_the_motion_is_recorded_in_results_units():
    d = WallMotion.default().to_dict()
    assert d["respiratory"] == {"amplitude_mm": 5.0, "frequency_hz": 0.25, "direction": [0.0, 0.0, 1.0]}
    assert d["cardiac"]["amplitude_mm"] == 1.0 and d["cardiac"]["frequency_hz"] == 1.2
    assert sum(x * x for x in d["cardiac"]["direction"]) == pytest.approx(1.0, abs=1e-12)


def _estimator(p_WE, p_WM) -> TipForceEstimator:
    """A force model with its sheath's exit at p_WE (along x) and one magnet at p_WM [m]."""
    return TipForceEstimator(BallChain(), p_WE, np.eye(3), [(CylinderMagnet(), p_WM)], "dipole", 16)


def test_the_tracked_sheath_moves_the_model_s_sheath_not_the_magnets():
    """The estimator given the sheath's offset h holds the tip with the sheath's exit at p_WE + h
    and the magnets where they stand (the cart does not breathe): it is the model built with its
    sheath there. Moving the magnets by h as well changes nothing (the physics is translation
    invariant), and the motion-blind model (sheath at rest) answers differently."""
    p_WE, p_WM = np.array([0.01, -0.02, 0.03]), np.array([0.03, 0.0, 0.12])
    m = np.array([[0.0, 0.2, 1.0]]) / np.hypot(0.2, 1.0)
    s = 15 * BallChain().ball_diameter
    tip = p_WE + np.array([0.036, 0.012, 0.008])  # a point the 16 free balls reach
    h = np.array([0.0, 0.0, 5e-3])  # respiration's amplitude, supero-inferior
    tracked = _estimator(p_WE, p_WM).reaction_W(tip + h, m, s, h)
    built_there = _estimator(p_WE + h, p_WM).reaction_W(tip + h, m, s)
    at_rest = _estimator(p_WE, p_WM).reaction_W(tip, m, s)
    all_moved = _estimator(p_WE + h, p_WM + h).reaction_W(tip + h, m, s)
    blind = _estimator(p_WE, p_WM).reaction_W(tip + h, m, s)
    np.testing.assert_allclose(tracked, built_there, rtol=0, atol=1e-9)  # [N]
    np.testing.assert_allclose(all_moved, at_rest, rtol=0, atol=1e-9)
    assert np.linalg.norm(blind - tracked) > 0.01 * np.linalg.norm(tracked)
    assert np.array_equal(_estimator(p_WE, p_WM).reaction_W(tip, m, s, None),
                          _estimator(p_WE, p_WM).reaction_W(tip, m, s, np.zeros(3)))


@pytest.mark.slow
@pytest.mark.parametrize("track", [[], ["--track-sheath"]], ids=["blind", "tracked"])
def test_a_stretch_of_the_right_ring_under_motion_through_the_command(track, capsys):
    """Three right-ring targets, 2 s dwells, respiration and the heart beat at their defaults,
    no ``engine: statics`` given, the navigator motion-blind or tracking the sheath: every target
    reached, every dwell sample inside the 10-40 gf window, the motion recorded, and the estimate
    within 2.5 gf (a quarter of the 10 gf margin between the command and the window's floor)."""
    code = cli_main(["procedure", "--targets", "3", "--dwell", "2", "--wall-motion", "on", *track, "--json"])
    data = json.loads(capsys.readouterr().out)
    assert code == 0
    s, settings = data["summary"], data["settings"]
    assert settings["engine"] == "statics" and settings["navigator_tracks_sheath"] == bool(track)
    assert settings["wall_motion"] == WallMotion.default().to_dict()
    assert s["failure"] is None and s["reached"] == s["targets"] == 3
    assert s["in_window_fraction"] == 1.0
    assert s["estimate_worst_error_gf"] < 2.5
    for row in data["rows"]:
        assert row["dwell_s"] >= 2.0 - 0.05
