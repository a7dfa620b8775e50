"""The actuation units' shortcuts give the very same numbers as the work they skip, and the
statics' field check looks where the balls are.

The shortcuts (each a function the test can put back to the checked path): the Hall sensor's and
the estimator's magnet fields at the sensor without a checked source per orientation, the
orientation-free part computed once (``FieldAtPoint``), the estimator's compensated fields
remembered per orientation, the latched controller skipping its measurement, the magnet's pose
from one RotationMatrix; the Hall noise's generator built without numpy's ``default_rng``
(``SampleGenerators``), the magnet's angular velocity remembered per wheel-speed
input, its quaternion turned on plain floats, the drive's wheel command, the mapper's command, the
estimate and the controller's command remembered for their last input, the ADC's rounding as one
``np.rint``, the feeder's steps in batches at the engine's updates. A teleoperation run with them
and one with the checked path must agree bit for bit: every unit's magnet, Hall reading, estimate
and wheel state, the engine's state and the feeder's inserted length.
"""

import numpy as np
import pytest


class _Recorder:
    """The unit and engine states every 10 ms of a run (the Hall sensors' samples)."""

    def __init__(self, station):
        self.station, self.rows = station, []

    def __call__(self, root):
        t = root.get_time()
        if abs(t * 100 - round(t * 100)) > 1e-9:
            return
        row = [np.array([t])]
        for h in self.station.units.values():
            for system in (h.magnet, h.drive, h.sensor, h.controller):
                context = system.GetMyContextFromRoot(root)
                row += [context.get_discrete_state(i).get_value().copy()
                        for i in range(context.num_discrete_state_groups())]
            row.append(h.estimator.GetOutputPort("m_hat_W").Eval(h.estimator.GetMyContextFromRoot(root)).copy())
            row.append(h.magnet.GetOutputPort("m_W").Eval(h.magnet.GetMyContextFromRoot(root)).copy())
        engine = self.station.chain.engine_system
        row.append(engine.state_vector(engine.GetMyContextFromRoot(root)).copy())
        feeder = self.station.feeder
        row.append(feeder.GetOutputPort("inserted_length").Eval(feeder.GetMyContextFromRoot(root)).copy())
        self.rows.append(np.concatenate(row))


def _record(name: str, duration: float, overrides: str = "") -> tuple[np.ndarray, float | None]:
    """The recorder's rows of a run, and its feeder's batch period."""
    from pydrake.systems.analysis import Simulator

    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation

    # The composed Python units: their shortcuts are what this file checks (tests/test_compiled_units.py
    # holds the compiled units to them).
    station = MakeStation(load_scenario(name, "{engine: statics, mode: quasi-static, unit_systems: python" + overrides + "}"))
    simulator = Simulator(station.diagram)
    recorder = _Recorder(station)
    simulator.set_monitor(recorder)
    simulator.Initialize()
    simulator.AdvanceTo(duration)
    return np.array(recorder.rows), station.feeder.batch_period


def _checked_path(monkeypatch) -> None:
    """Put every shortcut back to the work it skips."""
    from ballchain.drake_models.field_sources import FieldAtPoint, MagnetSource
    from ballchain.systems import hall_sensor, randomness, reconfiguration, rotating_magnet_unit

    def field_at_point(self, R_WM):  # a checked source at every sample
        return MagnetSource(self._magnet, self._p_WM, R_WM, self._model).field(self._p_W)[0]

    monkeypatch.setattr(FieldAtPoint, "__call__", field_at_point)
    monkeypatch.setattr(randomness.SampleGenerators, "generator", lambda self, seed, k: np.random.default_rng((seed, k)))

    def estimator_field(self, k, R_WM):  # the field afresh at every evaluation
        return self._others[k].source(R_WM).field(self._p_WS)[0]

    monkeypatch.setattr(hall_sensor.DipoleDirectionEstimator, "_other_field", estimator_field)

    def done_after(self, context, latched):  # the measurement evaluated also when latched
        m = self._m_port.Eval(context)
        converged = np.any(m) and reconfiguration.angle_between(m, self._m_c) < self._tol
        return bool(latched or converged)

    monkeypatch.setattr(reconfiguration.ReconfigurationController, "_done_after", done_after)

    def pose(self, context, output):
        from pydrake.math import RigidTransform, RotationMatrix

        output.set_value(RigidTransform(RotationMatrix(self.R_WM(context)), np.asarray(self._config.p_WM)))

    monkeypatch.setattr(rotating_magnet_unit.RotatingMagnetUnit, "_calc_X_WM", pose)

    from ballchain.systems import omni_wheel_drive, teleoperation

    monkeypatch.setattr(rotating_magnet_unit.RotatingMagnetUnit, "_omega_W",
                        rotating_magnet_unit.RotatingMagnetUnit._omega_W_checked)
    monkeypatch.setattr(rotating_magnet_unit, "_turned", _turned_numpy)
    monkeypatch.setattr(rotating_magnet_unit, "_norm", np.linalg.norm)
    monkeypatch.setattr(omni_wheel_drive.OmniWheelDrive, "_target", omni_wheel_drive.OmniWheelDrive._target_checked)

    def mapper(self, context, output):  # the command afresh at every evaluation
        u = teleoperation.apply_dead_band(self._joy_port.Eval(context), self._dead_band)
        assert self._frame == "world"
        output.SetFromVector(self._omega_max * u)

    monkeypatch.setattr(teleoperation.TeleoperationMapper, "_calc", mapper)
    monkeypatch.setattr(hall_sensor.DipoleDirectionEstimator, "_estimate_of",
                        hall_sensor.DipoleDirectionEstimator.estimate)

    def command(self, context):  # the wheel command and its angular velocity afresh
        wheels = np.zeros(3) if self._is_done(context) else self.wheel_command(self._m_port.Eval(context))
        return wheels, self._g.sphere_angular_velocity(wheels)

    monkeypatch.setattr(reconfiguration.ReconfigurationController, "_command", command)

    def quantise(B, spec):  # the ADC's rounding axis by axis
        B = np.clip(np.asarray(B, dtype=float), -spec.range_T, spec.range_T)
        lsb = np.asarray(spec.lsb_T, dtype=float)
        out = B.copy()
        nz = lsb > 0
        out[nz] = np.round(B[nz] / lsb[nz]) * lsb[nz]
        return out

    monkeypatch.setattr(hall_sensor, "quantise_reading", quantise)

    from ballchain.systems import station

    def feeder_alone(*args, add_feeder=station.add_feeder, **kwargs):  # every 2 ms step on its own
        return add_feeder(*args, **{**kwargs, "reader_period": 0.0})

    monkeypatch.setattr(station, "add_feeder", feeder_alone)


