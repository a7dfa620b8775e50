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
    # Nothing jammed (no feeding), no length cap, no confusion: it ran out of time, 20 mm away
    # (the wall-side point a ball radius beyond the centre, towards the target).
    assert row["reason"] == "timeout"
    assert row["closest_mm"] == pytest.approx(20.0 - BALL_RADIUS * 1e3, abs=6e-4)  # rounded to 1 um


def test_missed_reasons_follow_what_the_operator_recorded():
    """TargetRecord.reason from its counts: jams first, then the length cap, then confusion."""
    from ballchain.systems.simulated_operator import TargetRecord

    def record(**kw):
        return TargetRecord("t", 0.0, t_end=20.0, looks=100, **kw)

    assert record(jammed_looks=26, capped_looks=90).reason() == "chain jammed"
    assert record(jammed_looks=25, capped_looks=51).reason() == "out of reach"
    assert record(capped_looks=50, relearns=3).reason() == "confused"
    assert record(relearns=2).reason() == "timeout"
    assert TargetRecord("t", 0.0, t_touch=3.0, t_end=3.0, accuracy=1e-3).reason() is None  # touched
    assert TargetRecord("t", 0.0).reason() is None  # still open
    # The experiment's reasons: the watchdog, the time limit, not turned to yet.
    open_row, unseen = {"reason": None}, {"reason": "not reached"}
    assert teleop.missed_reason(open_row) == "time limit"
    assert teleop.missed_reason(unseen, "ball 3 escaped") == "simulation stopped"
    assert teleop.missed_reason({"reason": "chain jammed"}, "ball 3 escaped") == "chain jammed"


def test_the_engine_is_the_default_and_overrides_merge():
    """No overrides: the quasi-static engine; other fields merge with it; the plant on request
    (or when the mode needs it)."""
    assert teleop.scenario_for("world").engine == "statics"
    merged = teleop.scenario_for("catheter", overrides="{time_step: 0.002, statics_period: 0.025}")
    assert merged.engine == "statics" and merged.time_step == 0.002 and merged.statics_period == 0.025
    assert merged.units[0].teleop_frame == "tip"
    plant = teleop.scenario_for("world", overrides=teleop.FAST)
    assert plant.engine == "plant" and plant.time_step == 0.004
    assert teleop.scenario_for("world", overrides="{mode: dynamics}").engine == "plant"
    with pytest.raises(ValueError, match="engine must be one of"):
        teleop.scenario_for("world", overrides="{engine: fast}")


def test_seed_is_validated(capsys):
    for bad in (-1, 2**32, 1.5, True, "3"):
        with pytest.raises(ValueError, match="seed must be an integer in 0..4294967295"):
            teleop.run(seed=bad)
    assert cli_main(["teleop", "--seed", "-4", "--json"]) == 2
    assert "seed must be an integer" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # argparse: not an integer
        cli_main(["teleop", "--seed", "x"])
    assert "must be an integer" in capsys.readouterr().err
    assert cli_main(["teleop", "--live", "--seed", "3"]) == 2
    assert "--seed does not apply to --live" in capsys.readouterr().err
    for bad, match in ((5, "list of seeds"), ([1, 1], "distinct"), ([], "at least one"), ([0, -2], "each seed")):
        with pytest.raises(ValueError, match=match):
            teleop.run_seeds(seeds=bad)
    with pytest.raises(ValueError, match="task must be one of"):
        teleop.run_seeds(tasks=("middle",))


def _fake_result(task, seed, times, accuracy, reasons=None, rtf=6.0):
    touched = [t for t, a in zip(times, accuracy) if a is not None]
    summary = teleop.TeleopSummary(
        touched=len(touched), targets=len(times), total_time_s=float(sum(times)),
        median_time_s=float(np.median(touched)) if touched else None,
        median_accuracy_mm=float(np.median([a for a in accuracy if a is not None])) if touched else None,
        max_accuracy_mm=None, missed=[], missed_reasons=reasons or {}, struggled=[], sim_time_s=0.0,
        realtime_factor=rtf, wall_time_s=0.0, failure=None)
    return teleop.TeleopResult(task=task, mapping="world", rows=[], summary=summary, paper={}, settings={"seed": seed})


