"""The manual arm of the paper's comparison (Sec. V-C): a steerable catheter in the atrium and a
hand on its handle, the systems of its device model (``catheter_model.CatheterModel``).

``MakeStation`` builds them for a scenario with ``device: steerable_catheter`` into the same
station as the ball chain's: the same atrium, the same sheath exit and axis, the same target
rings and ``TargetTouchTracker``, the same ``add_systems`` hook for an operator and the same run
loop, with the catheter instead of the chain and the hand instead of the units:

* ``SteerableCatheterSystem``: the catheter's quasi-static state, advanced every ``period`` from
  the handle's position (the push past the start [m], the handle's twist [rad], the knob in
  [-1, 1]): the shaft's friction chains in the sheath (``drake_models.steerable_catheter``:
  stick-slip in twist and in push), then the distal rod's equilibrium in the atrium
  (``optimization.rod_statics``), warm-started from the last one. Outputs ``body_poses`` (the
  rod's nodes as bodies 1..n + 1, the tip sphere's centre last, for the operator's camera and
  the touch test), ``tip_position`` (3: the tip's end) and ``windup`` (3: the handle's twist,
  the twist at the sheath exit [rad], slips so far).
* ``ManualHand``: the hand on the handle, driven like the robotic console (a stick with a dead
  band and a feeder command, so that the same ``SimulatedOperator`` drives it): stick axis 0 turns
  the handle, axis 1 the knob, the feeder command pushes or pulls, each within a human-like rate
  limit. It feels the shaft's torque at the handle (the catheter's ``handle_load``); when the
  torque it turns against reaches its threshold (``HandParams.torque_threshold``, a human
  parameter: the windup the paper describes is felt, not counted in degrees), its strategy is to
  ``keep`` turning or to ``switch``: turn the handle back by half a turn while moving the knob to
  the opposite tendon (the same bend, the other wire), during which it takes no other command. The ``switch`` hand does the same when the
  knob is at the F tendon's end and asked for more bend: the D tendon (the tighter curve) and the
  handle half a turn towards neutral.

Exported inputs (when the hook leaves them unconnected): ``hand.joystick`` (3),
``feeder.v_insert_cmd`` (1) (the hand's push: the station's names for every device).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.geometry import Rgba, Sphere
from pydrake.systems.framework import EventStatus, LeafSystem

from ballchain.infrastructure.errors import UserInputError, require_finite_fields
from ballchain.drake_models.sheath import SteerableSheath
from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.infrastructure.arg_checks import require_type
from ballchain.optimization.rod_statics import RodStatics
from ballchain.systems.meshcat_view import frame_scene
from ballchain.systems.sheath_plan import SheathPlan
from ballchain.systems.teleoperation import apply_dead_band

STRATEGIES = ("keep", "switch")


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


SHEATH_SUBSTEP = 1.0  # [deg or mm] the largest move of a steerable sheath between the rod's solves


class ManualHand(LeafSystem):
    """The hand on the handle (module docstring).

    Input ports: joystick (3: axis 0 turns the handle, axis 1 the knob), v_insert_cmd (1) [m/s],
    handle_load (2: the shaft's torque [N m] and axial force [N] at the handle, the catheter's;
    unconnected: nothing felt).
    Output ports: handle (3: push past the start [m], twist [rad], knob in [-1, 1]),
    switches (1: tendon switches so far).
    State (discrete, 7; 18 with a sheath plan): push, twist, knob, switching (0/1), the switch's
    target twist and knob, switches; the sheath's setting (advance [m], rotation, deflection
    [rad]) and its goal, the target (3), the push before a pull-back and whether one is under way.

    With a ``SheathPlan`` (a steerable sheath, issue 45) it also has an input ``target`` (6: the
    operator's target centre and wall normal, what the operator sees) and an output ``sheath``
    (3: the sheath's setting): on each new target it plans the sheath's setting (``SheathPlan``:
    straight, the fixed sheath's exit, when the catheter's shapes reach the target from there)
    and, when that differs from the sheath's, pulls the catheter back to ``sheath_retract_out``,
    moves the sheath at its rates (``HandParams.sheath_*_rate``) and pushes the catheter out as
    far as it was (pull back and re-approach), holding the handle's twist and knob meanwhile
    (the clinician's other hand on the sheath); the operator's commands wait.
    """

    def __init__(self, params: HandParams | None = None, plan: SheathPlan | None = None,
                 initial_length: float = 20e-3) -> None:
        super().__init__()
        self.params = p = (params or HandParams()).validate()
        self.plan, self.initial_length = plan, float(initial_length)
        self.set_name("hand")
        self._joystick = self.DeclareVectorInputPort("joystick", 3)
        self._push = self.DeclareVectorInputPort("v_insert_cmd", 1)
        self._feel = self.DeclareVectorInputPort("handle_load", 2)
        start = np.zeros(7 if plan is None else 18)
        if plan is not None:
            start[7:10] = start[10:13] = plan.nominal
            start[13:16] = np.nan  # no target planned yet
            self._target = self.DeclareVectorInputPort("target", 6)
            self.DeclareVectorOutputPort("sheath", 3, self._calc_sheath, prerequisites_of_calc={self.xd_ticket()})
        self._state = self.DeclareDiscreteState(start)
        self.DeclareStateOutputPort("state", self._state)
        self.DeclareVectorOutputPort("handle", 3, self._calc_handle, prerequisites_of_calc={self.xd_ticket()})
        self.DeclareVectorOutputPort("switches", 1, self._calc_switches, prerequisites_of_calc={self.xd_ticket()})
        self.DeclarePeriodicDiscreteUpdateEvent(p.period, 0.0, self._update)

    def _calc_handle(self, context, output):
        output.SetFromVector(context.get_discrete_state(self._state).get_value()[:3])

    def _calc_switches(self, context, output):
        output.SetAtIndex(0, context.get_discrete_state(self._state).get_value()[6])

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
        sheath, goal = x[7:10], x[10:13]
        delta = goal - sheath
        delta[1] = (delta[1] + np.pi) % (2 * np.pi) - np.pi  # the rotation the short way round
        if sheath[2] == 0.0 and goal[2] == 0.0:
            delta[1] = 0.0  # a straight sheath: its rotation does not matter
        if not np.any(np.abs(delta) > 1e-12):
            if x[17]:  # re-approach: the catheter out again as far as before the pull-back
                x[0] = min(x[0] + p.push_speed * dt, x[16])
                x[17] = float(x[0] < x[16] - 1e-12)
                return True
            return False
        # Pull back first (the catheter's tip into the sheath's mouth, ``sheath_retract_out`` out),
        # then move the sheath, then push the catheter out again.
        if not x[17]:
            x[16], x[17] = x[0], 1.0
        if self.initial_length + x[0] > p.sheath_retract_out + 1e-9:
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
        discrete_state.get_mutable_vector(self._state).SetFromVector(x)
        return EventStatus.Succeeded()


@dataclass
class _CatheterState:
    """The catheter's state between updates (an abstract state value)."""

    q: np.ndarray
    twist: np.ndarray  # the shaft's twist chain nodes [rad] (handle first)
    push: np.ndarray  # the shaft's push chain nodes [m]
    length: float  # rod beyond the sheath exit [m]
    torque: float  # the rod's torque on the shaft at the exit [N m]
    nodes: np.ndarray  # (n + 1, 3): every joint (those in the sheath on its axis) and the tip centre
    R_tip: np.ndarray
    slips: int = 0
    force: float = 0.0  # the rod's axial force on the shaft at the exit [N]
    push_slips: int = 0
    failures: list = field(default_factory=list)

    def __deepcopy__(self, memo):
        new = copy.copy(self)
        for name in ("q", "twist", "push", "nodes", "R_tip"):
            setattr(new, name, getattr(self, name).copy())
        new.failures = list(self.failures)
        return new


class SteerableCatheterSystem(LeafSystem):
    """The steerable catheter in the atrium, quasi-static (module docstring).

    Input ports: handle (3: push past the start [m], handle twist [rad], knob in [-1, 1]).
    Output ports: body_poses (abstract list[RigidTransform]: index 0 the world, 1..n + 1 the rod's
    nodes, the tip sphere's centre last, with the tip's frame), tip_position (3: the tip's end),
    windup (3: handle twist, twist at the sheath exit [rad], slips so far), tip_wall_force (6: zero, the rod
    statics do not report the wall's force, then the tip sphere's centre).

    Args:
        catheter: the SteerableCatheter.
        p_E, axis: the sheath exit [m] and its direction.
        sdf: the atrium's signed distance (``drake_models.atrium_sdf``).
        initial_length: rod beyond the exit at the start [m].
        period: the update period [s].
    """

    def __init__(self, catheter: SteerableCatheter, p_E, axis, sdf, initial_length: float = 20e-3,
                 period: float = 0.05, sheath: SteerableSheath | None = None) -> None:
        super().__init__()
        self.set_name("steerable_catheter")
        self.catheter = catheter.validate()
        self.rod = RodStatics(self.catheter, p_E, axis, sdf)
        # A steerable sheath (issue 45, the manual arm): its exit moves with its input (advance
        # beyond the septum [m], rotation [rad], deflection [rad]); None: the paper's fixed exit.
        self.sheath = None if sheath is None else require_type(sheath, SteerableSheath, "sheath",
                                                                "a SteerableSheath or None").validate()
        self._p_S = self.rod.p_E - (0.0 if sheath is None else sheath.nominal_advance) * self.rod.R_E[:, 2]
        self._R_S = self.rod.R_E.copy()
        self.sheath_setting = None if sheath is None else (sheath.nominal_advance, 0.0, 0.0)
        if not 0.0 < initial_length <= self.rod.max_length:
            raise UserInputError(f"SteerableCatheterSystem initial_length must be in (0, "
                                 f"{self.rod.max_length * 1e3:.0f} mm], got {initial_length}")
        self.initial_length = float(initial_length)
        self.period = float(period)
        self._twist_chain, self._push_chain = self.catheter.chains()
        # The coupling's scales: the chains' kinetic friction, the shaft unloaded.
        c = self.catheter
        self._torque_scale = c.mu_kinetic * c.radius * c.sheath_normal_force()
        self._force_scale = c.mu_kinetic * c.sheath_normal_force()
        self.n_bodies = self.rod.n_joints + 1
        self._handle = self.DeclareVectorInputPort("handle", 3)
        self._sheath = None if sheath is None else self.DeclareVectorInputPort("sheath", 3)
        self._index = self.DeclareAbstractState(AbstractValue.Make(self._solve(self._start(), 0.0, 0.0, 0.0)))
        ticket = {self.abstract_state_ticket(self._index)}
        self.DeclareAbstractOutputPort("body_poses", lambda: AbstractValue.Make([RigidTransform()]),
                                       self._calc_poses, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("tip_position", 3, self._calc_tip, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("windup", 3, self._calc_windup, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("tip_wall_force", 6, self._calc_wall_force, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("handle_load", 2, self._calc_handle_load, prerequisites_of_calc=ticket)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update)

    def _start(self) -> _CatheterState:
        return _CatheterState(np.zeros(0), self._twist_chain.initial(), self._push_chain.initial(),
                              self.initial_length, 0.0, np.zeros((self.n_bodies, 3)), np.eye(3))

    def state(self, context) -> _CatheterState:
        return context.get_abstract_state(self._index).get_value()

    def _solve(self, st: _CatheterState, push: float, twist: float, knob: float) -> _CatheterState:
        """``st`` advanced (in place, and returned) to the handle at (push, twist, knob): the shaft's
        chains through the sheath's bends (the axial one under the rod's axial force, the
        torsional one under the rod's torque and pressed by the axial one's tension), then the
        rod; the chains see the rod's new loads once more (the quasi-static coupling)."""
        kappa = self.catheter.curvature(knob)
        bends = self.catheter.sheath_friction == "bends"
        start = st.twist.copy()  # the twist chain before this update
        for _ in range(2):
            if bends:
                st.push, slips_push = self._push_chain.step(st.push, push, st.force)
                tension = self._push_chain.mean_tension(st.push, st.force)
                st.twist, slips = self._twist_chain.step(st.twist, twist, st.torque, tension)
            else:  # the earlier model (SteerableCatheter.sheath_friction): no axial load, no capstan
                st.push, slips_push = self._push_chain.step(st.push, push)
                st.twist, slips = self._twist_chain.step(st.twist, twist, st.torque)
            length = float(np.clip(self.initial_length + st.push[-1], 2 * self.rod.h, self.rod.max_length))
            st.push_slips += slips_push
            if self.sheath is not None:  # the exit twist and the rod's torque solved together
                st.twist, slips, sol = self.coupled_twist(start, twist, tension if bends else None, length, kappa,
                                                          st.q, st.failures)
            else:  # the paper's fixed sheath: the alternating coupling (its runs' numbers kept)
                sol = self.rod.solve(length, st.twist[-1], kappa, q0=st.q if len(st.q) else None)
            st.slips += slips
            if not (np.all(np.isfinite(sol.q)) and np.isfinite(sol.base_torque) and np.isfinite(sol.base_force)):
                if len(st.failures) < 20:
                    st.failures.append(f"rod statics not finite at length {length * 1e3:.1f} mm")
                return st  # the last finite state stays
            if not sol.converged and len(st.failures) < 20:  # the first few, for the run's warnings
                st.failures.append(f"rod statics did not converge at length {length * 1e3:.1f} mm")
            changed = (abs(sol.base_torque - st.torque) > 0.05 * self._torque_scale
                       or abs(sol.base_force - st.force) > 0.05 * self._force_scale)
            st.q, st.torque, st.force, st.length = sol.q, sol.base_torque, sol.base_force, length
            if not changed:
                break
        st.R_tip = sol.pose.R_tip
        j0 = self.rod.first_free(length)
        inside = self.behind_exit(self.rod.sigma[:j0] - length)
        st.nodes = np.vstack([inside, sol.pose.nodes])
        return st

    def coupled_twist(self, chain_x, handle: float, tension, length: float, kappa: float, q0,
                      failures: list, xtol: float = 1e-7, max_evaluations: int = 80, max_step: float = 0.1):
        """The twist chain stepped from ``chain_x`` to ``handle`` with the rod's torque at its own
        exit twist (issue 45): the root of F(phi) = (the chain's exit node under the rod's torque
        at phi) - phi, bracketed outward from the last exit twist (where ``q0`` holds) in steps
        growing to ``max_step`` [rad], each rod solve warm-started from the nearest one done (the
        quasi-static path: a far jump lands the rod on another of its equilibria against the
        wall), then refined by the Illinois regula falsi on the values kept. Alternating the two
        (the fixed sheath's coupling) runs away when the rod's torsional stiffness exceeds the
        shaft's, as with the short rod beyond a curled sheath. ``tension`` None: "even" chains.

        Returns:
            (chain nodes, slips, the RodSolution at the exit twist)."""
        q0 = q0 if len(q0) else None
        chain, seen = self._twist_chain, {}
        step = ((lambda load: chain.step(chain_x, handle, load)) if tension is None
                else (lambda load: chain.step(chain_x, handle, load, tension)))

        def F(phi):
            near = min(seen, key=lambda p: abs(p - phi)) if seen else None
            sol = self.rod.solve(length, phi, kappa, q0=q0 if near is None else seen[near][0].q)
            if not (np.all(np.isfinite(sol.q)) and np.isfinite(sol.base_torque)):
                raise FloatingPointError
            x, slips = step(sol.base_torque)
            seen[phi] = (sol, x, slips)
            return float(x[-1]) - phi

        try:
            a = float(chain_x[-1])
            fa = F(a)
            if abs(fa) > xtol:
                d = float(np.sign(fa)) * min(abs(fa), 0.02)
                b, fb = a + d, F(a + d)
                while fb * fa > 0 and len(seen) < max_evaluations // 2:
                    a, fa, d = b, fb, float(np.sign(d)) * min(2 * abs(d), max_step)
                    b, fb = a + d, F(a + d)
                while fb * fa < 0 and abs(b - a) > xtol and len(seen) < max_evaluations:
                    m = b - fb * (b - a) / (fb - fa)  # the Illinois regula falsi on the bracket's values
                    fm = F(m)
                    if fm * fb < 0:
                        a, fa = b, fb
                    else:
                        fa *= 0.5
                    b, fb = m, fm
            phi = min(seen, key=lambda p: abs(seen[p][1][-1] - p))
            # F jumps where a chain node starts to slip (static above kinetic): a bracket closed on
            # the jump is the node at the edge of slipping, balanced (its nodes as the chain left them).
            edge = abs(fa) > xtol and fb * fa < 0 and abs(b - a) <= xtol
        except FloatingPointError:
            phi, edge = None, False
        if phi is None or (abs(seen[phi][1][-1] - phi) > 1e3 * xtol and not edge):  # the last finite try
            if len(failures) < 20:
                failures.append(f"exit twist not balanced at length {length * 1e3:.1f} mm ({len(seen)} solves)")
            if phi is None:
                sol = self.rod.solve(length, float(chain_x[-1]), kappa, q0=q0)
                return np.asarray(chain_x, float).copy(), 0, sol
        sol, x, slips = seen[phi]
        return x, slips, sol

    @property
    def septum(self) -> tuple:
        """(p_S, R_S): where the sheath crosses the septum and the fixed sheath's frame there."""
        return self._p_S, self._R_S

    def behind_exit(self, d) -> np.ndarray:
        """Points (k, 3) ``d`` (k,) behind the exit along the sheath [m]: on the fixed sheath's
        axis, or along the steerable sheath's centreline and then its axis behind the septum."""
        d = np.asarray(d, float)
        if self.sheath is None:
            return self.rod.p_E[None, :] - np.outer(d, self.rod.R_E[:, 2])
        return self.sheath.behind_exit(self._p_S, self._R_S, *self.sheath_setting, d)

    def in_sheath(self, p_W, radius: float) -> np.ndarray:
        """Which points (k, 3) lie in the sheath (within ``radius`` of its centreline)."""
        p_W = np.atleast_2d(np.asarray(p_W, float))
        if self.sheath is None:
            line = self.rod.p_E[None, :]
        else:
            line = self.behind_exit(np.linspace(0.0, self.sheath.max_advance, 81))
        axis = self._R_S[:, 2]
        start = line[-1] if self.sheath is not None else self.rod.p_E
        rel = p_W - start
        along = rel @ axis
        behind = (along <= 1e-9) & (np.linalg.norm(rel - along[:, None] * axis, axis=1) <= radius)
        if self.sheath is None:
            return behind
        near = np.min(np.linalg.norm(p_W[:, None, :] - line[None], axis=2), axis=1) <= radius + 0.5e-3
        return behind | near

    def place_sheath(self, advance: float, rotation: float, deflection: float) -> None:
        """The rod's base at the steerable sheath's exit for its (advance [m], rotation [rad],
        deflection [rad]) (``SteerableSheath.exit_pose``): the next solve starts there, warm-started
        from the last joint angles (a quasi-static move: the catheter rides in the sheath)."""
        self.sheath_setting = (float(advance), float(rotation), float(deflection))
        p, R, _ = self.sheath.exit_pose(self._p_S, self._R_S, advance, rotation, deflection)
        if not (np.array_equal(p, self.rod.p_E) and np.array_equal(R, self.rod.R_E)):
            self.rod.p_E, self.rod.R_E = p, R
            self.rod._last_pose = None  # its cached pose is keyed by the joint angles only, not the base

    def _update(self, context, state):
        push, twist, knob = _finite(self._handle.Eval(context))
        if self._sheath is not None and self._sheath.HasValue(context):
            new = _finite(self._sheath.Eval(context))
            old = np.array(self.sheath_setting)
            # In steps of at most SHEATH_SUBSTEP's degrees (or mm): the rod's solve is warm-started
            # from the last one, which a large jump of its base leaves too far behind.
            turn = np.degrees(np.abs(new - old))
            n = int(np.ceil(max(turn[1] * abs(new[2]) / np.pi, turn[2], abs(new[0] - old[0]) * 1e3) / SHEATH_SUBSTEP))
            for k in range(1, n):
                self.place_sheath(*(old + (new - old) * k / n))
                self._solve(state.get_mutable_abstract_state(self._index).get_mutable_value(), float(push),
                            float(twist), float(knob))
            self.place_sheath(*(float(v) for v in new))
        # Drake hands the update a copy of the state: the catheter's is advanced in place there.
        self._solve(state.get_mutable_abstract_state(self._index).get_mutable_value(), float(push), float(twist),
                    float(knob))
        return EventStatus.Succeeded()

    def _calc_poses(self, context, output):
        st = self.state(context)
        poses = [RigidTransform()] + [RigidTransform(p) for p in st.nodes[:-1]]
        poses.append(RigidTransform(RotationMatrix(st.R_tip), st.nodes[-1]))
        output.set_value(poses)

    def _calc_tip(self, context, output):
        st = self.state(context)
        output.SetFromVector(st.nodes[-1] + self.catheter.radius * st.R_tip[:, 2])

    def _calc_windup(self, context, output):
        st = self.state(context)
        output.SetFromVector([st.twist[0], st.twist[-1], float(st.slips)])

    def _calc_handle_load(self, context, output):
        """What the hand feels: the shaft's torque [N m] and axial force [N] at the handle (its
        first elements', positive when the shaft resists the handle's positive twist / push)."""
        st = self.state(context)
        output.SetFromVector([-self._twist_chain.forces(st.twist)[0], -self._push_chain.forces(st.push)[0]])

    def _calc_wall_force(self, context, output):
        output.SetFromVector(np.concatenate([np.zeros(3), self.state(context).nodes[-1]]))


class CatheterMeshcat(LeafSystem):
    """The catheter in Meshcat: the atrium's blood-side surface and the targets drawn once, the
    rod's nodes (spheres of its radius) moved at every publish from ``body_poses``, at the
    publish's time (while the Meshcat records, these are the replay's frames). It records a
    replay as the station's visualizer does (``StartRecording``, ``StopRecording``,
    ``PublishRecording``: ``run_station(html=...)``), a frame every ``period``.

    Input ports: body_poses (abstract list[RigidTransform]).
    """

    def __init__(self, meshcat, heart, n_bodies: int, radius: float, targets=None, period: float = 0.05) -> None:
        super().__init__()
        self.set_name("catheter_meshcat")
        self._meshcat, self._n, self._period = meshcat, n_bodies, period
        self._poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        frame_scene(meshcat, heart)  # the camera on the atrium (and a replay opens on the same view)
        V, F = heart.blood_surface
        meshcat.SetTriangleMesh("catheter_view/atrium", np.asarray(V, float).T, np.asarray(F).T,
                                Rgba(0.85, 0.45, 0.45, 0.25))
        if targets is not None:
            for name, p in zip(targets[0], targets[1]):
                meshcat.SetObject(f"catheter_view/targets/{name}", Sphere(targets[3]), Rgba(0.2, 0.6, 0.9, 0.6))
                meshcat.SetTransform(f"catheter_view/targets/{name}", RigidTransform(p))
        for i in range(n_bodies):
            meshcat.SetObject(f"catheter_view/rod/{i}", Sphere(radius), Rgba(0.3, 0.3, 0.3, 1.0))
        self.DeclarePeriodicPublishEvent(period, 0.0, self._publish)
        self.DeclareForcedPublishEvent(self._publish)

    def _publish(self, context):
        poses = self._poses.Eval(context)
        for i in range(self._n):
            self._meshcat.SetTransform(f"catheter_view/rod/{i}", poses[i + 1], context.get_time())
        return EventStatus.Succeeded()

    def StartRecording(self) -> None:
        """Record the frames (the poses set at their times), one every ``period``."""
        self._meshcat.StartRecording(1.0 / self._period, False)

    def StopRecording(self) -> None:
        self._meshcat.StopRecording()

    def PublishRecording(self) -> None:
        self._meshcat.PublishRecording()


@dataclass
class CatheterParams:
    """The catheter device's own parameters (``MakeStation(device_params=...)``).

    Attributes:
        catheter: the SteerableCatheter (default: its defaults).
        hand: the HandParams of the hand on its handle (default: its defaults).
        initial_length: rod beyond the sheath exit at the start [m].
        sheath: a steerable sheath the hand moves (``SteerableSheath``, issue 45), or None: the
            paper's fixed sheath.
    """

    catheter: SteerableCatheter = field(default_factory=SteerableCatheter)
    hand: HandParams = field(default_factory=HandParams)
    initial_length: float = 20e-3
    sheath: SteerableSheath | None = None
