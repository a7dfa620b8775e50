"""One actuation unit as one Drake system, its update compiled: the station's default unit.

``actuation_station.add_unit`` builds a unit from six Python systems (mode switch -> omni-wheel
drive -> magnet -> Hall sensor -> estimator -> reconfiguration controller): the composable
parts, and the reference. ``ActuationUnit`` is the same unit in one LeafSystem whose one
periodic update (at the drive's period) does all of their updates in one compiled call
(``drake_models/kernels/actuation.py``): the drive steps towards the selected command, the
magnet turns by the last period's wheel speeds, and at the Hall sensor's period the sensor
samples and the reconfiguration latch is updated. Every number is the composed unit's, bit for
bit (``tests/test_compiled_units.py`` holds whole teleoperation runs to it); what differs is the
cost: one Python callback per update instead of a dozen, each a few microseconds of Drake's API.

Ports (the composed unit's names):

    inputs:  omega_teleop_W (3, the teleoperation mapper's command), mode (1: 0 teleoperation,
             1 reconfiguration, rounded; its going to 1 is a reconfiguration request),
             q_WM_<other> (4) per other unit whose magnet the sensor sees (that unit's q_WM);
    outputs: q_WM (4), X_WM (RigidTransform), m_W (3), omega_WM_W (3), B_points_W (3 k, with
             field points), omega_wheels (3), wheel_angles (3), wheel_speed_setpoint (3),
             B_sensor_T (3), m_hat_W (3), omega_wheels_cmd (3), omega_reconfigure_W (3, the
             law's angular velocity), omega_desired_W (3, the selected command the drive
             follows), done (1), angle_error (1).

State: one discrete vector (``kernels.actuation.X_*``): the quaternion and the time of the last
update, the drive's speed, angle command, microsteps and applied speeds, the last Hall sample and
the sample counter, the latch and the mode it saw. Parameter: the Hall noise's seed
(``randomness.SeededLeafSystem``).

Not compiled (Python, as the composed unit does it): the Hall noise (numpy's generator), the
latch's angle test (numpy's ``arctan2``), the exact (magpylib) field of a magnet whose model is
``exact`` or that is within reach of the sensor, the field at the field points.
"""

from __future__ import annotations

from dataclasses import replace
from math import isfinite
from typing import Sequence

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import Context

from ballchain.infrastructure.arg_checks import as_array, as_vector, require_int, require_type
from ballchain.drake_models.dipole_inversion import FieldInversion
from ballchain.infrastructure.errors import UserInputError, check_finite_input
from ballchain.drake_models.field_sources import FieldAtPoint, MagnetSource
from ballchain.drake_models.kernels import actuation as K
from ballchain.drake_models.omniwheel import paper_inverse_matrix
from ballchain.drake_models.vectors import angle_between, perpendicular_axis
from ballchain.systems.hall_sensor import HallSensorSpec
from ballchain.systems.omni_wheel_drive import StepperSpec
from ballchain.systems.randomness import SampleGenerators, SeededLeafSystem
from ballchain.systems.reconfiguration import ANTIPARALLEL_DEG
from ballchain.systems.rotating_magnet_unit import quaternion_from_rotation
from ballchain.systems.unit_config import MagnetUnitConfig

_kernels_ready = False  # kernels.actuation.warm_up has run in this process


def samples_per_update(sensor_spec: HallSensorSpec, stepper_spec: StepperSpec) -> int | None:
    """How many drive updates make one Hall sample period, or None when that is not a whole number
    (``ActuationUnit`` needs the sensor's samples at drive updates)."""
    ratio = (1.0 / sensor_spec.sample_rate_hz) / stepper_spec.update_period
    n = round(ratio)
    return n if n >= 1 and abs(ratio - n) < 1e-9 * n else None


def compilable(unit: MagnetUnitConfig, others: Sequence[MagnetUnitConfig], sensor_spec: HallSensorSpec,
               stepper_spec: StepperSpec) -> bool:
    """Whether ``ActuationUnit`` reproduces the composed unit: the Hall period is a whole number of
    drive periods, and each field the estimator subtracts is the dipole law's at the sensor (the
    other magnet beyond the sensor's reach)."""
    if samples_per_update(sensor_spec, stepper_spec) is None:
        return False
    if unit.estimator_compensates_other_units:
        for o in others:
            d = replace(o, model="dipole").check_placed()
            if FieldAtPoint(d.magnet, d.p_WM, d.model, unit.p_WS).dipole is None:
                return False
    return True


