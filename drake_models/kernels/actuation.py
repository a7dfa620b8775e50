"""One actuation unit's update, compiled: the stepper drive, the magnet's turn, the Hall sample,
the dipole inversion, the reconfiguration law and the mode switch, in one call per update.

The laws are the Python systems' (their reference, which ``tests/test_compiled_units.py`` holds
this to bit for bit over whole teleoperation runs):

* the omni-wheel maps ``omega_w = (rho_a/rho_w) A omega_W`` and its inverse
  (``drake_models/omniwheel.py``), the paper's printed map as an option;
* the stepper drive's rate limit, integration and microstep quantisation
  (``systems/omni_wheel_drive.py``);
* the magnet's quaternion turned by the rotation the last period's wheel speeds made, and its
  rotation matrix (``systems/rotating_magnet_unit.py``; Drake's ``RotationMatrix(Quaternion)``);
* the point-dipole field at the sensor (``dipole.DipoleFieldAtPoint``), the ADC's saturation and
  rounding (``hall_sensor.quantise_reading``);
* the exact inverse of the dipole law (``dipole_inversion.FieldInversion``) after subtracting the
  other units' fields (``hall_sensor.DipoleDirectionEstimator``);
* the reconfiguration law ``K (m x m_c)`` with its antiparallel fix and uniform wheel saturation
  (``systems/reconfiguration.py``).

Each operation is the reference's, in its order, so that the floats are the same: numpy's
``einsum`` three-term dot sums ``(x0 y0 + x2 y2) + x1 y1`` (``_einsum_dot``); a 1-D ``norm``,
``@`` and ``.dot`` go through BLAS's ``ddot``, left to right, fused or not by the CPU's kernel
(``_blas_dot``, ``_blas_order``); ``norm(..., axis=-1)`` sums left to right; Drake's rotation of a quaternion
takes ``2 / ((x^2 + z^2) + (y^2 + w^2))`` (Eigen's two-lane sum). What the kernels cannot
reproduce stays Python: the noise (numpy's generator), the latch's angle test (numpy's
``arctan2``), the exact (magpylib) fields of a magnet near its sensor.

Arrays of constants (built by ``systems/actuation_unit.py``):

``c`` (float64, ``C_*`` indices): the drive's, magnet's, sensor's and controller's scalars.
``maps`` (4, 3, 3): ``A``, ``A^-1``, the paper's ``A^-1`` (its printed map), the inversion's
``(3/2) u u' - I``.
``vec`` (3, 3): ``m_c``, the antiparallel fallback axis, the ADC's LSBs.
``sources`` (n, 9): per magnet the sensor sees (its own first, then each other unit's), the
dipole law's constants at the sensor ``(3 r, r, 1/|r|, 1/|r|^3, |m|)``; ``comp`` (k, 9) the same
for the fields the estimator subtracts, ``comp_of`` (k,) which other unit each is.
"""

from __future__ import annotations

import math

import numpy as np

from ballchain.drake_models.dipole import K_DIPOLE
from ballchain.drake_models.kernels._blas_order import DDOT_FMA, fma
from ballchain.drake_models.kernels._common import inline_kernel, kernel

# The scalars of ``c``.
C_RATIO, C_SLIP, C_DT, C_STEP, C_DV, C_MAX_SPEED, C_GAIN, C_SIN_CONE, C_RANGE, C_INV_SCALE, C_PAPER_MAP = range(11)
N_CONSTANTS = 11

# The unit's state vector.
X_Q, X_T, X_SPEED, X_ANGLE, X_STEPS, X_APPLIED, X_B, X_K, X_DONE, X_MODE = 0, 4, 5, 8, 11, 14, 17, 20, 21, 22
N_STATE = 23


@inline_kernel
def _einsum_dot(a, b):
    """``np.einsum``'s three-term dot: ``(a0 b0 + a2 b2) + a1 b1``."""
    return (a[0] * b[0] + a[2] * b[2]) + a[1] * b[1]


@inline_kernel
def _plain_dot(a, b):
    """A 1-D ``@``/``.dot``/``norm``'s BLAS ``ddot`` on a Haswell-class kernel: left to right,
    a product then a sum per term."""
    s = a[0] * b[0]
    for i in range(1, a.shape[0]):
        s += a[i] * b[i]
    return s


