"""Three stepper-driven omni-wheels: desired magnet angular velocity in, applied wheel speeds out.

The commanded magnet angular velocity goes through the derived inverse map
``omega_wheels = (rho_a/rho_w) A omega_W`` (``drake_models/omniwheel.py``), is scaled down as a
whole if any wheel would exceed the speed limit (so the rotation axis is kept), is rate-limited
per wheel (the steppers' acceleration limit), and is integrated into a commanded wheel angle.
Each stepper can only stand on whole microsteps, so the wheel angle is quantised; the applied
wheel speed over each period is the microsteps moved times the microstep angle divided by the
period, which makes the magnet turn by exactly the quantised wheel angles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import LeafSystem

from ballchain.infrastructure.arg_checks import require_type
from ballchain.infrastructure.errors import UserInputError, check_finite_input
from ballchain.drake_models.omniwheel import OmniWheelGeometry


@dataclass(frozen=True)
class StepperSpec:
    """Stepper motor and driver figures (defaults: a 1.8 deg NEMA17, 1/16 microstepping).

    Attributes:
        step_angle_deg: full-step angle [deg].
        microsteps: microsteps per full step.
        max_speed: wheel speed limit [rad/s].
        max_acceleration: wheel acceleration limit [rad/s^2].
        update_period: period at which the step generator re-plans the speed profile [s]; the
            wheel angle stays quantised to whole microsteps whatever the period (5 ms: twice
            the Hall sensor's rate, and half the simulation cost of 2 ms for the same result).
    """

    step_angle_deg: float = 1.8
    microsteps: int = 16
    max_speed: float = 2.0 * np.pi
    max_acceleration: float = 50.0
    update_period: float = 5e-3

    def __post_init__(self) -> None:
        for name in ("step_angle_deg", "max_speed", "max_acceleration", "update_period"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise UserInputError(f"StepperSpec.{name} must be positive, got {value!r}")
        if int(self.microsteps) != self.microsteps or self.microsteps < 1:
            raise UserInputError(f"StepperSpec.microsteps must be an integer >= 1, got {self.microsteps!r}")

    @property
    def microstep_angle(self) -> float:
        """[rad] (1.96e-3 rad = 0.1125 deg by default)."""
        return np.deg2rad(self.step_angle_deg) / self.microsteps


def saturate_uniformly(omega: np.ndarray, limit: float) -> np.ndarray:
    """Scale a vector of wheel speeds so that none exceeds ``limit``, keeping its direction."""
    peak = float(np.max(np.abs(omega)))
    return omega if peak <= limit else omega * (limit / peak)


class OmniWheelDrive(LeafSystem):
    """Stepper-driven omni-wheel drive of one actuation unit.

    Input ports:
        omega_desired_W: (3,) desired magnet angular velocity in world [rad/s].

    Output ports:
        omega_wheels: (3,) applied wheel speeds over the current period [rad/s]
            (microsteps moved x microstep angle / period).
        wheel_angles: (3,) wheel angles, whole microsteps [rad].
        wheel_speed_setpoint: (3,) rate- and speed-limited speed the step generator follows [rad/s].

    State (discrete, period ``spec.update_period``): ``speed`` (3) [rad/s], ``angle_command``
    (3) [rad], ``microsteps`` (3) [count], ``applied`` (3) [rad/s].
    """

    def __init__(
        self,
        geometry: OmniWheelGeometry | None = None,
        spec: StepperSpec | None = None,
        name: str = "right_unit",
    ) -> None:
        super().__init__()
        if geometry is not None:
            require_type(geometry, OmniWheelGeometry, "OmniWheelDrive geometry", "an OmniWheelGeometry or None")
        if spec is not None:
            require_type(spec, StepperSpec, "OmniWheelDrive spec", "a StepperSpec or None")
        self._geometry = geometry or OmniWheelGeometry()
        self._spec = spec or StepperSpec()
        self.set_name(f"{name}.drive")
        self._microstep_angle = float(self._spec.microstep_angle)
        self._dt = float(self._spec.update_period)
        self._dv = float(self._spec.max_acceleration * self._spec.update_period)
        # The wheel command of the last desired angular velocity (a teleoperation command holds
        # for many updates): (omega_desired_W.tobytes(), target list), see ``_target``.
        self._last_target: tuple[bytes, list[float]] | None = None

        self._omega_port = self.DeclareVectorInputPort("omega_desired_W", 3)
        self._speed_index = self.DeclareDiscreteState(3)
        self._angle_index = self.DeclareDiscreteState(3)
        self._steps_index = self.DeclareDiscreteState(3)
        self._applied_index = self.DeclareDiscreteState(3)
        self._applied_port = self.DeclareStateOutputPort("omega_wheels", self._applied_index)
        self._angles_port = self.DeclareVectorOutputPort("wheel_angles", 3, self._calc_angles,
                                                         prerequisites_of_calc={self.xd_ticket()})
        self._speed_port = self.DeclareStateOutputPort("wheel_speed_setpoint", self._speed_index)
        self.DeclarePeriodicDiscreteUpdateEvent(self._spec.update_period, 0.0, self._update)

    @property
    def spec(self) -> StepperSpec:
        return self._spec

    def wheel_command(self, omega_desired_W: np.ndarray) -> np.ndarray:
        """(3,) wheel speeds [rad/s] for a desired magnet angular velocity, speed-limited."""
        return saturate_uniformly(self._geometry.wheel_speeds(omega_desired_W), self._spec.max_speed)

    def _target_checked(self, context, omega_desired=None) -> list[float]:
        """The speed-limited wheel command of the desired angular velocity on the input (or of
        its value ``omega_desired``, already evaluated)."""
        # A NaN command would pass the speed limit (max |NaN| is NaN) and reach the magnet.
        return self.wheel_command(check_finite_input(self, self._omega_port, context, omega_desired)).tolist()

    def _target(self, context) -> list[float]:
        """``_target_checked``, remembered for the last input value (a NaN input is never
        remembered, so it is refused at every update). The list returned is shared: read it."""
        omega_desired = self._omega_port.Eval(context)
        key = omega_desired.tobytes()
        last = self._last_target
        if last is None or last[0] != key:
            last = self._last_target = (key, self._target_checked(context, omega_desired))
        return last[1]

    def _update(self, context, discrete_state):
        # Element by element on plain floats (200 updates a second, three wheels): min/max clip
        # as np.clip does and round() rounds half to even as np.round does.
        dt = self._dt
        step = self._microstep_angle
        target = self._target(context)
        state = context.get_discrete_state()
        dv = self._dv
        speed_old = state.value(self._speed_index).tolist()
        angle_old = state.value(self._angle_index).tolist()
        steps_old = state.value(self._steps_index).tolist()
        speed = [v + min(max(t - v, -dv), dv) for t, v in zip(target, speed_old)]
        angle = [a + v * dt for a, v in zip(angle_old, speed)]
        steps = [float(round(a / step)) for a in angle]
        discrete_state.set_value(self._speed_index, np.array(speed))
        discrete_state.set_value(self._angle_index, np.array(angle))
        discrete_state.set_value(self._steps_index, np.array(steps))
        discrete_state.set_value(self._applied_index,
                                 np.array([(n - n_old) * step / dt for n, n_old in zip(steps, steps_old)]))

    def _calc_angles(self, context, output):
        output.SetFromVector(
            context.get_discrete_state(self._steps_index).CopyToVector() * self._spec.microstep_angle
        )
