"""Where the manual arm's hand puts a steerable sheath for a target (issue 45): ``SheathPlan``,
used by ``catheter_station.ManualHand`` (split from that module for its length)."""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.sheath import SteerableSheath
from ballchain.drake_models.wall_motion import CONTACT_FORCE
from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.systems.rod_wall_compliance import INDENTATION_CAP
from ballchain.systems.target_contact import TOUCH_TOLERANCE

SHEATH_CLEARANCE = 1.5e-3  # [m] the planned sheath stays this far inside the atrium, beyond the septum's 4 mm
PLAN_DEFLECTIONS = (0.0, 45.0, 90.0, 135.0, 180.0)  # [deg] the sheath deflections a plan weighs
PLAN_ADVANCES = (10e-3, 15e-3, 20e-3, 30e-3)  # [m] and its advances beyond the septum (with the nominal and the most)
# [m] the fixed sheath's setting is kept while its unloaded shapes miss a target by no more: the
# wall's contact slides the tip further than the shapes (right_1 at 0.3 mm and left_11 at 1.1 mm
# are touched from the fixed exit, the paper's sheath); an assumption.
PLAN_KEEP = 1.5e-3


def press_depth(catheter: SteerableCatheter) -> float:
    """How far the catheter's shortest may press into a compliant wall when the hand places the
    sheath [m]: the indentation of the procedure's target contact force (``wall_motion.CONTACT_FORCE``,
    20 gf, the ball chain's too) on the wall's stiffness (``SteerableCatheter.wall_stiffness``),
    within the compliance's cap; 0 on the rigid wall (issue 45, H10: the manoeuvre of bringing the
    curled sheath up to the wall, the catheter's tip pressed on it, as a clinician feels it)."""
    if catheter.wall_stiffness <= 0:
        return 0.0
    return min(CONTACT_FORCE / catheter.wall_stiffness, INDENTATION_CAP)


def has_room(sheath: SteerableSheath, catheter: SteerableCatheter, sdf, p_S, R_S, setting, min_out: float,
             steps: int = 6) -> bool:
    """Whether the catheter's shortest (``min_out`` straight out of the exit, the hand's
    pull-back) stays a radius inside the atrium at the sheath ``setting`` and at the deflections
    the hand passes through on the way to it (it deflects last, ``ManualHand``): else the sheath
    curling with the catheter in it drives the rod's tip into the wall (a 6 mm rod on an exit
    4.5 mm from the wall pressed it with 18 N, the issue-45 steerable runs' 6-27 N). On a
    compliant wall the shortest may press into it by ``press_depth`` (the target contact force's
    indentation)."""
    advance, rotation, deflection = setting
    reach = np.linspace(0.0, min_out, 4)
    room = catheter.radius - press_depth(catheter)
    for d in np.linspace(0.0, deflection, steps + 1)[1:] if deflection else [0.0]:
        p, R, _ = sheath.exit_pose(p_S, R_S, advance, rotation, d)
        if np.any(sdf(p + np.outer(reach, R[:, 2]), gradient=False) < room):
            return False
    return True


