"""Scenarios and the `ballchain simulate` command: every named scenario, defaults, bad input."""

import dataclasses
import json

import numpy as np
import pytest

from ballchain.cli import main as cli_main
from ballchain.infrastructure.errors import UserInputError
from ballchain.systems.chain_scenario import ChainScenario, load_scenario, scenario_names
from ballchain.systems.chain_simulation import MakeStation, run_simulation

KEYS = {"realtime_factor", "sim_time_s", "tip_position_mm", "min_wall_clearance_mm",
        "max_neighbor_gap_um", "max_penetration_um", "targets_touched", "peak_memory_MB"}


def test_scenario_file_and_defaults():
    names = scenario_names()
    assert {"heart_left_quasi_static", "heart_right_dynamics", "free_space_uniform_90deg"} <= set(names)
    assert not any(n.startswith("_") for n in names)
    default = ChainScenario().validate()
    assert default.mode == "quasi-static" and default.effective_time_step == 1e-3
    assert default.n_balls == 16 and default.heart and default.sheath
    dyn = load_scenario("heart_right_dynamics")
    assert dyn.effective_time_step == 1e-4 and dyn.magnets[0].distance_from_puncture == 0.1651
    # Shared YAML anchors: both quasi-static heart scenarios have the same insertion ramp.
    assert load_scenario("heart_left_quasi_static").insertion == load_scenario("heart_sleeve_quasi_static").insertion
    # Inline overrides.
    s = load_scenario("heart_left_quasi_static", "{n_balls: 10, contact: {friction: 0.3}}")
    assert s.n_balls == 10 and s.contact.friction == 0.3


def test_diagram_has_named_systems(heart):
    cd = MakeStation(load_scenario("heart_left_quasi_static"), heart=heart)
    names = {s.get_name() for s in cd.diagram.GetSystems()}
    assert {"plant", "scene_graph", "magnetic_wrench", "feeder_command"} <= names
    external = MakeStation(load_scenario("heart_no_field", "{insertion: {external: true}}"), heart=heart)
    assert external.diagram.GetInputPort("inserted_length").size() == 1


@pytest.mark.parametrize("name", scenario_names())
def test_every_named_scenario_runs_briefly(name, heart):
    scenario = load_scenario(name)
    duration = 10 * scenario.effective_time_step
    result = run_simulation(scenario=scenario, duration=duration, heart=heart if scenario.heart else None)
    assert KEYS <= {f.name for f in dataclasses.fields(result)}
    assert result.sim_time_s == pytest.approx(duration)
    assert result.max_penetration_um < 20.0
    assert result.max_neighbor_gap_um < 20.0
    if scenario.heart:
        assert result.min_wall_clearance_mm > 0.0
    assert np.all(np.isfinite(result.tip_position_mm))


def test_cli_prints_json(capsys):
    code = cli_main(["simulate", "--scenario", "free_space_uniform_90deg", "--duration", "0.003",
                     "--mode", "quasi-static", "--json"])
    assert code == 0
    data = json.loads(capsys.readouterr().out)
    assert KEYS <= set(data)
    assert data["min_wall_clearance_mm"] is None  # no heart
    assert data["sim_time_s"] == pytest.approx(0.003)


def test_bad_scenarios_fail_with_clear_messages(capsys):
    assert cli_main(["simulate", "--scenario", "no_such_scenario", "--json"]) == 2
    assert "unknown scenario 'no_such_scenario'; known scenarios:" in capsys.readouterr().err
    with pytest.raises(ValueError, match="mode must be one of"):
        load_scenario("heart_no_field", "{mode: sideways}")
    with pytest.raises(ValueError, match="too large for the dynamics mode"):
        load_scenario("heart_no_field", "{mode: dynamics, time_step: 0.001}")
    with pytest.raises(ValueError, match="unknown field 'no_such_field'"):
        load_scenario("heart_no_field", "{no_such_field: 1}")
    with pytest.raises(ValueError, match="ball 1 must stay in the sheath"):
        MakeStation(load_scenario("free_space_uniform_90deg", "{insertion: {initial: 0.2}}"))


