"""Model-based steering (beyond the paper): inverse statics for each ablation target, and a plan.

For each target of a ring (Task I: the 20 around the left veins; Task II: the 18 around the
right veins) the tip ball is held touching the wall at the target (its centre a ball radius off
the wall along the wall's normal) and the magnet orientation and inserted length that press it
hardest are found by optimisation over equilibria (the same machinery as the Table I forces,
``experiments.forces``). The plan visits the targets in order; its time is what the hardware
needs between consecutive equilibria: the magnet's turn at the teleoperation speed and the
feeder's insertion change at its speed. The magnet is the paper's teleoperation set-up: one
prototype unit 10 cm beyond the right carina, on the line from the atrium's centre.
"""

from __future__ import annotations

import math

import numpy as np
from tqdm import tqdm

from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.drake_models.heart import LeftAtrium
from ballchain.drake_models.params import BallChain
from ballchain.experiments.forces import Stand, max_normal_force

TASKS = {"left": "left", "right": "right"}
PAPER = {"left": {"targets": 20, "path_mm": 115.0, "human_time_s": 40.0},
         "right": {"targets": 18, "path_mm": 95.0, "human_time_s": 26.0}}
MIN_FORCE_GF = 10.0


def teleop_stand(atrium: LeftAtrium, task: str, ball_diameter: float, carina_distance: float = 0.10) -> Stand:
    """The ring's targets and the teleoperation magnet in the statics frame."""
    R_HS = rotation_with_z_along(atrium.sheath_axis_H)[:, [2, 0, 1]]
    to_S = lambda p_H: R_HS.T @ (np.asarray(p_H) - atrium.p_HE)  # noqa: E731
    ring = atrium.rings[task]
    targets = {}
    for k, p_HT in enumerate(ring.p_HT):
        # The targets lie on the ellipsoidal endocardium: its outward normal is along p / a^2.
        n_out = p_HT / atrium.semi_axes**2
        n_in = -n_out / np.linalg.norm(n_out)  # into the chamber
        # Sensor axis: into the wall (the direction the tip presses).
        targets[f"{task}_{k + 1}"] = (to_S(p_HT + 0.5 * ball_diameter * n_in), R_HS.T @ (-n_in))
    carina = atrium.carinas["right"]
    p_HM = carina + carina_distance * carina / np.linalg.norm(carina)
    return Stand(targets, {"1": to_S(p_HM)}, R_HS, atrium.p_HE)


def run(*, task: str = "left", targets: int | None = None, balls=(16,), grid: int = 4, refine: int = 15,
        omega_max: float = 0.5, feeder_speed: float = 0.02, progress: bool = True) -> dict:
    """Inverse statics for every target of a task, then the visiting plan and its time.

    Args:
        task: "left" (Task I) or "right" (Task II).
        targets: only the first ``targets`` targets (None: all).
        balls: inserted chain lengths to try for each target.
        grid, refine: orientation search effort (see ``forces.max_normal_force``).
        omega_max: magnet angular speed [rad/s] (the teleoperation mapper's full stick).
        feeder_speed: insertion speed [m/s].
    """
    if task not in TASKS:
        raise ValueError(f"task must be 'left' or 'right', got {task!r}")
    atrium = LeftAtrium()
    d = BallChain().ball_diameter
    stand = teleop_stand(atrium, task, d)
    names = list(stand.targets)[: targets or None]
    rows = []
    for name in tqdm(names, desc=f"plan {task}", unit="target", disable=not progress):
        best = None
        for n in balls:
            out = max_normal_force(BallChain(n_balls=n), stand, name, ("1",), grid, refine)
            if out.get("force_N") is not None and (best is None or out["force_N"] > best["force_N"]):
                best = dict(out, n_balls=n)
        rows.append({"target": name, "reached": best is not None,
                     "force_gf": None if best is None else best["force_gf"],
                     "n_balls": None if best is None else best["n_balls"],
                     "dipole": None if best is None else best["dipoles"][0]})
    reached = [r for r in rows if r["reached"]]
    turn, feed = 0.0, 0.0
    for a, b in zip(reached, reached[1:]):
        angle = math.acos(float(np.clip(np.dot(a["dipole"], b["dipole"]), -1.0, 1.0)))
        turn += angle / omega_max
        feed += abs(a["n_balls"] - b["n_balls"]) * d / feeder_speed
    forces_gf = [r["force_gf"] for r in reached]
    summary = {
        "targets": len(rows), "reached": len(reached),
        "with_at_least_10_gf": sum(f >= MIN_FORCE_GF for f in forces_gf),
        "force_gf_min": min(forces_gf) if forces_gf else None,
        "force_gf_max": max(forces_gf) if forces_gf else None,
        "plan_time_s": turn + feed, "magnet_turn_time_s": turn, "insertion_time_s": feed,
        "ring_path_mm": 1e3 * atrium.rings[task].curve_length,
    }
    return {"task": task, "rows": rows, "summary": summary, "paper": PAPER[task]}