def test_aggregate_seeds_by_hand():
    """Three made-up runs of 3 targets: min/median/max touched, total time, medians of medians."""
    runs = [_fake_result("right", 0, [1.0, 2.0, 3.0], [1.0, 2.0, 1.5]),
            _fake_result("right", 1, [2.0, 20.0, 4.0], [0.5, None, 1.0], {"right_2": "timeout"}, rtf=5.0),
            _fake_result("right", 2, [20.0, 20.0, 1.0], [None, None, 2.0],
                         {"right_1": "chain jammed", "right_2": "timeout"}, rtf=7.0)]
    row = teleop.aggregate_seeds("right", "world", runs)
    assert row["seeds"] == [0, 1, 2] and row["runs"] == 3 and row["targets"] == 3
    assert (row["touched_min"], row["touched_median"], row["touched_max"]) == (1, 2.0, 3)
    assert (row["total_time_median_s"], row["total_time_min_s"], row["total_time_max_s"]) == (26.0, 6.0, 41.0)
    assert row["per_target_time_median_s"] == 2.0  # medians 2.0, 3.0, 1.0
    assert row["accuracy_median_mm"] == 1.5  # medians 1.5, 0.75, 2.0
    assert row["realtime_factor_median"] == 6.0
    assert row["paper_time_s"] == 26.0
    assert row["missed_reasons"] == "chain jammed: 1; timeout: 2"


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
    from ballchain.systems.chain_simulation import MakeStation

    for mapping, frame in (("world", "world"), ("catheter", "tip")):
        scenario = teleop.scenario_for(mapping, n_balls=10)
        assert scenario.units[0].teleop_frame == frame
        cd = MakeStation(scenario)
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


# The station tests run the paper's set-up (16 balls, one unit 10 cm beyond the right carina) on
# the quasi-static engine (the experiment's default), and the plant at a 4 ms quasi-static step
# (``teleop.FAST``: replaying 15 s of an operator's commands, its tip path stays within 0.3 mm of
# the default 1 ms step's) where the two are compared.


@pytest.mark.slow
def test_operator_touches_the_first_target_with_the_world_mapping(capsys):
    """Task II's first target through the CLI (--json), the paper's world-frame mapping: touched
    within 10 s of simulated time (probing wiggle included), inside the 5 mm circle."""
    code = cli_main(["teleop", "--task", "right", "--mapping", "world", "--targets", "1",
                     "--no-progress", "--json"])
    assert code == 0
    data = json.loads(capsys.readouterr().out)
    (row,) = data["rows"]
    print(row, data["summary"])
    assert data["task"] == "right" and data["mapping"] == "world" and data["paper"]["human_time_s"] == 26.0
    assert data["settings"]["engine"] == "statics" and data["settings"]["seed"] == 0
    assert row["target"] == "right_1" and row["touched"] and row["time_s"] < 10.0
    assert row["accuracy_mm"] <= 2.5 + BALL_RADIUS * 1e3  # the circle's radius (+ a ball radius)
    assert data["summary"]["touched"] == 1 and data["summary"]["failure"] is None


@pytest.mark.slow
def test_operator_touches_the_first_target_with_the_catheter_mapping(tmp_path):
    """The same target with the catheter-frame mapping (two stick axes), with a Meshcat replay."""
    html = tmp_path / "teleop.html"
    data = teleop.run(task="right", mapping="catheter", targets=1, html=html, progress=False)
    (row,) = data.rows
    print(row, data.summary)
    assert data.settings["axes"] == [0, 1]
    assert row["touched"] and row["time_s"] < 10.0
    assert row["accuracy_mm"] <= 2.5 + BALL_RADIUS * 1e3
    assert html.exists() and html.stat().st_size > 100_000


