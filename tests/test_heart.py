"""The procedural left atrium and the user-surface loader: dimensions, targets, meshes, errors."""

import numpy as np
import pytest

from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models import paper
from ballchain.drake_models.atrium_mesh import (
    AtriumMeshError,
    load_atrium_surface,
    read_obj,
    write_stl_ascii,
    write_stl_binary,
)
from ballchain.drake_models.heart import PV_NAMES, HeartParams, LeftAtrium

PAPER_RING_MM = {k: v["path_mm"] for k, v in paper.TELEOP_TASKS.items()}


@pytest.fixture(scope="module")
def heart_files(heart, tmp_path_factory):
    return heart.write_files(tmp_path_factory.mktemp("heart"))


def test_dimensions_are_anatomical(heart):
    d = 2e3 * heart.semi_axes  # diameters [mm]
    assert 45 <= d[0] <= 60  # transverse
    assert 35 <= d[1] <= 40  # antero-posterior
    assert 40 <= d[2] <= 55  # supero-inferior
    assert 2.0 <= heart.params.wall_thickness * 1e3 <= 3.0
    assert 40 <= heart.volume * 1e6 <= 70  # ml
    assert [o.name for o in heart.ostia] == list(PV_NAMES)
    # Left veins on the left (+x), right veins on the right, all posterior (-y), superior above.
    lspv, lipv, rspv, ripv = (o.p_HO for o in heart.ostia)
    assert lspv[0] > 0 and lipv[0] > 0 and rspv[0] < 0 and ripv[0] < 0
    assert all(o.p_HO[1] < 0 for o in heart.ostia)
    assert lspv[2] > lipv[2] and rspv[2] > ripv[2]
    # The puncture is on the septal (right) wall and the sheath points into the chamber.
    assert heart.p_HP[0] < -0.8 * heart.semi_axes[0]
    assert heart.sheath_axis_H[0] > 0.5


def test_targets_count_spacing_and_closed_rings(heart):
    for side, n in (("left", 20), ("right", 18)):
        ring = heart.rings[side]
        assert ring.p_HT.shape == (n, 3)
        # Closed ring: spacing includes the last-to-first step; equal to within 3 %.
        assert ring.spacing.shape == (n,)
        assert ring.spacing.max() / ring.spacing.min() < 1.03
        assert 4.0e-3 <= ring.spacing.mean() <= 6.5e-3  # "about 5 mm apart"
        # On the endocardium (ellipsoid equation = 1 to 1e-9).
        np.testing.assert_allclose(((ring.p_HT / heart.semi_axes) ** 2).sum(axis=1), 1.0, atol=1e-9)
        # Every target keeps at least 80 % of the ring margin from the ostia it encircles.
        for o in heart.ostia:
            gap = np.linalg.norm(ring.p_HT - o.p_HO, axis=1) - 0.5 * o.diameter
            assert gap.min() > 0.8 * heart.params.ring_margin or o.name[0] != side[0].upper()
        # First target is the ring's most inferior point.
        assert np.argmin(ring.p_HT[:, 2]) == 0


def test_ring_path_lengths_against_the_paper(heart):
    lengths_mm = {k: v * 1e3 for k, v in heart.ring_path_lengths.items()}
    print("ring path lengths [mm]:", lengths_mm, "paper:", PAPER_RING_MM)
    # The rings are built from anatomy, not fitted to the paper's phantom: within 25 %.
    for side, paper_mm in PAPER_RING_MM.items():
        assert abs(lengths_mm[side] - paper_mm) / paper_mm < 0.25
    # Left ring longer than the right one, as in the paper.
    assert lengths_mm["left"] > lengths_mm["right"]
    # The polygon through the targets is shorter than the smooth ring by < 1 %.
    for ring in heart.rings.values():
        assert 0.99 * ring.curve_length < ring.polygon_length <= ring.curve_length


def test_wall_mesh_is_a_closed_two_layer_tetrahedral_shell(heart, heart_files):
    V, T = heart.wall_tetrahedra
    assert np.all(mt.signed_volumes(V, T) > 0)
    boundary = mt.boundary_surface(V, T)
    assert mt.is_watertight(boundary)
    assert mt.enclosed_volume(V, boundary) > 0  # outward orientation
    # The wall volume equals the tetrahedra's volume (the boundary encloses exactly the wall).
    np.testing.assert_allclose(mt.enclosed_volume(V, boundary), mt.signed_volumes(V, T).sum(), rtol=1e-9)
    # Two layers: a third of the vertices (the middle layer) are interior except at the rims.
    on_boundary = np.zeros(len(V), bool)
    on_boundary[boundary.ravel()] = True
    assert heart.params.wall_layers >= 2
    assert (~on_boundary).mean() > 0.25
    # Files: the VTK reads back identically; the visual OBJ is watertight.
    V2, T2 = mt.read_vtk_tetrahedra(heart_files["vtk"])
    np.testing.assert_allclose(V2, V, atol=1e-12)
    np.testing.assert_array_equal(T2, T)
    Vo, Fo = read_obj(heart_files["obj"])
    assert mt.is_watertight(Fo)


