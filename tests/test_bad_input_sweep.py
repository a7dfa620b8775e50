"""Bad input to ``ballchain sweep``: one line, exit status 2, before any cluster starts.

The kinds: specs without bounds (points counted before the grid is expanded, every point's
values checked with the rules of its command's flags, the executor's flags), spec-file edges
(binary, encodings, a list where a name goes, a folder named like a shipped study, empty),
an unreadable table in ``--out`` when resuming, and Ctrl-C keeping every finished point.

The CLI runs in-process (``ballchain.cli.main``) with the executor's ``__enter__`` replaced by
a failure: a refused spec must not start a cluster. Cases that would hang without their fix
run in a subprocess with a timeout (a hang guard, not a speed claim).
"""

from __future__ import annotations

import codecs
import json
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from ballchain import sweep
from ballchain.cli import main
from ballchain.infrastructure.errors import UserInputError
from ballchain.sweep import load_spec, read_table, run_sweep

HANG_GUARD_S = 120.0  # a fresh interpreter imports pydrake and distributed; a hang takes hours

GOOD = "experiment: statics\ngrid:\n  n_balls: [4, 5]\n"


@pytest.fixture
def no_cluster(monkeypatch):
    """Starting an executor (a cluster, a client, even the serial one) fails the test."""

    def refuse(self):
        raise AssertionError("an executor started for a refused sweep")

    monkeypatch.setattr(sweep.Executor, "__enter__", refuse)


def _cli(capsys, argv) -> tuple[int, list[str]]:
    try:
        code = main(["sweep", *argv])
    except SystemExit as exc:  # argparse's own checks
        code = exc.code
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, [line for line in err.splitlines() if line.strip()]


def _refused(capsys, tmp_path, spec_text: str | bytes, named: str, *flags: str) -> None:
    spec = tmp_path / "spec.yaml"
    if isinstance(spec_text, bytes):
        spec.write_bytes(spec_text)
    else:
        spec.write_text(spec_text)
    code, lines = _cli(capsys, [str(spec), "--out", str(tmp_path / "o"), *flags])
    assert code == 2 and len(lines) == 1, lines
    assert named in lines[0], lines[0]
    assert not (tmp_path / "o").exists()


# --- specs without bounds: the count, every point's values, the executor's flags -----------------

@pytest.mark.parametrize("text, named", [
    # The statics command's ranges (statics_shape.check_inputs): 1..200 balls, 0.1..90 deg, 0..1000 mT.
    ("experiment: statics\ngrid: {n_balls: [4, 100000]}", "n_balls must be an integer in 1..200, got 100000"),
    ("experiment: statics\ngrid: {step_deg: [1e-9]}", "step_deg must be a number in [0.1, 90]"),
    ("experiment: statics\npoints: [{field_mT: 1e9}]", "points[0]: field_mT must be a number in [0, 1000] mT"),
    ("experiment: statics\ngrid: {max_iterations: [1000000000]}", "max_iterations must be in 1..10000"),
    # The forces command's --grid and --refine ranges, the statics' chain length, a sleeve over the balls.
    ("experiment: design\ngrid: {refine_evaluations: [0]}", "refine_evaluations must be a number in [1, 2000]"),
    ("experiment: design\ngrid: {grid: [100000]}", "grid must be a number in [2, 64]"),
    ("experiment: design\ngrid: {grid: [1" + "0" * 400 + "]}", "grid must be a number in [2, 64]"),  # > any float
    ("experiment: design\ngrid: {ball_diameter_mm: [0.01]}", "a chain of 5080 balls"),
    ("experiment: design\ngrid: {ball_diameter_mm: [1e-300]}", "a chain of 5.08e+301 balls"),
    ("experiment: design\npoints: [{ball_diameter_mm: 4.0, sleeve: true}]", "sleeve.outer_diameter"),
    ("experiment: design\ngrid: {distance_cm: [1e9]}", "distance_cm must be a number in (0, 100] cm"),
    # The teleop command's checks and the station scenario's (its time step's range).
    ("experiment: operators\ngrid: {n_balls: [100]}", "balls must be an integer in 3..64"),
    ("experiment: operators\ngrid: {tremor: [5.0]}", "tremor must be a number in [0, 1]"),
    ("experiment: operators\ngrid: {engine: [plant], time_step: [0.5]}", "scenario time_step must be 0"),
    # The workspace command's step and distance ranges.
    ("experiment: sleeve\ngrid: {step_deg: [0.01]}", "step_deg must be in [0.5, 45]"),
    ("experiment: sleeve\ngrid: {distance_cm: [1.0]}", "distance_cm must be in (10, 100] cm"),
    # Seeds: the range the operator's tremor takes (teleop.check_seed), for every experiment.
    ("experiment: statics\ngrid: {n_balls: [4]}\nseeds: [-1]", "seeds[0] must be an integer in 0..4294967295"),
], ids=["statics-balls", "statics-step", "statics-field", "statics-iterations", "design-refine", "design-grid", "design-grid-huge-int",
        "design-tiny-balls", "design-vanishing-balls", "design-sleeve-over-balls", "design-distance", "operators-balls", "operators-tremor",
        "operators-plant-step", "sleeve-step", "sleeve-distance", "negative-seed"])
