"""The manual arm's steerable sheath in the atrium (issue 45): the plan leaves the catheter room
(no rod driven into the wall by a curling sheath), the hand re-approaches as far as the plan's
curves say, and the operator waits and learns again while its other hand moves the sheath."""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import BasicVector, DiagramBuilder, LeafSystem

from ballchain.drake_models.sheath import SteerableSheath
from ballchain.experiments import manual_catheter as mc
from ballchain.optimization.rod_statics import RodStatics
from ballchain.systems.catheter_station import HandParams, ManualHand, SteerableCatheterSystem
from ballchain.systems.sheath_plan import SheathPlan
from ballchain.systems.simulated_operator import OperatorParams, SimulatedOperator
from ballchain.systems.target_contact import heart_targets
from tests.test_teleop import FakeTip

INSIDE = [f"right_{k}" for k in range(12, 19)]  # the targets inside the fixed sheath's curves' circle


@pytest.fixture(scope="module")
def setup():
    from ballchain.drake_models.atrium_sdf import atrium_sdf
    from ballchain.systems.station import atrium_for

    heart = atrium_for(mc.scenario_for())
    sdf = atrium_sdf(heart)
    cat = mc.comparison_catheter()
    system = SteerableCatheterSystem(cat, heart.p_HE, heart.sheath_axis_H, sdf, 20e-3, sheath=SteerableSheath())
    return heart, sdf, cat, system


def _shortest_rod_wall_force(setup, setting, out):
    """The wall's largest force on the catheter's rod ``out`` of the sheath at ``setting``,
    straight (no twist, no knob), solved from the straight rod [N]."""
    heart, sdf, cat, system = setup
    p, R, _ = SteerableSheath().exit_pose(*system.septum, *setting)
    rod = RodStatics(cat, p, R[:, 2], sdf)
    rod.R_E = R
    sol = rod.solve(out, 0.0, 0.0)
    return float(sol.wall_forces.max()) if len(sol.wall_forces) else 0.0


@pytest.mark.parametrize("names", [pytest.param(INSIDE[:1], id="right_12"),
                                   pytest.param(INSIDE, id="all", marks=pytest.mark.slow)])
def test_planned_sheath_leaves_the_shortest_catheter_off_the_wall(setup, names):
    """For the targets the fixed sheath's curves miss the plan curls the sheath (180 degrees), and
    the catheter's shortest (the hand's pull-back, 6 mm) on the planned exit stays off the wall
    (no force). Without the room check (``min_out`` 0) a planned exit puts it on the wall with
    more than 1 N: the cause of the steerable runs' 6-27 N. (All seven in the full suite: since
    the plan refines missed targets with the rod's statics, 20 s; right_12 alone in the quick
    tier, 0.8 s, whose bare plan leaves room too: the bare plans of right_13 and 15-17 press
    the wall with 26-52 N.)"""
    heart, sdf, cat, system = setup
    targets, p_WT, n_W, radius = heart_targets(heart)
    hand = HandParams()
    plan = SheathPlan(SteerableSheath(), cat, *system.septum, sdf, radius, min_out=hand.sheath_retract_out)
    bare = SheathPlan(SteerableSheath(), cat, *system.septum, sdf, radius, min_out=0.0)
    worst_bare = 0.0
    for name in names:
        k = targets.index(name)
        setting = plan.plan(p_WT[k], n_W[k])
        assert setting[2] > 0.5 * math.pi, (name, setting)  # curled back
        assert _shortest_rod_wall_force(setup, setting, hand.sheath_retract_out) == 0.0, (name, setting)
        # The re-approach: a few mm to a couple of cm, not the 20-60 mm the fixed exit needed.
        assert 5e-3 <= plan.approach(p_WT[k], n_W[k])[0] <= 20e-3
        worst_bare = max(worst_bare, _shortest_rod_wall_force(setup, bare.plan(p_WT[k], n_W[k]),
                                                              hand.sheath_retract_out))
    assert worst_bare > 1.0 or names == INSIDE[:1]


class _Plan:
    nominal = (3.5e-3, 0.0, 0.0)

    def __init__(self, goal, out):
        self.goal, self.out = goal, out

    def plan(self, p_T, n_T):
        return self.goal

    def approach(self, p_T, n_T):
        return self.out, 0.5, 1.0  # push out, knob, twist