@inline_kernel
def _fused_dot(a, b):
    """A 1-D ``@``/``.dot``/``norm``'s BLAS ``ddot`` on a SkylakeX-class kernel: left to right,
    a fused multiply-add per term (``_blas_order``)."""
    s = a[0] * b[0]
    for i in range(1, a.shape[0]):
        s = fma(a[i], b[i], s)
    return s


_blas_dot = _fused_dot if DDOT_FMA else _plain_dot
"""The sum numpy's ``ddot`` does on this machine (``_blas_order.ORDER``)."""


@inline_kernel
def _matvec(M, v):
    """``np.einsum("ij,...j->...i", M, v)`` for (3, 3) and (3,)."""
    out = np.empty(3)
    for i in range(3):
        out[i] = _einsum_dot(M[i], v)
    return out


@kernel
def sphere_angular_velocity(maps, c, wheels):
    """``OmniWheelGeometry.sphere_angular_velocity``: ``A^-1 omega_w / (rho_a/rho_w)``."""
    return _matvec(maps[1], wheels) / c[C_RATIO]


@kernel
def wheel_speeds(maps, c, omega):
    """``OmniWheelGeometry.wheel_speeds``: ``(rho_a/rho_w) A omega_W``."""
    return c[C_RATIO] * _matvec(maps[0], omega)


@inline_kernel
def _saturated(w, limit):
    """``omni_wheel_drive.saturate_uniformly``."""
    peak = max(abs(w[0]), abs(w[1]), abs(w[2]))
    return w if peak <= limit else w * (limit / peak)


@kernel
def magnet_angular_velocity(maps, c, applied):
    """The magnet's angular velocity [rad/s] of the applied wheel speeds, after slip
    (``RotatingMagnetUnit._omega_W_checked``)."""
    return (1.0 - c[C_SLIP]) * sphere_angular_velocity(maps, c, applied)


@kernel
def turned(q, w, dt):
    """``rotating_magnet_unit._turned``: q (w, x, y, z) turned for dt at the world angular
    velocity w (3,), on the same floats (a new array, a copy of q when it does not turn: never a
    view of a read-only state, which would make its callers compile a second specialisation)."""
    wx, wy, wz = w[0], w[1], w[2]
    speed = math.sqrt(wx * wx + wy * wy + wz * wz)
    if speed * dt == 0.0:
        return q.copy()
    half = 0.5 * speed * dt
    co, k = math.cos(half), math.sin(half) / speed
    ax, ay, az = k * wx, k * wy, k * wz
    qw, qx, qy, qz = q[0], q[1], q[2], q[3]
    out = np.empty(4)
    out[0] = co * qw - ax * qx - ay * qy - az * qz
    out[1] = co * qx + ax * qw + ay * qz - az * qy
    out[2] = co * qy - ax * qz + ay * qw + az * qx
    out[3] = co * qz + ax * qy - ay * qx + az * qw
    return out


@kernel
def normalised(q):
    """``q / _norm(q)`` (``rotating_magnet_unit._norm``: the square root of q's BLAS dot)."""
    return q / math.sqrt(_blas_dot(q, q))


@kernel
def rotation(q):
    """Drake's ``RotationMatrix(Quaternion(q)).matrix()`` (3, 3) of a quaternion (w, x, y, z)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    s = 2.0 / ((x * x + z * z) + (y * y + w * w))
    sx, sy, sz = s * x, s * y, s * z
    swx, swy, swz = sx * w, sy * w, sz * w
    sxx, sxy, sxz = sx * x, sy * x, sz * x
    syy, syz, szz = sy * y, sz * y, sz * z
    R = np.empty((3, 3))
    R[0, 0] = 1.0 - syy - szz
    R[0, 1] = sxy - swz
    R[0, 2] = sxz + swy
    R[1, 0] = sxy + swz
    R[1, 1] = 1.0 - sxx - szz
    R[1, 2] = syz - swx
    R[2, 0] = sxz - swy
    R[2, 1] = syz + swx
    R[2, 2] = 1.0 - sxx - syy
    return R


@kernel
def quaternion_at(x, t, maps, c):
    """The magnet's quaternion at time t (``RotatingMagnetUnit.quaternion``): the state's, turned
    by the applied wheel speeds since the last update (not normalised)."""
    w = magnet_angular_velocity(maps, c, x[X_APPLIED:X_APPLIED + 3])
    return turned(x[X_Q:X_Q + 4], w, t - x[X_T])


@kernel
def dipole_field(source, m):
    """``DipoleFieldAtPoint(r)(m)``: the point dipole m (3,) [A m^2] at the sensor [T]; ``source``
    its constants ``(3 r, r, 1/|r|, 1/|r|^3, ...)``."""
    inv_r, inv_r3 = source[6], source[7]
    cc = _einsum_dot(m, source[3:6]) * inv_r3 * inv_r * inv_r
    B = np.empty(3)
    for i in range(3):
        B[i] = K_DIPOLE * (source[i] * cc - m[i] * inv_r3)
    return B


@kernel
def magnet_field(source, R):
    """``FieldAtPoint``'s dipole law for a magnet at orientation R (3, 3): moment |m| R[:, 2]."""
    m = np.empty(3)
    for i in range(3):
        m[i] = source[8] * R[i, 2]
    return dipole_field(source, m)


