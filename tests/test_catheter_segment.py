"""The catheter rod's resolution and its tip's stiffening (issue 45): the segment length chosen by
a convergence test (the tip within 1 % of the 1 mm solution), the tip's path continuous as the
catheter is pushed out with the knob bent, and the tip's EI growing with its bend by the cited fit."""

from __future__ import annotations

import numpy as np
import pytest

from ballchain.drake_models.steerable_catheter import TIP_FIT_MAX_BEND, SteerableCatheter
from ballchain.optimization.rod_statics import RodStatics

AXIS = np.array([1.0, 0.0, 0.0])
# (length out [m], knob, tip force [N]): bends on both tendons, loads across and along the tip.
CASES = [(55e-3, 1.0, None), (110e-3, 1.0, None), (80e-3, -1.0, None), (60e-3, 0.0, [0.0, 0.1, 0.0]),
         (70e-3, 0.5, [0.0, 0.0, -0.1]), (100e-3, 0.3, [-0.2, 0.2, 0.0])]


def _tips(h):
    cat = SteerableCatheter(segment_length=h).validate()
    rod = RodStatics(cat, np.zeros(3), AXIS)
    out = []
    for length, knob, force in CASES:
        sol = rod.solve(length, 0.3, cat.curvature(knob), force=force, max_iterations=500)
        assert sol.converged
        out.append(sol.pose.tip_centre + cat.radius * sol.pose.tip_direction)
    return np.array(out)


def test_the_segment_length_puts_the_tip_within_one_percent_of_the_1_mm_solution():
    """Each case's tip at the default segment length within 1 % (of its distance from the exit)
    of the 1 mm solution; 4 mm, the earlier default, is not (1.15 % at a half knob under a 0.1 N
    side load)."""
    reference = _tips(1e-3)
    scale = np.linalg.norm(reference, axis=1)
    default = SteerableCatheter().segment_length
    errors = np.linalg.norm(_tips(default) - reference, axis=1) / scale
    assert errors.max() < 0.01, errors
    coarse = np.linalg.norm(_tips(4e-3) - reference, axis=1) / scale
    assert coarse.max() > 0.01


def test_pushing_out_with_the_knob_bent_moves_the_tip_continuously():
    """Full D knob, pushed from 20 to 60 mm out in 0.25 mm steps: the tip moves at most about 4
    times the push per step (the bent segment's lever), no joint's bend appearing at once (a
    whole 3 mm joint at full knob would turn the tip by 0.17 rad: a jump of about 9 mm)."""
    cat = SteerableCatheter().validate()
    rod = RodStatics(cat, np.zeros(3), AXIS)
    kappa, q, tips = cat.curvature(1.0), None, []
    step = 0.25e-3
    for length in np.arange(20e-3, 60e-3, step):
        sol = rod.solve(length, 0.0, kappa, q0=q)
        q = sol.q
        tips.append(sol.pose.tip_centre + cat.radius * sol.pose.tip_direction)
    jumps = np.linalg.norm(np.diff(tips, axis=0), axis=1)
    assert jumps.max() < 5 * step, jumps.max()


def test_the_tip_stiffens_with_its_bend_by_the_cited_fit():
    """EI(Phi) / EI(0) = (2.5 Phi^7.2 + 4.4) / 4.4 (Khoshnam and Patel): 1.57 at 1 rad, held at
    the fit's last measured bend (1.1 rad) beyond it, 1 at no bend or with the stiffening off;
    the rod's deflectable joints carry it, the shaft's do not."""
    cat = SteerableCatheter().validate()
    one_rad = 1.0 / cat.deflectable_length
    assert cat.tip_EI_factor(one_rad) == pytest.approx((2.5 + 4.4) / 4.4, rel=1e-12)
    assert cat.tip_EI_factor(-one_rad) == cat.tip_EI_factor(one_rad)
    held = (2.5 * TIP_FIT_MAX_BEND**7.2 + 4.4) / 4.4
    assert cat.tip_EI_factor(cat.curvature(1.0)) == pytest.approx(held) == pytest.approx(2.13, abs=0.01)
    assert cat.tip_EI_factor(0.0) == 1.0
    assert SteerableCatheter(tip_stiffening=False).tip_EI_factor(one_rad) == 1.0
    rod = RodStatics(cat, np.zeros(3), AXIS)
    soft, stiff = rod.stiffness(0, 0.0).reshape(-1, 3), rod.stiffness(0, one_rad).reshape(-1, 3)
    inside = rod.frac == 1.0
    np.testing.assert_allclose(stiff[inside, :2], soft[inside, :2] * cat.tip_EI_factor(one_rad), rtol=1e-12)
    np.testing.assert_array_equal(stiff[rod.frac == 0.0], soft[rod.frac == 0.0])
    # Under the same side load, a bent tip gives less: its deflection from the unloaded bend.
    kappa = cat.curvature(0.4)
    free = rod.solve(50e-3, 0.0, kappa).pose.tip_centre
    loaded = rod.solve(50e-3, 0.0, kappa, force=[0.0, 0.0, 0.05]).pose.tip_centre
    rod_soft = RodStatics(SteerableCatheter(tip_stiffening=False).validate(), np.zeros(3), AXIS)
    loaded_soft = rod_soft.solve(50e-3, 0.0, kappa, force=[0.0, 0.0, 0.05]).pose.tip_centre
    assert np.linalg.norm(loaded - free) < np.linalg.norm(loaded_soft - free) / 1.2
