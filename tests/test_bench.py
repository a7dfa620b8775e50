"""``ballchain bench``: the statics benchmark's JSON (correctness fields only, never wall time)
and its argument errors."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from ballchain.cli import main as cli_main
from script_helpers import load_benchmark

REPO = Path(__file__).resolve().parents[1]


def test_bench_statics_json(capsys):
    rc = cli_main(["bench", "statics", "--balls", "5", "--repeats", "1", "--json"])
    captured = capsys.readouterr()
    assert rc == 0
    out = json.loads(captured.out)
    for key in ("cold_median_ms", "warm_median_ms", "baseline_median_ms", "speedup_cold",
                "snopt_cold_median_ms", "snopt_warm_median_ms", "same_minimum", "iterations", "repeats"):
        assert key in out, key
    assert out["repeats"] == 1 and out["n_balls"] == 5
    assert out["angle_deg"] == 90.0 and out["warm_start_angle_deg"] == 87.5
    cases = ("newton_cold", "newton_warm", "snopt_cold", "snopt_warm", "baseline")
    assert all(len(out["samples_ms"][c]) == 1 for c in cases)
    assert all(out["converged"].values())
    same = out["same_minimum"]
    assert same["ok"]
    for case in ("newton_warm", "snopt_cold", "snopt_warm", "baseline"):
        assert same[case]["tip_diff_m"] < 1e-6
        assert same[case]["energy_diff_rel"] < 1e-9
    it = out["iterations"]
    assert all(isinstance(it[c], int) and it[c] >= 1 for c in cases)
    assert it["newton_warm"] <= it["newton_cold"]
    assert it["baseline_evaluations"] >= it["baseline"]
    # Equilibrium of 5 balls at 23 mT, 90 deg (tip in the x-y plane, bent towards +y).
    assert out["tip_position_mm"][1] > 5.0 and out["tip_position_mm"][2] == pytest.approx(0.0, abs=1e-9)
    # The speedup is the ratio of the medians it reports (no assertion on its size: wall time).
    assert out["speedup_cold"] == pytest.approx(out["baseline_median_ms"] / out["cold_median_ms"], rel=1e-12)
    assert out["speedup_cold_back_to_back"] == pytest.approx(
        out["baseline_median_ms"] / out["cold_back_to_back_median_ms"], rel=1e-12)


# The same benchmark run as the JSON test above, through the text report and the script: the
# quick tier keeps the JSON run (every correctness field), these two run in the slow tier.
@pytest.mark.slow
def test_bench_statics_text(capsys):
    assert cli_main(["bench", "statics", "--balls", "3", "--repeats", "1", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "SLSQP baseline" in text and "same minimum: yes" in text


@pytest.mark.parametrize(
    "argv",
    [
        ["bench", "statics", "--balls", "0"],
        ["bench", "statics", "--balls", "two"],
        ["bench", "statics", "--repeats", "0"],
        ["bench", "statics", "--field-mT", "nan"],
        ["bench", "statics", "--blas-threads", "100000"],
        ["bench", "dynamics"],
        ["bench"],
    ],
)
def test_bad_arguments_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        cli_main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "error" in err and "Traceback" not in err


@pytest.mark.parametrize(
    "flags, message",
    [(["--balls", "1"], "--balls must be an integer >= 2"),
     (["--field-mT", "-5"], "--field-mT must be a number in [0.001, 1000] mT, got -5.0"),
     (["--field-mT", "1e300"], "--field-mT must be a number in [0.001, 1000] mT"),  # a solve that never converges
     (["--angle-deg", "1e300"], "--angle-deg must be a number in [-360, 360] deg")],
)
def test_bad_values_exit_2_with_one_line(flags, message, capsys):
    assert cli_main(["bench", "statics", *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_bad_argument_in_a_fresh_process_has_no_traceback():
    proc = subprocess.run([sys.executable, "-m", "ballchain", "bench", "statics", "--balls", "1"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "--balls must be an integer >= 2" in proc.stderr


@pytest.mark.slow
def test_benchmark_script_runs():
    script = load_benchmark("bench_statics")
    assert script.__doc__ and callable(script.main)
    out = script.run(n_balls=3, repeats=1, progress=False)
    assert out.n_balls == 3 and out.same_minimum["ok"]


def test_each_round_orders_the_cases_afresh():
    """The statics benchmark's rounds run their cases in drawn orders (``round_order``): every
    round is a permutation of the cases, the same in every run, and no case always runs right
    after the same case (the compiled cold solve used to run right after SLSQP in every round,
    which leaves it the coldest caches)."""
    from ballchain.experiments.statics_bench import _CASES, round_order

    assert round_order(_CASES, 0) == _CASES
    rounds = [round_order(_CASES, r) for r in range(1, 6)]
    assert all(sorted(order) == sorted(_CASES) for order in rounds)
    assert rounds == [round_order(_CASES, r) for r in range(1, 6)]
    for case in _CASES:
        before = {order[order.index(case) - 1] if order.index(case) else None for order in rounds}
        assert len(before) > 1, (case, before)


def _cold_floor():
    return load_benchmark("cold_floor")


def test_cold_floor_splits_the_cold_solve_per_step_limit():
    """``benchmarks/cold_floor.py``: each step limit's solve is the solver's own (0.5 rad, the
    default, takes the canonical 7 iterations; 1.0 rad 5, docs/performance.md section 22), the
    kernel's time is a part of the call's, and the kernel is unwrapped afterwards."""
    import math

    from ballchain.drake_models.field_sources import UniformField
    from ballchain.drake_models.params import BallChain
    from ballchain.optimization import compiled_model
    from ballchain.optimization.statics import ChainStatics

    kernel = compiled_model.newton
    out = _cold_floor().run(repeats=1, max_steps=(0.5, 1.0), baseline_repeats=1)
    assert compiled_model.newton is kernel
    default = ChainStatics(BallChain(n_balls=16), method="newton").solve(UniformField.in_plane(23e-3, math.radians(90)))
    rows = out["max_steps"]
    assert set(rows) == {"0.5", "1"}
    assert rows["0.5"]["iterations"] == default.iterations == 7 and rows["1"]["iterations"] == 5
    assert rows["0.5"]["tip_m"] == [float(x) for x in default.positions[-1]]
    for row in rows.values():
        assert 0.0 < row["cold_kernel"] < row["cold"] and 0.0 < row["back_to_back_kernel"] < row["back_to_back"]
        assert row["speedup"]["cold"] == pytest.approx(out["slsqp_cold_ms"] / row["cold"])
    assert out["ms_for_700x"] == pytest.approx(out["slsqp_cold_ms"] / 700.0)


@pytest.mark.parametrize("flags, message", [
    (["--max-steps", "0,1"], "--max-steps must be positive finite step limits [rad], got '0,1'"),
    (["--max-steps", "a"], "--max-steps must be numbers separated by commas, got 'a'"),
    (["--repeats", "0"], "--repeats must be >= 1, got 0"),
])
def test_cold_floor_bad_flags_exit_2_with_one_line(flags, message):
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "cold_floor.py"), *flags],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and message in proc.stderr
