"""Anatomy files (drake_models/anatomy.py): the schema, every field's refusal naming the field and
the file, the targets CSV's variants, the 1 mm rule, the puncture's snapping, the default magnet,
and the procedural atrium as one anatomy file with the paper's targets."""

import numpy as np
import pytest
from anatomy_helpers import ellipsoid_mesh, lumen_anatomy

from ballchain.cli import main
from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models.anatomy import (DEFAULT_MAGNET_DISTANCE, DEFAULT_TOUCH_RADIUS, MAX_TARGET_GAP,
                                            PROCEDURAL_FILE, load_anatomy, procedural_anatomy_text)
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.heart import HeartParams


def refused(path) -> str:
    with pytest.raises(UserInputError) as err:
        load_anatomy(path)
    message = str(err.value)
    assert "\n" not in message and "anatomy file '" in message and path.name in message, message
    return message


def targets_csv(rows) -> str:
    return "name,x,y,z\n" + "".join(f"{n},{x!r},{y!r},{z!r}\n" for n, (x, y, z) in rows)


# ----------------------------------------------------------------------------------- the procedural atrium


@pytest.fixture(scope="module")
def procedural():
    """The procedural anatomy file, loaded once, and its atrium."""
    anatomy = load_anatomy(PROCEDURAL_FILE)
    return anatomy, anatomy.atrium()


def test_the_procedural_file_holds_the_rings_of_the_procedural_atrium(procedural):
    anatomy, heart = procedural
    rings = np.concatenate([heart.rings["left"].p_HT, heart.rings["right"].p_HT])
    assert anatomy.procedural and anatomy.side == "lumen"
    assert anatomy.target_names == [f"left_{k}" for k in range(1, 21)] + [f"right_{k}" for k in range(1, 19)]
    np.testing.assert_allclose(anatomy.p_WT, rings, rtol=0, atol=1e-9)
    assert anatomy.touch_radius == 0.5 * HeartParams().target_diameter
    # The magnet: the paper's teleoperation unit, 10 cm beyond the right carina on the line from the centre.
    carina = heart.carinas["right"]
    np.testing.assert_allclose(anatomy.magnets[0], carina * (1 + 0.10 / np.linalg.norm(carina)), rtol=0, atol=1e-12)
    # The normals at the targets point into the chamber: a step along them from a target stays inside.
    assert np.all(heart.contains(anatomy.p_WT + 1e-3 * anatomy.n_W))
    assert not np.any(heart.contains(anatomy.p_WT - 4e-3 * anatomy.n_W))  # beyond the 2.5 mm wall


def test_the_shipped_procedural_files_are_the_generator_s_output():
    yaml_text, csv_text = procedural_anatomy_text()
    assert PROCEDURAL_FILE.read_text() == yaml_text
    assert PROCEDURAL_FILE.with_suffix(".csv").read_text() == csv_text


def test_the_planner_s_stand_on_the_procedural_file_is_the_paper_task_s_bit_for_bit(procedural, heart):
    from ballchain.experiments import planner

    (anatomy, _), d = procedural, 3.175e-3
    for task in ("left", "right"):
        paper = planner.teleop_stand(heart, task, d)
        _, _, chosen = planner.anatomy_targets(anatomy, task)
        stand = planner.anatomy_stand(anatomy, chosen, d)
        assert list(stand.targets) == list(paper.targets)
        for name, (centre, axis) in paper.targets.items():
            assert np.array_equal(stand.targets[name][0], centre) and np.array_equal(stand.targets[name][1], axis)
        assert np.array_equal(stand.magnets["1"], paper.magnets["1"]) and np.array_equal(stand.R_HS, paper.R_HS)


# ----------------------------------------------------------------------------------- a user's lumen anatomy


