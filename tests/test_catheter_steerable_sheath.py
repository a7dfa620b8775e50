"""The steerable sheath of the manual arm (issue 45, item 4): its exit's closed-form geometry and
the catheter riding in it (``drake_models.sheath.SteerableSheath``,
``SteerableCatheterSystem(sheath=...)``)."""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from ballchain.drake_models.sheath import SteerableSheath
from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.infrastructure.errors import UserInputError
from ballchain.systems.catheter_station import SteerableCatheterSystem


def test_exit_closed_forms():
    s = SteerableSheath().validate()
    L = s.deflectable_length
    # Full deflection over the whole deflectable length: a half circle, 2 L / pi across, axis reversed.
    p, R, line = s.exit_pose(np.zeros(3), np.eye(3), L, 0.0, math.pi, 400)
    np.testing.assert_allclose(p, [2 * L / math.pi, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(R[:, 2], [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)  # a rotation
    # The centreline keeps its length (an arc, not a jump), within the chord's error at 400 points.
    assert abs(np.linalg.norm(np.diff(line, axis=0), axis=1).sum() - L) < 1e-6
    # A quarter turn rotated by 90 degrees: the bend in the y-z plane, 2 L / pi each way.
    p, R, _ = s.exit_pose(np.zeros(3), np.eye(3), L, math.pi / 2, math.pi / 2)
    np.testing.assert_allclose(p, [0.0, 2 * L / math.pi, 2 * L / math.pi], atol=1e-12)
    np.testing.assert_allclose(R[:, 2], [0.0, 1.0, 0.0], atol=1e-12)
    # Advanced beyond the deflectable length: a straight part, then the arc.
    p, R, _ = SteerableSheath(max_advance=60e-3).exit_pose(np.zeros(3), np.eye(3), L + 5e-3, 0.0, math.pi)
    np.testing.assert_allclose(p, [2 * L / math.pi, 0.0, 5e-3], atol=1e-12)
    # Less out than the deflectable length: only what is out bends.
    p, R, _ = s.exit_pose(np.zeros(3), np.eye(3), 0.5 * L, 0.0, math.pi)
    np.testing.assert_allclose(R[:, 2], [1.0, 0.0, 0.0], atol=1e-12)


def test_bad_sheath_is_refused():
    with pytest.raises(UserInputError, match="max_deflection"):
        SteerableSheath(max_deflection=4.0).validate()
    with pytest.raises(UserInputError, match="nominal_advance"):
        SteerableSheath(nominal_advance=50e-3).validate()
    with pytest.raises(UserInputError, match="sheath"):
        SteerableCatheterSystem(SteerableCatheter(), np.zeros(3), [0.0, 0.0, 1.0], None, sheath="agilis")


def _tip_after(system, handle, sheath=None, t=0.2):
    sim = Simulator(system)
    ctx = sim.get_mutable_context()
    system.GetInputPort("handle").FixValue(ctx, handle)
    if sheath is not None:
        system.GetInputPort("sheath").FixValue(ctx, sheath)
    sim.AdvanceTo(t)
    return system.GetOutputPort("tip_position").Eval(ctx)


def test_catheter_rides_in_the_sheath():
    """In free space the rod's shape relative to its exit does not depend on where the exit is:
    the tip, seen from the deflected sheath's exit in the exit's frame, is where it is from the
    fixed exit (the knob bent, so the check sees the frame's turn too)."""
    cat = SteerableCatheter(shaft_elements=2)
    axis = np.array([0.0, 0.0, 1.0])
    sheath = SteerableSheath()
    fixed = SteerableCatheterSystem(cat, np.zeros(3), axis, None, 30e-3)
    steer = SteerableCatheterSystem(cat, np.zeros(3), axis, None, 30e-3, sheath=sheath)
    handle = [0.0, 0.0, 0.6]
    tip_fixed = _tip_after(fixed, handle)
    # At its nominal advance and no deflection the steerable sheath's exit is the fixed one.
    np.testing.assert_allclose(_tip_after(steer, handle, [sheath.nominal_advance, 0.0, 0.0]), tip_fixed, atol=1e-9)
    state = [25e-3, 0.7, 2.0]
    tip = _tip_after(steer, handle, state)
    p_S = -sheath.nominal_advance * axis
    p, R, _ = sheath.exit_pose(p_S, fixed.rod.R_E, *state)
    np.testing.assert_allclose(steer.rod.p_E, p, atol=1e-12)
    np.testing.assert_allclose(steer.rod.R_E, R, atol=1e-12)
    seen_fixed = fixed.rod.R_E.T @ tip_fixed
    seen_steer = R.T @ (tip - p)
    np.testing.assert_allclose(seen_steer, seen_fixed, atol=1e-6)
    assert np.linalg.norm(tip - tip_fixed) > 10e-3  # the sheath moved the tip
