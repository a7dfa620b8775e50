"""The simulated procedure's report section (both navigators on both rings over seeds), the plans
made once per ring, and the tip tracker's figures as scenario fields."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.localisation import LocalisationParams
from ballchain.experiments import procedure, procedure_report
from ballchain.systems.chain_scenario import ChainScenario, LocalisationScenario, load_scenario


# --- the scenario's localisation fields ----------------------------------------------------------

def test_scenario_localisation_defaults_are_the_trackers():
    """One home for the figures: the scenario's defaults are LocalisationParams'."""
    assert load_scenario("teleop_two_units").localisation.params() == LocalisationParams()


def test_scenario_localisation_override_reaches_the_params():
    s = load_scenario("teleop_two_units", "{localisation: {rate: 20, latency: 0.1, noise_std: 0.001}}")
    assert s.localisation.params() == LocalisationParams(noise_std=0.001, rate=20.0, latency=0.1)


@pytest.mark.parametrize("field, value", [("noise_std", ".nan"), ("noise_std", "-0.001"), ("noise_std", "0.5"),
                                          ("rate", ".inf"), ("rate", "0"), ("rate", "abc"), ("rate", "true"),
                                          ("latency", "-0.05"), ("latency", "[1]"), ("latency", "0.03")])
def test_scenario_localisation_bad_yaml_names_the_field(field, value):
    with pytest.raises(UserInputError, match=f"localisation.{field}"):
        load_scenario("teleop_two_units", f"{{localisation: {{{field}: {value}}}}}")


@pytest.mark.parametrize("field, value", [("noise_std", math.nan), ("noise_std", -1e-3), ("rate", "40"),
                                          ("rate", True), ("latency", None), ("latency", 2.0)])
def test_scenario_localisation_bad_python_value_names_the_field(field, value):
    scenario = ChainScenario(localisation=LocalisationScenario(**{field: value}))
    with pytest.raises(UserInputError, match=rf"scenario:? localisation\.{field}") as err:
        scenario.validate()
    assert len(str(err.value)) < 300


def test_procedure_bad_localisation_override_refused_before_any_work():
    with pytest.raises(UserInputError, match="localisation.rate"):
        procedure.run("right", targets=1, overrides="{localisation: {rate: -40}}", progress=False)


# --- plans made once -------------------------------------------------------------------------------

def test_plans_of_another_ring_or_type_refused():
    other = procedure.RingPlans((), (), 0.0, ("3 targets from left_1, 20 gf, 2 unit(s)", ("left_1",), 20.0, 16, ()))
    with pytest.raises(UserInputError, match="plans were made for another ring"):
        procedure.run("right", targets=1, plans=other, progress=False)
    with pytest.raises(UserInputError, match="plans must be a RingPlans"):
        procedure.run("right", targets=1, plans=[1, 2], progress=False)


@pytest.mark.slow
def test_plans_made_once_give_the_run_that_plans_itself(tmp_path, monkeypatch):
    """Bit-identical rows, lesions and ring (the CPU times aside); the scenario's localisation
    (here overridden) is what the run uses when not given one. An empty cache of plans: the run
    without plans plans itself (``plan_ring(cache=False)`` neither reads nor keeps them)."""
    monkeypatch.setenv("BALLCHAIN_CACHE", str(tmp_path / "cache"))
    overrides = "{localisation: {rate: 20, latency: 0.1}}"
    plans = procedure.plan_ring("right", targets=1, overrides=overrides, cache=False)
    assert plans.plans and plans.cpu_time_s > 0
    reused = procedure.run("right", seed=2, targets=1, dwell_s=2.0, plans=plans, overrides=overrides, progress=False)
    own = procedure.run("right", seed=2, targets=1, dwell_s=2.0, overrides=overrides, progress=False)

    def kept(r):
        return json.dumps({"rows": r.rows, "lesions": r.lesions, "ring": r.ring}, sort_keys=True)

    assert kept(reused) == kept(own)
    assert reused.rows[0]["reached"]
    assert reused.summary["plan_cpu_time_s"] == 0.0 < own.summary["plan_cpu_time_s"]
    assert reused.settings["localisation"] == {"noise_std_mm": pytest.approx(0.70 / math.sqrt(3.0)),
                                               "rate_hz": 20.0, "latency_s": 0.1}


# --- the report ------------------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, field", [({"seeds": ()}, "seeds"), ({"seeds": (1, 1)}, "seeds"),
                                           ({"seeds": (-1,)}, "seed"), ({"seeds": "01"}, "seeds"),
                                           ({"rings": ("top",)}, "rings"), ({"targets": 0}, "targets"),
                                           ({"workers": 0}, "workers"), ({"dwell_s": math.nan}, "dwell")])
def test_report_bad_arguments_refused_before_any_run(kwargs, field):
    with pytest.raises(UserInputError, match=field):
        procedure_report.run(**kwargs)


def _fake_run(seed: int, reached: int, time_s: float, window, worst) -> dict:
    rows = [{"reached": True, "force_true_min_gf": 10.0 + seed, "force_true_max_gf": 30.0 - seed,
             "force_true_mean_gf": 20.0},
            {"reached": True, "force_true_min_gf": 0.0, "force_true_max_gf": 0.5, "force_true_mean_gf": 0.2},
            {"reached": False, "force_true_min_gf": None, "force_true_max_gf": None, "force_true_mean_gf": None}]
    return {"ring": "right", "navigator": "auto", "seed": seed, "units": ["right_unit"], "rows": rows,
            "summary": {"targets": 18, "reached": reached, "total_time_s": time_s, "in_window_fraction": window,
                        "estimate_mean_abs_error_gf": worst / 2, "estimate_worst_error_gf": worst, "failure": None},
            "ring_verdict": {"gaps": [None] * seed, "isolated": seed == 0}, "lesions": [], "cpu_time_s": 1.0 + seed}


def test_aggregate_medians_and_ranges_over_seeds():
    times, reached, windows, worst = [100.0, 130.0, 90.0], [18, 17, 16], [1.0, 0.9, None], [2.0, 3.0, 1.5]
    row = procedure_report._aggregate([_fake_run(k, reached[k], times[k], windows[k], worst[k]) for k in range(3)])
    assert row["total_time_s"] == {"median": float(np.median(times)), "min": min(times), "max": max(times)}
    assert row["reached"]["median"] == float(np.median(reached))
    assert row["in_window_fraction"] == {"median": 0.95, "min": 0.9, "max": 1.0}  # a run without a dwell left out
    assert row["estimate_worst_error_gf"] == max(worst)
    assert (row["force_true_min_gf"], row["force_true_max_gf"]) == (0.0, 30.0)  # a touch without force counts
    assert row["ring_gaps"] == {"median": 1.0, "min": 0.0, "max": 2.0} and row["isolated_runs"] == 1


@pytest.mark.slow
def test_quick_section_writes_its_table_and_figures(tmp_path):
    from ballchain import reproduce

    summary = reproduce.run(out=tmp_path, quick=True, sections=["ablation procedure"])
    md = (tmp_path / "report.md").read_text()
    assert "Simulated ablation procedure" in md and "| ring | navigator | targets reached |" in md
    assert (tmp_path / "procedure" / "procedure_forces.png").stat().st_size > 0
    for ring in procedure_report.RINGS:
        for nav in procedure.NAVIGATORS:
            assert (tmp_path / "procedure" / "runs" / f"{ring}_{nav}_seed0" / "ring.png").stat().st_size > 0
    data = json.loads((tmp_path / "sections" / "ablation_procedure.json").read_text())
    assert len(data["runs"]) == 4 and all(r["summary"]["targets"] == procedure_report.QUICK_TARGETS
                                          for r in data["runs"])
    assert any("targets reached, autonomous navigator vs simulated operator" in line
               for line in summary["headlines"])


@pytest.mark.slow
def test_plans_and_runs_share_one_cluster(monkeypatch):
    """The plans' and the runs' maps run on one LocalCluster (its workers import the package and
    load the kernels once), and the serial report (workers=1) starts none."""
    import distributed

    started = []

    class Counted(distributed.LocalCluster):
        def __init__(self, *args, **kwargs):
            started.append(kwargs.get("n_workers"))
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(distributed, "LocalCluster", Counted)
    report = procedure_report.run(seeds=(0,), rings=("right",), targets=1, dwell_s=1.0, workers=2)
    assert started == [2]
    assert [x["navigator"] for x in report.runs] == list(procedure.NAVIGATORS)
    started.clear()
    procedure_report.run(seeds=(0,), rings=("right",), targets=1, dwell_s=1.0, workers=1)
    assert started == []
