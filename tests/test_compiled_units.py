"""The compiled actuation unit (``systems/actuation_unit.ActuationUnit`` on
``drake_models/kernels/actuation.py``) gives the composed Python unit's numbers bit for bit.

Law by law on random inputs (each kernel against the Python law it compiles), then whole runs:
the station's two-unit teleoperation with every unit option the scenario offers, and the
actuation-only diagram reconfiguring from off neutral, compared at every simulator step (every
unit state, estimate, dipole, measured angle and the engine's state). Exact equality, never a
tolerance: the kernels take each operation in the reference's order (the module docstring of
``kernels/actuation.py``)."""

from dataclasses import replace

import numpy as np
import pytest
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator

from ballchain.drake_models.dipole import DipoleFieldAtPoint
from ballchain.infrastructure.errors import NonFiniteSignal, UserInputError
from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.drake_models.kernels import actuation as K
from ballchain.drake_models.omniwheel import OmniWheelGeometry, paper_wheel_speeds
from ballchain.systems.actuation_station import StationOptions, add_unit_systems, make_actuation_station, unit_system
from ballchain.systems.actuation_unit import ActuationUnit, compilable
from ballchain.systems.hall_sensor import DipoleDirectionEstimator, HallSensorSpec, quantise_reading
from ballchain.systems.omni_wheel_drive import StepperSpec, saturate_uniformly
from ballchain.systems.reconfiguration import ReconfigurationController
from ballchain.systems.rotating_magnet_unit import _norm, _turned
from ballchain.systems.unit_config import left_unit, right_unit

RNG = np.random.default_rng(20261204)


M_NEUTRAL = np.array([-1.0, 0.2, 0.1])  # normalised by the unit and the controller alike


def _unit_constants(**unit_options):
    """An ActuationUnit's kernel constants (maps, c, vec, sources, comp, comp_of)."""
    unit = ActuationUnit(right_unit(**unit_options), m_neutral_W=M_NEUTRAL, others=[left_unit()])
    return unit, unit._constants


def _vectors(n, size=3, spread=3.0):
    """Random vectors over orders of magnitude."""
    return RNG.normal(size=(n, size)) * 10.0 ** RNG.uniform(-spread, spread, (n, 1))


def test_the_magnets_turn_and_rotation_are_the_python_systems():
    maps, c = _unit_constants(slip=0.05)[1][:2]
    g = OmniWheelGeometry()
    for wheels, q, dt in zip(_vectors(300), RNG.normal(size=(300, 4)), RNG.uniform(0.0, 0.02, 300)):
        omega = K.magnet_angular_velocity(maps, c, wheels)
        assert np.array_equal(omega, 0.95 * g.sphere_angular_velocity(wheels))
        reference = _turned(q, omega, float(dt))
        turned = K.turned(q, omega, float(dt))
        assert np.array_equal(turned, reference)
        assert np.array_equal(K.normalised(turned), reference / _norm(reference))
        qn = reference / _norm(reference)
        assert np.array_equal(K.rotation(qn), RotationMatrix(Quaternion(qn)).matrix())
    q = RNG.normal(size=4)  # no turn: a copy of q (never a view of the read-only state)
    still = K.turned(q, np.zeros(3), 0.005)
    assert np.array_equal(still, q) and not np.shares_memory(still, q)


def test_the_field_at_the_sensor_and_the_adc_are_the_python_laws():
    r = np.array([0.01, -0.02, -0.035])
    reference = DipoleFieldAtPoint(r)
    source = np.array([*reference._r3, *reference._r[0], reference._inv_r, reference._inv_r3, 2.5])
    for m in _vectors(500):
        assert np.array_equal(K.dipole_field(source, m), reference(m))
    c = np.zeros(K.N_CONSTANTS)
    for lsb in ((1.5e-7, 1.5e-7, 2.4e-7), (1e-6, 0.0, 2e-6)):
        spec = HallSensorSpec(range_T=0.05, lsb_T=lsb)
        c[K.C_RANGE] = spec.range_T
        vec = np.array([np.zeros(3), np.zeros(3), np.asarray(lsb)])
        for B in _vectors(500, spread=2.0) * 1e-3:  # up to 0.1 T: some saturate
            assert np.array_equal(K.quantised(B, c, vec), quantise_reading(B, spec))


