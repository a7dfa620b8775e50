"""The moving wall (``drake_models.wall_motion``): the motion law, the moved signed distances, the
quasi-static limit's numbers, the quasi-static engine with the anatomy moving (the tip's force
oscillates at the motion's frequency, the wall constraint holds, the compiled solve equals the
Python reference, a still or absent motion is today's engine bit for bit, respiration in a uniform
field carries the chain rigidly), the parts that follow the wall (touch tracker, Meshcat
geometry, watchdog) and the scenario field's validation."""

import math
import re

import numpy as np
import pytest

from ballchain.drake_models import wall_motion as wm
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.params import BallChain
from ballchain.drake_models.wall_motion import Oscillation, WallMotion
from ballchain.optimization.wall_constraints import PlaneSDF

GF = 9.80665e-3  # [N] per gram-force


# --- the motion law -----------------------------------------------------------------------------
def test_oscillation_period_amplitude_and_direction():
    o = Oscillation(2e-3, 1.25, (0.0, 3.0, 4.0))
    assert o.direction == pytest.approx((0.0, 0.6, 0.8), abs=1e-15) and o.period == 0.8
    t = np.linspace(0.0, 3 * o.period, 3001)
    x = np.array([o.offset(ti) for ti in t])
    np.testing.assert_allclose(np.cross(x, o.direction), 0.0, atol=1e-18)  # along its direction
    along = x @ np.asarray(o.direction)
    assert along[0] == 0.0  # at rest at t = 0
    assert along.max() == pytest.approx(2e-3, rel=1e-6) and along.min() == pytest.approx(-2e-3, rel=1e-6)
    shifted = np.array([o.offset(ti + o.period) for ti in t])
    np.testing.assert_allclose(shifted, x, rtol=0, atol=1e-15)  # periodic
    h = 1e-6
    for ti in (0.1, 0.37, 0.7):  # velocity = the offset's derivative (central differences)
        fd = (o.offset(ti + h) - o.offset(ti - h)) / (2 * h)
        np.testing.assert_allclose(o.velocity(ti), fd, rtol=1e-6, atol=1e-12)


def test_wall_motion_composes_respiration_and_heart_beat():
    law = WallMotion.default()
    assert law.respiratory.amplitude == 5e-3 and law.respiratory.frequency == 0.25
    assert law.cardiac.amplitude == 1e-3 and law.cardiac.frequency == 1.2
    for t in (0.0, 0.3, 1.7, 2.2):
        np.testing.assert_array_equal(law.heart_offset(t), law.respiratory.offset(t))
        np.testing.assert_array_equal(law.wall_offset(t), law.respiratory.offset(t) + law.cardiac.offset(t))
    assert not law.still
    assert WallMotion(Oscillation(0.0, 0.25, (0, 0, 1)), Oscillation(0.0, 1.2, (1, 0, 0))).still


@pytest.mark.parametrize("amplitude, frequency, direction, field", [
    (-1e-3, 1.0, (0, 0, 1), "amplitude"), (0.5, 1.0, (0, 0, 1), "amplitude"), (math.nan, 1.0, (0, 0, 1), "amplitude"),
    (True, 1.0, (0, 0, 1), "amplitude"), ("1", 1.0, (0, 0, 1), "amplitude"), (1e-3, 0.0, (0, 0, 1), "frequency"),
    (1e-3, -1.0, (0, 0, 1), "frequency"), (1e-3, math.inf, (0, 0, 1), "frequency"),
    (1e-3, 50.0, (0, 0, 1), "frequency"),
    (1e-3, 1.0, (0, 0, 0), "direction"), (1e-3, 1.0, (0, 1), "direction"), (1e-3, 1.0, (0, math.nan, 1), "direction"),
    (1e-3, 1.0, "up", "direction"),
])
def test_oscillation_refuses_bad_values(amplitude, frequency, direction, field):
    with pytest.raises(UserInputError, match=rf"Oscillation\.{field} must"):
        Oscillation(amplitude, frequency, direction)


