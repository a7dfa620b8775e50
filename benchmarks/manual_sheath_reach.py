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

``--loaded`` (issue 45, the loop or prolapse): the same question with the rod's statics in the
atrium instead of the unloaded shapes (``optimization.rod_statics``: the rod pushed out along the
wall, its shaft bearing on it, the wall frictionless), for the targets named by ``--targets``.
From each sheath setting (the fixed exit, or ``--deflections`` at ``--advances`` and rotations
every ``--rotation-step``), at each twist at the exit (every ``--twist-step``) and knob
(``--knobs``), the rod is pushed out from 6 mm to ``--max-out`` in 3 mm steps, each equilibrium
warm-started from the last (a hand pushing); each converged equilibrium's electrode (its whole
surface, ``target_contact.targets_touched``) is tested against the targets and its wall forces
summed. Prints per target the least miss (0: a touch) with the rod's total wall force at most
each of ``WALL_FORCE_LIMITS`` and with any force, where (sheath, twist, knob, push) and the force
it takes (total on the rod, on the tip).

``--wall-mu`` (issue 45, H8) gives the wall Coulomb friction (``SteerableCatheter.wall_mu``,
``systems.rod_wall_friction``: the tip sphere sticks where it touched while the wall's tangential
reaction is within mu times the normal one, slips beyond it), each push's contact state carried
to the next; ``--step`` the push's step [mm] (the friction law is incremental: a finer step
follows the tip's catch more closely). Rows then add ``tip_stuck`` and ``friction_N`` (the sum
of the friction forces' magnitudes).