def test_a_point_the_command_refuses_is_refused_in_a_spec(capsys, tmp_path, no_cluster, text, named):
    _refused(capsys, tmp_path, text, named)


def test_the_point_is_named_by_its_grid_values():
    with pytest.raises(UserInputError, match=r"grid point 2 of 2 \(n_balls=100000\)"):
        load_spec("<test>", text="experiment: statics\ngrid: {n_balls: [4, 100000]}")


def test_a_huge_grid_is_counted_not_expanded():
    """Five axes of ten values and 10^4 seeds: 10^9 runs. Expanding them would take hours (the
    test would hang); the count, the product of the axes' lengths, refuses at once."""
    axes = ", ".join(f"{name}: [{', '.join(str(v) for v in values)}]" for name, values in {
        "n_balls": range(2, 12), "field_mT": range(1, 11), "field_angle_deg": range(10, 110, 10),
        "step_deg": range(1, 11), "max_iterations": range(100, 110)}.items())
    text = f"experiment: statics\ngrid: {{{axes}}}\nseeds: [{', '.join(map(str, range(10000)))}]"
    with pytest.raises(UserInputError, match=r"1000000000 runs \(100000 grid points \+ 0 points, times 10000 "
                                             r"seed\(s\)\) exceed the limit of 5000"):
        load_spec("<test>", text=text)


def test_the_point_cap_is_a_flag(capsys, tmp_path, no_cluster):
    text = "experiment: statics\ngrid: {n_balls: [4, 5, 6]}\nseeds: [0, 1]"
    _refused(capsys, tmp_path, text, "6 runs", "--max-points", "5")
    assert len(load_spec("<test>", text=text, max_points=6).tasks()) == 6
    _refused(capsys, tmp_path, text, "--max-points", "--max-points", "0")


