"""Joystick teleoperation: stick axes to a commanded magnet angular velocity, and the mode switch.

Two mappings:

* ``frame="world"`` (the paper, Section IV-A): the three axes (after the dead band) scale the
  magnet's angular velocity about world x, y, z: ``omega_W = omega_max u``.
* ``frame="tip"`` (the paper's stated future work): axes 0 and 1 swing the field direction at
  the catheter tip, which the tip follows, about the tip frame's z and -y axes (tip frame: x
  along the tip direction, y horizontal). The wanted field rate ``dB/dt = omega_B x B(p_T)`` is
  converted to the dipole rate with the inverse dipole law (``moment_from_field``; the field is
  linear in m) and to the smallest magnet angular velocity ``omega = m x dm/dt / |m|^2`` that
  makes it. Only the part of ``dm/dt`` perpendicular to m is reachable by pure rotation, but the
  part along m would only scale ``|B|``, so the field *direction* at the tip turns exactly as
  asked (its magnitude drifts). Axis 2 is unused in this mode.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import LeafSystem

from ballchain.drake_models.dipole import dipole_field
from ballchain.drake_models.dipole_inversion import moment_from_field
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.vectors import cross
from ballchain.systems.unit_config import MagnetUnitConfig

E3 = np.array([0.0, 0.0, 1.0])


def apply_dead_band(u: np.ndarray, dead_band: float) -> np.ndarray:
    """Clamp stick axes to [-1, 1], zero them inside the dead band, rescale the rest to [-1, 1]."""
    u = np.clip(np.asarray(u, dtype=float), -1.0, 1.0)
    mag = np.maximum(np.abs(u) - dead_band, 0.0) / (1.0 - dead_band)
    return np.sign(u) * mag


def tip_frame(tip_direction_W: np.ndarray) -> np.ndarray:
    """(3, 3) columns x_T (tip direction), y_T (horizontal), z_T = x_T x y_T."""
    x = np.asarray(tip_direction_W, dtype=float)
    x = x / np.linalg.norm(x)
    y = cross(E3, x)
    if np.linalg.norm(y) < 1e-6:  # tip vertical: any horizontal y will do, take world y
        y = np.array([0.0, 1.0, 0.0])
    y = y / np.linalg.norm(y)
    return np.column_stack([x, y, cross(x, y)])


def magnet_rate_for_tip_rotation(
    omega_B_W: np.ndarray, m_W: np.ndarray, p_WM: np.ndarray, p_WT: np.ndarray
) -> np.ndarray:
    """Magnet angular velocity (3,) [rad/s] that rotates the field at p_WT at omega_B_W (3,) [rad/s].

    Args:
        omega_B_W: desired angular velocity of the field direction at the tip [rad/s].
        m_W: (3,) magnet dipole [A m^2].
        p_WM: (3,) magnet centre [m].
        p_WT: (3,) tip position [m].
    """
    r = np.asarray(p_WT, dtype=float) - np.asarray(p_WM, dtype=float)
    m = np.asarray(m_W, dtype=float)
    B = dipole_field(r, m)
    m_dot = moment_from_field(cross(np.asarray(omega_B_W, dtype=float), B), r)  # B is linear in m
    return cross(m, m_dot) / (m @ m)


class TeleoperationMapper(LeafSystem):
    """Joystick axes to a commanded magnet angular velocity in world.

    Input ports:
        joystick: (3,) stick axes in [-1, 1] (values outside are clamped).
        m_W: (3,) the magnet's dipole [A m^2] (``frame="tip"`` only).
        p_WT: (3,) tip position [m] (``frame="tip"`` only).
        tip_direction_W: (3,) tip direction, any length (``frame="tip"`` only).

    Output ports:
        omega_desired_W: (3,) commanded magnet angular velocity [rad/s].
    """

    def __init__(
        self,
        *,
        frame: str = MagnetUnitConfig.teleop_frame,
        omega_max: float = MagnetUnitConfig.teleop_omega_max,
        dead_band: float = MagnetUnitConfig.teleop_dead_band,
        p_WM: np.ndarray | None = None,
        name: str = "right_unit",
    ) -> None:
        """
        Args:
            frame: "world" (paper) or "tip" (field rotation in the tip's frame). (Defaults: a
                unit's, ``unit_config.MagnetUnitConfig``.)
            omega_max: angular speed at full stick [rad/s] (magnet in "world", field at the tip
                in "tip").
            dead_band: fraction of the stick travel ignored around centre, in [0, 1).
            p_WM: (3,) magnet centre [m], needed for ``frame="tip"``.
            name: unit name for the system name.
        """
        super().__init__()
        if frame not in ("world", "tip"):
            raise UserInputError(f"frame must be 'world' or 'tip', got {frame!r}")
        if not (0.0 <= dead_band < 1.0) or not omega_max > 0:
            raise UserInputError("dead_band must be in [0, 1) and omega_max > 0")
        if frame == "tip" and p_WM is None:
            raise UserInputError("frame='tip' needs the magnet centre p_WM")
        self._frame = frame
        self._omega_max = float(omega_max)
        self._dead_band = float(dead_band)
        self._p_WM = None if p_WM is None else np.asarray(p_WM, dtype=float).reshape(3)
        self.set_name(f"{name}.teleoperation")
        # frame "world": the command of the last stick position (held for many drive updates):
        # (joystick.tobytes(), omega_desired_W), see ``_calc``.
        self._last_world: tuple[bytes, np.ndarray] | None = None
        self._joy_port = self.DeclareVectorInputPort("joystick", 3)
        if frame == "tip":
            self._m_port = self.DeclareVectorInputPort("m_W", 3)
            self._p_port = self.DeclareVectorInputPort("p_WT", 3)
            self._t_port = self.DeclareVectorInputPort("tip_direction_W", 3)
        # A function of the inputs alone: cached until one changes (not at every step).
        self._omega_port = self.DeclareVectorOutputPort("omega_desired_W", 3, self._calc,
                                                        prerequisites_of_calc={self.all_input_ports_ticket()})

    def _world_command(self, joystick: np.ndarray) -> np.ndarray:
        """frame "world": ``omega_max`` times the stick after the dead band."""
        return self._omega_max * apply_dead_band(joystick, self._dead_band)

    def _calc(self, context, output):
        joystick = self._joy_port.Eval(context)
        if self._frame == "world":  # remembered for the last stick position
            key = joystick.tobytes()
            last = self._last_world
            if last is None or last[0] != key:
                last = self._last_world = (key, self._world_command(joystick))
            output.SetFromVector(last[1])
            return
        u = apply_dead_band(joystick, self._dead_band)
        R_WT = tip_frame(self._t_port.Eval(context))
        omega_B = self._omega_max * (u[0] * R_WT[:, 2] - u[1] * R_WT[:, 1])
        output.SetFromVector(
            magnet_rate_for_tip_rotation(omega_B, self._m_port.Eval(context), self._p_WM, self._p_port.Eval(context))
        )


class ModeSwitch(LeafSystem):
    """Selects the magnet angular-velocity command: teleoperation or reconfiguration.

    Input ports:
        mode: (1,) 0 = teleoperation, 1 = reconfiguration (rounded).
        omega_teleop_W: (3,) [rad/s].
        omega_reconfigure_W: (3,) [rad/s].

    Output ports:
        omega_desired_W: (3,) the selected command [rad/s].
    """

    TELEOPERATION = 0
    RECONFIGURATION = 1

    def __init__(self, name: str = "right_unit") -> None:
        super().__init__()
        self.set_name(f"{name}.mode_switch")
        self._mode_port = self.DeclareVectorInputPort("mode", 1)
        self._teleop_port = self.DeclareVectorInputPort("omega_teleop_W", 3)
        self._reconf_port = self.DeclareVectorInputPort("omega_reconfigure_W", 3)
        self.DeclareVectorOutputPort("omega_desired_W", 3, self._calc,
                                     prerequisites_of_calc={self.all_input_ports_ticket()})  # the inputs alone

    def _calc(self, context, output):
        mode = int(round(float(self._mode_port.Eval(context)[0])))
        if mode == self.RECONFIGURATION:
            output.SetFromVector(self._reconf_port.Eval(context))
        elif mode == self.TELEOPERATION:
            output.SetFromVector(self._teleop_port.Eval(context))
        else:
            raise ValueError(f"{self.get_name()}: mode must be 0 (teleoperation) or 1 (reconfiguration), got {mode}")
