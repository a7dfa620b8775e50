"""Bad YAML and scenario input: the one loader (infrastructure/safe_yaml.py), the one schema check,
``--set`` list merging, fields that would be ignored, and the bounds of every field of a kind.

CLI cases run in-process (``ballchain.cli.main``) like tests/test_bad_input.py: exit status 2,
one line on stderr naming the field. The time bound is a hang guard (an alias bomb used to hang
for minutes), not a speed claim.
"""

from __future__ import annotations

import math
import time

import pytest

from ballchain.cli import main
from ballchain.infrastructure.errors import MAX_QUOTED, UserInputError

HANG_GUARD_S = 30.0

SIM = ["simulate", "--scenario", "free_space_uniform_90deg"]
WALL = ["simulate", "--scenario", "free_space_wall"]
HEART = ["simulate", "--scenario", "heart_no_field"]
TELEOP = ["simulate", "--scenario", "teleop_right_unit"]


def _bomb(levels: int = 9) -> str:
    """The "billion laughs": each level is nine aliases of the level before (9**levels values)."""
    parts = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    for k in range(1, levels):
        parts.append(f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 9) + "]")
    return "{" + ", ".join(parts) + "}"


LONG_VALUE = "{n_balls: [&a [" + ", ".join(["1234567"] * 100) + "]" + ", *a" * 40 + "]}"

