"""Which right-ring targets a steerable sheath brings within the manual catheter's reach: a cheap
geometric check (issue 45, item 4), before any full run.

The catheter beyond the sheath exit as its unloaded shape (a straight shaft, then the 55 mm
deflectable segment at the knob's constant curvature, ``SteerableCatheter.curvature``), swept over
the push (5-120 mm in 4 mm), the knob (11 in [-1, 1]) and the twist (24 a turn); the sheath
(``drake_models.sheath.SteerableSheath``) over its advance beyond the septum, its rotation (12 a
turn) and one deflection per line. A pose counts when every sheath point more than 4 mm beyond
the septum stays 1.5 mm inside the atrium and every catheter node but the tip inside it (the
atrium's signed distance); its tip's distance from a touch is ``manual_catheter.touch_miss``
(0: it touches). No wall contact: a tip that would slide along the wall is not followed, so a
few-mm miss here may still touch in a run, and a 0 may still be unreachable against friction.
``--min-out 6`` keeps only the settings the hand's plan may use (``sheath_plan.has_room``: the
catheter's shortest, 6 mm, fits ahead of the exit on the way). Prints one JSON line per sheath
setting: the least miss [mm] per right-ring target.

    python benchmarks/manual_sheath_reach.py [--deflections 0 45 90 135 180] [--min-out 6]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from ballchain.drake_models.atrium_sdf import atrium_sdf
from ballchain.drake_models.sheath import SteerableSheath
from ballchain.experiments import manual_catheter as mc
from ballchain.optimization.rod_statics import frame_along
from ballchain.systems.sheath_plan import has_room
from ballchain.systems.station import atrium_for
from ballchain.systems.target_contact import heart_targets


def _rz(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def catheter_shape(cat, out: float, knob: float, n: int = 14) -> np.ndarray:
    """The unloaded catheter beyond the exit in the exit's frame (z its axis, the bend towards
    +x): (n, 3) from the exit to the tip sphere's centre [m]."""
    sheathlike = SteerableSheath(deflectable_length=cat.deflectable_length, max_deflection=np.pi,
                                 max_advance=max(out, 1e-6), nominal_advance=0.0)
    bend = cat.curvature(knob) * cat.deflectable_length
    pts, _ = sheathlike.local(out, float(np.clip(bend, -np.pi, np.pi)), n)
    return pts


def reach(heart, sdf, sheath: SteerableSheath, deflection: float, advances, n_rot: int = 12,
          min_out: float = 0.0) -> dict:
    cat = mc.comparison_catheter()
    names, p_WT, n_W, radius = heart_targets(heart)
    right = [i for i, name in enumerate(names) if name.startswith("right_")]
    axis = np.asarray(heart.sheath_axis_H, float)
    R_S = frame_along(axis)
    p_S = np.asarray(heart.p_HE, float) - sheath.nominal_advance * axis
    shapes = [catheter_shape(cat, out, knob) for out in np.arange(5e-3, 120e-3 + 1e-9, 4e-3)
              for knob in np.linspace(-1.0, 1.0, 11)]
    best = np.full(len(right), np.inf)
    for advance in advances:
        for rotation in np.linspace(0.0, 2 * np.pi, n_rot, endpoint=False) if deflection else [0.0]:
            p, R_E, line = sheath.exit_pose(p_S, R_S, advance, rotation, deflection, 8)
            along = np.linspace(0.0, advance, len(line))
            if np.any(sdf(line[along > 4e-3], gradient=False) < 1.5e-3):
                continue
            if min_out > 0 and not has_room(sheath, cat, sdf, p_S, R_S, (advance, rotation, deflection), min_out):
                continue
            for shape in shapes:
                for twist in np.linspace(0.0, 2 * np.pi, 24, endpoint=False):
                    w = p + shape @ (R_E @ _rz(twist)).T
                    if np.min(sdf(w[:-1], gradient=False)) < 0.5 * cat.radius:
                        continue
                    best = np.minimum(best, mc.touch_miss(w[-1], p_WT[right], n_W[right], cat.radius, radius))
    return {names[i]: round(float(m) * 1e3, 1) for i, m in zip(right, best)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--deflections", type=float, nargs="+", default=[0.0, 45.0, 90.0, 135.0, 180.0],
                        help="sheath deflections [deg]")
    parser.add_argument("--min-out", type=float, default=0.0,
                        help="[mm] keep only the settings where this much straight catheter fits ahead of the "
                             "exit on the way (the hand's pull-back, 6 mm: the plan's room check; 0: none)")
    args = parser.parse_args()
    heart = atrium_for(mc.scenario_for())
    sdf = atrium_sdf(heart)
    sheath = SteerableSheath().validate()
    fixed = reach(heart, sdf, sheath, 0.0, [sheath.nominal_advance])
    print(json.dumps({"sheath": "fixed (the paper's exit)", "miss_mm": fixed}))
    for deg in args.deflections:
        t0 = time.process_time()
        advances = [sheath.nominal_advance, 10e-3, 15e-3, 20e-3, 30e-3, 40e-3]
        miss = reach(heart, sdf, sheath, float(np.radians(deg)), advances, min_out=args.min_out * 1e-3)
        print(json.dumps({"sheath": f"steerable, deflection {deg:g} deg, advance 3.5-40 mm, any rotation",
                          "miss_mm": miss, "cpu_s": round(time.process_time() - t0, 1)}))


if __name__ == "__main__":
    main()
