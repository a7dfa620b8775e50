"""The hand on the manual catheter's handle (the paper's comparison arm, Sec. V-C): ``HandParams``
and ``ManualHand`` (split from ``systems/catheter_station.py`` for its length; the module
docstring there describes the hand's strategy)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import EventStatus, LeafSystem

from ballchain.infrastructure.errors import UserInputError, require_finite_fields
from ballchain.systems.operator_params import CONFUSED_RELEARNS
from ballchain.systems.sheath_plan import REFINE_PUSH, REFINE_TWIST, SheathPlan
from ballchain.systems.sheath_plan_cache import RingSheathPlans
from ballchain.systems.teleoperation import apply_dead_band


STRATEGIES = ("keep", "switch")
# [rad] the re-approach turns the handle until the twist at the exit is within this of the plan's
# (with the windup input; issue 45, H12): half the plan's refined twist step (``sheath_plan.REFINE_TWIST``),
# an assumption (the resolution the plan asks for, not a measured hand's).
DIAL_TOLERANCE = 0.5 * REFINE_TWIST[0]
# [m] and the catheter pushed until it is out of the exit within this of the plan's length (half
# the refined push step, ``sheath_plan.REFINE_PUSH``; an assumption as above), the handle at most
# ``DIAL_PUSH_LEAD`` beyond the plan's push (the push chain's friction takes up a fraction of a mm).
DIAL_PUSH_TOLERANCE = 0.5 * REFINE_PUSH[0]
DIAL_PUSH_LEAD = 5e-3
# The operator's failed attempts on a target (its re-learning wiggles and bursts, ``SimulatedOperator``
# output ``attempts``) after which the hand re-approaches it with the plan's curve, once (issue 45, H14):
# as many as make its record call a miss "confused" (``operator_params.CONFUSED_RELEARNS``); an
# assumption (after three tries of its own a clinician goes back to the curve they know reaches it).
REAPPROACH_ATTEMPTS = CONFUSED_RELEARNS


def _finite(x) -> np.ndarray:
    """A copy of the input ``x`` with NaN as 0 and infinities as the largest floats (``np.nan_to_num``,
    called only when needed: it costs a hundred times the check)."""
    x = np.array(x, dtype=float)
    return x if np.isfinite(x).all() else np.nan_to_num(x)


@dataclass
class HandParams:
    """The hand on the catheter's handle (SI). Human-like rate limits: a steady push of up to
    20 mm/s, a wrist turning the handle at up to 90 deg/s in fine control, the thumb taking the
    knob across its travel in 1 s. No study measuring an electrophysiologist's push, twist or
    knob rates on an ablation catheter was found. Sources and sizing:

    * Push: 20 mm/s is the top of the translation speeds of robotic catheter drivers, which are
      built to move catheters as hands do (2-20 mm/s; the review "Evolution and current state of
      robotic catheters for endovascular surgery: A comprehensive review", Engineering Science
      and Technology, an International Journal, Sep 2024), and well below the hand's mean speed in
      a sheath-and-wire task (electromagnetic tracking of interventional radiologists, Palmer et
      al., J. Vasc. Interv. Radiol. 32:226, 2021: experts 1.1 m of hand path in 11.7 s, about
      94 mm/s): an upper bound only.
    * Twist: 90 deg/s is above the same drivers' rotation speeds (8-20 or 50-70 deg/s, the
      review): an assumption, sized by a sensitivity sweep (``docs/guide/manual_catheter.md``:
      the manual right ring at 60, 90 and 120 deg/s).
    * Knob: its travel in 1 s: an assumption, sized by the same sweep (0.5, 1 and 2 per s); no
      source found.

    The paper's operator times were not used to size any of them.

    Attributes:
        push_speed: [m/s] at full feeder command.
        twist_rate: [rad/s] at full stick on axis 0.
        knob_rate: knob travel per second at full stick on axis 1 (the travel is -1..1).
        dead_band: the stick's dead band (the operator pushes past it).
        torque_threshold: the shaft's torque at the handle, against the turn asked for, at which
            the ``switch`` strategy turns back [N m]: 7.6 mN m, the just-noticeable difference
            in torque of a hand turning a handle between thumb and index finger (12.7 % of a
            60 mN m reference; Jandura and Srinivasan 1994, "Experiments on human performance in
            torque discrimination and control", ASME DSC vol. 55-1, MIT Touch Lab's instrumented
            screwdriver); taken as the rise in resistance a hand notices, an assumption (no
            absolute threshold for torque on a catheter handle was found).
        strategy: "keep" (keep turning) or "switch" (the opposite tendon and back by half a turn).
        knob_end_switch: the ``switch`` hand also switches at the F tendon's end when asked for
            more bend (to the D tendon, the handle half a turn towards neutral).
        f_over_d: the F curve's largest bend over the D curve's (the hand knows its handle's two
            curves): a switch puts the knob where the other tendon gives the same bend.
        period: the hand's update [s].
        sheath_advance_rate, sheath_rotation_rate, sheath_deflection_rate: how fast the other hand
            moves a steerable sheath (advance [m/s], rotation [rad/s], deflection [rad/s]): 10 mm/s,
            90 deg/s (the handle's twist rate) and its knob's travel (half a turn each way) in
            1 s as the catheter's knob: assumptions, no source found.
        sheath_retract_out: how much catheter the hand leaves out of the sheath while it moves
            the sheath (it pulls back first, at ``push_speed``) [m]: the rod's shortest (two of
            its 3 mm segments).
    """

    push_speed: float = 0.02
    twist_rate: float = np.radians(90.0)
    knob_rate: float = 1.0
    dead_band: float = 0.1
    torque_threshold: float = 0.127 * 60e-3
    strategy: str = "switch"
    knob_end_switch: bool = True
    f_over_d: float = 1.0
    period: float = 0.05
    sheath_advance_rate: float = 10e-3
    sheath_rotation_rate: float = np.radians(90.0)
    sheath_deflection_rate: float = np.pi
    sheath_retract_out: float = 6e-3

    def validate(self) -> "HandParams":
        require_finite_fields(self)
        if self.strategy not in STRATEGIES:
            raise UserInputError(f"HandParams.strategy must be one of {STRATEGIES}, got {self.strategy!r}")
        for name in ("push_speed", "twist_rate", "knob_rate", "torque_threshold", "period", "f_over_d",
                     "sheath_advance_rate", "sheath_rotation_rate", "sheath_deflection_rate", "sheath_retract_out"):
            if not getattr(self, name) > 0:
                raise UserInputError(f"HandParams.{name} must be > 0, got {getattr(self, name)}")
        if not 0.0 <= self.dead_band < 1.0:
            raise UserInputError(f"HandParams.dead_band must be in [0, 1), got {self.dead_band}")
        return self


def _sheath_delta(sheath: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """The sheath's move to its goal (advance, rotation the short way round, deflection); a
    straight sheath's rotation does not matter."""
    delta = goal - sheath
    delta[1] = (delta[1] + np.pi) % (2 * np.pi) - np.pi
    if sheath[2] == 0.0 and goal[2] == 0.0:
        delta[1] = 0.0
    return delta