def test_moved_signed_distances(sdf):
    """A translated wall's distance at p + offset is the still wall's at p (to round-off); the
    node values are shared, and the compiled solve's view of the grid is rebuilt for the new origin."""
    from ballchain.optimization.compiled_model import _sdf_arrays

    offset = np.array([1.3e-3, -0.7e-3, 2.1e-3])
    rng = np.random.default_rng(5)
    p = rng.uniform(-0.015, 0.015, size=(50, 3))
    _sdf_arrays(sdf)  # the still wall's cached view
    moved = sdf.translated(offset)
    assert moved._padded is sdf._padded and not hasattr(moved, "_compiled_arrays")
    for a, b in zip(moved(p + offset, hessian=True), sdf(p, hessian=True)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * max(1.0, np.abs(b).max()))
    np.testing.assert_array_equal(_sdf_arrays(moved)[1][:3], sdf.origin + offset)
    np.testing.assert_array_equal(_sdf_arrays(sdf)[1][:3], sdf.origin)  # the original untouched
    plane = PlaneSDF([0.0, 0.012, 0.0], [0.0, -1.0, 0.0])
    np.testing.assert_allclose(plane.translated(offset)(p + offset)[0], plane(p)[0], rtol=0, atol=1e-17)


# --- where the quasi-static assumption stops holding --------------------------------------------
def test_inertial_and_viscous_forces_are_the_stated_laws():
    chain = BallChain()
    d, rho = chain.ball_diameter, chain.density
    inertial, viscous = wm.inertial_and_viscous_forces(1e-3, 2.0, 16, d, rho)
    mass = 16 * (rho + 0.5 * wm.BLOOD_DENSITY) * chain.ball_volume
    assert inertial == pytest.approx(mass * 1e-3 * (2 * math.pi * 2.0) ** 2, rel=1e-12)
    i2, _ = wm.inertial_and_viscous_forces(1e-3, 4.0, 16, d, rho)
    assert i2 == pytest.approx(4 * inertial, rel=1e-12)  # A w^2
    # At a small Reynolds number the drag is Stokes's 6 pi mu r v per ball (to the 0.15 Re^0.687 term).
    A, f = 1e-7, 1.0
    v = A * 2 * math.pi * f
    _, slow = wm.inertial_and_viscous_forces(A, f, 16, d, rho)
    assert slow == pytest.approx(16 * 6 * math.pi * wm.BLOOD_VISCOSITY * 0.5 * d * v, rel=2e-3)
    assert viscous > 0


def test_the_docstring_numbers_of_the_quasi_static_limit():
    """The module docstring's numbers (share of the 20 gf contact force at the physiological
    frequencies, the frequencies of 10 %) as the functions compute them."""
    chain = BallChain()
    args = (16, chain.ball_diameter, chain.density)
    share = {name: sum(wm.inertial_and_viscous_forces(A, f, *args)) / wm.CONTACT_FORCE
             for name, A, f in (("cardiac", 1e-3, 1.2), ("respiratory", 5e-3, 0.25))}
    limit = {name: wm.quasi_static_limit(A, *args) for name, A in (("cardiac", 1e-3), ("respiratory", 5e-3))}
    text = " ".join(wm.__doc__.split())
    assert f"they are {100 * share['cardiac']:.2f} % of the contact force at 1.2 Hz" in text
    assert f"reach 10 % at {limit['cardiac']:.0f} Hz" in text
    assert f"they are {100 * share['respiratory']:.2f} % at 0.25 Hz" in text
    assert f"reach 10 % at {limit['respiratory']:.1f} Hz" in text
    for name, A in (("cardiac", 1e-3), ("respiratory", 5e-3)):  # the limit is where the share is 10 %
        F = sum(wm.inertial_and_viscous_forces(A, limit[name], *args))
        assert F == pytest.approx(0.1 * wm.CONTACT_FORCE, rel=1e-9)
    assert wm.quasi_static_limit(0.0, *args) == math.inf


