"""The catheter rod's compiled pose (``optimization/compiled_rod.py``) against its numpy
reference (``RodStatics.pose_reference``): the same floats, bit for bit, and the same memory
layout (the products that read the Jacobian take the reference's strides), over the free
joints' counts from none to all, twists of the shaft and joint angles far from straight."""

import numpy as np
import pytest

from ballchain.experiments import manual_catheter as mc
from ballchain.optimization.rod_statics import RodStatics


@pytest.fixture(scope="module")
def rod():
    return RodStatics(mc.comparison_catheter(), np.array([0.01, -0.02, 0.003]), np.array([0.2, 0.3, 1.0]), None)


@pytest.mark.parametrize("length", [0.0, 0.001, 0.0045, 0.02, 0.06, 0.119, 0.2])
def test_the_compiled_pose_is_the_reference_bit_for_bit(rod, length):
    rng = np.random.default_rng(int(length * 1e4))
    f = rod.n_joints - rod.first_free(length)
    for _ in range(20):
        q, phi = rng.normal(scale=0.3, size=3 * f), rng.uniform(-np.pi, np.pi)
        got, ref = rod._pose(q, length, phi), rod.pose_reference(q, length, phi)
        for name in ("nodes", "J", "J_rot", "R_tip", "base"):
            a, b = getattr(got, name), getattr(ref, name)
            assert a.shape == b.shape and a.strides == b.strides, name
            np.testing.assert_array_equal(a, b, err_msg=name)


def test_the_jacobian_is_the_nodes_derivative(rod):
    """An independent check of both: central differences of the nodes (step 1e-7 rad) against J
    within 1e-9 m per rad."""
    length, phi = 0.05, 0.4
    f = rod.n_joints - rod.first_free(length)
    q = np.random.default_rng(3).normal(scale=0.2, size=3 * f)
    J = rod._pose(q, length, phi).J
    for col in range(0, 3 * f, 5):
        dq = np.zeros(3 * f)
        dq[col] = 1e-7
        numeric = (rod.pose_reference(q + dq, length, phi).nodes - rod.pose_reference(q - dq, length, phi).nodes) / 2e-7
        np.testing.assert_allclose(J[:, :, col], numeric, atol=1e-9)


def test_the_remembered_answers_are_the_computed_ones():
    """``first_free``, ``share`` and ``rest`` remember their last answer with its arguments: over a
    sequence of lengths and curvatures that repeats and changes, each answer equals a fresh
    model's (which remembers nothing yet), bit for bit."""
    cat = mc.comparison_catheter()
    kept = RodStatics(cat, np.zeros(3), np.array([0.0, 0.0, 1.0]), None)
    sequence = [(0.02, 0.0), (0.02, 0.0), (0.0203, 0.0), (0.02, 30.0), (0.0215, 30.0), (0.0215, 30.0),
                (0.02, 0.0), (0.06, 12.5), (0.001, 12.5), (0.2, -8.0), (0.2, -8.0)]
    for with_length in (True, False):  # rest() with the length, then without (the whole first joint's share)
        for length, kappa in sequence:
            fresh = RodStatics(cat, np.zeros(3), np.array([0.0, 0.0, 1.0]), None)
            j0 = kept.first_free(length)
            assert j0 == fresh.first_free(length)
            assert kept.share(j0, length) == fresh.share(j0, length)
            at = length if with_length else None
            np.testing.assert_array_equal(kept.rest(j0, kappa, at), fresh.rest(j0, kappa, at))
