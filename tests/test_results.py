"""The experiments' results serialise one way (``experiments/_result.py`` on ``safe_files.to_jsonable``):
the fields in their order, numpy to plain Python, NaN to null, optional fields left out while None."""

import dataclasses
import json

import numpy as np
import pytest

from ballchain.commands._common import json_text
from ballchain.experiments import _result, alignment, field_models, forces_dynamics, sizing_check, wheels
from ballchain.drake_models.params import BallChain
from ballchain.infrastructure.safe_files import OMIT_IF_NONE
from ballchain.optimization.sizing import SizingInputs


def test_fields_in_order_numpy_to_lists_nan_to_null_optional_left_out_while_none():
    summary = alignment.AlignmentSummary(float("nan"), None, 1.4)
    result = alignment.AlignmentResult(rows=[{"n_balls": np.int64(2), "tip_angle_deg": np.float64(0.5)}],
                                       shapes={0.0: np.zeros((2, 3))}, summary=summary)
    data = json.loads(result.to_json())
    assert list(data) == ["rows", "shapes", "summary"]  # no "files" without out
    assert data["rows"] == [{"n_balls": 2, "tip_angle_deg": 0.5}]
    assert data["shapes"] == {"0.0": [[0.0, 0.0, 0.0]] * 2}
    assert data["summary"] == {"max_tip_angle_deg_beyond_10_balls": None,
                               "max_tip_angle_deg_beyond_10_balls_at_180deg": None, "paper_claim_deg": 1.4}
    result.files = []  # an optional field that is set, even empty, is written
    assert list(json.loads(result.to_json())) == ["rows", "shapes", "summary", "files"]
    # One serialisation: the method, the command's printer and to_dict agree.
    assert result.to_json() == json_text(result) == json_text(result.to_dict())


def test_every_result_field_is_a_key_of_the_json_and_nothing_else():
    """Real results: the JSON's keys are the dataclass's fields, in order (the optional ones
    only when set)."""
    results = [
        sizing_check.run(inputs=SizingInputs()),
        field_models.run(distances_m=[0.1], angles_deg=[0.0], ball=BallChain()),
        wheels.run(samples=5),
    ]
    for result in results:
        assert isinstance(result, _result.Result)
        names = [f.name for f in dataclasses.fields(result)
                 if not (f.metadata.get(OMIT_IF_NONE) and getattr(result, f.name) is None)]
        assert list(json.loads(result.to_json())) == names, type(result).__name__


def test_the_pin_simulation_result_leaves_statics_loaded_out_unless_set():
    fields = {f.name: None for f in dataclasses.fields(forces_dynamics.PinForceResult)}
    fields.update(settled=False, stiffness_N_per_m=500.0, time_step_s=1e-3, sim_time_s=0.0, wall_time_s=0.0,
                  steps=0, reason="too short")
    del fields["statics_loaded_N"]
    result = forces_dynamics.PinForceResult(**fields)
    assert "statics_loaded_N" not in result.to_dict()
    result.statics_loaded_N = 0.01
    assert list(result.to_dict())[-1] == "statics_loaded_N"


# The JSON keys (and their order) that ablation, clinical, Table I effects and the statics benchmark
# printed before they moved onto Result: the contract the moves kept (issue 11).
DEVICE_KEYS = ["device", "label", "power_W", "duration_s", "indentation_mm", "omega_width_mm", "omega_depth_mm",
               "omega_surface_diameter_mm", "iso50_width_mm", "iso50_depth_mm", "omega99_width_mm",
               "omega99_depth_mm", "peak_tissue_C", "peak_electrode_C", "peak_electrode_mean_C",
               "impedance_initial_ohm", "impedance_final_ohm", "energy_J", "mean_power_W", "cutoff_from_s",
               "electrode_above_80C_s", "paper", "meets_criterion", "growth"]
CLINICAL_ROW_KEYS = ["chain", "target", "group", "force_gf", "feasible", "friction_needed", "gradient_pull_gf",
                     "sheath_push_gf", "dipoles", "evaluations", "status", "effective_gf"]
SIZING_KEYS = ["chain", "criterion", "diameter_mm", "mass_kg", "magnet_distance_cm", "force_between_magnets_gf",
               "size_steps"]