# --- the quasi-static engine with the anatomy moving ----------------------------------------------
S_PRESSED = 0.047  # [m]: heart_wall_contact's final insertion, the tip pressed on the roof by 30 mT


@pytest.fixture(scope="module")
def station():
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.station import MakeStation

    return MakeStation(load_scenario("heart_wall_contact_moving",
                                     f"{{insertion: {{initial: {S_PRESSED}, final: {S_PRESSED}}}}}"))


def _cardiac_only(frequency=1.25, amplitude=1e-3):
    return WallMotion(Oscillation(0.0, 0.25, (0, 0, 1)), Oscillation(amplitude, frequency, (1, 1, -1)))


def _run(engine, times, s=S_PRESSED):
    """The engine's states after its initialisation at t = 0 and an update at each of ``times``."""
    context = engine.CreateDefaultContext()
    engine.get_feeder_state_input_port().FixValue(context, [s, 0.0])
    engine.ExecuteInitializationEvents(context)
    states = [engine.state_vector(context).copy()]
    for t in times:
        context.SetTime(t)
        context.SetDiscreteState(engine.EvalUniquePeriodicDiscreteUpdate(context))
        states.append(engine.state_vector(context).copy())
    return np.array(states)


def test_the_station_engine_moves_with_the_scenario(station):
    engine = station.chain.engine_system
    assert engine.wall_motion == WallMotion.default() and engine.compiled
    names = [engine.get_output_port(i).get_name() for i in range(engine.num_output_ports())]
    assert names == ["body_poses", "tip_wall_force", "ball_positions", "snap_throughs", "anatomy_offsets"]
    assert engine.get_anatomy_offsets_output_port().size() == 6


def test_tip_force_oscillates_at_the_heart_rate_and_the_wall_holds(station):
    """Pressed on the roof, the heart beat alone (1.25 Hz: 16 updates of 50 ms a cycle): the tip's
    wall force is periodic with the beat (a cycle later the same to 1e-9 N; measured 6e-16 N),
    its spectrum peaks at 1.25 Hz, it varies by more than 0.1 gf; no free ball is inside the
    moved wall beyond the solver's feasibility tolerance (1e-9 of a ball diameter); the tip
    touches the moved wall and its force is along that wall's normal."""
    engine = station.chain.engine_system.replica(wall_motion=_cardiac_only())
    dt = 0.05
    times = dt * np.arange(1, 65)  # four beats
    x = _run(engine, times)[1:]
    sl, n, d = engine._slices, engine._n, engine._d
    f = x[:, sl["tip"]][:, :3]
    force = np.linalg.norm(f, axis=1)
    assert force.min() > 10 * GF  # pressed all along
    np.testing.assert_allclose(force[32:], force[16:48], rtol=0, atol=1e-9)  # periodic in the beat
    assert np.ptp(force[16:]) > 0.1 * GF  # measured 0.40 gf on this branch (initialised at 47 mm)
    spectrum = np.abs(np.fft.rfft(force[16:] - force[16:].mean()))
    assert np.fft.rfftfreq(48, dt)[np.argmax(spectrum)] == pytest.approx(1.25)
    tolerance = next(iter(engine._solvers.values())).feasibility_tolerance * d
    for t, row in zip(times, x):
        p = row[sl["p"]].reshape(n, 3)
        moved = engine._placement(t)[1]
        _, constraints = engine._constraints(S_PRESSED, t)
        free = p[constraints.n_behind + 1:]
        beyond = (free - engine._placement(t)[0]) @ engine._axis > 0
        assert np.all(moved(free[beyond], gradient=False) - 0.5 * d >= -tolerance)
        # The tip touches the moved wall and is pushed along its normal there.
        distance, normal = moved(p[-1:])
        assert abs(distance[0] - 0.5 * d) <= 1e-9
        np.testing.assert_allclose(f[list(times).index(t)] / np.linalg.norm(f[list(times).index(t)]),
                                   normal[0] / np.linalg.norm(normal[0]), rtol=0, atol=1e-9)


