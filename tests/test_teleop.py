"""Teleoperation tasks: the simulated operator alone (a fake tip), in the station, and the CLI."""

import json

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from ballchain.cli import main as cli_main
from ballchain.experiments import teleop
from ballchain.systems.simulated_operator import OperatorParams, SimulatedOperator
from ballchain.systems.teleoperation import apply_dead_band

BALL_RADIUS = 0.5 * 3.175e-3


class FakeTip(LeafSystem):
    """A tip that moves linearly with the controls: v = A (stick after the dead band) + c v_insert.

    Outputs ``body_poses`` as a plant would: [previous ball, tip ball] (BodyIndex 0 and 1).
    """

    def __init__(self, A, c, p0, dt=0.005):
        super().__init__()
        self.A, self.c = np.asarray(A, float), np.asarray(c, float)
        self._joystick = self.DeclareVectorInputPort("joystick", 3)
        self._feed = self.DeclareVectorInputPort("v_insert_cmd", 1)
        self._state = self.DeclareDiscreteState(np.asarray(p0, float))
        self.DeclarePeriodicDiscreteUpdateEvent(dt, 0.0, self._update)
        self._dt = dt
        self.DeclareAbstractOutputPort("body_poses", lambda: AbstractValue.Make([RigidTransform()]), self._poses,
                                       prerequisites_of_calc={self.xd_ticket()})

    def _update(self, context, state):
        u = apply_dead_band(self._joystick.Eval(context), 0.1)
        v = self.A @ u + self.c * self._feed.Eval(context)[0]
        state.get_mutable_vector().SetFromVector(context.get_discrete_state_vector().get_value() + self._dt * v)

    def _poses(self, context, output):
        p = context.get_discrete_state_vector().get_value()
        output.set_value([RigidTransform(p - [2 * BALL_RADIUS, 0.0, 0.0]), RigidTransform(p)])


