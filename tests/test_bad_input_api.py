"""Bad input through the Python API and in a user's mesh file: a UserInputError naming the
argument (or the file and line) and what is allowed, never a numpy error from deep inside."""

from __future__ import annotations

import re
import struct

import numpy as np
import pytest

from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models.atrium_mesh import AtriumMeshError, load_atrium_surface, read_obj
from ballchain.infrastructure.errors import UserInputError


# ------------------------------------------------------------------ a user's mesh file

def _sphere_obj_lines() -> list[str]:
    U, F = mt.icosphere(1)
    V = U * 25.0  # mm
    return [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in V] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]


def _with_line(lines: list[str], index: int, text: str) -> str:
    return "\n".join(lines[:index] + [text] + lines[index:]) + "\n"


def _obj_case(how: str, lines: list[str]) -> tuple[str, int]:
    """(file text, 1-based number of the bad line)."""
    nv = sum(1 for line in lines if line.startswith("v "))
    cases = {
        "two coordinates": (3, "v 1.0 2.0"),
        "a word for a coordinate": (3, "v 1.0 two 3.0"),
        "NaN coordinate": (3, "v 1.0 nan 3.0"),
        "inf coordinate": (3, "v 1.0 2.0 -inf"),
        "index beyond int64": (nv + 2, "f 1 2 99999999999999999999999"),
        "index beyond the vertices": (nv + 2, f"f 1 2 {nv + 1}"),
        "index 0": (nv + 2, "f 0 1 2"),
        "negative index too far back": (nv + 2, f"f -1 -2 -{nv + 1}"),
        "a face of two vertices": (nv + 2, "f 1 2"),
        "a word for an index": (nv + 2, "f 1 two 3"),
    }
    index, text = cases[how]
    return _with_line(lines, index, text), index + 1


OBJ_CASES = ["two coordinates", "a word for a coordinate", "NaN coordinate", "inf coordinate", "index beyond int64",
             "index beyond the vertices", "index 0", "negative index too far back", "a face of two vertices",
             "a word for an index"]


@pytest.mark.parametrize("how", OBJ_CASES)
def test_a_malformed_obj_line_is_named_with_what_is_allowed(tmp_path, how):
    text, lineno = _obj_case(how, _sphere_obj_lines())
    path = tmp_path / "atrium.obj"
    path.write_text(text)
    with pytest.raises(AtriumMeshError) as err:
        load_atrium_surface(path)
    message = str(err.value)
    assert "\n" not in message and str(path) in message and f"line {lineno}:" in message, message
    assert "allowed:" in message


def test_an_obj_of_the_same_surface_in_utf16_or_with_a_bom_reads_the_same(tmp_path):
    text = "# an atrium\n" + "\n".join(_sphere_obj_lines()) + "\n"
    plain = read_obj(_write(tmp_path / "plain.obj", text.encode()))
    for name, data in (("utf16.obj", text.encode("utf-16")), ("bom.obj", b"\xef\xbb\xbf" + text.encode())):
        V, F = read_obj(_write(tmp_path / name, data))
        np.testing.assert_array_equal(V, plain[0])
        np.testing.assert_array_equal(F, plain[1])


def _write(path, data: bytes):
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("name, data, expected", [
    ("empty.obj", b"", "0 vertices and 0 faces"),
    ("comments.obj", b"# nothing here\n\n", "0 vertices and 0 faces"),
    ("garbage.obj", bytes(range(256)) * 4, "binary data, not a text OBJ"),
    ("garbage.stl", bytes(range(256)) * 4, "neither a binary STL"),
    ("empty.stl", b"", "neither a binary STL"),
])
def test_an_empty_or_binary_mesh_file_is_one_line(tmp_path, name, data, expected):
    path = _write(tmp_path / name, data)
    with pytest.raises(AtriumMeshError, match=expected) as err:
        load_atrium_surface(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)


def test_malformed_stl_records_are_named(tmp_path):
    U, F = mt.icosphere(1)
    V = U * 25.0
    ascii_path = tmp_path / "two.stl"
    from ballchain.drake_models.atrium_mesh import write_stl_ascii, write_stl_binary

    lines = write_stl_ascii(ascii_path, V, F).read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("vertex"))
    lines[k] = "vertex 1.0 2.0"
    ascii_path.write_text("\n".join(lines) + "\n")
    with pytest.raises(AtriumMeshError, match=rf"line {k + 1}: bad vertex .*allowed: 'vertex x y z'"):
        load_atrium_surface(ascii_path)
    binary = write_stl_binary(tmp_path / "nan.stl", V, F)
    data = bytearray(binary.read_bytes())
    data[84 + 50 * 3 + 12: 84 + 50 * 3 + 16] = struct.pack("<f", float("nan"))  # triangle 4, first corner x
    binary.write_bytes(bytes(data))
    with pytest.raises(AtriumMeshError, match="triangle 4 of the binary STL .* not finite"):
        load_atrium_surface(binary)