def test_hand_re_approaches_as_far_as_the_plan_says_and_reports_its_hold():
    params = HandParams()
    hand = ManualHand(params, _Plan((15e-3, 0.5, math.pi), 9e-3), initial_length=20e-3)
    ctx = hand.CreateDefaultContext()
    hand.GetInputPort("joystick").FixValue(ctx, [0.0, 0.0, 0.0])
    hand.GetInputPort("v_insert_cmd").FixValue(ctx, [0.02])  # the operator would push: the hand holds
    hand.GetInputPort("handle_load").FixValue(ctx, [0.0, 0.0])
    hand.GetInputPort("target").FixValue(ctx, [0.01, 0.0, 0.0, 0.0, 0.0, 1.0])
    ctx.get_mutable_discrete_state(0).get_mutable_value()[2] = -0.8  # the knob bent before
    held, knobs = [], []
    for _ in range(200):
        x = hand.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector().CopyToVector()
        ctx.SetDiscreteState(0, x)
        held.append(hand.GetOutputPort("hold").Eval(ctx).copy())
        knobs.append(hand.GetOutputPort("handle").Eval(ctx)[2])
    held = np.array(held)
    first_free = int(np.argmin(held[:, 0]))
    assert held[:first_free, 0].all() and not held[first_free:, 0].any()
    # Straightened while pulled back (at the knob's rate), then set to the plan's curve.
    pulled = int(np.flatnonzero(held[:, 1] <= held[:, 1].min() + 1e-12)[-1])  # the last look pulled back
    assert knobs[pulled] == 0.0 and knobs[0] == pytest.approx(-0.8 + params.knob_rate * params.period)
    x = ctx.get_discrete_state(0).get_value()
    assert knobs[first_free] == pytest.approx(0.5) and x[1] == pytest.approx(1.0)
    # Held until out again as far as the plan's approach; the readout is the catheter out.
    assert held[first_free, 1] == pytest.approx(9e-3, abs=1e-9)
    assert min(held[:, 1]) == pytest.approx(params.sheath_retract_out, abs=1e-9)
    # The operator's push then moves the catheter again (past the approach).
    assert held[-1, 1] > 20e-3


class _Hold(LeafSystem):
    """hand_hold: (1, out) until ``t_release``, then (0, out)."""

    def __init__(self, t_release, out):
        super().__init__()
        self.t_release, self.out = t_release, out
        self.DeclareVectorOutputPort("hold", BasicVector(2), self._calc)

    def _calc(self, context, output):
        output.SetFromVector([1.0 if context.get_time() < self.t_release else 0.0, self.out])


def _held_operator(t_release, t_end):
    A = np.array([[0.012, 0.0], [0.0, 0.012], [0.0, 0.0]])
    builder = DiagramBuilder()
    tip = builder.AddSystem(FakeTip(np.column_stack([A, np.zeros(3)]), np.zeros(3), p0=np.zeros(3)))
    params = OperatorParams(axes=(0, 1), initial_length=0.05, tremor=0.0)
    op = builder.AddSystem(SimulatedOperator(1, 0, ["fake_1"], [[0.01, 0.01, -0.02]], [[0.0, 0.0, 1.0]], params))
    hold = builder.AddSystem(_Hold(t_release, 0.009))
    builder.Connect(tip.GetOutputPort("body_poses"), op.get_body_poses_input_port())
    builder.Connect(op.GetOutputPort("joystick"), tip.GetInputPort("joystick"))
    builder.Connect(op.GetOutputPort("v_insert_cmd"), tip.GetInputPort("v_insert_cmd"))
    builder.Connect(hold.get_output_port(), op.GetInputPort("hand_hold"))
    sim = Simulator(builder.Build())
    sim.AdvanceTo(t_end)
    ctx = op.GetMyContextFromRoot(sim.get_mutable_context())
    return op, ctx, tip.GetMyContextFromRoot(sim.get_mutable_context())


def test_operator_waits_while_its_other_hand_moves_the_sheath_then_learns_again():
    # Held from the start: after its probing would have ended it has commanded nothing, learned
    # nothing, the tip has not moved.
    op, ctx, tip_ctx = _held_operator(t_release=3.0, t_end=2.9)
    mem = op._memory(ctx)
    assert mem.held and not mem.J.any()
    assert np.allclose(tip_ctx.get_discrete_state_vector().get_value(), 0.0)
    assert not op.GetOutputPort("joystick").Eval(ctx).any()
    # Released: it reads the catheter's length from the handle and probes (a fresh estimate).
    op, ctx, _ = _held_operator(t_release=3.0, t_end=3.1)
    mem = op._memory(ctx)
    assert not mem.held and mem.phase == "probe" and mem.length == pytest.approx(0.009)
    # Then it learns the mapping again and steers.
    op, ctx, _ = _held_operator(t_release=1.0, t_end=6.0)
    mem = op._memory(ctx)
    J = op.jacobian_estimate(ctx)
    assert np.allclose(J[:2], [[0.012, 0.0], [0.0, 0.012]], atol=2e-3)
