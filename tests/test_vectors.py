"""The small vector rules of ``drake_models/vectors.py`` against numpy's own."""

from __future__ import annotations

import numpy as np
import pytest

from ballchain.drake_models.vectors import angle_between, cross


@pytest.mark.parametrize("shape_a, shape_b", [((3,), (3,)), ((1, 30, 3), (31, 30, 3)), ((3,), (12, 3)),
                                              ((12, 3), (3,)), ((12, 3), (12, 3))])
def test_cross_is_numpys_bit_for_bit(shape_a, shape_b):
    """``cross`` (the units' controllers, the catheter mapping, the rod statics) gives np.cross's
    floats, on the plain-float path of two 3-vectors and the broadcast one, across magnitudes."""
    rng = np.random.default_rng(7)
    for _ in range(300 if shape_a == shape_b == (3,) else 10):
        scale_a, scale_b = 10.0 ** rng.uniform(-9, 9, size=2)
        a, b = scale_a * rng.normal(size=shape_a), scale_b * rng.normal(size=shape_b)
        expected = np.cross(a, b)
        got = cross(a, b)
        assert got.shape == expected.shape and got.dtype == np.float64
        assert np.array_equal(got, expected)


def test_angle_between_is_the_atan2_of_the_cross_and_dot_products():
    """Against the arccos of the normalised dot product away from 0 and pi (1e-12 rad), and exact
    near them where arccos loses the digits: 1e-9 rad apart is 1e-9 rad."""
    rng = np.random.default_rng(3)
    u, v = rng.normal(size=(2, 200, 3))
    expected = np.arccos(np.einsum("ij,ij->i", u, v) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1))
    assert np.allclose(angle_between(u, v), expected, rtol=0.0, atol=1e-12)
    assert np.allclose([angle_between(a, b) for a, b in zip(u, v)], expected, rtol=0.0, atol=1e-12)
    a = np.array([1.0, 0.0, 0.0])
    assert angle_between(a, np.array([np.cos(1e-9), np.sin(1e-9), 0.0])) == pytest.approx(1e-9, rel=1e-12)
    assert angle_between(a, np.array([-np.cos(1e-9), np.sin(1e-9), 0.0])) == pytest.approx(np.pi - 1e-9, rel=1e-15)
