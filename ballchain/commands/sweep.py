"""Run a sweep spec on Dask: every point a task, one table of results (Parquet and CSV).

By default on a LocalCluster of worker processes, one per core (nothing to start); on an
existing cluster with ``--scheduler tcp://host:8786`` (``dask scheduler`` and ``dask worker
tcp://host:8786`` on the machines); on a job queue with ``--jobqueue slurm`` (needs dask-jobqueue,
configured by its own file); serially in this process with ``--workers 0``. The shipped studies:
``ballchain sweep design|operators|operators_reduced|sleeve`` (``ballchain/studies/*.yaml``), or
any spec file (a bare study name is always the shipped study, even beside a folder or file of
that name: write ``./design`` for a local one). Every point is checked with its command's own
rules, and the points are counted (``--max-points``, default 5000) before any cluster starts;
the count and an estimate of the time are printed first (on stderr). Rerunning with the same
``--out`` skips the points already done; Ctrl-C keeps what finished.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ballchain.commands._common import add_json_flag, non_negative_int, path_arg, positive_int, print_json
from ballchain.drake_models.errors import UserInputError, short_repr
from ballchain.sweep import DEFAULT_MAX_POINTS, MAX_JOBS, MAX_WORKERS_PER_CORE

STUDIES = Path(__file__).resolve().parents[1] / "studies"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("spec", help="a sweep spec (YAML file) or the name of a shipped study: "
                                     + ", ".join(shipped_studies()) + " (./NAME for a local file of that name)")
    parser.add_argument("--out", type=path_arg, required=True, help="results folder (table.parquet, table.csv, figure)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="an existing Dask scheduler, e.g. tcp://host:8786 (default: a LocalCluster here)")
    parser.add_argument("--workers", type=non_negative_int, default=None,
                        help=f"LocalCluster worker processes (default: one per core; at most "
                             f"{MAX_WORKERS_PER_CORE} per core), or job-queue jobs (at most {MAX_JOBS}); "
                             "0 runs serially in this process")
    parser.add_argument("--max-points", type=positive_int, default=DEFAULT_MAX_POINTS,
                        help=f"refuse a spec of more runs (points x seeds) than this (default {DEFAULT_MAX_POINTS})")
    parser.add_argument("--jobqueue", default=None, metavar="KIND",
                        help="a dask-jobqueue cluster: slurm, pbs, sge, lsf, htcondor, moab, oar (optional dependency) "
                             "(default: none, the workers run here)")
    parser.add_argument("--no-figure", action="store_true", help="do not draw the study's figure")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_json_flag(parser)


def shipped_studies() -> list[str]:
    return sorted(p.stem for p in STUDIES.glob("*.yaml"))


def resolve_spec(spec: str) -> Path:
    """A shipped study's file when ``spec`` is its bare name (a folder or file of that name here
    does not shadow it: ``./design`` names those), else ``spec`` as a path."""
    if spec in shipped_studies():
        return STUDIES / f"{spec}.yaml"
    path = Path(spec)
    if not path.exists() and path.name == spec and not path.suffix:  # a bare name, neither study nor file
        raise UserInputError(f"sweep spec {short_repr(spec)} is neither a file nor a shipped study "
                             f"({', '.join(shipped_studies())})")
    return path


def main(args: argparse.Namespace) -> int:
    import sys

    from ballchain import sweep

    # Every check (spec, flags, output folder) runs before a cluster starts.
    spec = sweep.load_spec(resolve_spec(args.spec), max_points=args.max_points)
    data = sweep.run_sweep(spec, args.out, scheduler=args.scheduler, workers=args.workers, jobqueue=args.jobqueue,
                           progress=not args.no_progress, figure=not args.no_figure,
                           echo=lambda line: print(line, file=sys.stderr, flush=True))
    if args.json:
        print_json(data)
    else:
        print(f"{data['experiment']}: {data['points']} points, {data['ran']} run, {data['skipped']} skipped "
              f"(done before), {data['failed']} failed, {data['resubmitted']} resubmitted; "
              f"{data['wall_time_s']:.1f} s on {data['executor']}")
        print(f"table: {data['table_parquet']} and {data['table_csv']}")
        if data["figure"]:
            print(f"figure: {data['figure']}")
    if data["interrupted"]:
        print("interrupted: the table holds the points that finished; rerun with the same --out to go on")
        return 130
    return 0