def test_a_breaking_chain_stops_with_when_and_which_ball(capsys):
    """Too little damping for a 1 ms step: the explicit magnetic forces blow the chain apart."""
    argv = ["simulate", "--scenario", "free_space_uniform_90deg", "--duration", "0.05",
            "--set", "{translational_damping: 0.1}", "--json"]
    assert cli_main(argv) == 1
    captured = capsys.readouterr()
    assert "simulation stopped:" in captured.err
    # Deterministic: the first check after the blow-up (5 ms) finds the chain broken.
    assert "the chain broke between balls 13 and 14 at t = 0.0050 s" in captured.err
    data = json.loads(captured.out)
    assert "failure" in data and data["sim_time_s"] < 0.05


def test_html_recording(tmp_path):
    html = tmp_path / "run.html"
    result = run_simulation(scenario=load_scenario("free_space_uniform_90deg", "{n_balls: 4}"),
                            duration=0.01, html=html)
    text = html.read_text()
    assert result.html == str(html)
    assert text.lstrip().lower().startswith("<!doctype html") or "<html" in text[:1000].lower()
    assert len(text) > 10_000


def test_ctrl_c_while_the_finished_runs_replay_is_written_keeps_the_replay(tmp_path, monkeypatch, capsys):
    """Ctrl-C (or a stop signal) just after the run ended, while its replay was being written:
    the replay is written all the same (the cut-short write left no file), one line says so and
    the interrupt goes on (CI once signalled a short teleoperation task just as it ended)."""
    from ballchain.systems import chain_simulation

    export, calls = chain_simulation._export_recording, []

    def interrupted_once(cd, meshcat, html):
        calls.append(html)
        if len(calls) == 1:
            raise KeyboardInterrupt  # where the signal's handler would raise it
        export(cd, meshcat, html)

    monkeypatch.setattr(chain_simulation, "_export_recording", interrupted_once)
    html = tmp_path / "run.html"
    with pytest.raises(KeyboardInterrupt):
        run_simulation(scenario=load_scenario("free_space_uniform_90deg", "{n_balls: 4}"), duration=0.01, html=html)
    assert len(calls) == 2
    assert html.read_text().rstrip().endswith("</html>")
    assert "interrupted at t = 0.0100 s; replay so far written" in capsys.readouterr().err


@pytest.mark.slow
def test_monitor_names_the_escaped_ball_and_nan(heart):
    """The watchdog on hand-made states: a ball moved outside the heart, then a NaN."""
    from pydrake.math import RigidTransform

    from ballchain.systems.chain_simulation import ChainMonitor

    cd = MakeStation(load_scenario("heart_no_field"), heart=heart)
    plant = cd.chain.plant
    context = plant.CreateDefaultContext()
    monitor = ChainMonitor(cd)
    assert monitor.check(context) is None
    ball_9 = plant.GetBodyByName("ball_9")
    plant.SetFreeBodyPose(context, ball_9, RigidTransform([0.0, 0.0, 0.06]))  # 6 cm up: outside
    message = monitor.check(context)
    assert message.startswith("ball 9 escaped the heart at t = 0.0000 s")
    x = context.get_mutable_discrete_state_vector()  # SetPositions itself refuses NaN
    x.SetAtIndex(x.size() - 1, np.nan)
    assert monitor.check(context).startswith("NaN or inf in the state")


