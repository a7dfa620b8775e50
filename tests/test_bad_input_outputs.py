"""Outputs that are not plain files, names too long and a full disk (infrastructure/safe_files.py).

Only regular files are ever replaced: a device (``/dev/null``), a socket or a folder at an
output path is refused before any work (exit status 2, one line), also behind a symbolic link;
a named pipe is written into; a link to a file stays a link. A name longer than the file system
allows and a disk without room are refused up front; a write that fails anyway (the disk filled
up during the run) is one line, exit status 1, and the destination keeps its old content.
"""

from __future__ import annotations

import errno
import os
import shutil
import stat
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from ballchain.cli import main as cli_main
from ballchain.infrastructure import safe_files
from ballchain.infrastructure.errors import OutputError, UserInputError
from ballchain.infrastructure.safe_files import atomic_path, atomic_write_text, check_output_dir, check_output_file

SIMULATE = ["simulate", "--scenario", "free_space_uniform_90deg", "--duration", "0.003", "--no-progress", "--json"]


def _char_device(tmp_path: Path) -> Path:
    """A character device like /dev/null (same numbers) in tmp_path; skips where mknod is not permitted."""
    dev = tmp_path / "null"
    try:
        os.mknod(dev, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    except (PermissionError, OSError) as err:
        pytest.skip(f"cannot create a device here: {err}")
    return dev


def _one_line_error(capsys, code: int, expected: int = 2) -> str:
    err = capsys.readouterr().err.strip()
    assert code == expected, err
    assert "\n" not in err and "Traceback" not in err, err
    return err


def test_dev_null_is_refused_as_html_and_left_alone(capsys):
    before = os.stat("/dev/null")
    with pytest.raises(UserInputError, match=r"--html '/dev/null' is a character device, not a regular file"):
        check_output_file("/dev/null", "--html")
    err = _one_line_error(capsys, cli_main([*SIMULATE, "--html", "/dev/null"]))
    assert "--html '/dev/null' is a character device" in err
    after = os.stat("/dev/null")
    assert stat.S_ISCHR(after.st_mode) and after.st_ino == before.st_ino


def test_a_character_device_is_never_replaced_by_the_writer(tmp_path):
    dev = _char_device(tmp_path)
    with pytest.raises(UserInputError, match="character device"):
        check_output_file(dev, "--html")
    with pytest.raises(OutputError, match=r"it is a character device, not a regular file"):
        atomic_write_text(dev, "<html></html>\n")
    assert stat.S_ISCHR(os.lstat(dev).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["null"]  # no temporary file left


def test_a_link_to_a_device_is_refused_and_stays_a_link(tmp_path, capsys):
    link = tmp_path / "replay.html"
    link.symlink_to("/dev/null")
    with pytest.raises(UserInputError, match="character device"):
        check_output_file(link, "--html")
    err = _one_line_error(capsys, cli_main(["teleop", "--targets", "1", "--html", str(link)]))
    assert "character device" in err
    with pytest.raises(OutputError):
        atomic_write_text(link, "x")
    assert link.is_symlink() and os.readlink(link) == "/dev/null"


def test_a_folder_where_a_file_is_expected(tmp_path, capsys):
    folder = tmp_path / "replay.html"
    (folder / "keep").mkdir(parents=True)
    with pytest.raises(UserInputError, match="is a folder; give a file name"):
        check_output_file(folder, "--html")
    with pytest.raises(OutputError, match="it is a folder, not a regular file"):
        atomic_write_text(folder, "x")
    assert (folder / "keep").is_dir()
    # Inside an output folder: a results name taken by a folder is refused before the run.
    out = tmp_path / "results"
    (out / "report.md").mkdir(parents=True)
    err = _one_line_error(capsys, cli_main(["reproduce", "--quick", "--sections", "sizing", "--out", str(out)]))
    assert "'report.md' in it is a folder" in err and "reproduce" in err
    (out / "report.md").rmdir()
    (out / "table.csv").mkdir()
    spec = tmp_path / "spec.yaml"
    spec.write_text("experiment: statics\ngrid: {n_balls: [4]}\n")
    err = _one_line_error(capsys, cli_main(["sweep", str(spec), "--out", str(out), "--workers", "0"]))
    assert "'table.csv' in it is a folder" in err


def test_an_output_folder_that_is_a_device(tmp_path, capsys):
    dev = _char_device(tmp_path)
    with pytest.raises(UserInputError, match="is a character device, not a folder"):
        check_output_dir(dev, "--out")
    err = _one_line_error(capsys, cli_main(["validation", "--out", str(dev)]))
    assert "--out" in err and "character device" in err


def test_a_named_pipe_is_written_into_not_replaced(tmp_path):
    fifo = tmp_path / "replay.html"
    os.mkfifo(fifo)
    assert check_output_file(fifo, "--html") == fifo
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()))
    reader.start()
    text = "<html>" + "x" * 200_000 + "</html>\n"  # more than a pipe's buffer
    atomic_write_text(fifo, text)
    reader.join(timeout=60)
    assert got == [text.encode()]
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["replay.html"]


