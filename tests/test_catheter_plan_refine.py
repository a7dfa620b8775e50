"""The steerable sheath's plan refined locally and checked with the rod's statics, and the hand
that dials the plan's curve (issue 45, H12: right_17 and right_1)."""

import math

import numpy as np
import pytest

from ballchain.drake_models.electrode import CATHETER_ELECTRODE_LENGTH, axis_start
from ballchain.experiments import manual_catheter as mc
from ballchain.systems.manual_hand import DIAL_PUSH_TOLERANCE, DIAL_TOLERANCE, HandParams, ManualHand
from ballchain.systems.rod_wall_compliance import CompliantRodStatics
from ballchain.systems.sheath_plan import REFINE_ADVANCE, REFINE_ROTATION, SheathPlan
from ballchain.systems.target_contact import targets_touched

from sheath_world import sheath_world  # noqa: E402

LIMIT = 40e-3 * 9.80665  # [N] 40 gf, the plan's force limit


@pytest.fixture(scope="module")
def world():
    w = sheath_world()
    heart, sdf, sheath, p_S, R_S, names, p_WT, n_W, radius, cat = (
        w[k] for k in ("heart", "sdf", "sheath", "p_S", "R_S", "names", "p_WT", "n_W", "radius", "cat"))
    plan = SheathPlan(sheath, cat, p_S, R_S, sdf, radius, min_out=6e-3)
    return heart, sdf, sheath, p_S, R_S, names, p_WT, n_W, radius, cat, plan


def _target(world, name):
    names, p_WT, n_W = world[5], world[6], world[7]
    k = names.index(name)
    return p_WT[k], n_W[k]


def test_refinement_finds_right_17_near_the_coarse_setting_and_the_rod_touches_it(world):
    """right_17 (compliant wall, 0.14 N/mm): the coarse plan's shapes miss it by more than half a
    mm; the refinement, within one coarse step of the coarse setting, gives a curve whose rod
    (its statics against the wall) touches it within 40 gf. Solved again independently (a fresh
    rod, pushed out in 1 mm steps instead of 3), the electrode still touches."""
    heart, sdf, sheath, p_S, R_S, names, p_WT, n_W, radius, cat, plan = world
    p_T, n_T = _target(world, "right_17")
    coarse = plan._coarse(p_T, n_T)
    assert plan.miss(coarse, p_T, n_T) > 0.5e-3
    miss, setting, out, knob, twist = plan.refine(coarse, p_T, n_T)
    assert miss == 0.0 and setting == plan.plan(p_T, n_T)
    assert plan.approach(p_T, n_T) == pytest.approx((out, knob, twist), abs=1e-12)
    assert abs(setting[1] - coarse[1]) <= REFINE_ROTATION[0] * REFINE_ROTATION[1] + 1e-9
    assert abs(setting[0] - coarse[0]) <= REFINE_ADVANCE[0] * REFINE_ADVANCE[1] + 0.25e-3  # (the wall's bisection)
    rod_miss, force = plan.rod_miss(setting, out, knob, twist, p_T, n_T)
    assert rod_miss == 0.0 and force <= LIMIT
    rod = CompliantRodStatics(cat, heart.p_HE, heart.sheath_axis_H, sdf)
    rod.p_E, rod.R_E, _ = sheath.exit_pose(p_S, R_S, *setting)
    q = None
    for length in np.append(np.arange(6e-3, out - 1e-9, 1e-3), out):
        sol = rod.solve(float(length), twist, cat.curvature(knob), q0=q)
        assert sol.converged
        q = sol.q
    c, d = sol.pose.tip_centre, sol.pose.tip_direction
    assert targets_touched(c, p_T[None], n_T[None], cat.radius, radius,
                           axis_start=axis_start(c, d, cat.radius, CATHETER_ELECTRODE_LENGTH))[0]
    assert float(sol.wall_forces.sum()) <= LIMIT


def test_refinement_leaves_right_16_out_of_reach(world):
    """right_16 stays out of reach (the finding): the refined curve's rod misses it by more than
    half a mm within 40 gf."""
    p_T, n_T = _target(world, "right_16")
    plan = world[-1]
    miss, setting, out, knob, twist = plan.refine(plan._coarse(p_T, n_T), p_T, n_T)
    assert 0.5e-3 < miss < 1e-3
    assert plan.rod_miss(setting, out, knob, twist, p_T, n_T)[0] == pytest.approx(miss, abs=1e-12)


def test_the_hand_dials_only_where_the_kept_sheath_s_coarse_curves_miss(world):
    plan = world[-1]
    right_1, right_3, right_17 = (_target(world, n) for n in ("right_1", "right_3", "right_17"))
    assert plan.plan(*right_1) == plan.nominal and plan.miss(plan.nominal, *right_1) > 0.0
    assert plan.dials(*right_1)
    out, knob, twist = plan.approach(*right_1)
    assert plan.rod_miss(plan.nominal, out, knob, twist, *right_1)[0] == 0.0
    assert plan.miss(plan.nominal, *right_3) == 0.0 and not plan.dials(*right_3)  # the coarse curves touch
    assert not plan.dials(*right_17)  # a moved sheath: the re-approach, not a dial


