"""The chain feeder: a NEMA17 stepper pushing a PLA filament through a Bowden tube.

The ball chain is attached to the filament's tip; the stepper's drive gear (effective diameter
``gear_diameter``) advances the filament by ``pi gear_diameter / (200 microsteps)`` per
microstep. The inserted length is measured from the sheath tip (0: the first ball still inside)
and is limited to 0..chain length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from ballchain.drake_models.arg_checks import require_positive, require_type
from ballchain.drake_models.errors import UserInputError, check_finite_input, require_finite_fields
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
        v_insert_cmd: (1,) commanded insertion speed [m/s] (negative retracts).

    Output ports:
        inserted_length: (1,) length beyond the sheath tip, whole microsteps [m].
        balls_out: (1,) number of whole balls beyond the sheath tip.

    State (discrete, period ``spec.update_period``): ``speed`` (1) [m/s], ``length_command``
    (1) [m], ``microsteps`` (1) [count].
    """

    def __init__(self, chain: BallChain | None = None, spec: FeederSpec | None = None, name: str = "feeder",
                 initial_length: float = 0.0) -> None:
        """
        Args:
            chain: the chain being fed (its length is the end stop).
            spec: feeder figures.
            name: system name.
            initial_length: inserted length in the default state [m], in 0..chain length
                (rounded to whole microsteps).
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
        self._dt = float(self._spec.update_period)
        self._max_speed = float(self._spec.max_speed)
        self._dv = float(self._spec.max_acceleration * self._spec.update_period)
        self._v_port = self.DeclareVectorInputPort("v_insert_cmd", 1)
        self._speed_index = self.DeclareDiscreteState(1)
        self._length_index = self.DeclareDiscreteState(BasicVector([float(initial_length)]))
        self._steps_index = self.DeclareDiscreteState(
            BasicVector([float(np.round(initial_length / self._spec.step_length))]))
        self._length_port = self.DeclareVectorOutputPort("inserted_length", 1, self._calc_length)
        self._balls_port = self.DeclareVectorOutputPort("balls_out", 1, self._calc_balls)
        self.DeclarePeriodicDiscreteUpdateEvent(self._spec.update_period, 0.0, self._update)

    @property
    def spec(self) -> FeederSpec:
        return self._spec

    def _update(self, context, discrete_state):
        # Plain floats throughout (500 updates a second): min/max clip a finite number as
        # np.clip does, and round() rounds half to even as np.round does.
        dt = self._dt
        # np.clip keeps a NaN: refuse it here, naming the feeder, the port and the time.
        command = float(check_finite_input(self, self._v_port, context)[0])
        target = min(max(command, -self._max_speed), self._max_speed)
        dv = self._dv
        state = context.get_discrete_state()
        v = state.value(self._speed_index).item()
        v += min(max(target - v, -dv), dv)
        x = state.value(self._length_index).item() + v * dt
        if x <= 0.0 or x >= self._chain_length:  # end stops: stop there, no wind-up
            x = min(max(x, 0.0), self._chain_length)
            v = 0.0
        discrete_state.get_mutable_value(self._speed_index)[0] = v
        discrete_state.get_mutable_value(self._length_index)[0] = x
        # Whole microsteps, never past the end stops.
        steps = min(float(round(x / self._step_length)), self._max_steps)
        discrete_state.get_mutable_value(self._steps_index)[0] = steps

    def _length(self, context) -> float:
        return context.get_discrete_state(self._steps_index).GetAtIndex(0) * self._spec.step_length

    def _calc_length(self, context, output):
        output.SetAtIndex(0, self._length(context))

    def _calc_balls(self, context, output):
        # A ball counts once its far side has cleared the tip; the tolerance absorbs round-off.
        output.SetAtIndex(0, float(np.floor(self._length(context) / self._chain.ball_diameter + 1e-9)))
