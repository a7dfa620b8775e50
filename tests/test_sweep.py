"""The sweep executor (ballchain/sweep/, ballchain/executor.py, ballchain/sections.py): specs, tables, faults, a scheduler address, sections.

The cluster tests run on a 2-worker LocalCluster of processes on 127.0.0.1 (no dashboard) with
cheap points (the ``statics`` experiment: one equilibrium in a uniform field, tens of ms).
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ballchain.infrastructure.errors import UserInputError
from ballchain.experiments.studies import EXPERIMENTS
from ballchain.sweep import load_spec, point_key, read_table, run_point, run_sections, run_sweep

TIMING = ("wall_time_s", "cpu_time_s", "worker")

SPEC = """
experiment: statics
grid:
  n_balls: [4, 6]
  field_angle_deg: [45.0, 90, 135]
points:
  - {n_balls: 5, max_iterations: 1}
"""

# Slower points (continuation in 1.5 deg steps, about 0.1-0.3 s each) so that tasks are in
# flight when a worker dies.
SLOW_SPEC = """
experiment: statics
grid:
  n_balls: [8, 10]
  field_angle_deg: [60.0, 90, 120, 150, 180]
  step_deg: [1.5]
"""


def _without_timing(rows):
    """Rows to compare: every column (a missing output is None), no wall time or worker, the
    error's type only (its message carries a solve time)."""
    columns = {k for r in rows for k in r} - set(TIMING)
    return [{k: (r.get(k) or "").split(":")[0] if k == "error" else r.get(k) for k in sorted(columns)} for r in rows]


def _serial_rows(spec):
    import dataclasses

    return [run_point(spec.experiment, dataclasses.asdict(p), s) for p, s in spec.tasks()]


@pytest.fixture(scope="module")
def client():
    import logging

    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=None, silence_logs=logging.ERROR)
    c = Client(cluster)
    yield c
    c.close()
    cluster.close()


# --- specs ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("text, named", [
    ("experiment: nope\ngrid: {n_balls: [4]}", "experiment"),
    ("experiment: statics\ngrid: {n_bals: [4]}", "grid.n_bals"),
    ("experiment: statics\ngrid: {n_balls: [4.5]}", "grid.n_balls[0]"),
    ("experiment: statics\ngrid: {field_mT: [fast]}", "grid.field_mT[0]"),
    ("experiment: statics\ngrid: {sleeve: [1]}", "grid.sleeve[0]"),
    ("experiment: statics\ngrid: {n_balls: []}", "grid.n_balls is empty"),
    ("experiment: statics\ngrid: {}", "grid is empty"),
    ("experiment: statics", "grid is empty"),
    ("experiment: statics\npoints: [{n_balls: 4, colour: red}]", "points[0].colour"),
    ("experiment: statics\ngrid: {n_balls: 4}", "grid.n_balls must be a list"),
    ("experiment: statics\ngrid: {n_balls: [4]}\nseeds: [1, 1]", "seeds"),
    ("experiment: statics\ngrid: {n_balls: [4]}\nsamples: 3", "samples"),
    ("experiment: statics\ngrid: {n_balls: [0]}", "n_balls must be an integer in 1..200"),
    ("experiment: design\ngrid: {vein: [XXPV]}", "vein must be one of"),
    ("experiment: design\ngrid: {magnet: [cube]}", "magnet must be"),
    ("experiment: operators\ngrid: {engine: [warp]}", "engine must be one of"),
    ("experiment: statics\ngrid: {n_balls: [4]}\npoints: [{n_balls: 4}]", "appears twice"),
])
def test_bad_spec_names_the_field(text, named):
    with pytest.raises(UserInputError, match=named.replace("[", r"\[").replace("]", r"\]").replace(".", r"\.")):
        load_spec("<test>", text=text)


