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
BOM; read by ``infrastructure/safe_yaml.py``), unknown experiment or field, wrong type, empty grid,
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

The package: ``spec.py`` (the schema, ``load_spec``, ``point_key``), ``table.py`` (the results
table), ``runner.py`` (``run_sweep``, ``run_point``). The Dask executor (``ballchain/executor.py``)
and the report sections' runner (``ballchain/sections.py``: ``run_sections``, which ``reproduce``
and the procedure report use) are modules of their own beside it, re-exported here under their
old names.
"""

from ballchain.executor import (CONNECT_TIMEOUT, JOBQUEUE_CLUSTERS, MAX_JOBS, MAX_WORKERS_PER_CORE, Executor,
                                default_workers, max_workers)
from ballchain.sections import SectionRun, run_sections
from ballchain.sweep import runner, spec, table
from ballchain.sweep.runner import MAX_ATTEMPTS, WRITE_PERIOD, run_point, run_sweep
from ballchain.sweep.spec import DEFAULT_MAX_POINTS, SPEC_KEYS, SweepSpec, load_spec, point_key
from ballchain.sweep.table import (MAX_TABLE_BYTES, META_COLUMNS, TABLE_CSV, TABLE_PARQUET, TAIL_COLUMNS, read_table,
                                   read_table_csv, rows_to_table, write_table)

__all__ = [
    "CONNECT_TIMEOUT", "DEFAULT_MAX_POINTS", "Executor", "JOBQUEUE_CLUSTERS", "MAX_ATTEMPTS", "MAX_JOBS",
    "MAX_TABLE_BYTES", "MAX_WORKERS_PER_CORE", "META_COLUMNS", "SPEC_KEYS", "SectionRun", "SweepSpec", "TABLE_CSV",
    "TABLE_PARQUET", "TAIL_COLUMNS", "WRITE_PERIOD", "default_workers", "load_spec", "max_workers", "point_key",
    "read_table", "read_table_csv", "rows_to_table", "run_point", "run_sections", "run_sweep", "runner", "spec",
    "table", "write_table",
]
