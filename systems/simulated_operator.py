"""A simulated operator: touches ablation targets in order through the joystick and the feeder.

``SimulatedOperator`` is a LeafSystem that closes the teleoperation loop the way a person at the
console does, watching a camera: every ``period`` seconds (20 Hz by default) it looks at the tip
ball (its centre, and the tip's direction from the ball before it), decides a stick deflection and
a feeder command, and these take effect ``reaction_steps`` periods later (0.1 s by default). It
does not read the physics model, the magnet or its field: it only knows what a camera shows
(the tip, the target discs on the wall and which way they face), what it did with its hands, and
that the stick has a dead band.

The policy, an honest model of a person learning an unfamiliar mapping by watching:

* What it knows beforehand: feeding pushes the tip forward along its direction (that is what a
  feeder does), and the stick swings it somehow. What it learns: an estimate ``J`` (3 x n) of the
  tip velocity per unit of each stick axis it uses (three for the paper's world-frame mapping, two
  for the catheter-frame mapping, handle and knob for the manual catheter), and ``F`` (3,) of the
  feeder's effect beyond that expected share (a catheter bent past a right angle does not go where
  its tip points when pushed; ``learn_feeder``), by recursive least squares with forgetting on
  what it sees: after each look, the tip's displacement over the period (less the feeder's
  expected share) against the stick deflections and the feeder command that were in effect. It
  starts by probing: it wiggles each axis back and forth once (the estimate starts at zero). Its
  hand is not perfectly steady: a small random tremor (``tremor``) on the stick, which also keeps
  the estimate informed.
* Steering: first to a point ``hover`` above the target (off the wall: no dragging the tip along
  the tissue), then, once over it, down onto its centre, aimed slightly inside the wall (``press``)
  so that the tip presses on it; desired tip velocity ``gain * error`` (capped at ``max_speed``);
  the feeder's command from the whole learned map (stick and feeder together, damped least
  squares), within the feeder's limits, and the rest by the stick through ``J``, no axis beyond
  full deflection (with ``learn_feeder`` off: the part along the tip's direction by the feeder).
* It keeps the tip out of the vein openings it sees (``keep_out``, the ipsilateral pairs with the
  carina between them): within ``keep_out_margin`` of their outline it adds a velocity away.
* Feeding has limits a person at the console sees: never forward while the tip is at the wall near
  the target pointing into it (its centre within ``contact_margin`` of a ball radius above the
  target's wall plane, its direction within 45 degrees of the wall's inward normal: pushing more
  chain then only drives the tip into the tissue); not more chain than
  ``reach_factor`` times the sheath exit's distance to the target (enough for a half-turn bend);
  and when it pushes but the tip does not go forward (the chain jams), it pulls back.
* Confusion: when the tip keeps moving against what its estimate predicts (the mean cosine
  between predicted and seen stick-driven motion over about ``confusion_window`` below zero),
  it stops and probes again (a re-learning wiggle; counted per target).
* No progress: if the distance to the target has not shrunk by ``stall_progress`` in
  ``stall_window`` seconds, it feeds more chain for ``burst`` seconds when feeding takes the tip
  towards the target (the learned feeder direction within 60 degrees of the target's: out of
  reach) and feeding is allowed, and retracts otherwise (stuck against the wall), steering
  meanwhile; then it resumes. A burst that brought the tip no closer is followed, on the same
  target, by one the other way (a local probe of the feeder). It never retracts below
  ``min_length``.
* Touch: the target counts as touched when ``targets_touched`` (``target_contact``: the tip
  ball within 0.5 mm of the wall inside the target's 5 mm circle) says so at one of its looks;
  it records the time and the accuracy (distance from the ball's wall-side point, its centre
  moved a ball radius against the target's normal, to the target's centre) and moves on. After
  ``timeout`` seconds on a target it gives up (recorded as missed), so a run always ends.

None of its constants was tuned to match the paper's operator times.

``OperatorParams`` and ``TargetRecord`` live in ``operator_params``, re-exported here.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
from numpy.random.bit_generator import ISeedSequence
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import EventStatus

from ballchain.drake_models.electrode import axis_start
from ballchain.infrastructure.errors import UserInputError
from ballchain.systems.operator_params import OperatorParams, TargetRecord
from ballchain.systems.randomness import SeededLeafSystem
from ballchain.systems.target_contact import targets_touched


@dataclass
class _Memory:
    """The operator's state (an abstract state value, replaced at every look)."""

    J: np.ndarray  # (3, n) tip velocity [mm/s] per unit of each stick axis (after the dead band)
    P: np.ndarray  # (n + 1, n + 1): the stick axes' and the feeder's (n, n: the feeder not learned)
    queue: list  # decided controls (n + 1: stick axes, feeder) waiting for the reaction delay
    applied: np.ndarray  # (n + 1,) controls in effect since the last look
    rng: np.random.Generator | None = None  # the tremor's; made from the seed parameter at the first look
    p_last: np.ndarray | None = None
    d_last: np.ndarray | None = None
    k: int = 0  # current target
    records: list = field(default_factory=list)
    phase: str = "wait"  # wait, probe, pursue, burst, done
    phase_start: float = 0.0
    phase_end: float = 0.0
    burst_sign: float = 0.0
    best: float = np.inf  # closest distance to the current aim [m]
    t_best: float = 0.0
    done: bool = False
    length: float = 0.0  # chain fed out, by its own count [m]
    fed_recent: float = 0.0  # forward feed in the last jam_window or so [m]
    advanced_recent: float = 0.0  # forward tip motion meanwhile [m]
    agreement: float = 1.0  # running mean cosine between predicted and seen stick-driven motion
    descending: bool = False  # pressing down on the target (else hovering towards it)
    F: np.ndarray | None = None  # (3,) the feeder's effect beyond its expected share [mm/s per unit command]
    burst_start: float = np.inf  # distance to the aim when the current burst began [m]
    burst_failed: float = 0.0  # sign of this target's last burst that brought the tip no closer (0: none)
    held: bool = False  # its other hand was moving a steerable sheath at the last look (``hand_hold``)

    def __deepcopy__(self, memo) -> "_Memory":
        """An independent copy, field by field: the arrays and the open record copied (a closed
        one, ``t_end`` set, is never changed again: the copies share it), the generator by its
        state. Drake clones the abstract state (Value[object] deep-copies) twice per update, and
        the generic deepcopy of this memory took about a tenth of a whole task's wall time on
        the quasi-static engine."""
        new = copy.copy(self)
        for name in ("J", "P", "applied", "p_last", "d_last", "F"):
            value = getattr(self, name)
            if value is not None:
                setattr(new, name, value.copy())
        new.queue = [u.copy() for u in self.queue]
        new.records = [r if r.t_end is not None else copy.copy(r) for r in self.records]
        if self.rng is not None:  # a bit generator of the same kind (seeded with no entropy), then the state
            new.rng = np.random.Generator(type(self.rng.bit_generator)(_NO_ENTROPY))
            new.rng.bit_generator.state = self.rng.bit_generator.state
        return new


