"""An autonomous, model-based navigator: every ablation target of a ring, pressed and held.

``AutonomousNavigator`` is a LeafSystem that sees what a clinical magnetic navigation system
sees: the localisation sensor's measured tip (``localisation_sensor``; never the chain's true
state), the magnets' measured dipole directions (the units' encoders: each magnet's ``m_W``)
and the feeder's inserted length. It drives each unit's joystick input (world mapping: magnet
angular velocity) and the feeder's speed command.

Feed-forward: for every target the experiment has computed ahead, by inverse statics
(``optimization.inverse_statics``, warm-started target to target), the magnets' dipole
directions that hold the tip on the target's centre pressing it with the commanded force, the
inserted length, and the held equilibrium's sensitivities (``TargetPlan``): J_m, the pressing
force (normal, two tangential components, in the target's frame) per change of the dipoles,
and J_o per offset of the touch point along the wall. These are data: the navigator does not
plan.

Feedback, every ``period``: with the force model (``TipForceEstimator``: the chain's statics
with the tip held at the measured point, under the measured magnets, at the measured
insertion) it estimates the contact force F (the reaction that holds the tip there, on the
wall's outward normal: no force sensor), the tip taken as the measured one (or the mean of
the last ``average`` looks on this target). A look with no held equilibrium (near the chain's
reach the sensor's noise can put the measured tip beyond it) keeps the last look's reaction
on this target (none yet: no force). A Newton step on the magnets' orientation then asks
for the held equilibrium at the target's centre (lateral offset o measured -> 0) with F at the
commanded force::

    [J_m,n; J_m,t] dm = [F_cmd - F_est + J_o,n o; J_o,t o - F_t,est]

with dm = omega x m per unit (a rotation), solved by damped least squares; the desired dipoles
turn by ``gain`` times that rotation (capped at ``max_step``) and the joysticks drive the
measured dipoles to them (proportional, at most the mapper's full speed).

Sequencing, per target: ``move`` (the magnets to the plan's dipoles, the feeder to its length;
from the second target on the chain is drawn back by ``lift`` while the magnets turn, so that
the tip leaves the wall rather than sliding along it pressed), ``seek`` (the Newton steps until
the measured tip is within ``touch_radius`` of the target's centre laterally and the estimate
inside the force window for ``settle`` looks), ``dwell`` (``dwell`` seconds of the same loop
holding the force: the RF application, looking every ``dwell_period``), then the next target. A target not touched within ``seek_timeout`` is retried from its plan's dipoles after
retracting part of the chain (``back_off``: it re-forms under the plan's field, off a branch
the plan did not foresee), ``retries`` times; then it is given up (missed).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import copysign, isfinite

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem

from ballchain.infrastructure.errors import UserInputError, require_finite_fields
from ballchain.drake_models.omniwheel import OmniWheelGeometry
from ballchain.drake_models.params import BallChain, gram_force, newtons_from_gram_force
from ballchain.drake_models.vectors import cross
from ballchain.systems.omni_wheel_drive import StepperSpec
from ballchain.systems.tip_force_estimator import TipForceEstimator


def _half_microstep_turn() -> float:
    """Half the smallest turn one wheel's microstep gives the magnet, with the paper's drive
    (``StepperSpec``, ``OmniWheelGeometry``: 0.124 deg a microstep) [rad]."""
    geometry, step = OmniWheelGeometry(), StepperSpec().microstep_angle
    return 0.5 * min(float(np.linalg.norm(geometry.sphere_angular_velocity(step * e))) for e in np.eye(3))


_HALF_MICROSTEP = _half_microstep_turn()


@dataclass
class NavigatorParams:
    """The navigator's settings (SI; forces in N).

    Attributes:
        period: how often it reads the sensors and decides [s].
        force_command: the contact force it holds [N] (20 gf).
        force_window: (low, high) the acceptable contact force [N] (10-40 gf).
        dwell: the RF application at each target [s] (the force is held and recorded over it).
        touch_radius: the tip counts as on the target within this lateral distance of its
            centre (measured) [m].
        settle: looks on the target inside the window before the dwell starts.
        gain: fraction of the Newton rotation taken per look.
        max_step: cap on the desired dipoles' turn per look [rad].
        max_deviation: the desired dipoles stay within this of the plan's [rad] (the model is
            trusted near its plan only).
        force_weight: weight of the force row against the position rows of the Newton step
            (position first: a frictionless wall lets a tip pushed too hard slide away).
        average: the force model holds the tip at the mean of the last ``average`` measured
            tips on this target (relative to the tracked sheath when it moves), reset at each
            target, retry and slip: the sensor's noise (0.4 mm per axis) at the chain's full
            reach puts half the looks beyond it (no held equilibrium) and the other half nearer
            the sheath than the tip is (a force model pressed too hard); the mean of 8 looks
            (0.4 s at 20 Hz) has a third of the noise. 1 (the default): each look alone
            (docs/guide/procedure.md: what 8 changed).
        slip: in the dwell, a measured tip this far from the target's centre laterally has
            slipped off: back to seeking from the plan (the dwell's clock stops meanwhile) [m].
        dwell_period: how often it looks while dwelling [s] (a whole number of ``period``s):
            the force held on a target only drifts with the sensor's noise, and each look costs
            a held-tip solve (docs/guide/procedure.md: the dwell's looks).
        damping: damped least squares, as a fraction of the Jacobian's largest singular value.
        magnet_gain: joystick per radian of dipole error [1/rad] (then saturated).
        aligned: the move phase ends when every dipole is within this of its plan [rad].
        feed_after: in the move phase the feeder inserts only once every dipole is within
            this of its plan (the magnets turn first) [rad].
        feeder_gain: feeder speed per metre of length error [1/s]; feeder_speed: its cap [m/s].
        lift: from the second target on, the move draws the chain back this far while the
            magnets turn to the next plan, then feeds it to the plan's length [m] (one ball): the
            tip leaves the wall instead of sliding along it pressed under a turning field, where
            the pressed chain can snap through to an equilibrium far from both targets
            (docs/guide/procedure.md: the move between targets).
        captured: a measured tip this far beyond the target's wall (along its normal, from the
            target's centre) for ``settle`` looks while moving or seeking has left the atrium (a
            vein or the appendage) [m]: the chain is drawn back until the tip is inside the wall
            again; a target not yet pressed is then given up (its plan's field grows the chain
            into the vein: a retry would too), one pressed before (the tip slipped off it) is
            sought again on the seek's clock; 0: never. The feeder inserts nothing while the
            last look was beyond.
        seek_timeout: seconds seeking one target before a retry.
        retries: retries before giving up a target.
        back_off: the fraction of the inserted length retracted before a retry: the chain
            re-forms from a short stub under the plan's field (a chain held on another
            equilibrium branch than the plan's leaves it; a few millimetres back does not).
        omega_max: the mapper's magnet speed at full stick [rad/s]; dead_band: its dead band.
        hold_band: a measured dipole within this of its desired one is left where it is [rad]:
            half the turn one wheel microstep gives the magnet (the paper's drive: 0.06 deg), below
            which the steppers can only hunt about the desired dipole a step either side.
        start_time: when it starts [s].
    """

    period: float = 0.05
    force_command: float = newtons_from_gram_force(20.0)
    force_window: tuple = (newtons_from_gram_force(10.0), newtons_from_gram_force(40.0))
    dwell: float = 10.0
    touch_radius: float = 1.5e-3
    settle: int = 3
    gain: float = 0.2
    max_step: float = np.radians(1.0)
    max_deviation: float = np.radians(8.0)
    force_weight: float = 0.3
    average: int = 1
    slip: float = 3.0e-3
    dwell_period: float = 0.25
    damping: float = 0.05
    magnet_gain: float = 8.0
    aligned: float = np.radians(1.0)
    feed_after: float = np.radians(5.0)
    feeder_gain: float = 4.0
    feeder_speed: float = 0.02
    lift: float = BallChain().ball_diameter
    captured: float = 2.0 * BallChain().ball_diameter
    seek_timeout: float = 6.0
    retries: int = 1
    back_off: float = 0.5
    omega_max: float = 0.5
    dead_band: float = 0.1
    hold_band: float = _HALF_MICROSTEP
    start_time: float = 0.1

    def validate(self) -> "NavigatorParams":
        require_finite_fields(self)
        lo, hi = self.force_window
        if not 0.0 < lo <= self.force_command <= hi:
            raise UserInputError(f"navigator force_command {gram_force(self.force_command):.3g} gf must lie in its "
                                 f"window {gram_force(lo):.3g}..{gram_force(hi):.3g} gf (low > 0)")
        if not self.period > 0 or not self.dwell >= 0 or not self.seek_timeout > 0 or self.retries < 0:
            raise UserInputError("NavigatorParams: period and seek_timeout must be > 0, dwell and retries >= 0")
        if isinstance(self.average, bool) or not isinstance(self.average, (int, np.integer)) or self.average < 1:
            raise UserInputError(f"NavigatorParams average must be a whole number of looks >= 1, got {self.average!r}")
        if not self.captured >= 0.0:
            raise UserInputError(f"NavigatorParams captured must be >= 0 m (0: never), got {self.captured!r}")
        if not 0.0 <= self.lift <= 0.05:
            raise UserInputError(f"NavigatorParams lift must be in 0..0.05 m, got {self.lift!r}")
        if not 0.0 <= self.back_off <= 1.0:
            raise UserInputError(f"NavigatorParams back_off must be a fraction in 0..1, got {self.back_off!r}")
        if not 0.0 <= self.hold_band < 0.1:
            raise UserInputError(f"NavigatorParams hold_band must be in 0..0.1 rad, got {self.hold_band!r}")
        ratio = self.dwell_period / self.period
        if not ratio >= 1.0 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
            raise UserInputError(f"NavigatorParams dwell_period must be a whole number (>= 1) of periods "
                                 f"({self.period!r} s), got {self.dwell_period!r} s")
        return self


@dataclass(frozen=True)
class TargetPlan:
    """What the experiment computed ahead for one target (world frame).

    Attributes:
        name: the target's name; p_WT (3,) the point on the wall the tip is aimed at (the
            target's centre unless ``aim_offset``); n_W (3,) the wall's normal into the chamber.
        dipoles_W: (k, 3) unit dipole directions of the k units that press it.
        inserted_length: the feeder's length [m].
        basis_W: (3, 3) columns: the direction the tip presses (into the wall), two along it.
        J_m: (3, 3 k) pressing force (normal, tangential u, v) [N] per dipole component.
        J_o: (3, 2) the same per touch-point offset along basis_W[:, 1:] [N/m].
        force_N: the planned pressing force [N].
        aim_offset: how far ``p_WT`` lies from the target's centre along the wall [m] (0: on
            it; > 0: a target beyond the straight chain's reach, aimed inside its circle).
    """

    name: str
    p_WT: np.ndarray
    n_W: np.ndarray
    dipoles_W: np.ndarray
    inserted_length: float
    basis_W: np.ndarray
    J_m: np.ndarray
    J_o: np.ndarray
    force_N: float
    aim_offset: float = 0.0


@dataclass
class DwellRecord:
    """One target's outcome as the navigator saw it."""

    target: str
    t_start: float
    t_touch: float | None = None
    t_end: float | None = None
    retries: int = 0
    slips: int = 0
    captures: int = 0  # times the tip was drawn back from beyond the wall (``NavigatorParams.captured``)
    reached: bool = False
    dwell_time: float = 0.0  # [s] spent in the dwell (on the target)
    estimates: list = field(default_factory=list)  # [(t, F_est [N])] over the dwell
    p_measured: list = field(default_factory=list)  # measured tip over the dwell [m]


@dataclass
class _Memory:
    k: int = 0
    phase: str = "wait"  # wait, move, seek, back, dwell, done
    phase_start: float = 0.0
    m_des: np.ndarray | None = None  # (k, 3) desired dipoles
    s_des: float = 0.0
    on_target: int = 0
    records: list = field(default_factory=list)
    stick: np.ndarray | None = None  # (k, 3)
    v_feed: float = 0.0
    f_est: float = 0.0
    r_est: np.ndarray | None = None  # the last look's reaction on the tip (W) [N]
    looks: tuple = ()  # the last measured tips on this target (relative to the sheath's offset) [m]
    skip: int = 0  # periods left before the dwell's next look
    lifted: bool = False  # the move draws the chain back by ``lift`` until the magnets are aligned
    beyond: int = 0  # looks in a row with the tip beyond the target's wall by ``captured``
    resume: float = 0.0  # the seek's start to resume after drawing a captured tip back
    done: bool = False

    def __deepcopy__(self, memo):
        # Drake copies the state twice a look: copy.copy's shallow copies, without its
        # __reduce_ex__ protocol (the attributes in a new instance's __dict__).
        new = _shallow_copy(self)
        new.m_des = None if self.m_des is None else self.m_des.copy()
        new.stick = None if self.stick is None else self.stick.copy()
        new.records = list(self.records)  # the closed records never change again: shared
        if self.records:  # only the open record changes
            new.records[-1] = last = _shallow_copy(self.records[-1])
            last.estimates, last.p_measured = list(last.estimates), list(last.p_measured)
        return new


def _shallow_copy(obj):
    """``copy.copy`` of a plain dataclass instance (its attributes shared)."""
    new = object.__new__(type(obj))
    new.__dict__.update(obj.__dict__)
    return new


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _rotate(m: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Unit vector m turned by the rotation vector omega (Rodrigues)."""
    angle = float(np.linalg.norm(omega))
    if angle < 1e-12:
        return m
    a = omega / angle
    out = m * np.cos(angle) + cross(a, m) * np.sin(angle) + a * (a @ m) * (1.0 - np.cos(angle))
    return out / np.linalg.norm(out)


class AutonomousNavigator(LeafSystem):
    """Visits the targets of ``plans`` in order, pressing and holding each (module docstring).

    Input ports:
        p_WT_measured: (3,) the localisation sensor's tip [m].
        m_W_<unit>: (3,) each unit's measured dipole (any length).
        inserted_length: (1,) the feeder's [m].
        sheath_offset_measured: (3,) only with ``tracks_sheath``: the tracked sheath's displacement
            from its rest pose [m] (respiration moves the heart and the sheath with it,
            ``drake_models.wall_motion``): the force model's sheath and the targets move with it.

    Output ports:
        joystick_<unit>: (3,) stick axes (world mapping) for each unit.
        v_insert_cmd: (1,) feeder speed command [m/s].
        force_estimate: (1,) the estimated contact force [N] (0 when not pressing a target).
        done: (1,) 1 once every target is pressed or given up.

    Args:
        unit_names: the units, in the order of the plans' dipoles.
        plans: the targets' TargetPlans, in the order to visit them.
        estimator: the TipForceEstimator.
        params: NavigatorParams.
        tracks_sheath: read ``sheath_offset_measured`` (else the sheath and the targets are at rest).
    """

    def __init__(self, unit_names, plans: list[TargetPlan], estimator: TipForceEstimator,
                 params: NavigatorParams | None = None, name: str = "navigator", tracks_sheath: bool = False) -> None:
        super().__init__()
        self.params = p = (params or NavigatorParams()).validate()
        self.set_name(name)
        if not plans:
            raise UserInputError("AutonomousNavigator needs at least one target plan")
        self.units, self.plans, self.estimator = list(unit_names), list(plans), estimator
        self.names = [q.name for q in self.plans]
        self._tip = self.DeclareVectorInputPort("p_WT_measured", 3)
        self._m = [self.DeclareVectorInputPort(f"m_W_{u}", 3) for u in self.units]
        self._s = self.DeclareVectorInputPort("inserted_length", 1)
        self._sheath = self.DeclareVectorInputPort("sheath_offset_measured", 3) if tracks_sheath else None
        self._memory_index = self.DeclareAbstractState(AbstractValue.Make(_Memory()))
        ticket = {self.abstract_state_ticket(self._memory_index)}
        for j, u in enumerate(self.units):
            self.DeclareVectorOutputPort(f"joystick_{u}", 3, lambda c, o, j=j: self._calc_stick(c, o, j),
                                         prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("v_insert_cmd", 1, lambda c, o: o.SetAtIndex(0, self._memory(c).v_feed),
                                     prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("force_estimate", 1, lambda c, o: o.SetAtIndex(0, self._memory(c).f_est),
                                     prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("done", 1, lambda c, o: o.SetAtIndex(0, float(self._memory(c).done)),
                                     prerequisites_of_calc=ticket)
        self.DeclarePeriodicUnrestrictedUpdateEvent(p.period, 0.0, self._update)

    def _memory(self, context) -> _Memory:
        return context.get_abstract_state(self._memory_index).get_value()

    def _calc_stick(self, context, output, j: int) -> None:
        stick = self._memory(context).stick
        output.SetFromVector(np.zeros(3) if stick is None else stick[j])

    def records(self, context) -> list[DwellRecord]:
        return list(self._memory(context).records)

    def is_done(self, context) -> bool:
        return self._memory(context).done

    # ------------------------------------------------------------------------------- policy
    def _update(self, context, state):
        p = self.params
        t = context.get_time()
        # Drake hands the update a copy of the state: the memory is changed in place there.
        mem = state.get_mutable_abstract_state(self._memory_index).get_mutable_value()
        tip = np.asarray(self._tip.Eval(context), float)
        m = np.array([np.asarray(port.Eval(context), float) for port in self._m])
        m /= np.maximum(np.linalg.norm(m, axis=1, keepdims=True), 1e-12)
        s = float(self._s.Eval(context)[0])
        h = None if self._sheath is None else np.asarray(self._sheath.Eval(context), float)
        if mem.phase == "wait" and t + 1e-9 >= p.start_time:
            self._start_target(mem, t)
        if mem.phase not in ("wait", "done"):
            self._step(mem, t, tip, m, s, h)
        if mem.phase in ("wait", "done"):
            mem.stick, mem.v_feed = np.zeros((len(self.units), 3)), 0.0
        else:
            mem.stick = self._sticks(m, mem.m_des)
            mem.v_feed = min(max(p.feeder_gain * (mem.s_des - s), -p.feeder_speed), p.feeder_speed)  # (np.clip's)
            if mem.phase == "move" and self._misalignment(m, mem.m_des) > p.feed_after:
                mem.v_feed = min(mem.v_feed, 0.0)  # the magnets turn first, then the chain goes in
            if mem.beyond > 0:
                mem.v_feed = min(mem.v_feed, 0.0)  # a tip beyond the wall is never pushed on
        return EventStatus.Succeeded()

    def _start_target(self, mem: _Memory, t: float, retry: bool = False) -> None:
        plan = self.plans[mem.k]
        if not retry:
            mem.records.append(DwellRecord(plan.name, t))
        mem.phase, mem.phase_start, mem.on_target, mem.r_est, mem.looks = "move", t, 0, None, ()
        mem.skip = 0
        mem.m_des, mem.s_des = plan.dipoles_W.copy(), plan.inserted_length
        mem.beyond = 0
        mem.lifted = not retry and mem.k > 0 and self.params.lift > 0.0
        if mem.lifted:
            mem.s_des = plan.inserted_length - self.params.lift

    def _finish_target(self, mem: _Memory, t: float) -> None:
        mem.records[-1].t_end = t
        mem.f_est = 0.0
        mem.k += 1
        if mem.k == len(self.plans):
            mem.phase, mem.done = "done", True
        else:
            self._start_target(mem, t)

    def _step(self, mem: _Memory, t: float, tip: np.ndarray, m: np.ndarray, s: float, h=None) -> None:
        p = self.params
        plan, record = self.plans[mem.k], mem.records[-1]
        if mem.phase == "back":
            if s <= mem.s_des + 0.5e-3 or t - mem.phase_start > 1.0 + p.back_off * plan.inserted_length / p.feeder_speed:
                self._start_target(mem, t, retry=True)
            return
        if mem.phase == "out":  # captured: drawn back until the tip is inside the wall
            if self._beyond_wall(plan, tip, h) <= 0.0 or t - mem.phase_start > 1.0 + plan.inserted_length / p.feeder_speed:
                if not record.reached:  # the plan's field grows the chain into the vein: given up
                    self._finish_target(mem, t)
                    return
                # pressed before (slipped off it into the vein): sought again on the seek's clock
                mem.phase, mem.phase_start, mem.on_target, mem.looks = "seek", mem.resume, 0, ()
                mem.s_des, mem.beyond = plan.inserted_length, 0
            return
        if p.captured > 0.0 and mem.phase in ("move", "seek"):
            mem.beyond = mem.beyond + 1 if self._beyond_wall(plan, tip, h) > p.captured else 0
            if mem.beyond >= p.settle:  # in a vein or the appendage
                record.captures += 1
                mem.resume = mem.phase_start if mem.phase == "seek" else t
                mem.phase, mem.phase_start, mem.s_des = "out", t, 0.0
                return
        if mem.phase == "move":
            angle = self._misalignment(m, mem.m_des)
            if mem.lifted:  # drawn back while the magnets turn; then fed to the plan's length
                if angle < p.aligned:
                    mem.s_des, mem.lifted = plan.inserted_length, False
                return
            if angle < p.aligned and abs(s - mem.s_des) < 0.5e-3:
                mem.phase, mem.phase_start = "seek", t
            return
        if mem.phase == "dwell" and mem.skip > 0:  # between the dwell's looks
            mem.skip -= 1
            return
        f_est, lateral = self._newton(mem, plan, tip, m, s, h)
        mem.f_est = f_est
        lo, hi = p.force_window
        if mem.phase == "seek":
            inside = lateral < p.touch_radius and lo <= f_est <= hi
            mem.on_target = mem.on_target + 1 if inside else 0
            if mem.on_target >= p.settle:
                mem.phase, mem.phase_start = "dwell", t
                mem.skip = round(p.dwell_period / p.period) - 1  # the dwell's first look a dwell_period on
                record.t_touch, record.reached = t, True
            elif t - mem.phase_start > p.seek_timeout:
                if record.retries < p.retries:
                    record.retries += 1
                    mem.phase, mem.phase_start = "back", t
                    mem.s_des = (1.0 - p.back_off) * s
                else:
                    self._finish_target(mem, t)
            return
        if lateral > p.slip:  # slipped off: seek again from the plan
            record.slips += 1
            mem.phase, mem.phase_start, mem.on_target, mem.looks = "seek", t, 0, ()
            mem.m_des = plan.dipoles_W.copy()
            return
        record.estimates.append((t, f_est))  # dwell
        record.p_measured.append(tip.copy())
        looks = round(p.dwell_period / p.period)
        record.dwell_time += looks * p.period
        mem.skip = looks - 1
        if record.dwell_time >= p.dwell - 1e-9:
            self._finish_target(mem, t)

    def _newton(self, mem: _Memory, plan: TargetPlan, tip: np.ndarray, m: np.ndarray, s: float,
                h: np.ndarray | None = None) -> tuple[float, float]:
        """One Newton step on the desired dipoles (module docstring); returns (F_est [N], the
        measured tip's lateral distance from the target's centre [m]); ``h``: the tracked
        sheath's offset (the target and the model's sheath moved by it), None: at rest."""
        p = self.params
        B = plan.basis_W
        ball_r = 0.5 * self.estimator.chain.ball_diameter
        centre = plan.p_WT + ball_r * plan.n_W
        if h is not None:
            centre = centre + h
        o = B[:, 1:].T @ (tip - centre)
        p_est = tip
        if p.average > 1:
            offset = np.zeros(3) if h is None else h
            mem.looks = (mem.looks + (tip - offset,))[-p.average:]
            p_est = np.mean(mem.looks, axis=0) + offset
        r = self.estimator.reaction_W(p_est, m, s, h)
        if r is None:  # no held equilibrium at this look (a noisy tip beyond the chain's reach):
            r = mem.r_est  # the last look's reaction (none yet: no force)
        mem.r_est = r
        r = np.zeros(3) if r is None else r
        f_est = max(float(r @ plan.n_W), 0.0)
        f_t = B[:, 1:].T @ (-r)  # tangential pressing force the model says the wall must hold
        w = np.array([p.force_weight, 1.0, 1.0])
        rhs = w * np.concatenate([[p.force_command - f_est + plan.J_o[0] @ o], plan.J_o[1:] @ o - f_t])
        # dm_j = omega_j x m_j: J_m's columns of unit j times -skew(m_j).
        blocks = [plan.J_m[:, 3 * j:3 * j + 3] @ (-_skew(m_j)) for j, m_j in enumerate(m)]
        J = w[:, None] * (blocks[0] if len(blocks) == 1 else np.hstack(blocks))
        s_max = float(np.linalg.svd(J, compute_uv=False)[0])  # norm(J, 2), without its wrapping
        if s_max > 1e-12 and all(map(isfinite, rhs.tolist())):
            mu = (p.damping * s_max) ** 2
            omega = np.linalg.solve(J.T @ J + mu * np.eye(J.shape[1]), J.T @ rhs) * p.gain
            big = float(np.linalg.norm(omega.reshape(-1, 3), axis=1).max())
            if big > p.max_step:
                omega *= p.max_step / big
            m_new = np.array([_rotate(md, w) for md, w in zip(mem.m_des, omega.reshape(-1, 3))])
            if self._misalignment(m_new, plan.dipoles_W) <= p.max_deviation:
                mem.m_des = m_new
        return f_est, float(np.linalg.norm(o))

    def _beyond_wall(self, plan: TargetPlan, tip: np.ndarray, h: np.ndarray | None) -> float:
        """How far the measured tip lies beyond the target's centre, out of the chamber along
        the wall's normal [m] (the sheath's tracked offset ``h`` moves the target)."""
        d = tip - plan.p_WT - 0.5 * self.estimator.chain.ball_diameter * plan.n_W
        if h is not None:
            d = d - h
        return -float(plan.n_W @ d)

    @staticmethod
    def _misalignment(m: np.ndarray, m_des: np.ndarray) -> float:
        """The largest angle between a measured dipole and its desired one [rad]."""
        # min/max clip a dot product (a NaN too) as np.clip does, without its wrapping.
        return max(float(np.arccos(min(max(float(a @ b), -1.0), 1.0))) for a, b in zip(m, m_des))

    def _sticks(self, m: np.ndarray, m_des: np.ndarray) -> np.ndarray:
        """Joystick axes turning each measured dipole towards its desired one (world mapping:
        axes = magnet angular velocity / omega_max, past the dead band)."""
        p = self.params
        sticks = np.zeros((len(m), 3))
        band, rest = p.dead_band, 1.0 - p.dead_band
        for j, (a, b) in enumerate(zip(m, m_des)):
            axis = cross(a, b)
            sin = float(np.linalg.norm(axis))
            angle = float(np.arctan2(sin, a @ b))
            if angle < p.hold_band:
                continue
            # The numpy expressions' element-wise operations on plain floats, in their order.
            gain, d = min(p.magnet_gain * angle, 1.0), max(sin, 1e-12)
            u = [gain * x / d for x in axis.tolist()]
            if not all(map(isfinite, u)):  # a NaN or an inf: the numpy expressions (NaN-propagating)
                u = min(p.magnet_gain * angle, 1.0) * axis / max(sin, 1e-12)
                u /= max(float(np.abs(u).max()), 1.0)
                sticks[j] = np.where(np.abs(u) > 1e-6, np.sign(u) * (band + rest * np.abs(u)), 0.0)
                continue
            scale = max(abs(u[0]), abs(u[1]), abs(u[2]), 1.0)  # no axis beyond full speed
            # Past the mapper's dead band, axis by axis (it subtracts it and rescales).
            sticks[j] = [copysign(band + rest * abs(x / scale), x) if abs(x / scale) > 1e-6 else 0.0 for x in u]
        return sticks