def _dipole_constants(field: FieldAtPoint) -> np.ndarray:
    """(9,) the dipole law's constants of a ``FieldAtPoint`` and the moment (``kernels.actuation``'s
    sources)."""
    return np.append(field.dipole.law_constants, float(field.moment))


class ActuationUnit(SeededLeafSystem):
    """One actuation unit (drive, magnet, Hall sensor, estimator, controller, mode switch) as one
    system with a compiled update; see the module docstring for its ports."""

    def __init__(
        self,
        unit: MagnetUnitConfig,
        *,
        m_neutral_W: np.ndarray,
        others: Sequence[MagnetUnitConfig] = (),
        sensor_spec: HallSensorSpec | None = None,
        stepper_spec: StepperSpec | None = None,
        seed: int = 0,
        R_WM: np.ndarray | None = None,
        field_points_W: np.ndarray | None = None,
    ) -> None:
        """
        Args:
            unit: the unit, placed (its slip, Hall noise, field model, controller and wheel map).
            m_neutral_W: (3,) the reconfiguration's target direction (normalised here).
            others: the units whose magnets the sensor sees (in this order, one ``q_WM_<name>``
                input each); the estimator subtracts their fields when the unit's
                ``estimator_compensates_other_units`` says so.
            sensor_spec, stepper_spec: the Hall sensor's and the steppers' figures; the sensor's
                period must be a whole number of the drive's (``samples_per_update``).
            seed: the Hall noise's default seed.
            R_WM: (3, 3) the magnet's initial orientation (identity: dipole along +z).
            field_points_W: (k, 3) points where ``B_points_W`` reports the own magnet's field [m].

        Raises:
            UserInputError: a bad argument, or a unit this system cannot reproduce
                (``compilable``: use ``actuation_station.add_unit``'s composed systems).
        """
        super().__init__()
        require_type(unit, MagnetUnitConfig, "ActuationUnit unit", "a MagnetUnitConfig")
        for k, other in enumerate(others):
            require_type(other, MagnetUnitConfig, f"ActuationUnit others[{k}]", "a MagnetUnitConfig")
        as_vector(m_neutral_W, "ActuationUnit m_neutral_W", nonzero=True)
        if R_WM is not None:
            as_array(R_WM, "ActuationUnit R_WM", (3, 3))
        require_int(seed, "ActuationUnit seed", 0)
        self._sensor_spec = sensor_spec or HallSensorSpec()
        self._stepper_spec = stepper_spec or StepperSpec()
        require_type(self._sensor_spec, HallSensorSpec, "ActuationUnit sensor_spec")
        require_type(self._stepper_spec, StepperSpec, "ActuationUnit stepper_spec")
        self._config = unit.check_placed()
        self._others = tuple(o.check_placed() for o in others)
        if not compilable(self._config, self._others, self._sensor_spec, self._stepper_spec):
            raise UserInputError(f"ActuationUnit {unit.name!r}: the Hall period must be a whole number of drive "
                                 "periods and the other magnets beyond the sensor's reach (use the composed unit)")
        self.set_name(f"{unit.name}.unit")
        self.DeclareSeedParameter(seed)
        global _kernels_ready
        if not _kernels_ready:  # compiled (or loaded from the cache) when built, not in a timed run
            K.warm_up()
            _kernels_ready = True
        u, spec, stepper = self._config, self._sensor_spec, self._stepper_spec
        g = u.geometry
        self._period = float(stepper.update_period)
        self._ratio = samples_per_update(spec, stepper)
        self._moment = float(u.magnet.dipole_moment)
        self._p_WM = np.asarray(u.p_WM, dtype=float)
        self._microstep_angle = float(stepper.microstep_angle)
        m_c = np.asarray(m_neutral_W, dtype=float).reshape(3)
        self._m_c = m_c / np.linalg.norm(m_c)  # as ReconfigurationController normalises it
        self._tol = np.deg2rad(u.tolerance_deg)
        sin_cone = np.sin(np.deg2rad(ANTIPARALLEL_DEG))
        inversion = FieldInversion(np.array([0.0, 0.0, -u.sensor_distance]))
        c = np.zeros(K.N_CONSTANTS)
        c[K.C_RATIO], c[K.C_SLIP], c[K.C_DT] = g.ratio, u.slip, self._period
        c[K.C_STEP], c[K.C_DV] = self._microstep_angle, float(stepper.max_acceleration * stepper.update_period)
        c[K.C_MAX_SPEED], c[K.C_GAIN], c[K.C_SIN_CONE] = stepper.max_speed, u.controller_gain, sin_cone
        c[K.C_RANGE], c[K.C_INV_SCALE], c[K.C_PAPER_MAP] = spec.range_T, inversion.scale, u.wheel_map == "paper"
        maps = np.ascontiguousarray(np.stack([g.A, g.A_inv, paper_inverse_matrix(), inversion.matrix]), dtype=float)
        vec = np.array([self._m_c, perpendicular_axis(self._m_c), np.asarray(spec.lsb_T, dtype=float)])
        # The fields at the sensor: the own magnet's and each other's seen (the HallSensor's
        # FieldAtPoint each); the dipole law's constants when it is a dipole there, else the
        # field is computed in Python (the exact model) and handed in.
        self._fields = [FieldAtPoint(m.magnet, m.p_WM, m.model, u.p_WS) for m in (u, *self._others)]
        self._use_given = np.array([f.dipole is None for f in self._fields])
        self._any_given = bool(self._use_given.any())
        sources = np.array([_dipole_constants(f) if f.dipole is not None else np.zeros(9) for f in self._fields])
        self._last_fields: list[tuple[bytes, np.ndarray] | None] = [None] * len(self._fields)
        compensate = self._others if u.estimator_compensates_other_units else ()
        comp = [FieldAtPoint(d.magnet, d.p_WM, d.model, u.p_WS)
                for d in (replace(o, model="dipole").check_placed() for o in compensate)]
        comp = np.array([_dipole_constants(f) for f in comp]).reshape(-1, 9)
        comp_of = np.arange(len(compensate), dtype=np.int64)
        self._constants = (maps, c, vec, sources, comp, comp_of)
        self._given = np.zeros((len(self._fields), 3))
        self._noise_std = float(spec.noise_std_T) if u.sensor_noise and spec.noise_std_T > 0 else 0.0
        self._generators = SampleGenerators()
        self._no_noise = np.zeros(0)
        self._zeros = np.zeros(3)
        self._no_others = np.zeros((0, 4))
        self._points = None if field_points_W is None else np.asarray(field_points_W, dtype=float).reshape(-1, 3)

        x0 = np.zeros(K.N_STATE)
        x0[K.X_Q:K.X_Q + 4] = quaternion_from_rotation(np.eye(3) if R_WM is None else R_WM)
        self._x_index = self.DeclareDiscreteState(x0)
        self._teleop_port = self.DeclareVectorInputPort("omega_teleop_W", 3)
        self._mode_port = self.DeclareVectorInputPort("mode", 1)
        self._q_ports = [self.DeclareVectorInputPort(f"q_WM_{o.name}", 4) for o in self._others]
        state, now = {self.xd_ticket()}, {self.xd_ticket(), self.time_ticket()}
        inputs = {self.xd_ticket(), self.time_ticket(), self.all_input_ports_ticket()}
        self.DeclareVectorOutputPort("q_WM", 4, self._calc_q, prerequisites_of_calc=now)
        self.DeclareAbstractOutputPort("X_WM", lambda: AbstractValue.Make(RigidTransform()), self._calc_X_WM,
                                       prerequisites_of_calc=now)
        self.DeclareVectorOutputPort("m_W", 3, self._calc_m_W, prerequisites_of_calc=now)
        self.DeclareVectorOutputPort("omega_WM_W", 3, self._calc_omega_WM, prerequisites_of_calc=state)
        if self._points is not None:
            self.DeclareVectorOutputPort("B_points_W", 3 * len(self._points), self._calc_B_points,
                                         prerequisites_of_calc=now)
        self.DeclareVectorOutputPort("omega_wheels", 3, self._slice(K.X_APPLIED), prerequisites_of_calc=state)
        self.DeclareVectorOutputPort("wheel_angles", 3, self._calc_angles, prerequisites_of_calc=state)
        self.DeclareVectorOutputPort("wheel_speed_setpoint", 3, self._slice(K.X_SPEED), prerequisites_of_calc=state)
        self.DeclareVectorOutputPort("B_sensor_T", 3, self._slice(K.X_B), prerequisites_of_calc=state)
        self.DeclareVectorOutputPort("m_hat_W", 3, self._calc_m_hat, prerequisites_of_calc=inputs)
        self.DeclareVectorOutputPort("omega_wheels_cmd", 3, self._calc_wheels_cmd, prerequisites_of_calc=inputs)
        self.DeclareVectorOutputPort("omega_reconfigure_W", 3, self._calc_omega_reconfigure,
                                     prerequisites_of_calc=inputs)
        self.DeclareVectorOutputPort("omega_desired_W", 3, self._calc_omega_desired, prerequisites_of_calc=inputs)
        self.DeclareVectorOutputPort("done", 1, self._slice(K.X_DONE, 1), prerequisites_of_calc=state)
        self.DeclareVectorOutputPort("angle_error", 1, self._calc_angle, prerequisites_of_calc=inputs)
        self.DeclarePeriodicDiscreteUpdateEvent(self._period, 0.0, self._update)
        self.DeclareInitializationDiscreteUpdateEvent(self._initial_sample)

    # -- what the composed unit's systems offer -------------------------------------------------

    @property
    def config(self) -> MagnetUnitConfig:
        return self._config

    @property
    def m_c_W(self) -> np.ndarray:
        """(3,) the reconfiguration's target direction (unit)."""
        return self._m_c.copy()

    @property
    def update_period(self) -> float:
        """The update's period [s] (the drive's)."""
        return self._period

    @property
    def sensor_spec(self) -> HallSensorSpec:
        return self._sensor_spec

    @property
    def stepper_spec(self) -> StepperSpec:
        return self._stepper_spec

    def state(self, context: Context) -> np.ndarray:
        """A copy of the unit's state vector (``kernels.actuation.X_*``) in its context."""
        return context.get_discrete_state(self._x_index).CopyToVector()

    def quaternion(self, context: Context) -> np.ndarray:
        """(4,) the magnet's orientation quaternion (w, x, y, z) at the context's time."""
        return K.quaternion_at(self._x(context), context.get_time(), self._constants[0], self._constants[1])

    def R_WM(self, context: Context) -> np.ndarray:
        """(3, 3) the magnet's orientation in this context."""
        return K.rotation(K.normalised(self.quaternion(context)))

    def set_orientation(self, context: Context, R_WM: np.ndarray) -> None:
        """Set the magnet's orientation from a rotation matrix (3, 3), at the context's time."""
        x = self.state(context)
        x[K.X_Q:K.X_Q + 4] = quaternion_from_rotation(R_WM)
        x[K.X_T] = context.get_time()
        context.SetDiscreteState(self._x_index, x)

    def magnet_source(self, context: Context) -> MagnetSource:
        """The shared MagnetSource at the current pose."""
        return self._config.source(self.R_WM(context))

    def true_field(self, context: Context) -> np.ndarray:
        """(3,) the noise-free field at the sensor [T] at the context's time."""
        x, t = self._x(context), context.get_time()
        q_others = self._q_others(context)
        maps, c, _, sources, _, _ = self._constants
        return K.sensor_field(x, t, q_others, maps, c, sources, *self._given_fields(x, t, q_others))

    # -- the update -----------------------------------------------------------------------------

    def _x(self, context) -> np.ndarray:
        return context.get_discrete_state(self._x_index).get_value()

    def _mode(self, context) -> int:
        # The one number as a float (its finiteness checked by the float's own test; a NaN or an
        # inf is refused by check_finite_input, naming the port and the time).
        (value,) = self._mode_port.Eval(context).tolist()
        if not isfinite(value):
            check_finite_input(self, self._mode_port, context)
        mode = int(round(value))
        if mode not in (0, 1):
            raise ValueError(f"{self.get_name()}: mode must be 0 (teleoperation) or 1 (reconfiguration), got {mode}")
        return mode

    def _q_others(self, context) -> np.ndarray:
        if not self._q_ports:
            return self._no_others
        rows = []
        for port in self._q_ports:
            # The four numbers' finiteness by their float sum (a NaN or an inf among them, or a sum
            # past the largest float: then check_finite_input decides, naming the port and the time).
            q = port.Eval(context)
            if not isfinite(sum(q.tolist())):
                q = check_finite_input(self, port, context, q)
            rows.append(q)
        return np.array(rows)

    def _given_fields(self, x, t, q_others) -> tuple[np.ndarray, np.ndarray]:
        """The fields at the sensor the kernel cannot compute (``use_given``), in Python."""
        if not self._any_given:
            return self._given, self._use_given
        given = self._given.copy()
        for k in np.flatnonzero(self._use_given):
            q = K.quaternion_at(x, t, *self._constants[:2]) if k == 0 else q_others[k - 1]
            R = K.rotation(K.normalised(q))
            key = R.tobytes()
            last = self._last_fields[k]
            if last is None or last[0] != key:  # the exact model costs about a millisecond a sample
                last = self._last_fields[k] = (key, self._fields[k](R))
            given[k] = last[1]
        return given, self._use_given

    def _noise(self, context, x) -> np.ndarray:
        if not self._noise_std:
            return self._no_noise
        # default_rng((seed, k)).normal(scale=..., size=3), the same floats, drawn compiled.
        return self._generators.normal(self.seed(context), int(x[K.X_K]), self._noise_std, 3)

    def _initial_sample(self, context, discrete_state):
        x, t = self._x(context), context.get_time()
        q_others = self._q_others(context)
        new = x.copy()
        maps, c, vec, sources, _, _ = self._constants
        new[K.X_B:K.X_B + 3] = K.sample(x, t, q_others, self._noise(context, x),
                                        *self._given_fields(x, t, q_others), maps, c, vec, sources)
        new[K.X_K] = x[K.X_K] + 1.0
        discrete_state.set_value(self._x_index, new)

    def _update(self, context, discrete_state):
        x, t = self._x(context), context.get_time()
        mode = self._mode(context)
        if mode == 0:
            teleop = self._teleop_port.Eval(context)
            a, b, c = teleop.tolist()
            if not isfinite(a + b + c):  # a NaN or an inf among them (or a sum past the largest float)
                check_finite_input(self, self._teleop_port, context, teleop)
        else:
            teleop = self._zeros
        sampling = round(t / self._period) % self._ratio == 0
        needs_others = sampling or mode == 1
        q_others = self._q_others(context) if needs_others else self._no_others
        noise = self._noise(context, x) if sampling else self._no_noise
        given, use_given = self._given_fields(x, t, q_others) if sampling else (self._given, self._use_given)
        maps, c, vec, sources, comp, comp_of = self._constants
        new, m_hat = K.update(x, t, mode, teleop, q_others, sampling, noise, given, use_given, maps, c, vec, sources,
                              comp, comp_of)
        if sampling:  # the reconfiguration latch (ReconfigurationController._update_done)
            reconfiguring = mode == 1
            requested = reconfiguring and not x[K.X_MODE] > 0.5
            latched = x[K.X_DONE] > 0.5 and not requested
            done = latched or bool(m_hat.any() and angle_between(m_hat, self._m_c) < self._tol)
            new[K.X_MODE] = 1.0 if reconfiguring else 0.0
            new[K.X_DONE] = 1.0 if done else 0.0
        discrete_state.set_value(self._x_index, new)

    # -- outputs --------------------------------------------------------------------------------

    def _slice(self, start: int, size: int = 3):
        def calc(context, output):
            output.SetFromVector(self._x(context)[start:start + size])
        return calc

    def _calc_q(self, context, output):
        output.SetFromVector(self.quaternion(context))

    def _calc_X_WM(self, context, output):
        q = K.normalised(self.quaternion(context))
        output.get_mutable_value().set(RotationMatrix(Quaternion(q)), self._p_WM)

    def _calc_m_W(self, context, output):
        output.SetFromVector(self._moment * self.R_WM(context)[:, 2])

    def _calc_omega_WM(self, context, output):
        maps, c = self._constants[:2]
        output.SetFromVector(K.magnet_angular_velocity(maps, c, self._x(context)[K.X_APPLIED:K.X_APPLIED + 3]))

    def _calc_B_points(self, context, output):
        output.SetFromVector(self.magnet_source(context).field(self._points).reshape(-1))

    def _calc_angles(self, context, output):
        output.SetFromVector(self._x(context)[K.X_STEPS:K.X_STEPS + 3] * self._microstep_angle)

    def _estimate(self, context) -> np.ndarray:
        maps, c, _, _, comp, comp_of = self._constants
        return K.estimate(self._x(context)[K.X_B:K.X_B + 3], self._q_others(context), maps, c, comp, comp_of)

    def _calc_m_hat(self, context, output):
        output.SetFromVector(self._estimate(context))

    def _command(self, context) -> tuple[np.ndarray, np.ndarray]:
        maps, c, vec = self._constants[:3]
        if self._x(context)[K.X_DONE] > 0.5:
            return K.latched_command(maps, c)
        return K.reconfiguration_command(self._estimate(context), maps, c, vec)

    def _calc_wheels_cmd(self, context, output):
        output.SetFromVector(self._command(context)[0])

    def _calc_omega_reconfigure(self, context, output):
        output.SetFromVector(self._command(context)[1])

    def _calc_omega_desired(self, context, output):
        if self._mode(context) == 1:
            output.SetFromVector(self._command(context)[1])
        else:
            output.SetFromVector(self._teleop_port.Eval(context))

    def _calc_angle(self, context, output):
        m = self._estimate(context)
        output.SetAtIndex(0, float(angle_between(m, self._m_c)) if m.any() else np.pi)
