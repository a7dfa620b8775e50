"""Axis reconfiguration: turn the magnet back to its neutral direction using the Hall sensor.

The paper's law (Section IV-B) is ``omega_w = K eta^-1 A^-1 (m_meas x m_c)``: it asks the magnet
to turn at ``omega_W = K (m_meas x m_c)``, which makes ``d m/dt = omega_W x m`` point towards
``m_c``, and converts that to wheel speeds. With the derived kinematics
(``drake_models/omniwheel.py``) the conversion is ``omega_w = (rho_a/rho_w) A omega_W``; the
paper's printed ``eta^-1 A^-1`` is kept as an option (``wheel_map="paper"``) for comparison:
on the real wheels it turns the magnet at ``C K (m x m_c)`` with ``C`` about ``eta^-2 (A^T)^2``,
a 26.6 deg rotation with gain 1.22. Below 90 deg the error still falls, so the closed loop hides
the mistake; open loop (teleoperation) the magnet would turn about an axis 26.6 deg off.

What the paper leaves open and this controller decides:

* Antiparallel start (docs/design.md, 4.5): ``m x m_c`` vanishes at 180 deg, so the law stalls. Within
  ``antiparallel_deg`` of antiparallel the controller turns at the law's speed at the edge of
  that cone, ``K sin(antiparallel_deg)``, about the cross product's direction if it is resolvable
  and otherwise about a fixed axis perpendicular to ``m_c``.
* Wheel-speed saturation: the wheel vector is scaled as a whole, so the rotation axis is kept.
* Termination: ``done`` latches once the measured error is below ``tolerance_deg``; the wheel
  command is then zero (the paper runs the law "until convergence").
* Requests: the latch belongs to one reconfiguration. Each time the unit's mode goes to 1
  (reconfiguration) a new one starts: ``done`` clears at that sample and the error is measured
  afresh, so a unit that started neutral, or finished an earlier reconfiguration, and was then
  turned by teleoperation goes back to neutral when asked again.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import EventStatus, LeafSystem

from ballchain.infrastructure.arg_checks import as_vector, require_type
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.omniwheel import OmniWheelGeometry, paper_wheel_speeds
from ballchain.drake_models.vectors import angle_between, cross, perpendicular_axis
from ballchain.systems.omni_wheel_drive import saturate_uniformly
from ballchain.systems.teleoperation import ModeSwitch
from ballchain.systems.unit_config import MagnetUnitConfig


ANTIPARALLEL_DEG = 5.0  # the default half-angle of the stall fix's cone around -m_c [deg]


class ReconfigurationController(LeafSystem):
    """Closed-loop return of the magnet's dipole to the neutral direction ``m_c``.

    Input ports:
        m_hat_measured_W: (3,) estimated dipole direction (zeros = no reading: command zero).
        mode: (1,) the unit's mode, from the same source as its mode switch's (0 teleoperation,
            1 reconfiguration, rounded): its going to 1 is a reconfiguration request.

    Output ports:
        omega_wheels_cmd: (3,) wheel speeds by the law, saturated [rad/s].
        omega_desired_W: (3,) magnet angular velocity those wheel speeds make without slip
            [rad/s] (the drive's input).
        done: (1,) 1.0 once converged (latched until the next request), else 0.0.
        angle_error: (1,) measured angle between m_hat and m_c [rad].

    State: discrete ``done`` (1) and the mode seen at the last update (1: 1.0 reconfiguration,
    else 0.0; 0.0 before the first), both updated every ``period`` seconds (the sensor's sample
    period).
    """

    def __init__(
        self,
        m_c_W: np.ndarray,
        *,
        gain: float = MagnetUnitConfig.controller_gain,
        max_wheel_speed: float = 2.0 * np.pi,
        tolerance_deg: float = MagnetUnitConfig.tolerance_deg,
        antiparallel_deg: float = ANTIPARALLEL_DEG,
        period: float = 0.01,
        geometry: OmniWheelGeometry | None = None,
        wheel_map: str = MagnetUnitConfig.wheel_map,
        name: str = "right_unit",
    ) -> None:
        """
        Args:
            m_c_W: (3,) neutral dipole direction (normalised here).
            gain: K [1/s] (defaults: a unit's, ``unit_config.MagnetUnitConfig``).
            max_wheel_speed: saturation of the wheel command [rad/s].
            tolerance_deg: measured error at which ``done`` latches [deg].
            antiparallel_deg: half-angle of the cone around -m_c where the stall fix applies [deg].
            period: update period of the done latch [s].
            geometry: omni-wheel geometry.
            wheel_map: "derived" (``(rho_a/rho_w) A``) or "paper" (``eta^-1 A_paper^-1`` as printed).
            name: unit name for the system name.
        """
        super().__init__()
        as_vector(m_c_W, "ReconfigurationController m_c_W", nonzero=True)
        if geometry is not None:
            require_type(geometry, OmniWheelGeometry, "ReconfigurationController geometry",
                         "an OmniWheelGeometry or None")
        m_c = np.asarray(m_c_W, dtype=float).reshape(3)
        if not np.all(np.isfinite(m_c)) or np.linalg.norm(m_c) == 0:
            raise UserInputError(f"neutral direction must be finite and non-zero, got {m_c_W!r}")
        if gain <= 0 or max_wheel_speed <= 0 or tolerance_deg <= 0 or not (0 < antiparallel_deg < 90):
            raise UserInputError("gain, max_wheel_speed, tolerance_deg must be > 0 and antiparallel_deg in (0, 90)")
        self._m_c = m_c / np.linalg.norm(m_c)
        self._K = float(gain)
        self._max_speed = float(max_wheel_speed)
        self._tol = np.deg2rad(tolerance_deg)
        self._sin_cone = np.sin(np.deg2rad(antiparallel_deg))  # the law's speed at the cone's edge, over K
        self._g = geometry or OmniWheelGeometry()
        if wheel_map == "derived":
            self._to_wheels = self._g.wheel_speeds
        elif wheel_map == "paper":
            self._to_wheels = lambda omega: paper_wheel_speeds(omega, self._g)
        else:
            raise UserInputError(f"wheel_map must be 'derived' or 'paper', got {wheel_map!r}")
        self._fallback_axis = perpendicular_axis(self._m_c)
        self._zero_command = (np.zeros(3), self._g.sphere_angular_velocity(np.zeros(3)))
        self._last_command: tuple[bytes, tuple[np.ndarray, np.ndarray]] | None = None
        self.set_name(f"{name}.controller")

        self._m_port = self.DeclareVectorInputPort("m_hat_measured_W", 3)
        self._mode_port = self.DeclareVectorInputPort("mode", 1)
        self._done_index = self.DeclareDiscreteState(1)
        self._mode_index = self.DeclareDiscreteState(1)
        # Functions of the latch and the measurement alone: cached until one changes.
        ticket = {self.xd_ticket(), self.all_input_ports_ticket()}
        self._wheels_port = self.DeclareVectorOutputPort("omega_wheels_cmd", 3, self._calc_wheels,
                                                         prerequisites_of_calc=ticket)
        self._omega_port = self.DeclareVectorOutputPort("omega_desired_W", 3, self._calc_omega,
                                                        prerequisites_of_calc=ticket)
        self._done_port = self.DeclareStateOutputPort("done", self._done_index)
        self._angle_port = self.DeclareVectorOutputPort("angle_error", 1, self._calc_angle,
                                                        prerequisites_of_calc=ticket)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update_done)

    @property
    def m_c_W(self) -> np.ndarray:
        return self._m_c.copy()

    def desired_angular_velocity(self, m_hat: np.ndarray) -> np.ndarray:
        """The law ``K (m x m_c)`` [rad/s] with the antiparallel fix (before saturation)."""
        m_hat = np.asarray(m_hat, dtype=float)
        if not m_hat.any():
            return np.zeros(3)
        m_hat = m_hat / np.linalg.norm(m_hat)
        m_x_mc = cross(m_hat, self._m_c)
        if m_hat @ self._m_c < 0 and np.linalg.norm(m_x_mc) < self._sin_cone:
            # Near antiparallel the cross product is tiny and noisy: turn at the law's speed at
            # the cone's edge, about its direction if resolvable, else about a fixed axis.
            n = np.linalg.norm(m_x_mc)
            axis = m_x_mc / n if n > 1e-3 * self._sin_cone else self._fallback_axis
            return self._K * self._sin_cone * axis
        return self._K * m_x_mc

    def wheel_command(self, m_hat: np.ndarray) -> np.ndarray:
        """(3,) saturated wheel speeds [rad/s] for a measured direction."""
        return saturate_uniformly(self._to_wheels(self.desired_angular_velocity(m_hat)), self._max_speed)

    def _is_done(self, context) -> bool:
        return bool(context.get_discrete_state(self._done_index).GetAtIndex(0) > 0.5)

    def _update_done(self, context, discrete_state):
        reconfiguring = round(float(self._mode_port.Eval(context)[0])) == ModeSwitch.RECONFIGURATION
        state = context.get_discrete_state()
        was_reconfiguring = state.value(self._mode_index).item() > 0.5
        requested = reconfiguring and not was_reconfiguring  # a new reconfiguration starts here
        latched = state.value(self._done_index).item() > 0.5 and not requested  # done, as _is_done
        mode, done = 1.0 if reconfiguring else 0.0, 1.0 if self._done_after(context, latched) else 0.0
        if mode == state.value(self._mode_index).item() and done == state.value(self._done_index).item():
            # Unchanged (the flags are exactly 0.0 or 1.0): the state is left as it is, so the
            # outputs that depend on it stay in Drake's cache (the mode switch's among them).
            return EventStatus.DidNothing()
        discrete_state.get_mutable_value(self._mode_index)[0] = mode
        discrete_state.get_mutable_value(self._done_index)[0] = done
        return EventStatus.Succeeded()

    def _done_after(self, context, latched: bool) -> bool:
        """Whether ``done`` holds after this update, given whether it stays latched."""
        if latched:  # the measurement is not needed (nor evaluated)
            return True
        m = self._m_port.Eval(context)
        return bool(m.any() and angle_between(m, self._m_c) < self._tol)

    def _command(self, context) -> tuple[np.ndarray, np.ndarray]:
        """(wheel speeds, the angular velocity they make) for the measurement on the input,
        remembered for the last measurement; zeros once done. The arrays are shared: read them."""
        if self._is_done(context):
            return self._zero_command
        m = self._m_port.Eval(context)
        key = m.tobytes()
        last = self._last_command
        if last is None or last[0] != key:
            wheels = self.wheel_command(m)
            last = self._last_command = (key, (wheels, self._g.sphere_angular_velocity(wheels)))  # the true forward map
        return last[1]

    def _calc_wheels(self, context, output):
        output.SetFromVector(self._command(context)[0])

    def _calc_omega(self, context, output):
        output.SetFromVector(self._command(context)[1])

    def _calc_angle(self, context, output):
        m = self._m_port.Eval(context)
        output.SetAtIndex(0, float(angle_between(m, self._m_c)) if m.any() else np.pi)