def test_the_count_and_an_estimate_come_first(capsys, tmp_path):
    spec = tmp_path / "spec.yaml"
    spec.write_text(GOOD)
    assert main(["sweep", str(spec), "--out", str(tmp_path / "o"), "--workers", "0", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "sweep statics: 2 points, 0 done before, 2 to run; estimate" in err
    assert main(["sweep", str(spec), "--out", str(tmp_path / "o"), "--workers", "0", "--no-progress"]) == 0
    assert "2 done before, 0 to run" in capsys.readouterr().err


@pytest.mark.parametrize("flags, named", [
    (["--workers", "1000"], "--workers must be at most"),
    (["--scheduler", "foo://127.0.0.1:8786"], "unknown scheme 'foo'"),
    (["--scheduler", "tcp://127.0.0.1"], "a host and a port"),
    (["--scheduler", "tcp://127.0.0.1:99999"], "a host and a port"),
], ids=["workers-1000", "unknown-scheme", "no-port", "port-out-of-range"])
def test_bad_executor_flags_are_one_line(capsys, tmp_path, no_cluster, flags, named):
    _refused(capsys, tmp_path, GOOD, named, *flags)


def test_reproduce_shares_the_worker_cap(capsys, tmp_path):
    from ballchain.sweep import max_workers

    code = main(["reproduce", "--quick", "--out", str(tmp_path / "r"), "--workers", str(max_workers() + 1)])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and f"--workers must be an integer in 1..{max_workers()}" in lines[0], lines
    assert not (tmp_path / "r").exists()


def test_a_bad_point_is_refused_before_connecting(capsys, tmp_path, no_cluster):
    _refused(capsys, tmp_path, "experiment: statics\ngrid: {n_balls: [0]}", "n_balls",
             "--scheduler", "tcp://127.0.0.1:9")


@pytest.fixture
def silent_listener():
    """A TCP listener on 127.0.0.1 that accepts connections and never says anything."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    accepted = []

    def accept():
        while True:
            try:
                accepted.append(server.accept()[0])
            except OSError:  # closed
                return

    threading.Thread(target=accept, daemon=True).start()
    yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    server.close()
    for conn in accepted:
        conn.close()


@pytest.mark.slow
def test_a_silent_listener_is_not_a_scheduler(tmp_path, silent_listener):
    spec = load_spec("<test>", text=GOOD)
    with pytest.raises(UserInputError, match="no Dask scheduler answered within 2 s"):
        run_sweep(spec, tmp_path, scheduler=silent_listener, progress=False, connect_timeout=2.0)
    assert not (tmp_path / "table.parquet").exists()


# --- spec-file edges ------------------------------------------------------------------------------

@pytest.mark.parametrize("content, named", [
    (b"\x00\x01\x02PK\x03\x04 binary", "is a binary file"),
    (GOOD.encode("utf-16-le"), "is a binary file"),  # UTF-16 without its BOM: NUL bytes
    ("experiment: statics\ndescription: caf\xe9\ngrid: {n_balls: [4]}\n".encode("latin-1"), "is not UTF-8 text"),
    ("experiment: [statics]\ngrid: {n_balls: [4]}", "experiment must be a string, got ['statics']"),
    ("", "is empty"),
    ("# only a comment\n", "is empty"),
    ("- experiment: statics\n- grid: {n_balls: [4]}", "must be a mapping with keys"),
    ("experiment: statics\ngrid: {n_balls: [4]}\ngrid: {n_balls: [5]}", "duplicate key 'grid'"),
    ("experiment: statics\ngrid: [n_balls, 4]", "grid must be a mapping"),
    ("experiment: statics\ngrid: {n_balls: [4]}\npoints: {n_balls: 5}", "points must be a list"),
], ids=["binary", "utf16-no-bom", "latin1", "experiment-list", "empty", "comment-only", "yaml-list", "duplicate-key",
        "grid-list", "points-mapping"])
def test_spec_file_edges_are_one_line(capsys, tmp_path, no_cluster, content, named):
    _refused(capsys, tmp_path, content if isinstance(content, bytes) else content.encode(), named)


def test_utf16_with_its_bom_is_read(tmp_path):
    """UTF-16 with a byte-order mark (as some Windows editors save) is decoded; so is UTF-8's BOM."""
    for name, data in (("utf16.yaml", codecs.BOM_UTF16_LE + GOOD.encode("utf-16-le")),
                       ("utf8bom.yaml", codecs.BOM_UTF8 + GOOD.encode())):
        (tmp_path / name).write_bytes(data)
        spec = load_spec(tmp_path / name)
        assert [p.n_balls for p in spec.points] == [4, 5]


def test_yaml_12_floats_in_a_spec(tmp_path):
    spec = load_spec("<test>", text="experiment: statics\ngrid: {field_mT: [2.3e1]}")
    assert spec.points[0].field_mT == 23.0


def test_a_folder_named_like_a_study_does_not_shadow_it(capsys, tmp_path, monkeypatch, no_cluster):
    from ballchain.commands.sweep import STUDIES, resolve_spec

    monkeypatch.chdir(tmp_path)
    (tmp_path / "design").mkdir()
    assert resolve_spec("design") == STUDIES / "design.yaml"
    code, lines = _cli(capsys, ["./design", "--out", str(tmp_path / "o")])
    assert code == 2 and len(lines) == 1 and "is a folder, not a spec file" in lines[0], lines
    code, lines = _cli(capsys, ["desing", "--out", str(tmp_path / "o")])
    assert code == 2 and len(lines) == 1 and "neither a file nor a shipped study" in lines[0], lines


# --- an unreadable table in --out -----------------------------------------------------------------

def _first_run(tmp_path) -> list[dict]:
    spec = load_spec("<test>", text=GOOD)
    run_sweep(spec, tmp_path, workers=0, progress=False, figure=False)
    return read_table(tmp_path)


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def test_a_truncated_parquet_resumes_from_the_csv(tmp_path):
    rows = _first_run(tmp_path)
    _truncate(tmp_path / "table.parquet")
    notes = []
    result = run_sweep(load_spec("<test>", text=GOOD), tmp_path, workers=0, progress=False, figure=False,
                       echo=notes.append)
    assert (result["ran"], result["skipped"]) == (0, 2)
    assert "table.parquet is unreadable" in notes[0] and "resumed from table.csv (2 rows)" in notes[0]
    assert read_table(tmp_path) == rows  # the CSV's rows, typed as the Parquet table's were
    assert (tmp_path / "table.parquet.unreadable").exists()


def test_both_tables_unreadable_reruns_the_points(tmp_path):
    rows = _first_run(tmp_path)
    _truncate(tmp_path / "table.parquet")
    (tmp_path / "table.csv").write_bytes(b"\x00garbage\n\x01\x02")
    notes = []
    result = run_sweep(load_spec("<test>", text=GOOD), tmp_path, workers=0, progress=False, figure=False,
                       echo=notes.append)
    assert (result["ran"], result["skipped"]) == (2, 0)
    assert "table.csv is unreadable too: every point runs again" in notes[0]
    assert [r["key"] for r in read_table(tmp_path)] == [r["key"] for r in rows]


def test_a_foreign_parquet_in_out_is_refused(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({"x": [1, 2]}), tmp_path / "table.parquet")
    with pytest.raises(UserInputError, match="not a sweep's table"):
        run_sweep(load_spec("<test>", text=GOOD), tmp_path, workers=0, progress=False)
    assert pq.read_table(tmp_path / "table.parquet").num_rows == 2  # left as it was


# --- Ctrl-C ---------------------------------------------------------------------------------------

def test_an_interrupt_wrapped_by_compiled_code_stops_the_sweep(tmp_path, monkeypatch):
    """Ctrl-C landing in a compiled call comes back as another exception with the interrupt as its
    context: it stops the sweep (the table keeps the finished points), not an error row."""
    import dataclasses

    from ballchain.experiments import studies

    calls = []

    def point(p, seed):
        calls.append(p.n_balls)
        if len(calls) == 2:
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt:
                raise SystemError("a compiled call returned a result with an exception set") from None
        return {"tip_x_mm": 1.0}

    monkeypatch.setitem(studies.EXPERIMENTS, "statics", dataclasses.replace(studies.EXPERIMENTS["statics"],
                                                                           point=point))
    spec = load_spec("<test>", text="experiment: statics\ngrid: {n_balls: [4, 5, 6]}")
    result = run_sweep(spec, tmp_path, workers=0, progress=False, figure=False)
    assert result["interrupted"] and result["ran"] == 1 and calls == [4, 5]
    assert [r["n_balls"] for r in read_table(tmp_path)] == [4]


def test_a_stop_while_the_cluster_closes_keeps_every_finished_point(tmp_path, monkeypatch):
    """Ctrl-C (or a stop signal) after the last point, while the executor closes (a LocalCluster
    takes about a second): the table holds every point, not only the last periodic write, and
    the sweep says it was interrupted (CI once signalled a 2-worker sweep just as it ended)."""
    closed = []

    def interrupted_close(self, *exc):
        closed.append(True)
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep.runner, "WRITE_PERIOD", 1e9)  # no periodic write after the first point
    monkeypatch.setattr(sweep.Executor, "__exit__", interrupted_close)
    spec = load_spec("<test>", text="experiment: statics\ngrid: {n_balls: [4, 5, 6]}")
    try:
        result = run_sweep(spec, tmp_path, workers=0, progress=False, figure=False)
    except KeyboardInterrupt:  # (not raised on: pytest would take it for the person's Ctrl-C)
        pytest.fail(f"the stop escaped the sweep; the table holds {len(read_table(tmp_path))} of 3 points")
    assert closed and result["interrupted"] and result["ran"] == 3
    assert [r["n_balls"] for r in read_table(tmp_path)] == [4, 5, 6]
    assert json.loads((tmp_path / "sweep.json").read_text())["interrupted"]


def test_a_stop_while_the_cluster_starts_stops_the_sweep(tmp_path, monkeypatch):
    """Ctrl-C while the executor starts: no point ran, the interrupt goes on."""

    def interrupted_start(self):
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep.Executor, "__enter__", interrupted_start)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(load_spec("<test>", text=GOOD), tmp_path, workers=0, progress=False, figure=False)