@kernel
def sensor_field(x, t, q_others, maps, c, sources, given, use_given):
    """The noise-free field at the sensor [T] (``HallSensor.true_field``): the own magnet's, then
    each other unit's seen, summed in that order; a source with ``use_given`` takes its row of
    ``given`` (a field the caller computed: the exact model)."""
    B = given[0].copy() if use_given[0] else magnet_field(sources[0], rotation(normalised(quaternion_at(x, t, maps, c))))
    for k in range(1, sources.shape[0]):
        f = given[k] if use_given[k] else magnet_field(sources[k], rotation(normalised(q_others[k - 1])))
        B = B + f
    return B


@kernel
def quantised(B, c, vec):
    """``hall_sensor.quantise_reading``: saturated at the range, rounded to the LSBs."""
    r = c[C_RANGE]
    out = np.empty(3)
    for i in range(3):
        b = min(max(B[i], -r), r)
        lsb = vec[2, i]
        if lsb > 0.0:
            out[i] = np.rint(b / lsb) * lsb
        else:
            out[i] = b
    return out


@kernel
def sample(x, t, q_others, noise, given, use_given, maps, c, vec, sources):
    """A Hall sample at time t (``HallSensor._sample``): the field, plus ``noise`` (3,) when it is
    not empty, saturated and rounded."""
    B = sensor_field(x, t, q_others, maps, c, sources, given, use_given)
    if noise.shape[0]:
        B = B + noise
    return quantised(B, c, vec)


@kernel
def estimate(B_sample, q_others, maps, c, comp, comp_of):
    """``DipoleDirectionEstimator``'s output: the sample minus the compensated units' dipole
    fields (when it is not zero), inverted (zeros for a zero field)."""
    B = B_sample.copy()
    if B[0] != 0.0 or B[1] != 0.0 or B[2] != 0.0:
        for k in range(comp.shape[0]):
            B = B - magnet_field(comp[k], rotation(normalised(q_others[comp_of[k]])))
    if not (B[0] != 0.0 or B[1] != 0.0 or B[2] != 0.0):
        return np.zeros(3)
    v = c[C_INV_SCALE] * _matvec(maps[3], B)
    return v / math.sqrt((v[0] * v[0] + v[1] * v[1]) + v[2] * v[2])


@kernel
def reconfiguration_command(m_hat, maps, c, vec):
    """``ReconfigurationController``'s command for a measured direction (not latched):
    ``(wheel speeds, the angular velocity they make)``."""
    omega = np.zeros(3)
    if m_hat[0] != 0.0 or m_hat[1] != 0.0 or m_hat[2] != 0.0:
        m = m_hat / math.sqrt(_blas_dot(m_hat, m_hat))
        m_c = vec[0]
        x = np.empty(3)
        x[0] = m[1] * m_c[2] - m[2] * m_c[1]
        x[1] = m[2] * m_c[0] - m[0] * m_c[2]
        x[2] = m[0] * m_c[1] - m[1] * m_c[0]
        sin_cone = c[C_SIN_CONE]
        if _blas_dot(m, m_c) < 0 and math.sqrt(_blas_dot(x, x)) < sin_cone:
            n = math.sqrt(_blas_dot(x, x))
            axis = x / n if n > 1e-3 * sin_cone else vec[1]
            omega = c[C_GAIN] * sin_cone * axis
        else:
            omega = c[C_GAIN] * x
    if c[C_PAPER_MAP] == 1.0:
        wheels = _matvec(maps[2], omega) / c[C_RATIO]
    else:
        wheels = wheel_speeds(maps, c, omega)
    wheels = _saturated(wheels, c[C_MAX_SPEED])
    return wheels, sphere_angular_velocity(maps, c, wheels)


