"""Where the manual arm's hand puts a steerable sheath for a target (issue 45): ``SheathPlan``,
used by ``catheter_station.ManualHand`` (split from that module for its length)."""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.electrode import CATHETER_ELECTRODE_LENGTH, axis_start
from ballchain.drake_models.sheath import SteerableSheath
from ballchain.drake_models.wall_motion import CONTACT_FORCE
from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.optimization.rod_statics import RodStatics
from ballchain.systems.autonomous_navigator import NavigatorParams
from ballchain.systems.rod_wall_compliance import INDENTATION_CAP, CompliantRodStatics
from ballchain.systems.target_contact import TOUCH_TOLERANCE, targets_touched

SHEATH_CLEARANCE = 1.5e-3  # [m] the planned sheath stays this far inside the atrium, beyond the septum's 4 mm
PLAN_DEFLECTIONS = (0.0, 45.0, 90.0, 135.0, 180.0)  # [deg] the sheath deflections a plan weighs
PLAN_ADVANCES = (10e-3, 15e-3, 20e-3, 30e-3)  # [m] and its advances beyond the septum (with the nominal and the most)
# [m] the fixed sheath's setting is kept while its unloaded shapes miss a target by no more: the
# wall's contact slides the tip further than the shapes (right_1 at 0.3 mm and left_11 at 1.1 mm
# are touched from the fixed exit, the paper's sheath); an assumption.
PLAN_KEEP = 1.5e-3


# The local refinement (``SheathPlan.refine``, issue 45, H12) around the coarse plan's best for a
# target whose shapes miss it: (step, steps each way) of the sheath's rotation and deflection [rad]
# and advance [m], and of the catheter's twist [rad], knob and push [m]; a fifth to a sixth of the
# coarse grid's steps (15 deg, 45 deg, 5-10 mm; 15 deg, 0.2, 4 mm) over one coarse step each way
# (the deflection and the advance a third of one): a grid, not a constant fitted to a target.
REFINE_ROTATION = (np.radians(2.5), 6)
REFINE_DEFLECTION = (np.radians(7.5), 2)
REFINE_ADVANCE = (0.5e-3, 3)
REFINE_TWIST = (np.radians(2.5), 6)
REFINE_KNOB = (0.05, 4)
REFINE_PUSH = (0.25e-3, 16)


# The refinement's nearest unloaded curves (by their miss, then the shortest and least bent) that
# the plan solves with the rod's statics against the wall (``SheathPlan.rod_miss``), pushed out from
# the hand's shortest in ``ROD_CHECK_STEP``: a bound on the plan's CPU (about 2 CPU-s a target).
ROD_CHECKS = 24
ROD_CHECK_STEP = 3e-3


def _around(centre: float, step_span, lo: float = -np.inf, hi: float = np.inf) -> np.ndarray:
    step, n = step_span
    return np.unique(np.clip(centre + step * np.arange(-n, n + 1), lo, hi))


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


def force_limit() -> float:
    """[N] the largest wall force a planned curve may take (``SheathPlan.refine``): the procedure's
    window's top, 40 gf (``NavigatorParams.force_window``'s top, the procedure's ``WINDOW_GF``;
    0.39 N, Matsuda et al.'s excessive tip force)."""
    return NavigatorParams.force_window[1]


