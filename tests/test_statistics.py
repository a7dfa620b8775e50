"""The closed-loop rows' intervals (ballchain/intervals.py) against cases with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from ballchain.infrastructure.errors import UserInputError
from ballchain.intervals import (agrees, difference_interval, interval, paired_interval, proportion_interval,
                                 side_agrees)


@pytest.mark.parametrize("statistic", ["mean", "median"])
def test_coverage_of_the_true_centre_on_normal_samples(statistic):
    """200 samples of 20 normal values: the 95 % interval holds the true mean (= median) in about
    95 % of them. Binomial sd of the coverage over 200: 1.5 %; the bootstrap undercovers a little
    at n = 20 (about 1-3 %): accepted 0.88-0.99."""
    rng = np.random.default_rng(43)
    hits = sum(interval(rng.normal(5.0, 2.0, 20), statistic, n_resamples=2000).contains(5.0) for _ in range(200))
    assert 0.88 <= hits / 200 <= 0.99, hits


def test_mean_interval_matches_the_t_interval():
    """For 40 normal values the BCa interval of the mean is close to the textbook t interval (within 15 % of its width)."""
    x = np.random.default_rng(1).normal(10.0, 3.0, 40)
    iv = interval(x, "mean")
    t = stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=stats.sem(x))
    width = t[1] - t[0]
    assert iv.method == "BCa"
    assert abs(iv.lo - t[0]) < 0.15 * width and abs(iv.hi - t[1]) < 0.15 * width, (iv, t)


def test_degenerate_and_single_samples_are_the_point():
    iv = interval([20, 20, 20, 20])
    assert (iv.value, iv.lo, iv.hi, iv.method, iv.n) == (20.0, 20.0, 20.0, "degenerate", 4)
    assert agrees(20, iv) and not agrees(19.999, iv)
    one = interval([3.5])
    assert (one.lo, one.hi, one.n) == (3.5, 3.5, 1)
    mostly = interval([20, 20, 19, 20, 20, 20])  # BCa fails here (scipy: nan); the median's percentile interval
    assert mostly.method == "percentile" and 19.0 <= mostly.lo <= 20.0 == mostly.hi


def test_seeded_reproducible():
    x = np.random.default_rng(2).exponential(3.0, 12)
    assert interval(x, "mean") == interval(list(x), "mean")
    assert interval(x, "mean", seed=1) != interval(x, "mean", seed=2)  # (a median's bounds are sample points)


def test_paired_sees_what_unpaired_cannot():
    """Two arms whose seeds share a large common part: b = a + 1 + small noise. The paired
    interval of the differences excludes 0 (and holds -1); the unpaired one, swamped by the
    seeds' spread, holds 0."""
    rng = np.random.default_rng(3)
    a = rng.normal(40.0, 10.0, 10)
    b = a + 1.0 + rng.normal(0.0, 0.2, 10)
    paired = paired_interval(a, b, "mean")
    unpaired = difference_interval(a, b, "mean")
    assert paired.paired and paired.hi < 0 and paired.contains(-1.0)
    assert side_agrees(paired, "lower") and not side_agrees(paired, "similar")
    assert unpaired.contains(0.0) and side_agrees(unpaired, "similar") and not side_agrees(unpaired, "lower")
    assert unpaired.hi - unpaired.lo > 10 * (paired.hi - paired.lo)


def test_proportion_is_clopper_pearson():
    iv = proportion_interval(5, 5)
    assert iv.hi == 1.0 and abs(iv.lo - 0.025 ** (1 / 5)) < 1e-9  # all n: lower bound (alpha/2)^(1/n)
    zero = proportion_interval(0, 20)
    assert zero.lo == 0.0 and abs(zero.hi - (1 - 0.025 ** (1 / 20))) < 1e-9


def test_text_and_dict():
    iv = interval([38.0, 41.0, 40.5, 44.0, 39.0, 42.0])
    assert iv.text().startswith("40.8 [95 % CI ") and iv.text().endswith("(6 seeds)")
    d = iv.to_dict()
    assert d["values"] == [38.0, 41.0, 40.5, 44.0, 39.0, 42.0] and d["n"] == 6 and d["statistic"] == "median"


@pytest.mark.parametrize("call", [lambda: interval([]), lambda: interval([1.0, float("nan")]),
                                  lambda: interval([1, 2], "mode"), lambda: interval([1, 2], confidence=1.5),
                                  lambda: paired_interval([1, 2], [1]), lambda: proportion_interval(3, 2),
                                  lambda: side_agrees(interval([1, 2]), "faster")])
def test_bad_input(call):
    with pytest.raises(UserInputError):
        call()


def test_the_docstring_example_runs():
    import doctest

    import ballchain.intervals as module

    results = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert results.attempted >= 2 and results.failed == 0, results