def test_bad_spec_fails_before_any_cluster(tmp_path):
    from ballchain.cli import main

    spec = tmp_path / "bad.yaml"
    spec.write_text("experiment: statics\ngrid: {n_bals: [4]}\n")
    start = time.perf_counter()
    # A scheduler address nobody listens on: the spec must be rejected before connecting.
    assert main(["sweep", str(spec), "--out", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:9"]) == 2
    assert time.perf_counter() - start < 5.0
    assert not (tmp_path / "o").exists()


def test_bad_executor_flags(tmp_path):
    spec = load_spec("<test>", text=SPEC)
    with pytest.raises(UserInputError, match="--workers"):
        run_sweep(spec, tmp_path, workers=-1)
    with pytest.raises(UserInputError, match="--scheduler and --jobqueue"):
        run_sweep(spec, tmp_path, scheduler="tcp://127.0.0.1:8786", jobqueue="slurm")
    with pytest.raises(UserInputError, match="--jobqueue must be one of"):
        run_sweep(spec, tmp_path, jobqueue="kubernetes")
    try:
        import dask_jobqueue  # noqa: F401
    except ImportError:  # the optional dependency, absent: a clear message, not an ImportError
        with pytest.raises(UserInputError, match="pip install dask-jobqueue"):
            run_sweep(spec, tmp_path, jobqueue="slurm")
    (tmp_path / "file").write_text("")
    with pytest.raises(UserInputError, match="not a folder"):
        run_sweep(spec, tmp_path / "file", workers=0)
    assert not (tmp_path / "table.parquet").exists()


def test_spec_grid_points_and_seeds():
    spec = load_spec("<test>", text=SPEC + "seeds: [3, 4]\n")
    assert len(spec.points) == 2 * 3 + 1 and spec.seeds == [3, 4]
    assert [p.field_angle_deg for p in spec.points[:3]] == [45.0, 90.0, 135.0]  # last axis fastest
    assert spec.points[-1].max_iterations == 1 and spec.points[-1].field_mT == 23.0  # defaults fill in
    keys = [point_key(spec.experiment, p, s) for p, s in spec.tasks()]
    assert len(set(keys)) == len(keys) == 14


def test_shipped_studies_load():
    studies = Path(__file__).resolve().parents[1] / "ballchain" / "studies"
    names = {p.stem: load_spec(p) for p in studies.glob("*.yaml")}
    assert {"design", "operators", "operators_reduced", "sleeve"} <= set(names)
    assert {s.experiment for s in names.values()} == {"design", "operators", "sleeve"}
    full = names["operators"]
    assert {p.task for p in full.points} == {"left", "right"} and {p.mapping for p in full.points} == {"world", "catheter"}
    assert len(full.seeds) >= 10 and all(p.targets == 0 for p in full.points)


def test_serial_sweep_error_row_and_rerun(tmp_path):
    spec = load_spec("<test>", text=SPEC)
    first = run_sweep(spec, tmp_path, workers=0, progress=False)
    rows = read_table(tmp_path)
    assert first["ran"] == 7 and first["failed"] == 1 and len(rows) == 7
    failed = [r for r in rows if r["error"] is not None]
    assert len(failed) == 1 and failed[0]["max_iterations"] == 1 and "StaticsError" in failed[0]["error"]
    assert failed[0]["tip_x_mm"] is None
    assert all(r["tip_angle_deg"] is not None for r in rows if r["error"] is None)
    assert _without_timing(rows) == _without_timing(_serial_rows(spec))
    assert (tmp_path / "table.csv").read_text().count("\n") == 8  # header + 7 rows
    # Rerun: the 6 done points are skipped (their rows kept as they were); the failed one reruns.
    second = run_sweep(spec, tmp_path, workers=0, progress=False)
    assert (second["ran"], second["skipped"], second["failed"]) == (1, 6, 1)
    again = read_table(tmp_path)
    assert [r["key"] for r in again] == [r["key"] for r in rows]
    assert [r["wall_time_s"] for r in again][:6] == [r["wall_time_s"] for r in rows][:6]
    assert not list(tmp_path.glob(".*tmp"))  # no temporary file left by the atomic writes
    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "table.parquet").stat().st_mode & 0o777 == 0o666 & ~mask  # not mkstemp's 0600


# --- on a 2-worker LocalCluster -------------------------------------------------------------------

@pytest.mark.slow
def test_cluster_table_equals_serial_loop(client, tmp_path):
    spec = load_spec("<test>", text=SPEC)
    result = run_sweep(spec, tmp_path, client=client, progress=False)
    rows = read_table(tmp_path)
    assert result["failed"] == 1 and len(rows) == 7
    assert _without_timing(rows) == _without_timing(_serial_rows(spec))
    assert {r["worker"] for r in rows} <= set(client.scheduler_info()["workers"])
    # The same spec again on the same cluster (another folder) is computed again, not handed
    # back from the scheduler's memory of the first run's task keys.
    run_sweep(spec, tmp_path / "again", client=client, progress=False)
    again = read_table(tmp_path / "again")
    assert _without_timing(again) == _without_timing(rows)
    assert all(a["wall_time_s"] != b["wall_time_s"] for a, b in zip(again, rows))


def _worker_pids(client):
    return client.run(os.getpid)


@pytest.mark.slow
@pytest.mark.parametrize("fault", ["kill", "restart"])
def test_worker_lost_mid_sweep_loses_and_duplicates_nothing(client, tmp_path, fault):
    spec = load_spec("<test>", text=SLOW_SPEC)
    faults = []

    def on_result(n, ex):
        if n == 2 and not faults:
            if fault == "kill":  # SIGKILL one worker process; its nanny starts a new one
                address, pid = sorted(_worker_pids(ex.client).items())[0]
                os.kill(pid, signal.SIGKILL)
            else:  # every worker restarted: the pending futures are cancelled
                ex.client.restart()
            faults.append(n)

    result = run_sweep(spec, tmp_path, client=client, progress=False, on_result=on_result)
    rows = read_table(tmp_path)
    assert faults == [2]
    keys = [point_key(spec.experiment, p, s) for p, s in spec.tasks()]
    assert [r["key"] for r in rows] == keys  # every point once, in the spec's order
    assert all(r["error"] is None for r in rows), [r["error"] for r in rows if r["error"]]
    assert result["failed"] == 0 and result["ran"] == len(keys)
    if fault == "restart":
        assert result["resubmitted"] >= 1
    assert _without_timing(rows) == _without_timing(_serial_rows(spec))
    client.wait_for_workers(2, timeout=60)


@pytest.mark.slow
def test_sections_in_parallel_equal_the_serial_run(client, tmp_path):
    from ballchain import reproduce
    from ballchain.infrastructure.safe_files import to_jsonable

    sections = [("sizing", reproduce.sizing_section), ("field models", reproduce.field_models_section)]
    serial = run_sections(sections, tmp_path, quick=True, workers=1)
    parallel = run_sections(sections, tmp_path, quick=True, client=client)
    assert [r.name for r in parallel] == ["sizing", "field models"]
    assert {r.worker for r in serial} == {"serial"}
    assert {r.worker for r in parallel} <= set(client.scheduler_info()["workers"])
    for a, b in zip(serial, parallel):
        assert a.value[0] == b.value[0]  # the report section: title, paragraphs, tables, figures
        assert json.dumps(to_jsonable(a.value[1])) == json.dumps(to_jsonable(b.value[1]))


# --- against a scheduler address ------------------------------------------------------------------

@pytest.mark.slow
def test_sweep_against_a_scheduler_address(tmp_path, capsys):
    from ballchain.cli import main

    dask = [sys.executable, "-m", "dask"]  # the `dask` command of this interpreter
    file = tmp_path / "scheduler.json"
    procs = [subprocess.Popen([*dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(file)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline, address = time.time() + 60, None
        while address is None and time.time() < deadline:  # the file may exist before it is written
            try:
                address = json.loads(file.read_text())["address"]
            except (OSError, ValueError, KeyError):
                time.sleep(0.2)
        assert address is not None, "the dask scheduler did not start"
        procs.append(subprocess.Popen([*dask, "worker", address, "--nworkers", "2", "--nthreads", "1", "--host",
                                       "127.0.0.1", "--no-dashboard"], stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL))
        from distributed import Client

        with Client(address, timeout="30s") as c:
            c.wait_for_workers(2, timeout=60)
            workers = set(c.scheduler_info()["workers"])
        spec = tmp_path / "spec.yaml"
        spec.write_text(SPEC)
        assert main(["sweep", str(spec), "--scheduler", address, "--out", str(tmp_path / "o"), "--json",
                     "--no-progress"]) == 0
        data = json.loads(capsys.readouterr().out)
        assert data["executor"] == f"scheduler {address}" and data["ran"] == 7 and data["failed"] == 1
        rows = read_table(tmp_path / "o")
        assert {r["worker"] for r in rows} <= workers
        assert _without_timing(rows) == _without_timing(_serial_rows(load_spec(spec)))
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def test_every_experiment_has_checked_defaults():
    for exp in EXPERIMENTS.values():
        if exp.check:
            exp.check(exp.params())  # the defaults are valid


# --- the studies' points against the experiments they call ---------------------------------------

@pytest.mark.slow
def test_design_point_passes_the_magnet_through():
    """A sphere with the prototype cylinder's volume (moment) makes the same point-dipole field, so
    the same optimum as the cylinder; the cylinder point is forces.max_normal_force itself."""
    from ballchain.drake_models.params import BallChain
    from ballchain.experiments import forces
    from ballchain.experiments.studies import DesignPoint, design_point

    settings = dict(vein="RSPV", config="1", grid=4, refine_evaluations=5)
    cylinder = design_point(DesignPoint(magnet="cylinder", **settings), 0)
    reference = forces.max_normal_force(BallChain(n_balls=16), forces.build_stand(), "RSPV", ("1",), grid=4,
                                        refine_evaluations=5)
    assert cylinder["force_gf"] == pytest.approx(reference["force_gf"], rel=1e-12)
    same_moment = design_point(DesignPoint(magnet="sphere69.2323", **settings), 0)  # (6 r^2 L)^(1/3)
    assert same_moment["magnet_moment_Am2"] == pytest.approx(cylinder["magnet_moment_Am2"], rel=1e-5)
    assert same_moment["force_gf"] == pytest.approx(cylinder["force_gf"], rel=1e-4)
    bigger = design_point(DesignPoint(magnet="sphere119", **settings), 0)
    assert bigger["force_gf"] > 2.0 * cylinder["force_gf"]  # 5 times the moment


@pytest.mark.slow
def test_sleeve_point_equals_the_workspace_experiment():
    from ballchain.experiments import workspace
    from ballchain.experiments.studies import SleevePoint, sleeve_point

    point = sleeve_point(SleevePoint(n_balls=9, step_deg=15.0), 0)  # the default sleeve: Dragon Skin
    summary = workspace.run(balls=(9,), step_deg=15.0, progress=False).summary
    for key in ("half_area_bare_mm2", "half_area_sleeve_mm2", "reduction_pct", "tip_to_tip_max_mm"):
        assert point[key] == pytest.approx(getattr(summary, key), rel=1e-12), key


@pytest.mark.slow
def test_workers_pin_blas_to_one_thread(client, tmp_path):
    from threadpoolctl import threadpool_info

    def blas_threads(out, quick):  # pickled by value: runs on a worker inside _run_section
        import numpy  # noqa: F401  (loads the BLAS)
        from threadpoolctl import threadpool_info as info

        return [p["num_threads"] for p in info() if p["user_api"] == "blas"]

    (run,) = run_sections([("blas", blas_threads)], tmp_path, quick=True, client=client)
    assert run.worker in client.scheduler_info()["workers"]
    assert run.value and set(run.value) == {1}
    # ...and here, outside the pin, numpy's BLAS may use more (the check above is not vacuous
    # when this machine has several cores).
    assert [p for p in threadpool_info() if p["user_api"] == "blas"]


DESIGN_SPEC = """
experiment: design
grid:
  vein: [LSPV]
  config: ["1"]
  n_balls: [12, 16]
  distance_cm: [14.0, 20.0]
  grid: [2]
  refine_evaluations: [1]
"""


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_design_summary_and_figure_keep_every_grid_field_apart(tmp_path, capsys):
    """The design summary keys a design by every grid field but the vein: the 16-ball rows were
    overwritten by the 12-ball ones (and LSPV at 14 cm reported one length's force for both). The
    figure draws the user's grid (one magnet, 14-20 cm) with a line per chain length; a grid with
    one distance per design gives no figure and says why. The command prints a headed table."""
    import matplotlib.image

    from ballchain.cli import main
    from ballchain.experiments.studies import design_figure, design_summary

    assert main(["sweep", str(_write(tmp_path / "spec.yaml", DESIGN_SPEC)), "--out", str(tmp_path / "out"),
                 "--workers", "0", "--no-progress"]) == 0
    printed = capsys.readouterr().out.splitlines()
    rows = read_table(tmp_path / "out")
    designs = design_summary(rows)["designs"]
    assert sorted((d["n_balls"], d["distance_cm"]) for d in designs) == [(12, 14.0), (12, 20.0), (16, 14.0),
                                                                         (16, 20.0)]
    for d in designs:
        (row,) = [r for r in rows if (r["n_balls"], r["distance_cm"]) == (d["n_balls"], d["distance_cm"])]
        assert d["forces_gf"]["LSPV"] == row["force_gf"] and d["veins_swept"] == ["LSPV"]
        assert d["weakest_swept_gf"] == row["force_gf"] and d["min_force_gf"] is None  # three veins not swept
    # The figure: the user's distances on the x-axis, one magnet in the title.
    figure = json.loads((tmp_path / "out" / "sweep.json").read_text())["figure"]
    assert figure and matplotlib.image.imread(figure).shape[0] > 100
    # The headed table: the varied fields, then the outputs.
    header = printed[1].split() if printed[0].startswith("design:") else printed[0].split()
    assert header[:2] == ["n_balls", "distance_cm"] and "force_gf" in header
    assert sum(line.split()[:2] in (["12", "14"], ["16", "20"]) for line in printed) == 2
    # One distance per design: no figure, and the reason instead.
    one = [r for r in rows if r["distance_cm"] == 14.0]
    reason = design_figure(one, tmp_path / "one")
    assert isinstance(reason, str) and "two distances" in reason and not (tmp_path / "one" / "design.png").exists()


def test_design_figure_axes_follow_the_grid(tmp_path):
    """The figure's x-axis spans the grid's distances and its title names the configuration."""
    import matplotlib

    matplotlib.use("Agg")
    from unittest import mock

    import matplotlib.pyplot as plt

    from ballchain.experiments.studies import design_figure

    rows = [{"ball_diameter_mm": 3.175, "n_balls": n, "magnet": "cylinder", "distance_cm": d, "vein": "LSPV",
             "config": "1", "sleeve": False, "grid": 2, "refine_evaluations": 1, "force_gf": f, "error": None}
            for n, d, f in ((12, 14.0, 3.0), (12, 20.0, 1.0), (16, 14.0, 4.0), (16, 20.0, 1.5))]
    with mock.patch.object(plt, "close"):  # keep the figure to read its axes
        design_figure(rows, tmp_path)
        ax = plt.gcf().axes[0]
    lo, hi = ax.get_xlim()
    assert 13.0 < lo < 14.0 and 20.0 < hi < 21.0  # the grid's 14-20 cm (the 29.65 cm line left out)
    assert "one magnet, patient's right" in ax.get_title() and "two magnets" not in ax.get_title()
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any("n_balls 12" in t for t in labels) and any("n_balls 16" in t for t in labels)
    plt.close("all")


EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "docs" / "guide" / "sweep_examples").glob("*.yaml"))


def test_every_experiment_has_an_example_spec_and_documents_its_fields():
    from ballchain.experiments.studies import field_docs

    assert sorted(p.stem for p in EXAMPLES) == sorted(EXPERIMENTS)
    for name, exp in EXPERIMENTS.items():
        import dataclasses

        documented = field_docs(exp.params)
        assert [f.name for f in dataclasses.fields(exp.params)] == list(documented), name
        assert all(documented.values()) and all(exp.outputs.values()), name


@pytest.mark.slow
@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_the_sweep_reference_example_runs_and_its_outputs_are_documented(path, tmp_path):
    """Each experiment's example spec of the sweep reference runs as it stands, and every output
    column it writes is one the reference explains (``Experiment.outputs``)."""
    spec = load_spec(path)
    result = run_sweep(spec, tmp_path, workers=0, progress=False)
    assert result["failed"] == 0 and result["ran"] == result["points"] > 0
    rows = read_table(tmp_path)
    import dataclasses

    params = {f.name for f in dataclasses.fields(EXPERIMENTS[spec.experiment].params)}
    meta = {"key", "experiment", "seed", "wall_time_s", "cpu_time_s", "worker", "error"}
    assert set(rows[0]) - params - meta == set(EXPERIMENTS[spec.experiment].outputs)
