"""One home for the confidence interval of a closed-loop result over seeds, and the verdict rule.

A closed-loop row (teleoperation, robotic vs manual, navigator vs operator, ring isolation) is a
statistic over operator or noise seeds. Its 95 % interval is a bootstrap interval
(``scipy.stats.bootstrap``; Efron & Tibshirani 1993, *An Introduction to the Bootstrap*, Chapman &
Hall), seeded (``SEED``) so that the same values give the same interval:

* the **mean**: bias-corrected and accelerated (BCa), the percentile interval when BCa cannot be
  computed (its jackknife acceleration is 0/0 on a sample of few distinct values);
* the **median**: the percentile interval (BCa's jackknife is unreliable for the median of small
  samples, DiCiccio & Efron 1996, *Statistical Science* 11(3));
* **paired** (``paired_interval``): the statistic of the per-seed differences a_i - b_i, where
  the same seed drives both arms; **unpaired** (``difference_interval``): the difference of the
  two arms' statistics, each arm resampled on its own;
* a **proportion** (k of n runs, e.g. rings isolated): the exact Clopper-Pearson interval
  (``scipy.stats.binomtest``), which the bootstrap of 0/1 values would shrink to a point when
  every run agrees.

A sample whose values are all equal (or of one value) has the point as its interval (``method``
says "degenerate"): nothing varies, nothing to resample.

The verdict rule (``agrees``, ``side_agrees``): a row agrees with the paper only when the paper's
number lies inside the interval; a comparison row (e.g. "the robot is faster than the hand") only
when the interval of the paired difference excludes 0 on the paper's side; a "similar" claim
only when 0 lies inside it. Few seeds give wide intervals: a row then agrees easily and says so
with its ``n``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

from ballchain.infrastructure.errors import UserInputError, short_repr

CONFIDENCE = 0.95
N_RESAMPLES = 9999  # bootstrap resamples (the Monte Carlo error of a 95 % bound: well below the seeds' spread)
SEED = 0  # the resampling's seed: the same values give the same interval
STATISTICS = ("median", "mean")
SIDES = ("lower", "higher", "similar")


@dataclass(frozen=True)
class Interval:
    """A statistic over seeds and its confidence interval.

    Attributes:
        statistic: "median", "mean", "proportion" (of the runs) or "median difference" / "mean
            difference" (paired: of the per-seed differences; unpaired: of the arms' statistics).
        value: the statistic of the sample.
        lo, hi: the interval's bounds.
        n: the seeds (runs) it rests on (unpaired: the smaller arm's).
        confidence: the interval's level (0.95).
        method: "BCa", "percentile", "Clopper-Pearson" or "degenerate" (every value equal: the point).
        paired: the difference of paired arms (the same seeds).
        values: the per-seed values (paired: the differences), as given.
    """

    statistic: str
    value: float
    lo: float
    hi: float
    n: int
    confidence: float = CONFIDENCE
    method: str = "percentile"
    paired: bool = False
    values: tuple = ()

    def contains(self, x: float) -> bool:
        """Whether ``x`` lies inside the interval (bounds included)."""
        return self.lo <= float(x) <= self.hi

    def text(self, fmt: str = "{:.3g}", unit: str = "") -> str:
        """As "median [95 % CI lo, hi] (n seeds)", e.g. "41.2 [38.0, 47.5] (6 seeds)"."""
        u = f" {unit}" if unit else ""
        return (f"{fmt.format(self.value)}{u} [{100 * self.confidence:.0f} % CI {fmt.format(self.lo)}, "
                f"{fmt.format(self.hi)}] ({self.n} seed{'s' if self.n != 1 else ''})")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["values"] = list(self.values)
        return d


def _sample(values, what: str) -> np.ndarray:
    try:
        x = np.asarray([float(v) for v in values], dtype=float)
    except (TypeError, ValueError):
        raise UserInputError(f"{what} must be a list of numbers, got {short_repr(values)}") from None
    if x.size == 0:
        raise UserInputError(f"{what} must hold at least one value, got none")
    if not np.all(np.isfinite(x)):
        raise UserInputError(f"{what} must be finite numbers, got {short_repr(values)}")
    return x


def _check(statistic: str, confidence: float) -> None:
    if statistic not in STATISTICS:
        raise UserInputError(f"statistic must be one of {STATISTICS}, got {short_repr(statistic)}")
    if isinstance(confidence, bool) or not isinstance(confidence, (int, float)) or not 0.5 <= confidence < 1.0:
        raise UserInputError(f"confidence must be a level in [0.5, 1), got {short_repr(confidence)}")


def _function(statistic: str):
    return np.median if statistic == "median" else np.mean


def _bootstrap(data: tuple, fn, statistic: str, confidence: float, paired: bool, n_resamples: int,
               seed: int) -> tuple[float, float, str]:
    """(lo, hi, method) of scipy's bootstrap: BCa for the mean (percentile when BCa fails), percentile for the median."""
    methods = ("BCa", "percentile") if statistic == "mean" else ("percentile",)
    for method in methods:
        with warnings.catch_warnings():  # BCa's 0/0 on a sample of few distinct values: the fallback below
            warnings.simplefilter("ignore", RuntimeWarning)
            warnings.simplefilter("ignore", getattr(stats, "DegenerateDataWarning", RuntimeWarning))
            res = stats.bootstrap(data, fn, confidence_level=confidence, n_resamples=n_resamples, method=method,
                                  paired=paired, vectorized=True, axis=-1, random_state=np.random.default_rng(seed))
        lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
        if math.isfinite(lo) and math.isfinite(hi):
            return lo, hi, method
    raise RuntimeError("the bootstrap gave no interval")  # percentile always gives one on finite data


def interval(values, statistic: str = "median", *, confidence: float = CONFIDENCE, n_resamples: int = N_RESAMPLES,
             seed: int = SEED) -> Interval:
    """The bootstrap interval of the median (or mean) of ``values`` (one per seed).

    Example:
        >>> from ballchain.intervals import interval
        >>> iv = interval([38.0, 41.0, 40.5, 44.0, 39.0, 42.0])
        >>> iv.value, iv.n, iv.lo <= iv.value <= iv.hi
        (40.75, 6, True)
    """
    _check(statistic, confidence)
    x = _sample(values, "values")
    fn = _function(statistic)
    value = float(fn(x))
    if np.all(x == x[0]):
        return Interval(statistic, value, value, value, int(x.size), confidence, "degenerate", False, tuple(x.tolist()))
    lo, hi, method = _bootstrap((x,), fn, statistic, confidence, False, n_resamples, seed)
    return Interval(statistic, value, lo, hi, int(x.size), confidence, method, False, tuple(x.tolist()))


def paired_interval(a, b, statistic: str = "median", **kwargs) -> Interval:
    """The interval of the median (or mean) of the per-seed differences ``a[i] - b[i]`` (the same
    seed drove both arms: ``a`` and ``b`` in the same seed order)."""
    xa, xb = _sample(a, "a"), _sample(b, "b")
    if xa.size != xb.size:
        raise UserInputError(f"paired arms must have a value per seed each, got {xa.size} and {xb.size} values")
    iv = interval(xa - xb, statistic, **kwargs)
    return Interval(f"{statistic} difference", iv.value, iv.lo, iv.hi, iv.n, iv.confidence, iv.method, True,
                    iv.values)


def difference_interval(a, b, statistic: str = "median", *, confidence: float = CONFIDENCE,
                        n_resamples: int = N_RESAMPLES, seed: int = SEED) -> Interval:
    """The interval of statistic(a) - statistic(b) for independent arms (each resampled on its own)."""
    _check(statistic, confidence)
    xa, xb = _sample(a, "a"), _sample(b, "b")
    fn = _function(statistic)
    value = float(fn(xa) - fn(xb))
    n = int(min(xa.size, xb.size))
    if np.all(xa == xa[0]) and np.all(xb == xb[0]):
        return Interval(f"{statistic} difference", value, value, value, n, confidence, "degenerate")

    def diff(x, y, axis=-1):
        return fn(x, axis=axis) - fn(y, axis=axis)

    lo, hi, method = _bootstrap((xa, xb), diff, statistic, confidence, False, n_resamples, seed)
    return Interval(f"{statistic} difference", value, lo, hi, n, confidence, method)


def proportion_interval(k: int, n: int, *, confidence: float = CONFIDENCE) -> Interval:
    """The exact (Clopper-Pearson) interval of a proportion: ``k`` of ``n`` runs."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise UserInputError(f"n (runs) must be a positive integer, got {short_repr(n)}")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k <= n:
        raise UserInputError(f"k (runs with the outcome) must be an integer in 0..{n}, got {short_repr(k)}")
    _check("mean", confidence)
    ci = stats.binomtest(int(k), int(n)).proportion_ci(confidence_level=confidence, method="exact")
    return Interval("proportion", k / n, float(ci.low), float(ci.high), int(n), confidence, "Clopper-Pearson",
                    False, tuple([1.0] * int(k) + [0.0] * int(n - k)))


def agrees(paper_value, iv: Interval) -> bool | None:
    """The report's verdict on a row: the paper's number lies inside the interval (None: no paper number)."""
    if paper_value is None or isinstance(paper_value, bool) or not isinstance(paper_value, (int, float)):
        return None
    return iv.contains(paper_value)


def side_agrees(iv: Interval, side: str) -> bool:
    """The verdict on a comparison row from the interval of the (paired) difference a - b:
    ``side`` "lower" (the paper: a below b), "higher" (a above b): the interval excludes 0 on that
    side; "similar": 0 lies inside the interval."""
    if side not in SIDES:
        raise UserInputError(f"side must be one of {SIDES}, got {short_repr(side)}")
    if side == "lower":
        return iv.hi < 0.0
    if side == "higher":
        return iv.lo > 0.0
    return iv.contains(0.0)
