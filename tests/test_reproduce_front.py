"""The main job's front: the console summary, the report's summary, contents and links, the
rounding of round-off, the progress bar's weights, and batch runs without Meshcat's server line."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from ballchain.report import (Section, anchors, format_number, section_from_dict, section_to_dict, summary_lines,
                              to_html, write_report)


def _synthetic_sections() -> list[Section]:
    a = (Section("Clinical magnet sizing (paper Section V-A)")
         .text("See `data/sizing.csv` and missing.json.")
         .table(["quantity", "paper", "model"], [["diameter [mm]", 119, 119.2], ["force [gf]", 500, 245.2]])
         .headline("diameter [mm]", 119, 119.2, True, "the cube, not the printed fourth power")
         .headline("force [gf]", 500, 245.2, False, "2 d_c instead of 2 (d_c + d_d/2)"))
    b = (Section("Teleoperation tasks with a simulated operator")
         .table(["task", "Meshcat replay"], [["left", "replays/teleop_left_world.html"]])
         .headline("left ring: targets touched", "20/20", "20/20", True))
    c = Section("Run time").table(["experiment", "seconds"], [["sizing", 0.5]])
    return [a, b, c]


def test_summary_lines_one_per_headline_with_verdict_values_and_difference():
    lines = summary_lines(list(zip(["sizing", "teleoperation", "run time"], _synthetic_sections())))
    assert len(lines) == 3  # the run-time section has no headline
    assert lines[0].startswith("agrees") and "sizing: diameter [mm]: paper 119, model 119.2 (+0.17 %)" in lines[0]
    assert lines[1].startswith("disagrees") and "(-51 %)" in lines[1] and lines[1].endswith("2 (d_c + d_d/2)")
    assert "paper 20/20, model 20/20" in lines[2] and "%" not in lines[2]  # text values: no difference


def test_report_opens_with_summary_and_contents_and_links_the_files_it_mentions(tmp_path):
    (tmp_path / "replays").mkdir()
    (tmp_path / "replays" / "teleop_left_world.html").write_text("<html></html>")
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "sizing.csv").write_text("a,b\n")
    sections = _synthetic_sections()
    md_path, html_path = write_report("Title", sections, tmp_path)
    md, page = md_path.read_text(), html_path.read_text()

    # Summary first, then contents, then the sections.
    assert md.index("## Summary") < md.index("## Contents") < md.index("## Clinical magnet sizing")
    assert page.index("Summary</h2>") < page.index("Contents</h2>") < page.index("<h2 id='clinical-magnet-sizing")
    summary = md.split("## Summary")[1].split("## Contents")[0]
    assert summary.count("\n| ") == 1 + 3  # the header and one row per headline
    assert "| agrees |" in summary and "| disagrees |" in summary and "119.2 (+0.17 %)" in summary

    # Every contents entry points at a heading that exists, in both files.
    ids = set(re.findall(r"<h2 id='([^']+)'>", page))
    for anchor in anchors(sections):
        assert f"(#{anchor})" in md and f"href='#{anchor}'" in page and anchor in ids
    assert anchors([Section("Table I's gap, effect by effect")]) == ["table-is-gap-effect-by-effect"]

    # Existing results files become relative links (a code span stays code); missing ones stay text.
    assert "[`data/sizing.csv`](data/sizing.csv)" in md
    assert '<a href="data/sizing.csv"><code>data/sizing.csv</code></a>' in page
    assert "[replays/teleop_left_world.html](replays/teleop_left_world.html)" in md
    assert '<a href="replays/teleop_left_world.html">replays/teleop_left_world.html</a>' in page
    assert "missing.json" in md and "(missing.json)" not in md and 'href="missing.json"' not in page


def test_noise_prints_as_zero_and_a_columns_resolution_sets_its_digits():
    # Round-off relative to the column's largest value, or below 1e-12 in any unit: 0.
    assert format_number(1.053e-14, scale=7.423) == "0"
    assert format_number(-3e-13) == "0"
    assert format_number(2e-8, scale=7.423) == "2e-08"  # not round-off at this scale: kept
    assert format_number(1.5e-6) == "1.5e-06"
    # Otherwise 4 significant digits, whole numbers above that without an exponent.
    assert format_number(0.13469) == "0.1347" and format_number(18466.3) == "18466"
    # A resolution rounds to the quantity's precision, with no negative zero.
    assert format_number(0.4181, resolution=0.01) == "0.42"
    assert format_number(-0.004, resolution=0.01) == "0"
    assert format_number(7.4229, resolution=0.001) == "7.423"
    assert [format_number(v) for v in (None, True, False, 3, "text")] == ["-", "yes", "no", "3", "text"]

    section = Section("s").table(["angle error [deg]", "force error [%]"],
                                 [[7.423, 26.53], [1.053e-14, -0.007277]], resolution={1: 0.01})
    page = to_html("t", [section])
    assert "<td>0</td><td>-0.01</td>" in page and "e-14" not in page


def test_headlines_and_resolutions_survive_the_resume_record(tmp_path):
    section = _synthetic_sections()[0].table(["x"], [[0.123]], resolution={0: 0.1})
    back = section_from_dict(json.loads(json.dumps(section_to_dict(section, tmp_path))), tmp_path)
    assert back.headlines == section.headlines and back.blocks[-1].resolution == {0: 0.1}


def test_a_damaged_headline_in_a_resume_record_reruns_the_section():
    from ballchain.reproduce import _record_problem

    record = {"key": "k", "seconds": 1.0, "files": {}, "section": section_to_dict(_synthetic_sections()[0], Path("."))}
    assert _record_problem(record) is None
    record["section"]["headlines"] = [{"result": 3}]
    assert "headlines" in _record_problem(record)
    record["section"]["headlines"] = []
    record["section"]["blocks"][1]["table"]["resolution"] = {"x": 1}
    assert "resolution" in _record_problem(record)


def test_progress_weights_are_the_measured_costs_scaled_by_the_previous_run():
    from ballchain.reproduce import SECTION_COST_S, section_weights

    names = ["alignment", "teleoperation", "a new section"]
    weights = section_weights(names, False, {})
    ratio = SECTION_COST_S["teleoperation"][0] / SECTION_COST_S["alignment"][0]
    assert weights["teleoperation"] / weights["alignment"] == pytest.approx(ratio, rel=1e-12)
    assert weights["a new section"] == pytest.approx((weights["alignment"] + weights["teleoperation"]) / 2)  # median
    # The previous run's time replaces a section's cost and scales the others to this machine.
    previous = {"alignment": 3.0 * SECTION_COST_S["alignment"][0]}
    weights = section_weights(names, False, previous)
    assert weights["alignment"] == previous["alignment"]
    assert weights["teleoperation"] == pytest.approx(3.0 * SECTION_COST_S["teleoperation"][0])
    quick = section_weights(["alignment", "teleoperation"], True, {})
    assert quick["teleoperation"] / quick["alignment"] == pytest.approx(
        SECTION_COST_S["teleoperation"][1] / SECTION_COST_S["alignment"][1])


def test_a_previous_runs_times_count_only_for_the_same_mode(tmp_path):
    from ballchain.reproduce import CACHE, _previous_seconds

    (tmp_path / CACHE).mkdir()
    record = {"key": "k", "seconds": 12.5, "files": {}, "quick": True, "section": {"title": "t", "blocks": []}}
    (tmp_path / CACHE / "alignment.json").write_text(json.dumps(record))
    (tmp_path / CACHE / "sizing.json").write_text("{not json")
    assert _previous_seconds(tmp_path, ["alignment", "sizing", "workspace"], True) == {"alignment": 12.5}
    assert _previous_seconds(tmp_path, ["alignment"], False) == {}


_MESHCATS = """
from ballchain.systems.chain_simulation import replay_meshcat
from pydrake.geometry import Meshcat, MeshcatParams
replay = replay_meshcat()
print("replay meshcat started", flush=True)
interactive = Meshcat(MeshcatParams(host="localhost"))
"""


def test_a_replays_meshcat_starts_without_the_listening_line_and_leaves_drakes_logging_as_it_was():
    proc = subprocess.run([sys.executable, "-c", _MESHCATS], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = (proc.stdout + proc.stderr).splitlines()
    listening = [line for line in lines if "Meshcat listening for connections" in line]
    # One line: the interactive Meshcat's, started after the replay's with drake's level put back.
    assert len(listening) == 1 and "replay meshcat started" in proc.stdout


@pytest.mark.slow
def test_a_quick_batch_run_prints_no_meshcat_line_says_where_replays_go_and_ends_with_its_findings(tmp_path):
    out = tmp_path / "results"
    proc = subprocess.run([sys.executable, "-m", "ballchain", "reproduce", "--quick", "--out", str(out),
                           "--sections", "teleoperation", "Table I effects and clinical design"],
                          capture_output=True, text=True, timeout=1200)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Meshcat listening" not in proc.stdout + proc.stderr
    assert proc.stderr.count("Meshcat replays go to") == 1 and str(out / "replays") in proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert lines[-1] == f"open {out / 'report.html'}"
    found = [line for line in lines if line.startswith("  ")]
    assert len(found) == 5  # two teleoperation tasks (targets touched, time: each with its interval), the clinical design
    assert all(re.match(r"  (agrees|disagrees|-) +\S", line) for line in found)
    md = (out / "report.md").read_text()
    # The replays are linked; the force-per-target figure is left out with one target per chain.
    assert "[replays/teleop_left_world.html](replays/teleop_left_world.html)" in md
    assert "clinical_forces.png" not in md and (out / "clinical" / "clinical_forces.png").exists()


def _fake_experiments():
    def sizing(out: Path, quick: bool):
        section = (Section("Clinical magnet sizing").table(["quantity", "paper", "model"], [["diameter [mm]", 119, 150.0]])
                   .headline("diameter [mm]", 119, 150.0, False, "a fake section"))
        return section, {"diameter_mm": 150.0}

    def notes(out: Path, quick: bool):
        return Section("Notes").text("nothing to compare"), {"n": 1}

    from ballchain.reproduce import ReportSection

    return [ReportSection("sizing", sizing), ReportSection("notes", notes)]


def test_the_command_ends_with_the_findings_and_the_reports_path(tmp_path, monkeypatch, capsys):
    from ballchain import reproduce
    from ballchain.cli import main

    monkeypatch.setattr(reproduce.registry, "SECTIONS", _fake_experiments())
    assert main(["reproduce", "--out", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1] == f"open {tmp_path / 'report.html'}"
    assert lines[-2] == ("  disagrees  sizing: diameter [mm]: paper 119, model 150 (+26 %); a fake section")
    md = (tmp_path / "report.md").read_text()
    # Each section links its data; the summary has the one headline, the contents every section.
    assert "[`sections/sizing.json`](sections/sizing.json)" in md and "(sections/notes.json)" in md
    assert md.index("## Summary") < md.index("## Contents") < md.index("## Clinical magnet sizing")
    assert "- [Notes](#notes)" in md and "- [Run time](#run-time)" in md


def test_a_figure_named_relative_to_the_results_folder_is_embedded(tmp_path):
    """A section's figure given relative to the results folder (as the manual comparison named its
    ``manual_transitions.png``) is read from that folder: the report said "figure missing" while
    the file was there."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(1, 1))
    fig.savefig(tmp_path / "rel.png")
    plt.close(fig)
    (tmp_path / "sub").mkdir()
    (tmp_path / "rel.png").replace(tmp_path / "sub" / "rel.png")
    sections = [Section("Figures").figure("sub/rel.png", "relative").figure(tmp_path / "sub" / "rel.png", "absolute")
                .figure("sub/none.png", "absent")]
    page = to_html("Title", sections, tmp_path)
    assert page.count("<img src='data:image/png;base64,") == 2
    assert page.count("figure missing") == 1 and "figure missing: sub/none.png" in page
    md = write_report("Title", sections, tmp_path)[0].read_text()
    assert "![relative](sub/rel.png)" in md and "![absolute](sub/rel.png)" in md