def test_a_lumen_anatomy_in_millimetres_loads_in_metres(tmp_path):
    anatomy = load_anatomy(lumen_anatomy(tmp_path))
    V, _ = ellipsoid_mesh()
    assert anatomy.side == "lumen" and not anatomy.procedural and anatomy.target_names == ["L1", "L2", "L3", "L4"]
    np.testing.assert_allclose(np.ptp(anatomy.surface.V, axis=0), np.ptp(V, axis=0) * 1e-3, rtol=1e-6)
    np.testing.assert_allclose(anatomy.gaps, 0.0, atol=1e-9)  # the targets are mesh vertices
    assert anatomy.touch_radius == DEFAULT_TOUCH_RADIUS
    # The puncture is snapped onto a vertex; the normals point into the chamber (towards the chain).
    assert np.min(np.linalg.norm(anatomy.surface.V - anatomy.puncture, axis=1)) == 0.0
    inside = mt.winding_numbers(anatomy.p_WT + 1e-3 * anatomy.n_W, anatomy.surface.V, anatomy.surface.F)
    np.testing.assert_allclose(inside, 1.0, atol=1e-6)
    atrium = anatomy.atrium()
    assert list(atrium.rings) == ["anatomy"] and atrium.rings["anatomy"].names == anatomy.target_names