def test_a_folder_for_a_mesh_file_is_one_line(tmp_path):
    folder = tmp_path / "atrium.obj"
    folder.mkdir()
    with pytest.raises(AtriumMeshError, match="is a folder, not a mesh file"):
        load_atrium_surface(folder)


def test_the_command_says_which_line_of_the_users_mesh_is_wrong(tmp_path, capsys):
    from ballchain.cli import main

    text, lineno = _obj_case("two coordinates", _sphere_obj_lines())
    path = tmp_path / "la.obj"
    path.write_text(text)
    argv = ["simulate", "--scenario", "heart_no_field", "--duration", "0.001",
            "--set", f"{{atrium_file: '{path}', puncture: [-0.025, 0.0, 0.0]}}"]
    assert main(argv) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "atrium_file" in line and str(path) in line and f"line {lineno}:" in line and "3 finite numbers" in line


# ------------------------------------------------------------------ the Python API

def _chain():
    from ballchain.drake_models.params import BallChain

    return BallChain(n_balls=4)


def _field():
    from ballchain.drake_models.field_sources import UniformField

    return UniformField([0.0, 0.023, 0.0])


def _solver():
    from ballchain.optimization.statics import ChainStatics

    return ChainStatics(_chain())


def _calls():
    """(label, call, the words the message must hold)."""
    from ballchain.drake_models import field_sources as fs
    from ballchain.drake_models.atrium_mesh import UserAtrium, validate_surface
    from ballchain.drake_models.heart import HeartParams, LeftAtrium
    from ballchain.drake_models.params import CylinderMagnet
    from ballchain.executor import Executor
    from ballchain.drake_models.params import BallChain, Sleeve
    from ballchain.drake_models.steerable_catheter import SteerableCatheter
    from ballchain.experiments import (ablation, alignment, clinical, field_models, manual_catheter, planner, procedure,
                                       reconfiguration, teleop, wheels, workspace)
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import run_simulation
    from ballchain.optimization import inverse_statics, sizing
    from ballchain.optimization.statics import ChainStatics, tip_angle_deg, uniform_field_equilibrium
    from ballchain.systems.actuation_station import StationOptions, make_actuation_station
    from ballchain.systems.rotating_magnet_unit import MagnetUnitConfig
    from ballchain.systems.feeder import Feeder
    from ballchain.systems.hall_sensor import HallSensor
    from ballchain.systems.reconfiguration import ReconfigurationController
    from ballchain.systems.rotating_magnet_unit import RotatingMagnetUnit
    from ballchain.systems.station import MakeStation

    U, F = mt.icosphere(1)
    return [
        ("UniformField 2-vector", lambda: fs.UniformField([0, 0.023]), "UniformField.B_W must be 3 finite numbers"),
        ("UniformField text", lambda: fs.UniformField("north"), "UniformField.B_W must be 3 finite numbers"),
        ("UniformField None", lambda: fs.UniformField(None), "UniformField.B_W"),
        ("UniformField booleans", lambda: fs.UniformField([True, False, False]),
         r"UniformField.B_W must be 3 finite numbers \[T\], got \[True, False, False\]"),
        ("MagnetSource reflection", lambda: fs.MagnetSource(CylinderMagnet(), [0, 0, 0.2], np.diag([1.0, 1.0, -1.0])),
         r"MagnetSource.R_WM is a reflection \(determinant -1\)"),
        ("MagnetSource magnet", lambda: fs.MagnetSource("N52", [0, 0, 0.1]),
         "MagnetSource.magnet must be CylinderMagnet"),
        ("MagnetSource p_WM", lambda: fs.MagnetSource(CylinderMagnet(), [0, 0.1]), "MagnetSource.p_WM must be 3"),
        ("MagnetSource model", lambda: fs.MagnetSource(CylinderMagnet(), [0, 0, 0.1], model=None),
         "MagnetSource.model must be one of 'dipole', 'exact'"),
        ("FieldSources of one", lambda: fs.FieldSources(_field()), "FieldSources.sources must be a list"),
        ("FieldSources item", lambda: fs.FieldSources([_field(), 0.023]), r"FieldSources.sources\[1\] must be a field"),
        ("direction zero", lambda: fs.rotation_with_z_along([0, 0, 0]),
         "direction must be 3 finite numbers (non-zero)"),
        ("ChainStatics chain", lambda: ChainStatics("not a chain"), "ChainStatics chain must be a BallChain, got str"),
        ("ChainStatics iterations", lambda: ChainStatics(_chain(), max_iterations=0),
         "max_iterations must be an integer"),
        ("ChainStatics gravity", lambda: ChainStatics(_chain(), gravity="yes"), "gravity must be True or False"),
        ("CylinderMagnet tiny", lambda: CylinderMagnet(diameter=1e-300),
         r"CylinderMagnet.diameter must be in \[0.1, 10000\] mm, got 1e-297 mm"),
        ("ChainStatics tolerance", lambda: ChainStatics(_chain(), tolerance=1e300),
         r"ChainStatics tolerance must be in \(0, 0.001\]"),
        ("solve external", lambda: _solver().solve("field"), "external must be a field source"),
        ("solve warm start", lambda: _solver().solve(_field(), warm_start=[1, 2]),
         "warm_start must be a StaticsResult"),
        ("tip target 2-vector", lambda: _solver().solve(_field(), tip_target=[0.01, 0.0]),
         "tip_target must be 3 finite"),
        ("wall normal 2-vector", lambda: _solver().solve(_field(), wall=([0.0, 0.0, -0.01], [0.0, 1.0])),
         "wall normal must be 3 finite numbers"),
        ("wall zero normal", lambda: _solver().solve(_field(), wall=([0.0, 0.0, -0.01], [0, 0, 0])),
         "wall normal must be 3 finite numbers (non-zero)"),
        ("wall not a pair", lambda: _solver().solve(_field(), wall=[0.0, 0.0, -0.01]),
         "wall must be a (point, normal) pair"),
        ("continuation of one field", lambda: _solver().continuation(_field()),
         "continuation fields must be a sequence"),
        ("tip angle direction", lambda: tip_angle_deg(_solver().solve(_field()), [0.0, 1.0]),
         "field_direction must be 3"),
        ("uniform equilibrium B_W", lambda: uniform_field_equilibrium(_chain(), [0.0, 0.023]), "B_W must be 3 finite"),
        ("pin_tip target", lambda: inverse_statics.pin_tip(_solver(), _field(), [0.01, 0.0], None),
         "pin_tip target must be 3 finite"),
        ("pin_tip solver", lambda: inverse_statics.pin_tip(_chain(), _field(), [0.01, 0, 0], None),
         "pin_tip solver must be a ChainStatics"),
        ("HeldTip axis", lambda: inverse_statics.HeldTip(_solver(), lambda m: None, [0, 0, 0], [1.0, 0.0], None),
         "HeldTip axis must be 3 finite numbers"),
        ("sizing moment", lambda: sizing.force_between_magnets(-1.0, 0.1), "moment must be a finite number > 0"),
        ("sizing inputs", lambda: sizing.size_clinical_magnet({"alpha": 0.32}), "inputs must be a SizingInputs"),
        ("MakeStation dict", lambda: MakeStation(dict), "MakeStation scenario must be a ChainScenario"),
        ("actuation units", lambda: make_actuation_station([{"name": "right_unit"}]),
         r"make_actuation_station units\[0\] must be MagnetUnitConfig"),
        ("actuation options", lambda: make_actuation_station(None, {"slip": 0.1}), "options must be a StationOptions"),
        ("unit slip", lambda: make_actuation_station([MagnetUnitConfig(p_WM=[0.0, -0.2, 0.0], slip=1.5)]), "slip must be in \\[0, 1\\)"),
        ("StationOptions seed", lambda: StationOptions(seed=-1), "StationOptions.seed must be"),
        ("StationOptions points", lambda: StationOptions(field_points_W=[0.0, 0.1]), "StationOptions.field_points_W"),
        ("MagnetUnitConfig shape", lambda: MagnetUnitConfig(shape="ball").magnet, "shape must be one of"),
        ("units None", lambda: validate_surface(U * 25.0, F, units=None), "units must be one of 'auto', 'm', 'mm'"),
        ("surface V 2 columns", lambda: validate_surface(U[:, :2], F), r"V must be an array of shape \(k, 3\)"),
        ("surface F beyond V", lambda: validate_surface(U * 25.0, F + 1), "F must index the 42 vertices"),
        ("UserAtrium surface", lambda: UserAtrium("atrium.obj", [0, 0, 0]),
         "UserAtrium surface must be an AtriumSurface"),
        ("HeartParams semi_axes", lambda: HeartParams(semi_axes=(0.03, 0.02)), "HeartParams.semi_axes must be 3"),
        ("LeftAtrium params", lambda: LeftAtrium({"scale": 1.0}), "LeftAtrium params must be a HeartParams"),
        ("field_models ball", lambda: field_models.run(distances_m=[0.1], angles_deg=[0.0], ball="3 mm"),
         "ball must be a BallChain"),
        ("planner targets", lambda: planner.run(targets="3"), "targets must be an integer >= 1"),
        ("Feeder chain", lambda: Feeder("16 balls"), "Feeder chain must be a BallChain or None"),
        ("HallSensor unit", lambda: HallSensor({"name": "right_unit"}), "HallSensor unit must be a MagnetUnitConfig"),
        ("RotatingMagnetUnit R_WM", lambda: RotatingMagnetUnit(R_WM=np.eye(2)),
         r"R_WM must be an array of shape \(3, 3\)"),
        ("ReconfigurationController m_c_W", lambda: ReconfigurationController([1.0, 0.0]), "m_c_W must be 3 finite"),
        ("wheels samples", lambda: wheels.run(samples=1.5), "samples must be an integer"),
        ("BallChain huge balls", lambda: BallChain(n_balls=4, ball_diameter=1e300),
         r"BallChain.ball_diameter must be in \[0.1, 100\] mm, got 1e\+303 mm"),
        ("BallChain tiny balls", lambda: BallChain(n_balls=4, ball_diameter=1e-300), "BallChain.ball_diameter"),
        ("BallChain remanence", lambda: BallChain(remanence=1e300), r"BallChain.remanence must be in \(0, 2.5\] T"),
        ("BallChain density", lambda: BallChain(density=1e9), r"BallChain.density must be in \(0, 25000\] kg/m\^3"),
        ("ChainStatics a million balls", lambda: ChainStatics(BallChain(n_balls=10**6)),
         "ChainStatics solves chains of up to 200 balls"),
        ("sizing tiny force", lambda: sizing.SizingInputs(desired_force=1e-300),
         r"SizingInputs.desired_force must be in \[1e-06, 1000\] \(SI\)"),
        ("CylinderMagnet huge", lambda: CylinderMagnet(diameter=1e200), r"CylinderMagnet.diameter must be in \[0.1, 10000\] mm"),
        ("reconfiguration runs", lambda: reconfiguration.run(runs=1.5), "runs must be an integer in 1..10000, got 1.5"),
        ("Executor jobqueue", lambda: Executor(jobqueue={}), r"--jobqueue must be a string \(or None\), got \{\}"),
        ("reconfiguration t_max", lambda: reconfiguration.run(t_max=-1.0), "t_max must be a finite number > 0"),
        ("reconfiguration tolerance", lambda: reconfiguration.run(tolerance_deg=float("nan")), "tolerance_deg must be"),
        ("reconfiguration wheel map", lambda: reconfiguration.run(wheel_map="x"), "wheel_map must be one of"),
        ("reconfiguration seed", lambda: reconfiguration.run(seed=-1), "seed must be an integer in 0.."),
        ("ablation time step 0", lambda: ablation.run(dt_max_s=0.0), r"dt_max_s = 0.0 is outside the model's range: 0.05..10 s"),
        ("alignment balls 16.0", lambda: alignment.run(max_balls=16.0), "--max-balls must be an integer in 1..64, got 16.0"),
        ("clinical vein", lambda: clinical.run(veins=("SVC",)), "veins must be some of LSPV, LIPV, RSPV, RIPV"),
        ("teleop operator", lambda: teleop.run(targets=1, operator="x"), "teleop.run operator must be an OperatorParams"),
        ("teleop heart", lambda: teleop.run(targets=1, heart="x"), "teleop.run heart must be an atrium"),
        ("teleop live duration", lambda: teleop.check_live_inputs("world", "one", None, 1e300, 1.0),
         r"--duration must be in \(0, 3600\] s"),
        ("teleop live rate", lambda: teleop.check_live_inputs("world", "one", None, 1.0, 1e300),
         r"--realtime-rate must be in \[0, 100\]"),
        ("manual hand", lambda: manual_catheter.run(hand="x"), "manual_catheter.run hand must be a HandParams"),
        ("manual catheter", lambda: manual_catheter.run(catheter="x"), "manual_catheter.run catheter must be"),
        ("procedure window of one", lambda: procedure.run(targets=1, window_gf=(10.0,)),
         r"window_gf must be \(low, high\) in gf, got \(10.0,\)"),
        ("procedure window reversed", lambda: procedure.run(targets=1, window_gf=(40, 10)),
         "the force window 40..10 gf must have 0 < low <= high <= 200 gf"),
        ("run_simulation by name", lambda: run_simulation(scenario="free_space_uniform_90deg"),
         "run_simulation scenario must be a ChainScenario"),
        ("MakeStation meshcat", lambda: MakeStation(load_scenario("free_space_uniform_90deg"), meshcat="x"),
         "MakeStation meshcat must be a pydrake Meshcat or None"),
        ("scenarios file None", lambda: load_scenario("x", filename=None), "the scenarios file must be a file name"),
        ("planner omega_max", lambda: planner.run(omega_max=-1.0), r"omega_max must be a finite number > 0 \[rad/s\]"),
        ("planner feeder_speed", lambda: planner.run(feeder_speed=0.0), "feeder_speed must be a finite number > 0"),
        ("Sleeve modulus", lambda: Sleeve(youngs_modulus=1e300), r"Sleeve.youngs_modulus must be in \(0, 10000\] MPa"),
        ("braid wires", lambda: SteerableCatheter(braid_wires=10**9).validate(),
         "SteerableCatheter.braid_wires must be an even count in 0..256"),
        ("workspace 10000 balls", lambda: workspace.run(balls=(10000,)), r"chains of up to 200 balls \(.*\), got 10000"),
    ]