def test_compiled_equals_the_reference_with_the_wall_moving(station):
    compiled = station.chain.engine_system.replica(wall_motion=WallMotion.default())
    reference = compiled.replica(compiled=False)
    times = 0.05 * np.arange(1, 9)
    a, b = _run(compiled, times), _run(reference, times)
    n = compiled._n
    assert np.abs(a[:, : 3 * n] - b[:, : 3 * n]).max() <= 1e-9
    assert np.abs(a[:, 6 * n: 6 * n + 3] - b[:, 6 * n: 6 * n + 3]).max() <= 1e-9  # the tip's force [N]


def test_still_or_absent_motion_is_todays_engine_bit_for_bit(station):
    still = WallMotion(Oscillation(0.0, 0.25, (0, 0, 1)), Oscillation(0.0, 1.2, (1, 1, -1)))
    engines = [station.chain.engine_system.replica(wall_motion=m) for m in (None, still)]
    assert all(e.wall_motion is None for e in engines)
    times = 0.05 * np.arange(1, 6)
    for s in (S_PRESSED, 0.03):
        a, b = (_run(e, times, s) for e in engines)
        assert a.shape == b.shape and np.array_equal(a, b)
    # The scenario's field off (the default) or still builds today's engine too.
    from ballchain.systems.chain_scenario import load_scenario

    off = load_scenario("heart_wall_contact_moving", "{wall_motion: {enabled: false}}")
    zero = load_scenario("heart_wall_contact_moving",
                         "{wall_motion: {respiratory: {amplitude: 0.0}, cardiac: {amplitude: 0.0}}}")
    assert off.wall_motion.law() is None and zero.wall_motion.law() is None


def test_respiration_in_a_uniform_field_carries_the_chain_rigidly(station):
    """Respiration alone moves the heart, the sheath and the wall together; in a uniform field
    with gravity (both the same everywhere) the equilibrium moves with them: every ball by the
    heart's offset (measured: to 2e-16 m, the same problem in the sheath's frame; the force to
    1e-10 N)."""
    law = WallMotion(Oscillation(5e-3, 0.25, (0.3, -0.2, 1.0)), Oscillation(0.0, 1.2, (1, 1, -1)))
    engine = station.chain.engine_system.replica(wall_motion=law)
    still = station.chain.engine_system.replica(wall_motion=None)
    times = 0.05 * np.arange(1, 21)
    moving, rest = _run(engine, times), _run(still, times[:1])
    n = engine._n
    for t, row in zip(times, moving[1:]):
        shift = row[: 3 * n].reshape(n, 3) - rest[-1, : 3 * n].reshape(n, 3)
        np.testing.assert_allclose(shift, np.tile(law.heart_offset(t), (n, 1)), rtol=0, atol=1e-12)
    assert np.abs(moving[1:, 6 * n: 6 * n + 3] - rest[-1, 6 * n: 6 * n + 3]).max() < 1e-9  # [N]


# --- what follows the wall ------------------------------------------------------------------------
def test_touch_tracker_sees_the_targets_where_the_wall_put_them():
    from pydrake.math import RigidTransform

    from ballchain.systems.target_contact import TargetTouchTracker

    p_T, n_T, r = np.array([[0.01, 0.0, 0.0]]), np.array([[-1.0, 0.0, 0.0]]), 1.5875e-3
    offset = np.array([0.0, 0.0, 4e-3])  # further than the 2.5 mm target radius
    tracker = TargetTouchTracker(1, ["left_1"], p_T, n_T, 2.5e-3, r, 0.05, moving_wall=True)
    context = tracker.CreateDefaultContext()
    tip_on_moved = RigidTransform(p_T[0] + offset - r * n_T[0])
    tracker.get_body_poses_input_port().FixValue(context, [RigidTransform(), tip_on_moved])
    tracker.get_anatomy_offsets_input_port().FixValue(context, np.r_[np.zeros(3), offset])
    tracker.ExecuteInitializationEvents(context)
    assert tracker.touched_names(context) == ["left_1"]
    tracker.get_anatomy_offsets_input_port().FixValue(context, np.zeros(6))  # the still wall: 4 mm off
    fixed = TargetTouchTracker(1, ["left_1"], p_T, n_T, 2.5e-3, r, 0.05)
    assert fixed.get_anatomy_offsets_input_port() is None
    c2 = fixed.CreateDefaultContext()
    fixed.get_body_poses_input_port().FixValue(c2, [RigidTransform(), tip_on_moved])
    fixed.ExecuteInitializationEvents(c2)
    assert fixed.touched_names(c2) == []


