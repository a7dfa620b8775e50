"""Endings made clear (issue 41, item 8): ``reproduce`` stops when its results folder goes.

A results folder deleted (or replaced) while ``reproduce`` runs ended with exit status 0 and a
report citing files that were no longer there: the run now checks, before each section and
before each report, that ``--out`` is still the folder it started in (device and inode), and
stops with one line, exit status 1. The sections here are stand-ins (``reproduce.EXPERIMENTS``
replaced) that write a file each, as the real ones write their figures.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from ballchain import reproduce
from ballchain.cli import main as cli_main
from ballchain.drake_models.errors import OutputError


def _sections(calls: list, act=None):
    """Three stand-in sections; ``act(name, out)`` runs inside each, before its file is written."""
    from ballchain.drake_models.safe_files import atomic_write_text
    from ballchain.report import Section

    def make(name):
        def section(out: Path, quick: bool):
            calls.append(name)
            if act is not None:
                act(name, out)
            atomic_write_text(out / name / f"{name}.txt", f"{name}\n")
            return Section(f"Section {name}").text(f"{name} done: `{name}/{name}.txt`"), {"n": name}
        return section

    return [(name, make(name)) for name in ("one", "two", "three")]


def _one_line(capsys, code: int, expected: int) -> str:
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("ballchain reproduce")]
    assert code == expected, err
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def test_the_results_folder_deleted_during_a_section_stops_the_run_with_exit_1(tmp_path, monkeypatch, capsys):
    out = tmp_path / "results"
    calls = []
    # During section two the folder goes; the section's own write then makes an empty one again.
    monkeypatch.setattr(reproduce, "EXPERIMENTS",
                        _sections(calls, lambda name, o: shutil.rmtree(o) if name == "two" else None))
    line = _one_line(capsys, cli_main(["reproduce", "--out", str(out)]), 1)
    assert f"--out '{out}' was deleted or replaced" in line and "stopped before the data of section 'two'" in line
    assert calls == ["one", "two"]  # section three never started
    assert sorted(p.name for p in out.iterdir()) == ["two"]  # no report citing section one's files


def test_the_results_folder_deleted_between_sections_stops_before_the_next(tmp_path, monkeypatch):
    out = tmp_path / "results"
    calls = []

    def delete_after_one(name, o):
        if name == "two":
            return
        if name == "one":  # the section ends normally; the folder goes just after its report
            real = reproduce.write_report

            def write_then_delete(*args, **kwargs):
                real(*args, **kwargs)
                monkeypatch.setattr(reproduce, "write_report", real)
                shutil.rmtree(o)

            monkeypatch.setattr(reproduce, "write_report", write_then_delete)

    monkeypatch.setattr(reproduce, "EXPERIMENTS", _sections(calls, delete_after_one))
    with pytest.raises(OutputError, match=r"was deleted during the run: stopped before section 'two'; nothing more"):
        reproduce.run(out=out)
    assert calls == ["one"] and not out.exists()


def test_a_results_folder_replaced_by_another_is_not_written_into(tmp_path, monkeypatch):
    out = tmp_path / "results"
    calls = []

    def swap(name, o):
        if name == "two":  # another folder moved to the name (a sync tool, a second run's clean-up)
            os.rename(o, tmp_path / "old")
            (tmp_path / "elsewhere").mkdir()
            os.rename(tmp_path / "elsewhere", o)

    monkeypatch.setattr(reproduce, "EXPERIMENTS", _sections(calls, swap))
    with pytest.raises(OutputError, match="was deleted or replaced"):
        reproduce.run(out=out)
    assert not (out / "report.md").exists() and (tmp_path / "old" / "report.md").exists()


def test_a_run_whose_folder_stays_is_unchanged(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(reproduce, "EXPERIMENTS", _sections(calls))
    data = reproduce.run(out=tmp_path / "results")
    assert calls == ["one", "two", "three"] and data["report_md"].exists()
    assert "Section three" in data["report_md"].read_text()
