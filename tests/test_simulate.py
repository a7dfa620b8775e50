"""Scenarios and the `ballchain simulate` command: every named scenario, defaults, bad input."""

import json

import numpy as np
import pytest

from ballchain.cli import main as cli_main
from ballchain.drake_models.heart import LeftAtrium
from ballchain.systems.chain_scenario import ChainScenario, load_scenario, scenario_names
from ballchain.systems.chain_simulation import SimulationFailure, build_chain_diagram, run_simulation

KEYS = {"realtime_factor", "sim_time_s", "tip_position_mm", "min_wall_clearance_mm",
        "max_neighbor_gap_um", "max_penetration_um"}


@pytest.fixture(scope="module")
def heart():
    return LeftAtrium()  # the scenarios' default atrium, built once


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
    cd = build_chain_diagram(load_scenario("heart_left_quasi_static"), heart=heart)
    names = {s.get_name() for s in cd.diagram.GetSystems()}
    assert {"plant", "scene_graph", "magnetic_wrench", "feeder_command"} <= names
    external = build_chain_diagram(load_scenario("heart_no_field", "{insertion: {external: true}}"), heart=heart)
    assert external.diagram.GetInputPort("inserted_length").size() == 1


@pytest.mark.parametrize("name", scenario_names())
def test_every_named_scenario_runs_briefly(name, heart):
    scenario = load_scenario(name)
    duration = 10 * scenario.effective_time_step
    result = run_simulation(scenario=scenario, duration=duration, heart=heart if scenario.heart else None)
    assert KEYS <= set(result)
    assert result["sim_time_s"] == pytest.approx(duration)
    assert result["max_penetration_um"] < 20.0
    assert result["max_neighbor_gap_um"] < 20.0
    if scenario.heart:
        assert result["min_wall_clearance_mm"] > 0.0
    assert np.all(np.isfinite(result["tip_position_mm"]))


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
    with pytest.raises(ValueError, match="scenario 'heart_no_field'"):
        load_scenario("heart_no_field", "{no_such_field: 1}")
    with pytest.raises(ValueError, match="ball 1 must stay in the sheath"):
        build_chain_diagram(load_scenario("free_space_uniform_90deg", "{insertion: {initial: 0.2}}"))


def test_a_breaking_chain_stops_with_when_and_which_ball(capsys):
    """Too little damping for a 1 ms step: the explicit magnetic forces blow the chain apart."""
    argv = ["simulate", "--scenario", "free_space_uniform_90deg", "--duration", "0.05",
            "--set", "{translational_damping: 0.1}", "--json"]
    assert cli_main(argv) == 1
    captured = capsys.readouterr()
    assert "simulation stopped:" in captured.err
    assert "between balls" in captured.err or "flew away" in captured.err or "NaN" in captured.err
    data = json.loads(captured.out)
    assert "failure" in data and data["sim_time_s"] < 0.05
    with pytest.raises(SimulationFailure, match=r"at t = 0\.0"):
        run_simulation(scenario=load_scenario("free_space_uniform_90deg", "{translational_damping: 0.1}"),
                       duration=0.05)


def test_html_recording(tmp_path):
    html = tmp_path / "run.html"
    result = run_simulation(scenario=load_scenario("free_space_uniform_90deg", "{n_balls: 4}"),
                            duration=0.01, html=html)
    text = html.read_text()
    assert result["html"] == str(html)
    assert text.lstrip().lower().startswith("<!doctype html") or "<html" in text[:1000].lower()
    assert len(text) > 10_000


def test_monitor_names_the_escaped_ball_and_nan(heart):
    """The watchdog on hand-made states: a ball moved outside the heart, then a NaN."""
    from pydrake.math import RigidTransform

    from ballchain.systems.chain_simulation import ChainMonitor

    cd = build_chain_diagram(load_scenario("heart_no_field"), heart=heart)
    plant = cd.chain_plant.plant
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
    cd = build_chain_diagram(scenario)
    builder = DiagramBuilder()
    chain = builder.AddSystem(cd.diagram)
    feeder = builder.AddSystem(Feeder(cd.chain_plant.config.chain))
    speed = builder.AddSystem(ConstantVectorSource([0.02]))  # m/s
    builder.Connect(speed.get_output_port(), feeder.GetInputPort("v_insert_cmd"))
    builder.Connect(feeder.GetOutputPort("inserted_length"), chain.GetInputPort("inserted_length"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    plant = cd.chain_plant.plant
    plant_context = plant.GetMyContextFromRoot(simulator.get_mutable_context())
    p0 = cd.chain_plant.ball_positions(plant_context)
    simulator.AdvanceTo(0.3)
    s = feeder.GetOutputPort("inserted_length").Eval(feeder.GetMyContextFromRoot(simulator.get_context()))[0]
    p1 = cd.chain_plant.ball_positions(plant_context)
    assert s > 2e-3  # the feeder did move
    np.testing.assert_allclose((p1 - p0)[:, 0], s, atol=0.05e-3)  # the whole chain, straight


def test_a_user_atrium_surface_runs_and_a_bad_one_is_refused(tmp_path, capsys):
    from ballchain.drake_models import mesh_tools as mt

    U, F = mt.icosphere(3)
    obj = mt.write_obj(tmp_path / "la_mm.obj", U * np.array([27.0, 19.0, 24.0]), F)  # mm
    overrides = f"{{atrium_file: '{obj}', puncture: [-0.027, 0.0, 0.0], insertion: {{initial: 0.02, final: 0.025}}}}"
    scenario = load_scenario("heart_no_field", overrides)
    result = run_simulation(scenario=scenario, duration=0.05)
    tip = np.array(result["tip_position_mm"])
    assert tip[0] > -27.0 + 15.0  # ~20 mm of chain out of the sheath, pointing to the centre
    assert result["min_wall_clearance_mm"] > 0 and result["max_neighbor_gap_um"] < 20
    # An open surface: the CLI says why, exit status 2.
    bad = mt.write_obj(tmp_path / "open.obj", U * 25.0, F[1:])
    argv = ["simulate", "--scenario", "heart_no_field", "--duration", "0.001",
            "--set", f"{{atrium_file: '{bad}', puncture: [-0.025, 0.0, 0.0]}}"]
    assert cli_main(argv) == 2
    assert "not closed: 3 boundary edges" in capsys.readouterr().err
    with pytest.raises(ValueError, match="needs puncture"):
        load_scenario("heart_no_field", f"{{atrium_file: '{obj}'}}")
