"""The electrode's touch of a target (issue 45): the whole surface of the catheter's distal
electrode (cylinder and dome), the ball chain's tip ball as before, one rule for both."""

from __future__ import annotations

import numpy as np
import pytest

from ballchain.drake_models.electrode import CATHETER_ELECTRODE_LENGTH, axis_start, touches
from ballchain.systems.target_contact import TOUCH_TOLERANCE, targets_touched

R, RT, TOL = 4e-3 / 3, 2.5e-3, TOUCH_TOLERANCE


def _sampled(a, b, p_WT, n_W, radius, target_radius, tol, samples=4001):
    """The rule by brute force: axis points at ``samples`` s in [0, 1]."""
    s = np.linspace(0.0, 1.0, samples)[:, None]
    x = a[None, :] + s * (b - a)[None, :]
    out = []
    for p, n in zip(p_WT, n_W):
        rel = x - p
        h = rel @ n
        lat2 = (rel * rel).sum(axis=1) - h * h
        out.append(bool(np.any((np.abs(h) <= radius + tol) & (lat2 <= target_radius**2))))
    return np.array(out)


def test_a_ball_is_the_robotic_rule_exactly():
    """With no axis (a ball), the result is the sphere test's expressions, bit for bit, at random
    tip positions about random targets."""
    rng = np.random.default_rng(0)
    p_WT = rng.normal(size=(50, 3)) * 0.02
    n_W = rng.normal(size=(50, 3))
    n_W /= np.linalg.norm(n_W, axis=1, keepdims=True)
    for _ in range(200):
        tip = p_WT[rng.integers(50)] + rng.normal(size=3) * 3e-3
        rel = tip - p_WT
        h = (rel * n_W).sum(axis=1)
        lateral2 = (rel * rel).sum(axis=1) - h * h
        old = (np.abs(h) <= R + TOL) & (lateral2 <= RT**2)
        np.testing.assert_array_equal(targets_touched(tip, p_WT, n_W, R, RT), old)
        np.testing.assert_array_equal(touches(tip, p_WT, n_W, R, RT, TOL, a=tip.copy()), old)


def test_an_electrode_lying_on_the_target_touches_with_its_side():
    """An electrode parallel to the wall, resting on it, its dome 3 mm beyond the target's edge
    and its side over the target: touched; its tip sphere alone would not be; the same electrode
    held 1 mm off the wall: not touched."""
    p_WT, n_W = np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]])
    direction = np.array([1.0, 0.0, 0.0])
    centre = np.array([RT + 0.4e-3 + R, 0.0, R])  # the dome's side 0.4 mm past the circle
    a = axis_start(centre, direction, R, CATHETER_ELECTRODE_LENGTH)
    assert a[0] == pytest.approx(centre[0] - (CATHETER_ELECTRODE_LENGTH - R))
    assert touches(centre, p_WT, n_W, R, RT, TOL, a)[0]
    assert not touches(centre, p_WT, n_W, R, RT, TOL)[0]
    lifted = np.array([0.0, 0.0, TOL + 1e-3])
    assert not touches(centre + lifted, p_WT, n_W, R, RT, TOL, a + lifted)[0]


def test_the_rule_matches_a_brute_force_sampling_of_the_axis():
    """Random electrodes about random targets (near the decision's edge): the closed-form rule
    agrees with a 4001-point sampling of the axis except within the sampling's resolution."""
    rng = np.random.default_rng(1)
    p_WT = rng.normal(size=(30, 3)) * 0.01
    n_W = rng.normal(size=(30, 3))
    n_W /= np.linalg.norm(n_W, axis=1, keepdims=True)
    disagree = 0
    for _ in range(300):
        k = rng.integers(30)
        b = p_WT[k] + n_W[k] * rng.uniform(0.0, 3 * R) + rng.normal(size=3) * 2e-3
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        a = axis_start(b, d, R, CATHETER_ELECTRODE_LENGTH)
        exact = touches(b, p_WT, n_W, R, RT, TOL, a)
        sampled = _sampled(a, b, p_WT, n_W, R, RT, TOL)
        assert np.all(sampled <= exact)  # a sampled touch is a touch
        disagree += int(np.count_nonzero(exact != sampled))
    assert disagree <= 3  # touches only between samples 0.5 um apart