def _turned_numpy(q, omega_W, dt):
    """The quaternion's turn on numpy scalars (``rotating_magnet_unit._turned`` before it ran on
    plain floats)."""
    wx, wy, wz = omega_W
    speed = float(np.sqrt(wx * wx + wy * wy + wz * wz))
    if speed * dt == 0.0:
        return q
    half = 0.5 * speed * dt
    c, k = np.cos(half), np.sin(half) / speed
    ax, ay, az = k * wx, k * wy, k * wz
    w, x, y, z = q
    return np.array([
        c * w - ax * x - ay * y - az * z,
        c * x + ax * w + ay * z - az * y,
        c * y - ax * z + ay * w + az * x,
        c * z + ax * y - ay * x + az * w,
    ])


# Both cases have two units, each sensor seeing the other's magnet and each estimator
# subtracting it. As named, the magnets start neutral (the controllers latch at the first sample);
# turned away from neutral, the controllers measure at every sample and the left unit
# reconfigures from 0.05 s.
_UNITS_OFF_NEUTRAL = (
    ", units: [{name: right_unit, anchor: carina_right, distance: 0.10, direction_W: [-0.45, -0.8, 0.0], "
    "m_hat_W: [0.0, 1.0, 0.2], joystick: [{time: 0.02, axes: [0.3, 0.0, 1.0]}]}, "
    "{name: left_unit, anchor: carina_left, distance: 0.10, direction_W: [0.8, -0.5, 0.0], m_hat_W: [1.0, 0.0, 0.0], "
    "joystick: [{time: 0.05, axes: [0.0, 0.0, 0.0], mode: 1}]}]")


@pytest.mark.parametrize("overrides, duration", [
    ("", 0.3),  # latched from 0.01 s, both magnets turning from 0.1 s
    pytest.param("", 1.0, marks=pytest.mark.slow),  # the whole scenario: the left unit's mode 1 from 0.5 s
    (_UNITS_OFF_NEUTRAL, 0.15),
])
def test_teleop_run_is_the_same_with_and_without_the_shortcuts(overrides, duration, monkeypatch):
    from ballchain.systems.hall_sensor import DipoleDirectionEstimator

    compensations = []
    remembered = DipoleDirectionEstimator._other_field

    def counted(self, k, R_WM):
        compensations.append(k)
        return remembered(self, k, R_WM)

    with monkeypatch.context() as patch:
        patch.setattr(DipoleDirectionEstimator, "_other_field", counted)
        fast, batch = _record("teleop_two_units", duration, overrides)
    # Off neutral the estimators run (and subtract the other unit) at every sample.
    assert len(compensations) >= (2 * 100 * duration if overrides else 0)
    with monkeypatch.context() as patch:
        _checked_path(patch)
        checked, alone = _record("teleop_two_units", duration, overrides)
    assert (batch, alone) == (0.05, None)  # the feeder in batches at the engine's updates, or alone
    assert fast.shape == checked.shape and len(fast) >= 100 * duration
    assert np.array_equal(fast, checked)  # bit for bit, every sample
    magnets = fast[:, 1:5]
    assert np.ptp(magnets, axis=0).max() > 1e-3, "the magnets should turn during the run"