def test_the_feeder_system_drives_the_chain():
    """systems/feeder.py's inserted_length through the exported port moves ball 1 as much."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from ballchain.systems.feeder import Feeder

    scenario = load_scenario("free_space_uniform_90deg",
                             "{n_balls: 6, uniform_field: [0.0, 0.0, 0.0], insertion: {initial: 0.0, external: true}}")
    cd = MakeStation(scenario)
    builder = DiagramBuilder()
    chain = builder.AddSystem(cd.diagram)
    feeder = builder.AddSystem(Feeder(cd.chain.config.chain))
    speed = builder.AddSystem(ConstantVectorSource([0.02]))  # m/s
    builder.Connect(speed.get_output_port(), feeder.GetInputPort("v_insert_cmd"))
    builder.Connect(feeder.GetOutputPort("inserted_length"), chain.GetInputPort("inserted_length"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    plant = cd.chain.plant
    plant_context = plant.GetMyContextFromRoot(simulator.get_mutable_context())
    p0 = cd.chain.ball_positions(plant_context)
    simulator.AdvanceTo(0.3)
    s = feeder.GetOutputPort("inserted_length").Eval(feeder.GetMyContextFromRoot(simulator.get_context()))[0]
    p1 = cd.chain.ball_positions(plant_context)
    assert s > 2e-3  # the feeder did move
    np.testing.assert_allclose((p1 - p0)[:, 0], s, atol=0.05e-3)  # the whole chain, straight


@pytest.mark.slow
def test_a_user_atrium_surface_runs_and_a_bad_one_is_refused(tmp_path, capsys):
    from ballchain.drake_models import mesh_tools as mt

    U, F = mt.icosphere(3)
    obj = mt.write_obj(tmp_path / "la_mm.obj", U * np.array([27.0, 19.0, 24.0]), F)  # mm
    overrides = f"{{atrium_file: '{obj}', puncture: [-0.027, 0.0, 0.0], insertion: {{initial: 0.02, final: 0.025}}}}"
    scenario = load_scenario("heart_no_field", overrides)
    result = run_simulation(scenario=scenario, duration=0.05)
    tip = np.array(result.tip_position_mm)
    assert tip[0] > -27.0 + 15.0  # ~20 mm of chain out of the sheath, pointing to the centre
    assert result.min_wall_clearance_mm > 0 and result.max_neighbor_gap_um < 20
    # An open surface: the CLI says why, exit status 2.
    bad = mt.write_obj(tmp_path / "open.obj", U * 25.0, F[1:])
    argv = ["simulate", "--scenario", "heart_no_field", "--duration", "0.001",
            "--set", f"{{atrium_file: '{bad}', puncture: [-0.025, 0.0, 0.0]}}"]
    assert cli_main(argv) == 2
    assert "not closed: 3 boundary edges" in capsys.readouterr().err
    with pytest.raises(ValueError, match="needs puncture"):
        load_scenario("heart_no_field", f"{{atrium_file: '{obj}'}}")


# ------------------------------------------------------------------ actuation units in the station
UNIT_8_BALLS = ("{n_balls: 8, uniform_field: [0.0, 0.0, 0.0], units: [{name: right_unit, p_WM: [0.03, -0.08, 0.0], "
                "sensor_noise: false, joystick: [{time: 0.0, axes: [0.0, 0.0, 1.0]}, {time: 0.3, axes: [0.0, 0.0, 0.0]}]}]}")


@pytest.mark.slow
def test_station_with_units_has_named_systems_and_wiring(heart):
    cd = MakeStation(load_scenario("teleop_two_units"), heart=heart)
    names = {s.get_name() for s in cd.diagram.GetSystems()}
    for unit in ("right_unit", "left_unit"):  # each unit one compiled system (tests/test_compiled_units.py)
        assert {f"{unit}.{part}" for part in ("unit", "teleoperation", "joystick", "mode_command")} <= names
    composed = MakeStation(load_scenario("teleop_two_units", "{unit_systems: python}"), heart=heart)
    for unit in ("right_unit", "left_unit"):
        assert {f"{unit}.{part}" for part in ("magnet", "drive", "hall_sensor", "estimator", "controller",
                                              "teleoperation", "mode_switch", "joystick", "mode_command")} <= {
            s.get_name() for s in composed.diagram.GetSystems()}
    assert {"feeder", "feeder_interface", "magnet_states", "magnetic_wrench"} <= names
    # The feeder plays the insertion ramp itself; the plant reads its length at every step, so it
    # steps alone (with the quasi-static engine: in batches, tests/test_actuation_speed_identical.py).
    assert "feeder_command" not in names and cd.feeder.num_input_ports() == 0
    assert cd.chain.move_period == 0.0 and cd.feeder.batch_period is None
    assert cd.chain.wrench.get_magnet_states_input_port().size() == 12  # (p_WM, m_hat_W) per unit
    # Fixed inputs at t = 0: the wrench sees each unit at its centre with its neutral dipole, and the
    # neutral dipole makes the field at the sheath exit point along the sheath (to 1e-9).
    context = cd.diagram.CreateDefaultContext()
    wrench = cd.chain.wrench
    x = wrench.get_magnet_states_input_port().Eval(wrench.GetMyContextFromRoot(context)).reshape(2, 6)
    field = wrench.external_field(wrench.GetMyContextFromRoot(context))
    for row, unit in zip(x, cd.units.values()):
        np.testing.assert_allclose(row[:3], unit.config.p_WM, atol=1e-12)
        np.testing.assert_allclose(row[3:] / np.linalg.norm(row[3:]), unit.m_hat_neutral_W, atol=1e-12)
    B = field.field_and_gradient(heart.p_HE[None])[0][0]
    np.testing.assert_allclose(B / np.linalg.norm(B), heart.sheath_axis_H, atol=1e-9)
    # The paper's placement: 10 cm from the right carina.
    right = cd.units["right_unit"].config
    assert np.linalg.norm(np.asarray(right.p_WM) - heart.carinas["right"]) == pytest.approx(0.10)


def test_bad_unit_scenarios_fail_clearly(heart):
    with pytest.raises(ValueError, match="distinct names"):
        load_scenario("teleop_two_units", "{units: [{name: a}, {name: a}]}")
    with pytest.raises(ValueError, match="needs the heart"):
        load_scenario("free_space_uniform_90deg", "{units: [{name: a, anchor: carina_left}]}")
    with pytest.raises(ValueError, match="joystick key times"):
        load_scenario("teleop_right_unit", "{units: [{name: a, joystick: [{time: 0.5}, {time: 0.1}]}]}")
    with pytest.raises(ValueError, match="exceeds the feeder's limit"):
        MakeStation(load_scenario("free_space_uniform_90deg", "{insertion: {final: 0.01, speed: 0.5, feeder: true}}"))
    with pytest.raises(ValueError, match="external .* or feeder"):
        MakeStation(load_scenario("free_space_uniform_90deg", "{insertion: {external: true, feeder: true}}"))
    with pytest.raises(ValueError, match="has no carinas"):
        MakeStation(load_scenario("teleop_right_unit", "{units: [{name: a, anchor: carina_right}]}"),
                            heart=_without_carinas(heart))


def _without_carinas(heart):
    """A copy of the atrium without carinas, as a user's surface (UserAtrium) has none."""
    import copy

    stub = copy.copy(heart)
    stub.carinas = {}
    return stub


