"""Sweeps and studies on Dask distributed: one task per point, one table of results.

A sweep spec (YAML, typed like the scenarios: a dataclass schema loaded with pydrake's
``yaml_load_typed``) names an experiment of ``ballchain.experiments.studies.EXPERIMENTS`` and
its points, a grid (the cartesian product of per-field lists) and/or a list of explicit
parameter sets, times a list of seeds::

    experiment: design
    description: which ball and magnet give 10 gf on every vein
    grid:
      ball_diameter_mm: [3.175, 2.17]
      magnet: [cylinder, sphere119]
      distance_cm: [16.51, 29.65]
    points:
      - {ball_diameter_mm: 2.17, magnet: sphere119, distance_cm: 35.6}
    seeds: [0]

Fields a point does not set take the experiment's defaults. The spec is checked before any
cluster starts, ``UserInputError`` naming the field: the file (UTF-8 text, or UTF-16 with its
BOM; read by ``drake_models/safe_yaml.py``), unknown experiment or field, wrong type, empty grid,
the number of runs (points x seeds, counted as the product of the axes' lengths before the grid
is expanded; at most ``DEFAULT_MAX_POINTS`` unless ``max_points`` says more), and every point's
values against its experiment's check, which applies the rules of the experiment's command.

``run_sweep`` runs each point as a Dask task: by default on a ``LocalCluster`` of worker
processes (one thread each) sized to the machine's cores (at most ``MAX_WORKERS_PER_CORE`` per
core), on an existing cluster (``scheduler="tcp://host:8786"``: asked who it is first, within
``CONNECT_TIMEOUT``), on a dask-jobqueue cluster (``jobqueue="slurm"``, optional dependency, at
most ``MAX_JOBS`` jobs), or serially in this process (``workers=0``). Rows stream into ``DIR/table.parquet``
and ``DIR/table.csv`` (each write atomic: a temporary file and ``os.replace``), one row per point:
its key (a hash of the experiment, parameters and seed), the parameters, the seed, the outputs,
the wall and CPU time, the worker and the error if it failed (a failed point is a row with the reason).
Tasks lost with a worker (killed, restarted) are resubmitted; Ctrl-C writes the table with every
finished point (before the cluster closes); a rerun with the same ``DIR`` skips the points that
already have a row without error (from ``table.csv`` when ``table.parquet`` is unreadable).

``run_sections`` maps independent report sections over the same executor (``reproduce``).
"""

from __future__ import annotations

import codecs
import dataclasses
import hashlib
import itertools
import json
import math
import os
import time
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, NamedTuple, Sequence

from ballchain.drake_models.arg_checks import require_positive
from ballchain.drake_models.errors import UserInputError, caused_by_interrupt, short_repr
from ballchain.drake_models.safe_files import atomic_path, check_output_dir, register_input

TABLE_PARQUET = "table.parquet"
TABLE_CSV = "table.csv"
MAX_TABLE_BYTES = 1_000_000_000  # a results table read back on resume (5000 points are a few MB)
META_COLUMNS = ("key", "experiment")
TAIL_COLUMNS = ("wall_time_s", "cpu_time_s", "worker", "error")
MAX_ATTEMPTS = 3  # submissions of one point whose worker died before it gives up (an error row)
WRITE_PERIOD = 2.0  # [s] between table writes while results stream in
SPEC_KEYS = ("experiment", "description", "grid", "points", "seeds")
DEFAULT_MAX_POINTS = 5000  # runs (points x seeds) a spec may hold unless --max-points raises it


# --- the spec ------------------------------------------------------------------------------------

@dataclass
class SweepSpec:
    """A loaded, checked sweep spec.

    Attributes:
        experiment: a name in ``ballchain.experiments.studies.EXPERIMENTS``.
        description: one line.
        points: the parameter sets (each a dataclass instance of the experiment's ``params``),
            the grid's product first, then the explicit ones.
        seeds: every point runs once per seed.
        source: the file it came from (or "<inline>").
    """

    experiment: str
    description: str
    points: list
    seeds: list[int]
    source: str = "<inline>"

    def tasks(self) -> list[tuple[Any, int]]:
        """(params, seed) of every run, in the table's order (points outer, seeds inner)."""
        return [(p, s) for p in self.points for s in self.seeds]


