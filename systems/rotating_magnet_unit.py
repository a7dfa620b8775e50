"""A rotating actuation magnet on three omni-wheels, as a Drake LeafSystem.

The magnet (prototype cylinder or clinical sphere) sits inside a sphere that three omni-wheels
turn in place; its centre ``p_WM`` never moves. Its orientation ``R_WM`` is a unit quaternion
driven by the wheel speeds through the derived forward map
``omega_W = (1 - slip) (rho_w/rho_a) A^-1 omega_wheels`` (``drake_models/omniwheel.py``). The
field it makes comes from the shared ``MagnetSource`` (dipole or exact cylinder).

The quaternion is continuous state (integrated by the simulator) by default. With an
``update_period`` it is discrete state instead, exact for wheel speeds that are constant over
each period (the omni-wheel drive holds its applied speeds over its own update period: pass that
period): at each update the quaternion turns by the rotation ``exp(omega_W dt)`` the last
period's speed made, and the outputs in between are the same rotation carried to the context's
time. A diagram without continuous state takes no integrator sub-steps and evaluates no
derivatives.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import BasicVector, Context, LeafSystem

from ballchain.infrastructure.errors import check_finite_input
from ballchain.drake_models.field_sources import MagnetSource
from ballchain.systems.unit_config import MagnetUnitConfig, right_unit
from ballchain.infrastructure.arg_checks import as_array, require_type

# Pull |q| back to 1 at this rate [1/s]: the quaternion ODE conserves the norm exactly, so
# this only removes integrator drift and never changes the rotation.
QUATERNION_NORM_GAIN = 10.0


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """(4,) unit quaternion (w, x, y, z) of a rotation matrix (3, 3)."""
    return RotationMatrix(np.asarray(R, dtype=float)).ToQuaternion().wxyz()


def rotation_from_quaternion(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix of a (not necessarily unit) quaternion (w, x, y, z)."""
    return _rotation_matrix(q).matrix()


def _norm(q: np.ndarray) -> float:
    """``np.linalg.norm`` of a float vector, as it computes it (``sqrt(q.dot(q))``), without its
    argument handling (a quarter of the magnet's update)."""
    return math.sqrt(q.dot(q))


def _rotation_matrix(q: np.ndarray) -> RotationMatrix:
    """The RotationMatrix of a (not necessarily unit) quaternion (w, x, y, z)."""
    q = np.asarray(q, dtype=float)
    return RotationMatrix(Quaternion(q / _norm(q)))


def _turned(q: np.ndarray, omega_W: np.ndarray, dt: float) -> np.ndarray:
    """The quaternion q (w, x, y, z) turned for dt [s] at the constant world angular velocity
    omega_W (3,) [rad/s]: ``(cos(phi/2), sin(phi/2) axis) (x) q``, phi = |omega| dt.

    On plain floats (IEEE arithmetic, the same numbers as numpy's scalars); the cosine and sine
    are numpy's."""
    wx, wy, wz = omega_W.tolist()
    speed = math.sqrt(wx * wx + wy * wy + wz * wz)
    if speed * dt == 0.0:
        return q
    half = 0.5 * speed * dt
    c, k = float(np.cos(half)), float(np.sin(half)) / speed
    ax, ay, az = k * wx, k * wy, k * wz
    w, x, y, z = q.tolist()
    return np.array([
        c * w - ax * x - ay * y - az * z,
        c * x + ax * w + ay * z - az * y,
        c * y - ax * z + ay * w + az * x,
        c * z + ax * y - ay * x + az * w,
    ])