# (case id, argv, text the one-line message must contain)
CASES = [
    # the loader: bounded, no duplicate keys, no tags, YAML 1.2 numbers
    ("alias-bomb", SIM + ["--set", _bomb()], "expands to more than"),
    ("alias-recursive", SIM + ["--set", "{units: &u [*u]}"], "refers to its own anchor"),
    ("too-large", SIM + ["--set", "{description: '" + "x" * 1_100_000 + "'}"], "more than 1000000"),
    ("duplicate-key", SIM + ["--set", "{n_balls: 4, n_balls: 5}"], "duplicate key 'n_balls'"),
    ("duplicate-nested-key", SIM + ["--set", "{insertion: {speed: 0.01, speed: 0.02}}"], "duplicate key 'speed'"),
    ("python-tag", SIM + ["--set", "!!python/object/apply:os.system ['true']"], "tag"),
    ("exponent-is-a-float", SIM + ["--set", "{n_balls: 2.3e1}"], "n_balls must be an integer, got 23.0"),
    ("exponent-in-range-check", SIM + ["--set", "{time_step: 1e-9}"], "time_step must be 0"),
    # one schema check: the value's type, nested paths, pydrake structs' vectors
    ("string-for-number", SIM + ["--set", "{duration: '2.3e1'}"], "duration must be a finite number"),
    ("joystick-mode", TELEOP + ["--set", "{units: [{joystick: [{time: 0.1, mode: 2}]}]}"], "joystick[0].mode"),
    ("unit-shape", TELEOP + ["--set", "{units: [{shape: cube}]}"], "units[0].shape"),
    ("magnet-model", ["simulate", "--scenario", "heart_left_quasi_static", "--set", "{magnets: [{model: fem}]}"],
     "magnets[0].model"),
    ("rgba-text", SIM + ["--set", "{visualization: {default_illustration_color: {rgba: [red, 0, 0, 1]}}}"],
     "rgba[0]"),
    # fields that would be ignored
    ("puncture-procedural", HEART + ["--set", "{puncture: [0.02, 0, 0]}"], "puncture"),
    ("sheath-aim-procedural", HEART + ["--set", "{sheath_aim: [0.0, 0.0, 0.01]}"], "sheath_aim"),
    ("atrium-file-free-space", SIM + ["--set", "{atrium_file: la.stl, puncture: [0.02, 0, 0]}"], "atrium_file"),
    ("heart-scale-free-space", SIM + ["--set", "{heart_scale: 2.0}"], "heart_scale"),
    ("heart-scale-user-atrium", HEART + ["--set", "{atrium_file: la.stl, puncture: [0.02, 0, 0], heart_scale: 2.0}"],
     "heart_scale"),
    ("wall-plane-in-heart", HEART + ["--set", "{wall_plane: [0, 0.01, 0, 0, -1, 0]}"], "wall_plane"),
    ("damping-in-dynamics", ["simulate", "--scenario", "heart_right_dynamics", "--set", "{angular_damping: 1.0e-3}"],
     "angular_damping"),
    ("magnet-p-WM-and-distance", ["simulate", "--scenario", "heart_left_quasi_static", "--set",
                                  "{magnets: [{p_WM: [0.2, 0, 0], distance_from_puncture: 0.3}]}"],
     "magnets[0].distance_from_puncture"),
    ("unit-p-WM-and-anchor", TELEOP + ["--set", "{units: [{p_WM: [0.1, 0.1, 0]}]}"], "units[0].anchor"),
    ("pin-stiffness-without-point", SIM + ["--set", "{pin: {stiffness: 100.0}}"], "pin.stiffness"),
    # bounds: every position and distance within MAX_DISTANCE
    ("wall-12-m", WALL + ["--set", "{wall_plane: [0, 12.0, 0, 0, -1, 0]}"], "wall_plane point"),
    ("wall-normal-zero", WALL + ["--set", "{wall_plane: [0, 0.012, 0, 0, 0, 0]}"], "wall_plane normal"),
    ("insertion-final-5-m", SIM + ["--set", "{insertion: {final: 5.0}}"], "insertion.final"),
    ("break-gap-5-m", SIM + ["--set", "{break_gap: 5.0}"], "break_gap"),
    ("penetration-allowance-1-m", SIM + ["--set", "{plant_config: {penetration_allowance: 1.0}}"],
     "plant_config.penetration_allowance"),
    # bounds: every periodic update counts against MAX_STEPS
    ("statics-period-1e-9", SIM + ["--set", "{engine: statics, statics_period: 1e-9}"], "statics_period"),
    ("check-period-1e-9", SIM + ["--set", "{check_period: 1e-9}"], "check_period"),
    ("check-period-1e300", SIM + ["--set", "{check_period: 1e300}"], "check_period must be at most 1 s"),
    ("damping-1e300", SIM + ["--set", "{translational_damping: 1e300}"], "translational_damping must be in 0..1000"),
    ("publish-period-1e-9", SIM + ["--set", "{visualization: {publish_period: 1e-9}}"], "publish_period"),
    ("max-step-size-1e-12", SIM + ["--set", "{simulator_config: {max_step_size: 1e-12}}"], "max_step_size"),
    ("duration-flag-statics", SIM + ["--set", "{engine: statics, statics_period: 1e-5}", "--duration", "3000"],
     "statics_period"),
    # bounds: contact parameters
    ("stiffness-1e30", SIM + ["--set", "{contact: {ball_point_stiffness: 1e30}}"], "contact.ball_point_stiffness"),
    ("stiffness-soft", SIM + ["--set", "{contact: {ball_point_stiffness: 10}}"], "contact.ball_point_stiffness"),
    ("relaxation-time-100", SIM + ["--set", "{contact: {relaxation_time: 100}}"], "contact.relaxation_time"),
    ("friction-5", SIM + ["--set", "{contact: {friction: 5}}"], "contact.friction"),
    ("wall-modulus-1e15", SIM + ["--set", "{contact: {wall_hydroelastic_modulus: 1e15}}"],
     "contact.wall_hydroelastic_modulus"),
    ("margin-1-m", SIM + ["--set", "{contact: {hydroelastic_margin: 1.0}}"], "contact.hydroelastic_margin"),
    ("resolution-hint-1e-9", SIM + ["--set", "{contact: {ball_resolution_hint: 1e-9}}"], "contact.ball_resolution_hint"),
    ("slide-kp-1e30", SIM + ["--set", "{insertion: {slide_gains: [1e30, 20.0]}}"], "insertion.slide_gains"),
]