def _schema(experiment) -> type:
    """The typed spec schema of one experiment (for ``yaml_load_typed``)."""
    hints = typing.get_type_hints(experiment.params)
    Grid = dataclasses.make_dataclass(
        f"{experiment.params.__name__}Grid",
        [(f.name, list[hints[f.name]], field(default_factory=list)) for f in dataclasses.fields(experiment.params)])
    return dataclasses.make_dataclass(f"{experiment.params.__name__}Sweep", [
        ("experiment", str, ""), ("description", str, ""),
        ("grid", Grid, field(default_factory=Grid)),
        ("points", list[experiment.params], field(default_factory=list)),
        ("seeds", list[int], field(default_factory=lambda: [0])),
    ])


def load_spec(source: str | Path, *, text: str | None = None, max_points: int = DEFAULT_MAX_POINTS) -> SweepSpec:
    """Load and check a sweep spec (a YAML file, or ``text``).

    Args:
        source: the spec file (or a label for ``text``).
        text: inline YAML instead of reading ``source``.
        max_points: the most runs (points x seeds) the spec may hold (``--max-points``).

    Raises:
        UserInputError: an unreadable, binary or non-UTF-8 file, YAML that ``safe_yaml`` refuses,
            an unknown experiment, an unknown field, a value of the wrong type, an empty grid or
            field list, more runs than ``max_points`` (counted before the grid is expanded), or a
            value the experiment's command refuses; the message names the field (and the point).
    """
    from ballchain.drake_models.safe_yaml import load_typed, load_yaml

    if not isinstance(source, (str, os.PathLike)) or not str(source).strip():
        raise UserInputError(f"load_spec source must be a spec file's name (or a label with text=...), "
                             f"got {short_repr(source)}")
    if text is not None and not isinstance(text, str):
        raise UserInputError(f"load_spec text must be the spec's YAML text, got {type(text).__name__}")
    label = str(source)
    where = f"sweep spec {short_repr(label)}"
    if isinstance(max_points, bool) or not isinstance(max_points, int) or max_points < 1:
        raise UserInputError(f"--max-points must be an integer >= 1, got {short_repr(max_points)}")
    raw = load_yaml(_read_spec_text(Path(source), where) if text is None else text, where)
    experiment = _spec_experiment(raw, where)
    hints = typing.get_type_hints(experiment.params)
    grid = _spec_grid(raw, hints, where, experiment.name)
    points = _spec_points(raw, hints, where, experiment.name)
    seeds = _spec_seeds(raw, where)
    n_grid = math.prod(len(values) for values in grid.values()) if grid else 0
    runs = (n_grid + len(points)) * len(seeds)
    if runs > max_points:
        raise UserInputError(f"{where}: {runs} runs ({n_grid} grid points + {len(points)} points, times {len(seeds)} "
                             f"seed(s)) exceed the limit of {max_points}: split the study, or raise --max-points")
    typed = load_typed(raw, _schema(experiment), where)
    axes = [f.name for f in dataclasses.fields(experiment.params) if f.name in grid]
    product = [experiment.params(**dict(zip(axes, combo)))
               for combo in itertools.product(*(getattr(typed.grid, a) for a in axes))] if axes else []
    all_points = product + list(typed.points)
    _check_point_values(experiment, all_points, len(product), axes, where)
    keys = [point_key(experiment.name, p, s) for p in all_points for s in seeds]
    if len(set(keys)) != len(keys):
        raise UserInputError(f"{where}: the same point appears twice (grid and points overlap)")
    return SweepSpec(experiment.name, typed.description, all_points, list(seeds), label)


def _read_spec_text(path: Path, where: str) -> str:
    """A spec file's text: UTF-8 (a BOM is skipped), or UTF-16 with its BOM (as some Windows
    editors save); a binary file or another encoding is refused."""
    from ballchain.drake_models.input_files import read_input_file
    from ballchain.drake_models.safe_yaml import MAX_BYTES

    data = read_input_file(path, where, MAX_BYTES, "a spec file (YAML)")
    register_input(path, "sweep spec")  # the sweep's outputs may not replace it
    try:
        if data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
            return data.decode("utf-16")
        if b"\0" in data:
            raise UserInputError(f"{where} is a binary file, not YAML text (save the spec as UTF-8 text)")
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise UserInputError(f"{where} is not UTF-8 text (byte {err.start} is not): save it as UTF-8") from None


