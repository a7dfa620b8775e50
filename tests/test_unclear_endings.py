"""Endings made clear (issue 41, item 8): ``reproduce`` stops when its results folder goes, and a
mesh that crosses itself is said (a note, or a refusal when the wall distance would be wrong).

A results folder deleted (or replaced) while ``reproduce`` runs ended with exit status 0 and a
report citing files that were no longer there: the run now checks, before each section and
before each report, that ``--out`` is still the folder it started in (device and inode), and
stops with one line, exit status 1. The sections here are stand-ins (``reproduce.registry.SECTIONS``
replaced) that write a file each, as the real ones write their figures.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from ballchain import reproduce
from ballchain.cli import main as cli_main
from ballchain.infrastructure.errors import OutputError


def _sections(calls: list, act=None):
    """Three stand-in sections; ``act(name, out)`` runs inside each, before its file is written."""
    from ballchain.infrastructure.safe_files import atomic_write_text
    from ballchain.report import Section

    def make(name):
        def section(out: Path, quick: bool):
            calls.append(name)
            if act is not None:
                act(name, out)
            atomic_write_text(out / name / f"{name}.txt", f"{name}\n")
            return Section(f"Section {name}").text(f"{name} done: `{name}/{name}.txt`"), {"n": name}
        return section

    return [reproduce.ReportSection(name, make(name)) for name in ("one", "two", "three")]


def _one_line(capsys, code: int, expected: int) -> str:
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("ballchain reproduce")]
    assert code == expected, err
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def test_the_results_folder_deleted_during_a_section_stops_the_run_with_exit_1(tmp_path, monkeypatch, capsys):
    out = tmp_path / "results"
    calls = []
    # During section two the folder goes; the section's own write then makes an empty one again.
    monkeypatch.setattr(reproduce.registry, "SECTIONS",
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
            real = reproduce.runner.write_report

            def write_then_delete(*args, **kwargs):
                real(*args, **kwargs)
                monkeypatch.setattr(reproduce.runner, "write_report", real)
                shutil.rmtree(o)

            monkeypatch.setattr(reproduce.runner, "write_report", write_then_delete)

    monkeypatch.setattr(reproduce.registry, "SECTIONS", _sections(calls, delete_after_one))
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

    monkeypatch.setattr(reproduce.registry, "SECTIONS", _sections(calls, swap))
    with pytest.raises(OutputError, match="was deleted or replaced"):
        reproduce.run(out=out)
    assert not (out / "report.md").exists() and (tmp_path / "old" / "report.md").exists()


def test_a_run_whose_folder_stays_is_unchanged(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(reproduce.registry, "SECTIONS", _sections(calls))
    data = reproduce.run(out=tmp_path / "results")
    assert calls == ["one", "two", "three"] and data["report_md"].exists()
    assert "Section three" in data["report_md"].read_text()


# --- a shell that crosses itself ------------------------------------------------------------------

def helix_tube(pitch: float, turn_deg: float = 400.0, R: float = 14.0, r: float = 7.0, n_along: int = 100,
               n_around: int = 96) -> tuple[np.ndarray, np.ndarray]:
    """(V [mm], F): a capped tube of radius r along a helix of radius R turning ``turn_deg``: its
    end overlaps its start when the turns are closer than 2 r (perpendicular to the tube). One
    closed shell, consistently oriented outward, about 45 x 45 x 30 mm: every check but
    self-intersection passes."""
    from ballchain.drake_models import mesh_tools as mt

    th = np.radians(np.linspace(0.0, turn_deg, n_along))
    c = np.stack([R * np.cos(th), R * np.sin(th), pitch * th / (2 * np.pi)], axis=1)
    t = np.gradient(c, axis=0)
    t /= np.linalg.norm(t, axis=1)[:, None]
    u = np.stack([np.cos(th), np.sin(th), 0 * th], axis=1)
    u -= (u * t).sum(axis=1)[:, None] * t
    u /= np.linalg.norm(u, axis=1)[:, None]
    v = np.cross(t, u)
    ph = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    V = (c[:, None] + r * (np.cos(ph)[None, :, None] * u[:, None] + np.sin(ph)[None, :, None] * v[:, None]))
    V = np.vstack([V.reshape(-1, 3), c[0], c[-1]])
    i, j = np.meshgrid(np.arange(n_along - 1), np.arange(n_around), indexing="ij")
    a, b = (i * n_around + j).ravel(), (i * n_around + (j + 1) % n_around).ravel()
    F = np.concatenate([np.stack([a, b, b + n_around], 1), np.stack([a, b + n_around, a + n_around], 1)])
    s, e, last = len(V) - 2, len(V) - 1, (n_along - 1) * n_around
    ring = np.arange(n_around)
    F = np.concatenate([F, np.stack([np.full(n_around, s), (ring + 1) % n_around, ring], 1),
                        np.stack([np.full(n_around, e), last + ring, last + (ring + 1) % n_around], 1)])
    return V, (F if mt.enclosed_volume(V, F) > 0 else F[:, [0, 2, 1]])


def test_the_crossing_test_finds_a_shell_crossing_itself_not_separate_shells():
    from ballchain.drake_models import mesh_tools as mt
    from ballchain.drake_models.atrium_mesh import self_crossings, shell_labels

    U, F = mt.icosphere(5)
    assert len(self_crossings(U * 25.0, F)) == 0  # a clean closed surface
    V2, F2 = np.vstack([U * 25.0, U * 12.0 + [20.0, 0, 0]]), np.vstack([F, F + len(U)])  # two spheres overlapping
    assert len(self_crossings(V2, F2)) > 0
    assert len(self_crossings(V2, F2, shell_labels(F2, V2))) == 0  # across shells: the accepted union
    V, F = helix_tube(pitch=6.0)
    pairs = self_crossings(V, F)
    assert len(pairs) > 0
    assert not (F[pairs[:, 0]][:, :, None] == F[pairs[:, 1]][:, None, :]).any()  # no pair shares a corner


@pytest.mark.slow
def test_a_shell_overlapping_itself_deeply_is_refused(tmp_path, capsys):
    """The tube's end inside its start: the winding number is 2 there (still inside: the inside
    test gives the union), but the buried triangles stay in the surface, so the wall distance
    was off by up to 6 mm there and the contact wall grew into the chamber. Accepted before."""
    from ballchain.drake_models.atrium_mesh import AtriumMeshError, validate_surface, write_stl_binary

    V, F = helix_tube(pitch=6.0)
    with pytest.raises(AtriumMeshError, match=r"intersects itself: \d+ pairs of its triangles cross .* parts of it "
                                              r"lie up to [5-7]\.\d mm on the wrong side of it"):
        validate_surface(V, F, "mm")
    write_stl_binary(tmp_path / "tube.stl", V, F)
    (tmp_path / "anatomy.yaml").write_text("mesh: tube.stl\nlength_unit: mm\nside: lumen\ntargets: [[14, 0, 7]]\n"
                                           "sheath: {puncture: [14, 0, -7]}\n")
    code = cli_main(["simulate", "--scenario", "teleop_right_unit", "--anatomy", str(tmp_path / "anatomy.yaml"),
                     "--duration", "0.01", "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "Traceback" not in err, err
    assert "mesh 'tube.stl'" in err and "intersects itself" in err and "remove the self-intersections" in err


@pytest.mark.parametrize("overlap_mm, refused", [(0.01, False), (0.3, True)])
def test_a_shallow_self_crossing_is_a_note_on_stderr_and_a_deeper_one_refused(capsys, overlap_mm, refused):
    """Turns of the tube that just touch (their axes 2 r - overlap apart): the buried lens is
    about sqrt(r overlap) wide, 0.3 mm for 0.01 mm, 1.4 mm for 0.3 mm."""
    from scipy.optimize import brentq

    from ballchain.drake_models.atrium_mesh import AtriumMeshError, validate_surface

    gap = lambda p: p * np.cos(np.arctan(p / (2 * np.pi * 14.0))) - (14.0 - overlap_mm)  # noqa: E731
    V, F = helix_tube(pitch=brentq(gap, 10.0, 20.0))
    if refused:
        with pytest.raises(AtriumMeshError, match=r"up to 1\.\d mm on the wrong side"):
            validate_surface(V, F, "mm")
        return
    surface = validate_surface(V, F, "mm")
    err = capsys.readouterr().err
    assert "atrium mesh: note: the surface intersects itself" in err and "within 0.3 mm of its boundary" in err
    assert any("intersects itself" in note for note in surface.notes)
