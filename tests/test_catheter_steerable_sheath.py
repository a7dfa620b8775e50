"""The steerable sheath of the manual arm (issue 45, item 4): its exit's closed-form geometry and
the catheter riding in it (``drake_models.sheath.SteerableSheath``,
``SteerableCatheterSystem(sheath=...)``)."""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from ballchain.drake_models.sheath import SteerableSheath
from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.infrastructure.errors import UserInputError
from ballchain.systems.catheter_station import SteerableCatheterSystem


def test_exit_closed_forms():
    s = SteerableSheath().validate()
    L = s.deflectable_length
    # Full deflection over the whole deflectable length: a half circle, 2 L / pi across, axis reversed.
    p, R, line = s.exit_pose(np.zeros(3), np.eye(3), L, 0.0, math.pi, 400)
    np.testing.assert_allclose(p, [2 * L / math.pi, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(R[:, 2], [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)  # a rotation
    # The centreline keeps its length (an arc, not a jump), within the chord's error at 400 points.
    assert abs(np.linalg.norm(np.diff(line, axis=0), axis=1).sum() - L) < 1e-6
    # A quarter turn rotated by 90 degrees: the bend in the y-z plane, 2 L / pi each way.
    p, R, _ = s.exit_pose(np.zeros(3), np.eye(3), L, math.pi / 2, math.pi / 2)
    np.testing.assert_allclose(p, [0.0, 2 * L / math.pi, 2 * L / math.pi], atol=1e-12)
    np.testing.assert_allclose(R[:, 2], [0.0, 1.0, 0.0], atol=1e-12)
    # Advanced beyond the deflectable length: a straight part, then the arc.
    p, R, _ = SteerableSheath(max_advance=60e-3).exit_pose(np.zeros(3), np.eye(3), L + 5e-3, 0.0, math.pi)
    np.testing.assert_allclose(p, [2 * L / math.pi, 0.0, 5e-3], atol=1e-12)
    # Less out than the deflectable length: only what is out bends.
    p, R, _ = s.exit_pose(np.zeros(3), np.eye(3), 0.5 * L, 0.0, math.pi)
    np.testing.assert_allclose(R[:, 2], [1.0, 0.0, 0.0], atol=1e-12)


def test_bad_sheath_is_refused():
    with pytest.raises(UserInputError, match="max_deflection"):
        SteerableSheath(max_deflection=4.0).validate()
    with pytest.raises(UserInputError, match="nominal_advance"):
        SteerableSheath(nominal_advance=50e-3).validate()
    with pytest.raises(UserInputError, match="sheath"):
        SteerableCatheterSystem(SteerableCatheter(), np.zeros(3), [0.0, 0.0, 1.0], None, sheath="agilis")


def _tip_after(system, handle, sheath=None, t=0.2):
    sim = Simulator(system)
    ctx = sim.get_mutable_context()
    system.GetInputPort("handle").FixValue(ctx, handle)
    if sheath is not None:
        system.GetInputPort("sheath").FixValue(ctx, sheath)
    sim.AdvanceTo(t)
    return system.GetOutputPort("tip_position").Eval(ctx)


def test_catheter_rides_in_the_sheath():
    """In free space the rod's shape relative to its exit does not depend on where the exit is:
    the tip, seen from the deflected sheath's exit in the exit's frame, is where it is from the
    fixed exit (the knob bent, so the check sees the frame's turn too)."""
    cat = SteerableCatheter(shaft_elements=2)
    axis = np.array([0.0, 0.0, 1.0])
    sheath = SteerableSheath()
    fixed = SteerableCatheterSystem(cat, np.zeros(3), axis, None, 30e-3)
    steer = SteerableCatheterSystem(cat, np.zeros(3), axis, None, 30e-3, sheath=sheath)
    handle = [0.0, 0.0, 0.6]
    tip_fixed = _tip_after(fixed, handle)
    # At its nominal advance and no deflection the steerable sheath's exit is the fixed one.
    np.testing.assert_allclose(_tip_after(steer, handle, [sheath.nominal_advance, 0.0, 0.0]), tip_fixed, atol=1e-9)
    state = [25e-3, 0.7, 2.0]
    tip = _tip_after(steer, handle, state)
    p_S = -sheath.nominal_advance * axis
    p, R, _ = sheath.exit_pose(p_S, fixed.rod.R_E, *state)
    np.testing.assert_allclose(steer.rod.p_E, p, atol=1e-12)
    np.testing.assert_allclose(steer.rod.R_E, R, atol=1e-12)
    seen_fixed = fixed.rod.R_E.T @ tip_fixed
    seen_steer = R.T @ (tip - p)
    np.testing.assert_allclose(seen_steer, seen_fixed, atol=1e-6)
    assert np.linalg.norm(tip - tip_fixed) > 10e-3  # the sheath moved the tip


class _Plan:
    """A plan stub: one setting for any target."""

    nominal = (3.5e-3, 0.0, 0.0)

    def __init__(self, goal, out=20e-3):
        self.goal, self.calls, self.out = goal, 0, out

    def plan(self, p_T, n_T):
        self.calls += 1
        return self.goal

    def approach(self, p_T, n_T):
        return self.out, 0.0, 0.0


def test_hand_pulls_back_then_moves_the_sheath_at_its_rates():
    from ballchain.systems.catheter_station import HandParams, ManualHand

    params = HandParams()
    goal = (20e-3, 1.0, math.pi)
    plan = _Plan(goal)
    hand = ManualHand(params, plan, initial_length=20e-3)
    ctx = hand.CreateDefaultContext()
    hand.GetInputPort("joystick").FixValue(ctx, [1.0, 1.0, 0.0])  # the operator asks for a turn and a bend
    hand.GetInputPort("v_insert_cmd").FixValue(ctx, [0.02])
    hand.GetInputPort("handle_load").FixValue(ctx, [0.0, 0.0])
    hand.GetInputPort("target").FixValue(ctx, [0.01, 0.0, 0.0, 0.0, 0.0, 1.0])
    dt = params.period
    pulled_steps = round((20e-3 - params.sheath_retract_out) / (params.push_speed * dt))
    for _ in range(pulled_steps):
        x = hand.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector().CopyToVector()
        ctx.SetDiscreteState(0, x)
    handle = hand.GetOutputPort("handle").Eval(ctx)
    # Pulled back to sheath_retract_out out, the handle's twist and knob held, the sheath not yet moved.
    assert handle[0] == pytest.approx(params.sheath_retract_out - 20e-3, abs=1e-9)
    assert handle[1] == 0.0 and handle[2] == 0.0
    np.testing.assert_allclose(hand.GetOutputPort("sheath").Eval(ctx), plan.nominal, atol=1e-12)
    # Then the sheath, straight while it advances and turns, then deflected.
    straight = int(np.ceil(max((goal[0] - 3.5e-3) / params.sheath_advance_rate,
                               goal[1] / params.sheath_rotation_rate) / dt - 1e-9))
    bend = int(np.ceil(goal[2] / params.sheath_deflection_rate / dt - 1e-9))
    for k in range(straight + bend):
        x = hand.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector().CopyToVector()
        ctx.SetDiscreteState(0, x)
        if k == 0:
            np.testing.assert_allclose(x[7:10] - plan.nominal, [params.sheath_advance_rate * dt,
                                       params.sheath_rotation_rate * dt, 0.0], atol=1e-12)
        if k == straight - 1:
            np.testing.assert_allclose(x[7:10], [goal[0], goal[1], 0.0], atol=1e-12)
    np.testing.assert_allclose(hand.GetOutputPort("sheath").Eval(ctx), goal, atol=1e-12)
    assert plan.calls == 1  # planned once per target
    # Re-approach: the catheter pushed out as far as the plan's approach (here as far as it was),
    # the operator still waiting.
    for _ in range(pulled_steps):
        x = hand.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector().CopyToVector()
        ctx.SetDiscreteState(0, x)
    assert x[0] == pytest.approx(0.0, abs=1e-9) and x[1] == 0.0 and not x[17]
    # The sheath stands: the operator's commands move the catheter again.
    before = hand.GetOutputPort("handle").Eval(ctx).copy()
    x = hand.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector().CopyToVector()
    assert x[0] > before[0] and x[1] > before[1]


def test_sheath_plan_keeps_the_straight_sheath_when_it_reaches_and_curls_it_when_not():
    from ballchain.systems.catheter_station import SheathPlan

    cat, sheath = SteerableCatheter(), SteerableSheath()
    plan = SheathPlan(sheath, cat, np.zeros(3), np.eye(3), None, 2e-3)  # free space, the septum at 0
    ahead = np.array([0.0, 0.0, 60e-3])
    assert plan.plan(ahead, [0.0, 0.0, -1.0]) == plan.nominal
    assert plan.miss(plan.nominal, ahead, np.array([0.0, 0.0, -1.0])) == 0.0
    # Beside the septum, facing into the atrium: the straight sheath's curves cannot press on it
    # (the catheter's D curve is a half turn, 35 mm across: it would have to come back past the exit).
    behind, normal = np.array([20e-3, 0.0, 2e-3]), np.array([0.0, 0.0, 1.0])
    straight = plan.miss(plan.nominal, behind, normal)
    assert straight > 1e-3
    setting = plan.plan(behind, normal)
    assert setting != plan.nominal and abs(setting[2]) > np.radians(90.0)
    assert plan.miss(setting, behind, normal) < 0.5 * straight  # closer, though its first 12 need not touch


# (the coupled twist solved to its balance, 2.5 CPU-s: the full suite)
@pytest.mark.slow
def test_exit_twist_balances_the_rods_torque_where_the_alternating_coupling_runs_away():
    """Issue 45: seed 0's right ring stopped with the sheath curled (advance 20 mm, rotation
    120 deg, deflection 180 deg), the knob at full D, the handle at -256 deg and the catheter
    pushed out from 6.7 mm: the rod, pressed on the wall, loads the shaft's twist with a torque
    over ten times what the shaft's friction holds. Alternating the twist chain and the rod (the
    fixed sheath's coupling) sends the exit twist round by turns (HEAD's runs: -229, -989, -1239
    deg); ``coupled_twist`` finds the exit twist where the chain's exit node under the rod's
    torque is the exit twist, and each chain node's elastic torque balances its load within what
    its friction holds."""
    from ballchain.drake_models.atrium_sdf import atrium_sdf
    from ballchain.experiments import manual_catheter as mc
    from ballchain.systems.station import atrium_for

    heart = atrium_for(mc.scenario_for())
    s = SteerableCatheterSystem(SteerableCatheter(), heart.p_HE, heart.sheath_axis_H, atrium_sdf(heart), 20e-3,
                                sheath=SteerableSheath())
    s.place_sheath(20e-3, 2 * math.pi / 3, math.pi)
    kappa, chain, handle = s.catheter.curvature(1.0), s._twist_chain, math.radians(-256.0)
    x, q = chain.initial(), np.zeros(0)
    for h in np.radians(np.linspace(0.0, -256.0, 58)):  # the handle turned with 6.7 mm out, the rod free
        x, _, sol = s.coupled_twist(x, h, None, 6.7e-3, kappa, q, [])
        q = sol.q
    xa, qa, torque = x.copy(), q.copy(), sol.base_torque
    alternating, failures = [], []
    for length in np.arange(7.7e-3, 16e-3, 1e-3):  # pushed out 1 mm per update (20 mm/s)
        for _ in range(2):  # HEAD's alternating coupling
            xa, _ = chain.step(xa, handle, torque)
            rod = s.rod.solve(length, xa[-1], kappa, q0=qa)
            qa, torque = rod.q, rod.base_torque
        alternating.append(math.degrees(xa[-1]))
        x, _, sol = s.coupled_twist(x, handle, None, length, kappa, q, failures)
        q = sol.q
        assert sol.converged
        # The fixed point: the chain under the rod's torque at x[-1] ends at x[-1].
        again, _ = chain.step(x, handle, sol.base_torque)
        assert abs(again[-1] - x[-1]) < 1e-6
        # Every chain node balanced within its static friction (the last one under the rod's torque).
        assert np.all(np.abs(chain.net_loads(x, sol.base_torque)) <= chain.static * (1 + 1e-9))
    assert not failures
    assert max(abs(a) for a in alternating) > 700.0  # the runaway reproduced
    assert abs(sol.base_torque) > 10 * chain.static  # the rod's torque is far above the friction
    assert -400.0 < math.degrees(x[-1]) < -256.0  # the exit ahead of the handle, less than half a turn


def test_unloaded_shape_ends_at_the_rods_free_tip():
    """The plan's unloaded shape (``SteerableCatheter.unloaded_shape``) ends where the rod's
    statics in free space put the tip sphere's centre (a radius short of the rod's end), within
    0.1 mm over pushes and knobs (the shape ended 1.3 mm beyond it before)."""
    from ballchain.optimization.rod_statics import RodStatics

    cat = SteerableCatheter().validate()
    rod = RodStatics(cat, np.zeros(3), [0.0, 0.0, 1.0], None)
    for out in (9e-3, 21e-3, 45e-3, 100e-3):
        for knob in (1.0, -0.5, 0.0):
            tip = rod.solve(out, 0.0, cat.curvature(knob)).pose.tip_centre
            shape = rod.R_E @ cat.unloaded_shape(out, knob)[-1]
            assert np.linalg.norm(tip - shape) < 0.1e-3, (out, knob)
