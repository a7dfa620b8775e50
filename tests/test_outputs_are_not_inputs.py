"""An output never replaces a file the same run reads (issue 41, item 2).

The loaders register every file they read (``safe_files.register_input``: the anatomy file, the
mesh and targets CSV it names, the scenarios file, a scenario's ``atrium_file``, a sweep spec);
``check_output_file`` / ``check_output_dir`` refuse an output that is one of them (by its path
once links are followed, or as a hard link of it), or a folder holding one where the run writes
a file of that name, before any work: exit status 2, one line naming the flag and the input;
``atomic_path`` refuses it at the latest (exit status 1). In each case the input keeps its bytes.

The commands run in-process (``ballchain.cli.main``): the refusals come before the build.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest
from anatomy_helpers import lumen_anatomy

from ballchain.cli import main as cli_main
from ballchain.infrastructure import safe_files
from ballchain.infrastructure.errors import OutputError, UserInputError
from ballchain.infrastructure.safe_files import (atomic_write_text, check_output_dir, check_output_file, input_at,
                                               register_input)


@pytest.fixture(autouse=True)
def fresh_inputs():
    """Each test starts with no registered input (the registry is the process's)."""
    safe_files.forget_inputs()
    yield
    safe_files.forget_inputs()


def _digests(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


def _refused(capsys, argv, *named: str) -> str:
    code = cli_main([str(a) for a in argv])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert "\n" not in err and "Traceback" not in err, err
    assert "is an input of this run" in err, err
    for text in named:
        assert text in err, err
    return err


def _link(kind: str, target: Path, link: Path) -> Path:
    if kind == "symlink":
        link.symlink_to(target.resolve())
    else:
        os.link(target, link)
    return link


# --- the checks themselves ---------------------------------------------------------------------

@pytest.mark.parametrize("how", ["itself", "relative", "symlink", "hardlink", "folder_symlink"])
def test_an_input_is_refused_as_an_output_file_by_any_name(tmp_path, how):
    data = tmp_path / "in" / "atrium.stl"
    data.parent.mkdir()
    data.write_bytes(b"solid x\nendsolid x\n")
    register_input(data, "anatomy mesh")
    if how == "itself":
        out = data
    elif how == "relative":
        out = Path(os.path.relpath(data))
    elif how == "folder_symlink":
        (tmp_path / "alias").symlink_to(data.parent)
        out = tmp_path / "alias" / "atrium.stl"
    else:
        out = _link(how, data, tmp_path / "replay.html")
    with pytest.raises(UserInputError, match=r"--html .* is an input of this run \(anatomy mesh.*\): choose "
                                             "another name"):
        check_output_file(out, "--html")
    with pytest.raises(OutputError, match=r"is an input of this run \(anatomy mesh.*nothing was replaced"):
        atomic_write_text(out, "<html></html>\n")  # the last guard, for a writer that did not check
    assert data.read_bytes() == b"solid x\nendsolid x\n"
    assert sorted(p.name for p in data.parent.iterdir()) == ["atrium.stl"]  # no temporary file left


def test_an_output_folder_holding_an_input_under_a_name_the_run_writes_is_refused(tmp_path):
    spec = tmp_path / "o" / "sweep.json"
    spec.parent.mkdir()
    spec.write_text("{}\n")
    register_input(spec, "sweep spec")
    with pytest.raises(UserInputError, match=r"--out .*: 'sweep.json' in it is an input of this run \(sweep spec\), "
                                             "and this run writes a file of that name there: choose another folder"):
        check_output_dir(spec.parent, "--out", names=("table.csv", "sweep.json"))
    check_output_dir(spec.parent, "--out", names=("table.csv",))  # a folder holding an input is fine otherwise


def test_other_files_and_absent_names_are_not_inputs(tmp_path):
    data = tmp_path / "targets.csv"
    data.write_text("1,2,3\n")
    register_input(data, "anatomy targets CSV")
    other = tmp_path / "copy.csv"
    other.write_text("1,2,3\n")  # the same bytes, another file
    assert input_at(other) is None and input_at(tmp_path / "new.html") is None
    assert input_at(data) == (os.path.realpath(data), "anatomy targets CSV")
    check_output_file(other, "--html")
    atomic_write_text(other, "replaced\n")
    assert other.read_text() == "replaced\n"
    data.unlink()  # the input gone: a hard link of it made before (``other`` is not) cannot be found by it
    assert input_at(other) is None
    safe_files.forget_inputs()
    assert input_at(data) is None


# --- the commands ------------------------------------------------------------------------------

@pytest.mark.parametrize("name, what", [("atrium.stl", "anatomy mesh"), ("anatomy.yaml", "anatomy file"),
                                        ("targets.csv", "anatomy targets CSV")])
def test_teleop_html_that_is_one_of_the_anatomy_s_files_is_refused(tmp_path, capsys, name, what):
    anatomy = lumen_anatomy(tmp_path)
    before = _digests(tmp_path)
    _refused(capsys, ["teleop", "--anatomy", anatomy, "--html", tmp_path / name, "--targets", "1", "--no-progress"],
             f"--html '{tmp_path / name}'", f"({what})")
    assert _digests(tmp_path) == before


@pytest.mark.parametrize("kind", ["symlink", "hardlink"])
def test_teleop_html_linked_to_the_mesh_is_refused(tmp_path, capsys, kind):
    (tmp_path / "a").mkdir()
    anatomy = lumen_anatomy(tmp_path / "a")
    html = _link(kind, anatomy.parent / "atrium.stl", tmp_path / "replay.html")
    before = _digests(anatomy.parent)
    _refused(capsys, ["teleop", "--anatomy", anatomy, "--html", html, "--targets", "1", "--no-progress"],
             "--html", "(anatomy mesh '")
    assert _digests(anatomy.parent) == before
    assert html.is_symlink() == (kind == "symlink")


@pytest.mark.parametrize("kind", ["symlink", "hardlink"])
def test_simulate_html_linked_to_an_input_is_refused(tmp_path, capsys, kind):
    (tmp_path / "a").mkdir()
    anatomy = lumen_anatomy(tmp_path / "a")
    html = _link(kind, anatomy, tmp_path / "replay.html")
    before = _digests(anatomy.parent)
    _refused(capsys, ["simulate", "--scenario", "teleop_right_unit", "--anatomy", anatomy, "--duration", "0.01",
                      "--no-progress", "--html", html], "(anatomy file '")
    assert _digests(anatomy.parent) == before


def test_procedure_html_and_out_that_hold_inputs_are_refused(tmp_path, capsys):
    (tmp_path / "a").mkdir()
    anatomy = lumen_anatomy(tmp_path / "a")
    # A targets file named like the procedure's output (the CSV reader takes any name).
    os.replace(tmp_path / "a" / "targets.csv", tmp_path / "a" / "procedure.json")
    anatomy.write_text(anatomy.read_text().replace("targets.csv", "procedure.json"))
    before = _digests(anatomy.parent)
    html = _link("symlink", anatomy.parent / "atrium.stl", tmp_path / "replay.html")
    _refused(capsys, ["procedure", "--anatomy", anatomy, "--targets", "1", "--html", html], "(anatomy mesh '")
    _refused(capsys, ["procedure", "--anatomy", anatomy, "--targets", "1", "--out", anatomy.parent],
             "'procedure.json' in it", "(anatomy targets CSV)", "choose another folder")
    assert _digests(anatomy.parent) == before


SPEC = '{"experiment": "statics", "grid": {"n_balls": [4]}}\n'  # JSON is YAML: a spec may be named sweep.json


@pytest.mark.parametrize("how", ["in_out", "out_is_a_link_to_its_folder", "hardlink_in_out"])
def test_sweep_out_holding_its_own_spec_is_refused(tmp_path, capsys, how):
    spec = tmp_path / "o" / "sweep.json"
    spec.parent.mkdir()
    spec.write_text(SPEC)
    out = spec.parent
    if how == "out_is_a_link_to_its_folder":
        out = tmp_path / "alias"
        out.symlink_to(spec.parent)
    elif how == "hardlink_in_out":
        spec = tmp_path / "spec.json"
        spec.write_text(SPEC)
        out = tmp_path / "o2"
        out.mkdir()
        os.link(spec, out / "sweep.json")
    _refused(capsys, ["sweep", spec, "--out", out, "--workers", "0", "--no-progress"],
             "'sweep.json' in it", "(sweep spec")
    assert spec.read_text() == SPEC
    assert not (out / "table.csv").exists() and not (out / "table.parquet").exists()


def test_reproduce_out_holding_an_input_under_a_name_it_writes_is_refused(tmp_path, capsys):
    """reproduce reads no user file itself; an input registered earlier in the process (a
    script's anatomy, spec...) under a name the report takes is refused all the same."""
    (tmp_path / "o").mkdir()
    kept = tmp_path / "o" / "report.md"
    kept.write_text("# my notes\n")
    register_input(kept, "anatomy file")
    (tmp_path / "alias").symlink_to(tmp_path / "o")
    for out in (tmp_path / "o", tmp_path / "alias"):
        _refused(capsys, ["reproduce", "--out", out, "--sections", "sizing"], "'report.md' in it", "(anatomy file")
    assert kept.read_text() == "# my notes\n"
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["report.md"]