class _NoEntropy(ISeedSequence):
    """A seed sequence of zeros: a bit generator made only to receive another's state (a seedless
    one reads the operating system's entropy, a fifth of the copy's time)."""

    def generate_state(self, n_words, dtype=np.uint32):
        return np.zeros(n_words, dtype=dtype)


_NO_ENTROPY = _NoEntropy()


class SimulatedOperator(SeededLeafSystem):
    """A person at the joystick and the feeder, touching targets in order (module docstring).

    Input ports:
        body_poses: abstract list[RigidTransform] indexed by BodyIndex (the plant's ``body_poses``):
            it looks at the tip ball and the ball before it.
        hand_hold: optional (2): its other hand moving a steerable sheath (``_held``).

    Output ports:
        joystick: (3,) stick axes in [-1, 1] (into a unit's TeleoperationMapper).
        v_insert_cmd: (1,) feeder speed command [m/s] (into the Feeder).
        done: (1,) 1 once every target is touched or given up.
        target: (6,) the target it is on: centre [m] and wall normal.
        attempts: (1,) its failed attempts on that target (``_calc_attempts``).

    State: abstract, its memory (what it learned, its plan, its records, its tremor's generator).
    Parameter: the tremor's seed (1; ``randomness.SeededLeafSystem``: its default is
    ``params.seed``, ``randomness.set_random_context`` draws another); the tremor is drawn from
    ``numpy.random.default_rng(seed)``, made at the first look.

    Args:
        tip_body_index, previous_body_index: BodyIndex of the tip ball and of the ball before it.
        names: the targets' names, in the order to touch them.
        p_WT: (n, 3) target centres on the wall [m].
        n_W: (n, 3) unit wall normals at the targets, into the chamber.
        params: OperatorParams.
    """

    def __init__(self, tip_body_index, previous_body_index, names, p_WT, n_W,
                 params: OperatorParams | None = None, name: str = "operator") -> None:
        super().__init__()
        self.params = p = (params or OperatorParams()).validate()
        self.set_name(name)
        self.names = list(names)
        self._p_WT = np.asarray(p_WT, float).reshape(-1, 3)
        self._n_W = np.asarray(n_W, float).reshape(-1, 3)
        if len(self.names) != len(self._p_WT) or len(self._p_WT) != len(self._n_W) or not self.names:
            raise UserInputError("SimulatedOperator needs at least one target, with as many names, centres and normals")
        self._tip, self._previous = int(tip_body_index), int(previous_body_index)
        self._n = n = len(p.axes)
        memory = _Memory(J=np.zeros((3, n)), P=p.initial_covariance * np.eye(n + 1 if p.learn_feeder else n),
                         queue=[np.zeros(n + 1)] * p.reaction_steps, applied=np.zeros(n + 1),
                         length=p.initial_length, F=np.zeros(3))
        self.DeclareSeedParameter(p.seed)
        self._poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        # Optional (the manual arm's steerable sheath, issue 45): (1 while its other hand moves the
        # sheath, the catheter out by the handle's readout [m]); unconnected: no such hand.
        self._hand_hold = self.DeclareVectorInputPort("hand_hold", 2)
        self._memory_index = self.DeclareAbstractState(AbstractValue.Make(memory))
        ticket = {self.abstract_state_ticket(self._memory_index)}
        self.DeclareVectorOutputPort("joystick", 3, self._calc_joystick, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("v_insert_cmd", 1, self._calc_feeder, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("done", 1, self._calc_done, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("target", 6, self._calc_target, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("attempts", 1, self._calc_attempts, prerequisites_of_calc=ticket)
        self.DeclarePeriodicUnrestrictedUpdateEvent(p.period, 0.0, self._update)

    # ---------------------------------------------------------------------------- ports
    def get_body_poses_input_port(self):
        return self._poses

    def _memory(self, context) -> _Memory:
        return context.get_abstract_state(self._memory_index).get_value()

    def _stick(self, u: np.ndarray) -> np.ndarray:
        """Stick deflections that the mapper's dead band turns into the effective controls u."""
        db = self.params.dead_band
        s = np.where(np.abs(u) > 1e-6, np.sign(u) * (db + (1.0 - db) * np.abs(u)), 0.0)
        return np.clip(s, -1.0, 1.0)

    def _calc_joystick(self, context, output):
        u = self._memory(context).applied
        axes = np.zeros(3)
        axes[list(self.params.axes)] = self._stick(u[:-1])
        output.SetFromVector(axes)

    def _calc_feeder(self, context, output):
        output.SetAtIndex(0, float(np.clip(self._memory(context).applied[-1], -1.0, 1.0)) * self.params.feeder_speed)

    def _calc_done(self, context, output):
        output.SetAtIndex(0, 1.0 if self._memory(context).done else 0.0)

    def _calc_target(self, context, output):
        """The target it is on (the last once done): its centre [m] and wall normal (what it sees;
        for a hand that places a steerable sheath, issue 45)."""
        k = min(self._memory(context).k, len(self.names) - 1)
        output.SetFromVector(np.concatenate([self._p_WT[k], self._n_W[k]]))

    def _calc_attempts(self, context, output):
        """Its failed attempts on the target it is on: the re-learning wiggles and the bursts (each
        its own verdict that the tip made no progress; ``TargetRecord.relearns + bursts``), 0
        before the first (what it knows of its own struggle: for a hand that re-approaches, issue 45)."""
        records = self._memory(context).records
        output.SetAtIndex(0, float(records[-1].relearns + records[-1].bursts) if records else 0.0)

    # -------------------------------------------------------------------------- results
    def records(self, context) -> list[TargetRecord]:
        """The targets turned to so far (the last one may still be open)."""
        return list(self._memory(context).records)

    def rows(self, context) -> list[dict]:
        """Per target: target, touched, time_s (spent on it; up to now for an open one), t_touch_s,
        accuracy_mm, relearns, bursts, reason (a missed target's: ``TargetRecord.reason``; an open
        one's None; "not reached" for a target not turned to yet, untouched with no time) and
        closest_mm (its wall-side point's closest approach to the target's centre)."""
        t = context.get_time()
        records = {r.target: r for r in self._memory(context).records}
        rows = []
        for name in self.names:
            r = records.get(name)
            rows.append(r.row(t) if r is not None else
                        {"target": name, "touched": False, "time_s": None, "t_touch_s": None, "accuracy_mm": None,
                         "relearns": None, "bursts": None, "reason": "not reached", "closest_mm": None})
        return rows

    def is_done(self, context) -> bool:
        return self._memory(context).done

    def jacobian_estimate(self, context) -> np.ndarray:
        """(3, n) the current estimate: tip velocity [m/s] per unit of each stick axis it uses
        (after the dead band)."""
        return self._memory(context).J * 1e-3

    # --------------------------------------------------------------------------- policy
    def _update(self, context, state):
        p = self.params
        t = context.get_time()
        # Drake hands the update a copy of the state: the memory is changed in place there.
        mem = state.get_mutable_abstract_state(self._memory_index).get_mutable_value()
        if mem.rng is None:
            mem.rng = np.random.default_rng(self.seed(context))
        poses = self._poses.Eval(context)
        tip = poses[self._tip].translation().copy()
        d = tip - poses[self._previous].translation()
        d = d / max(np.linalg.norm(d), 1e-12)
        if mem.phase == "wait" and t + 1e-9 >= p.start_time:
            mem.records.append(TargetRecord(self.names[0], t))
            self._start_probe(mem, t)
        if self._hand_hold.HasValue(context) and mem.phase not in ("wait", "done") and self._held(mem, t, tip, d,
                                                                                                 context):
            return EventStatus.Succeeded()
        if mem.p_last is not None and mem.phase != "wait":
            self._watch(mem, tip, d)
        mem.p_last, mem.d_last = tip, d
        if mem.phase not in ("wait", "done"):
            self._check_target(mem, t, tip, d)
        u = np.zeros(self._n + 1) if mem.phase in ("wait", "done", "hold") else self._decide(mem, t, tip, d)
        mem.queue.append(u)
        mem.applied = mem.queue.pop(0)
        return EventStatus.Succeeded()

    def _held(self, mem: _Memory, t: float, tip: np.ndarray, d: np.ndarray, context) -> bool:
        """While its other hand moves a steerable sheath (``hand_hold``): it gives no command and
        learns nothing from the tip's motion (it knows the sheath moves it), and still sees a
        touch or runs out of time; once the sheath stands, the stick's effect has changed (the
        exit turned): it learns it again as at the start (the estimate cleared, a probing
        wiggle) and reads how much catheter is out from the handle. Returns whether it is held."""
        hold = self._hand_hold.Eval(context)
        if hold[0] > 0.5:
            mem.held, mem.p_last, mem.d_last = True, None, None
            self._check_target(mem, t, tip, d)
            mem.queue.append(np.zeros(self._n + 1))
            mem.applied = mem.queue.pop(0)
            return True
        if mem.held:
            p = self.params
            mem.held = False
            mem.J, mem.F = np.zeros_like(mem.J), np.zeros(3)
            mem.P = p.initial_covariance * np.eye(len(mem.P))
            mem.length = float(np.clip(hold[1], 0.0, p.max_length))
            if mem.phase in ("probe", "pursue", "burst"):
                self._start_probe(mem, t)
        return False

    def _start_probe(self, mem: _Memory, t: float) -> None:
        mem.phase, mem.phase_start = "probe", t
        mem.agreement = 1.0

    def _watch(self, mem: _Memory, tip: np.ndarray, d: np.ndarray) -> None:
        """What it learns from the last period: the stick's effect, the chain fed, jams, surprises."""
        p = self.params
        stick, feed = mem.applied[:-1], mem.applied[-1]
        v = (tip - mem.p_last) / p.period * 1e3  # mm/s
        fed = feed * p.feeder_speed * p.period
        # The feeder's expected share: forward along the tip's direction at the fed speed.
        v_stick = v - feed * p.feeder_speed * 1e3 * mem.d_last
        # The regressor: the stick axes and (learning the feeder's effect beyond that share) the feeder.
        x = mem.applied if p.learn_feeder else stick
        if np.linalg.norm(x) > 0.05:  # excitation: learn (and no wind-up without it)
            predicted = mem.J @ stick + mem.F * feed
            norms = np.linalg.norm(predicted) * np.linalg.norm(v_stick)
            if mem.phase == "pursue" and norms > 1.0:  # both above about 1 mm/s
                w = p.period / p.confusion_window
                mem.agreement = (1.0 - w) * mem.agreement + w * float(predicted @ v_stick) / norms
            Px = mem.P @ x
            k = Px / (p.forgetting + x @ Px)
            if p.learn_feeder:
                JF = np.column_stack([mem.J, mem.F]) + np.outer(v_stick - predicted, k)
                mem.J, mem.F = JF[:, :-1], JF[:, -1]
            else:
                mem.J = mem.J + np.outer(v_stick - predicted, k)
            P = (mem.P - np.outer(k, Px)) / p.forgetting
            P = 0.5 * (P + P.T)
            tr = np.trace(P)
            if tr > p.max_covariance:
                P *= p.max_covariance / tr
            mem.P = P
        # The feeder's readout, and whether the tip went forward as far as the chain was fed.
        mem.length = float(np.clip(mem.length + fed, 0.0, p.max_length))
        decay = np.exp(-p.period / p.jam_window)
        mem.fed_recent = decay * mem.fed_recent + max(fed, 0.0)
        mem.advanced_recent = decay * mem.advanced_recent + max(float((tip - mem.p_last) @ mem.d_last), 0.0)

    def _aim(self, k: int, descending: bool = True) -> np.ndarray:
        """Where it steers the tip ball's centre: its wall-side point ``press`` inside the wall at
        the target's centre, or (not descending yet) ``hover`` above it."""
        p = self.params
        height = p.ball_radius - p.press if descending else p.ball_radius + p.hover
        return self._p_WT[k] + height * self._n_W[k]

    def _update_approach(self, mem: _Memory, tip: np.ndarray, t: float) -> None:
        """Hover over the target until the tip is over it (laterally within ``descend_lateral``),
        then press down; back to hovering when it slides ``2 * descend_lateral`` off."""
        p = self.params
        rel = tip - self._p_WT[mem.k]
        n = self._n_W[mem.k]
        lateral = float(np.linalg.norm(rel - (rel @ n) * n))
        descending = lateral < p.descend_lateral or (mem.descending and lateral < 2.0 * p.descend_lateral)
        if descending != mem.descending:
            mem.descending, mem.best, mem.t_best = descending, np.inf, t

    def _check_target(self, mem: _Memory, t: float, tip: np.ndarray, d: np.ndarray | None = None) -> None:
        p = self.params
        k = mem.k
        record = mem.records[-1]
        if mem.phase == "hold":  # the dwell on a touched target
            if t >= mem.phase_end - 1e-9:
                mem.phase = "pursue"
                self._next_target(mem, t)
            return
        record.closest = min(record.closest, float(np.linalg.norm(tip - p.ball_radius * self._n_W[k] - self._p_WT[k])))
        start = None if d is None or p.electrode_length <= p.ball_radius else axis_start(
            tip, d, p.ball_radius, p.electrode_length)  # the electrode's whole surface (d: the tip's direction)
        touched = targets_touched(tip, self._p_WT[k:k + 1], self._n_W[k:k + 1], p.ball_radius, p.target_radius,
                                  axis_start=start)[0]
        if touched:
            record.t_touch = t
            record.accuracy = float(np.linalg.norm(tip - p.ball_radius * self._n_W[k] - self._p_WT[k]))
            if p.dwell > 0:
                mem.phase, mem.phase_end = "hold", t + p.dwell
                return
        elif t - record.t_start < p.timeout - 1e-9:
            return
        self._next_target(mem, t)

    def _next_target(self, mem: _Memory, t: float) -> None:
        """The current target ends now (touched, held, or given up): on to the next one."""
        record = mem.records[-1]
        record.t_end = t
        mem.k += 1
        if mem.k == len(self.names):
            mem.phase, mem.done = "done", True
            return
        mem.records.append(TargetRecord(self.names[mem.k], t))
        mem.best, mem.t_best, mem.burst_failed = np.inf, t, 0.0
        if mem.phase == "burst":
            mem.phase = "pursue"

    def _decide(self, mem: _Memory, t: float, tip: np.ndarray, d: np.ndarray) -> np.ndarray:
        p = self.params
        n = self._n
        if mem.phase == "probe":
            # Each stick axis back and forth once: +a for probe_time, then -a.
            half = int(np.floor((t - mem.phase_start) / p.probe_time + 1e-9))
            if half < 2 * n:
                u = np.zeros(n + 1)
                u[half // 2] = p.probe_amplitude * (1.0 if half % 2 == 0 else -1.0)
                return u
            mem.phase, mem.t_best, mem.best = "pursue", t, np.inf
        k = mem.k
        self._update_approach(mem, tip, t)
        e = self._aim(k, mem.descending) - tip
        dist = float(np.linalg.norm(e))
        if dist < mem.best - p.stall_progress:
            mem.best, mem.t_best = dist, t
        if mem.phase == "burst" and t >= mem.phase_end - 1e-9:
            # A burst that brought the tip no closer: the next one on this target goes the other way.
            mem.burst_failed = mem.burst_sign if dist > mem.burst_start - p.stall_progress else 0.0
            mem.phase, mem.t_best, mem.best = "pursue", t, dist
        if mem.phase == "pursue" and mem.agreement < 0.0:
            # The tip keeps going the wrong way: stop and find out again.
            mem.records[-1].relearns += 1
            self._start_probe(mem, t)
            return self._decide(mem, t, tip, d)
        # At the wall near the target with the tip pointing into it: pushing only presses it in.
        at_wall = ((tip - self._p_WT[k]) @ self._n_W[k] < p.ball_radius + p.contact_margin
                   and -(d @ self._n_W[k]) > np.cos(np.radians(45.0)))
        jammed = mem.fed_recent > p.jam_feed and mem.advanced_recent < p.jam_ratio * mem.fed_recent
        capped = mem.length >= self._length_cap(k)
        may_feed = not at_wall and not jammed and not capped
        may_retract = mem.length > p.min_length + 1e-9  # it keeps at least min_length out
        f = p.feeder_speed * 1e3 * d + mem.F  # [mm/s] per unit feeder command: along the tip, and as learned
        ahead = f @ e > 0.5 * np.linalg.norm(f) * dist  # feeding takes the tip towards the target
        record = mem.records[-1]  # what it notes for the reason of a miss
        record.looks += 1
        record.jammed_looks += int(jammed)
        record.capped_looks += int(capped and ahead)
        if mem.phase == "pursue" and (t - mem.t_best > p.stall_window or jammed):
            # No progress: feed when feeding takes the tip towards the target (out of reach), else
            # pull back; the other way when the last burst on this target brought it no closer.
            mem.records[-1].bursts += 1
            sign = 1.0 if ahead and may_feed else -1.0
            if (sign == mem.burst_failed or sign < 0 and not may_retract) and not jammed and (sign > 0 or may_feed):
                sign = -sign
            mem.burst_sign, mem.burst_start = sign, dist
            mem.phase, mem.phase_end = "burst", t + p.burst
            mem.fed_recent = mem.advanced_recent = 0.0
        v = p.gain * e
        speed = np.linalg.norm(v)
        if speed > p.max_speed:
            v *= p.max_speed / speed
        v = v + self._keep_out(tip)
        # The feeder takes the part along the tip's direction, the stick the rest.
        if mem.phase == "burst":
            u_f = mem.burst_sign * p.burst_command
        elif p.learn_feeder:  # the feeder and the stick together, through what it has learned of both
            u_f = float(_damped_solve(np.column_stack([mem.J, f]), v * 1e3, p.damping)[-1])
            u_f = float(np.clip(u_f, -1.0 if may_retract else 0.0, 1.0 if may_feed else 0.0))
        else:
            u_f = float(np.clip(v @ d / p.feeder_speed, -1.0, 1.0 if may_feed else 0.0))
        v_stick = v * 1e3 - u_f * f  # mm/s, as J
        u_s = _saturate(_damped_solve(mem.J, v_stick, p.damping))
        u_s = np.clip(u_s + p.tremor * mem.rng.uniform(-1.0, 1.0, n), -1.0, 1.0)
        return np.append(u_s, u_f)

    def _keep_out(self, tip: np.ndarray) -> np.ndarray:
        """Velocity [m/s] away from the vein openings it sees, when the tip is within
        ``keep_out_margin`` of their outline: each entry of ``keep_out`` is a pair of neighbouring
        openings (or one, twice) seen as one region, the hull of two discs (centres c1, c2, radii
        r1, r2, axes a1, a2), so that the carina between them is avoided too."""
        p = self.params
        v = np.zeros(3)
        for c1, c2, r1, r2, a1, a2 in p.keep_out:
            c1, c2 = np.asarray(c1, float), np.asarray(c2, float)
            axis = np.asarray(a1, float) + np.asarray(a2, float)
            axis /= np.linalg.norm(axis)
            seg = c2 - c1
            s_ = float(np.clip((tip - c1) @ seg / max(seg @ seg, 1e-18), 0.0, 1.0))
            nearest = c1 + s_ * seg
            radius = r1 + s_ * (r2 - r1)
            rel = tip - nearest
            along = float(rel @ axis)
            radial = rel - along * axis
            rho = float(np.linalg.norm(radial))
            gap = rho - radius
            if abs(along) < radius and gap < p.keep_out_margin and rho > 1e-9:
                v += p.gain * (p.keep_out_margin - gap) * radial / rho
        return v

    def _length_cap(self, k: int) -> float:
        """The most chain it feeds for target k: ``reach_factor`` times the sheath exit's distance
        to the target (a bend of up to half a turn), at most the chain's length."""
        p = self.params
        if p.p_WE is None:
            return np.inf
        return min(p.max_length, p.reach_factor * float(np.linalg.norm(self._p_WT[k] - np.asarray(p.p_WE))))


def _saturate(u: np.ndarray) -> np.ndarray:
    """Scaled so that no control exceeds full deflection (the direction is kept)."""
    big = np.abs(u).max() if u.size else 0.0
    return u / big if big > 1.0 else u


def _damped_solve(J: np.ndarray, v: np.ndarray, damping: float) -> np.ndarray:
    """argmin_u |J u - v|^2 + mu |u|^2, mu = (damping * largest singular value of J)^2."""
    # The largest singular value: np.linalg.norm(J, 2)'s number (the same LAPACK call) without
    # its axis handling, which cost as much as the decomposition of these small matrices.
    s_max = float(np.linalg.svd(J, compute_uv=False).max()) if J.size else 0.0
    if s_max < 1e-9:
        return np.zeros(J.shape[1])
    mu = (damping * s_max) ** 2
    return np.linalg.solve(J.T @ J + mu * np.eye(J.shape[1]), J.T @ v)
