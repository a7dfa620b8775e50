"""Run a sweep spec on Dask: every point a task, one table of results (Parquet and CSV).

By default on a LocalCluster of worker processes, one per core (nothing to start); on an
existing cluster with ``--scheduler tcp://host:8786`` (``dask scheduler`` and ``dask worker
tcp://host:8786`` on the machines); on a job queue with ``--jobqueue slurm`` (needs dask-jobqueue,
configured by its own file); serially in this process with ``--workers 0``. The shipped studies:
``ballchain sweep design|operators|operators_reduced|sleeve`` (``ballchain/studies/*.yaml``), or
any spec file. Rerunning with the same ``--out`` skips the points already done; Ctrl-C keeps what
finished.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ballchain.commands._common import add_json_flag, non_negative_int, print_json

STUDIES = Path(__file__).resolve().parents[1] / "studies"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("spec", help="a sweep spec (YAML file) or the name of a shipped study: "
                                     + ", ".join(sorted(p.stem for p in STUDIES.glob("*.yaml"))))
    parser.add_argument("--out", type=Path, required=True, help="results folder (table.parquet, table.csv, figure)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="an existing Dask scheduler, e.g. tcp://host:8786 (default: a LocalCluster here)")
    parser.add_argument("--workers", type=non_negative_int, default=None,
                        help="LocalCluster worker processes (default: one per core), or job-queue jobs; "
                             "0 runs serially in this process")
    parser.add_argument("--jobqueue", default=None, metavar="KIND",
                        help="a dask-jobqueue cluster: slurm, pbs, sge, lsf, htcondor, moab, oar (optional dependency)")
    parser.add_argument("--no-figure", action="store_true", help="do not draw the study's figure")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_json_flag(parser)


def resolve_spec(spec: str) -> Path:
    """A spec file, or a shipped study's by name."""
    path = Path(spec)
    if not path.exists() and (STUDIES / f"{spec}.yaml").exists():
        return STUDIES / f"{spec}.yaml"
    return path


def main(args: argparse.Namespace) -> int:
    from ballchain import sweep

    # Every check (spec, flags, output folder) runs before a cluster starts.
    spec = sweep.load_spec(resolve_spec(args.spec))
    data = sweep.run_sweep(spec, args.out, scheduler=args.scheduler, workers=args.workers, jobqueue=args.jobqueue,
                           progress=not args.no_progress, figure=not args.no_figure)
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
