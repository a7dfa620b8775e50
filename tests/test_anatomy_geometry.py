"""The engines on anatomies the project did not generate: test meshes built with another mesh
library (trimesh's primitives and manifold3d's booleans), checked against that library's own
inside test (``contains``) and signed distance (``proximity.signed_distance``).

Anatomies: a solid wall section (a 10 mm plate with two vein holes, millimetres, binary STL;
the chain works outside it), an atrium with an appendage (a union of two spheres, metres, PLY),
the same two spheres as overlapping separate shells, one inside out (OBJ), a hollow solid (two
nested shells, both facing out), a sphere cut into two halves along an unwelded seam, and a
327,680-triangle sphere (decimated).
"""

from __future__ import annotations

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")
pytest.importorskip("manifold3d")
pytest.importorskip("rtree")

from ballchain.drake_models import mesh_tools as mt  # noqa: E402
from ballchain.drake_models.atrium_mesh import (DECIMATE_TO, UserAtrium, UserAtriumParams,  # noqa: E402
                                                grid_winding_inside, load_atrium_surface, validate_surface)
from ballchain.drake_models.atrium_sdf import atrium_sdf  # noqa: E402
from ballchain.infrastructure.errors import UserInputError  # noqa: E402
from ballchain.drake_models.surface_tree import SurfaceTree  # noqa: E402

PLATE_TIP_MM = [0.0, 0.0, 25.0]  # the sheath's tip above the plate, between the holes


def wall_section() -> "trimesh.Trimesh":
    """A 60 x 40 x 10 mm plate with two 12 mm vein holes (millimetres)."""
    plate = trimesh.creation.box((60.0, 40.0, 10.0))
    for x in (-15.0, 15.0):
        plate = plate.difference(trimesh.creation.cylinder(6.0, 30.0, sections=48,
                                                           transform=trimesh.transformations.translation_matrix(
                                                               [x, 0.0, 0.0])), engine="manifold")
    return plate


def appendage_atrium() -> "trimesh.Trimesh":
    """A 50 mm chamber with a 20 mm appendage bulging out of it (metres)."""
    body = trimesh.creation.icosphere(4, radius=25e-3)
    lobe = trimesh.creation.icosphere(3, radius=10e-3)
    lobe.apply_translation([22e-3, 12e-3, 8e-3])
    return body.union(lobe, engine="manifold")


def sample(mesh, n: int, margin: float, seed: int) -> np.ndarray:
    lo, hi = mesh.bounds
    return np.random.default_rng(seed).uniform(lo - margin, hi + margin, (n, 3))


@pytest.fixture(scope="module")
def plate_stl(tmp_path_factory):
    path = tmp_path_factory.mktemp("plate") / "wall_section_mm.stl"
    wall_section().export(path)  # trimesh writes binary STL
    return path


@pytest.fixture(scope="module")
def appendage_ply(tmp_path_factory):
    path = tmp_path_factory.mktemp("appendage") / "atrium_m.ply"
    appendage_atrium().export(path, encoding="binary")
    return path


@pytest.fixture(scope="module")
def plate(plate_stl):
    return UserAtrium(load_atrium_surface(plate_stl, "mm"), np.array(PLATE_TIP_MM) * 1e-3,
                      sheath_aim=[0.0, 0.0, 0.0], side="solid")


@pytest.fixture(scope="module")
def appendage(appendage_ply):
    return UserAtrium(load_atrium_surface(appendage_ply, "m"), [-25e-3, 0.0, 0.0])


def test_side_is_validated_and_part_of_the_cache_key(plate_stl):
    surface = load_atrium_surface(plate_stl, "mm")
    with pytest.raises(UserInputError, match="UserAtrium side must be one of 'lumen', 'solid'"):
        UserAtrium(surface, np.array(PLATE_TIP_MM) * 1e-3, side="outside")
    solid = UserAtrium(surface, np.array(PLATE_TIP_MM) * 1e-3, side="solid")
    assert solid.side == "solid" and "solid" in solid.lumen_key


def test_the_plate_reads_in_millimetres_with_its_volume(plate_stl):
    mesh = wall_section()
    surface = load_atrium_surface(plate_stl, "mm")
    assert surface.units == "mm"
    # binary STL stores float32 corners: the volume agrees to float32's relative precision
    np.testing.assert_allclose(surface.volume_ml, mesh.volume * 1e-3, rtol=1e-5)