BENCH_KEYS = ["benchmark", "n_balls", "field_mT", "angle_deg", "warm_start_angle_deg", "repeats", "clock",
              "cold_median_ms", "warm_median_ms", "python_cold_median_ms", "python_warm_median_ms",
              "numpy_cold_median_ms", "numpy_warm_median_ms",
              "snopt_cold_median_ms", "snopt_warm_median_ms", "baseline_median_ms", "speedup_cold", "speedup_warm",
              "speedup_cold_vs_snopt", "kernel_speedup_cold", "kernel_speedup_warm", "compiled_speedup_cold",
              "compiled_speedup_warm", "cold_back_to_back_median_ms", "speedup_cold_back_to_back",
              "kernel_note", "same_minimum",
              "converged", "iterations", "iterations_note", "energy_J", "tip_position_mm", "baseline", "samples_ms",
              "spread", "spread_note", "blas_threads", "load_average_1min", "cpu_count"]


def test_the_ablation_result_keeps_its_keys_and_leaves_the_simulation_out():
    from ballchain.experiments import ablation

    values = {name: 1.0 for name in DEVICE_KEYS}
    values.update(device="ball_chain", label="ball", paper=ablation.PAPER["ball_chain"], meets_criterion=False,
                  growth=[], cutoff_from_s=None, impedance_final_ohm=float("nan"))
    device = ablation.DeviceResult(**values, simulation=object())  # not JSON-able: must stay out
    settings = ablation.AblationSettings(90.0, 1.0, "myocardium", 22.0, 0.1, 1.0, "a", "b", "c")
    result = ablation.AblationResult(devices=[device], settings=settings, notes=["n"])
    data = json.loads(result.to_json())
    assert list(data) == ["devices", "settings", "paper", "criterion", "notes"]
    assert list(data["devices"][0]) == DEVICE_KEYS
    assert data["devices"][0]["impedance_final_ohm"] is None  # NaN: null in the JSON ...
    assert np.isnan(result.devices[0].impedance_final_ohm)  # ... and still NaN for the report's "nan"
    assert data["criterion"] == {"min_depth_mm": 2.9, "width_range_mm": [5.2, 6.0]}
    result.power_duration_map, result.sensitivity, result.files = {"rows": []}, [], []
    assert list(result.to_dict()) == ["devices", "settings", "paper", "criterion", "notes", "power_duration_map",
                                      "sensitivity", "files"]


def test_the_clinical_rows_keep_their_keys():
    from ballchain.experiments import clinical

    best = clinical.TargetForce("RSPV", 2.0, False, 0.3, 0.01, 1.99, [[1.0, 0.0, 0.0]] * 2, 12, "ok")
    row = clinical.ClinicalRow.of("8Fr", "vein", best)
    assert list(row.to_dict()) == CLINICAL_ROW_KEYS
    assert row.effective_gf == 0.0  # outside the cone: counts as nothing
    none = clinical.sizing_row("8Fr", "10 gf on every vein", None, 0.1, "surface", 3)
    assert list(none.to_dict()) == SIZING_KEYS  # no side-by-side force without a diameter
    found = clinical.sizing_row("8Fr", "10 gf on every vein", 0.2, 0.1, "surface", 3)
    assert list(found.to_dict()) == SIZING_KEYS + ["force_between_side_by_side_gf"]
    # Coaxial pull of two dipoles is twice the side-by-side one (same moments, same distance).
    assert found.force_between_magnets_gf == pytest.approx(2.0 * found.force_between_side_by_side_gf, rel=1e-9)


def test_the_table1_effects_are_typed_results_with_their_old_keys():
    from ballchain.experiments import table1_effects as effects

    resolution = effects.sensor_resolution()
    assert list(resolution.to_dict()) == ["step_gf", "multiples", "largest_distance_from_a_whole_step",
                                          "max_rounding_error_gf"]
    assert [f.name for f in dataclasses.fields(effects.EffectsResult)] == [
        "table", "case", "resolution", "ferromagnetic", "side_support", "friction", "push", "gradient",
        "compute_time_s", "notes"]
    assert [f.name for f in dataclasses.fields(effects.EffectRow)] == [
        "effect", "model", "force_range_gf", "reading_of_model_gf", "could_reach_paper"]


def test_the_statics_benchmark_json_keeps_its_keys():
    from ballchain.experiments.statics_bench import StaticsBenchResult, run_statics

    result = run_statics(n_balls=3, repeats=1, progress=False, cases="numpy", clock="cpu")
    assert isinstance(result, StaticsBenchResult)
    data = json.loads(json_text(result))
    assert list(data) == BENCH_KEYS  # compile_cost only when asked
    assert data["tip_position_mm"] == pytest.approx(list(result.tip_position_mm), abs=0)
    result.compile_cost = {"empty_cache_s": 1.0}
    assert list(result.to_dict()) == BENCH_KEYS + ["compile_cost"]
