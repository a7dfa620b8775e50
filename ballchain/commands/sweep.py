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
``--out`` skips the points already done; Ctrl-C keeps what finished. An ``--out`` whose table
holds another spec's rows is refused unless ``--append``; one holding the spec file itself
(``sweep.json``, a JSON spec) is refused.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ballchain.commands._common import add_json_flag, non_negative_int, path_arg, positive_int, print_json
from ballchain.infrastructure.errors import UserInputError, short_repr
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
    parser.add_argument("--append", action="store_true",
                        help="add this spec's rows to a table in --out that holds another spec's rows (refused "
                             "without it); the table's spec column then names each row's spec")
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
    # a bare name, neither study nor file (os.path.exists: False for a name too long, which load_spec names)
    if not os.path.exists(spec) and path.name == spec and not path.suffix:
        raise UserInputError(f"sweep spec {short_repr(spec)} is neither a file nor a shipped study "
                             f"({', '.join(shipped_studies())})")
    return path


def main(args: argparse.Namespace) -> int:
    import sys

    from ballchain import sweep

    # Every check (spec, flags, output folder) runs before a cluster starts.
    spec = sweep.load_spec(resolve_spec(args.spec), max_points=args.max_points)
    data = sweep.run_sweep(spec, args.out, scheduler=args.scheduler, workers=args.workers, jobqueue=args.jobqueue,
                           progress=not args.no_progress, figure=not args.no_figure, append=args.append,
                           echo=lambda line: print(line, file=sys.stderr, flush=True))
    if args.json:
        print_json(data)
    else:
        print(f"{data['experiment']}: {data['points']} points, {data['ran']} run, {data['skipped']} skipped "
              f"(done before), {data['failed']} failed, {data['resubmitted']} resubmitted; "
              f"{data['wall_time_s']:.1f} s on {data['executor']}")
        print_result_table(spec, sweep.read_table(args.out))
        print(f"table: {data['table_parquet']} and {data['table_csv']}")
        if data["figure"]:
            print(f"figure: {data['figure']}")
        elif data.get("figure_note"):
            print(data["figure_note"])
    if data["interrupted"]:
        print("interrupted: the table holds the points that finished; rerun with the same --out to go on")
        return 130
    return 0


SHOWN_ROWS = 12  # rows of the table printed after a sweep (all of them are in table.csv)
SHOWN_OUTPUTS = 5  # output columns printed


def result_table(spec, rows: list[dict]) -> list[str]:
    """A short, headed table of a sweep's rows: the grid fields that vary, the seed if there are
    several, and the experiment's headline outputs (``Experiment.shown``; else its first scalar
    outputs); at most ``SHOWN_ROWS`` rows."""
    import dataclasses

    from ballchain import sweep
    from ballchain.experiments.studies import EXPERIMENTS

    params = [f.name for f in dataclasses.fields(type(spec.points[0]))] if spec.points else []
    varied = [p for p in params if len({repr(r.get(p)) for r in rows}) > 1]
    if len({r.get("seed") for r in rows}) > 1:
        varied.append("seed")
    skip = set(params) | set(sweep.META_COLUMNS) | set(sweep.TAIL_COLUMNS) | {"seed"}
    outputs = []
    for r in rows:
        outputs += [k for k, v in r.items() if k not in skip and k not in outputs
                    and (v is None or isinstance(v, (int, float, bool, str)))]
    shown = [c for c in EXPERIMENTS[spec.experiment].shown if c in outputs] or outputs[:SHOWN_OUTPUTS]
    columns = varied + shown + ["error"]

    def cell(value) -> str:
        if value is None:
            return "-"
        if isinstance(value, float):
            return f"{value:.4g}"
        text = str(value)
        return text if len(text) <= 24 else text[:21] + "..."

    table = [[cell(r.get(c)) for c in columns] for r in rows[:SHOWN_ROWS]]
    widths = [max([len(c)] + [len(t[i]) for t in table]) for i, c in enumerate(columns)]
    lines = ["  ".join(c.rjust(w) for c, w in zip(columns, widths)),
             "  ".join("-" * w for w in widths)]
    lines += ["  ".join(t.rjust(w) for t, w in zip(row, widths)) for row in table]
    if len(rows) > SHOWN_ROWS:
        lines.append(f"... {len(rows) - SHOWN_ROWS} more rows in table.csv")
    return lines


def print_result_table(spec, rows: list[dict]) -> None:
    if rows:
        print("\n".join(result_table(spec, rows)))