@pytest.fixture(scope="module")
def heart():
    from ballchain.systems.chain_simulation import atrium_for

    return atrium_for(teleop.scenario_for("world"))


@pytest.mark.slow
@pytest.mark.parametrize("task", teleop.TASKS)
def test_operator_on_the_engine_touches_the_first_targets_of_each_ring(task, heart):
    """The quasi-static engine (default): the first two targets of each ring with both mappings,
    inside the 5 mm circle (plus a ball radius, the accuracy's reference point), each within
    10 s, no watchdog stop."""
    for mapping in teleop.MAPPINGS:
        data = teleop.run(task=task, mapping=mapping, targets=2, progress=False, heart=heart)
        print(task, mapping, data.rows, data.summary.realtime_factor)
        assert data.settings["engine"] == "statics" and data.summary.failure is None
        assert [r["target"] for r in data.rows] == [f"{task}_1", f"{task}_2"]
        for r in data.rows:
            assert r["touched"] and r["time_s"] < 10.0 and r["reason"] is None
            assert r["accuracy_mm"] <= 2.5 + BALL_RADIUS * 1e3
        assert data.summary.missed_reasons == {}


@pytest.mark.slow
def test_engine_and_plant_touch_the_same_first_target(heart):
    """Right ring, world mapping, first target: the engine (equilibrium every 50 ms) and the
    plant (4 ms quasi-static steps) both touch it; the touch times agree within 1.5 s (the
    operator's loop is closed and chaotic: the same commands give a tip path within 0.3 mm, but a
    few tenths of a mm move its next decisions; the first target includes the 1.5 s wiggle)."""
    runs = {}
    for overrides in (None, teleop.FAST):
        data = teleop.run(task="right", mapping="world", targets=1, progress=False, heart=heart, overrides=overrides)
        runs[data.settings["engine"]] = data.rows[0]
    print(runs)
    assert runs["statics"]["touched"] and runs["plant"]["touched"]
    assert abs(runs["statics"]["t_touch_s"] - runs["plant"]["t_touch_s"]) < 1.5


@pytest.mark.slow
def test_run_seeds_aggregates_its_runs(tmp_path, heart):
    """A tiny spread (right ring, world mapping, first target, seeds 3 and 7): the table's row is
    the aggregate of the runs it returns, the CSV and JSON are written, the seeds differ in the
    operator's tremor (different rows)."""
    import csv

    result = teleop.run_seeds(tasks=("right",), mappings=("world",), seeds=(3, 7), targets=1, out=tmp_path,
                              progress=False, heart=heart)
    (row,) = result.table
    runs = result.runs
    assert [r["seed"] for r in runs] == [3, 7] and row["seeds"] == [3, 7]
    expected = teleop.aggregate_seeds("right", "world", [
        teleop.TeleopResult(task="right", mapping="world", rows=r["rows"], summary=r["summary"], paper={},
                            settings={"seed": r["seed"]}) for r in runs])
    assert row == expected
    times = [r["summary"].total_time_s for r in runs]
    assert row["total_time_min_s"] == min(times) and row["total_time_max_s"] == max(times)
    # another tremor, another run: the total times are kept to 0.05 s, and the learned operator
    # can reach the first target in the same step count; the path's rows (accuracy, approach) differ
    assert runs[0]["rows"] != runs[1]["rows"]
    with open(tmp_path / "teleop_seeds.csv") as f:
        (line,) = list(csv.DictReader(f))
    assert line["task"] == "right" and float(line["total_time_median_s"]) == row["total_time_median_s"]
    assert json.loads((tmp_path / "teleop_seeds.json").read_text())["table"][0]["seeds"] == [3, 7]