@kernel
def latched_command(maps, c):
    """The controller's command once done: zero wheel speeds and what they make."""
    wheels = np.zeros(3)
    return wheels, sphere_angular_velocity(maps, c, wheels)


@kernel
def update(x, t, mode, omega_teleop, q_others, sampling, noise, given, use_given, maps, c, vec, sources, comp,
           comp_of):
    """One update of the unit at time t from its state x (the state before every simultaneous
    update, as Drake's discrete updates see it): the drive steps towards the selected command
    (teleoperation, or the reconfiguration law on the estimate), the magnet turns by the last
    period's wheel speeds, and, when ``sampling``, the Hall sensor samples (plus ``noise``).

    Returns:
        ``(x_new, m_hat)``: the new state but for the latch (``X_DONE``, ``X_MODE``: the caller's),
        and the estimate the controller saw (zeros when it was not needed: teleoperation and no
        sample).
    """
    new = x.copy()
    m_hat = np.zeros(3)
    if mode == 1 or sampling:
        m_hat = estimate(x[X_B:X_B + 3], q_others, maps, c, comp, comp_of)
    # the mode switch: teleoperation, or the reconfiguration law (zero once done)
    if mode == 1:
        if x[X_DONE] > 0.5:
            _, omega = latched_command(maps, c)
        else:
            _, omega = reconfiguration_command(m_hat, maps, c, vec)
    else:
        omega = omega_teleop
    # the drive (OmniWheelDrive._update)
    target = _saturated(wheel_speeds(maps, c, omega), c[C_MAX_SPEED])
    dt, step, dv = c[C_DT], c[C_STEP], c[C_DV]
    for i in range(3):
        v = x[X_SPEED + i]
        speed = v + min(max(target[i] - v, -dv), dv)
        angle = x[X_ANGLE + i] + speed * dt
        steps = np.rint(angle / step)
        new[X_SPEED + i] = speed
        new[X_ANGLE + i] = angle
        new[X_STEPS + i] = steps
        new[X_APPLIED + i] = (steps - x[X_STEPS + i]) * step / dt
    # the magnet (RotatingMagnetUnit._update): turned by the speed applied since the last update
    q = normalised(quaternion_at(x, t, maps, c))
    new[X_Q:X_Q + 4] = q
    new[X_T] = t
    if sampling:
        new[X_B:X_B + 3] = sample(x, t, q_others, noise, given, use_given, maps, c, vec, sources)
        new[X_K] = x[X_K] + 1.0
    return new, m_hat


def warm_up() -> None:
    """Compile (or load from the cache) every kernel ``ActuationUnit`` calls, with the argument
    types it passes (its state read-only, as Drake's context hands it over; everything else
    writable), so that a station's first update does not compile."""
    x = np.zeros(N_STATE)
    x[X_Q] = 1.0
    x.setflags(write=False)
    maps = np.stack([np.eye(3)] * 4)
    c, vec = np.ones(N_CONSTANTS), np.ones((3, 3))
    sources, comp, comp_of = np.ones((2, 9)), np.ones((1, 9)), np.zeros(1, np.int64)
    q_others, given, use_given = np.array([[1.0, 0.0, 0.0, 0.0]]), np.zeros((2, 3)), np.zeros(2, np.bool_)
    for mode, sampling in ((0, False), (1, True)):
        update(x, 0.0, mode, np.zeros(3), q_others, sampling, np.zeros(3), given, use_given, maps, c, vec, sources,
               comp, comp_of)
    sample(x, 0.0, q_others, np.zeros(0), given, use_given, maps, c, vec, sources)
    sensor_field(x, 0.0, q_others, maps, c, sources, given, use_given)
    m_hat = estimate(x[X_B:X_B + 3], q_others, maps, c, comp, comp_of)
    reconfiguration_command(m_hat, maps, c, vec)
    latched_command(maps, c)
    rotation(normalised(quaternion_at(x, 0.0, maps, c)))
    magnet_angular_velocity(maps, c, x[X_APPLIED:X_APPLIED + 3])