def test_the_estimate_is_the_estimators():
    unit, (maps, c, vec, sources, comp, comp_of) = _unit_constants()
    estimator = DipoleDirectionEstimator(unit.config, compensate_units=[left_unit()])
    context = estimator.CreateDefaultContext()
    for B, q in zip(_vectors(300, spread=1.0) * 1e-3, RNG.normal(size=(300, 4))):
        B[RNG.integers(3)] *= RNG.choice([1.0, 0.0])
        estimator.get_input_port(0).FixValue(context, B)
        qn = q / _norm(q)
        estimator.GetInputPort("X_WM_left_unit").FixValue(context, RigidTransform(RotationMatrix(Quaternion(qn)),
                                                                                  left_unit().p_WM))
        assert np.array_equal(K.estimate(B, q[None, :], maps, c, comp, comp_of), estimator.get_output_port(0).Eval(context))
    assert np.array_equal(K.estimate(np.zeros(3), q[None, :], maps, c, comp, comp_of), np.zeros(3))


@pytest.mark.parametrize("wheel_map", ["derived", "paper"])
def test_the_reconfiguration_law_is_the_controllers(wheel_map):
    """Random directions, and the antiparallel cone: near -m_c (the law's speed at the cone's edge)
    and exactly at it (the fixed axis)."""
    unit, (maps, c, vec, sources, comp, comp_of) = _unit_constants(wheel_map=wheel_map)
    controller = ReconfigurationController(M_NEUTRAL, gain=unit.config.controller_gain, wheel_map=wheel_map,
                                           geometry=unit.config.geometry)
    g = unit.config.geometry
    m_c = unit.m_c_W
    near = -m_c + 1e-3 * RNG.normal(size=(100, 3))
    directions = np.vstack([_vectors(300, spread=1.0), near, [-m_c, -2.0 * m_c, np.zeros(3)]])
    branches = set()
    for m in directions:
        wheels, omega = K.reconfiguration_command(m, maps, c, vec)
        assert np.array_equal(wheels, controller.wheel_command(m))
        assert np.array_equal(omega, g.sphere_angular_velocity(controller.wheel_command(m)))
        if m.any():
            n = m / np.linalg.norm(m)
            x = np.linalg.norm(np.cross(n, m_c))
            branches.add("cone" if n @ m_c < 0 and x < np.sin(np.radians(5.0)) else "law")
    assert branches == {"cone", "law"}
    if wheel_map == "paper":
        omega = RNG.normal(size=3)
        assert np.array_equal(K._matvec(maps[2], omega) / c[K.C_RATIO], paper_wheel_speeds(omega, g))
    assert np.array_equal(K.latched_command(maps, c)[1], g.sphere_angular_velocity(np.zeros(3)))


def test_wheel_maps_and_saturation_are_the_drives():
    maps, c = _unit_constants()[1][:2]
    g = OmniWheelGeometry()
    for omega in _vectors(300, spread=1.0):
        assert np.array_equal(K.wheel_speeds(maps, c, omega), g.wheel_speeds(omega))
        assert np.array_equal(K._saturated(g.wheel_speeds(omega), 2 * np.pi),
                              saturate_uniformly(g.wheel_speeds(omega), 2 * np.pi))


# -- whole runs ---------------------------------------------------------------------------------


def _unit_rows(station, root) -> np.ndarray:
    """Every unit's state (the composed systems' state groups in the ActuationUnit's order), its
    estimate, dipole and measured angle, then the engine's state."""
    row = []
    for h in station.units.values():
        if isinstance(h.magnet, ActuationUnit):
            row.append(h.magnet.state(h.magnet.GetMyContextFromRoot(root)))
        else:
            def groups(system):
                context = system.GetMyContextFromRoot(root)
                return [context.get_discrete_state(i).CopyToVector() for i in range(context.num_discrete_state_groups())]
            row += groups(h.magnet) + groups(h.drive) + groups(h.sensor) + groups(h.controller)
        for system, port in ((h.estimator, "m_hat_W"), (h.magnet, "m_W"), (h.controller, "angle_error"),
                             (h.magnet, "q_WM"), (h.drive, "wheel_angles")):
            row.append(system.GetOutputPort(port).Eval(system.GetMyContextFromRoot(root)).copy())
    engine = station.chain.engine_system
    row.append(engine.state_vector(engine.GetMyContextFromRoot(root)).copy())
    return np.concatenate(row)