class SheathPlan:
    """Where the hand puts a steerable sheath for a target (issue 45): what a clinician does with
    the curves they know, not a search of the mechanics. The catheter's unloaded shapes
    (``SteerableCatheter.unloaded_shape``: the push 5-120 mm in 4 mm, 11 knob positions, 24 twists
    a turn) from a sheath setting's exit must touch the target (the tip sphere's centre over the
    target's circle, its surface within the touch tolerance of the wall), the rod inside the
    atrium; the fixed sheath's setting (nominal advance, straight) is kept when it does (within
    ``PLAN_KEEP``). Else the
    settings (advance 3.5-40 mm, rotation 24 a turn, ``PLAN_DEFLECTIONS``; the sheath
    ``SHEATH_CLEARANCE`` inside the atrium) are tried in the order of how squarely their exit
    faces the target (the exit's axis against the wall's normal, and against the line to the
    target), the first ``top`` of them, and the first that touches is the plan (else the least
    miss). ``benchmarks/manual_sheath_reach.py`` is the same check over every setting.
    """

    def __init__(self, sheath: SteerableSheath, catheter: SteerableCatheter, p_S, R_S, sdf,
                 target_radius: float, top: int = 12, min_out: float = 6e-3) -> None:
        self.sheath, self.catheter, self.sdf = sheath.validate(), catheter, sdf
        self.target_radius, self.top = float(target_radius), int(top)
        self.nominal = (sheath.nominal_advance, 0.0, 0.0)
        advances = sorted({sheath.nominal_advance, *PLAN_ADVANCES, sheath.max_advance})
        self.candidates = []
        for advance in advances + ([None] if press_depth(catheter) > 0 and sdf is not None else []):
            for deg in PLAN_DEFLECTIONS:
                for rotation in np.linspace(0.0, 2 * np.pi, 24, endpoint=False) if deg else [0.0]:
                    if advance is None:  # on a compliant wall: the sheath advanced until the tip presses it
                        to_wall = self._to_wall(p_S, R_S, float(rotation), float(np.radians(deg)), min_out)
                        if to_wall is None:
                            continue
                        setting = (to_wall, float(rotation), float(np.radians(deg)))
                    else:
                        setting = (advance, float(rotation), float(np.radians(deg)))
                    p, R, line = sheath.exit_pose(p_S, R_S, *setting, 8)
                    along = np.linspace(0.0, setting[0], len(line))
                    if sdf is not None and np.any(sdf(line[along > 4e-3], gradient=False) < SHEATH_CLEARANCE):
                        continue
                    if sdf is not None and not self._room(p_S, R_S, setting, min_out):
                        continue
                    self.candidates.append((setting, p, R))
        self._p_S, self._R_S = np.asarray(p_S, float), np.asarray(R_S, float)
        grid = [(out, knob) for out in np.arange(5e-3, 120e-3 + 1e-9, 4e-3) for knob in np.linspace(-1.0, 1.0, 11)]
        self.outs = np.array([out for out, _ in grid])  # (S,) each shape's catheter out of the sheath [m]
        self.knobs = np.array([knob for _, knob in grid])  # (S,) each shape's knob
        self.shapes = np.array([catheter.unloaded_shape(out, knob) for out, knob in grid])  # (S, n, 3)
        t = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
        c, si, z, o = np.cos(t), np.sin(t), np.zeros_like(t), np.ones_like(t)
        self._twists = np.stack([np.stack([c, -si, z], -1), np.stack([si, c, z], -1), np.stack([z, z, o], -1)], 1)
        self._cache = {}

    def _room(self, p_S, R_S, setting, min_out: float) -> bool:
        return has_room(self.sheath, self.catheter, self.sdf, p_S, R_S, setting, min_out)

    def _to_wall(self, p_S, R_S, rotation: float, deflection: float, min_out: float, tol: float = 0.25e-3):
        """On a compliant wall, the manoeuvre of advancing the deflected sheath until the
        catheter's shortest presses the wall (``press_depth``: the target contact force): the
        largest advance with room (``has_room``), by bisection to ``tol``, when the sheath's
        most advance has none and its nominal one has (None: no such wall ahead)."""
        lo, hi = self.sheath.nominal_advance, self.sheath.max_advance
        if not self._room(p_S, R_S, (lo, rotation, deflection), min_out) or \
                self._room(p_S, R_S, (hi, rotation, deflection), min_out):
            return None
        while hi - lo > tol:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if self._room(p_S, R_S, (mid, rotation, deflection), min_out) else (lo, mid)
        return lo

    def misses(self, setting, p_T, n_T) -> np.ndarray:
        """The distance from a touch of the target (p_T, n_T) of each of the catheter's unloaded
        shapes from the sheath ``setting``'s exit, (24 twists, S shapes) [m] (inf: the shape
        leaves the atrium)."""
        p, R, _ = self.sheath.exit_pose(self._p_S, self._R_S, *setting)
        frames = R[None] @ self._twists  # (24, 3, 3)
        pts = p + np.einsum("snj,tij->tsni", self.shapes, frames)  # (24, S, n, 3)
        ok = np.ones(pts.shape[:2], bool)
        if self.sdf is not None:
            d = self.sdf(pts[:, :, :-1].reshape(-1, 3), gradient=False).reshape(pts.shape[0], pts.shape[1], -1)
            ok = d.min(axis=2) >= 0.5 * self.catheter.radius
        rel = pts[:, :, -1] - p_T
        h = rel @ n_T
        lateral = np.sqrt(np.maximum((rel * rel).sum(axis=-1) - h * h, 0.0))
        miss = np.hypot(np.maximum(lateral - self.target_radius, 0.0),
                        np.maximum(np.abs(h) - self.catheter.radius - TOUCH_TOLERANCE, 0.0))
        return np.where(ok, miss, np.inf)

    def miss(self, setting, p_T, n_T) -> float:
        """The least distance from a touch of the target (p_T, n_T) over the catheter's unloaded
        shapes from the sheath ``setting``'s exit [m] (inf: none stays in the atrium)."""
        return float(self.misses(setting, p_T, n_T).min())

    def approach(self, p_T, n_T) -> tuple[float, float, float]:
        """The catheter's curve the hand sets at the planned setting before the operator steers
        again (the re-approach after a pull-back, ``ManualHand``): (push out of the sheath [m],
        knob, twist about the exit's axis [rad]) of the unloaded shape nearest a touch of the
        target, the shortest and least bent of the equals (a clinician dials the curve they know
        reaches the target and advances the catheter about as far as the target lies from the
        sheath's tip, not as far as it was out before: with the exit facing the wall a few mm
        away, the old length drove the rod into the wall)."""
        p_T, n_T = np.asarray(p_T, float), np.asarray(n_T, float)
        miss = self.misses(self.plan(p_T, n_T), p_T, n_T)  # (24, S)
        if not np.isfinite(miss.min()):
            return float(self.outs.min()), 0.0, 0.0
        t, k = np.nonzero(miss <= miss.min() + 1e-12)
        best = min(zip(t, k), key=lambda tk: (self.outs[tk[1]], abs(self.knobs[tk[1]]), tk[0]))
        return float(self.outs[best[1]]), float(self.knobs[best[1]]), float(2 * np.pi * best[0] / len(self._twists))

    def plan(self, p_T, n_T, keep: bool = True) -> tuple:
        """The sheath setting (advance [m], rotation [rad], deflection [rad]) for the target
        (``keep``: the fixed sheath's setting when its shapes reach; else a deflected one)."""
        p_T, n_T = np.asarray(p_T, float), np.asarray(n_T, float)
        key = (tuple(np.round(p_T, 9)), bool(keep))
        if key in self._cache:
            return self._cache[key]
        best, best_miss = self.nominal, self.miss(self.nominal, p_T, n_T)
        if not keep:
            best_miss = np.inf
        if best_miss > PLAN_KEEP:
            def facing(c):
                _, p, R = c
                v = p_T - p
                return (np.arccos(np.clip(-(R[:, 2] @ n_T), -1.0, 1.0))
                        + 0.5 * np.arccos(np.clip(R[:, 2] @ v / max(np.linalg.norm(v), 1e-9), -1.0, 1.0)))
            for setting, _, _ in sorted(self.candidates, key=facing)[:self.top]:
                m = self.miss(setting, p_T, n_T)
                if m < best_miss:
                    best, best_miss = setting, m
                if m == 0.0:
                    break
        self._cache[key] = best
        return best
