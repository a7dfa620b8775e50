"""The target-reaching commands on an anatomy file (``--anatomy``): plan, teleop, teleop --live and
simulate on a small lumen anatomy in millimetres, each naming the anatomy and reporting its targets;
and the procedural atrium's plan through its anatomy file, the paper task's numbers."""

import json

import numpy as np
import pytest
from anatomy_helpers import lumen_anatomy, solid_anatomy

from ballchain.cli import main
from ballchain.drake_models.anatomy import PROCEDURAL_FILE


def run_json(capsys, *argv) -> dict:
    code = main([str(a) for a in argv] + ["--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return json.loads(captured.out)


def without_first_target(directory):
    """The test anatomy without its first target (L1: out of reach of one unit at the default place)."""
    path = lumen_anatomy(directory)
    csv = directory / "targets.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(lines[:1] + lines[2:]) + "\n")
    return path


def test_plan_reports_each_target_of_the_anatomy(tmp_path, capsys):
    path = without_first_target(tmp_path)
    data = run_json(capsys, "plan", "--anatomy", path, "--targets", "2", "--balls", "16", "--grid", "2",
                    "--refine", "3", "--min-force", "10")
    assert data["task"] is None and data["paper"] is None
    assert data["anatomy"]["file"] == str(path) and data["anatomy"]["side"] == "lumen"
    assert [t["name"] for t in data["anatomy"]["targets"]] == ["L2", "L3", "L4"]
    assert [r["target"] for r in data["rows"]] == ["L2", "L3"]
    assert data["summary"]["targets"] == 2
    for row in data["rows"]:
        if row["reached"]:  # a held equilibrium pressing >= 10 gf inside the friction cone
            assert row["force_gf"] >= 10.0 * (1 - 1e-4)
            # The plan's own test (``min_turn_orientation``): |F_t| <= mu F_n + 1e-3 F_min, as test_planner.
            assert row["friction_needed"] <= data["friction"] + 1e-3 * 10.0 / row["force_gf"]
            assert abs(np.linalg.norm(row["dipole"]) - 1.0) < 1e-9
            # The world-frame dipole is the statics frame's turned by the sheath's frame (x along the sheath).
            axis = np.array(row["dipole_W"]) @ np.array(data["anatomy"]["sheath_axis"])
            assert abs(axis - row["dipole"][0]) < 1e-9
            assert row["offset_mm"] <= data["target_radius_mm"] * (1 + 1e-6)
        else:
            assert row["reason"]
    assert data["summary"]["reached"] >= 1


@pytest.mark.slow
def test_teleop_visits_the_anatomy_s_targets_in_file_order_and_writes_the_replay(tmp_path, capsys):
    path = lumen_anatomy(tmp_path)
    html = tmp_path / "replay.html"
    data = run_json(capsys, "teleop", "--anatomy", path, "--targets", "2", "--no-progress", "--html", html)
    assert data["anatomy"]["file"] == str(path) and data["task"] is None and data["paper"] is None
    assert [r["target"] for r in data["rows"]] == ["L1", "L2"]
    assert html.stat().st_size > 0 and data["html"] == str(html)
    assert f"anatomy: {path.name}" in html.read_text()  # the replay names the anatomy it ran on
    radius = data["anatomy"]["touch_radius_mm"]
    for row in data["rows"]:
        if row["touched"]:
            assert row["accuracy_mm"] <= radius + 1e-6
    assert data["summary"]["failure"] is None


@pytest.mark.slow
def test_simulate_runs_a_scenario_on_the_anatomy(tmp_path, capsys):
    path = lumen_anatomy(tmp_path)
    data = run_json(capsys, "simulate", "--scenario", "teleop_right_unit", "--anatomy", path, "--duration", "0.2",
                    "--set", "{engine: statics}", "--no-progress")
    assert data["anatomy"]["file"] == str(path) and len(data["anatomy"]["targets"]) == 4
    assert data["min_wall_clearance_mm"] > 0.0  # the chain in the lumen, clear of the wall


def test_teleop_live_runs_on_the_anatomy(tmp_path, capsys):
    path = lumen_anatomy(tmp_path)
    data = run_json(capsys, "teleop", "--live", "--anatomy", path, "--duration", "0.1", "--realtime-rate", "0",
                    "--no-wait")
    assert data["n_targets"] == 4 and data["settings"]["anatomy"] == str(path)
    assert data["ended"] == "duration" and data["failure"] is None


@pytest.mark.slow
def test_the_procedural_file_plans_the_paper_task_as_the_ring_stand_does():
    """The plan through the procedural anatomy file is the plan on the ring's own stand
    (``teleop_stand``, the procedural atrium's rings and its carina magnet) to the last bit."""
    from ballchain.drake_models.heart import LeftAtrium
    from ballchain.drake_models.params import BallChain, newtons_from_gram_force
    from ballchain.experiments import planner

    data = planner.run(task="right", targets=1, balls=(16,), grid=3, refine=4, progress=False,
                       anatomy=PROCEDURAL_FILE)
    heart, chain = LeftAtrium(), BallChain(n_balls=16)
    stand = planner.teleop_stand(heart, "right", chain.ball_diameter)
    out = planner.plan_target(chain, stand, "right_1", planner.neutral_dipole(stand), None,
                              newtons_from_gram_force(planner.MIN_FORCE_GF), 0.5 * heart.params.target_diameter,
                              data.friction, 3, 4)
    row = data.rows[0]
    assert row["target"] == "right_1" and row["reached"] == out["feasible"]
    if out["feasible"]:
        assert row["dipole"] == out["plan"].dipoles[0].tolist()
        assert row["turn_deg"] == float(np.degrees(out["plan"].turn_rad[0]))


@pytest.mark.slow
def test_plan_and_teleop_on_a_solid_phantom(tmp_path, capsys):
    path = solid_anatomy(tmp_path, per_hole=2)
    plan = run_json(capsys, "plan", "--anatomy", path, "--targets", "2", "--balls", "16", "--grid", "2",
                    "--refine", "3")
    assert plan["anatomy"]["side"] == "solid" and [r["target"] for r in plan["rows"]] == ["left_1", "left_2"]
    # The default unit stands 10 cm below the plate's top face, under the targets' centroid.
    np.testing.assert_allclose(plan["anatomy"]["magnets_mm"][0], [0.0, 0.0, 2.0 - 100.0], atol=1e-3)
    for row in plan["rows"]:
        assert row["reason"] or row["force_gf"] >= 10.0 * (1 - 1e-4)
    data = run_json(capsys, "teleop", "--anatomy", path, "--task", "right", "--no-progress")
    assert [r["target"] for r in data["rows"]] == ["right_1", "right_2"] and data["task"] == "right"
    assert data["summary"]["failure"] is None
    for row in data["rows"]:
        if row["touched"]:
            assert row["accuracy_mm"] <= data["anatomy"]["touch_radius_mm"] + 1e-6


def test_a_replay_names_its_anatomy_in_its_title_and_corner():
    from ballchain.systems.chain_simulation import captioned_replay

    page = "<html><head><meta></head><body><div>scene</div></body></html>"
    assert captioned_replay(page, None) == page  # the built-in atrium: the page as Meshcat wrote it
    out = captioned_replay(page, "anatomy: a<b>.yaml")
    assert out.startswith("<html><head><title>anatomy: a&lt;b&gt;.yaml</title><meta>")
    assert out.index('id="ballchain-caption"') < out.index("</body>") and "a<b>" not in out