def test_drake_reads_the_wall_as_compliant_hydroelastic(heart_files):
    from pydrake.geometry import Mesh, ReadObjToTriangleSurfaceMesh

    mesh = Mesh(str(heart_files["vtk"]))
    assert mesh.extension() == ".vtk"
    surface = ReadObjToTriangleSurfaceMesh(str(heart_files["obj"]))
    assert surface.num_triangles() > 1000


def test_contains_and_wall_distance(heart):
    assert heart.contains(np.zeros((1, 3)))[0]
    assert not heart.contains(np.array([[0.1, 0.0, 0.0]]))[0]
    # Inside the LSPV tube, past the wall.
    o = heart.ostia[0]
    assert heart.contains((o.p_HO + 5e-3 * o.axis_H)[None])[0]
    # Distance from the centre to the blood-side wall: about the smallest semi-axis.
    np.testing.assert_allclose(heart.wall_distance(np.zeros((1, 3)))[0], heart.semi_axes.min(), rtol=0.01)


def test_scale_parameter_scales_everything():
    big = LeftAtrium(HeartParams(scale=1.2, subdivisions=3))
    ref = LeftAtrium(HeartParams(subdivisions=3))
    np.testing.assert_allclose(big.semi_axes, 1.2 * ref.semi_axes)
    for side in ("left", "right"):
        np.testing.assert_allclose(big.rings[side].curve_length, 1.2 * ref.rings[side].curve_length, rtol=1e-3)


def test_bad_heart_parameters_are_refused():
    with pytest.raises(ValueError, match="wall_layers must be >= 2"):
        HeartParams(wall_layers=1)
    with pytest.raises(ValueError, match="overlap"):
        LeftAtrium(HeartParams(pv_directions=((1, -0.5, 0.1), (1, -0.5, -0.1), (-0.5, -1, 0.4), (-0.5, -1, -0.4))))


# ------------------------------------------------------------------ user surfaces


def _sphere_mm(radius_mm=25.0):
    U, F = mt.icosphere(2)
    return U * radius_mm, F


def _write_obj(path, V, F):
    return mt.write_obj(path, V, F)


def test_user_obj_in_mm_is_guessed_and_converted(tmp_path):
    V, F = _sphere_mm()
    surface = load_atrium_surface(_write_obj(tmp_path / "la.obj", V, F))
    assert surface.units == "mm" and surface.units_guessed
    np.testing.assert_allclose(np.ptp(surface.V, axis=0).max(), 0.05, rtol=1e-6)
    assert 50 < surface.volume_ml < 66  # 4/3 pi 25^3 mm^3 = 65 ml, less for the polyhedron
    # The same surface declared in metres is refused as far too large.
    with pytest.raises(AtriumMeshError, match="size"):
        load_atrium_surface(tmp_path / "la.obj", units="m")


def test_user_stl_ascii_and_binary_round_trip(tmp_path):
    V, F = _sphere_mm()
    V = V * 1e-3  # metres
    for write in (write_stl_ascii, write_stl_binary):
        surface = load_atrium_surface(write(tmp_path / f"la_{write.__name__}.stl", V, F))
        assert surface.units == "m"
        assert len(surface.F) == len(F) and len(surface.V) == len(V)
        Vt, T = surface.wall(2.5e-3, 2)
        assert np.all(mt.signed_volumes(Vt, T) > 0)


