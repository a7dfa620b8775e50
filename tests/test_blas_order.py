"""The kernels' dot product sums as this machine's BLAS does (``kernels/_blas_order``)."""

import numpy as np
from numba import njit

from ballchain.drake_models.kernels import _blas_order
from ballchain.drake_models.kernels import actuation as K


def test_the_probe_names_one_known_order_here():
    # "other" would mean numpy's ddot is neither left-to-right sum: the kernels could not mirror it.
    assert _blas_order.ORDER in ("fma", "plain")
    assert _blas_order.DDOT_FMA == (_blas_order.ORDER == "fma")


def test_the_kernels_dot_is_numpys_bit_for_bit():
    rng = np.random.default_rng(7)
    for n in (2, 3, 4):
        for _ in range(500):
            a, b = rng.normal(size=n), rng.normal(size=n) * 10.0 ** rng.integers(-6, 6)
            assert K._blas_dot(a, b) == a.dot(b)
    q = rng.normal(size=(500, 4))
    for v in q:  # the normalised quaternion of the magnet units: numpy's norm, divided
        assert np.array_equal(K.normalised(v), v / np.sqrt(v.dot(v)))


def test_the_compiled_fma_rounds_once():
    compiled = njit(lambda a, b, c: _blas_order.fma(a, b, c))
    rng = np.random.default_rng(3)
    differs = 0
    for a, b, c in rng.normal(size=(2000, 3)):
        exact = _blas_order._exact_fma(float(a), float(b), float(c))
        assert compiled(a, b, c) == exact
        differs += exact != a * b + c
    assert differs > 100  # the cases where one rounding and two differ: the check can tell them apart