def _fake_station(A, c, p_T, n_T, params):
    builder = DiagramBuilder()
    tip = builder.AddSystem(FakeTip(A, c, p0=np.zeros(3)))
    op = builder.AddSystem(SimulatedOperator(1, 0, ["fake_1"], [p_T], [n_T], params))
    builder.Connect(tip.GetOutputPort("body_poses"), op.get_body_poses_input_port())
    builder.Connect(op.GetOutputPort("joystick"), tip.GetInputPort("joystick"))
    builder.Connect(op.GetOutputPort("v_insert_cmd"), tip.GetInputPort("v_insert_cmd"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    return simulator, op, op.GetMyContextFromRoot(simulator.get_mutable_context())


def test_operator_learns_the_mapping_and_drives_a_fake_tip_to_the_target():
    """A linear, well-conditioned but mixed-up mapping (no axis moves the tip along one world axis):
    after its probing wiggle (1.5 s for 3 axes) the operator's Jacobian estimate matches the true
    one, and it touches a target 25 mm away (feeding along the tip's direction where that helps)
    within 2 mm of its centre."""
    rng = np.random.default_rng(3)
    R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    A = 0.015 * R * [1.0, 0.7, 1.3]  # [m/s] at full stick after the dead band
    c = np.array([1.0, 0.0, 0.0])  # feeding moves the tip along its direction (+x, FakeTip's)
    p_T = np.array([0.015, -0.012, 0.016])
    n_T = -p_T / np.linalg.norm(p_T)  # the wall faces the tip's start
    simulator, op, context = _fake_station(A, c, p_T, n_T, OperatorParams(timeout=10.0))
    simulator.AdvanceTo(1.5)  # the end of the probing wiggle
    J = op.jacobian_estimate(context)
    assert np.abs(J - A).max() < 0.05 * np.abs(A).max()
    simulator.AdvanceTo(10.0)
    (row,) = op.rows(context)
    print(row)
    assert op.is_done(context) and row["touched"]
    assert row["time_s"] < 6.0
    assert row["accuracy_mm"] <= 2.0  # aimed at the centre, the fake tip has no wall to slide on
    J = op.jacobian_estimate(context)
    assert np.abs(J[:, :3] - A).max() < 0.1 * np.abs(A).max()


def test_operator_gives_up_after_the_timeout():
    """A stick that does nothing: the target is recorded as missed after the timeout and the run ends."""
    simulator, op, context = _fake_station(np.zeros((3, 3)), np.zeros(3), [0.02, 0.0, 0.0], [-1.0, 0.0, 0.0],
                                           OperatorParams(timeout=3.0))
    simulator.AdvanceTo(4.0)
    (row,) = op.rows(context)
    assert op.is_done(context) and not row["touched"] and row["accuracy_mm"] is None
    assert row["time_s"] == pytest.approx(3.0, abs=0.06)


def test_bad_input_is_rejected_with_clear_messages(capsys):
    with pytest.raises(ValueError, match="task must be one of"):
        teleop.run(task="middle")
    with pytest.raises(ValueError, match="mapping must be one of"):
        teleop.run(mapping="tip")
    with pytest.raises(ValueError, match="targets must be a positive number"):
        teleop.run(targets=-2)
    with pytest.raises(ValueError, match="axes"):
        OperatorParams(axes=(0, 3)).validate()
    assert cli_main(["teleop", "--task", "up", "--json"]) == 2
    assert "task must be one of" in capsys.readouterr().err
    assert cli_main(["teleop", "--targets", "-1"]) == 2
    assert "targets must be a positive number" in capsys.readouterr().err


@pytest.mark.slow
def test_station_wiring_for_both_mappings():
    """External stick and feeder: the scenario hooks route the mapping to the mapper's frame and
    leave the inputs to the operator (exported when nothing drives them)."""
    from ballchain.systems.chain_simulation import build_chain_diagram

    for mapping, frame in (("world", "world"), ("catheter", "tip")):
        scenario = teleop.scenario_for(mapping, n_balls=10)
        assert scenario.units[0].teleop_frame == frame
        cd = build_chain_diagram(scenario)
        names = {s.get_name() for s in cd.diagram.GetSystems()}
        assert "right_unit.joystick" not in names and "feeder_command" not in names
        assert ("tip_observer" in names) == (frame == "tip")
        assert cd.diagram.GetInputPort("right_unit.joystick").size() == 3
        assert cd.diagram.GetInputPort("feeder.v_insert_cmd").size() == 1
    with pytest.raises(ValueError, match="teleop_frame must be one of"):
        teleop.scenario_for("world", overrides="{units: [{name: a, teleop_frame: camera}]}")
    from ballchain.systems.chain_scenario import load_scenario

    with pytest.raises(ValueError, match="needs the feeder"):
        load_scenario("heart_no_field", "{insertion: {feeder_command: external}}")
    with pytest.raises(ValueError, match="joystick_source must be one of"):
        load_scenario("teleop_right_unit", "{units: [{name: a, joystick_source: operator}]}")


# The station tests run the paper's set-up (16 balls, one unit 10 cm beyond the right carina) at a
# 4 ms quasi-static step: replaying 15 s of an operator's commands, its tip path stays within
# 0.3 mm of the default 1 ms step's (3.2 times faster; see the teleop experiment's notes).
FAST = "{time_step: 0.004}"


@pytest.mark.slow
def test_operator_touches_the_first_target_with_the_world_mapping(capsys):
    """Task II's first target through the CLI (--json), the paper's world-frame mapping: touched
    within 10 s of simulated time (probing wiggle included), inside the 5 mm circle."""
    code = cli_main(["teleop", "--task", "right", "--mapping", "world", "--targets", "1", "--set", FAST,
                     "--no-progress", "--json"])
    assert code == 0
    data = json.loads(capsys.readouterr().out)
    (row,) = data["rows"]
    print(row, data["summary"])
    assert data["task"] == "right" and data["mapping"] == "world" and data["paper"]["human_time_s"] == 26.0
    assert row["target"] == "right_1" and row["touched"] and row["time_s"] < 10.0
    assert row["accuracy_mm"] <= 2.5 + BALL_RADIUS * 1e3  # the circle's radius (+ a ball radius)
    assert data["summary"]["touched"] == 1 and data["summary"]["failure"] is None


@pytest.mark.slow
def test_operator_touches_the_first_target_with_the_catheter_mapping(tmp_path):
    """The same target with the catheter-frame mapping (two stick axes), with a Meshcat replay."""
    html = tmp_path / "teleop.html"
    data = teleop.run(task="right", mapping="catheter", targets=1, html=html, progress=False, overrides=FAST)
    (row,) = data["rows"]
    print(row, data["summary"])
    assert data["settings"]["axes"] == [0, 1]
    assert row["touched"] and row["time_s"] < 10.0
    assert row["accuracy_mm"] <= 2.5 + BALL_RADIUS * 1e3
    assert html.exists() and html.stat().st_size > 100_000