def test_meshcat_draws_the_units():
    from pydrake.geometry import Meshcat, MeshcatParams

    meshcat = Meshcat(MeshcatParams(host="localhost"))
    scenario = load_scenario("free_space_uniform_90deg", "{n_balls: 3, units: [{name: right_unit, p_WM: [0.0, -0.1, 0.0]}]}")
    cd = MakeStation(scenario, meshcat=meshcat)
    assert "unit_markers" in {s.get_name() for s in cd.diagram.GetSystems()}
    assert meshcat.HasPath("units/right_unit/body") and meshcat.HasPath("units/right_unit/dipole")


def test_rotating_unit_steers_the_chain_to_the_statics_equilibrium():
    """Full stick about +z for 0.3 s turns the magnet 0.15 rad; the chain swings the way the field
    at the chain turned and settles within 0.1 mm of ChainStatics for the final magnet pose.

    Free space, no gravity, 8 balls, ball 1 clamped at the origin along +x (the statics frame); the
    unit (prototype cylinder, point dipole) 8.5 cm away starts at its neutral direction (field along
    +x at ball 1: the straight chain is in equilibrium). Measured: tip (22.2, 0) -> (17.64, -13.19)
    mm, statics (17.65, -13.22) mm, 0.03 mm apart; magnet turned 0.1500 rad.
    """
    from pydrake.systems.analysis import Simulator

    from ballchain.drake_models.field_sources import MagnetSource
    from ballchain.optimization.statics import ChainStatics

    cd = MakeStation(load_scenario("free_space_uniform_90deg", UNIT_8_BALLS))
    unit = cd.units["right_unit"]
    simulator = Simulator(cd.diagram)
    root = simulator.get_mutable_context()
    plant_context = cd.chain.plant.GetMyContextFromRoot(root)
    magnet_context = unit.magnet.GetMyContextFromRoot(root)
    simulator.Initialize()
    p0 = cd.chain.ball_positions(plant_context)
    simulator.AdvanceTo(0.8)
    p = cd.chain.ball_positions(plant_context)
    R_WM = unit.magnet.R_WM(magnet_context)
    m0, m1 = unit.m_hat_initial_W, R_WM[:, 2]
    turned = np.arctan2(np.cross(m0, m1)[2], m0 @ m1)
    assert turned == pytest.approx(0.5 * 0.3, abs=2e-3)  # omega_max x time, to a few microsteps
    np.testing.assert_allclose(R_WM[2, 2], 0.0, atol=1e-9)  # a rotation about z keeps m horizontal
    # Direction: the field at the chain's middle turned towards -y, and so did the tip.
    source = MagnetSource(unit.config.magnet, np.asarray(unit.config.p_WM), R_WM, "dipole")
    B_mid = source.field(p0[len(p0) // 2][None])[0]
    assert B_mid[1] < 0 and p[-1, 1] < -5e-3 and p0[-1, 1] == pytest.approx(0.0, abs=1e-6)
    # Statics: the same magnet, the equilibrium reached from the straight chain.
    statics = ChainStatics(cd.chain.config.chain).solve_or_raise(source)
    tip_error = np.linalg.norm(p[-1] - statics.positions[-1])
    print(f"tip {p[-1] * 1e3} mm, statics {statics.positions[-1] * 1e3} mm, error {tip_error * 1e3:.3f} mm")
    assert tip_error < 0.1e-3
    assert np.abs(p - statics.positions).max() < 0.1e-3


# A 1.3 s station run: the quick tier checks the controller's law, latch and station wiring in
# test_systems_actuation and a closed-loop run in test_reconfiguration_study.
@pytest.mark.slow
def test_reconfiguration_mode_returns_the_magnet_to_neutral():
    """Mode 1 from t = 0: the Hall-sensor loop turns a magnet started 30 deg off neutral back
    (K = 4 1/s: 30 deg e^(-4 t), 0.5 deg latch near 1.0 s), with the chain attached. The unit is
    on the -y side, so its neutral dipole (field along +x at ball 1) is -x."""
    from pydrake.systems.analysis import Simulator

    off = np.deg2rad(30.0)
    scenario = load_scenario("free_space_uniform_90deg", (
        "{n_balls: 3, uniform_field: [0.0, 0.0, 0.0], units: [{name: right_unit, p_WM: [0.0, -0.1651, 0.0], "
        f"m_hat_W: [{-np.cos(off)}, {np.sin(off)}, 0.0], joystick: [{{time: 0.0, mode: 1}}]}}]}}"))
    cd = MakeStation(scenario)
    unit = cd.units["right_unit"]
    simulator = Simulator(cd.diagram)
    np.testing.assert_allclose(unit.m_hat_neutral_W, [-1.0, 0.0, 0.0], atol=1e-12)
    simulator.AdvanceTo(1.3)
    context = unit.magnet.GetMyContextFromRoot(simulator.get_context())
    m = unit.magnet.R_WM(context)[:, 2]
    error_deg = np.degrees(np.arccos(np.clip(m @ unit.m_hat_neutral_W, -1, 1)))
    controller_context = unit.controller.GetMyContextFromRoot(simulator.get_context())
    assert unit.controller.GetOutputPort("done").Eval(controller_context)[0] == 1.0
    assert error_deg < 1.0  # latched at 0.5 deg measured (Hall noise and quantisation on top)


def test_feeder_plays_the_insertion_ramp():
    """insertion.feeder: the stepper feeder starts at the initial length and, despite its
    acceleration limit, ends at the final one (whole microsteps of 10.8 um); ball 1 follows."""
    from pydrake.systems.analysis import Simulator

    scenario = load_scenario("free_space_uniform_90deg", (
        "{n_balls: 3, uniform_field: [0.0, 0.0, 0.0], "
        "insertion: {initial: 0.002, final: 0.006, start_time: 0.05, speed: 0.02, feeder: true}}"))
    cd = MakeStation(scenario)
    feeder = cd.feeder
    simulator = Simulator(cd.diagram)
    root = simulator.get_mutable_context()
    plant_context = cd.chain.plant.GetMyContextFromRoot(root)
    feeder_context = feeder.GetMyContextFromRoot(root)
    s0 = feeder.GetOutputPort("inserted_length").Eval(feeder_context)[0]
    p0 = cd.chain.ball_positions(plant_context)
    simulator.AdvanceTo(0.6)  # ramp 0.2 s, plus 0.2 s for the feeder's acceleration limit
    s1 = feeder.GetOutputPort("inserted_length").Eval(feeder_context)[0]
    p1 = cd.chain.ball_positions(plant_context)
    step = feeder.spec.step_length
    assert s0 == pytest.approx(0.002, abs=step) and s1 == pytest.approx(0.006, abs=step)
    np.testing.assert_allclose(p1[0] - p0[0], [s1 - s0, 0.0, 0.0], atol=5e-6)


@pytest.mark.parametrize("unit_systems", ["compiled", "python"])
def test_every_unit_option_is_reachable_from_the_scenario(unit_systems):
    """The scenario's unit fields reach the unit's systems (they were StationOptions-only):
    slip in the magnet, the printed wheel map and the gain in the controller, no cross-talk."""
    from ballchain.drake_models.kernels import actuation as K

    scenario = load_scenario("teleop_two_units", f"{{unit_systems: {unit_systems}}}")
    u = scenario.units[0]
    u.slip, u.wheel_map, u.controller_gain = 0.05, "paper", 2.0
    u.sensors_see_other_units = u.estimator_compensates_other_units = False
    cd = MakeStation(scenario.validate())
    right, left = cd.units["right_unit"], cd.units["left_unit"]
    inputs = lambda system: [system.get_input_port(i).get_name() for i in range(system.num_input_ports())]
    assert right.config.name == "right_unit"
    if unit_systems == "compiled":
        c_right, c_left = right.magnet._constants[1], left.magnet._constants[1]
        assert c_right[K.C_SLIP] == 0.05 and c_left[K.C_SLIP] == 0.0
        assert c_right[K.C_GAIN] == 2.0 and c_left[K.C_GAIN] == 4.0
        assert c_right[K.C_PAPER_MAP] == 1.0 and c_left[K.C_PAPER_MAP] == 0.0  # the printed map
        assert inputs(right.sensor) == ["omega_teleop_W", "mode"]
        assert "q_WM_right_unit" in inputs(left.sensor)
    else:
        assert right.magnet._slip == 0.05 and left.magnet._slip == 0.0
        assert right.controller._K == 2.0 and left.controller._K == 4.0
        assert right.controller._to_wheels is not right.controller._g.wheel_speeds  # the printed map
        assert inputs(right.sensor) == ["X_WM"]
        assert "X_WM_right_unit" in inputs(left.sensor)
    with pytest.raises(UserInputError, match=r"units\[0\].slip must be in \[0, 1\)"):
        load_scenario("teleop_right_unit", "{units: [{name: right_unit, slip: 1.5}]}")


def test_the_one_run_loop_stops_on_its_condition_and_reports_a_failure():
    """``run_station``: a stop condition ends the run (a termination, not a failure); without one
    the run goes to its duration; the watchdog's failure comes back as a message."""
    from ballchain.systems.chain_simulation import run_station

    scenario = load_scenario("free_space_uniform_90deg", "{n_balls: 4}")
    stopped = run_station(MakeStation(scenario), duration=0.2, stop=lambda root: root.get_time() >= 0.05)
    assert stopped.stopped and stopped.failure is None and 0.05 <= stopped.sim_time < 0.06
    full = run_station(MakeStation(scenario), duration=0.1)
    assert not full.stopped and full.failure is None and full.sim_time == pytest.approx(0.1)
    broken = run_station(MakeStation(load_scenario("free_space_uniform_90deg",
                                                           "{translational_damping: 0.1}")), duration=0.05)
    assert "the chain broke between balls" in broken.failure and broken.sim_time < 0.05


def test_the_progress_bar_ends_at_100_percent_when_the_task_ends_early(capsys):
    """A run whose stop condition ends it early (its task done) ends its bar at 100 %, at the
    time it ended; a run the watchdog ends keeps its bar where it stopped."""
    from ballchain.systems.chain_simulation import run_station

    scenario = load_scenario("free_space_uniform_90deg", "{n_balls: 4}")
    run_station(MakeStation(scenario), duration=0.2, stop=lambda root: root.get_time() >= 0.05, progress="task")
    last = capsys.readouterr().err.replace("\r", "\n").strip().splitlines()[-1]
    assert last.startswith("task: 100%") and "0.05/0.05 sim s" in last, last
    broken = MakeStation(load_scenario("free_space_uniform_90deg", "{translational_damping: 0.1}"))
    assert run_station(broken, duration=0.05, progress="broken").failure is not None
    last = capsys.readouterr().err.replace("\r", "\n").strip().splitlines()[-1]
    assert last.startswith("broken:") and "100%" not in last, last


def test_the_run_loop_takes_a_run_check_and_a_start_context():
    """``run_station``'s ``check`` (a run's own failure test, before the watchdog) ends the run
    with its message; ``context`` is the state the run starts from (here ball 4 put 2 m away:
    the watchdog stops the run at t = 0)."""
    from pydrake.math import RigidTransform

    from ballchain.systems.chain_simulation import run_station

    scenario = load_scenario("free_space_uniform_90deg", "{n_balls: 4}")
    cd = MakeStation(scenario)
    checked = run_station(cd, duration=0.2, check=lambda root: "too late" if root.get_time() >= 0.02 else None)
    assert checked.failure == "too late" and not checked.stopped and checked.sim_time == pytest.approx(0.02)
    assert checked.monitor.failure is None  # the watchdog saw nothing wrong
    root = cd.diagram.CreateDefaultContext()
    plant = cd.chain.plant
    plant.GetJointByName("ball_4_floating").SetPose(plant.GetMyContextFromRoot(root), RigidTransform([2.0, 0.0, 0.0]))
    away = run_station(cd, duration=0.2, context=root)
    assert away.context is root and away.sim_time == 0.0
    assert away.failure.startswith("ball 4 flew away at t = 0.0000 s")


def test_the_metrics_serialise_to_the_keys_of_the_simulate_json():
    """``SimulationMetrics`` through ``safe_files.to_jsonable``: the keys of ``ballchain simulate
    --json`` in their order; the engine's stats (with a snap-through), the replay and the ball
    centres only when there are any."""
    from ballchain.infrastructure.safe_files import to_jsonable
    from ballchain.systems.chain_simulation import SimulationMetrics, SnapThrough, StaticsEngineStats

    always = ["realtime_factor", "sim_time_s", "tip_position_mm", "min_wall_clearance_mm", "max_neighbor_gap_um",
              "max_penetration_um", "max_ball_overlap_um", "max_wall_penetration_um", "monitor_checks",
              "wall_time_s", "build_time_s", "time_step_s", "mode", "engine", "n_steps", "targets_touched",
              "tip_wall_force_N", "peak_memory_MB"]
    values = dict(zip(always, [1.5, 0.1, [1.0, 2.0, 3.0], None, 0.5, 1.0, 1.0, 0.0, 20, 0.2, 1.0, 1e-3,
                               "quasi-static", "plant", 100, ["left_3"], [0.0, 0.0, 0.1], 300.0]))
    plain = to_jsonable(SimulationMetrics(**values))
    assert list(plain) == always and plain == values
    stats = StaticsEngineStats(solves=2, median_solve_ms=4.0, max_solve_ms=5.0, median_iterations=7.0,
                               snap_throughs=[SnapThrough(t_s=0.05, jump_mm=float("nan"), detail="branch ended")],
                               failures=[])
    full = to_jsonable(SimulationMetrics(**values, statics=stats, html="run.html", p_W_mm=[[0.0, 0.0, 0.0]]))
    assert list(full) == always + ["statics", "html", "p_W_mm"]
    assert full["statics"] == {"solves": 2, "median_solve_ms": 4.0, "max_solve_ms": 5.0, "median_iterations": 7.0,
                               "snap_throughs": [{"t_s": 0.05, "jump_mm": None, "detail": "branch ended"}],
                               "failures": []}


class _Flips(__import__("pydrake.systems.framework", fromlist=["LeafSystem"]).LeafSystem):
    """A counter updated every ``period`` (offset 0) among faster events (every ``fast``): its
    condition (the count reached ``at``) changes only at its updates."""

    def __init__(self, period: float, fast: float, at: int):
        super().__init__()
        self.at = at
        self.count = self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclarePeriodicDiscreteUpdateEvent(fast, 0.0, lambda context, state: None)

    def _update(self, context, state):
        state.get_mutable_vector(self.count).SetAtIndex(0, context.get_discrete_state(self.count).GetAtIndex(0) + 1)

    def reached(self, context) -> bool:
        return context.get_discrete_state(self.count).GetAtIndex(0) >= self.at


@pytest.mark.parametrize("period, fast, at", [(0.05, 0.002, 7), (0.05, 0.005, 1), (0.02, 0.003, 13), (0.1, 0.1, 4)])
def test_a_stop_asked_only_after_its_updates_ends_the_run_where_asking_every_step_does(period, fast, at):
    """``after_updates``: the same end time as the condition asked at every step, including a run
    started over from an earlier time, and it asks far less often than every step."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import EventStatus

    from ballchain.systems.chain_simulation import after_updates

    def end_time(gated: bool, restart: bool = False):
        system = _Flips(period, fast, at)
        asked = [0]

        def condition(context):
            asked[0] += 1
            return system.reached(context)

        stop = after_updates(condition, period) if gated else condition
        simulator = Simulator(system)

        def monitor(context):
            if stop(context):
                return EventStatus.ReachedTermination(None, "reached")
            return EventStatus.Succeeded()

        simulator.set_monitor(monitor)
        simulator.Initialize()
        if restart:  # half-way, then from the start again (StationRunner.restart)
            simulator.AdvanceTo(0.5 * period * at)
            simulator.get_mutable_context().SetTime(0.0)
            simulator.get_mutable_context().SetDiscreteState(0, [0.0])
            simulator.Initialize()
        simulator.AdvanceTo(10.0)
        return simulator.get_context().get_time(), asked[0], simulator.get_num_steps_taken()

    t_every, asked_every, steps = end_time(False)
    t_gated, asked_gated, _ = end_time(True)
    assert t_every < 9.0 and t_gated == t_every
    assert asked_every >= steps and asked_gated <= at + 1  # every step (and the initialisation)
    assert end_time(True, restart=True)[0] == t_every


def test_after_updates_refuses_a_period_that_is_not_positive():
    from ballchain.systems.chain_simulation import after_updates

    for bad in (0.0, -1.0, float("nan"), "0.05"):
        with pytest.raises(ValueError, match="period must be a positive"):
            after_updates(lambda context: False, bad)
