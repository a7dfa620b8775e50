"""The simulated operator on a non-linear device: it learns the feeder's effect, it tries the other
way when a burst did not help, and the hand's tendon switch at the knob's end; the manual right
ring with these (slow)."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from ballchain.systems.catheter_station import HandParams, ManualHand
from ballchain.systems.simulated_operator import OperatorParams, SimulatedOperator
from tests.test_teleop import FakeTip

BALL_RADIUS = 0.5 * 3.175e-3
FEED = 0.02  # the operator's feeder speed [m/s] (OperatorParams' default)


def _bent_back_run(learn_feeder: bool, t_end: float = 12.0):
    """A fake tip whose feeder does not push it along its direction (+x) but back and to the side,
    as feeding a catheter bent past a right angle does; two stick axes that move it only in y and
    z. The target lies behind the tip (-x): only feeding forward takes it there."""
    A = np.array([[0.0, 0.0], [0.012, 0.003], [-0.004, 0.014]])  # [m/s] at full stick
    c = np.array([-0.8, 0.6, 0.0])  # the feeder's effect per unit of its speed
    p_T = np.array([-0.015, 0.008, 0.004])
    n_T = np.array([1.0, 0.0, 0.0])  # the wall faces the tip's side
    builder = DiagramBuilder()
    tip = builder.AddSystem(FakeTip(np.column_stack([A, np.zeros(3)]), c, p0=np.zeros(3)))
    params = OperatorParams(axes=(0, 1), timeout=10.0, learn_feeder=learn_feeder, initial_length=0.05)
    op = builder.AddSystem(SimulatedOperator(1, 0, ["fake_1"], [p_T], [n_T], params))
    builder.Connect(tip.GetOutputPort("body_poses"), op.get_body_poses_input_port())
    builder.Connect(op.GetOutputPort("joystick"), tip.GetInputPort("joystick"))
    builder.Connect(op.GetOutputPort("v_insert_cmd"), tip.GetInputPort("v_insert_cmd"))
    simulator = Simulator(builder.Build())
    context = op.GetMyContextFromRoot(simulator.get_mutable_context())
    simulator.AdvanceTo(t_end)
    (row,) = op.rows(context)
    return row, op._memory(context), c


def test_operator_learns_a_feeder_that_does_not_push_along_the_tip():
    """Learning the feeder's effect (beyond its expected share along the tip) by the same recursive
    least squares as the stick's: the learned effect per unit command matches the fake's within
    10 % of the feeder's speed, and it touches the target behind the tip; with the prior alone
    (feeding pushes along the tip) it does not touch it in the same time."""
    row, mem, c = _bent_back_run(learn_feeder=True)
    learned = FEED * 1e3 * np.array([1.0, 0.0, 0.0]) + mem.F  # [mm/s] per unit command (d = +x)
    assert np.abs(learned - FEED * 1e3 * c).max() < 0.1 * FEED * 1e3
    assert row["touched"], row
    prior, _, _ = _bent_back_run(learn_feeder=False)
    assert not prior["touched"] or prior["time_s"] > row["time_s"], (prior, row)


def _hand(stick, params, t, initial):
    builder = DiagramBuilder()
    hand = builder.AddSystem(ManualHand(params))
    joystick = builder.AddSystem(ConstantVectorSource(np.asarray(stick, float)))
    feed = builder.AddSystem(ConstantVectorSource([0.0]))
    builder.Connect(joystick.get_output_port(), hand.GetInputPort("joystick"))
    builder.Connect(feed.get_output_port(), hand.GetInputPort("v_insert_cmd"))
    sim = Simulator(builder.Build())
    context = hand.GetMyContextFromRoot(sim.get_mutable_context())
    context.SetDiscreteState(np.asarray(initial, float))
    sim.AdvanceTo(t)
    return hand.GetOutputPort("state").Eval(context)


def test_hand_switches_to_the_tighter_tendon_at_the_knob_s_end():
    """The knob at the F tendon's end (-1) and asked for more bend: the ``switch`` hand moves the
    knob to the D tendon (to its end, +1, with curves alike; to the same bend with ``f_over_d``)
    and turns the handle half a turn towards neutral (from +60 deg to -120 deg), 2 s at 90 deg/s
    and the knob's 2 of travel at 1 per s, taking no command meanwhile; without the knob-end switch, or with the ``keep`` hand, the knob stays at its end
    and the handle where it was."""
    start = [0.0, np.radians(60.0), -1.0, 0.0, 0.0, 0.0, 0.0]
    p = HandParams(strategy="switch")
    halfway = _hand([0.0, -1.0, 0.0], p, 1.0, start)  # 20 updates: half of each travel
    assert halfway[3] == 1.0 and halfway[2] == pytest.approx(0.0, abs=1e-9)
    assert halfway[1] == pytest.approx(np.radians(60.0 - 90.0))
    state = _hand([0.0, -1.0, 0.0], p, 2.0, start)  # 40 updates: the switch's end
    assert state[6] == 1.0 and state[3] == 0.0 and state[2] == pytest.approx(1.0)
    assert state[1] == pytest.approx(np.radians(60.0 - 180.0))
    # Knowing its handle's curves (F 120 deg, D 180 deg at full knob), the hand keeps the bend: the
    # F tendon's full 120 deg is two thirds of the D tendon's travel.
    kept_bend = _hand([0.0, -1.0, 0.0], HandParams(strategy="switch", f_over_d=120.0 / 180.0), 2.0, start)
    assert kept_bend[6] == 1.0 and kept_bend[2] == pytest.approx(2.0 / 3.0)
    for other in (HandParams(strategy="switch", knob_end_switch=False), HandParams(strategy="keep")):
        kept = _hand([0.0, -1.0, 0.0], other, 2.0, start)
        assert kept[6] == 0.0 and kept[2] == -1.0 and kept[1] == pytest.approx(np.radians(60.0))


@pytest.mark.slow
def test_manual_right_ring_touches_more_than_the_fixed_prior_operator():
    """The manual catheter's right ring, operator seed 0: before the feeder learning, the burst the
    other way and the bend-keeping tendon switches the operator touched 7 of the 18 targets (seeds
    0, 1, 2: 7 each, right_3 to right_9); with them 11 (seeds 0, 1, 2: 11, 8, 11, measured; the
    misses right_12 to right_18, three out of the catheter's reach, four only with a 100-120 mm
    loop). The floor, 10, leaves one target of margin: the run is deterministic for its seed, but
    a touch decided within one look may go the other way on another machine's floating point;
    10 is still above every seed's count before."""
    from ballchain.experiments import manual_catheter as mc

    r = mc.run(task="right", seed=0, sheath="fixed", catheter=mc.comparison_catheter())  # the fixed arm
    touched = sum(row["touched"] for row in r.rows)
    assert touched >= 10, [(row["target"], row["touched"], row["reason"]) for row in r.rows]