def _spec_experiment(raw, where: str):
    """The spec's experiment, once the top level is a mapping of known keys."""
    from ballchain.experiments.studies import EXPERIMENTS

    if raw is None:
        raise UserInputError(f"{where} is empty: give a mapping with keys {SPEC_KEYS}")
    if not isinstance(raw, dict):
        raise UserInputError(f"{where}: must be a mapping with keys {SPEC_KEYS}, got a {type(raw).__name__}")
    unknown = [k for k in raw if k not in SPEC_KEYS]
    if unknown:
        raise UserInputError(f"{where}: unknown field(s) {short_repr(unknown)}; allowed: {SPEC_KEYS}")
    for key in ("experiment", "description"):
        if key in raw and not isinstance(raw[key], str):
            raise UserInputError(f"{where}: {key} must be a string, got {short_repr(raw[key])}")
    name = raw.get("experiment")
    if name not in EXPERIMENTS:
        raise UserInputError(f"{where}: experiment must be one of {sorted(EXPERIMENTS)}, got {short_repr(name)}")
    return EXPERIMENTS[name]


def _spec_field(key, hints: dict, where: str, name: str, at: str) -> None:
    if key not in hints:
        raise UserInputError(f"{where}: {at} is not a field of experiment {name!r}; fields: {list(hints)}")


def _spec_grid(raw: dict, hints: dict, where: str, name: str) -> dict:
    """The grid: field -> non-empty list of values, each of the field's type."""
    from ballchain.systems.chain_scenario import check_value

    grid = raw.get("grid")
    if grid is None:
        return {}
    if not isinstance(grid, dict):
        raise UserInputError(f"{where}: grid must be a mapping of field -> list of values, got {short_repr(grid)}")
    for key, values in grid.items():
        _spec_field(key, hints, where, name, f"grid.{key}")
        if not isinstance(values, list):
            raise UserInputError(f"{where}: grid.{key} must be a list of values, got {short_repr(values)}")
        if not values:
            raise UserInputError(f"{where}: grid.{key} is empty (give at least one value)")
        for k, v in enumerate(values):
            check_value(v, hints[key], f"grid.{key}[{k}]", where)
    return grid


def _spec_points(raw: dict, hints: dict, where: str, name: str) -> list:
    """The explicit points: mappings of field -> value of the field's type."""
    from ballchain.systems.chain_scenario import check_value

    points = raw.get("points")
    if points is None:
        points = []
    if not isinstance(points, list):
        raise UserInputError(f"{where}: points must be a list of parameter sets, got {short_repr(points)}")
    for k, point in enumerate(points):
        if not isinstance(point, dict):
            raise UserInputError(f"{where}: points[{k}] must be a mapping of field -> value, got {short_repr(point)}")
        for key, v in point.items():
            _spec_field(key, hints, where, name, f"points[{k}].{key}")
            check_value(v, hints[key], f"points[{k}].{key}", where)
    if not raw.get("grid") and not points:
        raise UserInputError(f"{where}: the grid is empty and there are no points "
                             f"(give grid: {{field: [values]}} or points: [{{field: value}}])")
    return points


def _spec_seeds(raw: dict, where: str) -> list[int]:
    """Distinct seeds, each in the range the operator's tremor takes (``teleop.check_seed``)."""
    from ballchain.experiments.teleop import check_seed
    from ballchain.systems.chain_scenario import check_value

    seeds = raw.get("seeds", [0])
    if not isinstance(seeds, list) or not seeds:
        raise UserInputError(f"{where}: seeds must be a non-empty list of integers, got {short_repr(seeds)}")
    for k, s in enumerate(seeds):
        check_value(s, int, f"seeds[{k}]", where)
        check_seed(s, f"{where}: seeds[{k}]")
    if len(set(seeds)) != len(seeds):
        raise UserInputError(f"{where}: seeds has duplicates: {short_repr(seeds)}")
    return seeds


def _check_point_values(experiment, points: list, n_grid: int, axes: list[str], where: str) -> None:
    """Every point against the experiment's check (the rules of its command's flags)."""
    if experiment.check is None:
        return
    for k, p in enumerate(points):
        try:
            experiment.check(p)
        except UserInputError as err:
            if k < n_grid:
                values = ", ".join(f"{a}={short_repr(getattr(p, a))}" for a in axes)
                at = f"grid point {k + 1} of {n_grid} ({values})"
            else:
                at = f"points[{k - n_grid}]"
            raise UserInputError(f"{where}: {at}: {err}") from None


