"""The atrium's signed-distance grid against the exact mesh distance, its sign at the ostia, its
gradient against finite differences, and its cache."""

import numpy as np
import pytest

from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models.atrium_sdf import atrium_sdf, build_atrium_sdf


def _relevant_points(heart, n, rng):
    """Points within 3 mm of the blood-side surface, away from the vein tubes' far (open) ends
    and the septal puncture, where the signed distance to an open surface jumps by design."""
    V, F = heart.lumen_surface
    idx = rng.integers(0, len(F), n)
    P = np.einsum("kj,kjd->kd", rng.dirichlet([1, 1, 1], n), V[F[idx]]) + rng.uniform(-3e-3, 3e-3, (n, 3))
    keep = np.linalg.norm(P - heart.p_HP, axis=1) > 6e-3
    for o in heart.ostia:
        keep &= (P - o.p_HO) @ o.axis_H < heart.params.vein_length + heart.params.wall_thickness - 4e-3
    return P[keep]


@pytest.mark.slow
def test_grid_matches_exact_mesh_distance(heart, sdf):
    rng = np.random.default_rng(1)
    P = _relevant_points(heart, 3000, rng)
    exact = heart.wall_distance(P) * np.where(heart.lumen_contains(P), 1.0, -1.0)
    grid = sdf(P, gradient=False)
    # Where a ball centre can be (at most 1 mm sunk into the 2.5 mm wall): the spline's error is
    # O(h^2 curvature) on the faces, up to ~h/4 at the creases of the distance field over the
    # ostium rims' edges.
    region = exact > -1e-3
    err = np.abs(grid - exact)[region]
    assert np.quantile(err, 0.99) < 0.06e-3
    assert err.max() < 0.2e-3
    # The sign agrees wherever the exact distance is more than a grid spacing from zero.
    clear = np.abs(exact) > 0.5e-3
    assert np.all(np.sign(grid[clear]) == np.sign(exact[clear]))