def _three_right_targets(heart) -> tuple[list[dict], float]:
    """Rows and simulated time of the operator on the right ring's first three targets."""
    data = teleop.run(task="right", mapping="world", targets=3, progress=False, heart=heart)
    return data.rows, data.summary.sim_time_s


def test_the_run_ends_where_asking_the_operator_at_every_step_would_end_it(heart, monkeypatch):
    """The run's stop (the operator done) is asked only after the operator's updates
    (``after_updates``): the same rows and simulated time as asking at every step (three
    targets, right ring, world mapping)."""
    import ballchain.systems.chain_simulation as chain_simulation

    gated = _three_right_targets(heart)
    monkeypatch.setattr(chain_simulation, "after_updates", lambda condition, period: condition)
    every_step = _three_right_targets(heart)
    assert gated == every_step and len(gated[0]) == 3 and gated[1] > 1.0


def test_feeder_command_period_is_checked_in_the_scenario():
    """``insertion.feeder_command_period``: only for a command from another system's looks, a
    whole number of the feeder's 2 ms steps, up to 1 s; the teleoperation scenario gets the
    operator's period."""
    from ballchain.infrastructure.errors import UserInputError
    from ballchain.systems.chain_scenario import load_scenario

    external = "feeder: true, feeder_command: external, final: 0.02"
    for overrides in ("{insertion: {feeder_command_period: 0.05}}",  # the ramp changes at any time
                      "{insertion: {%s, feeder_command_period: 0.003}}" % external,
                      "{insertion: {%s, feeder_command_period: -0.05}}" % external,
                      "{insertion: {%s, feeder_command_period: 2.0}}" % external,
                      "{insertion: {%s, feeder_command_period: .nan}}" % external):
        with pytest.raises(UserInputError, match="insertion.feeder_command_period must be"):
            load_scenario("teleop_right_unit", overrides)
    assert load_scenario("teleop_right_unit", "{insertion: {%s, feeder_command_period: 0.05}}"
                         % external).insertion.feeder_command_period == 0.05
    scenario = teleop.scenario_for("world")
    teleop.command_period(scenario, OperatorParams().period)
    assert scenario.insertion.feeder_command_period == OperatorParams().period == 0.05
    teleop.command_period(scenario, 0.0333)  # not whole steps: left as it was
    assert scenario.insertion.feeder_command_period == 0.05


def test_a_feeder_stepping_at_the_looks_gives_the_run_of_a_feeder_stepping_alone(heart, monkeypatch):
    """The feeder steps in batches at the operator's looks (``teleop.command_period``): the
    same rows as a feeder stepping every 2 ms (three targets, right ring, world mapping); the
    run ends at the first simulator step after the operator is done, which without the
    feeder's own steps comes up to 3 ms later (the drives' 5 ms steps)."""
    batched = _three_right_targets(heart)
    monkeypatch.setattr(teleop, "command_period", lambda scenario, period: None)
    alone = _three_right_targets(heart)
    assert batched[0] == alone[0] and len(alone[0]) == 3
    assert 0.0 <= batched[1] - alone[1] < 0.005


def test_a_task_whose_simulation_stopped_exits_1_after_its_results(capsys):
    """The sheath's rows off in the heart: the engine's first solve cannot hold the chain, the run
    stops at t = 0. Its results still print (the target not reached), and the exit status is 1
    with the reason on stderr, as ``simulate``'s (it was 0: a script took it for a finished task)."""
    from ballchain.cli import main as cli_main

    assert cli_main(["teleop", "--targets", "1", "--no-progress", "--set", "{sheath: false}", "--json"]) == 1
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert data["summary"]["touched"] == 0 and data["summary"]["failure"].startswith("at t = 0.0000 s")
    (line,) = [ln for ln in captured.err.splitlines() if ln.startswith("ballchain teleop:")]
    assert line.startswith("ballchain teleop: simulation stopped: at t = 0.0000 s: statics in the heart")