# 24 points that take long enough for a SIGINT a second after the first row to land mid-run: the
# compiled solve's speed-up made 8-12 balls at 0.5 deg finish in about a second in all (the
# signal then arrived after the end); 48-64 balls at 0.25 deg take about 25 s serially.
SLOW_POINTS = """
experiment: statics
grid:
  n_balls: [48, 56, 64]
  field_angle_deg: [60.0, 90, 120, 150, 180, 210, 240, 270]
  step_deg: [0.25]
"""


@pytest.mark.slow
@pytest.mark.parametrize("workers", ["0", "2"], ids=["serial", "local-cluster"])
def test_sigint_keeps_every_finished_point(tmp_path, workers):
    spec = tmp_path / "spec.yaml"
    spec.write_text(SLOW_POINTS)
    out = tmp_path / "o"
    proc = subprocess.Popen([sys.executable, "-m", "ballchain", "sweep", str(spec), "--out", str(out), "--workers",
                             workers, "--no-progress", "--no-figure"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + HANG_GUARD_S
        while not (out / "table.csv").exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
        assert (out / "table.csv").exists(), proc.communicate()
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=HANG_GUARD_S)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, stderr
    result = json.loads((out / "sweep.json").read_text())
    rows = read_table(out)
    assert result["interrupted"] and 0 < result["ran"] < 24
    assert len(rows) == result["ran"] and len({r["key"] for r in rows}) == len(rows)
    assert all(r["error"] is None for r in rows), [r["error"] for r in rows]


def test_the_sweep_api_names_an_argument_of_the_wrong_kind(tmp_path):
    """``run_sweep`` and ``load_spec`` from Python: a study's name for the spec, None for a folder,
    a mapping for the text, a bad timeout or client are refused before any work."""
    import ballchain as bc

    spec = bc.load_spec("s.yaml", text="experiment: statics\ngrid: {n_balls: [4]}")
    out = tmp_path / "out"
    for call, expected in (
            (lambda: bc.run_sweep("design", out, workers=0), "run_sweep spec must be a SweepSpec: "
                                                               "ballchain.load_spec(file)"),
            (lambda: bc.run_sweep(spec, None, workers=0), "run_sweep out must be a folder name, got None"),
            (lambda: bc.run_sweep(spec, "", workers=0), "run_sweep out must be a folder name, got ''"),
            (lambda: bc.run_sweep(spec, out, client="x"), "run_sweep client must be a distributed.Client or None"),
            (lambda: bc.run_sweep(spec, out, connect_timeout=-1.0),
             "run_sweep connect_timeout must be a finite number > 0 [s], got -1.0"),
            (lambda: bc.run_sweep(spec, out, connect_timeout=float("nan")),
             "run_sweep connect_timeout must be a finite number > 0 [s], got nan"),
            (lambda: bc.load_spec(None), "load_spec source must be a spec file's name"),
            (lambda: bc.load_spec("s.yaml", text={"experiment": "statics"}),
             "load_spec text must be the spec's YAML text, got dict")):
        with pytest.raises(UserInputError) as err:
            call()
        assert str(err.value).startswith(expected), str(err.value)
    assert not out.exists()


# --- a folder holding another spec's table (issue 41) ---------------------------------------------

OTHER = "experiment: statics\ngrid:\n  n_balls: [6]\n"


def _spec_file(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_a_second_different_spec_into_the_same_out_is_refused_naming_the_spec_it_holds(tmp_path, capsys):
    first, second = _spec_file(tmp_path, "first.yaml", GOOD), _spec_file(tmp_path, "second.yaml", OTHER)
    out = tmp_path / "o"
    assert main(["sweep", str(first), "--out", str(out), "--workers", "0", "--no-progress", "--no-figure"]) == 0
    capsys.readouterr()
    table = {name: (out / name).read_bytes() for name in ("table.csv", "table.parquet", "sweep.json")}
    code, lines = _cli(capsys, [str(second), "--out", str(out), "--workers", "0", "--no-progress"])
    assert code == 2 and len(lines) == 1, lines
    assert f"--out '{out}' holds rows of another sweep spec ('{first}'): 2 of its 2 rows are not points of " \
           f"'{second}'; give another folder, or --append" in lines[0]
    assert {name: (out / name).read_bytes() for name in table} == table  # nothing written
    # The same spec again resumes as before, and so does one that only adds points to it.
    grown = _spec_file(tmp_path, "grown.yaml", "experiment: statics\ngrid:\n  n_balls: [4, 5, 7]\n")
    result = run_sweep(load_spec(grown), out, workers=0, progress=False, figure=False)
    assert (result["ran"], result["skipped"]) == (1, 2)
    assert "spec" not in read_table(out)[0]  # one spec's table: no spec column
    # A spec without one of the table's points is another spec: the table would keep that row.
    with pytest.raises(UserInputError, match=r"holds rows of another sweep spec \('.*grown.yaml'\): 1 of its 3 rows"):
        run_sweep(load_spec(first), out, workers=0, progress=False, figure=False)
    grown.write_text(GOOD)  # the same file, edited
    with pytest.raises(UserInputError, match=r"holds rows of an earlier version of '.*grown.yaml' \(or of the "):
        run_sweep(load_spec(grown), out, workers=0, progress=False, figure=False)


def test_append_keeps_both_specs_rows_and_names_each_row_s_spec(tmp_path):
    first, second = _spec_file(tmp_path, "first.yaml", GOOD), _spec_file(tmp_path, "second.yaml", OTHER)
    out = tmp_path / "o"
    run_sweep(load_spec(first), out, workers=0, progress=False, figure=False)
    result = run_sweep(load_spec(second), out, workers=0, progress=False, figure=False, append=True)
    assert (result["ran"], result["skipped"]) == (1, 0)
    rows = read_table(out)
    assert [(r["n_balls"], r["spec"]) for r in rows] == [(6, str(second)), (4, str(first)), (5, str(first))]
    csv_header = (out / "table.csv").read_text().splitlines()[0]
    assert '"spec"' in csv_header
    # Appended again: every row keeps the spec it came from; a plain rerun of either is refused.
    run_sweep(load_spec(first), out, workers=0, progress=False, figure=False, append=True)
    assert [(r["n_balls"], r["spec"]) for r in read_table(out)] == [(4, str(first)), (5, str(first)),
                                                                    (6, str(second))]
    with pytest.raises(UserInputError, match=r"holds rows of another sweep spec \('.*second.yaml'\)"):
        run_sweep(load_spec(first), out, workers=0, progress=False, figure=False)
    with pytest.raises(UserInputError, match="run_sweep append must be true or false"):
        run_sweep(load_spec(first), out, workers=0, progress=False, append="yes")
