"""What counts as inside the heart in a pulmonary vein: one rule (``LeftAtrium.in_veins``) for the
watchdog's escape test (``LeftAtrium.contains`` in ``ChainMonitor``), the lumen test that signs
the quasi-static engine's distance grid (``lumen_contains``, ``atrium_sdf``), and the grid itself.

A point down a vein's axis, up to the tube's open end (vein_length + wall_thickness beyond the
ostium centre, where the tube's mesh ends), within its radius, is inside for all of them; a
point beyond the open end, or radially outside the tube's outer wall, is outside for all."""

from types import SimpleNamespace

import numpy as np
import pytest

from ballchain.systems.chain_simulation import ChainMonitor

BALL = 2.5e-3  # [m] the fake chain's ball diameter (only the spacing of its balls)


def _frame(o):
    helper = np.array([1.0, 0.0, 0.0]) if abs(o.axis_H[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(o.axis_H, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(o.axis_H, e1)


def _inside_points(heart, o):
    """Down the vein's axis to 0.1 mm short of the open end, on the axis and at 0.9 of its radius."""
    end = heart.params.vein_length + heart.params.wall_thickness
    e1, e2 = _frame(o)
    r = 0.5 * o.diameter
    pts = []
    for along in np.linspace(0.0, end - 1e-4, 6):
        for a in np.linspace(0.0, 2 * np.pi, 5, endpoint=False):
            for rho in (0.0, 0.9 * r):
                pts.append(o.p_HO + along * o.axis_H + rho * (np.cos(a) * e1 + np.sin(a) * e2))
    return np.array(pts)


def _outside_points(heart, o):
    """2 mm beyond the open end on the axis, and 1 mm outside the tube's outer wall halfway along."""
    end = heart.params.vein_length + heart.params.wall_thickness
    e1, e2 = _frame(o)
    rho = 0.5 * o.diameter + heart.params.wall_thickness + 1e-3
    mid = o.p_HO + (heart.params.vein_length + 0.5 * heart.params.wall_thickness) * o.axis_H
    ring = [mid + rho * (np.cos(a) * e1 + np.sin(a) * e2) for a in np.linspace(0.0, 2 * np.pi, 6, endpoint=False)]
    return np.array([o.p_HO + (end + 2e-3) * o.axis_H] + ring)


def test_the_reported_escape_point_is_inside_the_right_inferior_vein(heart):
    """The live session's 'ball 16 escaped the heart at [-15.4, -28.9, -13.5] mm': 14.4 mm down the
    RIPV's axis (its tube ends at 14.5 mm), 2.6 mm off it (radius 7 mm)."""
    p = np.array([[-15.4, -28.9, -13.5]]) * 1e-3
    assert heart.contains(p)[0] and heart.lumen_contains(p)[0] and heart.in_veins(p)[0]


@pytest.mark.parametrize("vein", range(4))
def test_every_containment_test_agrees_down_each_vein(heart, vein):
    o = heart.ostia[vein]
    inside, outside = _inside_points(heart, o), _outside_points(heart, o)
    for test in (heart.contains, heart.lumen_contains, lambda p: heart.in_veins(p, outer=True), heart.in_veins):
        assert np.all(test(inside)), o.name
        assert not np.any(test(outside)), o.name


def _fake_station(heart, n: int):
    """The parts of a Station ChainMonitor reads (its ``chain``, a DeviceModel): a chain of n
    balls whose centres are set."""
    state = {"p": np.zeros((n, 3))}
    chain = SimpleNamespace(system=SimpleNamespace(GetMyContextFromRoot=lambda root: root),
                            config=SimpleNamespace(chain=SimpleNamespace(ball_diameter=BALL, length=n * BALL)),
                            n_balls=n, body_indices=list(range(1, n + 1)), body_radius=BALL / 2,
                            move_period=1e-3, failure=None, in_sheath=lambda p: np.zeros(len(p), bool),
                            is_finite=lambda ctx: bool(np.all(np.isfinite(state["p"]))),
                            non_finite_part=lambda ctx: "a ball", ball_positions=lambda ctx: state["p"],
                            body_positions=lambda ctx: state["p"],
                            neighbour_gaps=lambda p: np.linalg.norm(np.diff(p, axis=0), axis=1) - BALL,
                            anatomy_offsets=lambda ctx: None)
    cd = SimpleNamespace(chain=chain, heart=heart, scenario=SimpleNamespace(check_period=5e-3, break_gap=1e-3))
    return cd, state


@pytest.mark.parametrize("vein", range(4))
def test_the_watchdog_lets_a_chain_reach_a_veins_open_end_and_stops_one_beyond(heart, vein):
    """A straight chain down the vein's axis, its tip 0.1 mm short of the open end: no escape;
    its tip 2 mm beyond the end (the rest touching, inside): 'ball n escaped the heart'."""
    o = heart.ostia[vein]
    end = heart.params.vein_length + heart.params.wall_thickness
    n = 5
    cd, state = _fake_station(heart, n)
    monitor = ChainMonitor(cd)
    context = SimpleNamespace(get_time=lambda: 1.0)
    for tip, escapes in ((end - 1e-4, False), (end + 2e-3, True)):
        state["p"] = o.p_HO + (tip - BALL * np.arange(n)[::-1])[:, None] * o.axis_H
        message = monitor.check(context, wall=True)
        if escapes:
            assert message is not None and message.startswith(f"ball {n} escaped the heart"), message
        else:
            assert message is None or "escaped" not in message, message


@pytest.mark.slow
@pytest.mark.parametrize("vein", range(4))
def test_the_distance_grid_is_positive_down_each_vein_and_negative_beyond(heart, vein):
    """The quasi-static engine's grid (signed by ``lumen_contains``): > 0 at the inside points,
    < 0 beyond the open end and outside the tube's outer wall."""
    from ballchain.drake_models.atrium_sdf import atrium_sdf

    sdf = atrium_sdf(heart)
    o = heart.ostia[vein]
    # The grid's spline blurs the sign within a node spacing of the surface and of the open end.
    end = heart.params.vein_length + heart.params.wall_thickness
    inside = _inside_points(heart, o)
    deep = ((inside - o.p_HO) @ o.axis_H < end - 2 * sdf.spacing) & (
        np.linalg.norm(np.cross(inside - o.p_HO, o.axis_H), axis=1) < 0.5 * o.diameter - 2 * sdf.spacing)
    assert np.all(sdf(inside[deep], gradient=False) > 0), o.name
    assert np.all(sdf(_outside_points(heart, o), gradient=False) < 0), o.name
