"""Workspace (paper Fig. workspace_results): one magnet 16.51 cm away, rotated through its range.

The chain leaves the sheath at the origin along +x; the prototype cylinder sits beside the
insertion point at (0, -16.51 cm, 0) and turns about z. Starting from the straight chain (the
magnet's field along +x at the base), the magnet turns one way until the field at the base
points along -x through +y (one half workspace) and the other way through -y (the other half).
For 4, 9 and 16 balls, with and without sleeve, the tip positions trace two curves from the
straight chain to the field-along--x equilibrium; together they enclose the workspace (shoelace
formula on the closed loop), and the paper's "half workspace" is half of it. The magnet's pull
makes the two halves unequal, and near the end of the far-side sweep the chain snaps through to
the near side (reported with the field angle where it happens). The paper: 3345 mm^2 without
sleeve, 2939 mm^2 with (12 % less), tip-to-tip about 8 mm.
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from ballchain.drake_models.params import BallChain, Sleeve
from ballchain.experiments.magnet_poses import field_angle_for_magnet_angle, side_magnet
from ballchain.optimization.statics import ChainStatics

PAPER = {"half_area_bare_mm2": 3345.0, "half_area_sleeve_mm2": 2939.0, "reduction_pct": 12.0,
         "tip_to_tip_mm": 8.0}
DISTANCE = 0.1651


def polygon_area(points_xy: np.ndarray) -> float:
    """Area of the closed polygon through the points (shoelace), in the points' units squared."""
    x, y = points_xy[:, 0], points_xy[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def sweep(chain: BallChain, side: int, step_deg: float, distance: float = DISTANCE):
    """Tip positions [m] as the magnet turns from field +x to field -x on one side (+1: +y)."""
    solver = ChainStatics(chain)
    phis = np.radians(180.0 - side * np.arange(0.0, 180.0 + 1e-9, step_deg))
    tips, field_angles, result = [], [], None
    for phi in phis:
        result = solver.solve_or_raise(side_magnet(phi, distance), result)
        tips.append(result.positions[-1].copy())
        field_angles.append(np.degrees(field_angle_for_magnet_angle(phi)))
    return np.array(tips), np.array(field_angles)


def workspace_area(tips_plus: np.ndarray, tips_minus: np.ndarray) -> float:
    """Area enclosed by the tip curves of the two rotation directions (each (k, 3), same unit,
    from the straight chain to the field-along--x equilibrium), in that unit squared; the
    paper's half workspace is half of it."""
    return polygon_area(np.vstack([tips_plus[:, :2], tips_minus[::-1, :2]]))


def tip_to_tip_distance(curves_a: dict, curves_b: dict) -> float:
    """Largest distance between the tips of two chains at the same magnet angle, over both
    rotation directions (``curves[side]`` (k, 3) from ``sweep``, same unit)."""
    return max(float(np.max(np.linalg.norm(curves_a[s] - curves_b[s], axis=1))) for s in (1, -1))


def run(*, balls=(4, 9, 16), step_deg: float = 5.0, distance: float = DISTANCE, progress: bool = True) -> dict:
    """Tip curves, half-workspace areas and the sleeve's effect.

    Returns:
        {"curves": {(n, sleeve, side): tips_mm (k, 3)}, "rows": [{n_balls, sleeve,
        workspace_area_mm2, half_area_mm2, snap angles}], "summary": {...}, "paper": ...}
    """
    curves, rows, snaps = {}, [], {}
    jobs = [(n, sleeve) for n in balls for sleeve in (False, True)]
    d_mm = BallChain().ball_diameter * 1e3
    for n, sleeve in tqdm(jobs, desc="workspace", unit="chain", disable=not progress):
        chain = BallChain(n_balls=n, sleeve=Sleeve() if sleeve else None)
        for side in (+1, -1):
            tips, angles = sweep(chain, side, step_deg, distance)
            curves[(n, sleeve, side)] = tips * 1e3
            jumps = np.linalg.norm(np.diff(tips, axis=0), axis=1) * 1e3
            # A smooth step moves the tip by at most about L x (field step, <= 2 x magnet step);
            # a jump over a quarter of the chain's length is a snap-through to another branch.
            threshold = max(0.25 * n * d_mm, 1.5 * n * d_mm * np.radians(2 * step_deg))
            if np.any(jumps > threshold):
                snaps[(n, sleeve, side)] = float(abs(angles[int(np.argmax(jumps > threshold)) + 1]))
        area = workspace_area(curves[(n, sleeve, 1)], curves[(n, sleeve, -1)])
        rows.append({"n_balls": n, "sleeve": sleeve, "workspace_area_mm2": area,
                     "half_area_mm2": 0.5 * area,
                     "far_side_snap_field_angle_deg": snaps.get((n, sleeve, 1)),
                     "near_side_snap_field_angle_deg": snaps.get((n, sleeve, -1))})
    longest = max(balls)
    half = {r["sleeve"]: r["half_area_mm2"] for r in rows if r["n_balls"] == longest}
    tip_to_tip = tip_to_tip_distance({s: curves[(longest, True, s)] for s in (1, -1)},
                                     {s: curves[(longest, False, s)] for s in (1, -1)})
    summary = {
        "half_area_bare_mm2": half[False],
        "half_area_sleeve_mm2": half[True],
        "reduction_pct": 100.0 * (1.0 - half[True] / half[False]),
        "tip_to_tip_max_mm": tip_to_tip,
        "chain_length_mm": longest * BallChain().ball_diameter * 1e3,
        "field_at_base_mT_range": [1e3 * side_magnet(np.pi, distance).field([[0, 0, 0]])[0, 0],
                                   1e3 * np.linalg.norm(side_magnet(np.pi / 2, distance).field([[0, 0, 0]]))],
    }
    return {"curves": curves, "rows": rows, "summary": summary, "paper": PAPER,
            "setup": f"magnet at (0, -{distance * 100:.2f} cm, 0) turning about z; half area = half the loop of both tip curves"}
