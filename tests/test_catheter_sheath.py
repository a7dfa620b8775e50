"""The shaft's friction where it bears on the sheath's bends (issue 45) against hand-solved cases:
the capstan through one circular bend, the windup's onset and the stick-slip jump, and the hand
that turns back from the torque it feels instead of at a scripted twist."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ballchain.drake_models.sheath import SheathPath, ShaftChain, axial_slip_force, capstan_ratio, shaft_chains
from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.infrastructure.errors import UserInputError

ONE_BEND = SheathPath(bend_radius=25e-3, bend_angles=(math.pi,), bend_ends=(0.0,))


def _axial(mu_s=0.3, mu_k=0.2, end_force=0.0, k=2000.0):
    return ShaftChain("axial", k, ONE_BEND, end_force, mu_s, mu_k, 1.33e-3)


def test_capstan_through_one_bend_by_hand():
    """A shaft pulled back through a half-turn bend against a distal pull T0, no end forces:
    it slides when the handle's tension reaches T0 exp(mu_s pi) (Euler-Eytelwein), slides on at
    T0 exp(mu_k pi); pushed forward, it slides at T0 exp(-mu pi)."""
    T0, chain = 1.0, _axial()
    x = chain.initial()
    onset = None
    for h in np.linspace(0.0, -3e-3, 3001):  # the handle drawn back 3 mm in 1 um steps
        before = x[1]
        x, slipped = chain.step(x, h, T0)
        tension = chain.forces(x)[0]
        if slipped and onset is None and x[1] < before:
            onset = chain.k * (before - h)  # the tension that broke it free
    assert onset == pytest.approx(T0 * math.exp(0.3 * math.pi), rel=2e-3)  # 1 um of handle: 2 mN of 2.6 N
    assert tension == pytest.approx(T0 * math.exp(0.2 * math.pi), abs=T0 * (math.exp(0.3 * math.pi)
                                                                            - math.exp(0.2 * math.pi)))
    assert axial_slip_force(ONE_BEND, 0.0, T0, -1.0, 0.2) == pytest.approx(T0 * capstan_ratio(0.2, math.pi), rel=1e-12)
    assert axial_slip_force(ONE_BEND, 0.0, T0, 1.0, 0.2) == pytest.approx(T0 / capstan_ratio(0.2, math.pi), rel=1e-12)


def test_stick_slip_sawtooth_by_hand():
    """Pulled on steadily, the shaft sticks until the tension reaches T0 exp(mu_s pi) and each
    slip drops it to T0 exp(mu_k pi): the distal end jumps by (exp(mu_s pi) - exp(mu_k pi)) T0 / k
    and the handle travels as much between slips (the sawtooth's tooth)."""
    T0, chain = 1.0, _axial(k=2000.0)
    jump = T0 * (math.exp(0.3 * math.pi) - math.exp(0.2 * math.pi)) / chain.k
    x = chain.initial()
    positions, slips_at = [], []
    for i, h in enumerate(np.linspace(0.0, -10e-3, 20001)):  # 0.5 um steps
        x, slipped = chain.step(x, h, T0)
        positions.append(x[1])
        if slipped:
            slips_at.append(h)
    jumps = -np.diff(positions)
    big = jumps[jumps > 1e-9]
    assert len(big) >= 3
    np.testing.assert_allclose(big[1:], jump, rtol=5e-3)  # after the first (from the unloaded start)
    np.testing.assert_allclose(-np.diff(slips_at[1:]), jump, rtol=5e-3)


def test_windup_onset_in_torsion_by_hand():
    """The handle twisted from rest, the shaft under a steady axial force T through the bends:
    the tip turns once the handle leads by mu_s r (4 P + |T| theta) / k (P = 2 EI / R^2 at each
    bend end, two bends), then lags by the kinetic lead; the lead grows with the shaft's tension
    (the capstan's normal force)."""
    cat = SteerableCatheter(sheath_friction="bends").validate()
    twist, push = cat.chains()
    path = cat.sheath
    P = 2 * cat.shaft_EI / path.bend_radius**2
    k = cat.shaft_GJ / (cat.shaft_length - path.bearing_length)
    for T in (0.0, 2.0):
        expected = cat.mu_static * cat.radius * (4 * P + T * path.total_angle) / k
        x = twist.initial()
        onset = None
        for h in np.arange(0.0, 2.0, 1e-4):
            x, slipped = twist.step(x, h, 0.0, T)
            if slipped and onset is None:
                onset = h
        assert onset == pytest.approx(expected, abs=1.1e-4)
        kinetic = cat.mu_kinetic * cat.radius * (4 * P + T * path.total_angle) / k
        assert kinetic - 1e-12 <= x[0] - x[1] <= expected + 1e-12  # between a slip's end and the next
    assert twist.lead(cat.mu_static, 2.0) > twist.lead(cat.mu_static, 0.0)
    # The figures the docs quote: about 48 deg static, 32 deg kinetic, unloaded.
    assert math.degrees(twist.lead(cat.mu_static)) == pytest.approx(47.7, abs=0.1)
    assert math.degrees(twist.lead(cat.mu_kinetic)) == pytest.approx(31.8, abs=0.1)


def test_bad_sheath_is_refused():
    with pytest.raises(UserInputError, match="bend_angles"):
        SheathPath(bend_angles=(1.0,), bend_ends=(0.0, 0.1)).validate()
    with pytest.raises(UserInputError, match="bend_ends"):
        SheathPath(bend_angles=(1.0, 1.0), bend_ends=(0.0, 0.01)).validate()  # overlapping bends
    with pytest.raises(UserInputError, match="sheath_friction"):
        SteerableCatheter(sheath_friction="spread").validate()
    with pytest.raises(UserInputError, match="kind"):
        ShaftChain("bending", 1.0, ONE_BEND, 0.0, 0.2, 0.1, 1e-3)
    twist, push = shaft_chains(1e-3, 1e3, 1e-3, 1e-3, 1.0, 0.2, 0.1, SheathPath())
    assert twist.kind == "torsion" and push.kind == "axial"