CALLS = _calls()


@pytest.mark.parametrize("label, call, expected", CALLS, ids=[c[0] for c in CALLS])
def test_a_bad_api_argument_is_a_user_input_error_naming_it(label, call, expected):
    with pytest.raises(UserInputError) as err:
        call()
    message = str(err.value)
    assert expected in message or re.search(expected, message), message
    assert "\n" not in message and len(message) < 400


def test_the_checks_do_not_refuse_what_was_accepted():
    """Lists, tuples and numpy arrays of the right shape, numpy scalars and ints still work."""
    from ballchain.drake_models import field_sources as fs
    from ballchain.drake_models.params import CylinderMagnet
    from ballchain.systems.actuation_station import StationOptions

    B = fs.UniformField((0, np.float32(0.023), 0)).B_W
    assert B.dtype == float and B.tolist() == pytest.approx([0.0, 0.023, 0.0])
    fs.MagnetSource(CylinderMagnet(), np.array([0, 0, 0.2]), np.eye(3).tolist())
    StationOptions(field_points_W=np.zeros(6), seed=np.int64(3), with_feeder=np.bool_(False))
    solver = _solver()
    free = solver.solve(_field())
    held = solver.solve(_field(), free, tip_target=tuple(free.tip_position))
    assert free.converged and held.converged
    np.testing.assert_allclose(held.tip_position, free.tip_position, atol=1e-9)


