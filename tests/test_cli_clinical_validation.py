"""The ``validation`` and ``clinical`` commands end to end: exit 0, the documented JSON, the files
it names, and the relations the numbers must keep (each command's physics is tested in its
experiment's tests; these check the adapters)."""

import csv
import json

import pytest

from ballchain.cli import main

pytestmark = pytest.mark.slow  # whole commands (2-3 s each): the full tier


def _json(capsys, argv):
    code = main(argv + ["--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return json.loads(captured.out)


def test_validation_writes_its_table_and_the_dipole_beats_the_uniform_field(capsys, tmp_path):
    data = _json(capsys, ["validation", "--out", str(tmp_path)])
    assert {d["n_balls"] for d in data["differences"]} == set(range(5, 11))
    with open(tmp_path / "validation.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert len(table) == len(data["differences"])
    for row, d in zip(table, data["differences"]):
        assert int(row["n_balls"]) == d["n_balls"]
        assert float(row["dipole_vs_exact_tip_mm"]) == pytest.approx(d["dipole_vs_exact_tip_mm"], rel=1e-12)
    # The point dipole is the exact cylinder's far field: nearer it than a uniform field, row by row.
    for d in data["differences"]:
        assert d["dipole_vs_exact_tip_mm"] < d["uniform_vs_exact_tip_mm"] + 1e-9
    s = data["summary"]
    assert s["dipole_vs_exact_angle_median_deg_6plus"] <= s["dipole_vs_exact_angle_max_deg_6plus"]
    assert s["dipole_vs_exact_angle_max_deg_6plus"] < s["uniform_vs_exact_angle_max_deg_6plus"]


def test_validation_field_changes_the_answer(capsys):
    weak = _json(capsys, ["validation", "--no-files", "--field-mT", "5"])
    strong = _json(capsys, ["validation", "--no-files", "--field-mT", "40"])
    assert weak["differences"] != strong["differences"]


def test_clinical_veins_only_writes_what_it_names(capsys, tmp_path):
    data = _json(capsys, ["clinical", "--chains", "today", "--ring-step", "0", "--no-sizing", "--out", str(tmp_path)])
    assert data["setup"]["diameter_mm"] == 119.0 and data["setup"]["ring_step"] == 0
    assert [r["group"] for r in data["rows"]] == ["vein"] * 4  # the four veins, no ring target
    assert {r["chain"] for r in data["rows"]} == {"today"}
    for row in data["rows"]:
        assert row["force_gf"] >= 0.0
        if row["feasible"]:  # held at its friction: the sheath's push and the gradient's pull add up
            assert row["force_gf"] == pytest.approx(row["sheath_push_gf"] + row["gradient_pull_gf"], abs=1e-6)
    for name in ("clinical.csv", "clinical.json", "clinical_forces.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert json.loads((tmp_path / "clinical.json").read_text())["rows"] == data["rows"]


def test_clinical_no_files_writes_nothing(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _json(capsys, ["clinical", "--chains", "today", "--ring-step", "0", "--no-sizing", "--no-files"])
    assert list(tmp_path.iterdir()) == []