def point_key(experiment: str, params, seed: int) -> str:
    """A stable 16-hex-digit key of one run: the experiment, its parameters and its seed."""
    payload = json.dumps({"experiment": experiment, "params": dataclasses.asdict(params), "seed": seed},
                         sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


# --- one point ------------------------------------------------------------------------------------

def _scalar(value):
    """A table cell: None, bool, int, float or str; anything else as JSON text."""
    import numpy as np

    if isinstance(value, np.generic):
        value = value.item()
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    from ballchain.drake_models.safe_files import to_jsonable

    return json.dumps(to_jsonable(value), allow_nan=False, default=str)


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


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return "serial"


# --- the table ------------------------------------------------------------------------------------

def _atomic_write(path: Path, write: Callable[[str], None]) -> None:
    """``write(temporary path)`` next to ``path``, then renamed onto it (``safe_files.atomic_path``)."""
    with atomic_path(path) as tmp:
        write(str(tmp))


def _columns(rows: list[dict], first: Sequence[str]) -> list[str]:
    columns = list(first)
    for row in rows:
        columns += [k for k in row if k not in columns and k not in TAIL_COLUMNS]
    return columns + list(TAIL_COLUMNS)


def rows_to_table(rows: list[dict], first: Sequence[str] = ()):
    """A pyarrow Table of the rows (columns: ``first``, then in order of appearance, then the
    wall time, worker and error). A column whose values do not share a type is stored as text."""
    import pyarrow as pa

    columns = _columns(rows, list(META_COLUMNS) + list(first))
    arrays = {}
    for c in columns:
        values = [r.get(c) for r in rows]
        try:
            arrays[c] = pa.array(values)
        except (pa.ArrowInvalid, pa.ArrowTypeError):
            arrays[c] = pa.array([None if v is None else str(v) for v in values], pa.string())
    return pa.table(arrays)


def write_table(out: Path, rows: list[dict], first: Sequence[str] = ()) -> None:
    """Write ``out/table.parquet`` and ``out/table.csv`` atomically."""
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    table = rows_to_table(rows, first)
    _atomic_write(out / TABLE_PARQUET, lambda tmp: pq.write_table(table, tmp))
    _atomic_write(out / TABLE_CSV, lambda tmp: pacsv.write_csv(table, tmp))


def read_table(out: Path) -> list[dict]:
    """The rows of ``out/table.parquet`` (empty if there is none)."""
    import pyarrow.parquet as pq

    from ballchain.drake_models.input_files import check_input_file

    path = Path(out) / TABLE_PARQUET
    if not path.exists():
        return []
    check_input_file(path, f"--out {short_repr(str(out))}: {TABLE_PARQUET}", MAX_TABLE_BYTES, "a sweep's table")
    return pq.read_table(path).to_pylist()


def read_table_csv(out: Path, experiment) -> list[dict]:
    """The rows of ``out/table.csv``, typed as the Parquet table is: the experiment's parameters
    by their fields' types, the key, seed, times, worker and error by theirs; the outputs as
    pyarrow infers them. Raises pyarrow's errors (or OSError) on a file that does not parse, and
    UserInputError on one that is not a regular file or larger than ``MAX_TABLE_BYTES``."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    arrow = {bool: pa.bool_(), int: pa.int64(), float: pa.float64(), str: pa.string()}
    types = {"key": pa.string(), "experiment": pa.string(), "seed": pa.int64(), "wall_time_s": pa.float64(),
             "cpu_time_s": pa.float64(), "worker": pa.string(), "error": pa.string()}
    types.update({name: arrow[t] for name, t in typing.get_type_hints(experiment.params).items()})
    from ballchain.drake_models.input_files import check_input_file

    check_input_file(Path(out) / TABLE_CSV, f"--out {short_repr(str(out))}: {TABLE_CSV}", MAX_TABLE_BYTES,
                     "a sweep's table")
    table = pacsv.read_csv(Path(out) / TABLE_CSV,
                           convert_options=pacsv.ConvertOptions(column_types=types, strings_can_be_null=True))
    return table.to_pylist()


def _read_previous(out: Path, experiment) -> tuple[list[dict], str | None]:
    """The earlier rows in ``out`` and a one-line note when ``table.parquet`` was unreadable
    (truncated, corrupt): then the rows come from ``table.csv`` if it parses and holds the same
    points' keys, else the points run again; the unreadable file is kept beside it.

    Raises:
        UserInputError: ``table.parquet`` is a readable table but not a sweep's (no key column).
    """
    import pyarrow as pa

    parquet = out / TABLE_PARQUET
    try:
        rows = read_table(out)
    except (pa.ArrowException, OSError, ValueError) as err:
        reason = " ".join(str(err).split())[:120] or type(err).__name__
    else:
        if rows and not all(isinstance(r.get("key"), str) and r.get("experiment") for r in rows):
            raise UserInputError(f"--out {out}: its {TABLE_PARQUET} is not a sweep's table (no key or experiment "
                                 "column): use another folder")
        return rows, None
    aside = parquet.with_name(TABLE_PARQUET + ".unreadable")
    os.replace(parquet, aside)
    try:
        rows = read_table_csv(out, experiment)
        if not all(isinstance(r.get("key"), str) and r.get("experiment") for r in rows):
            raise ValueError("no key or experiment column")
        source = f"resumed from {TABLE_CSV} ({len(rows)} rows)"
    except (pa.ArrowException, OSError, ValueError):
        rows, source = [], f"{TABLE_CSV} is unreadable too: every point runs again"
    return rows, f"--out {out}: {TABLE_PARQUET} is unreadable ({reason}); {source}; the file is kept as {aside.name}"


# --- the executor ---------------------------------------------------------------------------------

def _check_out(out: Path) -> Path:
    """The results folder: checked writable (``safe_files.check_output_dir``), then created."""
    out = check_output_dir(out, "--out", names=(TABLE_PARQUET, TABLE_CSV, "sweep.json"))
    out.mkdir(parents=True, exist_ok=True)
    return out


MAX_WORKERS_PER_CORE = 4  # LocalCluster processes per core: more only share the cores (and the memory)
MAX_JOBS = 256  # job-queue jobs one sweep may ask for
CONNECT_TIMEOUT = 15.0  # [s] for a scheduler to accept the connection and answer


def default_workers() -> int:
    """One worker process per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def max_workers() -> int:
    """The most LocalCluster worker processes: ``MAX_WORKERS_PER_CORE`` per core."""
    return MAX_WORKERS_PER_CORE * default_workers()


def _check_executor(scheduler: str | None, workers: int | None, jobqueue: str | None) -> None:
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
        raise UserInputError(f"--workers must be an integer >= 0 (0: serial, in this process), got {short_repr(workers)}")
    if scheduler is not None and jobqueue is not None:
        raise UserInputError("--scheduler and --jobqueue exclude each other: give one")
    if scheduler is not None and workers == 0:
        raise UserInputError("--workers 0 (serial) and --scheduler exclude each other")
    if scheduler is not None:
        _check_address(scheduler)
    if jobqueue is None and scheduler is None and workers is not None and workers > max_workers():
        raise UserInputError(f"--workers must be at most {max_workers()} ({MAX_WORKERS_PER_CORE} per core; this "
                             f"process may use {default_workers()}), got {workers}")
    if jobqueue is not None and workers is not None and workers > MAX_JOBS:
        raise UserInputError(f"--workers (jobs of --jobqueue) must be at most {MAX_JOBS}, got {workers}")
    if jobqueue is not None:
        if jobqueue not in JOBQUEUE_CLUSTERS:
            raise UserInputError(f"--jobqueue must be one of {sorted(JOBQUEUE_CLUSTERS)}, got {short_repr(jobqueue)}")
        try:
            import dask_jobqueue  # noqa: F401
        except ImportError:
            raise UserInputError("--jobqueue needs dask-jobqueue (pip install dask-jobqueue); it is an "
                                 "optional dependency") from None


def _check_address(address) -> None:
    """A scheduler address: a scheme Dask speaks (tcp:// when none is given), a host and a port."""
    from distributed.comm.addressing import parse_host_port
    from distributed.comm.registry import backends

    if not isinstance(address, str):
        raise UserInputError(f"--scheduler must be an address like tcp://host:8786, got {short_repr(address)}")
    scheme, sep, location = address.partition("://")
    if not sep:
        scheme, location = "tcp", address
    schemes = sorted(set(backends) - {"inproc"})  # inproc: only within one process
    if scheme not in schemes:
        raise UserInputError(f"--scheduler {short_repr(address)}: unknown scheme {short_repr(scheme)}; Dask "
                             f"speaks {', '.join(schemes)} (e.g. tcp://host:8786)")
    try:
        host, port = parse_host_port(location)
    except ValueError:
        host, port = "", 0
    if not host or not 0 < port < 65536:
        raise UserInputError(f"--scheduler must be an address like tcp://host:8786 (a host and a port in "
                             f"1..65535), got {short_repr(address)}")


def _probe_scheduler(address: str, timeout: float) -> None:
    """Ask what listens at ``address`` who it is (Dask's ``identity``) within ``timeout`` seconds.

    ``distributed.Client`` waits for a silent peer past its own timeout (the handshake has none),
    so the question runs first, bounded as a whole, on a loop of its own (in a thread: the caller
    may be inside a running event loop, e.g. a notebook).

    Raises:
        UserInputError: nothing answered in time, or what answered is not a Dask scheduler.
    """
    import asyncio
    from concurrent.futures import ThreadPoolExecutor

    from distributed.comm import connect

    async def identity():
        comm = await connect(address, timeout=timeout)
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            comm.abort()

    def ask():
        return asyncio.run(asyncio.wait_for(identity(), timeout))

    with ThreadPoolExecutor(max_workers=1) as pool:
        try:
            reply = pool.submit(ask).result()
        except (asyncio.TimeoutError, TimeoutError):
            raise UserInputError(f"--scheduler {short_repr(address)}: no Dask scheduler answered within {timeout:g} s "
                                 "(something else listens there, or it is busy)") from None
        except OSError as err:
            raise UserInputError(f"--scheduler {short_repr(address)}: cannot connect: {' '.join(str(err).split())[:200]}") from None
        except Exception as err:  # noqa: BLE001 - whatever a foreign service sends back
            raise UserInputError(f"--scheduler {short_repr(address)}: what listens there does not speak Dask's protocol "
                                 f"({type(err).__name__})") from None
    kind = reply.get("type") if isinstance(reply, dict) else None
    if kind != "Scheduler":
        raise UserInputError(f"--scheduler {short_repr(address)}: a Dask {kind or 'peer'} answers there, not a scheduler")


JOBQUEUE_CLUSTERS = {"slurm": "SLURMCluster", "pbs": "PBSCluster", "sge": "SGECluster", "lsf": "LSFCluster",
                     "htcondor": "HTCondorCluster", "moab": "MoabCluster", "oar": "OARCluster"}


class Executor:
    """A Dask client on a new LocalCluster, a job-queue cluster or an existing scheduler.

    Use as a context manager; ``client`` is None for the serial (in-process) executor.
    """

    def __init__(self, *, scheduler: str | None = None, workers: int | None = None, jobqueue: str | None = None,
                 client=None, connect_timeout: float = CONNECT_TIMEOUT):
        _check_executor(scheduler, workers, jobqueue)
        self.scheduler, self.workers, self.jobqueue = scheduler, workers, jobqueue
        self.connect_timeout = connect_timeout
        self.client, self._own_client, self.cluster = client, client is None, None
        self.description = "client given by the caller" if client is not None else ""

    def __enter__(self) -> "Executor":
        if self.client is not None or self.workers == 0:
            self.description = self.description or "serial (this process)"
            return self
        from distributed import Client

        if self.scheduler is not None:
            _probe_scheduler(self.scheduler, self.connect_timeout)
            try:
                self.client = Client(self.scheduler, timeout=f"{self.connect_timeout:g}s")
            except (OSError, TimeoutError) as err:
                raise UserInputError(f"--scheduler {short_repr(self.scheduler)}: cannot connect: {err}") from None
            self.description = f"scheduler {self.scheduler}"
        elif self.jobqueue is not None:
            import dask_jobqueue

            # Queue, cores, memory, walltime... come from the dask-jobqueue configuration
            # (~/.config/dask/jobqueue.yaml); --workers sets how many jobs to start.
            self.cluster = getattr(dask_jobqueue, JOBQUEUE_CLUSTERS[self.jobqueue])()
            self.cluster.scale(jobs=self.workers or 1)
            self.client = Client(self.cluster)
            self.description = f"{self.jobqueue} job queue, {self.workers or 1} job(s)"
        else:
            import logging
            import warnings

            from distributed import LocalCluster

            n = self.workers or default_workers()
            # Processes with one thread each: the points are GIL-bound Python and numpy. The
            # scheduler's HTTP server (health routes) moves to a free port when another cluster on
            # the machine holds 8787: not worth a warning.
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message=r"Port \d+ is already in use")
                self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                            dashboard_address=None, silence_logs=logging.ERROR)
            self.client = Client(self.cluster)
            self.description = f"LocalCluster, {n} worker process(es)"
        return self

    def __exit__(self, *exc) -> None:
        try:
            if self._own_client and self.client is not None:
                self.client.close()
                self.client = None
        finally:  # a stop while the client closes still closes the cluster (its worker processes)
            if self.cluster is not None:
                self.cluster.close()
                self.cluster = None