# ------------------------------------------------------------------ running a station

@pytest.fixture(scope="module")
def free_station():
    import ballchain as bc

    return bc.MakeStation(bc.load_scenario("free_space_uniform_90deg", "{engine: statics}"))


@pytest.mark.parametrize("kwargs, expected", [
    (dict(duration=-1.0), "run_station duration must be a finite number > 0, got -1.0"),
    (dict(duration=float("nan")), "run_station duration must be a finite number > 0, got nan"),
    (dict(duration=float("inf")), "run_station duration must be a finite number > 0, got inf"),
    (dict(duration="1"), "run_station duration must be a finite number > 0, got '1'"),
    (dict(duration=True), "run_station duration must be a finite number > 0, got True"),
    (dict(duration=0.01, progress=True), "run_station progress must be a label (str) or None, got True"),
    (dict(duration=0.01, progress_step=0.0), "run_station progress_step must be a finite number > 0, got 0.0"),
    (dict(duration=0.01, realtime_rate=-1), "run_station realtime_rate must be a finite number >= 0, got -1"),
    (dict(duration=0.01, html="replay.html"), "run_station html needs a station built with a Meshcat"),
])
def test_run_station_refuses_bad_arguments_before_the_run(free_station, kwargs, expected):
    """Drake's Simulator ends the process (a failed assertion raised as SystemExit) on a time
    before the context's, and waits forever on an infinite one: the arguments are checked first."""
    import ballchain as bc

    with pytest.raises(UserInputError) as err:
        bc.run_station(free_station, **kwargs)
    assert str(err.value).startswith(expected)