@pytest.mark.slow
def test_simulate_writes_its_replay_into_a_named_pipe(tmp_path):
    fifo = tmp_path / "replay.html"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    assert cli_main([*SIMULATE, "--html", str(fifo)]) == 0
    reader.join(timeout=60)
    assert got and got[0].rstrip().endswith(b"</html>")
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_a_link_to_a_file_stays_a_link_and_its_target_gets_the_content(tmp_path):
    target = tmp_path / "runs" / "run1.json"
    target.parent.mkdir()
    target.write_text("old\n")
    link = tmp_path / "latest.json"
    link.symlink_to(target)
    atomic_write_text(link, "new\n")
    assert link.is_symlink() and target.read_text() == "new\n"
    assert sorted(p.name for p in target.parent.iterdir()) == ["run1.json"]


def test_names_too_long_are_refused_up_front(tmp_path, capsys):
    long_name = "r" * 300 + ".html"
    with pytest.raises(UserInputError, match=r"is 305 bytes long; the file system allows 255 bytes per name"):
        check_output_file(tmp_path / long_name, "--html")
    err = _one_line_error(capsys, cli_main([*SIMULATE, "--html", str(tmp_path / long_name)]))
    assert "255 bytes per name" in err and len(err) < 400  # the name is quoted cut short
    with pytest.raises(UserInputError, match="255 bytes per name"):
        check_output_dir(tmp_path / ("d" * 256) / "inner", "--out")
    err = _one_line_error(capsys, cli_main(["validation", "--out", str(tmp_path / ("d" * 256))]))
    assert "--out" in err and "bytes per name" in err
    deep = tmp_path / "/".join(["p" * 250] * 17)  # each name fits, the path does not
    with pytest.raises(UserInputError, match="the path is .* bytes long"):
        check_output_file(deep / "x.html", "--html")


def test_a_name_of_the_longest_allowed_length_is_written(tmp_path):
    """The temporary file's name (".name.XXXXXXXX.partial") must fit too: it is cut."""
    path = tmp_path / ("n" * 250 + ".json")
    check_output_file(path, "--out")
    atomic_write_text(path, "{}\n")
    assert path.read_text() == "{}\n" and len(list(tmp_path.iterdir())) == 1


def test_a_full_disk_at_write_time_is_one_error_naming_the_file_and_keeps_the_old_content(tmp_path):
    path = tmp_path / "table.csv"
    path.write_text("old\n")
    # The path is quoted whole, or cut with its length when long (a deep temporary folder).
    with pytest.raises(OutputError, match=r"cannot write '.*(table\.csv'|\.\.\. \(\d+ characters\)): No space left on "
                                          r"device .*free.*nothing was replaced"):
        with atomic_path(path) as tmp:
            tmp.write_text("partial")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert path.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["table.csv"]
    # A bug in the writer stays what it is.
    with pytest.raises(ZeroDivisionError):
        with atomic_path(path):
            1 / 0