@pytest.mark.slow
def test_the_comparison_s_manual_arm_touches_17_of_the_right_ring():
    """Issue 45's bar with the comparison's manual arm (``manual_catheter.run``'s defaults: the
    steerable sheath on the 0.14 N/mm wall): at least 17 of the right ring's 18 on seed 0 (17
    measured on seeds 0-4; right_16 is out of the catheter's reach, docs/guide/manual_catheter.md),
    every touch within the 0.39 N excessive-force limit of Matsuda et al. but for the ones listed
    in the guide (none on this seed)."""
    from ballchain.experiments import manual_catheter as mc

    r = mc.run(task="right", seed=0)
    touched = [row["target"] for row in r.rows if row["touched"]]
    assert len(touched) >= 17 and r.settings["sheath"].startswith("steerable"), r.summary
    assert max(total for total, _ in r.settings["touch_wall_force_N"].values()) <= 0.39


def test_the_hand_s_rates_and_the_curve_name_their_sources():
    """Each of the hand's rates and the D-F curve says where it comes from, in the docstrings and
    in the guide's table (a source, or the sweep that sized it)."""
    from pathlib import Path

    from ballchain.drake_models import steerable_catheter

    hand = " ".join(HandParams.__doc__.split())
    assert "2-20 mm/s" in hand and "Palmer" in hand and "sensitivity sweep" in hand
    curve = " ".join(steerable_catheter.__doc__.split())
    assert "PMC4209906" in curve and "No curve chart" in curve
    page = (Path(__file__).parents[1] / "docs" / "guide" / "manual_catheter.md").read_text()
    sources = page.split("## Where each constant comes from")[1].split("\n## ")[0]
    rows = {line.split("|")[1].strip(): line for line in sources.splitlines() if line.startswith("| ")}
    for name in ("push speed", "twist rate", "knob rate", "D-F curve", "operator's least length out"):
        assert name in rows and len(rows[name].split("|")[3].strip()) > 20, name