def test_field_at_point_is_the_checked_source_field():
    """``FieldAtPoint`` gives a checked ``MagnetSource``'s field, bit for bit, for both models, at
    the unit's sensor (beyond the magnet's reach) and at a point within its bounding sphere."""
    from pydrake.math import RotationMatrix

    from ballchain.infrastructure.errors import UserInputError
    from ballchain.drake_models.field_sources import FieldAtPoint
    from ballchain.systems.unit_config import right_unit

    unit = right_unit().check_placed()
    rng = np.random.default_rng(4)
    turns = [RotationMatrix.MakeXRotation(a).multiply(RotationMatrix.MakeZRotation(b)).matrix()
             for a, b in rng.uniform(-np.pi, np.pi, (5, 2))]
    near = np.asarray(unit.p_WM) + np.array([0.0, 0.0, -0.75 * unit.magnet.bounding_radius])
    for model in ("dipole", "exact"):
        unit.model = model
        for point, beyond in ((unit.p_WS, True), (near, False)):
            at_point = FieldAtPoint(unit.magnet, unit.p_WM, model, point)
            assert at_point.beyond_reach is beyond
            inside = 0
            for R in turns:
                try:
                    checked = unit.source(R).field(point[None])[0]
                except UserInputError:  # the point inside the magnet at this orientation: refused alike
                    inside += 1
                    with pytest.raises(UserInputError, match="inside the CylinderMagnet"):
                        at_point(R)
                    continue
                assert np.array_equal(at_point(R), checked)
            assert inside < len(turns)


# --- the statics' field check: at the balls, in world ---------------------------------------------
class _NaNNear:
    """A field that is NaN within 0.5 mm of some points and zero elsewhere (a broken source)."""

    def __init__(self, points):
        self.points = np.asarray(points, float)

    def field_and_gradient(self, p_W):
        p = np.asarray(p_W, float).reshape(-1, 3)
        near = np.linalg.norm(p[:, None, :] - self.points[None], axis=2).min(axis=1) < 0.5e-3
        B, G = np.zeros((len(p), 3)), np.zeros((len(p), 3, 3))
        B[near], G[near] = np.nan, np.nan
        return B, G


def test_statics_field_check_looks_at_the_balls_in_world(heart, sdf):
    """In the heart the external field is given in world and the warm start in the base frame:
    a field that is NaN where the balls are (in world) is refused before the solve, and one that
    is NaN only at the base-frame coordinates (where no ball is) is not."""
    from ballchain.drake_models.params import BallChain
    from ballchain.optimization.statics import ChainStatics, straight_chain
    from ballchain.optimization.wall_constraints import HeartConstraints, SheathGeometry, base_rotation, sheath_split

    n, d, s = 16, 3.175e-3, 0.012  # the tip 12 mm inside: the balls away from the base-frame coordinates
    k, a = sheath_split(n, s, d)
    sheath = SheathGeometry(heart.p_HE, heart.sheath_axis_H, 1.8e-3, 0.3e-3)
    constraints = HeartConstraints(heart.p_HE + a * heart.sheath_axis_H, base_rotation(heart.sheath_axis_H), sdf,
                                   sheath, n_behind=k, gravity=True)
    chain = BallChain(n_balls=n - k)
    p_B, m_B = straight_chain(chain)
    p_W = constraints.to_world(p_B, m_B)[0]
    assert np.linalg.norm(p_W[:, None] - p_B[None], axis=2).min() > 5e-3  # the two sets apart
    statics = ChainStatics(chain, gravity=True)

    at_balls = statics.solve(_NaNNear(p_W), None, constraints=constraints)
    assert not at_balls.converged and "not finite" in at_balls.reason and at_balls.iterations == 0

    at_base_coordinates = statics.solve(_NaNNear(p_B), None, constraints=constraints)
    assert "not finite" not in at_base_coordinates.reason and at_base_coordinates.iterations > 0


def test_station_builds_the_watchdog_wall_distance_before_the_run():
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation

    station = MakeStation(load_scenario("heart_wall_contact", "{engine: statics}"))
    assert "wall_distance" in vars(station.heart)  # the cached k-d tree exists already


def test_callback_benchmark_times_every_callback():
    """``benchmarks/unit_callbacks.py`` calls each unit callback on a running station's context."""
    from script_helpers import load_benchmark

    module = load_benchmark("unit_callbacks")
    times = module.run("teleop_right_unit", at=0.05, number=3)
    assert {"Hall sample, turned", "magnet update", "drive update", "feeder update",
            "watchdog (a step between checks)"} <= set(times)
    assert all(np.isfinite(t) and t > 0 for t in times.values())