def test_the_watchdog_names_its_arguments(free_station):
    import ballchain as bc

    with pytest.raises(UserInputError, match="ChainMonitor wall_check_every must be an integer >= 1, got 0"):
        bc.ChainMonitor(free_station, wall_check_every=0)
    with pytest.raises(UserInputError, match=r"ChainMonitor cd must be a Station \(MakeStation\(scenario\)\)"):
        bc.ChainMonitor(None)


def test_run_station_and_advance_to_name_what_they_need(free_station):
    import ballchain as bc
    from ballchain.systems.chain_simulation import StationRunner

    scenario = bc.load_scenario("free_space_uniform_90deg")
    with pytest.raises(UserInputError, match=r"run_station's cd must be a Station \(MakeStation\(scenario\)\), "
                                             "got ChainScenario"):
        bc.run_station(scenario, duration=0.01)
    runner = StationRunner(free_station)
    assert runner.advance_to(np.float64(0.01)) is None
    with pytest.raises(UserInputError, match="advance_to t must not be before the simulation's time 0.01 s, got 0"):
        runner.advance_to(0.0)
    for t in (float("nan"), -1.0, "1"):
        with pytest.raises(UserInputError, match="advance_to t must be a finite number >= 0"):
            runner.advance_to(t)
    assert runner.advance_to(0.02) is None and runner.context.get_time() == pytest.approx(0.02)
    with pytest.raises(UserInputError, match=r"duration must be a number in \(0, 3600\] s, got '1'"):
        bc.run_simulation(scenario=scenario, duration="1")