def _about_z(angles) -> np.ndarray:
    """(T, 3, 3) rotations about z by ``angles`` [rad]."""
    t = np.asarray(angles, float)
    c, si, z, o = np.cos(t), np.sin(t), np.zeros_like(t), np.ones_like(t)
    return np.stack([np.stack([c, -si, z], -1), np.stack([si, c, z], -1), np.stack([z, z, o], -1)], 1)


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
                    valid = self._valid(p_S, R_S, setting, min_out)
                    if valid is not None:
                        self.candidates.append((setting, *valid))
        self._p_S, self._R_S = np.asarray(p_S, float), np.asarray(R_S, float)
        grid = [(out, knob) for out in np.arange(5e-3, 120e-3 + 1e-9, 4e-3) for knob in np.linspace(-1.0, 1.0, 11)]
        self.outs = np.array([out for out, _ in grid])  # (S,) each shape's catheter out of the sheath [m]
        self.knobs = np.array([knob for _, knob in grid])  # (S,) each shape's knob
        self.shapes = np.array([catheter.unloaded_shape(out, knob) for out, knob in grid])  # (S, n, 3)
        self._twists = _about_z(np.linspace(0.0, 2 * np.pi, 24, endpoint=False))
        self.min_out = float(min_out)
        self._cache, self._refined, self._rod_misses = {}, {}, {}
        self._rod = None  # the rod's statics of ``rod_miss``, made at its first call

    def _valid(self, p_S, R_S, setting, min_out: float):
        """(exit p, R) of a sheath ``setting`` the hand may use (its sheath ``SHEATH_CLEARANCE``
        inside the atrium beyond 4 mm, the catheter's shortest with room: ``has_room``), else None."""
        p, R, line = self.sheath.exit_pose(p_S, R_S, *setting, 8)
        along = np.linspace(0.0, setting[0], len(line))
        if self.sdf is not None and np.any(self.sdf(line[along > 4e-3], gradient=False) < SHEATH_CLEARANCE):
            return None
        if self.sdf is not None and not self._room(p_S, R_S, setting, min_out):
            return None
        return p, R

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

    def misses(self, setting, p_T, n_T, shapes=None, twists=None) -> np.ndarray:
        """The distance from a touch of the target (p_T, n_T) of each of the catheter's unloaded
        shapes from the sheath ``setting``'s exit, (24 twists, S shapes) [m] (inf: the shape
        leaves the atrium); ``shapes`` (S, n, 3) and ``twists`` (T,) [rad] other than the plan's
        grid (``refine``)."""
        p, R, _ = self.sheath.exit_pose(self._p_S, self._R_S, *setting)
        shapes = self.shapes if shapes is None else shapes
        frames = R[None] @ (self._twists if twists is None else _about_z(twists))  # (T, 3, 3)
        pts = p + np.einsum("snj,tij->tsni", shapes, frames)  # (T, S, n, 3)
        ok = np.ones(pts.shape[:2], bool)
        if self.sdf is not None:
            d = self.sdf(pts[:, :, :-1].reshape(-1, 3), gradient=False).reshape(pts.shape[0], pts.shape[1], -1)
            ok = d.min(axis=2) >= 0.5 * self.catheter.radius
        return np.where(ok, self._touch_miss(pts[:, :, -1], p_T, n_T), np.inf)

    def _touch_miss(self, tips, p_T, n_T) -> np.ndarray:
        """The distance [m] of tip sphere centres (..., 3) from a touch of the target (p_T, n_T):
        beyond its circle laterally, and off the wall's plane by more than the touch rule allows
        (the catheter's radius and ``TOUCH_TOLERANCE``), combined."""
        rel = tips - p_T
        h = rel @ n_T
        lateral = np.sqrt(np.maximum((rel * rel).sum(axis=-1) - h * h, 0.0))
        return np.hypot(np.maximum(lateral - self.target_radius, 0.0),
                        np.maximum(np.abs(h) - self.catheter.radius - TOUCH_TOLERANCE, 0.0))

    def miss(self, setting, p_T, n_T) -> float:
        """The least distance from a touch of the target (p_T, n_T) over the catheter's unloaded
        shapes from the sheath ``setting``'s exit [m] (inf: none stays in the atrium)."""
        return float(self.misses(setting, p_T, n_T).min())

    def _best_shape(self, setting, p_T, n_T):
        """(miss, push, knob, twist) of the coarse grid's shape nearest a touch from ``setting``
        (the shortest and least bent of the equals)."""
        miss = self.misses(setting, p_T, n_T)  # (24, S)
        if not np.isfinite(miss.min()):
            return np.inf, float(self.outs.min()), 0.0, 0.0
        t, k = np.nonzero(miss <= miss.min() + 1e-12)
        best = min(zip(t, k), key=lambda tk: (self.outs[tk[1]], abs(self.knobs[tk[1]]), tk[0]))
        return (float(miss.min()), float(self.outs[best[1]]), float(self.knobs[best[1]]),
                float(2 * np.pi * best[0] / len(self._twists)))

    def refine(self, setting, p_T, n_T) -> tuple:
        """The local refinement around the coarse plan's ``setting`` for the target (p_T, n_T)
        (issue 45, H12): the sheath's rotation, deflection and advance (``REFINE_*``; a straight
        sheath is not turned or advanced: the fixed sheath's setting stays), on a compliant wall
        also each rotation's and deflection's advance to the wall (``_to_wall``), every setting the
        hand may use (``_valid``); at each, the catheter's shapes about the coarse nearest one (its
        twist, knob and push, the push at least the hand's shortest). Returns (miss [m], setting,
        push [m], knob, twist [rad]) of the shape nearest a touch (0: touches), the shortest, least
        bent and least moved of the equals; the coarse one when nothing misses less."""
        p_T, n_T = np.asarray(p_T, float), np.asarray(n_T, float)
        key = (tuple(np.round(p_T, 9)), tuple(np.round(setting, 12)))
        if key in self._refined:
            return self._refined[key]
        miss0, out0, knob0, twist0 = self._best_shape(setting, p_T, n_T)
        best = (miss0, tuple(setting), out0, knob0, twist0)
        if not np.isfinite(miss0):
            self._refined[key] = best
            return best
        advance, rotation, deflection = setting
        if deflection == 0.0:
            settings = [tuple(setting)]
        else:
            settings = set()
            for d in _around(deflection, REFINE_DEFLECTION, 1e-9, self.sheath.max_deflection):
                for r in _around(rotation, REFINE_ROTATION):
                    advances = list(_around(advance, REFINE_ADVANCE, self.sheath.nominal_advance, self.sheath.max_advance))
                    if press_depth(self.catheter) > 0 and self.sdf is not None:
                        wall = self._to_wall(self._p_S, self._R_S, float(r), float(d), self.min_out)
                        advances += [] if wall is None else [wall]
                    settings.update((float(a), float(r), float(d)) for a in advances)
            settings = sorted(s for s in settings if s == tuple(setting) or
                              self._valid(self._p_S, self._R_S, s, self.min_out) is not None)
        outs = _around(out0, REFINE_PUSH, max(self.min_out, 1e-3), self.catheter.model_length)
        knobs = _around(knob0, REFINE_KNOB, -1.0, 1.0)
        twists = _around(twist0, REFINE_TWIST)
        grid = [(o, k) for o in outs for k in knobs]
        shapes = np.array([self.catheter.unloaded_shape(o, k) for o, k in grid])
        g_out, g_knob = np.array([g[0] for g in grid]), np.array([g[1] for g in grid])

        def cost(c):  # the least miss, then the shortest, least bent and least moved
            return (c[0], c[2], abs(c[3]), abs(c[1][1] - rotation) + abs(c[1][0] - advance))
        near = [(miss0, tuple(setting), max(out0, self.min_out), knob0, twist0)]
        for st in settings:
            miss = self.misses(st, p_T, n_T, shapes, twists)  # (T, S)
            if not np.isfinite(miss.min()):
                continue
            for ti, ki in zip(*np.unravel_index(np.argsort(miss, axis=None)[:ROD_CHECKS], miss.shape)):
                if np.isfinite(miss[ti, ki]):
                    near.append((float(miss[ti, ki]), st, float(g_out[ki]), float(g_knob[ki]), float(twists[ti])))
        near = sorted(near, key=cost)
        best = near[0]
        if self.sdf is not None and self.catheter.wall_mu == 0:
            # The nearest unloaded curves solved with the rod's statics against the wall: the plan
            # takes the first that touches within the force limit, else the least miss.
            checked = []
            for c in near[:ROD_CHECKS]:
                miss, force = self.rod_miss(c[1], c[2], c[3], c[4], p_T, n_T)
                if force <= self._force_limit:
                    checked.append((miss,) + c[1:])
                    if miss == 0.0:
                        break
            if checked:
                best = min(checked, key=cost)
        self._refined[key] = best
        return best

    @property
    def _force_limit(self) -> float:
        """[N] the largest wall force a planned curve may take (``force_limit``)."""
        return force_limit()

    def rod_miss(self, setting, out: float, knob: float, twist: float, p_T, n_T) -> tuple[float, float]:
        """The rod's statics (the catheter's wall: rigid or compliant) at the sheath ``setting``,
        pushed out from the hand's shortest to ``out`` in ``ROD_CHECK_STEP`` at the knob and the
        twist at the exit: (its electrode's distance from a touch of the target [m], 0 when it
        touches (``target_contact.targets_touched``, its whole surface); the rod's total wall force
        [N]); (inf, inf) when a solve does not converge."""
        if self._rod is None:
            statics = CompliantRodStatics if self.catheter.wall_stiffness > 0 else RodStatics
            self._rod = statics(self.catheter, self._p_S + self.sheath.nominal_advance * self._R_S[:, 2],
                                self._R_S[:, 2], self.sdf)
        rod, cat = self._rod, self.catheter
        rod.p_E, rod.R_E, _ = self.sheath.exit_pose(self._p_S, self._R_S, *setting)
        rod._last_pose, q, sol = None, None, None
        for length in np.append(np.arange(self.min_out, out - 1e-9, ROD_CHECK_STEP), out):
            sol = rod.solve(float(length), float(twist), cat.curvature(knob), q0=q)
            if not sol.converged:
                return np.inf, np.inf
            q = sol.q
        c, d = sol.pose.tip_centre, sol.pose.tip_direction
        p_T, n_T = np.asarray(p_T, float)[None], np.asarray(n_T, float)[None]
        force = float(sol.wall_forces.sum()) if len(sol.wall_forces) else 0.0
        if targets_touched(c, p_T, n_T, cat.radius, self.target_radius,
                           axis_start=axis_start(c, d, cat.radius, CATHETER_ELECTRODE_LENGTH))[0]:
            return 0.0, force
        return float(self._touch_miss(c, p_T[0], n_T[0])), force

    def approach(self, p_T, n_T) -> tuple[float, float, float]:
        """The catheter's curve the hand sets at the planned setting before the operator steers
        again (the re-approach after a pull-back, ``ManualHand``): (push out of the sheath [m],
        knob, twist about the exit's axis [rad]) of the unloaded shape nearest a touch of the
        target, the shortest and least bent of the equals (a clinician dials the curve they know
        reaches the target and advances the catheter about as far as the target lies from the
        sheath's tip, not as far as it was out before: with the exit facing the wall a few mm
        away, the old length drove the rod into the wall)."""
        p_T, n_T = np.asarray(p_T, float), np.asarray(n_T, float)
        coarse = self._coarse(p_T, n_T)
        if self._refines(coarse, p_T, n_T):  # the refined setting's curve (``refine``)
            return self.refine(coarse, p_T, n_T)[2:]
        _, out, knob, twist = self._best_shape(coarse, p_T, n_T)
        return out, knob, twist

    def _refines(self, coarse, p_T, n_T) -> bool:
        """Whether the plan refines the coarse ``setting`` for the target (``refine``): its
        coarse shapes miss the target (the fixed sheath's setting, kept, only its curve), or, for a
        moved sheath, the rod of its coarse nearest curve does (``rod_miss``: the unloaded shape
        touches, the rod against the wall does not)."""
        if self.miss(coarse, p_T, n_T) > 0.0:
            return True
        if coarse == self.nominal or self.sdf is None or self.catheter.wall_mu > 0:
            return False
        key = (tuple(np.round(p_T, 9)), tuple(np.round(coarse, 12)))
        if key not in self._rod_misses:
            _, out, knob, twist = self._best_shape(coarse, p_T, n_T)
            self._rod_misses[key] = self.rod_miss(coarse, max(out, self.min_out), knob, twist, p_T, n_T)[0] > 0.0
        return self._rod_misses[key]

    def dials(self, p_T, n_T) -> bool:
        """Whether the hand dials the plan's curve (``approach``) for the target with the sheath
        where it is: the fixed sheath's setting kept (``PLAN_KEEP``) while its coarse shapes miss
        the target and the refined ones (``refine``) touch it (``ManualHand``)."""
        p_T, n_T = np.asarray(p_T, float), np.asarray(n_T, float)
        coarse = self._coarse(p_T, n_T)
        return coarse == self.nominal and self._refines(coarse, p_T, n_T) and self.refine(coarse, p_T, n_T)[0] == 0.0

    def plan(self, p_T, n_T, keep: bool = True) -> tuple:
        """The sheath setting (advance [m], rotation [rad], deflection [rad]) for the target
        (``keep``: the fixed sheath's setting when its shapes reach; else a deflected one): the
        coarse grid's (``_coarse``), refined locally (``refine``) when its shapes miss the target
        (the fixed sheath's setting stays: only its curve is refined)."""
        p_T, n_T = np.asarray(p_T, float), np.asarray(n_T, float)
        coarse = self._coarse(p_T, n_T, keep)
        return self.refine(coarse, p_T, n_T)[1] if self._refines(coarse, p_T, n_T) else coarse

    def _coarse(self, p_T, n_T, keep: bool = True) -> tuple:
        """The coarse grid's sheath setting for the target (``plan`` before ``refine``)."""
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
