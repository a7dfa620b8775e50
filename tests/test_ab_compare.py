"""``benchmarks/ab_compare.py``'s arithmetic and its flags: the sign test of ``--what seeds``
(the acceptance test of a change to the solver's iterates, docs/performance.md 18) against
scipy's exact binomial test, and bad ``--seeds``/``--task`` refused before any work."""

import subprocess
import sys
from pathlib import Path

import pytest
from scipy.stats import binomtest
from script_helpers import load_benchmark

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def ab():
    return load_benchmark("ab_compare")


@pytest.mark.parametrize("a, b", [(0, 5), (19, 31), (31, 19), (7, 4), (3, 3), (0, 1), (12, 40)])
def test_the_sign_test_is_the_exact_two_sided_binomial_test(ab, a, b):
    assert ab._sign_test(a, b) == pytest.approx(binomtest(a, a + b, 0.5).pvalue, rel=1e-12)


def test_the_sign_test_of_nothing_is_one_and_the_sections_figures_hold(ab):
    assert ab._sign_test(0, 0) == 1.0
    assert ab._sign_test(0, 5) == 0.0625  # Task I in docs/performance.md 18: 2 / 2**5
    assert ab._sign_test(19, 31) == pytest.approx(0.1189, abs=5e-5)  # Task II there


@pytest.mark.parametrize("text, seeds", [("0-3", [0, 1, 2, 3]), ("5", [5]), ("0,3,5", [0, 3, 5]), ("7-7", [7])])
def test_seed_lists(ab, text, seeds):
    assert ab._seed_list(text) == seeds


@pytest.mark.parametrize("text", ["3-1", "a-b", "1,,2", "", "-1", "0-4294967296", "1.5"])
def test_bad_seed_lists_say_what_is_allowed(ab, text):
    with pytest.raises(ValueError, match="comma-separated list of integers"):
        ab._seed_list(text)


@pytest.mark.parametrize("flags, field", [(["--seeds", "3-x"], "--seeds"), (["--task", "left,up"], "--task")])
def test_bad_flags_exit_2_with_one_line_before_any_work(flags, field):
    proc = subprocess.run([sys.executable, "benchmarks/ab_compare.py", "--base", "no-such-revision", "--what", "seeds",
                           *flags], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    last = proc.stderr.strip().splitlines()[-1]
    assert field in last and "Traceback" not in proc.stderr
    assert proc.stdout == ""