def test_overrides_given_as_a_mapping_take_numpy_values_and_refuse_other_objects():
    """``load_scenario``/``apply_overrides`` from Python: numpy scalars and arrays are the numbers
    and lists they hold (before, a mapping went through its ``str``: ``np.float64(0.5)`` was
    refused as text and an array was "not valid YAML"); objects that are not plain data, text
    for ``apply_overrides``' mapping and keys that are not text are named."""
    import ballchain as bc

    scenario = bc.load_scenario("free_space_uniform_90deg", {"duration": np.float64(0.5), "n_balls": np.int64(4)})
    assert (scenario.duration, scenario.n_balls) == (0.5, 4) and type(scenario.n_balls) is int
    station = bc.load_scenario("teleop_right_unit")
    moved = bc.apply_overrides(station, {"units": [{"distance": np.float32(0.25)}], "sleeve": np.bool_(True)})
    assert moved.units[0].distance == pytest.approx(0.25) and moved.sleeve is True
    assert moved.units[0].name == station.units[0].name  # the entry updated, not replaced
    assert moved.units[0].anchor == station.units[0].anchor
    for call, expected in (
            (lambda: bc.load_scenario("free_space_uniform_90deg", {"description": object()}),
             "--set: description must be plain data (numbers, text, true/false, lists, mappings), got object"),
            (lambda: bc.load_scenario("free_space_uniform_90deg", 5),
             "--set (overrides) must be inline YAML text or a mapping of scenario fields, got int"),
            (lambda: bc.apply_overrides(scenario, "{n_balls: 4}"),
             "apply_overrides data must be a mapping of scenario fields (parse_overrides' answer), got str"),
            (lambda: bc.apply_overrides(scenario, {1: 4}), "--set: field names must be text, got 1"),
            (lambda: bc.apply_overrides(scenario, {"n_balls": np.float64(4.5)}), "--set: n_balls must be an integer, got 4.5"),
            (lambda: bc.apply_overrides("free_space_uniform_90deg", {}),
             "apply_overrides scenario must be a ChainScenario, got str")):
        with pytest.raises(UserInputError) as err:
            call()
        assert str(err.value) == expected


# ------------------------------------------------------------------ round three: the API's edges

def test_a_run_outcome_pickles_as_plain_data(free_station):
    """``pickle.dumps(run_station(...))`` raised deep inside pydrake (a Diagram cannot be
    pickled): the outcome pickles its numbers and the chain's end state, without the live objects."""
    import copy
    import pickle

    import ballchain as bc

    outcome = bc.run_station(free_station, duration=0.01)
    again = pickle.loads(pickle.dumps(outcome))
    np.testing.assert_array_equal(again.tip_position, outcome.tip_position)
    np.testing.assert_array_equal(again.ball_positions, outcome.ball_positions)
    assert again.ball_positions.shape == (free_station.scenario.n_balls, 3)
    fields = ("sim_time", "wall_time", "cpu_time", "failure", "stopped")
    assert [getattr(again, f) for f in fields] == [getattr(outcome, f) for f in fields]
    watched = ("checks", "max_gap", "max_penetration", "failure", "tolerated_sinkings")
    assert [getattr(again.monitor, f) for f in watched] == [getattr(outcome.monitor, f) for f in watched]
    assert again.context is None and again.simulator is None and again.station is None
    twice = pickle.loads(pickle.dumps(again))  # an unpickled copy pickles too
    np.testing.assert_array_equal(twice.tip_position, outcome.tip_position)
    # The original keeps its live objects, and so does a shallow copy.
    assert outcome.station is free_station and copy.copy(outcome).context is outcome.context


