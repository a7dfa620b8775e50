"""Bad input is answered at once: exit status 2, one line on stderr naming the field, no traceback.

Table-driven: every subcommand's flags, the scenario YAML of ``--set``, user atrium
meshes and the Python API. The CLI runs in-process (``ballchain.cli.main``) so the table is fast;
a few cases go through a subprocess to check what a shell user sees. Each case must answer
before any long work: the time bound is a hang guard (generous for a loaded machine), not a
speed claim.
"""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

from ballchain.cli import main
from ballchain.infrastructure.errors import UserInputError

HANG_GUARD_S = 30.0  # a case that reaches the long work (or hangs) takes minutes


@pytest.fixture(scope="module")
def paths(tmp_path_factory):
    """A regular file (not a folder), a folder (not a file) and a closed user atrium (STL, m)."""
    from ballchain.drake_models import mesh_tools as mt
    from ballchain.drake_models.atrium_mesh import write_stl_ascii

    root = tmp_path_factory.mktemp("bad_input")
    a_file = root / "a_file.txt"
    a_file.write_text("not a folder\n")
    a_folder = root / "a_folder"
    a_folder.mkdir()
    V, F = mt.icosphere(2)
    atrium = write_stl_ascii(root / "atrium.stl", 0.025 * V, F)  # a 50 mm sphere, in metres
    garbage = root / "garbage.stl"
    garbage.write_bytes(b"\x00\x01 not a mesh at all")
    # Closed and consistently oriented, but 4 triangles (over 1 %) have zero area (a corner on
    # the opposite edge): the wall grown from them has flat tetrahedra that Drake cannot use
    # (fewer are left out of the wall).
    V2, F2 = V.copy(), F.copy()
    for k in (0, 80, 160, 240):  # faces sharing no edge
        a, b, c = F[k]
        m = len(V2)
        V2 = np.vstack([V2, 0.5 * (V[a] + V[b])])
        F2 = np.vstack([F2, [[a, m, c], [m, b, c], [a, b, m]]])
    F2 = np.delete(F2, [0, 80, 160, 240], axis=0)
    sliver = mt.write_obj(root / "sliver.obj", 0.025 * V2, F2)
    return {"file": str(a_file), "folder": str(a_folder), "atrium": str(atrium), "garbage": str(garbage),
            "sliver": str(sliver), "under_file": str(a_file / "x.html")}


SIM = ["simulate", "--scenario", "free_space_uniform_90deg"]