@pytest.mark.parametrize("argv,field", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_yaml_exits_2_with_one_line_naming_the_field(capsys, argv, field):
    start = time.monotonic()
    code = main(argv)
    elapsed = time.monotonic() - start
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, err[:2000]
    assert len(lines) == 1, err[:2000]
    assert field in lines[0], lines[0]
    assert len(lines[0]) < 600, lines[0][:600]  # user values are quoted cut short
    assert elapsed < HANG_GUARD_S


def test_a_long_expanded_value_is_cut_in_the_message(capsys):
    """4100 numbers from 41 uses of one anchor: under the expansion bound, so the schema check
    refuses the value, quoting at most MAX_QUOTED characters of it."""
    assert main(SIM + ["--set", LONG_VALUE]) == 2
    line = capsys.readouterr().err.strip()
    assert "n_balls must be an integer" in line and "characters)" in line
    quoted = line.split("got ", 1)[1]
    assert len(quoted.split(" (")[0]) <= MAX_QUOTED


def test_the_loader_reads_yaml_1_2_numbers_and_refuses_bombs_in_files(tmp_path):
    from ballchain.infrastructure.safe_yaml import load_yaml
    from ballchain.systems.chain_scenario import check_value, load_scenario

    data = load_yaml("{a: 2.3e1, b: 1e-9, c: .5, d: +1., e: 12, f: '2.3e1'}", "test")
    assert data == {"a": 23.0, "b": 1e-9, "c": 0.5, "d": 1.0, "e": 12, "f": "2.3e1"}
    assert [type(data[k]) for k in "abcdef"] == [float, float, float, float, int, str]
    check_value(data["a"], float, "field_mT", "sweep spec s.yaml")  # the sweep's check reads it too
    assert load_scenario("free_space_uniform_90deg", "{duration: 2.3e1}").duration == 23.0
    bomb = tmp_path / "bomb.scenarios.yaml"
    bomb.write_text(f"_parts: {_bomb()}\nx: {{n_balls: 4}}\n")
    with pytest.raises(UserInputError, match="bomb.scenarios.yaml.*expands to more than"):
        load_scenario("x", filename=bomb)
    dup = tmp_path / "dup.scenarios.yaml"
    dup.write_text("x: {n_balls: 4}\nx: {n_balls: 5}\n")
    with pytest.raises(UserInputError, match="duplicate key 'x'"):
        load_scenario("x", filename=dup)


def test_the_loader_reads_yaml_1_2_integers_booleans_and_dates():
    """YAML 1.1's readings that change a number silently (octal ``010``, base-60 ``1:30``,
    ``1_6``) or make a boolean or a date of text are YAML 1.2's: decimal, or text that the
    schemas refuse where they want a number."""
    from ballchain.infrastructure.safe_yaml import load_yaml
    from ballchain.sweep import load_spec
    from ballchain.systems.chain_scenario import load_scenario

    data = load_yaml("{a: 010, b: 1:30, c: 0x10, d: 0o17, e: 1_6, f: on, g: yes, h: 2026-12-01, i: -.Inf, "
                     "j: True, k: 0b11, l: -012, m: FALSE, n: Off}", "test")
    assert data == {"a": 10, "b": "1:30", "c": 16, "d": 15, "e": "1_6", "f": "on", "g": "yes", "h": "2026-12-01",
                    "i": float("-inf"), "j": True, "k": "0b11", "l": -12, "m": False, "n": "Off"}
    assert math.isnan(load_yaml("x: .NaN", "test")["x"])
    assert load_scenario("free_space_uniform_90deg", "{n_balls: 010}").n_balls == 10
    assert load_scenario("free_space_uniform_90deg", "{description: 2026-12-01}").description == "2026-12-01"
    for text, message in (("{duration: 1:30}", "--set: duration must be a finite number, got '1:30'"),
                          ("{sleeve: on}", "--set: sleeve must be true or false, got 'on'"),
                          ("{n_balls: 1_6}", "--set: n_balls must be an integer, got '1_6'")):
        with pytest.raises(UserInputError) as err:
            load_scenario("free_space_uniform_90deg", text)
        assert str(err.value) == message
    spec = load_spec("s.yaml", text="experiment: statics\ngrid: {n_balls: [010]}\nseeds: [007, 010]")
    assert spec.seeds == [7, 10] and spec.points[0].n_balls == 10


def test_scenarios_and_sweep_specs_share_one_type_check():
    from ballchain.sweep import load_spec
    from ballchain.systems.chain_scenario import parse_overrides

    with pytest.raises(UserInputError) as scenario:
        parse_overrides("{n_balls: 4.5}")
    with pytest.raises(UserInputError) as spec:
        load_spec("s.yaml", text="experiment: statics\ngrid: {n_balls: [4.5]}")
    assert str(scenario.value) == "--set: n_balls must be an integer, got 4.5"
    assert str(spec.value) == "sweep spec 's.yaml': grid.n_balls[0] must be an integer, got 4.5"


def test_set_merges_a_unit_entry_without_a_name_by_position():
    """The audit's case: a partial unit entry used to reset the unit's placement and joystick."""
    from ballchain.systems.chain_scenario import load_scenario

    right = load_scenario("teleop_two_units").units[0]
    s = load_scenario("teleop_two_units", "{units: [{teleop_omega_max: 1.0}]}")
    assert len(s.units) == 1 and s.units[0].teleop_omega_max == 1.0
    for name in ("name", "anchor", "distance", "direction_W", "joystick", "sensor_noise"):
        assert getattr(s.units[0], name) == getattr(right, name), name


def test_set_merges_units_by_name():
    from ballchain.systems.chain_scenario import load_scenario

    right, left = load_scenario("teleop_two_units").units
    # By name: the left unit first, keeping its own placement; a new name starts from the defaults.
    s = load_scenario("teleop_two_units", "{units: [{name: left_unit, slip: 0.1}, {name: right_unit}, "
                                          "{name: third, p_WM: [0.0, 0.0, 0.2]}]}")
    assert [u.name for u in s.units] == ["left_unit", "right_unit", "third"]
    assert (s.units[0].anchor, s.units[0].direction_W, s.units[0].slip) == (left.anchor, left.direction_W, 0.1)
    assert s.units[1] == right and s.units[2].joystick == []


def test_set_merges_joystick_keys_and_magnets_by_position():
    from ballchain.systems.chain_scenario import load_scenario

    right = load_scenario("teleop_right_unit").units[0]
    # A unit's joystick keys by position: the first key keeps its time, the list is the one given.
    s = load_scenario("teleop_right_unit", "{units: [{joystick: [{axes: [1.0, 0.0, 0.0]}]}]}")
    assert [(k.time, k.axes) for k in s.units[0].joystick] == [(right.joystick[0].time, [1.0, 0.0, 0.0])]
    assert load_scenario("teleop_two_units", "{units: []}").units == []
    # Magnets by position; a mapping field keeps what it does not name.
    magnet = load_scenario("heart_left_quasi_static").magnets[0]
    s = load_scenario("heart_left_quasi_static", "{magnets: [{model: exact}], insertion: {speed: 0.02}}")
    assert (s.magnets[0].model, s.magnets[0].direction_W, s.magnets[0].distance_from_puncture) == (
        "exact", magnet.direction_W, magnet.distance_from_puncture)
    assert s.insertion.final == load_scenario("heart_left_quasi_static").insertion.final


def test_bounds_accept_the_documented_ranges():
    """The bounds refuse only what is outside them: the edges are accepted."""
    from ballchain.systems.chain_scenario import CONTACT_BOUNDS, load_scenario

    for name, (lo, hi, _, _) in CONTACT_BOUNDS.items():
        for value in (lo, hi):
            s = load_scenario("free_space_wall", f"{{contact: {{{name}: {value!r}}}}}")
            assert getattr(s.contact, name) == value
    s = load_scenario("free_space_wall", "{wall_plane: [0.0, 1.0, 0.0, 0.0, -1.0, 0.0]}")
    assert s.wall_plane[1] == 1.0


# ----------------------------------------------------------------------------------- nesting depth
# libyaml's composer recurses in C: about 25,000 nested lists (a 50 kB value) ended the process
# with SIGSEGV, no message. Run in a child process, so that a crash is a negative return code
# here and not the end of the test session.

_RUN_SET = ("import sys; from ballchain.cli import main; "
            "sys.exit(main(sys.argv[1:-1] + ['--set', open(sys.argv[-1], encoding='utf-8').read()]))")


def _deep(levels: int) -> str:
    """A flow value nested ``levels`` lists deep: [[[...[1]...]]] (2 bytes a level)."""
    return "[" * levels + "1" + "]" * levels


def _child(argv: list[str], cwd) -> tuple[int, list[str]]:
    import subprocess
    import sys

    done = subprocess.run([sys.executable, *argv], cwd=cwd, capture_output=True, text=True, timeout=600)
    return done.returncode, [line for line in done.stderr.splitlines() if line.strip()]


@pytest.mark.parametrize("levels", [25_000, pytest.param(200_000, marks=pytest.mark.slow)])
@pytest.mark.parametrize("where", ["--set", "anatomy file", "sweep spec"])
def test_a_deeply_nested_value_is_one_line_not_a_crash(tmp_path, where, levels):
    """The value is read in a child process (``--set`` from a file: one argument may not exceed
    128 kB on Linux, and 200,000 levels are 400 kB); exit status 2 and one line naming the file
    (or --set) and the limit, instead of SIGSEGV."""
    from ballchain.infrastructure.safe_yaml import MAX_DEPTH

    if where == "--set":
        (tmp_path / "value.yaml").write_text(f"{{n_balls: {_deep(levels)}}}")
        code, lines = _child(["-c", _RUN_SET, *SIM, "value.yaml"], tmp_path)
        named = "--set"
    elif where == "anatomy file":
        from anatomy_helpers import lumen_anatomy

        path = lumen_anatomy(tmp_path, magnets=_deep(levels))
        code, lines = _child(["-m", "ballchain", "plan", "--anatomy", str(path)], tmp_path)
        named = "anatomy file"
    else:
        (tmp_path / "deep_spec.yaml").write_text(f"experiment: statics\ngrid: {{n_balls: {_deep(levels)}}}\n")
        code, lines = _child(["-m", "ballchain", "sweep", "deep_spec.yaml", "--out", "out"], tmp_path)
        named = "sweep spec 'deep_spec.yaml'"
    assert code == 2, (code, lines[-3:])
    assert len(lines) == 1, lines
    assert named in lines[0] and f"more than {MAX_DEPTH} deep" in lines[0], lines[0]


def test_the_depth_limit_counts_lists_mappings_and_aliases():
    """MAX_DEPTH levels are read, one more is refused: in flow and block style, and through an
    alias, whose anchor's depth adds to where it is used."""
    from ballchain.infrastructure.safe_yaml import MAX_DEPTH, load_yaml

    assert load_yaml(_deep(MAX_DEPTH), "t") is not None
    assert load_yaml("- " * MAX_DEPTH + "x", "t") is not None
    for text in (_deep(MAX_DEPTH + 1), "{a: " * (MAX_DEPTH + 1) + "1" + "}" * (MAX_DEPTH + 1),
                 "- " * (MAX_DEPTH + 1) + "x",
                 "a:\n" + "".join(" " * (k + 1) + "a:\n" for k in range(MAX_DEPTH)),
                 # 1 (the top mapping) + 60 + 41 (the anchor's) levels
                 f"a: &a {_deep(40)}\nb: {'[' * 60}*a{']' * 60}\n"):
        with pytest.raises(UserInputError, match=f"nests mappings and lists more than {MAX_DEPTH} deep"):
            load_yaml(text, "t")
    assert load_yaml(f"a: &a {_deep(40)}\nb: {'[' * 59}*a{']' * 59}\n", "t")["b"] is not None


def test_the_shipped_documents_are_far_from_the_depth_limit():
    """The limit leaves room: the deepest shipped document (the scenarios) nests 7 levels."""
    from pathlib import Path

    import yaml

    import ballchain
    from ballchain import drake_models
    from ballchain.infrastructure.safe_yaml import MAX_DEPTH

    shipped = [*Path(drake_models.__file__).parent.rglob("*.yaml"), *Path(ballchain.__file__).parent.rglob("*.yaml")]
    assert len(shipped) >= 5, shipped
    deepest = 0
    for path in shipped:
        depth = 0
        for event in yaml.parse(path.read_text(encoding="utf-8"), Loader=yaml.SafeLoader):
            depth += isinstance(event, yaml.CollectionStartEvent) - isinstance(event, yaml.CollectionEndEvent)
            deepest = max(deepest, depth)
    assert 0 < deepest <= MAX_DEPTH // 10


def test_not_valid_yaml_quotes_nothing_of_the_text():
    """A file that is not YAML (a key file, an environment dump) is refused naming the line, the
    column and the kind of problem, quoting none of it: nor a tag, nor a character."""
    from ballchain.infrastructure.safe_yaml import load_yaml

    secret = "AKIA_SECRET_TOKEN_123"
    for text in (f"!{secret} x", f"a: !!{secret} x", f"[default]\naws_access_key_id = {secret}\n",
                 f"FOO={secret}\0BAR=1\0", f"a: *{secret}", f'a: "\\q{secret}"', f"a: b: {secret}"):
        with pytest.raises(UserInputError) as err:
            load_yaml(text, "t")
        assert secret not in str(err.value) and "\n" not in str(err.value), str(err.value)