def _station_rows(unit_systems: str, duration: float, change=None) -> np.ndarray:
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation

    scenario = load_scenario("teleop_two_units", f"{{engine: statics, mode: quasi-static, unit_systems: {unit_systems}}}")
    if change is not None:
        change(scenario)
    station = MakeStation(scenario.validate())
    assert all(h.magnet is h.controller for h in station.units.values()) == (unit_systems == "compiled")
    simulator = Simulator(station.diagram)
    rows = []
    simulator.set_monitor(lambda root: rows.append(np.concatenate([[root.get_time()], _unit_rows(station, root)])))
    simulator.Initialize()
    simulator.AdvanceTo(duration)
    return np.array(rows)


def _right(**options):
    def change(scenario):
        scenario.units = [replace(scenario.units[0], **options), scenario.units[1]]
    return change


def _both(**options):
    def change(scenario):
        scenario.units = [replace(u, **options) for u in scenario.units]
    return change


def _from_antiparallel(scenario):
    """The right unit starts at -m_c and reconfigures at once: the law's stall point."""
    from ballchain.systems.chain_simulation import MakeStation
    from ballchain.systems.unit_config import JoystickKey

    m_c = MakeStation(scenario.validate()).units["right_unit"].m_hat_neutral_W
    scenario.units = [replace(scenario.units[0], m_hat_W=(-m_c).tolist(),
                              joystick=[JoystickKey(time=0.0, axes=[0.0, 0.0, 0.0], mode=1)]), scenario.units[1]]


@pytest.mark.parametrize("change, duration", [
    (None, 0.6),  # both magnets swept, noisy sensors, each seeing and subtracting the other
    pytest.param(None, 1.5, marks=pytest.mark.slow),  # the left unit's reconfiguration from 0.5 s
    pytest.param(_both(model="exact"), 0.6, marks=pytest.mark.slow),  # magpylib's field at the sensor
    pytest.param(_right(wheel_map="paper", slip=0.05, sensor_noise=False), 0.6, marks=pytest.mark.slow),
    pytest.param(_right(teleop_frame="tip"), 0.6, marks=pytest.mark.slow),
    pytest.param(_both(sensors_see_other_units=False), 0.6, marks=pytest.mark.slow),
    pytest.param(_both(estimator_compensates_other_units=False), 0.6, marks=pytest.mark.slow),
    (_from_antiparallel, 0.6),
], ids=["swept", "whole", "exact", "paper_slip_quiet", "tip_frame", "blind", "uncompensated", "antiparallel"])
def test_the_compiled_units_run_the_composed_units_numbers(change, duration):
    composed = _station_rows("python", duration, change)
    compiled = _station_rows("compiled", duration, change)
    assert composed.shape == compiled.shape and len(composed) > 100
    assert np.ptp(composed[:, 1:5], axis=0).max() > 0.0  # the right magnet turned
    different = np.flatnonzero(np.any(composed != compiled, axis=1))
    assert different.size == 0, f"first different step at t = {composed[different[0], 0]} s"


def test_the_actuation_only_diagram_is_the_same_with_compiled_units():
    """Reconfiguring both units from off neutral with the field points, the feeder and noisy
    sensors: every exported output at every step."""
    units = [right_unit(slip=0.02), left_unit()]
    points = np.array([[0.0, 0.0, 0.0], [0.01, 0.02, -0.01]])
    logs = {}
    for compiled in (False, True):
        station = make_actuation_station(units, StationOptions(field_points_W=points, with_feeder=True,
                                                               compiled_units=compiled))
        context = station.CreateDefaultContext()
        for n, m0 in (("right_unit", [0.0, 0.6, 0.8]), ("left_unit", [0.3, -0.2, -0.9])):
            station.GetInputPort(f"{n}.mode").FixValue(context, [1.0])
            station.GetInputPort(f"{n}.joystick").FixValue(context, np.zeros(3))
            magnet = unit_system(station, n, "magnet")
            assert isinstance(magnet, ActuationUnit) == compiled
            magnet.set_orientation(magnet.GetMyMutableContextFromRoot(context), rotation_with_z_along(m0))
        station.GetInputPort("feeder.v_insert_cmd").FixValue(context, [0.01])
        outputs = [station.get_output_port(i) for i in range(station.num_output_ports())
                   if station.get_output_port(i).get_name().split(".")[-1] != "X_WM"]
        log = []

        def monitor(root):
            log.append(np.concatenate([[root.get_time()]] + [np.atleast_1d(p.Eval(root)).astype(float) for p in outputs]))

        simulator = Simulator(station, context)
        simulator.set_monitor(monitor)
        simulator.AdvanceTo(0.4)
        logs[compiled] = np.array(log)
    assert logs[False].shape == logs[True].shape
    assert np.array_equal(logs[False], logs[True])