class RotatingMagnetUnit(LeafSystem):
    """The magnet's orientation, turned by three omni-wheels.

    Input ports:
        omega_wheels: (3,) wheel angular velocities [rad/s].

    Output ports:
        q_WM: (4,) orientation state, quaternion (w, x, y, z), unit norm up to integration error.
        X_WM: RigidTransform (abstract), pose of the magnet frame (z = dipole axis) [m].
        m_W: (3,) dipole moment in world [A m^2].
        omega_WM_W: (3,) the magnet's angular velocity in world [rad/s] (after slip).
        B_points_W: (3 k,) flux density at the k field points given at construction, stacked
            [T] (only when field points are given).

    State: continuous, 4 (the quaternion); or, with ``update_period``, discrete, 5 (the
    quaternion at the last update and that update's time [s]).
    """

    def __init__(
        self,
        config: MagnetUnitConfig | None = None,
        *,
        R_WM: np.ndarray | None = None,
        field_points_W: np.ndarray | None = None,
        update_period: float | None = None,
    ) -> None:
        """
        Args:
            config: the unit, placed (default: ``unit_config.right_unit()``, the prototype
                cylinder right of the patient); its ``slip``, ``shape`` and ``model`` are read.
            R_WM: (3, 3) default orientation (identity: dipole along +z).
            field_points_W: (k, 3) points where ``B_points_W`` reports the field [m].
            update_period: None (continuous state), or the period [s] of a discrete state that
                is exact when ``omega_wheels`` only changes at multiples of it.
        """
        super().__init__()
        if config is not None:
            require_type(config, MagnetUnitConfig, "RotatingMagnetUnit config", "a MagnetUnitConfig or None")
        if R_WM is not None:
            as_array(R_WM, "RotatingMagnetUnit R_WM", (3, 3))
        self._config = (config or right_unit()).check_placed()
        self._slip = float(self._config.slip)
        self._p_WM = np.asarray(self._config.p_WM, dtype=float)
        self._moment = float(self._config.magnet.dipole_moment)
        # omega_W of the wheel speeds seen last (the drive's applied speeds: whole microsteps per
        # period, so a few values recur): {omega_wheels.tobytes(): omega_W}, see ``_omega_W``.
        self._omega_of_wheels: dict[bytes, np.ndarray] = {}
        self.set_name(f"{self._config.name}.magnet")

        self._omega_wheels_port = self.DeclareVectorInputPort("omega_wheels", 3)
        q0 = quaternion_from_rotation(np.eye(3) if R_WM is None else R_WM)
        if update_period is not None and not (np.isfinite(update_period) and update_period > 0):
            raise ValueError(f"update_period must be None or a positive number of seconds, got {update_period!r}")
        self._period = update_period
        if update_period is None:
            self._q_index = self.DeclareContinuousState(BasicVector(q0))
            self._q_port = self.DeclareStateOutputPort("q_WM", self._q_index)
        else:
            self._q_index = self.DeclareDiscreteState(np.concatenate([q0, [0.0]]))
            self._q_port = self.DeclareVectorOutputPort("q_WM", 4, self._calc_q)
            self.DeclarePeriodicDiscreteUpdateEvent(update_period, 0.0, self._update)
        self._X_port = self.DeclareAbstractOutputPort(
            "X_WM", lambda: AbstractValue.Make(RigidTransform()), self._calc_X_WM
        )
        self._m_port = self.DeclareVectorOutputPort("m_W", 3, self._calc_m_W)
        self._omega_port = self.DeclareVectorOutputPort("omega_WM_W", 3, self._calc_omega)
        self._points = None
        if field_points_W is not None:
            pts = np.asarray(field_points_W, dtype=float).reshape(-1, 3)
            self._points = pts
            self._B_port = self.DeclareVectorOutputPort("B_points_W", 3 * len(pts), self._calc_B_points)

    @property
    def config(self) -> MagnetUnitConfig:
        return self._config

    def get_omega_wheels_input_port(self):
        return self._omega_wheels_port

    @property
    def update_period(self) -> float | None:
        """The discrete state's period [s], or None for continuous state."""
        return self._period

    def quaternion(self, context: Context) -> np.ndarray:
        """(4,) orientation quaternion (w, x, y, z) at the context's time."""
        if self._period is None:
            return context.get_continuous_state_vector().CopyToVector()
        x = context.get_discrete_state().value(self._q_index)
        return _turned(x[:4], self._omega_W(context), context.get_time() - x[4])

    def R_WM(self, context: Context) -> np.ndarray:
        """(3, 3) orientation of the magnet in this context."""
        return rotation_from_quaternion(self.quaternion(context))

    def set_orientation(self, context: Context, R_WM: np.ndarray) -> None:
        """Set the orientation state from a rotation matrix (3, 3)."""
        if self._period is None:
            context.SetContinuousState(quaternion_from_rotation(R_WM))
        else:
            context.SetDiscreteState(self._q_index, np.concatenate([quaternion_from_rotation(R_WM),
                                                                    [context.get_time()]]))

    def magnet_source(self, context: Context) -> MagnetSource:
        """The shared MagnetSource at the current pose (use it for the field anywhere)."""
        return self._config.source(self.R_WM(context))

    def _omega_W_checked(self, context: Context, omega_wheels=None) -> np.ndarray:
        # A NaN wheel speed must stop the simulation at once, naming this unit, the port and the
        # time: on a NaN derivative the error-controlled integrator would retry forever.
        # omega_W = (1 - slip) (rho_w/rho_a) A^-1 omega_wheels (docs/design.md, 4.2).
        omega_wheels = check_finite_input(self, self._omega_wheels_port, context, omega_wheels)
        return (1.0 - self._slip) * self._config.geometry.sphere_angular_velocity(omega_wheels)

    def _omega_W(self, context: Context) -> np.ndarray:
        """``_omega_W_checked``, remembered per wheel-speed input (the update, the pose and the
        dipole of one period all ask; a NaN input is never remembered, so it is refused at every
        call). The array returned is shared: read it, do not change it."""
        omega_wheels = self._omega_wheels_port.Eval(context)
        key = omega_wheels.tobytes()
        omega_W = self._omega_of_wheels.get(key)
        if omega_W is None:
            omega_W = self._omega_W_checked(context, omega_wheels)
            if len(self._omega_of_wheels) >= 64:
                self._omega_of_wheels.clear()
            self._omega_of_wheels[key] = omega_W
        return omega_W

    def _update(self, context, discrete_state):
        # The speed on the input now is the one applied since the last update (the drive's
        # simultaneous update has not changed it yet): turn by it, exactly.
        x = context.get_discrete_state().value(self._q_index)
        t = context.get_time()
        q = _turned(x[:4], self._omega_W(context), t - x[4])
        q = q / _norm(q)
        discrete_state.set_value(self._q_index, np.array([*q.tolist(), t]))

    def _calc_q(self, context, output):
        output.SetFromVector(self.quaternion(context))

    def DoCalcTimeDerivatives(self, context, derivatives):
        q = context.get_continuous_state_vector().CopyToVector()
        w = self._omega_W(context)
        # q_dot = 1/2 (0, w_W) (x) q for an angular velocity expressed in world, plus a term
        # that pulls |q| back to 1 (it is zero on the unit sphere).
        wx, wy, wz = w
        # Left quaternion-product matrix of (0, w), written out (np.cross dominates the cost).
        Omega = np.array(
            [
                [0.0, -wx, -wy, -wz],
                [wx, 0.0, -wz, wy],
                [wy, wz, 0.0, -wx],
                [wz, -wy, wx, 0.0],
            ]
        )
        qdot = 0.5 * (Omega @ q) + QUATERNION_NORM_GAIN * (1.0 - q @ q) * q
        derivatives.get_mutable_vector().SetFromVector(qdot)

    def _calc_X_WM(self, context, output):
        output.get_mutable_value().set(_rotation_matrix(self.quaternion(context)), self._p_WM)

    def _calc_m_W(self, context, output):
        output.SetFromVector(self._moment * self.R_WM(context)[:, 2])

    def _calc_omega(self, context, output):
        output.SetFromVector(self._omega_W(context))

    def _calc_B_points(self, context, output):
        output.SetFromVector(self.magnet_source(context).field(self._points).reshape(-1))