def test_solid_inside_test_and_signed_distance_match_trimesh(plate, tmp_path):
    """Free space (where the chain works) is outside trimesh's solid; the grid's node values
    are minus trimesh's signed distance (positive inside there), clamped to the band."""
    mesh = wall_section()
    mesh.apply_scale(1e-3)
    P = sample(mesh, 2000, 8e-3, seed=1)
    truth_solid = mesh.contains(P)
    d = np.abs(trimesh.proximity.signed_distance(mesh, P))
    clear = d > 1e-6
    assert 0.1 < truth_solid.mean() < 0.9
    free = plate._tree.winding_numbers(P) <= 0.5
    np.testing.assert_array_equal(free[clear], ~truth_solid[clear])
    sdf = atrium_sdf(plate, spacing=2e-3, directory=tmp_path)  # node values are exact at any spacing
    nodes, values = _grid_sample(sdf, 1000, seed=2)
    _check_node_values(mesh, nodes, values, sdf.band, sign=-1.0)
    assert sdf(np.array(PLATE_TIP_MM) * 1e-3, gradient=False)[0] > 0  # the sheath tip is in free space


def test_solid_contains_is_free_space_within_the_working_box(plate):
    mesh = wall_section()
    mesh.apply_scale(1e-3)
    P = sample(mesh, 3000, 10e-3, seed=3)
    d = trimesh.proximity.signed_distance(mesh, P)  # > 0 inside the solid
    wall = plate.params.wall_thickness
    # The wall's far side is the surface mitred a wall thickness inward: a wall thickness deep
    # under every face (deeper near the edges, where the mitred corners reach further)
    contains = plate.contains(P)
    assert contains[d < wall - 1e-9].all() and (d < 0).sum() > 1000
    behind = d > wall + 1e-9
    # deeper than a wall thickness: behind the far side except near the mitred edges (measured 2 %)
    assert behind.sum() > 100 and contains[behind].mean() < 0.05
    lo, hi = plate.working_box
    assert not plate.contains(hi[None] + 1e-3)[0]


def test_lumen_with_an_appendage_matches_trimesh(appendage, tmp_path):
    mesh = appendage_atrium()
    P = sample(mesh, 2000, 5e-3, seed=4)
    d = trimesh.proximity.signed_distance(mesh, P)  # > 0 inside
    clear = np.abs(d) > 1e-6
    inside = appendage._tree.winding_numbers(P) > 0.5
    np.testing.assert_array_equal(inside[clear], (d > 0)[clear])
    assert inside[np.linalg.norm(P - [27e-3, 15e-3, 10e-3], axis=1) < 3e-3].all()  # deep in the appendage
    sdf = atrium_sdf(appendage, spacing=2e-3, directory=tmp_path)
    nodes, values = _grid_sample(sdf, 1000, seed=5)
    _check_node_values(mesh, nodes, values, sdf.band, sign=1.0)


def _check_node_values(mesh, nodes: np.ndarray, values: np.ndarray, band: float, sign: float) -> None:
    """Grid node values against trimesh: the sign of ``sign`` times trimesh's signed distance
    (positive inside its solid) off the surface; the magnitude never more than trimesh's (the
    distance to the point of the surface trimesh picked, an upper bound: its candidate triangles
    may miss the nearest one), equal to it at most nodes, and equal to the minimum over every
    triangle; float32 storage: 2e-9 m."""
    theirs = sign * trimesh.proximity.signed_distance(mesh, nodes)
    off = np.abs(theirs) > 1e-6
    np.testing.assert_array_equal(np.sign(values[off]), np.sign(theirs[off]))
    capped = np.minimum(np.abs(theirs), band)
    assert np.all(np.abs(values) <= capped + 2e-9)
    # trimesh finds the nearest triangle at 94 % of the plate's nodes (its holes' long thin
    # facets fool its candidate boxes) and at nearly all of the spheres'
    assert np.mean(np.abs(np.abs(values) - capped) < 2e-9) > 0.9
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    exact = np.minimum(mt.SurfaceDistance(V, F, candidates=len(F))(nodes[:50]), band)
    np.testing.assert_allclose(np.abs(values[:50]), exact, atol=2e-9)