def test_the_transform_moves_the_mesh_targets_sheath_and_magnets_together(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    plain = load_anatomy(lumen_anatomy(tmp_path / "a", magnets="[[0, 0, 90]]"))
    moved = load_anatomy(lumen_anatomy(tmp_path / "b", magnets="[[0, 0, 90]]",
                                       transform="{translation: [10, -5, 3], rpy_deg: [0, 0, 90]}"))
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    t = np.array([10e-3, -5e-3, 3e-3])
    np.testing.assert_allclose(moved.surface.V, plain.surface.V @ R.T + t, atol=1e-12)
    np.testing.assert_allclose(moved.p_WT, plain.p_WT @ R.T + t, atol=1e-12)
    np.testing.assert_allclose(moved.n_W, plain.n_W @ R.T, atol=1e-9)
    np.testing.assert_allclose(moved.puncture, R @ plain.puncture + t, atol=1e-12)
    np.testing.assert_allclose(moved.magnets, plain.magnets @ R.T + t, atol=1e-12)
    np.testing.assert_allclose(moved.gaps, plain.gaps, atol=1e-12)


# ----------------------------------------------------------------------------------- targets: CSV variants

VERTICES = [[10.0, -4.0, -21.0], [26.0, -2.5, 0.0], [10.5, -3.0, 21.5]]  # replaced by the nearest mesh vertices


def _vertices():
    V, _ = ellipsoid_mesh()
    return [V[int(np.argmin(np.linalg.norm(V - p, axis=1)))].tolist() for p in VERTICES]


@pytest.mark.parametrize("style", ["comma_header", "semicolon_bare", "whitespace_names_first", "names_last",
                                   "comments_bom", "header_reordered"])
def test_the_targets_csv_variants_read_the_same_points(tmp_path, style):
    P = _vertices()
    f = lambda v: repr(v)  # noqa: E731
    text = {
        "comma_header": "x,y,z\n" + "".join(f"{f(x)},{f(y)},{f(z)}\n" for x, y, z in P),
        "semicolon_bare": "".join(f"{f(x)}; {f(y)}; {f(z)}\n" for x, y, z in P),
        "whitespace_names_first": "".join(f"T{k + 1}  {f(x)}\t{f(y)} {f(z)}\n" for k, (x, y, z) in enumerate(P)),
        "names_last": "".join(f"{f(x)},{f(y)},{f(z)},T{k + 1}\n" for k, (x, y, z) in enumerate(P)),
        "comments_bom": "\ufeff# exported targets\n\nname;x;y;z\n" + "".join(
            f"T{k + 1};{f(x)};{f(y)};{f(z)}\n\n" for k, (x, y, z) in enumerate(P)),
        "header_reordered": "Z, Label, X, Y\n" + "".join(
            f"{f(z)}, T{k + 1}, {f(x)}, {f(y)}\n" for k, (x, y, z) in enumerate(P)),
    }[style]
    anatomy = load_anatomy(lumen_anatomy(tmp_path, csv_text=text))
    np.testing.assert_allclose(anatomy.p_WT, np.array(P) * 1e-3, rtol=0, atol=1e-15)
    named = style not in ("comma_header", "semicolon_bare")
    assert anatomy.target_names == ([f"T{k}" for k in (1, 2, 3)] if named else [f"target_{k}" for k in (1, 2, 3)])


def test_inline_targets_with_and_without_names(tmp_path):
    (a, b, c) = _vertices()
    inline = f"[{a}, {{name: ridge, position: {b}}}, {c}]"
    anatomy = load_anatomy(lumen_anatomy(tmp_path, targets=inline))
    assert anatomy.target_names == ["target_1", "ridge", "target_3"]
    np.testing.assert_allclose(anatomy.p_WT, np.array([a, b, c]) * 1e-3, rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------------- the 1 mm rule


def test_a_target_more_than_1_mm_off_the_surface_is_refused_naming_its_row_and_distance(tmp_path):
    V, F = ellipsoid_mesh()
    N = mt.vertex_normals(V, F)
    k = int(np.argmax(V[:, 0]))
    rows = [("near", (V[k] - 0.8 * N[k]).tolist()), ("far", (V[k + 1] - 1.3 * N[k + 1]).tolist())]
    distance = mt.SurfaceDistance(V, F)(np.array([rows[0][1], rows[1][1]]))  # [mm]: the mesh is in mm
    assert distance[0] < MAX_TARGET_GAP * 1e3 < distance[1]
    message = refused(lumen_anatomy(tmp_path, csv_text=targets_csv(rows)))
    assert "targets 'targets.csv' row 3 (far)" in message and f"{distance[1]:.2f} mm from the surface" in message
    anatomy = load_anatomy(lumen_anatomy(tmp_path, csv_text=targets_csv(rows[:1])))
    np.testing.assert_allclose(anatomy.gaps, distance[:1] * 1e-3, rtol=0, atol=1e-9)  # the STL stores float32


# ----------------------------------------------------------------------------------- the sheath's snapping


def test_a_puncture_within_5_mm_is_snapped_onto_the_nearest_vertex_and_one_farther_refused(tmp_path):
    V, F = ellipsoid_mesh()
    N = mt.vertex_normals(V, F)
    k = int(np.argmin(V[:, 0]))  # the septal side
    near = (V[k] - 3.0 * N[k]).tolist()  # 3 mm into the chamber
    anatomy = load_anatomy(lumen_anatomy(tmp_path, sheath=f"{{puncture: {near}, aim: [0, 0, 0]}}"))
    nearest = V[int(np.argmin(np.linalg.norm(V - near, axis=1)))] * 1e-3
    np.testing.assert_array_equal(anatomy.puncture, nearest)
    assert np.linalg.norm(anatomy.puncture - np.array(near) * 1e-3) < 5e-3
    far = (V[k] - 6.0 * N[k]).tolist()
    message = refused(lumen_anatomy(tmp_path, sheath=f"{{puncture: {far}}}"))
    assert "sheath.puncture" in message and "mm from the surface" in message


# ----------------------------------------------------------------------------------- the default magnet


def test_the_default_magnet_stands_10_cm_out_along_the_mean_normal_at_the_targets(tmp_path):
    # The icosphere is symmetric under y -> -y and z -> -z: four mirrored vertices have their
    # centroid and mean normal on the x axis.
    V, _ = ellipsoid_mesh()
    k = int(np.argmin(np.linalg.norm(V - [24.0, 5.0, 6.0], axis=1)))
    x, y, z = V[k].tolist()
    rows = [(f"m{i}", [x, sy * y, sz * z]) for i, (sy, sz) in enumerate([(1, 1), (-1, 1), (1, -1), (-1, -1)])]
    anatomy = load_anatomy(lumen_anatomy(tmp_path, csv_text=targets_csv(rows)))
    assert anatomy.magnets_default
    np.testing.assert_allclose(anatomy.magnets[0], [x * 1e-3 + DEFAULT_MAGNET_DISTANCE, 0.0, 0.0], atol=1e-12)
    # Outside the chamber, behind the wall the targets are on.
    assert mt.winding_numbers(anatomy.magnets, anatomy.surface.V, anatomy.surface.F)[0] < 1e-6


def test_given_magnets_are_read_in_the_file_s_unit(tmp_path):
    anatomy = load_anatomy(lumen_anatomy(tmp_path, magnets="[[0, 0, 120], [-100, 0, 0]]"))
    assert not anatomy.magnets_default
    np.testing.assert_allclose(anatomy.magnets, [[0, 0, 0.12], [-0.1, 0, 0]], rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------------- every field's refusal

BAD = [
    ({"mesh": None}, "mesh is required"),
    ({"length_unit": None}, "length_unit is required"),
    ({"length_unit": "cm"}, "length_unit must be 'm' or 'mm'"),
    ({"length_unit": "m"}, "sheath.puncture is 25.8 m from the origin, more than 1 m: wrong length_unit (m)?"),
    ({"side": "inside"}, "side must be 'lumen'"),
    ({"mesh": "missing.stl"}, "mesh 'missing.stl': no such file"),
    ({"mesh": "targets.csv"}, "mesh 'targets.csv'"),
    ({"mesh": "[1, 2]"}, "mesh must be a string"),
    ({"transform": "{translation: [1, 2]}"}, "transform.translation must be 3 numbers"),
    ({"transform": "{scale: 2}"}, "unknown field 'scale' in transform"),
    ({"transform": "{rpy_deg: [0, .nan, 0]}"}, "transform.rpy_deg[1] must be a finite number"),
    ({"touch_radius": "-1"}, "touch_radius must be > 0"),
    ({"touch_radius": "0"}, "touch_radius must be > 0"),
    ({"touch_radius": "30"}, "touch_radius must be > 0 and at most 20 mm"),
    ({"touch_radius": "big"}, "touch_radius must be a finite number"),
    ({"targets": None}, "targets is required"),
    ({"targets": "5"}, "targets must be a CSV file name or a list"),
    ({"targets": "nothing.csv"}, "targets 'nothing.csv': no such file"),
    ({"targets": "[[1, 2]]"}, "targets[0] must be 3 numbers"),
    ({"targets": "[{name: a}]"}, "targets[0] must be [x, y, z] or {name"),
    ({"targets": "[]"}, "targets has no targets"),
    ({"sheath": None}, "sheath.puncture is required on the lumen side"),
    ({"sheath": "{puncture: [0, 0, 0], tip: [0, 0, 0]}"}, "sheath.tip is not read on the lumen side"),
    ({"sheath": "{puncture: [-24, 7, -6], aim: [-24, 7, -6]}"}, "sheath.aim"),
    ({"sheath": "{puncture: [-24, 7]}"}, "sheath.puncture must be 3 numbers"),
    ({"sheath": "{direction: [0, 0, 0]}"}, "sheath.direction must not be all zero"),
    ({"magnets": "[[1, 2]]"}, "magnets[0] must be 3 numbers"),
    ({"magnets": "[[5000, 0, 0]]"}, "magnets[0] is 5 m from the origin"),
    ({"magnets": "[1, 2, 3]"}, "magnets[0] must be a list"),
    # inside the chamber, and just outside its wall: the chain would reach into the magnet
    ({"magnets": "[[-24, 7, -6]]"}, "magnets[0] [-24, 7, -6] is"),
    ({"magnets": "[[0, 0, 120], [0, 0, 0]]"}, "magnets[1] [0, 0, 0] is"),
    ({"magnets": "[[0, 0, 0]]"}, "mm from the surface; a magnet unit stands outside the chamber, at least 42.6 mm"),
    ({"colour": "red"}, "unknown field 'colour'"),
]


@pytest.mark.parametrize("fields,message", BAD, ids=[m for _, m in BAD])
def test_every_bad_field_is_refused_naming_the_field_and_the_file(tmp_path, fields, message):
    path = lumen_anatomy(tmp_path, **fields)
    assert message in refused(path)


@pytest.mark.parametrize("text,message", [
    ("name,x,y,z\nL1,1,2\n", "row 2: 3 fields"),
    ("x,y,z\n1,2,z\n", "row 2: its z is not a finite number"),
    ("1,2,3\n4,5,nan\n", "row 2: its z is not a finite number"),
    ("a,b,c\n1,2,3\n", "row 1: a header (a row without numbers) must name the columns x, y, z"),
    ("L1,1,2,3\nL1,1,2,3\n", "row 2: the name 'L1' is used twice"),
])
def test_a_bad_targets_csv_is_refused_naming_its_row(tmp_path, text, message):
    got = refused(lumen_anatomy(tmp_path, csv_text=text))
    assert message in got and "targets 'targets.csv'" in got


@pytest.mark.parametrize("text,message", [
    ("mesh: procedural\nlength_unit: m\ntargets: procedural_left_atrium.csv\nsheath: {puncture: [0, 0, 0]}\n",
     "sheath is not read with mesh: procedural"),
    ("mesh: procedural\nlength_unit: mm\ntargets: procedural_left_atrium.csv\n", "length_unit must be m with mesh"),
    ("mesh: procedural\nlength_unit: m\nside: solid\ntargets: procedural_left_atrium.csv\n", "side must be lumen"),
    ("- mesh: procedural\n", "must be a mapping of anatomy fields"),
    ("mesh: procedural\nmesh: procedural\n", "duplicate key 'mesh'"),
])
def test_the_procedural_mesh_takes_no_sheath_nor_transform(tmp_path, text, message):
    (tmp_path / "procedural_left_atrium.csv").write_text(PROCEDURAL_FILE.with_suffix(".csv").read_text())
    path = tmp_path / "anatomy.yaml"
    path.write_text(text)
    assert message in refused(path)


@pytest.mark.parametrize("command", [["plan"], ["teleop"], ["teleop", "--live"],
                                     ["simulate", "--scenario", "teleop_right_unit"]])
def test_the_commands_exit_2_on_a_bad_anatomy_file_with_one_line(tmp_path, capsys, command):
    path = lumen_anatomy(tmp_path, side="both")
    assert main(command + ["--anatomy", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "side must be 'lumen'" in err and path.name in err


# ----------------------------------------------------------------------------------- the scenario's field


@pytest.mark.parametrize("overrides,message", [
    ("{atrium_file: atrium.stl}", "scenario atrium_file cannot go with anatomy"),
    ("{heart_scale: 1.2}", "scenario heart_scale cannot go with anatomy"),
    ("{puncture: [0.0, 0.0, 0.0]}", "scenario puncture cannot go with anatomy"),
    ("{heart: false}", "scenario anatomy is for the heart"),
])
def test_the_scenario_s_anatomy_excludes_the_other_atrium_fields(tmp_path, overrides, message):
    from ballchain.systems.chain_scenario import apply_overrides, load_scenario, parse_overrides

    path = lumen_anatomy(tmp_path)
    scenario = load_scenario("heart_left_quasi_static", f"{{anatomy: {path}}}")
    assert scenario.anatomy == str(path)
    with pytest.raises(UserInputError, match=message):
        apply_overrides(scenario, parse_overrides(overrides)).validate()


def test_the_scenario_s_anatomy_must_exist(tmp_path):
    from ballchain.systems.chain_scenario import load_scenario

    with pytest.raises(UserInputError, match="scenario anatomy .*no such file"):
        load_scenario("heart_left_quasi_static", f"{{anatomy: {tmp_path / 'none.yaml'}}}")



def test_a_solid_phantom_s_sheath_tip_inside_the_solid_is_refused_naming_the_file(tmp_path):
    from anatomy_helpers import solid_anatomy

    anatomy = load_anatomy(solid_anatomy(tmp_path))
    assert anatomy.side == "solid" and np.allclose(anatomy.n_W, [0.0, 0.0, 1.0])  # up, out of the plate's top
    assert "sheath tip" in refused(solid_anatomy(tmp_path, sheath="{tip: [0, 10, 0], direction: [0, 0, 1]}"))