# -- the edges ----------------------------------------------------------------------------------


def test_a_nan_command_stops_the_compiled_unit_naming_it_the_port_and_the_time():
    station = make_actuation_station([right_unit()])
    context = station.CreateDefaultContext()
    station.GetInputPort("right_unit.mode").FixValue(context, [0.0])
    station.GetInputPort("right_unit.joystick").FixValue(context, [np.nan, 0.0, 0.0])
    with pytest.raises(NonFiniteSignal, match=r"right_unit\.\w+: input port '\w+' is not finite at t = 0"):
        Simulator(station, context).AdvanceTo(0.02)
    context = station.CreateDefaultContext()
    station.GetInputPort("right_unit.mode").FixValue(context, [np.nan])
    station.GetInputPort("right_unit.joystick").FixValue(context, np.zeros(3))
    with pytest.raises(NonFiniteSignal, match=r"right_unit\.unit: input port 'mode' is not finite at t = 0"):
        Simulator(station, context).AdvanceTo(0.02)
    station.GetInputPort("right_unit.mode").FixValue(context, [2.0])
    with pytest.raises(ValueError, match=r"right_unit\.unit: mode must be 0 \(teleoperation\) or 1"):
        Simulator(station, context).AdvanceTo(0.02)


def test_a_unit_the_compiled_update_cannot_reproduce_is_built_from_the_composed_systems():
    """A Hall period that is not a whole number of drive periods: the composed systems (the
    station's choice), a clear error from ActuationUnit itself."""
    odd = HallSensorSpec(sample_rate_hz=150.0)
    assert not compilable(right_unit(), [], odd, StepperSpec())
    assert compilable(right_unit(), [left_unit()], HallSensorSpec(), StepperSpec())
    from pydrake.systems.framework import DiagramBuilder

    systems = add_unit_systems(DiagramBuilder(), [right_unit()], StationOptions(sensor_spec=odd),
                               m_neutral_W=[np.array([-1.0, 0.0, 0.0])], seeds=[0])
    assert not systems["right_unit"].compiled
    with pytest.raises(UserInputError, match="whole number of drive periods"):
        ActuationUnit(right_unit(), m_neutral_W=[-1.0, 0.0, 0.0], sensor_spec=odd)
    with pytest.raises(UserInputError, match="m_neutral_W"):
        ActuationUnit(right_unit(), m_neutral_W=[0.0, 0.0, 0.0])


def test_the_scenario_chooses_the_units_systems():
    from ballchain.systems.chain_scenario import load_scenario

    assert load_scenario("teleop_right_unit").unit_systems == "compiled"
    with pytest.raises(UserInputError, match="unit_systems"):
        load_scenario("teleop_right_unit", "{unit_systems: numba}").validate()


@pytest.mark.slow
def test_the_warm_up_compiles_what_a_station_runs():
    """After ``kernels.actuation.warm_up`` (run when the first unit is built) a station's run calls
    each kernel with the types it was compiled for: no second specialisation (a read-only state
    against a writable one would compile every kernel twice)."""
    import json
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import json
        from ballchain.drake_models.kernels import actuation as K
        K.warm_up()
        names = ["update", "sample", "sensor_field", "estimate", "reconfiguration_command", "latched_command",
                 "rotation", "normalised", "quaternion_at", "magnet_angular_velocity"]
        before = {n: len(getattr(K, n).signatures) for n in names}
        from pydrake.systems.analysis import Simulator
        from ballchain.systems.chain_scenario import load_scenario
        from ballchain.systems.chain_simulation import MakeStation
        station = MakeStation(load_scenario("teleop_two_units", "{engine: statics, mode: quasi-static}"))
        Simulator(station.diagram).AdvanceTo(0.7)
        for h in station.units.values():
            context = h.magnet.GetMyContextFromRoot(station.diagram.CreateDefaultContext())
            h.magnet.R_WM(context), h.magnet.true_field(context), h.estimator.GetOutputPort("angle_error").Eval(context)
        print(json.dumps([before, {n: len(getattr(K, n).signatures) for n in names}]))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=600)
    before, after = json.loads(out.stdout.strip().splitlines()[-1])
    assert before == after and set(before.values()) == {1}