def _infrastructure_error(exc) -> bool:
    """Whether a task's failure is the cluster's (its worker died), not the point's."""
    from distributed.scheduler import KilledWorker

    try:
        from distributed.comm.core import CommClosedError
    except ImportError:  # pragma: no cover
        CommClosedError = OSError  # noqa: N806
    return isinstance(exc, (KilledWorker, CommClosedError, OSError, TimeoutError))


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
        shown = ", ".join(map(short_repr, held[:3])) + (f" and {len(held) - 3} more" if len(held) > 3 else "")
        whose = (f"rows of an earlier version of {shown} (or of the experiment's parameters)" if held == [spec.source]
                 else f"rows of another sweep spec ({shown})")
        raise UserInputError(f"--out {short_repr(str(out))} holds {whose}: {len(extra)} of its {len(previous)} rows "
                             f"are not points of {short_repr(spec.source)}; give another folder, or --append to add "
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
    from ballchain.drake_models.safe_files import to_jsonable

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


# --- parallel report sections ---------------------------------------------------------------------

class SectionRun(NamedTuple):
    """One report section's outcome: its name, what its function returned, seconds, where it ran."""

    name: str
    value: Any
    seconds: float
    worker: str


def _run_section(fn: Callable, out: str, quick: bool):
    from threadpoolctl import threadpool_limits

    start = time.perf_counter()
    with threadpool_limits(limits=1, user_api="blas"):
        value = fn(Path(out), quick)
    return value, time.perf_counter() - start, _worker_name()


def run_sections(sections: Sequence[tuple[str, Callable]], out: str | Path, quick: bool,
                 workers: int | None = None, client=None, progress: str | None = None) -> list[SectionRun]:
    """Run independent report sections ``fn(out, quick)`` in parallel; results in the given order.

    Args:
        sections: (name, fn) pairs; each fn(out: Path, quick: bool) returns what the serial loop
            would keep (for ``reproduce``: a (Section, data) pair). They must not depend on each
            other's files. fn must be importable by name (a module-level function).
        out: the report folder (shared: the workers are processes on this machine, or on
            machines that see the same folder).
        quick: passed to every fn.
        workers: LocalCluster worker processes (default: one per core); 0 or 1 runs them
            serially in this process (the reference).
        client: an existing ``distributed.Client`` instead of a new LocalCluster.
        progress: a progress bar on stderr with this description, one step per finished
            section (None: no bar).

    Returns:
        one SectionRun per section, in the order of ``sections``.

    Raises:
        the first (in section order) exception a section raised: serially at once (as the
        serial loop), on workers after the other sections finished.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    import sys

    from tqdm import tqdm

    bar = tqdm(total=len(sections), desc=progress, unit="run", disable=progress is None, file=sys.stderr)
    if client is None and workers in (0, 1):
        runs = []
        with bar:
            for name, fn in sections:
                value, seconds, worker = _run_section(fn, str(out), quick)
                runs.append(SectionRun(name, value, seconds, worker))
                bar.update()
        return runs
    with Executor(workers=workers, client=client) as ex:
        # Longest first would balance better, but the caller knows the order; the scheduler
        # starts them in submission order as workers free up.
        import uuid

        run_id = uuid.uuid4().hex[:8]  # fresh keys: never an earlier run's result (see _run_on_client)
        futures = [ex.client.submit(_run_section, fn, str(out), quick, key=f"section-{k}-{run_id}", pure=False)
                   for k, (name, fn) in enumerate(sections)]
        from distributed import as_completed

        with bar:
            for _ in as_completed(futures):
                bar.update()
        runs, first_error = [], None
        for (name, _), future in zip(sections, futures):
            if future.status == "error":
                first_error = first_error or future.exception()
                runs.append(SectionRun(name, None, math.nan, ""))
                continue
            value, seconds, worker = future.result()
            runs.append(SectionRun(name, value, seconds, worker))
    if first_error is not None:
        raise first_error
    return runs