``--wall-stiffness`` (issue 45, H10) makes the wall compliant (``SteerableCatheter.wall_stiffness``,
``systems.rod_wall_compliance``: every free node indents the wall by d against N = k d, rigid
beyond a 3 mm cap), given in N/mm (the source's unit: Ijima et al., about 0.11-0.14 N/mm). Rows
then add ``tip_indentation_mm`` and ``hard_N`` (the part of the rod's wall force the rigid cap
carries). The wall force is the whole normal reaction in either case.

    python benchmarks/manual_sheath_reach.py --loaded [--targets right_15 right_16 right_17]
        [--deflections 0 90] [--advances 3.5 15 30] [--rotation-step 45 | --rotations 165 180]
        [--twist-step 30 | --twists 180 210] [--knobs -1 -0.5 0 0.5 0.75 1] [--max-out 120]
        [--wall-mu 0.2 | --wall-stiffness 0.14] [--step 1.5]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from ballchain.drake_models.atrium_sdf import atrium_sdf
from ballchain.drake_models.sheath import SteerableSheath
from ballchain.experiments import manual_catheter as mc
from ballchain.drake_models.electrode import CATHETER_ELECTRODE_LENGTH, axis_start
from ballchain.optimization.rod_statics import frame_along
from ballchain.systems.rod_wall_friction import rod_statics_class
from ballchain.systems.sheath_plan import has_room
from ballchain.systems.station import atrium_for
from ballchain.systems.target_contact import heart_targets, targets_touched

# [N] the rod's total wall force a loaded curve may take: 40 g (0.39 N), the contact force Matsuda
# et al. class as excessive at the tip (Heart Vessels 31:1544, 2016, TactiCath, PMC5010593: 4-7 %
# of ablation points); 1 N and 2 N beyond it (a shaft bearing on the wall over a length is not a
# tip: where its limit lies is an assumption, no source found).
WALL_FORCE_LIMITS = (0.39, 1.0, 2.0)


def _rz(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def catheter_shape(cat, out: float, knob: float, n: int = 14) -> np.ndarray:
    """The unloaded catheter beyond the exit in the exit's frame (z its axis, the bend towards
    +x): (n, 3) from the exit to the tip sphere's centre [m] (``SteerableCatheter.unloaded_shape``,
    the plan's)."""
    return cat.unloaded_shape(out, knob, n)


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


def loaded_reach(heart, sdf, sheath: SteerableSheath, settings, targets, twists, knobs, max_out: float = 120e-3,
                 step: float = 3e-3, limits=WALL_FORCE_LIMITS, cat=None) -> dict:
    """The loaded curves' reach (module docstring, ``--loaded``): per target name, per force limit
    (and "any"), the least miss [mm] (0: the electrode touches) of the converged equilibria whose
    total wall force is within it, with where and the force (None: no converged equilibrium);
    and the solves and how many did not converge."""
    cat = cat or mc.comparison_catheter()
    names, p_WT, n_W, radius = heart_targets(heart)
    ks = [names.index(t) for t in targets]
    axis = np.asarray(heart.sheath_axis_H, float)
    R_S = frame_along(axis)
    p_S = np.asarray(heart.p_HE, float) - sheath.nominal_advance * axis
    rod = rod_statics_class(cat)(cat, heart.p_HE, axis, sdf)
    keys = [str(lim) for lim in limits] + ["any"]
    bounds = list(limits) + [np.inf]
    best = {t: {k: None for k in keys} for t in targets}
    solves = failed = 0
    for setting in settings:
        p, R, line = sheath.exit_pose(p_S, R_S, *setting, 8)
        along = np.linspace(0.0, setting[0], len(line))
        if np.any(sdf(line[along > 4e-3], gradient=False) < 1.5e-3):
            continue
        rod.p_E, rod.R_E, rod._last_pose = p, R, None
        for twist in twists:
            for knob in knobs:
                q = None
                if cat.wall_mu > 0:  # the hand's push from the rod's shortest: nothing stuck yet
                    rod.anchors, rod.last_nodes = {}, {}
                for out in np.arange(6e-3, max_out + 1e-9, step):
                    sol = rod.solve(out, twist, cat.curvature(knob), q0=q)
                    q, solves = sol.q, solves + 1
                    if cat.wall_mu > 0:  # the wall's friction: the nodes stuck where they were
                        rod.anchors, rod.last_nodes = sol.anchors, sol.last_nodes
                    if not sol.converged:
                        failed += 1
                        continue
                    c, force = sol.pose.tip_centre, float(sol.wall_forces.sum())
                    a = axis_start(c, sol.pose.tip_direction, cat.radius, CATHETER_ELECTRODE_LENGTH)
                    touch = targets_touched(c, p_WT[ks], n_W[ks], cat.radius, radius, axis_start=a)
                    miss = np.where(touch, 0.0, mc.touch_miss(c, p_WT[ks], n_W[ks], cat.radius, radius))
                    for j, t in enumerate(targets):
                        row = {"miss_mm": round(float(miss[j]) * 1e3, 2), "wall_force_N": round(force, 3),
                               "tip_force_N": round(float(sol.wall_forces[-1]), 3),
                               "sheath": [round(setting[0] * 1e3, 1), round(float(np.degrees(setting[1]))),
                                          round(float(np.degrees(setting[2])))],
                               "twist_deg": round(float(np.degrees(twist))), "knob": knob, "out_mm": round(out * 1e3, 1)}
                        if cat.wall_mu > 0:  # the tip stuck on the wall, and the friction's share
                            row["tip_stuck"] = bool(rod.n_joints in sol.anchors)
                            row["friction_N"] = round(float(np.linalg.norm(sol.friction, axis=1).sum()), 3)
                        if cat.wall_stiffness > 0:  # the compliant wall: the tip's indentation, the cap's share
                            row["tip_indentation_mm"] = round(float(sol.indentation[-1]) * 1e3, 3)
                            row["hard_N"] = round(float(sol.hard_forces.sum()), 3)
                        for key, bound in zip(keys, bounds):
                            old = best[t][key]
                            if force <= bound and (old is None or (row["miss_mm"], force) < (old["miss_mm"], old["wall_force_N"])):
                                best[t][key] = row
    return {"targets": best, "solves": solves, "not_converged": failed}


def _main_loaded(args, heart, sdf, sheath) -> None:
    settings = []
    for deg in args.deflections:
        if deg == 0.0:
            settings.append((sheath.nominal_advance, 0.0, 0.0))
            continue
        for advance in args.advances:
            for rot in args.rotations if args.rotations else np.arange(0.0, 360.0, args.rotation_step):
                settings.append((advance * 1e-3, float(np.radians(rot)), float(np.radians(deg))))
    t0 = time.process_time()
    twists = args.twists if args.twists else np.arange(0.0, 360.0, args.twist_step)
    cat = mc.comparison_catheter()
    cat.wall_mu = args.wall_mu
    cat.wall_stiffness = args.wall_stiffness * 1e3  # [N/mm] -> [N/m]
    out = loaded_reach(heart, sdf, sheath, settings, args.targets, np.radians(twists),
                       [float(k) for k in args.knobs], args.max_out * 1e-3, step=args.step * 1e-3,
                       cat=cat.validate())
    print(json.dumps({"loaded": True, "deflections_deg": args.deflections, "advances_mm": args.advances,
                      "rotation_step_deg": args.rotation_step,
                      "rotations_deg": args.rotations, "twist_step_deg": args.twist_step, "twists_deg": args.twists, "knobs": args.knobs,
                      "max_out_mm": args.max_out, "step_mm": args.step, "wall_mu": args.wall_mu,
                      "wall_stiffness_N_per_mm": args.wall_stiffness, **out, "cpu_s": round(time.process_time() - t0, 1)}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--deflections", type=float, nargs="+", default=[0.0, 45.0, 90.0, 135.0, 180.0],
                        help="sheath deflections [deg]")
    parser.add_argument("--min-out", type=float, default=0.0,
                        help="[mm] keep only the settings where this much straight catheter fits ahead of the "
                             "exit on the way (the hand's pull-back, 6 mm: the plan's room check; 0: none)")
    parser.add_argument("--loaded", action="store_true", help="the rod's statics along the wall (module docstring)")
    parser.add_argument("--targets", nargs="+", default=["right_15", "right_16", "right_17"])
    parser.add_argument("--advances", type=float, nargs="+", default=[3.5, 15.0, 30.0], help="[mm] (--loaded)")
    parser.add_argument("--rotation-step", type=float, default=45.0, help="[deg] (--loaded)")
    parser.add_argument("--rotations", type=float, nargs="+", default=None,
                        help="[deg] the sheath's rotations instead of --rotation-step's (--loaded)")
    parser.add_argument("--twist-step", type=float, default=30.0, help="[deg] (--loaded)")
    parser.add_argument("--twists", type=float, nargs="+", default=None,
                        help="[deg] the twists at the exit instead of --twist-step's (--loaded)")
    parser.add_argument("--knobs", type=float, nargs="+", default=[-1.0, -0.5, 0.0, 0.5, 0.75, 1.0])
    parser.add_argument("--max-out", type=float, default=120.0, help="[mm] (--loaded)")
    parser.add_argument("--step", type=float, default=3.0, help="[mm] the push's step (--loaded)")
    parser.add_argument("--wall-mu", type=float, default=0.0,
                        help="the wall's Coulomb friction (--loaded; SteerableCatheter.wall_mu, 0: frictionless)")
    parser.add_argument("--wall-stiffness", type=float, default=0.0,
                        help="[N/mm] the wall's compliance (--loaded; SteerableCatheter.wall_stiffness / 1000, "
                             "0: the rigid wall)")
    args = parser.parse_args()
    heart = atrium_for(mc.scenario_for())
    sdf = atrium_sdf(heart)
    sheath = SteerableSheath().validate()
    if args.loaded:
        _main_loaded(args, heart, sdf, sheath)
        return
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
