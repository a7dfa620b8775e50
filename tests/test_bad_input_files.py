"""Input files checked before they are read (infrastructure/input_files.py): every file a user
names (an anatomy file, its mesh and targets CSV, a scenario's anatomy and atrium_file, a sweep
spec, a scenarios file, the records a resumed run reads back) is refused in one line, exit status
2, when its name is longer than the file system allows, when it is not a regular file, or when it
is larger than its kind's limit (sparse files: they cost nothing); and no message quotes a file's
contents: a credentials file or ``/proc/self/environ`` given where a targets CSV, a mesh, an
anatomy file or a sweep spec goes never shows in the error.

CLI cases run in-process (``ballchain.cli.main``), except those that read the process's own
environment or that would read gigabytes if a check were missing (a child under a 4 GB address
limit, as the audit ran them).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from anatomy_helpers import lumen_anatomy

from ballchain.cli import main
from ballchain.infrastructure.errors import UserInputError

SECRET = "AKIA_SECRET_TOKEN_123"
LONG = "x" * 300  # a name longer than the file system's 255 bytes
TOO_LONG = "longer than the file system allows"
SET_HEART = ["simulate", "--scenario", "heart_no_field", "--set"]


def _cli(capsys, argv) -> tuple[int, list[str]]:
    code = main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err, err[-2000:]
    return code, [line for line in err.splitlines() if line.strip()]


def _one_line(capsys, argv, *expected: str) -> str:
    code, lines = _cli(capsys, argv)
    assert code == 2 and len(lines) == 1, (code, lines)
    for text in expected:
        assert text in lines[0], lines[0]
    return lines[0]


def _with(anatomy: Path, **fields) -> Path:
    """The anatomy file with some of its lines replaced."""
    lines = dict(line.split(": ", 1) for line in anatomy.read_text().splitlines())
    lines.update(fields)
    anatomy.write_text("".join(f"{k}: {v}\n" for k, v in lines.items()))
    return anatomy


# ------------------------------------------------------------------------------ no file's contents quoted

# Files that are not what the user meant: each holds SECRET where a parser would look first.
SECRET_FILES = {
    "token": f"{SECRET}\n",
    "ini": f"[default]\naws_access_key_id = {SECRET}\n",
    "env": f"AWS_ACCESS_KEY_ID={SECRET}\nHOME=/root\n",
    "csv-header": f"{SECRET},b,c\n1,2,3\n",
    "csv-row": f"x,y,z\n1,2,{SECRET}\n",
    "csv-fields": f"1,2,3,4,{SECRET}\n",
    "obj": f"v {SECRET} 1 2\nf 1 2 3\n",
    "stl": f"solid {SECRET}\nfacet normal 0 0 1\nouter loop\nvertex {SECRET} 1 2\n",
    "ply": f"ply\nformat {SECRET} 1.0\nend_header\n",
    "ply-property": f"ply\nformat ascii 1.0\nelement vertex 3\nproperty {SECRET} x\nend_header\n",
    "yaml-tag": f"!{SECRET} x\n",
    "yaml-value": f"mesh: {{a: b}}\nkey: {SECRET}\n",
}


ROLES = {  # where the file is given: the files a parser of that kind reads
    "targets": ["token", "ini", "env", "csv-header", "csv-row", "csv-fields"],
    "mesh": ["token", "obj", "stl", "ply", "ply-property"],
    "atrium_file": ["obj", "stl", "ply"],
    "anatomy": ["token", "ini", "env", "yaml-tag", "yaml-value"],
    "scenario anatomy": ["token", "env", "yaml-tag"],
    "sweep spec": ["token", "ini", "env", "yaml-tag", "yaml-value"],
}


@pytest.mark.parametrize("role,name", [(r, n) for r, names in ROLES.items() for n in names])
def test_no_message_quotes_the_contents_of_a_file(tmp_path, monkeypatch, capsys, role, name):
    """Whatever the file holds and wherever it is given, the one-line refusal names the file,
    the line and the kind of problem, never its contents."""
    monkeypatch.chdir(tmp_path)  # short names: the messages cut long ones
    kind = name.split("-")[0]
    secret = Path(f"secret_{name}" + (f".{kind}" if kind in ("obj", "stl", "ply") else ".obj" if role in (
        "mesh", "atrium_file") else ""))  # the mesh readers go by the suffix
    secret.write_text(SECRET_FILES[name])
    anatomy = lumen_anatomy(tmp_path)
    argv = {
        "targets": lambda: ["plan", "--anatomy", str(_with(anatomy, targets=secret.name))],
        "mesh": lambda: ["plan", "--anatomy", str(_with(anatomy, mesh=secret.name))],
        "anatomy": lambda: ["plan", "--anatomy", str(secret)],
        "sweep spec": lambda: ["sweep", str(secret), "--out", "out"],
        "scenario anatomy": lambda: SET_HEART + [f"{{anatomy: {secret}}}"],
        "atrium_file": lambda: SET_HEART + [f"{{atrium_file: {secret}, puncture: [0.02, 0, 0]}}"],
    }[role]()
    code, lines = _cli(capsys, argv)
    assert code == 2 and len(lines) == 1, (code, lines)
    assert SECRET not in lines[0], lines[0]
    assert secret.name in lines[0], lines[0]


@pytest.mark.slow
def test_the_environment_of_the_process_is_not_quoted(tmp_path):
    """The audit's case: targets: /proc/self/environ quoted the first characters of the
    environment (an access key) in the error. Its size says 0: it is read up to the limit."""
    if not Path("/proc/self/environ").exists():
        pytest.skip("no /proc")
    anatomy = _with(lumen_anatomy(tmp_path), targets="/proc/self/environ")
    env = {"AAA_ACCESS_KEY": SECRET, **os.environ}  # first: what the header's message quoted
    done = subprocess.run([sys.executable, "-m", "ballchain", "plan", "--anatomy", str(anatomy)], env=env,
                          capture_output=True, text=True, timeout=600)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2 and len(lines) == 1, (done.returncode, lines)
    assert SECRET not in done.stderr and "/proc/self/environ" in lines[0] and "row 1" in lines[0], lines[0]


@pytest.mark.parametrize("text,message", [
    ("x,y,z\n1,2,nan\n", "row 2: its z is not a finite number"),
    ("x,y,z\n1,2\n", "row 2: 2 fields, expected 3"),
    ("a,b,c\n1,2,3\n", "row 1: a header (a row without numbers) must name the columns x, y, z"),
])
def test_a_targets_csv_s_problem_is_its_row_and_kind(tmp_path, text, message):
    from ballchain.drake_models.anatomy import load_anatomy

    with pytest.raises(UserInputError) as err:
        load_anatomy(lumen_anatomy(tmp_path, csv_text=text))
    assert message in str(err.value) and "targets 'targets.csv'" in str(err.value), str(err.value)


# ------------------------------------------------------------------------------ names too long

@pytest.mark.parametrize("role", ["anatomy", "mesh", "targets", "sweep spec", "scenario anatomy", "atrium_file",
                                  "scenarios file"])
def test_a_name_longer_than_the_file_system_allows_is_one_line(tmp_path, monkeypatch, capsys, role):
    """A 300-character name ended in an ``OSError: File name too long`` traceback: one line
    naming the field and saying the name is too long."""
    long_path = Path(f"{LONG}.yaml")
    if role == "scenarios file":
        from ballchain.systems.chain_scenario import load_scenario

        with pytest.raises(UserInputError, match=f"scenarios file .*{TOO_LONG}"):
            load_scenario("heart_no_field", filename=tmp_path / long_path)
        return
    monkeypatch.chdir(tmp_path)
    anatomy = lumen_anatomy(tmp_path)
    argv, named = {
        "anatomy": lambda: (["plan", "--anatomy", str(long_path)], "anatomy file"),
        "mesh": lambda: (["plan", "--anatomy", str(_with(anatomy, mesh=f"{LONG}.stl"))], "mesh 'xxx"),
        "targets": lambda: (["plan", "--anatomy", str(_with(anatomy, targets=f"{LONG}.csv"))], "targets 'xxx"),
        "sweep spec": lambda: (["sweep", str(long_path), "--out", "out"], "sweep spec"),
        "scenario anatomy": lambda: (SET_HEART + [f"{{anatomy: {long_path}}}"], "scenario anatomy"),
        "atrium_file": lambda: (SET_HEART + [f"{{atrium_file: {LONG}.stl, puncture: [0.02, 0, 0]}}"],
                                "scenario atrium_file"),
    }[role]()
    line = _one_line(capsys, argv, named, TOO_LONG, "(255 bytes per name)")
    assert len(line) < 600, line


# ------------------------------------------------------------------------------ not a regular file

@pytest.mark.parametrize("kind", ["fifo", "device", "loop", "folder"])
@pytest.mark.parametrize("role", ["anatomy", "mesh", "targets", "sweep spec", "atrium_file"])
def test_an_input_that_is_not_a_regular_file_is_one_line(tmp_path, monkeypatch, capsys, role, kind):
    """A named pipe (reading it would wait for a writer), a device that never ends, a loop of
    links and a folder: refused by the one input check, whichever field names them."""
    monkeypatch.chdir(tmp_path)
    odd = Path(f"odd_{kind}." + {"mesh": "stl", "atrium_file": "stl", "targets": "csv"}.get(role, "yaml"))
    if kind == "fifo":
        os.mkfifo(odd)
    elif kind == "device":
        odd.symlink_to("/dev/urandom")
    elif kind == "loop":
        odd.symlink_to("other")
        Path("other").symlink_to(odd)
    else:
        odd.mkdir()
    anatomy = lumen_anatomy(tmp_path)
    argv = {
        "anatomy": lambda: ["plan", "--anatomy", str(odd)],
        "mesh": lambda: ["plan", "--anatomy", str(_with(anatomy, mesh=str(odd)))],
        "targets": lambda: ["plan", "--anatomy", str(_with(anatomy, targets=str(odd)))],
        "sweep spec": lambda: ["sweep", str(odd), "--out", "out"],
        "atrium_file": lambda: SET_HEART + [f"{{atrium_file: '{odd}', puncture: [0.02, 0, 0]}}"],
    }[role]()
    phrase = {"fifo": "is a named pipe", "device": "is a character device", "loop": "a loop of symbolic links",
              "folder": "is a folder"}[kind]
    _one_line(capsys, argv, odd.name, phrase)


# ------------------------------------------------------------------------------ sizes checked before reading

def _sparse(path: Path, size: int) -> Path:
    with open(path, "wb") as f:
        f.truncate(size)
    return path


@pytest.mark.parametrize("role", ["mesh", "atrium_file", "targets", "anatomy", "sweep spec", "scenarios file"])
def test_a_file_larger_than_its_kind_s_limit_is_refused_naming_the_limit(tmp_path, monkeypatch, capsys, role):
    """One byte over the limit (a sparse file): refused from its size, the limit in the message."""
    from ballchain.infrastructure.input_files import MAX_MESH_BYTES, MAX_TABLE_TEXT_BYTES
    from ballchain.infrastructure.safe_yaml import MAX_BYTES

    limit = {"mesh": MAX_MESH_BYTES, "atrium_file": MAX_MESH_BYTES, "targets": MAX_TABLE_TEXT_BYTES}.get(role,
                                                                                                      MAX_BYTES)
    suffix = {"mesh": "stl", "atrium_file": "stl", "targets": "csv"}.get(role, "yaml")
    monkeypatch.chdir(tmp_path)
    big = _sparse(Path(f"big.{suffix}"), limit + 1)
    if role == "scenarios file":
        from ballchain.systems.chain_scenario import load_scenario

        with pytest.raises(UserInputError, match=rf"scenarios file 'big.yaml': .*more than .*{limit} bytes\) allowed"):
            load_scenario("heart_no_field", filename=big)
        return
    anatomy = lumen_anatomy(tmp_path)
    argv = {
        "mesh": lambda: ["plan", "--anatomy", str(_with(anatomy, mesh=big.name))],
        "atrium_file": lambda: SET_HEART + [f"{{atrium_file: {big}, puncture: [0.02, 0, 0]}}"],
        "targets": lambda: ["plan", "--anatomy", str(_with(anatomy, targets=big.name))],
        "anatomy": lambda: ["plan", "--anatomy", str(big)],
        "sweep spec": lambda: ["sweep", str(big), "--out", "out"],
    }[role]()
    _one_line(capsys, argv, big.name, f"({limit + 1} bytes), more than the", f"({limit} bytes) allowed")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["atrium.stl", "targets.csv"])
def test_an_8_gb_sparse_input_is_refused_under_a_4_gb_address_limit(tmp_path, name):
    """The audit's case, in a child limited to 4 GB of address space: an 8 GB sparse mesh or
    targets CSV was read whole (a MemoryError traceback); now one line, before reading."""
    resource = pytest.importorskip("resource")
    anatomy = lumen_anatomy(tmp_path)
    _sparse(tmp_path / name, 8 << 30)

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (4_000_000_000, 4_000_000_000))

    done = subprocess.run([sys.executable, "-m", "ballchain", "plan", "--anatomy", str(anatomy)], preexec_fn=limit,
                          capture_output=True, text=True, timeout=600)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2 and len(lines) == 1, (done.returncode, lines[-3:])
    assert name in lines[0] and "(8589934592 bytes), more than the" in lines[0], lines[0]


def test_a_file_that_says_it_is_small_is_read_only_up_to_the_limit(tmp_path):
    """The size a file's folder gives is checked, and so is what is read: a file longer than the
    limit (here: a limit below its size, as /proc's files say 0) is refused, not read whole."""
    from ballchain.infrastructure.input_files import read_input_file

    path = tmp_path / "t.csv"
    path.write_bytes(b"1,2,3\n" * 100)
    assert read_input_file(path, "t", 600) == b"1,2,3\n" * 100
    with pytest.raises(UserInputError, match="t: the file is 600 bytes, more than the 599 bytes allowed"):
        read_input_file(path, "t", 599)
    if Path("/proc/self/status").exists():
        assert os.stat("/proc/self/status").st_size == 0
        with pytest.raises(UserInputError, match="holds more than the 10 bytes allowed"):
            read_input_file("/proc/self/status", "status", 10)


def test_resume_records_larger_than_their_limit_are_not_read(tmp_path, capsys):
    """What a resumed run reads back from its folder: a sweep's table and a report section's
    record, each bounded (a table over the limit is set aside as unreadable; a record over it
    runs its section again, with a line)."""
    from ballchain import reproduce, sweep

    _sparse(tmp_path / sweep.TABLE_PARQUET, sweep.MAX_TABLE_BYTES + 1)
    with pytest.raises(UserInputError, match=f"table.parquet: the file is .*{sweep.MAX_TABLE_BYTES} bytes"):
        sweep.read_table(tmp_path)
    (tmp_path / reproduce.CACHE).mkdir()
    _sparse(tmp_path / reproduce.CACHE / "forces.json", reproduce.MAX_RECORD_BYTES + 1)
    assert reproduce._cached(tmp_path, "forces", "key") is None
    err = capsys.readouterr().err
    assert "record of the finished section 'forces'" in err and f"{reproduce.MAX_RECORD_BYTES} bytes" in err, err