def test_meshcat_geometry_moves_the_wall_and_the_sheath(heart):
    from pydrake.geometry import SceneGraph
    from pydrake.math import RigidTransform

    from ballchain.optimization.wall_constraints import SheathGeometry
    from ballchain.systems.quasi_static_engine import EngineGeometry

    sheath = SheathGeometry(heart.p_HE, heart.sheath_axis_H, 1.8e-3, 0.3e-3)
    scene_graph = SceneGraph()
    geometry = EngineGeometry(scene_graph, [1, 2], 1.5e-3, heart, sheath, 0.05, moving_anatomy=True)
    inspector = scene_graph.model_inspector()
    frames = {inspector.GetName(f): f for f in inspector.GetAllFrameIds()}
    wall_geometry = [g for g in inspector.GetAllGeometryIds() if inspector.GetName(g).endswith("heart_wall")][0]
    assert inspector.GetFrameId(wall_geometry) == frames["heart"]
    context = geometry.CreateDefaultContext()
    geometry.get_body_poses_input_port().FixValue(context, [RigidTransform()] * 3)
    offsets = np.array([0.0, 0.0, 2e-3, 0.5e-3, 0.5e-3, 1.5e-3])
    geometry.get_anatomy_offsets_input_port().FixValue(context, offsets)
    poses = geometry.get_geometry_pose_output_port().Eval(context)
    np.testing.assert_array_equal(poses.value(frames["heart"]).translation(), offsets[3:])
    np.testing.assert_array_equal(poses.value(frames["sheath"]).translation(), offsets[:3])
    still = EngineGeometry(SceneGraph(), [1, 2], 1.5e-3, heart, sheath, 0.05)
    assert still.get_anatomy_offsets_input_port() is None and still.num_input_ports() == 1


@pytest.mark.slow
def test_the_moving_wall_scenario_runs_and_the_watchdog_follows_the_wall():
    """The named scenario (the default motion, 5 s): the watchdog measures the clearance against
    the moved wall (respiration's 5 mm would otherwise read as sinking into it), no solve fails,
    the tip stays pressed on the roof."""
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import run_simulation

    m = run_simulation(scenario=load_scenario("heart_wall_contact_moving"))
    assert m.statics.failures == [] and m.statics.snap_throughs == []
    assert m.min_wall_clearance_mm > -1e-3 and m.max_wall_penetration_um < 1.0  # the SDF grid's error
    assert np.linalg.norm(m.tip_wall_force_N) > 10 * GF


@pytest.mark.slow
def test_the_replay_moves_the_atrium_the_sheath_and_the_target_discs(tmp_path):
    """A recorded run of the moving scenario: the wall and the targets are drawn on the frame
    ``heart``, the sheath on ``sheath``, and the overlays' target discs under a moved
    ``overlays/targets`` (each has its own animated transform in the replay)."""
    from pydrake.geometry import Meshcat, MeshcatParams

    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import run_simulation

    html = tmp_path / "moving.html"
    run_simulation(scenario=load_scenario("heart_wall_contact_moving", "{duration: 0.3}"), html=html,
                   meshcat=Meshcat(MeshcatParams(host="localhost")))
    from test_meshcat_overlays import _html_payload

    payload = _html_payload(html.read_text())
    for path in (b"visualizer/heart/heart_wall", b"visualizer/heart/target_left_1", b"visualizer/sheath/sheath"):
        assert path in payload, path
    for path in (rb"visualizer/heart", rb"visualizer/sheath", rb"overlays/targets"):
        assert re.search(path + rb"(?![/A-Za-z0-9_])", payload), path  # the moving parent itself