def _grid_sample(sdf, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random grid nodes within the band (and a few beyond it) and their stored values."""
    shape = sdf.values.shape
    rng = np.random.default_rng(seed)
    flat = sdf.values.reshape(-1)
    near = np.flatnonzero(np.abs(flat) < sdf.band)
    pick = np.concatenate([rng.choice(near, n, replace=False), rng.choice(len(flat), n // 10, replace=False)])
    ijk = np.stack(np.unravel_index(pick, shape), axis=1)
    return sdf.origin + sdf.spacing * ijk, flat[pick].astype(float)


def test_overlapping_shells_one_inside_out_join_into_one_chamber(tmp_path):
    """The chamber and the appendage as two separate, overlapping shells (as a segmentation tool
    may export a vein or an appendage), the appendage inside out: one chamber, the union."""
    body = trimesh.creation.icosphere(4, radius=25.0)
    lobe = trimesh.creation.icosphere(3, radius=10.0)
    lobe.apply_translation([22.0, 12.0, 8.0])
    lobe.invert()
    both = trimesh.util.concatenate([body, lobe])
    path = tmp_path / "two_shells_mm.obj"
    both.export(path)
    surface = load_atrium_surface(path, "mm")
    assert any("2 shells" in note for note in surface.notes) and any("re-oriented" in n for n in surface.notes)
    atrium = UserAtrium(surface, [-25e-3, 0.0, 0.0])
    union = appendage_atrium()
    P = sample(union, 1500, 5e-3, seed=6)
    d = trimesh.proximity.signed_distance(union, P)
    # the separate shells are faceted like the union's parts, except where the union cut them:
    # points 0.2 mm or more from the union's surface
    clear = np.abs(d) > 0.2e-3
    np.testing.assert_array_equal((atrium._tree.winding_numbers(P) > 0.5)[clear], (d > 0)[clear])
    # the chamber's triangles inside the appendage (and the appendage's inside the chamber) are
    # no part of the wall: the chain passes from the chamber into the appendage
    V, F = atrium.blood_surface
    assert len(F) < len(surface.F)
    centroids = V[F].mean(axis=1)
    assert np.all(np.abs(trimesh.proximity.signed_distance(union, centroids)) < 0.5e-3)


def test_a_hollow_solid_has_its_cavity_outside(tmp_path):
    """Two nested shells both facing out (a hollow part exported carelessly): the inner one is
    turned inward, so its cavity is not solid."""
    outer = trimesh.creation.icosphere(4, radius=25.0)
    inner = trimesh.creation.icosphere(4, radius=15.0)
    path = tmp_path / "hollow_mm.stl"
    trimesh.util.concatenate([outer, inner]).export(path)
    surface = load_atrium_surface(path, "mm")
    np.testing.assert_allclose(surface.volume_ml, (outer.volume - inner.volume) * 1e-3, rtol=1e-5)  # float32 STL
    part = UserAtrium(surface, [0.0, 0.0, 32e-3], side="solid")
    r = np.array([5.0, 14.0, 16.0, 24.0, 26.0, 40.0]) * 1e-3
    P = np.stack([r, 0 * r, 0 * r], axis=1)
    np.testing.assert_array_equal(part._tree.winding_numbers(P) > 0.5, [False, False, True, True, False, False])


def test_an_unwelded_seam_is_bridged(tmp_path):
    """A sphere cut at the equator, its halves' rim vertices duplicated and 0.05 mm apart: the
    openings are narrow, so the surface is accepted and inside tests agree with the whole sphere."""
    sphere = trimesh.creation.icosphere(4, radius=25.0)
    top = sphere.faces[sphere.triangles_center[:, 2] >= 0]
    bottom = sphere.faces[sphere.triangles_center[:, 2] < 0]
    V_top, V_bottom = sphere.vertices.copy(), sphere.vertices.copy() + [0.0, 0.0, -0.05]
    V = np.vstack([V_top, V_bottom])
    F = np.vstack([top, bottom + len(V_top)])
    surface = validate_surface(V, F, "mm")
    assert any("narrow openings" in note for note in surface.notes)
    atrium = UserAtrium(surface, [-25e-3, 0.0, 0.0])
    P = sample(sphere, 1000, 5.0, seed=7)
    inside = sphere.contains(P)
    # beyond the seam's 0.05 mm offset and the facets' 0.03 mm sag
    clear = np.abs(np.linalg.norm(P, axis=1) - 25.0) > 0.2
    np.testing.assert_array_equal((atrium._tree.winding_numbers(P * 1e-3) > 0.5)[clear], inside[clear])
    shape = (24, 24, 24)
    origin = np.full(3, -27e-3)
    grid = grid_winding_inside(atrium._tree, origin, 2.35e-3, shape).reshape(-1)
    nodes = origin + 2.35e-3 * np.indices(shape).reshape(3, -1).T
    r = np.linalg.norm(nodes, axis=1) * 1e3
    ok = np.abs(r - 25.0) > 0.2
    np.testing.assert_array_equal(grid[ok], (r < 25.0)[ok])


def test_disjoint_shells_and_a_sheath_aimed_out_are_refused(tmp_path, appendage):
    one = trimesh.creation.icosphere(3, radius=15.0)
    two = trimesh.creation.icosphere(3, radius=15.0)
    two.apply_translation([40.0, 0.0, 0.0])
    path = tmp_path / "two_chambers_mm.stl"
    trimesh.util.concatenate([one, two]).export(path)
    surface = load_atrium_surface(path, "mm")
    with pytest.raises(UserInputError, match="^mesh: the surface has 2 disjoint pieces"):
        UserAtrium(surface, [-15e-3, 0.0, 0.0])
    # as separate phantom parts (the chain outside them) they are fine
    UserAtrium(surface, [20e-3, 0.0, 25e-3], side="solid")
    with pytest.raises(UserInputError, match="^sheath_aim: the sheath .* leaves the chamber"):
        UserAtrium(appendage.surface, [-25e-3, 0.0, 0.0], sheath_aim=[-40e-3, 0.0, 0.0])
    with pytest.raises(UserInputError, match="sheath tip .* is inside the solid"):
        UserAtrium(load_atrium_surface(path, "mm"), [0.0, 0.0, 0.0], side="solid")


def test_surface_tree_against_direct_sums():
    """The tree's winding numbers (far field to second order) and distances against the direct
    sums over every triangle (``mesh_tools``)."""
    mesh = appendage_atrium()
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    tree = SurfaceTree.build(V, F)
    P = sample(mesh, 100, 5e-3, seed=8)
    # measured max error 0.03 (beta = 3) in the deep interior, where the sign is never in doubt
    np.testing.assert_allclose(tree.winding_numbers(P), mt.winding_numbers(P, V, F), atol=0.05)
    exact = np.concatenate([mt.SurfaceDistance(V, F, candidates=len(F))(chunk) for chunk in np.split(P, 4)])
    np.testing.assert_allclose(tree.distances(P), exact, atol=1e-12)
    np.testing.assert_allclose(tree.distances(P, cutoff=2e-3), np.minimum(exact, 2e-3), atol=1e-12)
    # trimesh's distance is to a point of the surface: never below the nearest
    assert np.all(exact <= np.abs(trimesh.proximity.signed_distance(mesh, P)) + 1e-12)


def test_the_walls_grow_away_from_the_chain(plate, appendage):
    """A lumen's wall lies outside its surface, a solid's inside it: every wall vertex is on the
    far side of the surface from the chain (or on it)."""
    for atrium, solid_side in ((plate, True), (appendage, False)):
        Vt, T = atrium.wall_tetrahedra
        assert np.all(mt.signed_volumes(Vt, T) > 0)
        n = len(atrium.surface.V)
        w = atrium._tree.winding_numbers(Vt[n:])  # the layers behind the surface
        assert np.all((w > 0.5) == solid_side)


@pytest.mark.slow
def test_a_large_mesh_is_decimated_for_contact_and_the_distance(tmp_path):
    """A 327,680-triangle sphere (icosphere of order 7): decimated to about ``DECIMATE_TO``
    triangles, still closed, its volume within 0.5 % and every original vertex within 0.1 mm of
    the decimated surface."""
    sphere = trimesh.creation.icosphere(7, radius=25.0)
    assert len(sphere.faces) == 327_680
    path = tmp_path / "big_mm.stl"
    sphere.export(path)
    surface = load_atrium_surface(path, "mm")
    assert abs(len(surface.F) - DECIMATE_TO) < 0.05 * DECIMATE_TO
    assert any("decimated from 327,680" in note for note in surface.notes)
    assert mt.is_watertight(surface.F)
    np.testing.assert_allclose(surface.volume_ml, sphere.volume * 1e-3, rtol=5e-3)
    far = SurfaceTree.build(surface.V, surface.F).distances(np.asarray(sphere.vertices[::7]) * 1e-3)
    assert far.max() < 0.1e-3
    atrium = UserAtrium(surface, [-25e-3, 0.0, 0.0], params=UserAtriumParams())
    files = atrium.write_files(tmp_path / "wall")
    assert files["vtk"].stat().st_size > 0


def _short_push(engine: str, heart):
    """20 mm of chain pushed out of the sheath at 0.1 m/s, no field: the chain meets the anatomy."""
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import run_simulation

    scenario = load_scenario("heart_no_field", f"{{engine: {engine}, insertion: {{initial: 0.01, final: 0.024, "
                                               "start_time: 0.0, speed: 0.1}}")
    result = run_simulation(scenario=scenario, duration=0.3, heart=heart)
    return result, np.array(result.p_W_mm) * 1e-3, scenario


@pytest.mark.slow
@pytest.mark.parametrize("engine", ["plant", "statics"])
def test_a_chain_pushed_onto_the_solid_phantom_stays_outside_it(plate_stl, engine):
    """The sheath 25 mm off the plate's top face, aimed obliquely at its middle: the chain
    reaches the face and rests on it (its tip a ball radius above it, within the contact's
    penetration), every ball outside trimesh's solid."""
    heart = UserAtrium(load_atrium_surface(plate_stl, "mm"), np.array([0.0, -25.0, 20.0]) * 1e-3,
                       sheath_aim=[0.0, 0.0, 0.0], side="solid")
    result, p, scenario = _short_push(engine, heart)
    mesh = wall_section()
    mesh.apply_scale(1e-3)
    assert not mesh.contains(p).any()
    r = 0.5 * 3.175e-3
    clearance = np.abs(trimesh.proximity.signed_distance(mesh, p)) - r
    # the plant's compliant wall lets a ball in by about 0.1 mm (its contact penetration); the
    # statics keep centres a radius from the surface to the solver's tolerance
    assert clearance.min() > (-0.3e-3 if engine == "plant" else -1e-6)
    assert clearance[-1] < 0.3e-3  # the tip is on the face
    assert result.max_neighbor_gap_um < 20


@pytest.mark.slow
@pytest.mark.parametrize("engine", ["plant", "statics"])
def test_a_chain_in_the_atrium_with_an_appendage_stays_inside(appendage, engine):
    """The sheath through the septum at -x, aimed at the chamber's centre: the balls out of the
    sheath stay inside trimesh's union, a ball radius from its surface."""
    result, p, scenario = _short_push(engine, appendage)
    p = p[(p - appendage.p_HE) @ appendage.sheath_axis_H > 0]  # out of the sheath
    assert len(p) >= 5
    mesh = appendage_atrium()
    assert mesh.contains(p).all()
    clearance = trimesh.proximity.signed_distance(mesh, p) - 0.5 * 3.175e-3
    assert clearance.min() > (-0.3e-3 if engine == "plant" else -1e-6)
    assert result.max_neighbor_gap_um < 20


def test_the_camera_frames_a_solid_with_its_sheath(plate, appendage):
    """A lumen's box is its surface's (the sheath is inside); a solid's also holds the sheath's
    tip and its last 20 mm, in free space above the plate."""
    from ballchain.systems.meshcat_view import SHEATH_IN_VIEW, atrium_box

    lo, hi = atrium_box(appendage)
    np.testing.assert_allclose(lo, appendage.surface.V.min(axis=0))
    np.testing.assert_allclose(hi, appendage.surface.V.max(axis=0))
    lo, hi = atrium_box(plate)
    back = plate.p_HE - SHEATH_IN_VIEW * plate.sheath_axis_H
    for p in (plate.p_HE, back, *plate.surface.V):
        assert np.all(p >= lo - 1e-12) and np.all(p <= hi + 1e-12)
    np.testing.assert_allclose(hi[2], back[2])  # the sheath stands highest
