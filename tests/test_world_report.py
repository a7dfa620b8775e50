"""The sensitivity table in the report (issue 43, ``reproduce/sensitivity.py``): ``reproduce`` runs
nothing for it; it lays out the JSON that ``ballchain sensitivity --out OUT/sensitivity`` wrote,
row for row, or says in one line how to make it."""

from __future__ import annotations

from ballchain.cli import main
from ballchain.experiments import world_sensitivity
from ballchain.report import Table
from ballchain.reproduce import find
from ballchain.reproduce.sensitivity import SENSITIVITY_FILE

ROWS = [
    {"ring": "right", "condition": "none", "magnitude": None, "seeds": 2, "reached": 4, "targets": 4, "dwells": 4,
     "estimate_mean_abs_error_gf": 0.55, "estimate_mean_error_gf": -0.45, "estimate_worst_error_gf": 1.41,
     "in_window_fraction": 1.0, "worse_than_tacticath": 0.0, "worse_than_smarttouch": 0.0, "failures": 0},
    {"ring": "right", "condition": "anatomy_rotation", "magnitude": "1.5 deg", "seeds": 2, "reached": 1, "targets": 4,
     "dwells": 1, "estimate_mean_abs_error_gf": 1.3333, "estimate_mean_error_gf": -1.3333,
     "estimate_worst_error_gf": 2.0, "in_window_fraction": 0.75, "worse_than_tacticath": 1.0,
     "worse_than_smarttouch": 0.0, "failures": 1},
    {"ring": "right", "condition": "all", "magnitude": None, "seeds": 2, "reached": 2, "targets": 4, "dwells": 2,
     "estimate_mean_abs_error_gf": 2.35, "estimate_mean_error_gf": -2.35, "estimate_worst_error_gf": 2.59,
     "in_window_fraction": 1.0, "worse_than_tacticath": 1.0, "worse_than_smarttouch": 0.5, "failures": 0},
]


def _tables(section):
    return [b for b in section.blocks if isinstance(b, Table)]


def test_without_a_sensitivity_file_the_section_says_how_to_make_it(tmp_path):
    section, data = find("world sensitivity")(tmp_path, True)
    assert data["source"] is None and not _tables(section) and not section.headlines
    (line,) = section.blocks
    assert f"--out {tmp_path / 'sensitivity'}" in line and "ballchain sensitivity" in line


def test_the_section_lays_out_what_ballchain_sensitivity_wrote(tmp_path, monkeypatch, capsys):
    def fake_run(rings, seeds, **kwargs):
        return world_sensitivity.SensitivityResult(rows=ROWS, runs=[], settings={
            "rings": list(rings), "seeds": list(seeds), "targets": kwargs["targets"], "dwell_s": kwargs["dwell_s"],
            "cpu_time_s": 12.5})

    monkeypatch.setattr(world_sensitivity, "run", fake_run)
    assert main(["sensitivity", "--ring", "right", "--seeds", "2", "--targets", "2", "--dwell", "5",
                 "--out", str(tmp_path / "sensitivity")]) == 0
    assert (tmp_path / SENSITIVITY_FILE).is_file() and "written:" in capsys.readouterr().out
    section, data = find("world sensitivity")(tmp_path, False)
    (table,) = _tables(section)
    assert data["rows"] == ROWS and len(table.rows) == len(ROWS)
    rotation = table.rows[1]
    assert rotation[:4] == ["right", "anatomy_rotation", "1.5 deg", "1/4"]
    assert rotation[4:] == ["1.33", "-1.33", "2.00", "75%", "100%", 1]
    assert table.rows[0][2] == "" and table.rows[0][4] == "0.55"
    assert "seeds [0, 1]" in section.blocks[0] and "12.5 CPU s" in section.blocks[0]
    (headline,) = section.headlines
    assert headline.paper is None and headline.agrees is None
    assert headline.model == "none: 4/4 reached, 0.55 gf; all: 2/4 reached, 2.35 gf"
    assert "anatomy_rotation reaches the fewest targets (1/4)" in headline.why


def test_a_damaged_sensitivity_file_is_said_not_raised(tmp_path):
    path = tmp_path / SENSITIVITY_FILE
    path.parent.mkdir()
    path.write_text('{"rows": [{"ring": "right"}], "settings": {}}')
    section, data = find("world sensitivity")(tmp_path, False)
    assert data["source"] is None and "problem" in data and not _tables(section)
    assert section.blocks[0].startswith("Could not read sensitivity/sensitivity.json") and "needs 'rows'" in section.blocks[0]