@pytest.mark.slow
def test_sign_and_continuity_at_the_ostia(heart, sdf):
    """Across each ostium: inside the vein's mouth the ball is in the lumen (sdf > 0), beside it
    in the wall (sdf < 0), and the distance never jumps (1-Lipschitz up to the grid's error)."""
    r_ball = 0.5 * 3.175e-3
    for o in heart.ostia:
        helper = np.array([0.0, 0.0, 1.0]) if abs(o.axis_H[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = np.cross(o.axis_H, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(o.axis_H, e1)
        a = np.linspace(0, 2 * np.pi, 12, endpoint=False)
        ring = np.cos(a)[:, None] * e1 + np.sin(a)[:, None] * e2
        R = 0.5 * o.diameter
        for along in (-1e-3, 0.0, 2e-3, 5e-3):
            mouth = o.p_HO + along * o.axis_H + (R - r_ball - 0.5e-3) * ring
            # In the lumen; 5 mm up the vein a ball fits (the tube's polygon is 0.1 mm inside
            # its circle), lower down the remaining endocardium facets can be nearer.
            assert np.all(sdf(mouth, gradient=False) > (r_ball if along > 4e-3 else 0.0)), (o.name, along)
        beside = o.p_HO + 6e-3 * o.axis_H + (R + 1.5e-3) * ring  # in the vein's wall
        assert np.all(sdf(beside, gradient=False) < 0.0), o.name
        # A line from the chamber through the ostium's rim into the vein's wall.
        start = o.p_HO - 6e-3 * o.axis_H + (R - 1e-3) * e1
        stop = o.p_HO + 6e-3 * o.axis_H + (R + 1e-3) * e1
        t = np.linspace(0.0, 1.0, 400)
        line = start + t[:, None] * (stop - start)
        values = sdf(line, gradient=False)
        step = np.linalg.norm(stop - start) / (len(t) - 1)
        assert np.abs(np.diff(values)).max() < 1.2 * step + 1e-6, o.name  # a 4 mm jump would show


@pytest.mark.slow
def test_gradient_and_hessian_against_finite_differences(heart, sdf):
    rng = np.random.default_rng(2)
    P = _relevant_points(heart, 400, rng)
    P = P[np.abs(sdf(P, gradient=False)) < 2e-3]
    value, grad, hess = sdf(P, hessian=True)
    h = 1e-6
    fd = np.stack([(sdf(P + h * e, gradient=False) - sdf(P - h * e, gradient=False)) / (2 * h)
                   for e in np.eye(3)], axis=1)
    # The gradient is the exact derivative of the (piecewise quadratic) interpolant: central
    # differences agree to round-off (values ~1e-3 m, step 1e-6 m).
    np.testing.assert_allclose(grad, fd, atol=1e-6)
    # Near the wall it is a unit normal up to the smoothing of the rims' creases.
    assert np.median(np.abs(np.linalg.norm(grad, axis=1) - 1.0)) < 0.02
    fd_h = np.stack([(sdf(P + h * e)[1] - sdf(P - h * e)[1]) / (2 * h) for e in np.eye(3)], axis=2)
    # The Hessian jumps at the spline's knots: a difference that straddles one (about 1 % of
    # random points) disagrees; all others agree to round-off.
    ok = np.all(np.abs(hess - fd_h) < 1e-3 / sdf.spacing, axis=(1, 2))
    assert ok.mean() > 0.95
    np.testing.assert_allclose(hess, hess.transpose(0, 2, 1))


@pytest.mark.slow
def test_user_surface_ray_parity_and_cache(tmp_path):
    """A user's closed surface (an ellipsoid from an icosphere): ray-parity sign, exact distance
    at the nodes, the interpolated distance against the exact one, and the cache is reused."""
    from ballchain.drake_models.atrium_mesh import UserAtrium, validate_surface

    U, F = mt.icosphere(3)
    V = U * np.array([25e-3, 18e-3, 22e-3])
    heart = UserAtrium(validate_surface(V, F, "m"), p_HP=[-25e-3, 0.0, 0.0])
    sdf = atrium_sdf(heart, spacing=1e-3, band=3e-3, directory=tmp_path)
    assert len(list(tmp_path.glob("atrium_sdf_*.npz"))) == 1
    again = atrium_sdf(heart, spacing=1e-3, band=3e-3, directory=tmp_path)
    np.testing.assert_array_equal(again.values, sdf.values)
    # The inside test at the nodes against the winding number (a closed surface).
    shape = sdf.values.shape
    nodes = np.stack(np.meshgrid(*[sdf.origin[k] + sdf.spacing * np.arange(shape[k]) for k in range(3)],
                                 indexing="ij"), -1).reshape(-1, 3)
    sample = np.random.default_rng(3).choice(len(nodes), 3000, replace=False)
    wn = mt.winding_numbers(nodes[sample], V, F) > 0.5
    parity = mt.ray_parity_contains(V, F, sdf.origin, sdf.spacing, shape).reshape(-1)[sample]
    assert np.array_equal(wn, parity)
    # Inside points 1-2 mm from the wall: the grid against the exact distance.
    rng = np.random.default_rng(4)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    surface = d / np.sqrt(((d / np.array([25e-3, 18e-3, 22e-3])) ** 2).sum(axis=1))[:, None]
    P = surface * (1.0 - rng.uniform(1e-3, 2e-3, (500, 1)) / np.linalg.norm(surface, axis=1)[:, None])
    exact = mt.SurfaceDistance(V, F)(P)
    # 1 mm grid on a faceted, gently curved surface (curvature radius >= 13 mm, creases at the
    # facet edges): measured max error 0.051 mm.
    np.testing.assert_allclose(sdf(P, gradient=False), exact, atol=0.08e-3)
    # A coarse rebuild without the cache gives the same grid.
    np.testing.assert_allclose(build_atrium_sdf(heart, spacing=1e-3, band=3e-3).values, sdf.values)


@pytest.mark.slow
def test_compiled_spline_matches_the_numpy_reference(sdf):
    rng = np.random.default_rng(5)
    lo, hi = sdf.origin, sdf.origin + sdf.spacing * (np.array(sdf.values.shape) - 1)
    P = rng.uniform(lo - 1e-3, hi + 1e-3, (500, 3))  # some outside the grid: clamped alike
    for got, ref in zip(sdf(P, hessian=True), sdf.reference(P, hessian=True)):
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(sdf(P, gradient=False), sdf.reference(P, gradient=False), rtol=1e-12, atol=1e-15)


def test_compiled_surface_distance_matches_the_numpy_reference():
    """``nearest_triangle_distances`` (the watchdog's wall check) against ``point_triangle_distances``
    on random triangles near the points: projections inside the triangles and onto every edge and
    vertex, nearly flat triangles; and ``SurfaceDistance`` compiled against numpy on a surface."""
    rng = np.random.default_rng(11)
    k, c = 200, 24
    P = rng.normal(size=(k, 3)) * 0.02
    T = P[:, None, None, :] + rng.normal(size=(k, c, 3, 3)) * rng.uniform(1e-4, 0.03, size=(k, c, 1, 1))
    T[:, :4, 2] = T[:, :4, 0] + 1e-7 * (T[:, :4, 1] - T[:, :4, 0]) + 1e-9  # slivers
    ref = mt.point_triangle_distances(P, T)
    assert (ref == ref.min(axis=1, keepdims=True)).any(axis=1).all()
    got = mt.nearest_triangle_distances(P, T)
    # A distance is a difference of coordinates of ~20 mm: rounding of 1e-16 m is 5e-15 of them.
    np.testing.assert_allclose(got, ref.min(axis=1), rtol=1e-13, atol=1e-16)
    V = rng.normal(size=(300, 3)) * 0.02
    F = rng.integers(0, 300, size=(500, 3))
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
    Q = rng.normal(size=(100, 3)) * 0.02
    np.testing.assert_allclose(mt.SurfaceDistance(V, F)(Q), mt.SurfaceDistance(V, F, compiled=False)(Q),
                               rtol=1e-13, atol=1e-16)
