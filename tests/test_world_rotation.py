"""The anatomy's registration rotation (issue 43, ``drake_models.world.PosedWall``,
``systems.world_apply.perturbed_wall``): a wall grid turned by transforming the query points into
its axis-aligned frame and the normals back agrees with the unturned grid at the transformed points
and with a plane turned analytically; a world without a rotation keeps the grid itself."""

from __future__ import annotations

import math

import numpy as np

from ballchain.drake_models.atrium_sdf import AtriumSDF
from ballchain.drake_models.world import NAMES, PRESETS, PosedWall, draw_world
from ballchain.optimization.wall_constraints import PlaneSDF
from ballchain.systems.world_apply import perturbed_wall

RNG = np.random.default_rng(43)


def _sphere_grid(radius: float = 0.02, spacing: float = 1e-3) -> AtriumSDF:
    """The signed distance of a ball of blood (> 0 inside) on a grid: a curved wall whose grid
    values, gradient and Hessian all vary."""
    n = int(2 * (radius + 4e-3) / spacing) + 1
    origin = np.full(3, -(radius + 4e-3))
    axes = [origin[k] + spacing * np.arange(n) for k in range(3)]
    P = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    values = np.clip(radius - np.linalg.norm(P, axis=-1), -3e-3, 3e-3)
    return AtriumSDF(origin, spacing, values, 3e-3, key="sphere")


def _rotation(angle_deg: float) -> np.ndarray:
    w = RNG.normal(size=3)
    w *= math.radians(angle_deg) / np.linalg.norm(w)
    k = w / np.linalg.norm(w)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    a = np.linalg.norm(w)
    return np.eye(3) + math.sin(a) * K + (1.0 - math.cos(a)) * K @ K


def test_a_turned_grid_is_the_grid_at_the_turned_points():
    grid = _sphere_grid()
    R, c = _rotation(7.0), np.array([0.004, -0.003, 0.012])
    posed = PosedWall.about(grid, R, c)
    q = RNG.uniform(-0.021, 0.021, size=(40, 3))  # points of the grid's own frame, near the wall
    p = c + (q - c) @ R.T  # the same points of the turned wall
    s0, g0, H0 = grid(q, hessian=True)
    s1, g1, H1 = posed(p, hessian=True)
    assert np.max(np.abs(s1 - s0)) < 1e-12
    assert np.max(np.abs(g1 - g0 @ R.T)) < 1e-12 * max(1.0, np.max(np.abs(g0)))  # normals turned back
    assert np.max(np.abs(H1 - np.einsum("ia,kab,jb->kij", R, H0, R))) < 1e-12 * np.max(np.abs(H0))
    assert np.array_equal(posed(p, gradient=False), s1)
    assert np.max(np.abs(g1 - g0)) > 1e-2  # the normals did turn (7 deg of unit vectors)
    # Moved as a whole (the moving wall): the turned wall at p + offset.
    offset = np.array([1e-3, -2e-3, 5e-4])
    assert np.max(np.abs(posed.translated(offset)(p + offset)[0] - s0)) < 1e-12


def test_a_turned_plane_is_the_plane_turned_analytically():
    R, c = _rotation(20.0), np.array([0.01, 0.0, -0.02])
    point, normal = np.array([0.0, 0.03, 0.0]), np.array([0.2, -1.0, 0.1])
    plane = PlaneSDF(point, normal)
    turned = PlaneSDF(c + R @ (point - c), R @ normal)  # the independent formula
    p = RNG.uniform(-0.05, 0.05, size=(30, 3))
    s, g, H = PosedWall.about(plane, R, c)(p, hessian=True)
    s_ref, g_ref = turned(p)
    assert np.max(np.abs(s - s_ref)) < 1e-12
    assert np.max(np.abs(g - g_ref)) < 1e-12
    assert np.max(np.abs(H)) == 0.0


def test_the_world_wall_turned_scaled_and_moved_is_the_nominal_at_the_registered_points():
    grid = _sphere_grid()
    draw = draw_world(PRESETS["literature"].only(["anatomy_rotation", "anatomy_scale", "anatomy_position"]), 5, 1)
    R = draw.anatomy_rotation_matrix()
    assert 0.0 < math.degrees(np.linalg.norm(draw.anatomy_rotation)) < 15.0
    c = np.array([0.003, 0.018, 0.002])  # the sheath exit
    world = perturbed_wall(grid, draw, c)
    assert isinstance(world, PosedWall)
    q = RNG.uniform(-0.021, 0.021, size=(40, 3))
    s = draw.anatomy_scale
    p = c + s * (q - c) @ R.T + np.asarray(draw.anatomy_offset)
    s0, g0 = grid(q)
    s1, g1 = world(p)
    assert np.max(np.abs(s1 - s * s0)) < 1e-12
    assert np.max(np.abs(g1 - g0 @ R.T)) < 1e-11


def test_no_rotation_keeps_the_grid_and_the_earlier_draws():
    grid = _sphere_grid()
    lit = PRESETS["literature"]
    without = lit.only([n for n in NAMES if n != "anatomy_rotation"])
    a, b = draw_world(lit, 9, 2), draw_world(without, 9, 2)
    assert b.anatomy_rotation == (0.0, 0.0, 0.0) and a.anatomy_rotation != b.anatomy_rotation
    for name in ("magnet_offsets", "magnet_tilts", "magnet_scales", "ball_diameter_scale", "ball_remanence_scale",
                 "sheath_exit_offset", "anatomy_offset", "anatomy_scale", "localisation_bias"):
        assert getattr(a, name) == getattr(b, name), name  # drawn last: the others unchanged
    assert perturbed_wall(grid, draw_world(lit.only(["magnet_position"]), 9, 1), np.zeros(3)) is grid
    d = a.to_dict()
    assert len(d["anatomy_rotation_deg"]) == 3 and d["anatomy_rotation_angle_deg"] > 0.0
    assert set(d["not_modelled"]) == {"wall_stiffness", "wall_friction"}


def test_the_engine_plays_the_turned_wall_and_none_keeps_its_grid():
    """Wired where the translation is: the quasi-static engine's wall is the nominal grid turned
    by the drawn rotation about the nominal sheath exit; ``world: none`` keeps the grid itself."""
    from ballchain.drake_models.atrium_sdf import atrium_sdf
    from ballchain.experiments import teleop
    from ballchain.experiments.procedure_world import with_world
    from ballchain.systems.station import MakeStation

    world = {"preset": "literature", "only": ["anatomy_rotation"], "seed": 5}
    turned = MakeStation(teleop.scenario_for("world", None, with_world(None, world, 5), None))
    nominal = MakeStation(teleop.scenario_for("world", None, None, None))
    grid = nominal.chain.engine_system._sdf
    assert isinstance(grid, AtriumSDF) and grid.key == atrium_sdf(nominal.heart).key
    wall = turned.chain.engine_system._sdf
    assert isinstance(wall, PosedWall) and wall.inner.key == grid.key
    draw = draw_world(PRESETS["literature"].only(["anatomy_rotation"]), 5, len(turned.units))
    c = np.asarray(nominal.chain.p_WE, float)
    assert np.array_equal(np.asarray(turned.chain.world_exit, float), c)  # the exit stays: the turn is about it
    assert np.allclose(wall.R, draw.anatomy_rotation_matrix(), rtol=0, atol=1e-15)
    q = c + RNG.uniform(-0.02, 0.02, size=(10, 3))
    assert np.max(np.abs(wall(c + (q - c) @ wall.R.T)[0] - grid(q)[0])) < 1e-12
