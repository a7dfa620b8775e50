"""The chain feeder: a NEMA17 stepper pushing a PLA filament through a Bowden tube.

The ball chain is attached to the filament's tip; the stepper's drive gear (effective diameter
``gear_diameter``) advances the filament by ``pi gear_diameter / (200 microsteps)`` per
microstep. The inserted length is measured from the sheath tip (0: the first ball still inside)
and is limited to 0..chain length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem
from pydrake.trajectories import PiecewisePolynomial

from ballchain.infrastructure.arg_checks import require_positive, require_type
from ballchain.infrastructure.errors import UserInputError, check_finite_input, require_finite_fields
from ballchain.drake_models.params import BallChain


@dataclass(frozen=True)
class FeederSpec:
    """Feeder figures.

    Attributes:
        steps_per_rev: full steps per revolution (200 for 1.8 deg).
        microsteps: microsteps per full step.
        gear_diameter: effective drive-gear diameter on the filament [m].
        max_speed: insertion speed limit [m/s].
        max_acceleration: [m/s^2].
        update_period: step-generation period [s].
    """

    steps_per_rev: int = 200
    microsteps: int = 16
    gear_diameter: float = 11e-3
    max_speed: float = 20e-3
    max_acceleration: float = 100e-3
    update_period: float = 2e-3

    def __post_init__(self) -> None:
        require_finite_fields(self)
        for name in ("gear_diameter", "max_speed", "max_acceleration", "update_period"):
            if not getattr(self, name) > 0:
                raise UserInputError(f"FeederSpec.{name} must be positive, got {getattr(self, name)!r}")
        if self.steps_per_rev < 1 or self.microsteps < 1:
            raise UserInputError("FeederSpec.steps_per_rev and microsteps must be >= 1")

    @property
    def step_length(self) -> float:
        """Filament travel per microstep [m] (10.8 um by default)."""
        return np.pi * self.gear_diameter / (self.steps_per_rev * self.microsteps)


class Feeder(LeafSystem):
    """Insertion/retraction of the ball chain.

    Input ports:
        v_insert_cmd: (1,) commanded insertion speed [m/s] (negative retracts); absent with a
            ``schedule``.

    Output ports:
        inserted_length: (1,) length beyond the sheath tip, whole microsteps [m].
        balls_out: (1,) number of whole balls beyond the sheath tip.
    The end stops are ``min_length`` (default 0: the first ball still inside) and the chain's
    length: a command past one stops the feeder there (no wind-up). A live session sets
    ``min_length`` to the starting length, so that holding retract stops with the chain's
    first balls out in the heart instead of pulling them back into the sheath
    (``set_min_length``); ``end_stops`` gives both, for a system that drops a command against
    one (``MeshcatJoystick``).

    State (discrete, period ``spec.update_period``): ``speed`` (1) [m/s], ``length_command``
    (1) [m], ``microsteps`` (1) [count].

    With a ``command_period`` (a multiple of ``spec.update_period``), for a command that changes
    only at multiples of it (an operator's looks): the steps of a period are computed together,
    at its end, with the same arithmetic one by one, and the outputs in between add the steps
    already due (the same numbers as stepping every ``update_period``, for a fifth or less of
    the simulator steps). Two more states: ``next_step`` (1), the index k of the next step due
    (at k ``update_period``), and ``held_command`` (1), the command of the steps since the last
    batch [m/s]; both set at initialisation. The command must be set in periodic unrestricted
    updates at multiples of ``command_period`` (a simulated operator's or navigator's looks):
    the steps at a look's time already move under its new command, as when stepping alone.

    With a ``schedule`` (the speed command as a known function of time: a scenario's ramp) the
    feeder plays it itself and has no input port: step k moves under the schedule's value at
    its time k ``update_period``, what a ``TrajectorySource`` of the schedule would give it
    there. With a ``batch_period`` too, the steps are made in batches at its multiples (the
    steps at or before the batch's time) and the outputs in between add the steps due, each
    under the schedule at its own time: the same numbers as stepping alone, at any batch time,
    because the command of a past step is known. State ``next_step`` (1) as above.
    """

    def __init__(self, chain: BallChain | None = None, spec: FeederSpec | None = None, name: str = "feeder",
                 initial_length: float = 0.0, command_period: float | None = None,
                 schedule: PiecewisePolynomial | None = None, batch_period: float | None = None,
                 min_length: float = 0.0) -> None:
        """
        Args:
            chain: the chain being fed (its length is the end stop).
            spec: feeder figures.
            name: system name.
            initial_length: inserted length in the default state [m], in 0..chain length
                (rounded to whole microsteps).
            command_period: None (every step on its own), or a whole multiple of
                ``spec.update_period`` [s] at whose multiples alone ``v_insert_cmd`` changes
                (the class docstring; a command that changes in between would be applied late).
            schedule: None (the command comes in ``v_insert_cmd``), or the speed command [m/s]
                as a (1 x 1) zero-order-hold ``PiecewisePolynomial`` of time, finite, played by
                the feeder itself (no input port; not with ``command_period``).
            batch_period: with a ``schedule``, None (every step on its own) or a whole multiple
                of ``spec.update_period`` [s]: the steps made in batches at its multiples (for
                readers at those times, e.g. the quasi-static engine's updates).
            min_length: the retraction stop [m], in 0..``initial_length`` (``set_min_length``).
        """
        super().__init__()
        if chain is not None:
            require_type(chain, BallChain, "Feeder chain", "a BallChain or None")
        if spec is not None:
            require_type(spec, FeederSpec, "Feeder spec", "a FeederSpec or None")
        require_positive(initial_length, "Feeder initial_length", "m", allow_zero=True)
        self._chain = chain or BallChain()
        self._spec = spec or FeederSpec()
        if not 0.0 <= initial_length <= self._chain.length:
            raise UserInputError(f"Feeder initial_length {initial_length} m is outside 0..{self._chain.length} m")
        self.set_name(name)
        self._chain_length = float(self._chain.length)
        self._step_length = float(self._spec.step_length)
        self._max_steps = float(np.floor(self._chain_length / self._step_length))
        self._min_length = 0.0
        self.set_min_length(min_length, initial_length)
        self._dt = float(self._spec.update_period)
        self._max_speed = float(self._spec.max_speed)
        self._dv = float(self._spec.max_acceleration * self._spec.update_period)
        self._schedule = _checked_schedule(schedule)
        if schedule is not None and command_period is not None:
            raise UserInputError("Feeder: a schedule is its own command; command_period is for a command "
                                 "that comes in v_insert_cmd (give one or the other)")
        if schedule is None and batch_period is not None:
            raise UserInputError("Feeder batch_period needs a schedule (a command in v_insert_cmd is batched "
                                 "with command_period)")
        self._v_port = None if schedule is not None else self.DeclareVectorInputPort("v_insert_cmd", 1)
        self._speed_index = self.DeclareDiscreteState(1)
        self._length_index = self.DeclareDiscreteState(BasicVector([float(initial_length)]))
        self._steps_index = self.DeclareDiscreteState(
            BasicVector([float(np.round(initial_length / self._spec.step_length))]))
        period = batch_period if schedule is not None else command_period
        self._batch = batch_steps(period, self._dt, "batch_period" if schedule is not None else "command_period")
        self._command_period = None if command_period is None else float(command_period)
        # The outputs are functions of the time and the state alone (the command of the steps due
        # is held in the state): Drake's cache keeps them while neither changes (the engine and
        # the navigator read the length at the same step, the navigator's update between them).
        now = {self.time_ticket(), self.xd_ticket()}
        self._length_port = self.DeclareVectorOutputPort("inserted_length", 1, self._calc_length,
                                                         prerequisites_of_calc=now)
        self._balls_port = self.DeclareVectorOutputPort("balls_out", 1, self._calc_balls, prerequisites_of_calc=now)
        if self._batch == 1:
            self.DeclarePeriodicDiscreteUpdateEvent(self._spec.update_period, 0.0, self._update)
        elif schedule is not None:
            self._next_index = self.DeclareDiscreteState(1)
            self.DeclarePeriodicDiscreteUpdateEvent(float(batch_period), 0.0, self._update_played)
            self.DeclareInitializationDiscreteUpdateEvent(self._start)
        else:
            self._next_index = self.DeclareDiscreteState(1)
            self._held_index = self.DeclareDiscreteState(1)
            # The command's own period (the very event times of the system that sets it).
            self.DeclarePeriodicDiscreteUpdateEvent(float(command_period), 0.0, self._update_batch)
            self.DeclareInitializationDiscreteUpdateEvent(self._start)

    @property
    def spec(self) -> FeederSpec:
        return self._spec

    @property
    def min_length(self) -> float:
        """The retraction stop [m] (0: the first ball still inside the sheath)."""
        return self._min_length

    def set_min_length(self, min_length: float, initial_length: float | None = None) -> None:
        """Set the retraction stop [m]: from the next step, a retraction stops there. It must lie
        in 0..the chain's length and not above ``initial_length`` when given (the start)."""
        require_positive(min_length, "Feeder min_length", "m", allow_zero=True)
        top = self._chain_length if initial_length is None else min(initial_length, self._chain_length)
        if not 0.0 <= min_length <= top + 1e-12:
            raise UserInputError(f"Feeder min_length {min_length} m is outside 0..{top} m "
                                 "(the retraction stop lies between the first ball inside and the start)")
        self._min_length = float(min_length)

    def end_stops(self) -> tuple[float, float, float]:
        """(retraction stop, insertion stop, tolerance) [m]: an ``inserted_length`` within the
        tolerance (a microstep and a half: the length is whole microsteps) of a stop is at it."""
        return self._min_length, self._chain_length, 1.5 * self._step_length

    @property
    def command_period(self) -> float | None:
        """The period [s] at whose multiples alone the command changes (None: any step)."""
        return None if self._batch == 1 or self._schedule is not None else self._command_period

    @property
    def batch_period(self) -> float | None:
        """With a schedule, the period [s] of the batches (None: every step on its own)."""
        return self._batch * self._dt if self._schedule is not None and self._batch > 1 else None

    def _steps(self, v: float, x: float, command: float, n: int) -> tuple[float, float]:
        """(speed, length) after n steps at the speed command ``command`` [m/s], one by one."""
        # Plain floats throughout (500 steps a second): min/max clip a finite number as np.clip
        # does.
        target = min(max(command, -self._max_speed), self._max_speed)
        dv, dt, start, end = self._dv, self._dt, self._min_length, self._chain_length
        if n > 0 and target == 0.0 and v == 0.0 and start < x < end:
            # Held still between the stops: each step adds 0.0 to the speed and 0.0 * dt to the
            # length, which leaves a positive length as it is and the speed +0.0 (what the loop
            # below gives, a signed zero included; ``_steps_reference``).
            return 0.0, x
        low = -dv
        for _ in range(n):
            # min(max(a, lo), hi) written out as the builtins decide (max(a, b) is b only if
            # b > a, min(a, b) is b only if b < a): the same floats, NaN and signed zeros included.
            a = target - v
            a = low if low > a else a
            v += dv if dv < a else a
            x = x + v * dt
            if x <= start or x >= end:  # end stops: stop there, no wind-up
                x = start if start > x else x
                x = end if end < x else x
                v = 0.0
        return v, x

    def _steps_reference(self, v: float, x: float, command: float, n: int) -> tuple[float, float]:
        """``_steps`` as the plain loop with the builtins (the reference its shortcuts are held to)."""
        target = min(max(command, -self._max_speed), self._max_speed)
        dv, dt, start, end = self._dv, self._dt, self._min_length, self._chain_length
        for _ in range(n):
            v += min(max(target - v, -dv), dv)
            x = x + v * dt
            if x <= start or x >= end:
                x = min(max(x, start), end)
                v = 0.0
        return v, x

    def _microsteps(self, x: float) -> float:
        # Whole microsteps, never past the end stops; round() rounds half to even as np.round.
        return min(float(round(x / self._step_length)), self._max_steps)

    def _command(self, context) -> float:
        if self._schedule is not None:
            return self._scheduled(context.get_time())
        # np.clip keeps a NaN: refuse it here, naming the feeder, the port and the time.
        return float(check_finite_input(self, self._v_port, context)[0])

    def _scheduled(self, t: float) -> float:
        """The schedule's command at time t [m/s] (a TrajectorySource's output there)."""
        return float(self._schedule.value(t)[0, 0])

    def _play(self, v: float, x: float, first: int, end: int) -> tuple[float, float]:
        """(speed, length) after the steps first..end-1, step k under the schedule at k dt."""
        if end <= first:
            return 0.0, x
        dt, schedule = self._dt, self._schedule
        if schedule.get_segment_index(first * dt) == schedule.get_segment_index((end - 1) * dt):
            return self._steps(v, x, self._scheduled(first * dt), end - first)  # one command
        for k in range(first, end):
            v, x = self._steps(v, x, self._scheduled(k * dt), 1)
        return v, x

    def _write(self, discrete_state, v: float, x: float) -> None:
        discrete_state.get_mutable_value(self._speed_index)[0] = v
        discrete_state.get_mutable_value(self._length_index)[0] = x
        discrete_state.get_mutable_value(self._steps_index)[0] = self._microsteps(x)

    def _update(self, context, discrete_state):
        state = context.get_discrete_state()
        v, x = self._steps(state.value(self._speed_index).item(), state.value(self._length_index).item(),
                           self._command(context), 1)
        self._write(discrete_state, v, x)

    # --- steps in batches (command_period) ------------------------------------------------------
    # Drake makes a step's unrestricted updates first (an operator's look sets the command), then
    # its discrete ones: a feeder step at the look's very time moves under the new command, one
    # whose time k dt falls just before the look's (round-off: k dt < j T) under the old one, as
    # do the steps since the last look. A batch, at the look's time (the command's own period,
    # the very same event times), makes the steps since the last batch under the command held
    # from it, the step at its time under the command seen now when that step is not earlier,
    # and holds the command seen now for the steps to come.
    def _first_due(self, t: float) -> int:
        """The index of the first step at or after time t (Drake's periodic event times k dt)."""
        k = round(t / self._dt)
        return k if k * self._dt >= t else k + 1

    def _start(self, context, discrete_state):
        """The first step due (at or after the start: Drake's periodic events fire at the start
        itself when it is one of their times), and the command held until the first batch."""
        discrete_state.get_mutable_value(self._next_index)[0] = float(self._first_due(context.get_time()))
        if self._schedule is None:
            discrete_state.get_mutable_value(self._held_index)[0] = self._command(context)

    def _update_played(self, context, discrete_state):
        """A batch of a schedule: the steps due at or before this time (step k at k dt)."""
        state = context.get_discrete_state()
        t = context.get_time()
        end = round(t / self._dt)
        end = end + 1 if end * self._dt <= t else end  # past the last step at or before t
        first = int(state.value(self._next_index).item())
        if end > first:
            v, x = self._play(state.value(self._speed_index).item(), state.value(self._length_index).item(),
                              first, end)
            self._write(discrete_state, v, x)
            discrete_state.get_mutable_value(self._next_index)[0] = float(end)

    def _update_batch(self, context, discrete_state):
        state = context.get_discrete_state()
        t = context.get_time()
        k = round(t / self._dt)  # the step at this batch's time, give or take round-off
        v, x = state.value(self._speed_index).item(), state.value(self._length_index).item()
        held, command = state.value(self._held_index).item(), self._command(context)
        n = k + 1 - int(state.value(self._next_index).item())
        if n > 0:
            earlier = k * self._dt < t  # step k fell just before the look: the old command
            v, x = self._steps(v, x, held, n if earlier else n - 1)
            if not earlier:
                v, x = self._steps(v, x, command, 1)
            self._write(discrete_state, v, x)
            discrete_state.get_mutable_value(self._next_index)[0] = float(k + 1)
        discrete_state.get_mutable_value(self._held_index)[0] = command

    def _due(self, context) -> int:
        """Steps due before this context's time t and not yet made (batches only): at time t,
        stepping every period has made the steps before t (those at t come with t's updates),
        each under the command held since the last batch."""
        if self._batch == 1:
            return 0
        return max(self._first_due(context.get_time())
                   - int(context.get_discrete_state(self._next_index).GetAtIndex(0)), 0)

    def _length(self, context) -> float:
        due = self._due(context)
        if due:
            state = context.get_discrete_state()
            v, x = state.value(self._speed_index).item(), state.value(self._length_index).item()
            if self._schedule is not None:
                first = int(state.value(self._next_index).item())
                x = self._play(v, x, first, first + due)[1]
            else:
                x = self._steps(v, x, state.value(self._held_index).item(), due)[1]
            return self._microsteps(x) * self._spec.step_length
        return context.get_discrete_state(self._steps_index).GetAtIndex(0) * self._spec.step_length

    def _calc_length(self, context, output):
        output.SetAtIndex(0, self._length(context))

    def _calc_balls(self, context, output):
        # A ball counts once its far side has cleared the tip; the tolerance absorbs round-off.
        output.SetAtIndex(0, float(np.floor(self._length(context) / self._chain.ball_diameter + 1e-9)))


def _checked_schedule(schedule) -> PiecewisePolynomial | None:
    """The feeder's schedule, checked: None, or a finite (1 x 1) zero-order hold."""
    if schedule is None:
        return None
    require_type(schedule, PiecewisePolynomial, "Feeder schedule", "a PiecewisePolynomial or None")
    segments = range(schedule.get_number_of_segments())
    if (schedule.rows(), schedule.cols()) != (1, 1) or any(schedule.getSegmentPolynomialDegree(i) for i in segments):
        raise UserInputError(f"Feeder schedule must be a (1 x 1) zero-order hold of the speed [m/s], got "
                             f"{schedule.rows()} x {schedule.cols()} of degrees "
                             f"{sorted({schedule.getSegmentPolynomialDegree(i) for i in segments})}")
    values = [schedule.value(t)[0, 0] for t in schedule.get_segment_times()]
    if not np.all(np.isfinite(values)):
        raise UserInputError(f"Feeder schedule's speeds must be finite, got {values}")
    return schedule


def batch_steps(command_period: float | None, update_period: float, name: str = "command_period") -> int:
    """How many feeder steps (``update_period`` [s]) one ``command_period`` [s] holds: 1 for None;
    UserInputError (naming the feeder's ``name``) unless it is a finite whole multiple (>= 1) of
    the step period."""
    if command_period is None:
        return 1
    n = whole_steps(command_period, update_period)
    if n < 1:
        raise UserInputError(f"feeder {name} must be a whole multiple of the step period "
                             f"{update_period:g} s, got {command_period!r}")
    return n


def whole_steps(period, update_period: float) -> int:
    """How many feeder steps (``update_period`` [s]) ``period`` [s] holds when it is a finite whole
    multiple (>= 1) of them, else 0."""
    ratio = period / update_period if isinstance(period, (int, float)) else math.nan
    n = round(ratio) if math.isfinite(ratio) else 0
    return n if n >= 1 and abs(ratio - n) <= 1e-9 * n else 0