def test_one_registry_gives_every_section_its_function_cost_and_headlines():
    from ballchain import reproduce

    names = [s.name for s in reproduce.SECTIONS]
    assert len(names) == len(set(names)) == 13
    for entry in reproduce.SECTIONS:
        assert callable(entry.function) and callable(entry.headlines), entry.name
        full, quick = entry.cost_s
        assert full > 0 and quick > 0, entry.name
    # The old tables are views of the registry, not second tables.
    assert reproduce.EXPERIMENTS == [(s.name, s) for s in reproduce.SECTIONS]
    assert reproduce.SECTION_COST_S == {s.name: s.cost_s for s in reproduce.SECTIONS}
    assert reproduce.find("sizing") is reproduce.sizing_section is reproduce.SECTIONS[1]


def test_a_registry_entry_runs_its_function_then_its_headline_builder(tmp_path):
    from ballchain.reproduce import ReportSection

    def function(out: Path, quick: bool):
        return Section("X").table(["quantity", "paper", "model"], [["d [mm]", 2.0, 2.1]]), {"d_mm": 2.1}

    def headlines(section: Section, data: dict):
        section.headline("d [mm]", 2.0, data["d_mm"], True, "from the data")

    section, data = ReportSection("x", function, (1.0, 1.0), headlines)(tmp_path, True)
    assert [(h.result, h.model) for h in section.headlines] == [("d [mm]", 2.1)] and data == {"d_mm": 2.1}
    bare, _ = ReportSection("x", function)(tmp_path, True)  # no headline builder: no summary rows
    assert bare.headlines == []
