"""The procedure in a world it does not know (issue 43): the JSON carries the drawn world, the
estimate's error grows with the mismatch, and the sensitivity table pools its runs and resumes
from its cache."""

from __future__ import annotations

import json

import pytest

from ballchain.experiments import procedure, world_sensitivity
from ballchain.infrastructure.errors import UserInputError


def _run(condition, seed, dwells):
    return {"ring": "right", "condition": condition, "seed": seed, "dwells": dwells,
            "summary": {"reached": len(dwells), "targets": 2, "failure": None}}


def test_rows_pool_the_seeds():
    runs = [_run("magnet_position", 0, [{"mean_error_gf": -1.0, "worst_error_gf": 2.0, "in_window": 1.0},
                                        {"mean_error_gf": 3.0, "worst_error_gf": 4.0, "in_window": 0.5}]),
            _run("magnet_position", 1, [{"mean_error_gf": -2.0, "worst_error_gf": 2.5, "in_window": 0.0}])]
    row = world_sensitivity._row("right", "magnet_position", runs)
    assert row["magnitude"] == "2 mm" and row["seeds"] == 2 and row["reached"] == 3 and row["targets"] == 4
    assert row["estimate_mean_abs_error_gf"] == pytest.approx(2.0, abs=1e-12)  # (1 + 3 + 2) / 3
    assert row["estimate_mean_error_gf"] == pytest.approx(0.0, abs=1e-12)
    assert row["estimate_worst_error_gf"] == 4.0
    assert row["in_window_fraction"] == pytest.approx(0.5, abs=1e-12)
    assert row["worse_than_tacticath"] == pytest.approx(2 / 3, abs=1e-3)  # 3 and 2 gf exceed 1.29
    assert row["worse_than_smarttouch"] == pytest.approx(1 / 3, abs=1e-3)  # 3 gf exceeds 2.26
    empty = world_sensitivity._row("right", "all", [_run("all", 0, [])])
    assert empty["estimate_mean_abs_error_gf"] is None and empty["magnitude"] is None


@pytest.mark.parametrize("kwargs,field", [({"rings": ("middle",)}, "rings"), ({"seeds": (-1,)}, "seeds"),
                                          ({"targets": 0}, "targets"), ({"dwell_s": 0.0}, "dwell"),
                                          ({"conditions": ("wall",)}, "conditions"), ({"scales": (0.0,)}, "scales")])
def test_bad_input_refused_before_any_run(kwargs, field):
    with pytest.raises(UserInputError, match=field):
        world_sensitivity.run(**kwargs, progress=False)


@pytest.mark.slow
def test_procedure_json_carries_the_world_and_a_larger_error():
    """A 6 % stronger magnet than the navigator's model (seed 1 of magnet_magnetisation at five
    times its published tolerance) presses harder than the estimate says: the error grows."""
    plans = procedure.plan_ring("right", targets=2)
    common = dict(seed=1, targets=2, dwell_s=2.0, plans=plans, progress=False, lesions=False)
    nominal = procedure.run("right", world="none", **common)
    world = {"preset": "literature", "only": ["magnet_magnetisation"], "scale": 5.0}
    perturbed = procedure.run("right", world=world, **common)
    data = json.loads(perturbed.to_json())
    drawn = data["settings"]["world"]
    assert drawn["seed"] == 1 and drawn["magnet_magnetisation_pct"][0] > 3.0
    assert drawn["magnet_offsets_mm"] == [[0.0, 0.0, 0.0]]  # only the magnetisation
    assert drawn["anatomy_rotation_deg"] == [0.0, 0.0, 0.0]
    assert set(drawn["not_modelled"]) == {"wall_stiffness", "wall_friction"}  # said, not drawn
    assert json.loads(nominal.to_json())["settings"]["world"] is None
    assert nominal.summary["reached"] == perturbed.summary["reached"] == 2
    grown = perturbed.summary["estimate_mean_abs_error_gf"] - nominal.summary["estimate_mean_abs_error_gf"]
    assert grown > 0.3, (nominal.summary, perturbed.summary)


@pytest.mark.slow
def test_sensitivity_resumes_from_its_cache(tmp_path, monkeypatch):
    cache = tmp_path / "runs.json"
    first = world_sensitivity.run(("right",), (0,), targets=1, dwell_s=1.0, conditions=("none", "ball_remanence"),
                                  cache=cache, progress=False)
    assert [r["condition"] for r in first.rows] == ["none", "ball_remanence"]
    assert all(r["targets"] == 1 for r in first.rows)

    def no_run(*args, **kwargs):
        raise AssertionError("a cached run was run again")

    monkeypatch.setattr(world_sensitivity, "_run_one", no_run)
    again = world_sensitivity.run(("right",), (0,), targets=1, dwell_s=1.0, conditions=("none", "ball_remanence"),
                                  cache=cache, progress=False)
    assert again.rows == first.rows


def test_scaled_worlds_are_rows_of_their_own():
    assert world_sensitivity._world("all x0.5", 3) == {"preset": "literature", "seed": 3, "scale": 0.5}
    assert world_sensitivity._world("anatomy_scale", 3) == {"preset": "literature", "only": ["anatomy_scale"], "seed": 3}
    assert world_sensitivity._row("right", "all x0.5", [_run("all x0.5", 0, [])])["magnitude"] == "x0.5"
