"""A sweep's run: one task per point on the executor, rows streamed into the table, lost points
resubmitted, an interrupt keeping every finished row (``run_sweep``); one point (``run_point``)."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path
from typing import Callable

from ballchain.infrastructure.arg_checks import require_positive
from ballchain.infrastructure.errors import UserInputError, caused_by_interrupt, short_repr, quote_path
from ballchain.executor import (CONNECT_TIMEOUT, Executor, _check_executor, _infrastructure_error, _worker_name,
                                default_workers)
from ballchain.sweep.spec import SweepSpec, point_key
from ballchain.sweep.table import (TABLE_CSV, TABLE_PARQUET, _atomic_write, _check_out, _read_previous, _scalar,
                                   write_table)

MAX_ATTEMPTS = 3  # submissions of one point whose worker died before it gives up (an error row)
WRITE_PERIOD = 2.0  # [s] between table writes while results stream in


def run_point(experiment: str, params: dict, seed: int) -> dict:
    """Run one point (on a worker or in-process) and return its table row.

    BLAS is pinned to one thread, as the ``ballchain`` command does: every matrix here is small,
    and threaded BLAS in each of several worker processes only oversubscribes the cores. An
    exception in the experiment becomes the row's ``error`` (type and message).
    """
    from threadpoolctl import threadpool_limits

    from ballchain.experiments.studies import EXPERIMENTS

    exp = EXPERIMENTS[experiment]
    p = exp.params(**params)
    row = {"key": point_key(experiment, p, seed), "experiment": experiment, **dataclasses.asdict(p), "seed": seed}
    start, cpu_start = time.perf_counter(), time.process_time()
    error = None
    outputs: dict = {}
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            outputs = exp.point(p, seed)
    except Exception as err:  # noqa: BLE001: a failed point is a row with the reason
        if caused_by_interrupt(err):  # Ctrl-C inside compiled code comes back wrapped: still Ctrl-C
            raise KeyboardInterrupt from err
        error = f"{type(err).__name__}: {err}"
    clash = set(outputs) & set(row)
    if clash:
        error = f"experiment {experiment!r} returned outputs named like parameters: {sorted(clash)}"
        outputs = {}
    row.update({k: _scalar(v) for k, v in outputs.items()})
    # CPU time besides wall time: on a shared machine the wall time also counts other jobs.
    row.update(wall_time_s=time.perf_counter() - start, cpu_time_s=time.process_time() - cpu_start,
               worker=_worker_name(), error=error)
    return row


def _lost_row(experiment: str, params, seed: int, reason: str) -> dict:
    row = {"key": point_key(experiment, params, seed), "experiment": experiment, **dataclasses.asdict(params),
           "seed": seed}
    row.update(wall_time_s=None, cpu_time_s=None, worker=None, error=reason)
    return row


def run_sweep(spec: SweepSpec, out: str | Path, *, scheduler: str | None = None, workers: int | None = None,
              jobqueue: str | None = None, client=None, progress: bool = True, figure: bool = True,
              on_result: Callable[[int, "Executor"], None] | None = None,
              echo: Callable[[str], None] | None = None, connect_timeout: float = CONNECT_TIMEOUT,
              append: bool = False) -> dict:
    """Run every point of ``spec`` not already done in ``out``; write the table (and the figure).

    Args:
        spec: from ``load_spec``.
        out: the results folder (created); a rerun with the same folder skips the points that
            already have a row without error and reruns the failed ones. A folder whose table
            holds rows that are not points of ``spec`` (another spec's) is refused unless
            ``append``.
        scheduler: address of an existing Dask scheduler (tcp://host:8786).
        workers: worker processes of the LocalCluster (default: one per core), jobs of the job
            queue; 0 runs the points serially in this process.
        jobqueue: a dask-jobqueue cluster kind ("slurm", "pbs", ...) configured by dask-jobqueue's
            own configuration file.
        client: an existing ``distributed.Client`` to use (tests, notebooks).
        progress: a tqdm bar over points.
        figure: draw the experiment's figure from the table at the end.
        on_result: called as ``on_result(points_finished, executor)`` after each finished point
            (tests use it to kill a worker mid-sweep).
        echo: called with one line each before the work starts: the number of points and an
            estimate of their time, and a note when an earlier table was unreadable.
        connect_timeout: [s] for ``scheduler`` to answer (``CONNECT_TIMEOUT``).
        append: keep another spec's rows in ``out``'s table and add this spec's (``--append``);
            the table then has a ``spec`` column naming the spec each row came from.

    Returns:
        {"experiment", "out", "table_parquet", "table_csv", "points", "ran", "skipped", "failed",
        "resubmitted", "interrupted", "wall_time_s", "executor", "figure", "summary"}

    Example:
        A two-point sweep run serially in this process, its table read back::

            >>> import tempfile, ballchain as bc
            >>> from ballchain.sweep import read_table
            >>> spec = bc.load_spec("example", text="{experiment: statics, grid: {n_balls: [4, 6]}}")
            >>> out = tempfile.mkdtemp()
            >>> result = bc.run_sweep(spec, out, workers=0, progress=False)
            >>> result["ran"], result["failed"]
            (2, 0)
            >>> [(r["n_balls"], round(r["tip_y_mm"], 1)) for r in read_table(out)]
            [(4, 7.1), (6, 13.4)]
    """
    from tqdm import tqdm

    from ballchain.experiments.studies import EXPERIMENTS

    if not isinstance(spec, SweepSpec):
        raise UserInputError(f"run_sweep spec must be a SweepSpec: ballchain.load_spec(file) (a shipped "
                             f"study's file is ballchain/studies/NAME.yaml), got {type(spec).__name__} {short_repr(spec)}")
    if not isinstance(out, (str, os.PathLike)) or not str(out).strip():
        raise UserInputError(f"run_sweep out must be a folder name, got {short_repr(out)}")
    require_positive(connect_timeout, "run_sweep connect_timeout", "s")
    if client is not None and not hasattr(client, "submit"):
        raise UserInputError(f"run_sweep client must be a distributed.Client or None, got {type(client).__name__}")
    _check_executor(scheduler, workers, jobqueue)
    if not isinstance(append, bool):
        raise UserInputError(f"run_sweep append must be true or false, got {short_repr(append)}")
    out = _check_out(out)
    exp = EXPERIMENTS[spec.experiment]
    param_names = [f.name for f in dataclasses.fields(exp.params)]
    first = param_names + ["seed"]
    previous, note = _read_previous(out, exp)
    others = sorted({r.get("experiment") for r in previous} - {spec.experiment})
    if others:
        raise UserInputError(f"--out {out} holds a sweep of experiment {others[0]!r}, not {spec.experiment!r}: "
                             "use another folder")
    done = {r["key"]: r for r in previous if r.get("error") is None}
    tasks = spec.tasks()
    keys = [point_key(spec.experiment, p, s) for p, s in tasks]
    # Earlier rows of these points (a failed one stays until its rerun replaces it).
    earlier = {r["key"]: r for r in previous}
    rows: dict[str, dict] = {k: earlier[k] for k in keys if k in earlier}
    todo = [(k, p, s) for k, (p, s) in zip(keys, tasks) if k not in done]
    key_set = set(keys)
    extra = [r for r in previous if r["key"] not in key_set]  # points of another spec: kept with --append
    if extra and not append:
        held = sorted({str(r["spec"]) for r in extra if r.get("spec")}) or [_recorded_spec(out) or "an earlier spec"]
        shown = ", ".join(map(quote_path, held[:3])) + (f" and {len(held) - 3} more" if len(held) > 3 else "")
        whose = (f"rows of an earlier version of {shown} (or of the experiment's parameters)" if held == [spec.source]
                 else f"rows of another sweep spec ({shown})")
        raise UserInputError(f"--out {quote_path(out)} holds {whose}: {len(extra)} of its {len(previous)} rows "
                             f"are not points of {quote_path(spec.source)}; give another folder, or --append to add "
                             "this spec's rows to that table")
    if append:  # every row says which spec it came from (the earlier ones: the spec the folder's last run ran)
        held = _recorded_spec(out) or "an earlier spec"
        for r in previous:
            if not r.get("spec"):
                r["spec"] = held

    def ordered() -> list[dict]:
        table = [rows[k] for k in keys if k in rows] + extra
        return [r if r.get("spec") else {**r, "spec": spec.source} for r in table] if append else table

    last_write = [0.0]

    def save(force: bool = False) -> None:
        if force or time.perf_counter() - last_write[0] > WRITE_PERIOD:
            write_table(out, ordered(), first)
            last_write[0] = time.perf_counter()

    if echo is not None:
        if note:
            echo(note)
        echo(_announce(spec.experiment, len(tasks), len(todo), previous, exp.typical_s, scheduler, workers,
                       jobqueue, client))
    start = time.perf_counter()
    interrupted, resubmitted, ran = False, 0, [0]
    bar = tqdm(total=len(tasks), initial=len(tasks) - len(todo), desc=f"sweep {spec.experiment}", unit="point",
               disable=not progress)
    if not todo:  # everything done before: no cluster to start (the table and figure are redrawn)
        scheduler, workers, jobqueue, client = None, 0, None, None
    ex = None
    try:
        with Executor(scheduler=scheduler, workers=workers, jobqueue=jobqueue, client=client,
                      connect_timeout=connect_timeout) as ex:
            try:
                if ex.client is None:
                    for n, (k, p, s) in enumerate(todo, 1):
                        rows[k] = run_point(spec.experiment, dataclasses.asdict(p), s)
                        ran[0] += 1
                        bar.update(1)
                        save()
                        if on_result:
                            on_result(n, ex)
                else:
                    resubmitted = _run_on_client(ex, spec.experiment, todo, rows, bar, save, on_result, ran)
            except KeyboardInterrupt:
                interrupted = True
                save(force=True)  # before the cluster closes: a second Ctrl-C there must not cost the rows
    except KeyboardInterrupt:
        if ex is None:  # stopped while the cluster started: no point ran
            raise
        interrupted = True  # stopped while the cluster closed: the rows are written below all the same
    bar.close()
    save(force=True)
    table_rows = ordered()
    summary = exp.summary(table_rows) if exp.summary and not interrupted else None
    figure_path = figure_note = None
    if figure and exp.figure and not interrupted and any(r.get("error") is None for r in table_rows):
        drawn = exp.figure(table_rows, out)  # a path, or a line saying why this grid gives no figure
        figure_path, figure_note = (None, drawn) if isinstance(drawn, str) else (drawn, None)
    result = {
        "experiment": spec.experiment, "description": spec.description, "spec": spec.source, "out": out,
        "table_parquet": out / TABLE_PARQUET, "table_csv": out / TABLE_CSV, "points": len(tasks),
        "ran": ran[0], "skipped": len(tasks) - len(todo),
        "failed": sum(1 for k in keys if k in rows and rows[k].get("error") is not None),
        "resubmitted": resubmitted, "interrupted": interrupted, "wall_time_s": time.perf_counter() - start,
        "executor": ex.description, "figure": figure_path, "figure_note": figure_note, "summary": summary,
        "table_note": note,
    }
    from ballchain.infrastructure.safe_files import to_jsonable

    _atomic_write(out / "sweep.json", lambda tmp: Path(tmp).write_text(
        json.dumps(to_jsonable(result), indent=1, allow_nan=False, default=str)))
    return result


def _recorded_spec(out: Path) -> str | None:
    """The spec the last sweep into ``out`` ran, as its ``sweep.json`` records it (None: none)."""
    path = out / "sweep.json"
    try:
        if path.stat().st_size > 10_000_000:  # the sweep writes a few kB: not its file
            return None
        recorded = json.loads(path.read_text(encoding="utf-8")).get("spec")
    except (OSError, ValueError, RecursionError, AttributeError):
        return None
    return recorded if isinstance(recorded, str) and recorded else None


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _announce(experiment: str, n_tasks: int, n_todo: int, previous: list[dict], typical_s: float,
              scheduler, workers, jobqueue, client) -> str:
    """One line before the work: the points, those done before, and an estimate of the time
    (a point's median CPU time in the earlier table, else the experiment's typical one)."""
    import statistics

    times = [r["cpu_time_s"] for r in previous
             if r.get("experiment") == experiment and r.get("error") is None and r.get("cpu_time_s")]
    per_point, basis = (statistics.median(times), "the earlier table") if times else (typical_s, "typical")
    cpu = n_todo * per_point
    if n_todo == 0:
        where = "nothing to run"
    elif client is None and scheduler is None and jobqueue is None:
        n = 1 if workers == 0 else (workers or default_workers())
        where = f"about {_duration(cpu / min(n, n_todo))} on {n} worker process(es)"
    else:
        where = "less on several workers"
    return (f"sweep {experiment}: {n_tasks} points, {n_tasks - n_todo} done before, {n_todo} to run; estimate "
            f"{_duration(cpu)} of CPU time ({per_point:.3g} s a point, {basis}), {where}")


def _run_on_client(ex: Executor, experiment: str, todo, rows: dict, bar, save, on_result, ran: list) -> int:
    """Submit every point, collect rows as they finish (counted in ``ran[0]``), resubmit the ones
    lost with a worker; returns the number of resubmissions."""
    from concurrent.futures import CancelledError

    from distributed import wait

    import uuid

    client = ex.client
    attempts: dict[str, int] = {}
    run_id = uuid.uuid4().hex[:8]
    specs = {k: (p, s) for k, p, s in todo}

    def submit(k):
        attempts[k] = attempts.get(k, 0) + 1
        p, s = specs[k]
        # The key names the point, this run and the attempt: a key the scheduler still holds
        # from an earlier run on the same cluster would hand back that run's result without
        # computing (a stale row), and a resubmission must not meet its cancelled predecessor.
        return client.submit(run_point, experiment, dataclasses.asdict(p), s,
                             key=f"{experiment}-{k}-{run_id}-{attempts[k]}", pure=False)

    futures = {submit(k): k for k, _, _ in todo}
    finished, resubmitted = 0, 0
    try:
        while futures:
            # Futures cancelled by a restart make ``wait`` raise: take them first, and if one is
            # cancelled while waiting, look again. The timeout keeps Ctrl-C responsive.
            done = [f for f in futures if f.status in ("cancelled", "lost")]
            if not done:
                try:
                    done, _ = wait(list(futures), timeout=1.0, return_when="FIRST_COMPLETED")
                except (CancelledError, TimeoutError):  # distributed's wait raises on its timeout
                    continue
            for future in done:
                k = futures.pop(future, None)
                if k is None:
                    continue
                status, row = future.status, None
                if status == "finished":
                    try:
                        row = future.result(timeout=30)
                    except Exception as err:  # noqa: BLE001: the result was lost in transit
                        status, exc = "lost", err
                elif status == "error":
                    exc = future.exception()
                    status = "lost" if _infrastructure_error(exc) else "error"
                else:
                    exc = None
                if row is None and status in ("cancelled", "lost"):
                    if attempts[k] < MAX_ATTEMPTS:
                        futures[submit(k)] = k
                        resubmitted += 1
                        continue
                    p, s = specs[k]
                    row = _lost_row(experiment, p, s, f"lost with its worker {attempts[k]} times: {exc!r}")
                elif row is None:  # the task itself failed outside the point (e.g. unpickling)
                    p, s = specs[k]
                    row = _lost_row(experiment, p, s, f"{type(exc).__name__}: {exc}")
                rows[k] = row
                finished += 1
                ran[0] += 1
                bar.update(1)
                save()
                if on_result:
                    on_result(finished, ex)
    except KeyboardInterrupt:
        client.cancel(list(futures))
        raise
    return resubmitted