def test_the_api_bounds_a_field_as_the_command_line_does():
    """``UniformField([0, 23, 0])`` (23 mT typed as tesla) ran a 23 T field; the commands refuse
    more than 1000 mT. One bound, ``field_sources.MAX_FIELD_T``, for both."""
    import ballchain as bc

    for call, expected in (
            (lambda: bc.UniformField([0, 23, 0]),
             "UniformField.B_W |B| = 23 T must be at most 1 T (1000 mT): it is in tesla (23 mT is 0.023), "
             "got [0.0, 23.0, 0.0]"),
            (lambda: bc.UniformField(np.full(3, 0.6)), "UniformField.B_W |B| = 1.03923 T must be at most 1 T"),
            (lambda: bc.UniformField.in_plane(23.0, 0.5),
             "UniformField.in_plane magnitude_T must be a number in [-1, 1] T, got 23.0"),
            (lambda: bc.MagnetSource(bc.CylinderMagnet(), [0, 0, 0.2], model="exact", fd_step=1e300),
             "MagnetSource.fd_step must be a number in (0, 0.001] m, got 1e+300"),
            (lambda: bc.CylinderMagnet(remanence=23.0), "CylinderMagnet.remanence must be in (0, 2.5] T, got 23 T"),
            (lambda: bc.UniformField([0, 0.023, 0]).field_and_gradient("origin"),
             "field points p_W must be (k, 3) finite numbers [m], got 'origin'")):
        with pytest.raises(UserInputError) as err:
            call()
        assert str(err.value).startswith(expected), str(err.value)
    import argparse

    from ballchain.commands import alignment as alignment_command
    from ballchain.drake_models.field_sources import MAX_FIELD_T
    from ballchain.experiments import alignment, statics_bench, statics_shape

    assert bc.UniformField([0.0, MAX_FIELD_T, 0.0]).B_W[1] == MAX_FIELD_T  # the bound itself is allowed
    assert statics_shape.MAX_FIELD_MT == statics_bench.FIELD_MT_RANGE[1] == MAX_FIELD_T * 1e3 == 1000.0
    with pytest.raises(UserInputError, match=r"--field-mT must be a number in \(0, 1000\] mT, got 1001"):
        alignment.run(field_mT=1001.0)
    parser = argparse.ArgumentParser()
    alignment_command.add_arguments(parser)
    assert parser.parse_args(["--field-mT", "1000"]).field_mT == 1000.0


def _scenario_with(**changes):
    import dataclasses

    import ballchain as bc

    return dataclasses.replace(bc.load_scenario("free_space_uniform_90deg"), **changes)


@pytest.mark.parametrize("changes, expected", [
    (dict(magnets=[{"shape": "sphere"}]), "scenario: magnets[0] must be a MagnetScenario (a mapping is the YAML's "
                                          "form: MagnetScenario(**fields), or load_scenario's overrides), got dict"),
    (dict(units=[{"name": "right_unit"}]), "scenario: units[0] must be a MagnetUnitConfig"),
    (dict(units=None), "scenario: units must be a list of MagnetUnitConfig, got NoneType None"),
    (dict(magnets={"shape": "sphere"}), "scenario: magnets must be a list of MagnetScenario, got dict"),
    (dict(insertion={"speed": 0.01}), "scenario: insertion must be an InsertionScenario"),
    (dict(plant_config={}), "scenario: plant_config must be a MultibodyPlantConfig"),
    (dict(visualization=None), "scenario: visualization must be a VisualizationConfig, got NoneType None"),
    (dict(sleeve="yes"), "scenario: sleeve must be true or false, got 'yes'"),
    (dict(description=None), "scenario: description must be a string, got None"),
    (dict(uniform_field="north"), "scenario: uniform_field must be a list of finite numbers, got 'north'"),
    (dict(random_seed=1.5), "scenario: random_seed must be an integer, got 1.5"),
])
def test_a_scenario_part_of_the_wrong_kind_is_named_at_make_station(changes, expected):
    """A scenario built in Python with a part of the wrong kind (plain dicts for ``magnets`` or
    ``units``, ``units=None``) ended in an AttributeError or TypeError from the checks or the
    build: ``MakeStation`` (its ``validate``) names the field path first."""
    import ballchain as bc

    with pytest.raises(UserInputError) as err:
        bc.MakeStation(_scenario_with(**changes))
    assert str(err.value).startswith(expected), str(err.value)
    assert "\n" not in str(err.value)


