"""``bench statics``' kernel rows: the numpy-reference Newton solve reaches the kernels' minimum,
--cases leaves baselines out, --clock cpu, and the compile-cost fields (correctness only)."""

import pytest

from ballchain.experiments.statics_bench import compile_cost, run_statics


def test_numpy_reference_rows_and_case_selection():
    out = run_statics(n_balls=5, repeats=1, progress=False, cases="numpy", clock="cpu")
    assert out.clock == "cpu"
    assert set(out.samples_ms) == {"newton_cold", "newton_warm", "numpy_cold", "numpy_warm"}
    for case in ("numpy_cold", "numpy_warm"):
        assert out.converged[case]
        assert out.same_minimum[case]["energy_diff_rel"] < 1e-12
        assert out.same_minimum[case]["tip_diff_m"] < 1e-9
    assert out.iterations["numpy_cold"] == out.iterations["newton_cold"]  # the same solver
    assert out.snopt_cold_median_ms is None and out.baseline_median_ms is None
    assert out.speedup_cold is None
    assert out.kernel_speedup_cold == pytest.approx(out.numpy_cold_median_ms / out.cold_median_ms)
    with pytest.raises(ValueError, match="--cases"):
        run_statics(n_balls=3, repeats=1, progress=False, cases="numpy,fortran")


@pytest.mark.slow
def test_compile_cost_compares_an_empty_cache_with_the_cache():
    cost = compile_cost()
    assert cost["empty_cache_s"] > cost["cached_s"] > 0.0
    assert cost["compile_cpu_s"] == pytest.approx(cost["empty_cache_cpu_s"] - cost["cached_cpu_s"])