# --- the scenario field ---------------------------------------------------------------------------
def _load(overrides, name="heart_wall_contact_moving"):
    from ballchain.systems.chain_scenario import load_scenario

    return load_scenario(name, overrides)


def test_scenario_defaults_are_off_and_the_literatures():
    from ballchain.systems.chain_scenario import ChainScenario

    default = ChainScenario().validate().wall_motion
    assert not default.enabled and default.law() is None
    assert _load(None).wall_motion.law() == WallMotion.default()
    changed = _load("{wall_motion: {cardiac: {amplitude: 0.002, frequency: 1.0, direction_W: [0, 1, 0]}}}")
    assert changed.wall_motion.law().cardiac == Oscillation(2e-3, 1.0, (0.0, 1.0, 0.0))
    assert changed.wall_motion.law().respiratory == WallMotion.default().respiratory


@pytest.mark.parametrize("overrides, message", [
    ("{wall_motion: {enabled: 1}}", "wall_motion.enabled"),
    ("{wall_motion: {cardiac: {amplitude: -0.001}}}", r"wall_motion\.cardiac\.amplitude must be a number in \[0"),
    ("{wall_motion: {cardiac: {amplitude: 1.0}}}", r"wall_motion\.cardiac\.amplitude"),
    ("{wall_motion: {respiratory: {amplitude: .nan}}}", r"wall_motion\.respiratory\.amplitude must be a finite"),
    ("{wall_motion: {respiratory: {amplitude: five}}}", r"wall_motion\.respiratory\.amplitude"),
    ("{wall_motion: {respiratory: {frequency: 0.0}}}", r"wall_motion\.respiratory\.frequency must be"),
    ("{wall_motion: {respiratory: {frequency: -0.25}}}", r"wall_motion\.respiratory\.frequency must be"),
    ("{wall_motion: {respiratory: {frequency: .inf}}}", r"wall_motion\.respiratory\.frequency must be a finite"),
    ("{wall_motion: {cardiac: {frequency: 3.0}}}", r"wall_motion\.cardiac\.frequency 3 Hz is sampled 6\.7 times"),
    ("{wall_motion: {cardiac: {direction_W: [0, 0, 0]}}}", r"wall_motion\.cardiac\.direction_W must be 3"),
    ("{wall_motion: {cardiac: {direction_W: [1, 0]}}}", r"wall_motion\.cardiac\.direction_W must be 3"),
    ("{wall_motion: {cardiac: {direction_W: up}}}", r"wall_motion\.cardiac\.direction_W"),
    ("{wall_motion: {cardiac: {phase: 1.0}}}", "phase"),
    ("{engine: plant}", "wall_motion needs engine: statics"),
    ("{wall_motion: {enabled: false, cardiac: {amplitude: 0.002}}}", "read only with wall_motion.enabled: true"),
    ("{heart: false}", "needs the heart or a wall_plane"),
])
def test_scenario_refuses_bad_wall_motion(overrides, message):
    with pytest.raises(UserInputError, match=message) as err:
        _load(overrides)
    assert "\n" not in str(err.value) and len(str(err.value)) < 400


def test_scenario_statics_period_must_sample_the_motion():
    assert _load("{statics_period: 0.02, wall_motion: {cardiac: {frequency: 3.0}}}").wall_motion.law() is not None
    with pytest.raises(UserInputError, match=re.escape("lower statics_period or the frequency")):
        _load("{statics_period: 0.5}")