# (case id, argv with {file}/{folder}/{atrium}/{garbage}/{under_file} placeholders, text the
# one-line message must contain: the flag or field)
CASES = [
    # statics
    ("statics-balls-1000", ["statics", "--balls", "1000"], "--balls"),
    ("statics-balls-text", ["statics", "--balls", "ten"], "--balls"),
    ("statics-step-1e-12", ["statics", "--step-deg", "1e-12"], "--step-deg"),
    ("statics-step-1e-4", ["statics", "--step-deg", "1e-4"], "--step-deg"),
    ("statics-field-nan", ["statics", "--field-mT", "nan"], "--field-mT"),
    ("statics-method", ["statics", "--method", "lbfgs"], "--method"),
    # ablation
    ("ablation-power-negative", ["ablation", "--ball-power-W", "-5"], "--ball-power-W"),
    ("ablation-duration-nan", ["ablation", "--duration-s", "nan"], "--duration-s"),
    ("ablation-indentation-5mm", ["ablation", "--indentation-mm", "5"], "--indentation-mm"),
    ("ablation-tissue", ["ablation", "--tissue", "bone"], "--tissue"),
    ("ablation-mesh-0", ["ablation", "--mesh-mm", "0"], "--mesh-mm"),
    ("ablation-out-is-file", ["ablation", "--out", "{file}"], "--out"),
    # clinical
    ("clinical-friction-nan", ["clinical", "--friction", "nan"], "--friction"),
    ("clinical-max-diameter-negative", ["clinical", "--max-diameter-mm", "-5"], "--max-diameter-mm"),
    ("clinical-reference", ["clinical", "--reference", "middle"], "--reference"),
    ("clinical-chains", ["clinical", "--chains", "9Fr"], "--chains"),
    ("clinical-surface-huge", ["clinical", "--heart-to-surface-cm", "1e300"],
     "--heart-to-surface-cm must be a number in (0, 100] cm"),
    ("clinical-friction-huge", ["clinical", "--friction", "1e300"], "--friction must be a number in [0, 10]"),
    ("clinical-max-diameter-huge", ["clinical", "--max-diameter-mm", "1e300"], "--max-diameter-mm"),
    # the sizing's fourth powers overflowed on a tiny force; a tiny ball gave NaN forces
    ("sizing-desired-force-tiny", ["sizing", "--desired-force-gf", "1e-300"],
     "--desired-force-gf must be in [0.000102, 1.02e+05] gf"),
    ("sizing-alpha-huge", ["sizing", "--alpha", "1e6"], "--alpha must be in [1e-06, 100]"),
    ("field-models-tiny-ball", ["field-models", "--ball-diameter-mm", "1e-300"], "--ball-diameter-mm must be in [0.1, 50]"),
    ("clinical-out-is-file", ["clinical", "--out", "{file}"], "--out"),
    # alignment
    ("alignment-out-under-file", ["alignment", "--out", "{under_file}"], "--out"),
    ("alignment-out-is-file", ["alignment", "--out", "{file}"], "--out"),
    ("alignment-max-balls", ["alignment", "--max-balls", "500"], "--max-balls"),
    ("alignment-step-0", ["alignment", "--step-deg", "0"], "--step-deg"),
    # forces
    ("forces-grid-1", ["forces", "--grid", "1"], "--grid"),
    ("forces-refine-0", ["forces", "--refine", "0"], "--refine"),
    ("forces-out-is-file", ["forces", "--veins", "RSPV", "--out", "{file}"], "--out"),
    ("forces-vein", ["forces", "--veins", "SVC"], "--veins"),
    # plan
    ("plan-friction-nan", ["plan", "--friction", "nan"], "--friction"),
    ("plan-min-force-negative", ["plan", "--min-force", "-1"], "--min-force"),
    ("plan-balls-1", ["plan", "--balls", "1"], "--balls"),
    ("procedure-latency-off-grid", ["procedure", "--latency", "0.03"], "latency"),
    ("procedure-world", ["procedure", "--world", "lab"], "--world"),
    ("sensitivity-seeds", ["sensitivity", "--seeds", "0"], "--seeds"),
    ("trials-seeds", ["trials", "--out", "{folder}", "--seeds", "0"], "--seeds"),
    # workspace, validation, field models, sizing, bench, wheels, reconfigure
    ("workspace-step", ["workspace", "--step-deg", "0.01"], "--step-deg"),
    ("workspace-distance", ["workspace", "--distance-cm", "5"], "--distance-cm"),
    ("workspace-out-is-file", ["workspace", "--out", "{file}"], "--out"),
    ("validation-field-0", ["validation", "--field-mT", "0"], "--field-mT"),
    ("validation-out-under-file", ["validation", "--out", "{under_file}"], "--out"),
    ("field-models-angle", ["field-models", "--angles-deg", "200"], "--angles-deg"),
    ("sizing-alpha-nan", ["sizing", "--alpha", "nan"], "--alpha"),
    ("sizing-alpha-overflows", ["sizing", "--alpha", "1e300"], "--alpha"),
    ("field-models-ball-1-km", ["field-models", "--ball-diameter-mm", "1e9"], "--ball-diameter-mm"),
    ("wheels-seed-negative", ["wheels", "--seed", "-1"], "--seed"),
    ("bench-balls-1", ["bench", "statics", "--balls", "1"], "--balls"),
    ("wheels-samples-0", ["wheels", "--samples", "0"], "--samples"),
    ("reconfigure-slip-1", ["reconfigure", "--slip", "1"], "--slip"),
    ("reconfigure-t-max", ["reconfigure", "--t-max", "1e9"], "--t-max"),
    ("wheels-samples-1e12", ["wheels", "--samples", "1000000000000"], "--samples"),
    ("bench-repeats", ["bench", "statics", "--repeats", "100000"], "--repeats"),
    # simulate: flags
    ("simulate-unknown-scenario", ["simulate", "--scenario", "no_such"], "scenario"),
    ("simulate-duration-0", SIM + ["--duration", "0"], "--duration"),
    ("simulate-duration-1e6", SIM + ["--duration", "1e6"], "--duration"),
    ("simulate-mode", SIM + ["--mode", "sideways"], "--mode"),
    ("simulate-html-folder", SIM + ["--html", "{folder}"], "--html"),
    ("simulate-html-under-file", SIM + ["--html", "{under_file}"], "--html"),
    # simulate: the scenario YAML (--set)
    ("set-parse-error", SIM + ["--set", "{n_balls: 10"], "--set"),
    ("set-not-a-mapping", SIM + ["--set", "[1, 2]"], "--set"),
    ("set-unknown-field", SIM + ["--set", "{bogus: 1}"], "bogus"),
    ("set-scalar-for-list", SIM + ["--set", "{uniform_field: 0.02}"], "uniform_field"),
    ("set-scalar-for-mapping", SIM + ["--set", "{insertion: 5}"], "insertion"),
    ("set-text-for-int", SIM + ["--set", "{n_balls: ten}"], "n_balls"),
    ("set-n-balls-1000", SIM + ["--set", "{n_balls: 1000}"], "n_balls"),
    ("set-time-step-1e-9", SIM + ["--set", "{time_step: 1.0e-9}"], "time_step"),
    ("set-time-step-nan", SIM + ["--set", "{time_step: .nan}"], "time_step"),
    ("set-duration-nan", SIM + ["--set", "{duration: .nan}"], "duration"),
    ("set-negative-damping", SIM + ["--set", "{translational_damping: -1.0}"], "translational_damping"),
    ("set-negative-speed", SIM + ["--set", "{insertion: {speed: -0.01}}"], "insertion.speed"),
    ("set-field-in-mT", SIM + ["--set", "{uniform_field: [0, 23, 0]}"], "uniform_field"),
    ("set-nan-joystick", ["simulate", "--scenario", "teleop_right_unit", "--set",
                          "{units: [{joystick: [{time: 0.0, axes: [.nan, 0, 0]}]}]}"], "axes"),
    ("set-friction-negative", SIM + ["--set", "{contact: {friction: -0.1}}"], "contact.friction"),
    # simulate: Drake's config structs in the scenario, the pin, the slide (systems/station.py)
    ("set-plant-config-time-step", SIM + ["--set", "{plant_config: {time_step: 0.001}}"], "plant_config.time_step"),
    ("set-plant-config-unknown", SIM + ["--set", "{plant_config: {bogus: 1}}"], "bogus"),
    ("set-plant-config-scalar", SIM + ["--set", "{plant_config: 5}"], "plant_config"),
    ("set-plant-config-contact-model", SIM + ["--set", "{plant_config: {contact_model: soft}}"],
     "plant_config.contact_model"),
    ("set-plant-config-threshold-negative", SIM + ["--set", "{plant_config: {sap_near_rigid_threshold: -1.0}}"],
     "plant_config.sap_near_rigid_threshold"),
    ("set-simulator-config-unknown", SIM + ["--set", "{simulator_config: {bogus: 1}}"], "bogus"),
    ("set-simulator-config-scheme", SIM + ["--set", "{simulator_config: {integration_scheme: euler2}}"],
     "simulator_config.integration_scheme"),
    ("set-simulator-config-start-time", SIM + ["--set", "{simulator_config: {start_time: 1.0}}"],
     "simulator_config.start_time"),
    ("set-simulator-config-rate-negative", SIM + ["--set", "{simulator_config: {target_realtime_rate: -1.0}}"],
     "simulator_config.target_realtime_rate"),
    ("set-visualization-unknown", SIM + ["--set", "{visualization: {bogus: 1}}"], "bogus"),
    ("set-visualization-period-0", SIM + ["--set", "{visualization: {publish_period: 0.0}}"],
     "visualization.publish_period"),
    ("set-visualization-contacts", SIM + ["--set", "{visualization: {publish_contacts: true}}"],
     "visualization.publish_contacts"),
    ("set-publish-period-moved", SIM + ["--set", "{publish_period: 0.1}"], "publish_period"),
    ("set-pin-point-2", SIM + ["--set", "{pin: {point: [0.01, 0.0]}}"], "pin.point"),
    ("set-pin-unstable", SIM + ["--set", "{pin: {point: [0.05, 0.0, 0.0], stiffness: 1.0e+5}}"], "pin.stiffness"),
    ("set-pin-statics", SIM + ["--set", "{engine: statics, pin: {point: [0.05, 0.0, 0.0]}}"], "pin"),
    ("set-plant-config-with-statics", SIM + ["--set", "{engine: statics, plant_config: {contact_model: point}}"],
     "plant_config"),
    ("set-slide-gains-with-statics", SIM + ["--set", "{engine: statics, insertion: {slide_gains: [1.0e+5, 20.0]}}"],
     "insertion.slide_gains"),
    ("set-slide-gains-negative", SIM + ["--set", "{insertion: {slide_gains: [-1.0, 20.0]}}"],
     "insertion.slide_gains"),
    # simulate: user atrium meshes
    ("atrium-is-folder", ["simulate", "--scenario", "heart_no_field", "--set",
                          "{atrium_file: '{folder}', puncture: [0.025, 0, 0]}"], "atrium_file"),
    ("atrium-unknown-package", ["simulate", "--scenario", "heart_no_field", "--set",
                                "{atrium_file: 'package://no_such_pkg/la.stl', puncture: [0.025, 0, 0]}"],
     "atrium_file"),
    ("atrium-garbage", ["simulate", "--scenario", "heart_no_field", "--set",
                        "{atrium_file: '{garbage}', puncture: [0.025, 0, 0]}"], "atrium_file"),
    ("atrium-puncture-in-mm", ["simulate", "--scenario", "heart_no_field", "--set",
                               "{atrium_file: '{atrium}', atrium_units: m, puncture: [27.0, 0, 0]}"], "puncture"),
    ("atrium-flat-wall-tetrahedron", ["simulate", "--scenario", "heart_no_field", "--set",
                                      "{atrium_file: '{sliver}', atrium_units: m, puncture: [0.025, 0, 0]}"],
     "atrium_file"),
    ("atrium-puncture-off-surface", ["simulate", "--scenario", "heart_no_field", "--set",
                                     "{atrium_file: '{atrium}', atrium_units: m, puncture: [0.04, 0, 0]}"],
     "mm from the atrium surface"),
    ("atrium-puncture-nan", ["simulate", "--scenario", "heart_no_field", "--set",
                             "{atrium_file: '{atrium}', puncture: [.nan, 0, 0]}"], "puncture"),
    # teleop
    ("teleop-set-scalar", ["teleop", "--set", "{insertion: 5}"], "insertion"),
    ("teleop-set-parse", ["teleop", "--set", "{x"], "--set"),
    ("teleop-html-under-file", ["teleop", "--html", "{under_file}"], "--html"),
    ("teleop-targets-0", ["teleop", "--targets", "0"], "targets"),
    ("teleop-task", ["teleop", "--task", "up"], "task"),
    ("teleop-time-limit-nan", ["teleop", "--time-limit", "nan"], "--time-limit"),
    # reproduce
    ("reproduce-out-is-file", ["reproduce", "--quick", "--out", "{file}"], "--out"),
    # sweep (refused before any cluster starts)
    ("sweep-unknown-study", ["sweep", "nosuchstudy", "--out", "{folder}"], "nosuchstudy"),
    ("sweep-workers-negative", ["sweep", "design", "--workers", "-3", "--out", "{folder}"], "--workers"),
    ("sweep-out-is-file", ["sweep", "design", "--out", "{file}"], "--out"),
    ("reproduce-workers-0", ["reproduce", "--quick", "--out", "{folder}", "--workers", "0"], "--workers"),
    ("reproduce-unknown-section", ["reproduce", "--quick", "--out", "{folder}", "--sections", "nope"], "--sections"),
    # an empty name is the current folder to pathlib: refused, not written into
    ("forces-out-empty", ["forces", "--out", ""], "--out: must be a file or folder name, got ''"),
    ("workspace-out-empty", ["workspace", "--out", ""], "--out"),
    ("sweep-out-empty", ["sweep", "design", "--workers", "0", "--out", ""], "--out"),
    ("reproduce-out-empty", ["reproduce", "--quick", "--out", " "], "--out"),
    ("bench-scaling-out-empty", ["bench", "scaling", "--out", ""], "--out"),
    ("teleop-html-empty", ["teleop", "--html", ""], "--html"),
    # --set twice dropped the first mapping's fields; units: [] left the operator no unit
    ("simulate-set-twice", ["simulate", "--scenario", "free_space_uniform_90deg", "--set", "{n_balls: 4}",
                            "--set", "{duration: 0.01}"], "--set given twice"),
    ("teleop-no-units", ["teleop", "--targets", "1", "--set", "{units: []}"], "--set: units is []"),
    ("procedure-no-units", ["procedure", "--targets", "1", "--set", "{units: []}"], "--set: units is []"),
    ("procedure-operator-no-units", ["procedure", "--targets", "1", "--navigator", "operator", "--set", "{units: []}"],
     "--set: units is []"),
    ("simulate-octal-is-decimal", ["simulate", "--scenario", "free_space_uniform_90deg", "--set", "{duration: 1:30}"],
     "duration must be a finite number, got '1:30'"),
]