def test_user_surface_errors_say_what_is_wrong(tmp_path):
    V, F = _sphere_mm()
    with pytest.raises(AtriumMeshError, match="not closed: 3 boundary edges"):
        load_atrium_surface(_write_obj(tmp_path / "open.obj", V, F[1:]))
    F_bad = F.copy()
    F_bad[0] = F_bad[0, [0, 2, 1]]
    with pytest.raises(AtriumMeshError, match="inconsistent orientation"):
        load_atrium_surface(_write_obj(tmp_path / "flip.obj", V, F_bad))
    with pytest.raises(AtriumMeshError, match="cannot tell the units"):
        load_atrium_surface(_write_obj(tmp_path / "tiny.obj", V * 1e-2, F))
    with pytest.raises(AtriumMeshError, match="unsupported format"):
        load_atrium_surface(_write_obj(tmp_path / "la.off", V, F))
    with pytest.raises(AtriumMeshError, match="no such file"):
        load_atrium_surface(tmp_path / "missing.obj")
    # Inward-facing but otherwise fine: accepted, flipped, and said so.
    surface = load_atrium_surface(_write_obj(tmp_path / "inward.obj", V, F[:, [0, 2, 1]]))
    assert any("flipped" in note for note in surface.notes)
    assert surface.volume_ml > 0


def test_package_helper_resolves_package_uris(heart, tmp_path, monkeypatch):
    from pydrake.multibody.plant import MultibodyPlant

    from ballchain.drake_models import model_files

    monkeypatch.setenv("BALLCHAIN_CACHE", str(tmp_path / "cache"))
    files = heart.write_files()  # into the (new) cache
    assert files["vtk"].parent.parent == model_files.cache_dir()
    uri = model_files.generated_uri(files["vtk"])
    assert uri.startswith("package://ballchain_generated/heart_")
    parser = model_files.make_parser(MultibodyPlant(0.0))
    packages = parser.package_map()
    assert packages.Contains("ballchain_models") and packages.Contains("ballchain_generated")
    assert model_files.resolve_uri(uri) == files["vtk"].resolve()
    yaml_file = model_files.resolve_uri("package://ballchain_models/station.scenarios.yaml")
    assert yaml_file.exists()


def test_both_atria_implement_the_atrium_protocol(heart, tmp_path):
    """The station uses an atrium only through ``drake_models.atrium.Atrium``: the procedural one
    and a user's surface both offer it (a user's with no rings, ostia or carinas)."""
    from ballchain.drake_models.atrium import Atrium
    from ballchain.drake_models.atrium_mesh import UserAtrium, load_atrium_surface

    assert isinstance(heart, Atrium)
    assert set(heart.rings) == {"left", "right"} and len(heart.ostia) == 4 and set(heart.carinas) == {"left", "right"}
    V, F = heart.closed_inner_surface
    path = tmp_path / "atrium.obj"
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in V) + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F))
    user = UserAtrium(load_atrium_surface(path), heart.p_HP)
    assert isinstance(user, Atrium)
    assert user.rings == {} and user.ostia == [] and user.carinas == {}


@pytest.mark.parametrize("params", [HeartParams(), HeartParams(scale=0.8, ring_margin=4e-3)])
def test_the_ring_hull_measured_near_its_nearest_ball_gives_the_floats_of_every_ball(params, monkeypatch):
    """``_hull_distance`` measures only the balls around the continuous hull's nearest point: the
    same floats as measuring all of them, at random points around the hull and at every point
    the rings' bisection visits, and the same rings bit for bit."""
    from ballchain.drake_models import heart as h

    rng = np.random.default_rng(7)
    c1, c2 = np.array([0.01, -0.02, 0.015]), np.array([0.035, 0.0, 0.02])
    for r1, r2 in ((0.009, 0.011), (0.012, 0.006), (0.008, 0.008)):
        t = np.linspace(0.0, 1.0, h.HULL_BALLS)
        centres, radii = c1 + t[:, None] * (c2 - c1), r1 + t * (r2 - r1)
        x = c1 + rng.normal(scale=0.03, size=(5000, 3))
        x[:50] = centres[rng.integers(0, h.HULL_BALLS, 50)]  # on the axis (b = 0)
        windowed = h._hull_distance(centres, radii, x)
        assert np.array_equal(windowed, h._hull_distance(centres, radii, x, window=0))
    visited, reference = [], h._hull_distance

    def both(centres, radii, x, window=h.HULL_WINDOW):
        visited.append(x.copy())
        out = reference(centres, radii, x, window)
        assert np.array_equal(out, reference(centres, radii, x, 0))
        return out

    monkeypatch.setattr(h, "_hull_distance", both)
    fast = LeftAtrium(params)
    assert len(visited) == 2 * 51  # the check of each ring's outer bound and its 50 bisection steps
    monkeypatch.setattr(h, "_hull_distance", lambda c, r, x, window=0: reference(c, r, x, 0))
    full = LeftAtrium(params)
    for side in ("left", "right"):
        assert np.array_equal(fast.rings[side].p_HT, full.rings[side].p_HT)
        assert np.array_equal(fast.rings[side].spacing, full.rings[side].spacing)