class _DialPlan:
    nominal = (3.5e-3, 0.0, 0.0)

    def __init__(self, out, knob, twist):
        self.curve = (out, knob, twist)

    def plan(self, p_T, n_T):
        return self.nominal

    def approach(self, p_T, n_T):
        return self.curve

    def dials(self, p_T, n_T):
        return True


def _dial(out, twist, exit_of, length_of, steps=200):
    """The hand with a plan that dials (out, knob 0.6, twist): each period the catheter's exit
    twist ``exit_of(handle twist)`` and its length out ``length_of(handle push)``; returns the
    hold flags and the last state."""
    hand = ManualHand(HandParams(), _DialPlan(out, 0.6, twist), initial_length=20e-3)
    ctx = hand.CreateDefaultContext()
    hand.GetInputPort("joystick").FixValue(ctx, [0.0, 0.0, 0.0])
    hand.GetInputPort("v_insert_cmd").FixValue(ctx, [0.0])
    hand.GetInputPort("handle_load").FixValue(ctx, [0.0, 0.0])
    hand.GetInputPort("target").FixValue(ctx, [0.01, 0.0, 0.0, 0.0, 0.0, 1.0])
    held = []
    for _ in range(steps):
        x = ctx.get_discrete_state(0).get_value()
        hand.GetInputPort("windup").FixValue(ctx, [x[1], exit_of(x[1]), 0.0])
        hand.GetInputPort("length_out").FixValue(ctx, [length_of(x[0])])
        ctx.SetDiscreteState(0, hand.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector().CopyToVector())
        held.append(hand.GetOutputPort("hold").Eval(ctx)[0])
    return np.array(held), ctx.get_discrete_state(0).get_value().copy()


def test_the_dial_takes_up_the_windup_and_the_push_chain_s_lag():
    """The sheath stays; the hand turns the handle until the exit's twist is the plan's (the
    exit lagging the handle by 0.4 rad) and pushes until the catheter is out as far as the plan
    says (the exit 0.7 mm behind the handle's push), then lets the operator steer."""
    lag, slack = 0.4, 0.7e-3
    held, x = _dial(31.5e-3, 2.0, lambda h: h - lag, lambda push: 20e-3 + push - slack)
    first_free = int(np.argmin(held))
    assert held[:first_free].all() and not held[first_free:].any() and first_free > 0
    assert abs(x[1] - lag - 2.0) <= DIAL_TOLERANCE
    assert abs(20e-3 + x[0] - slack - 31.5e-3) <= DIAL_PUSH_TOLERANCE
    assert x[2] == pytest.approx(0.6)
    # As if no windup (the exit following the handle): the handle at the plan's twist.
    held, x = _dial(31.5e-3, 2.0, lambda h: h, lambda push: 20e-3 + push)
    assert abs(x[1] - 2.0) <= DIAL_TOLERANCE and not held[-1]


def test_the_dial_stops_where_the_exit_does_not_follow_or_the_catheter_cannot_go():
    """An exit held by the shaft's friction: the handle stops a quarter turn past the plan's
    twist. A plan asking for less catheter than the hand's shortest out of an exit whose push
    lags: the hand stops at its shortest (no endless hold)."""
    held, x = _dial(31.5e-3, 1.0, lambda h: 0.0, lambda push: 20e-3 + push)
    step = HandParams().twist_rate * HandParams().period
    assert not held[-1] and 1.0 + math.pi / 2 <= x[1] < 1.0 + math.pi / 2 + step
    held, x = _dial(5e-3, 0.0, lambda h: h, lambda push: 20e-3 + push + 0.7e-3)
    assert not held[-1] and x[0] == pytest.approx(HandParams().sheath_retract_out - 20e-3, abs=1e-12)


def test_a_moved_sheath_whose_unloaded_curve_touches_but_whose_rod_misses_is_refined(world):
    """At 0.1 N/mm right_15's coarse unloaded curve touches it while the rod of that curve, on the
    wall, misses: the plan refines it (the rod's miss the trigger) and the refined curve's rod
    touches within 40 gf."""
    heart, sdf, sheath, p_S, R_S, names, p_WT, n_W, radius = world[:9]
    plan = SheathPlan(sheath, mc.comparison_catheter(None, 100.0), p_S, R_S, sdf, radius, min_out=6e-3)
    p_T, n_T = _target(world, "right_15")
    coarse = plan._coarse(p_T, n_T)
    assert coarse != plan.nominal and plan.miss(coarse, p_T, n_T) == 0.0
    _, out, knob, twist = plan._best_shape(coarse, p_T, n_T)
    assert plan.rod_miss(coarse, max(out, 6e-3), knob, twist, p_T, n_T)[0] > 0.0
    miss, setting, out, knob, twist = plan.refine(coarse, p_T, n_T)
    assert miss == 0.0 and plan.plan(p_T, n_T) == setting
    rod_miss, force = plan.rod_miss(setting, out, knob, twist, p_T, n_T)
    assert rod_miss == 0.0 and force <= LIMIT