def _fill(argv, paths):
    out = []
    for a in argv:
        for key, value in paths.items():
            a = a.replace("{" + key + "}", value)
        out.append(a)
    return out


@pytest.mark.parametrize("argv,field", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_cli_input_exits_2_with_one_line_naming_the_field(capsys, paths, argv, field):
    argv = _fill(argv, paths)
    field = _fill([field], paths)[0].rsplit("/", 1)[-1]
    start = time.monotonic()
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own checks exit from parse_args
        code = exc.code
    elapsed = time.monotonic() - start
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, err
    assert len(lines) == 1, err
    assert field in lines[0], lines[0]
    assert "Traceback" not in err
    assert elapsed < HANG_GUARD_S


def test_the_table_has_at_least_40_cases_over_every_subcommand():
    from ballchain.cli import COMMANDS

    assert len(CASES) >= 40
    covered = {c[1][0] for c in CASES}
    assert covered == set(COMMANDS), set(COMMANDS) - covered


# The Python API: the same checks raise UserInputError naming the field (before any long work).
def _api_cases():
    from ballchain.drake_models.field_sources import MagnetSource, UniformField
    from ballchain.drake_models.heart import HeartParams
    from ballchain.drake_models.params import BallChain, CylinderMagnet, Sleeve
    from ballchain.experiments import forces, planner, statics_shape, teleop, workspace
    from ballchain.optimization.statics import rotation_path
    from ballchain.systems.simulated_operator import OperatorParams
    from ballchain.systems.chain_scenario import load_scenario

    return [
        ("chain-nan-diameter", lambda: BallChain(ball_diameter=float("nan")), "ball_diameter"),
        ("chain-bool-balls", lambda: BallChain(n_balls=True), "n_balls"),
        ("sleeve-inside-balls", lambda: BallChain(sleeve=Sleeve(inner_diameter=1e-3, outer_diameter=2e-3)),
         "outer_diameter"),
        ("sleeve-nan-modulus", lambda: Sleeve(youngs_modulus=float("nan")), "youngs_modulus"),
        ("magnet-zero-direction", lambda: MagnetSource.pointing(CylinderMagnet(), [0.2, 0, 0], [0, 0, 0]),
         "direction"),
        ("uniform-field-nan", lambda: UniformField(np.array([np.nan, 0, 0])), "B_W"),
        ("rotation-path-1e-12", lambda: rotation_path(0.0, 180.0, 1e-12), "continuation step"),
        ("statics-run-step", lambda: statics_shape.run(balls=4, field_mT=23, field_angle_deg=90, step_deg=1e-6),
         "--step-deg"),
        ("forces-run-grid", lambda: forces.run(veins=("RSPV",), grid=1), "--grid"),
        ("workspace-run-nan", lambda: workspace.run(step_deg=float("nan")), "--step-deg"),
        ("planner-friction-nan", lambda: planner.run(task="right", targets=1, friction=float("nan")), "friction"),
        ("teleop-balls", lambda: teleop.check_inputs("left", "world", None, 1000, None), "balls"),
        ("heart-nan-scale", lambda: HeartParams(scale=float("nan")), "HeartParams.scale"),
        ("operator-nan-timeout", lambda: OperatorParams(timeout=float("nan")).validate(), "OperatorParams.timeout"),
        ("scenario-override", lambda: load_scenario("heart_no_field", "{magnets: [{distance_from_puncture: 165.1}]}"),
         "distance_from_puncture"),
    ]


@pytest.mark.parametrize("index", range(15))
def test_bad_api_input_raises_user_input_error_naming_the_field(index):
    name, call, field = _api_cases()[index]
    start = time.monotonic()
    with pytest.raises(UserInputError, match=field):
        call()
    assert time.monotonic() - start < HANG_GUARD_S, name


def test_numpy_scalars_are_accepted_by_the_parameters():
    from ballchain.drake_models.params import BallChain

    chain = BallChain(n_balls=np.int64(5), ball_diameter=np.float32(3.175e-3))
    assert chain.n_balls == 5 and isinstance(chain.n_balls, int)


def test_a_bug_is_a_traceback_with_exit_1_not_bad_input(monkeypatch):
    """Only UserInputError (and argparse) are the user's: a plain ValueError from a bug escapes."""
    from ballchain.experiments import wheels

    def broken(**kwargs):
        raise ValueError("a bug, not the user's input")

    monkeypatch.setattr(wheels, "run", broken)
    with pytest.raises(ValueError, match="a bug"):
        main(["wheels"])
    # Through the shell: a traceback and exit status 1.
    code = ("import sys; from ballchain.experiments import wheels; from ballchain import cli\n"
            "wheels.run = lambda **k: (_ for _ in ()).throw(ValueError('a bug'))\n"
            "sys.exit(cli.main(['wheels']))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "Traceback" in proc.stderr and "ValueError: a bug" in proc.stderr


@pytest.mark.slow  # a fresh interpreter per case
@pytest.mark.parametrize("argv,field", [
    (["statics", "--balls", "1000"], "--balls"),
    (["simulate", "--scenario", "teleop_right_unit", "--set",
      "{units: [{joystick: [{time: 0.0, axes: [.nan, 0, 0]}]}]}"], "axes"),
    (["simulate", "--scenario", "free_space_uniform_90deg", "--set", "{insertion: 5}"], "insertion"),
], ids=["statics-balls", "nan-joystick", "set-scalar"])
def test_bad_input_through_the_shell(argv, field):
    start = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "ballchain", *argv], capture_output=True, text=True, timeout=120)
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and field in lines[0], proc.stderr
    assert time.monotonic() - start < HANG_GUARD_S + 30.0  # a fresh interpreter imports pydrake