def test_too_little_free_space_is_refused_up_front(tmp_path, monkeypatch, capsys):
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(safe_files.shutil, "disk_usage", lambda p: usage._replace(free=3_000_000))
    check_output_file(tmp_path / "small.json", "--out", expected_bytes=1_000_000)
    with pytest.raises(UserInputError, match=r"--html .*: only 3\.0 MB free on the disk holding .*; this run writes "
                                             r"about 10\.0 MB"):
        check_output_file(tmp_path / "replay.html", "--html", expected_bytes=10e6)
    # simulate's estimate of its replay: 600 simulated seconds are tens of MB.
    err = _one_line_error(capsys, cli_main(["simulate", "--scenario", "free_space_uniform_90deg", "--duration", "600",
                                            "--html", str(tmp_path / "replay.html")]))
    assert "MB free" in err and not (tmp_path / "replay.html").exists()
    monkeypatch.setattr(safe_files.shutil, "disk_usage", lambda p: usage._replace(free=100_000))
    with pytest.raises(UserInputError, match="only 0.1 MB free"):
        check_output_dir(tmp_path / "results", "--out")


def test_a_full_disk_outside_the_result_files_is_one_line(monkeypatch, capsys):
    """ENOSPC from a write that is not a result file (a cache of generated models): one line, exit 1."""
    from ballchain.commands import wheels

    def full(args):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "/tmp/ballchain_cache/model.sdf")

    monkeypatch.setattr(wheels, "main", full)
    err = _one_line_error(capsys, cli_main(["wheels"]), expected=1)
    assert "No space left on device" in err and "model.sdf" in err


def _mount_tmpfs(where: Path, size: str) -> None:
    where.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], capture_output=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.decode().strip()}")


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("mount") is None or os.geteuid() != 0, reason="needs root and mount")
def test_a_really_full_disk_mid_run_is_one_line_and_leaves_no_partial_file(tmp_path, monkeypatch, capsys):
    """A 1 MB tmpfs: simulate's replay (about 2.4 MB) does not fit. Up front that is refused
    (exit 2); with the check out of the way, the write at the end fails: one line, exit 1."""
    disk = tmp_path / "disk"
    _mount_tmpfs(disk, "1m")
    try:
        err = _one_line_error(capsys, cli_main([*SIMULATE, "--html", str(disk / "replay.html")]))
        assert "MB free" in err
        monkeypatch.setattr(safe_files, "check_free_space", lambda *a, **k: None)
        err = _one_line_error(capsys, cli_main([*SIMULATE, "--html", str(disk / "replay.html")]), expected=1)
        assert "cannot write" in err and "No space left on device" in err and "nothing was replaced" in err
        assert list(disk.iterdir()) == []
    finally:
        subprocess.run(["umount", str(disk)], check=False)


def test_the_benchmark_script_checks_its_json_path_first(tmp_path):
    proc = subprocess.run([sys.executable, "benchmarks/station_bench.py", "--json", "/dev/null"],
                          capture_output=True, text=True, cwd=Path(__file__).parents[1], timeout=300)
    assert proc.returncode == 2 and "character device" in proc.stderr


def test_a_file_name_in_a_message_is_whole_or_keeps_both_ends():
    """A message quotes a file name whole up to MAX_PATH_QUOTED characters (a folder under
    pytest's workers cut at 80 lost the file's name: 'tar... (86 characters)'); a longer one is
    cut in the middle, so its file name stays."""
    from ballchain.infrastructure.errors import MAX_PATH_QUOTED, quote_path, short_repr

    path = "/tmp/" + "a" * 100 + "/targets.csv"
    assert quote_path(path) == repr(path)
    long = "/tmp/" + "b" * 400 + "/atrium.stl"
    quoted = quote_path(long)
    assert quoted.endswith(f"/atrium.stl' ({len(long) + 2} characters)") and quoted.startswith("'/tmp/bbb")
    assert len(quoted.split(" (")[0]) == MAX_PATH_QUOTED
    assert short_repr("x" * 200).startswith("'xxx") and "...xxx" in short_repr("x" * 200)