class ManualHand(LeafSystem):
    """The hand on the handle (module docstring).

    Input ports: joystick (3: axis 0 turns the handle, axis 1 the knob), v_insert_cmd (1) [m/s],
    handle_load (2: the shaft's torque [N m] and axial force [N] at the handle, the catheter's;
    unconnected: nothing felt).
    Output ports: handle (3: push past the start [m], twist [rad], knob in [-1, 1]),
    switches (1: tendon switches so far); with a sheath plan also sheath (3) and hold (2:
    ``_calc_hold``).
    State (discrete, 7; 22 with a sheath plan): push, twist, knob, switching (0/1), the switch's
    target twist and knob, switches; the sheath's setting (advance [m], rotation, deflection
    [rad]) and its goal, the target (3), the re-approach's push and whether a pull-back is under
    way, the plan's re-approach for the target (``SheathPlan.approach``: push, knob, handle twist),
    whether the hand has re-approached the target (the sheath moved, the plan dialled, or the
    operator lost: ``REAPPROACH_ATTEMPTS``).

    With a ``SheathPlan`` (a steerable sheath, issue 45; or ``sheath_plan_cache.RingSheathPlans``,
    its answers for a ring's targets computed once and kept on disk, H13) it also has an input ``target`` (6: the
    operator's target centre and wall normal, what the operator sees) and an output ``sheath``
    (3: the sheath's setting): on each new target it plans the sheath's setting (``SheathPlan``:
    straight, the fixed sheath's exit, when the catheter's shapes reach the target from there)
    and, when that differs from the sheath's, pulls the catheter back to ``sheath_retract_out``,
    moves the sheath at its rates (``HandParams.sheath_*_rate``), then turns the handle and the
    knob to the plan's curve for the target and pushes the catheter out as far as it says
    (``SheathPlan.approach``: pull back and re-approach; pushing it out as far as it was before
    drove the rod into the wall facing a curled sheath's exit; the handle is set as if the shaft
    had no windup: the operator corrects the rest), holding the handle's twist and knob meanwhile (the clinician's other
    hand on the sheath); the operator's commands wait. With a plan the hand never pulls the tip
    back into the sheath beyond ``sheath_retract_out`` out (the rod's shortest).

    With a plan it also reads the operator's failed attempts on its target (input ``attempts``,
    ``SimulatedOperator``'s; unconnected: none): once they reach ``REAPPROACH_ATTEMPTS`` on a target
    the hand has not re-approached yet, it dials the plan's curve for it with the sheath where it is
    (as ``dials``: the twist at the exit and the length out closed on what fluoroscopy shows), the
    operator waiting (issue 45, H14: left_1 and right_7, where the operator's local map had no way
    to the target: a straight catheter's twist, a twist inside the shaft's friction).
    """

    def __init__(self, params: HandParams | None = None, plan: SheathPlan | RingSheathPlans | None = None,
                 initial_length: float = 20e-3) -> None:
        super().__init__()
        self.params = p = (params or HandParams()).validate()
        self.plan, self.initial_length = plan, float(initial_length)
        self.set_name("hand")
        self._joystick = self.DeclareVectorInputPort("joystick", 3)
        self._push = self.DeclareVectorInputPort("v_insert_cmd", 1)
        self._feel = self.DeclareVectorInputPort("handle_load", 2)
        start = np.zeros(7 if plan is None else 22)
        if plan is not None:
            start[7:10] = start[10:13] = plan.nominal
            start[13:16] = np.nan  # no target planned yet
            start[18] = np.nan  # no re-approach planned yet
            self._target = self.DeclareVectorInputPort("target", 6)
            self._windup = self.DeclareVectorInputPort("windup", 3)
            self._length_out = self.DeclareVectorInputPort("length_out", 1)
            self._attempts = self.DeclareVectorInputPort("attempts", 1)
            self.DeclareVectorOutputPort("sheath", 3, self._calc_sheath, prerequisites_of_calc={self.xd_ticket()})
            self.DeclareVectorOutputPort("hold", 2, self._calc_hold, prerequisites_of_calc={self.xd_ticket()})
        self._state = self.DeclareDiscreteState(start)
        self.DeclareStateOutputPort("state", self._state)
        self.DeclareVectorOutputPort("handle", 3, self._calc_handle, prerequisites_of_calc={self.xd_ticket()})
        self.DeclareVectorOutputPort("switches", 1, self._calc_switches, prerequisites_of_calc={self.xd_ticket()})
        self.DeclarePeriodicDiscreteUpdateEvent(p.period, 0.0, self._update)

    def _calc_handle(self, context, output):
        output.SetFromVector(context.get_discrete_state(self._state).get_value()[:3])

    def _calc_switches(self, context, output):
        output.SetAtIndex(0, context.get_discrete_state(self._state).get_value()[6])

    def _calc_hold(self, context, output):
        """(1 while the hand pulls back, moves the sheath or re-approaches, else 0; the catheter
        out of the sheath by the handle's readout [m]): what the operator knows its hands do."""
        x = context.get_discrete_state(self._state).get_value()
        moving = bool(x[17]) or bool(np.any(np.abs(_sheath_delta(x[7:10], x[10:13])) > 1e-12))
        output.SetFromVector([float(moving), self.initial_length + x[0]])

    def _calc_sheath(self, context, output):
        output.SetFromVector(context.get_discrete_state(self._state).get_value()[7:10])

    def _move_sheath(self, context, x: np.ndarray) -> bool:
        """The sheath's setting and goal in ``x`` (the state) advanced one period: a new target
        plans a new goal; returns whether the sheath is still moving (the hand holds the catheter)."""
        p, dt = self.params, self.params.period
        if not self._target.HasValue(context):
            return False
        target = _finite(self._target.Eval(context))
        if not np.all(np.abs(target[:3] - x[13:16]) <= 1e-9):  # a new target (also the first: NaN)
            x[10:13], x[13:16] = self.plan.plan(target[:3], target[3:]), target[:3]
            out, x[19], x[20] = self.plan.approach(target[:3], target[3:])
            x[18] = max(out, p.sheath_retract_out) - self.initial_length  # the hand's shortest at least
            moves = bool(np.any(np.abs(_sheath_delta(x[7:10], x[10:13])) > 1e-12))
            x[21] = float(moves)  # a moved sheath is a re-approach (below)
            if not x[17] and not moves and self.plan.dials(target[:3], target[3:]):
                x[16], x[17], x[21] = x[18], 1.0, 1.0  # the sheath stays: the hand dials the plan's curve (H12)
        sheath, goal = x[7:10], x[10:13]
        delta = _sheath_delta(sheath, goal)
        if not np.any(np.abs(delta) > 1e-12):
            if not x[17] and not x[21] and self._lost(context):
                x[16], x[17], x[21] = x[18], 1.0, 1.0  # the operator lost: the plan's curve dialled (H14)
            if x[17]:  # re-approach: the catheter out again, its knob and handle set for the plan's curve
                seen = not np.isnan(x[18]) and self._windup.HasValue(context) and self._length_out.HasValue(context)
                if seen:  # pushed until the catheter is out of the exit as far as the plan's curve (H12)
                    gap = x[18] + self.initial_length - float(_finite(self._length_out.Eval(context))[0])
                    x[0] += float(np.clip(gap, -p.push_speed * dt, p.push_speed * dt))
                    floor = p.sheath_retract_out - self.initial_length  # the hand's shortest (below)
                    pushing = (abs(gap) > DIAL_PUSH_TOLERANCE and abs(x[0] - x[18]) < DIAL_PUSH_LEAD
                               and not (gap < 0 and x[0] <= floor + 1e-12))
                else:
                    x[0] = min(x[0] + p.push_speed * dt, x[16]) if x[0] <= x[16] else max(x[0] - p.push_speed * dt, x[16])
                    pushing = abs(x[0] - x[16]) > 1e-12
                if seen:
                    # The handle turned until the tip's curve points as the plan's (the twist at the
                    # exit, as a clinician sees the curve on fluoroscopy; H12): the windup's lag taken up.
                    exit_twist = float(_finite(self._windup.Eval(context))[1])
                    turn = (x[20] - exit_twist + np.pi) % (2 * np.pi) - np.pi
                    # the handle beyond the plan's twist the way it turns (the exit held by the shaft's
                    # friction): the hand stops a quarter turn past it. Measured from where the exit is
                    # to go (the exit's twist plus the turn, the windup x[1] - exit kept unwrapped), not
                    # the plan's twist wrapped about the handle: that read a turn and windup of more than
                    # half a turn together as a handle already past (H14).
                    lead = np.sign(turn) * (x[1] - exit_twist - turn)
                    if lead < np.pi / 2:
                        x[1] += float(np.clip(turn, -p.twist_rate * dt, p.twist_rate * dt))
                    x[2] += float(np.clip(x[19] - x[2], -p.knob_rate * dt, p.knob_rate * dt))
                    turn = (abs(turn) > DIAL_TOLERANCE and lead < np.pi / 2) or abs(x[19] - x[2]) > 1e-12
                elif not np.isnan(x[18]):
                    turn = (x[20] - x[1] + np.pi) % (2 * np.pi) - np.pi  # the handle the short way round
                    x[1] += float(np.clip(turn, -p.twist_rate * dt, p.twist_rate * dt))
                    x[2] += float(np.clip(x[19] - x[2], -p.knob_rate * dt, p.knob_rate * dt))
                    turn = abs(turn) - p.twist_rate * dt > 1e-12 or abs(x[19] - x[2]) > 1e-12
                else:
                    turn = False
                x[17] = float(pushing or turn)
                return True
            return False
        # Pull back first (the catheter's tip into the sheath's mouth, ``sheath_retract_out`` out),
        # then move the sheath, then push the catheter out again.
        if not x[17]:  # the re-approach's push: as far as the plan's curves say (``SheathPlan.approach``)
            x[16], x[17] = (x[0] if np.isnan(x[18]) else x[18]), 1.0
        # The catheter straightened as it is pulled back (the knob to neutral at its rate): a
        # steerable catheter is not withdrawn into a sheath deflected (the practice its
        # instructions for use state), and it re-approaches straight.
        x[2] = float(np.clip(0.0, x[2] - p.knob_rate * dt, x[2] + p.knob_rate * dt))
        if self.initial_length + x[0] > p.sheath_retract_out + 1e-9 or x[2] != 0.0:
            x[0] = max(x[0] - p.push_speed * dt, p.sheath_retract_out - self.initial_length)
            return True
        rates = np.array([p.sheath_advance_rate, p.sheath_rotation_rate, p.sheath_deflection_rate]) * dt
        # Straight while it advances or turns (the straight sheath stays on its axis, inside the
        # atrium; a deflected one swept about could cross the wall): straighten, advance and
        # turn, then deflect.
        if np.any(np.abs(delta[:2]) > 1e-12):
            delta = np.array([0.0, 0.0, -sheath[2]]) if abs(sheath[2]) > 1e-12 else np.array([delta[0], delta[1], 0.0])
        step = np.clip(delta, -rates, rates)
        x[7:10] = sheath + step
        return True

    def _lost(self, context) -> bool:
        """Whether the operator has failed ``REAPPROACH_ATTEMPTS`` times on its target (input
        ``attempts``; unconnected: never)."""
        return (self._attempts.HasValue(context)
                and float(_finite(self._attempts.Eval(context))[0]) >= REAPPROACH_ATTEMPTS)

    def _other_tendon(self, knob: float) -> float:
        """The knob on the other tendon for the same bend (``f_over_d``: the F curve's largest bend
        over the D curve's), within the knob's travel."""
        ratio = self.params.f_over_d
        return float(np.clip(-knob * (ratio if knob < 0 else 1.0 / ratio), -1.0, 1.0))

    def _update(self, context, discrete_state):
        p = self.params
        x = context.get_discrete_state(self._state).get_value().copy()
        holding = self.plan is not None and not x[3] and self._move_sheath(context, x)
        push, twist, knob, switching, target, goal, switches = x[:7]
        u = apply_dead_band(_finite(self._joystick.Eval(context)), p.dead_band)
        v = float(np.clip(_finite(self._push.Eval(context))[0], -p.push_speed, p.push_speed))
        dt = p.period
        twist_rate, knob_rate = u[0] * p.twist_rate, u[1] * p.knob_rate
        torque = float(_finite(self._feel.Eval(context))[0]) if self._feel.HasValue(context) else 0.0
        if (not switching and p.strategy == "switch" and abs(torque) >= p.torque_threshold
                and twist_rate * torque > 0 and abs(knob) > 0.2):
            # Wound up (felt) and asked to turn further: the other tendon, and back by half a turn.
            switching, target = 1.0, twist - np.sign(twist_rate) * np.pi
            goal, switches = self._other_tendon(knob), switches + 1
        elif (not switching and p.strategy == "switch" and p.knob_end_switch and knob <= -1.0 + 1e-9
              and knob_rate < 0.0):
            # The F tendon at its end and asked for more bend: the D tendon (the tighter curve), the
            # handle turned by half a turn towards neutral (the same bending plane, the other side).
            switching, target = 1.0, twist - (np.pi if twist > 0 else -np.pi)
            goal, switches = self._other_tendon(knob), switches + 1
        if switching:
            v = 0.0
            twist_rate = float(np.clip((target - twist) / dt, -p.twist_rate, p.twist_rate))
            knob_rate = float(np.clip((goal - knob) / dt, -p.knob_rate, p.knob_rate))
            if abs(target - twist - twist_rate * dt) < 1e-9 and abs(goal - knob - knob_rate * dt) < 1e-9:
                switching = 0.0
        if holding:  # the other hand on the sheath: the catheter held
            v = twist_rate = knob_rate = 0.0
        x[:7] = [push + v * dt, twist + twist_rate * dt, float(np.clip(knob + knob_rate * dt, -1.0, 1.0)),
                 switching, target, goal, switches]
        if self.plan is not None:  # the hand keeps the tip out of the sheath (the re-approach's shortest)
            x[0] = max(x[0], p.sheath_retract_out - self.initial_length)
        discrete_state.get_mutable_vector(self._state).SetFromVector(x)
        return EventStatus.Succeeded()