def test_a_scenario_built_with_numpy_values_and_tuples_validates_as_plain_data():
    """Numpy numbers and arrays, tuples: what a script has at hand; stored as the plain numbers
    and lists ``load_scenario`` gives (a numpy ``sheath_aim`` was "truth value of an array is
    ambiguous" before)."""
    import ballchain as bc

    scenario = _scenario_with(n_balls=np.int64(8), duration=np.float32(0.05), uniform_field=np.array([0.0, 0.02, 0.0]),
                              wall_plane=(0.0, 0.0, -0.01, 0.0, 0.0, 1.0), random_seed=np.uint32(3)).validate()
    assert type(scenario.n_balls) is int and scenario.n_balls == 8 and type(scenario.duration) is float
    assert scenario.uniform_field == [0.0, 0.02, 0.0] and scenario.wall_plane == [0.0, 0.0, -0.01, 0.0, 0.0, 1.0]
    assert scenario.random_seed == 3 and type(scenario.random_seed) is int
    heart = bc.load_scenario("heart_left_quasi_static")
    heart.sheath_aim = np.array([0.0, 0.0, 0.01])  # read as the list it holds, then refused as that list is
    with pytest.raises(UserInputError, match="scenario sheath_aim is for a user's atrium"):
        heart.validate()
    with pytest.raises(UserInputError, match=r"MagnetUnitConfig.p_WM must be \[\] or 3 numbers \[m\] .*got 'x'"):
        bc.MagnetUnitConfig(p_WM="x")
    assert bc.MagnetUnitConfig(p_WM=np.array([0.0, -0.2, 0.0])).p_WM == [0.0, -0.2, 0.0]


@pytest.mark.parametrize("overrides, expected", [
    ("{units: [{joystick_source: script}]}",
     "--set units[0].joystick_source: 'script' would be ignored: the stick of unit 'right_unit' is the operator's"),
    ("{units: [{joystick: [{time: 0.0, axes: [1.0, 0.0, 0.0]}]}]}", "--set units[0].joystick: "),
    ("{units: [{teleop_frame: tip}]}",
     "--set units[0].teleop_frame: 'tip' would be ignored: the mapping of unit 'right_unit' is --mapping world's"),
    ("{insertion: {feeder_command: ramp}}", "--set insertion.feeder_command: 'ramp' would be ignored: the operator"),
    ("{insertion: {final: 0.05}}", "--set insertion.final: 0.05 would be ignored"),
])
def test_teleop_refuses_an_override_its_operator_would_replace(overrides, expected):
    """``teleop`` hands each unit's stick and the feeder to its operator: a scripted stick
    (``joystick_source: script``) was replaced without a word and the run exited 0."""
    from ballchain.experiments import teleop

    with pytest.raises(UserInputError) as err:
        teleop.scenario_for("world", overrides=overrides)
    assert str(err.value).startswith(expected), str(err.value)
    # What the hand-over sets anyway is accepted.
    scenario = teleop.scenario_for("world", overrides="{units: [{joystick_source: external, teleop_frame: world}]}")
    assert scenario.units[0].joystick_source == "external"


def test_the_teleop_command_refuses_a_scripted_stick_in_one_line(capsys):
    from ballchain.cli import main

    assert main(["teleop", "--targets", "1", "--no-progress", "--set", "{units: [{joystick_source: script}]}"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "units[0].joystick_source: 'script' would be ignored" in line


def test_the_hooks_of_a_run_are_checked_before_it(free_station):
    """A monitor, ``stop``, ``check`` or ``context`` of the wrong kind failed at the first step
    (pybind11's multi-line "incompatible function arguments", "'str' object is not callable")."""
    import ballchain as bc

    for call, expected in (
            (lambda: bc.run_station(free_station, duration=0.01, stop="at 1 s"),
             "run_station stop must be a function of the root context or None, got str 'at 1 s'"),
            (lambda: bc.run_station(free_station, duration=0.01, check=True), "run_station check must be a function"),
            (lambda: bc.run_station(free_station, duration=0.01, monitor={}),
             "run_station monitor must be a ChainMonitor (ChainMonitor(station)) or None, got dict"),
            (lambda: bc.run_station(free_station, duration=0.01, context={}),
             "run_station context must be a root context of the station's diagram"),
            (lambda: bc.StationRunner(free_station, context=free_station.chain.system.CreateDefaultContext()),
             "StationRunner context must be a root context of the station's diagram"),
            (lambda: bc.StationRunner(free_station, realtime_rate=float("nan")),
             "StationRunner realtime_rate must be a finite number >= 0, got nan"),
            (lambda: bc.run_station(free_station, duration=0.01, html=5), "run_station html must be a file name"),
            (lambda: bc.run_simulation(scenario=free_station.scenario, duration=0.01, html={"file": "x.html"}),
             "run_simulation html must be a file name (str or Path) or None, got {'file': 'x.html'}"),
            (lambda: bc.run_simulation(scenario=free_station.scenario, duration=0.01, progress="yes"),
             "run_simulation progress must be True or False, got 'yes'")):
        with pytest.raises(UserInputError) as err:
            call()
        assert str(err.value).startswith(expected), str(err.value)
        assert "\n" not in str(err.value)