def test_every_json_is_valid_json(capsys):
    """`simulate --scenario list --json` prints JSON; non-finite numbers are written as null."""
    import json

    from ballchain.commands._common import json_text

    assert main(["simulate", "--scenario", "list", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert "free_space_uniform_90deg" in data["scenarios"]
    text = json_text({"a": float("nan"), "b": [np.float64("inf"), 1.0], "c": np.array([np.nan, 2.0])})
    assert json.loads(text) == {"a": None, "b": [None, 1.0], "c": [None, 2.0]}


def test_good_scenario_yaml_is_not_refused():
    """The checks refuse only what is wrong: exponent floats (PyYAML reads 1e-3 as text), ints
    where floats belong, an empty --set, nested partial mappings."""
    from ballchain.systems.chain_scenario import load_scenario

    s = load_scenario("free_space_uniform_90deg", "{time_step: 1e-3, duration: 2, insertion: {speed: 0.02}}")
    assert (s.time_step, s.duration, s.insertion.speed) == (1e-3, 2.0, 0.02)
    assert load_scenario("free_space_uniform_90deg", "").n_balls == load_scenario("free_space_uniform_90deg").n_balls
    s = load_scenario("teleop_right_unit", "{units: [{name: right_unit, joystick: [{time: 0.5, axes: [1, 0, -1]}]}]}")
    assert s.units[0].joystick[0].axes == [1.0, 0.0, -1.0]
