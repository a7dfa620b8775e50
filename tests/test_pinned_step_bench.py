"""``benchmarks/pinned_step_bench.py``: the held tip's Schur step against the null-space step on a
run's captured steps (figures in docs/performance.md section 33)."""

import json

import pytest

from tests.script_helpers import load_benchmark


@pytest.mark.slow
def test_the_bench_times_both_steps_and_they_solve_the_same_system(tmp_path, capsys):
    bench = load_benchmark("pinned_step_bench")
    out = tmp_path / "pinned.json"
    assert bench.main(["--targets", "1", "--steps", "20", "--repeats", "1", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert 0 < result["schur_steps"] <= result["steps"] <= 20
    assert set(result["median_us"]) == {"null-space (numpy)", "null-space (compiled)", "Schur (compiled)"}
    assert all(v > 0 for v in result["median_us"].values())
    for name in ("Schur", "null-space"):
        assert result["largest_stationarity"][name] < 1e-9
        assert result["largest_pin_residual"][name] < 1e-12  # the solver's feasibility tolerance
    assert result["median_step_difference"] < 1e-9
    assert "compiled null-space / Schur" in capsys.readouterr().out


def test_bad_counts_are_refused():
    bench = load_benchmark("pinned_step_bench")
    with pytest.raises(SystemExit):
        bench.main(["--repeats", "0"])
