"""The trials study (issue 43): closed-loop arms over many seeds on Dask, each row with its 95 % interval.

Runs seeds x arms (``experiments/trials.py``: the teleoperation tasks with the robotic chain,
the manual catheter, the ablation procedure's navigator and operator on a ring) through the
project's Dask executor: a LocalCluster by default, an existing cluster with
``--scheduler-address tcp://host:8786``, this process with ``--workers 0``. Each finished run is written to
``OUT/runs/`` at once; rerunning with the same ``--out`` skips them. Prints per arm the median of
the targets touched and of the total time with its 95 % bootstrap interval beside the paper's
number, and the paired comparisons; ``--json`` the whole result. ``OUT/table.parquet``,
``OUT/table.csv`` hold every run, ``OUT/trials.json`` the intervals.
"""

from __future__ import annotations

import argparse

from ballchain.commands._common import add_json_flag, non_negative_int, path_arg, positive_int, print_json
from ballchain.executor import MAX_WORKERS_PER_CORE
from ballchain.experiments import trials

SHOWN_FAILURES = 5  # failed runs named after the intervals (all of them are in the table)

def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=path_arg, required=True, metavar="DIR",
                        help="results folder (runs/, table.parquet, table.csv, trials.json); rerun into it to resume")
    parser.add_argument("--seeds", type=positive_int, default=trials.DEFAULT_SEEDS,
                        help="seeds 0..N-1, the same for every arm (paired comparisons)")
    parser.add_argument("--arms", nargs="+", choices=tuple(trials.ARMS), default=list(trials.ARMS), metavar="ARM",
                        help="the arms: " + ", ".join(trials.ARMS) + " (default: all)")
    parser.add_argument("--targets", type=positive_int, default=None,
                        help="only the first N targets of each task or ring (default: whole tasks; the paper's "
                             "numbers are compared only then)")
    parser.add_argument("--world", choices=trials.WORLDS, default="none",
                        help="the procedure arms' world: none (the model's own numbers) or literature (perturbed at "
                             "published magnitudes, drawn from each seed; docs/guide/world.md)")
    parser.add_argument("--workers", type=non_negative_int, default=None,
                        help=f"LocalCluster worker processes (default: one per core; at most {MAX_WORKERS_PER_CORE} "
                             "per core); 0 runs serially in this process")
    parser.add_argument("--scheduler-address", dest="scheduler", default=None, metavar="ADDRESS",
                        help="an existing Dask scheduler, e.g. tcp://host:8786 (default: a LocalCluster here)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    result = trials.run(args.arms, range(args.seeds), targets=args.targets, world=args.world, out=args.out,
                        workers=args.workers, scheduler=args.scheduler, progress=not args.no_progress)
    if args.json:
        print_json(result)
        return 0
    st = result.settings
    print(f"trials: {len(st['arms'])} arm(s) x {len(st['seeds'])} seed(s): {st['ran']} run, {st['skipped']} done "
          f"before, {st['failed']} failed; {st['wall_time_s']:.1f} s on {st['executor']}")
    for line in lines(result.intervals):
        print(line)
    failed = [r for r in result.rows if r.get("error")]
    for r in failed[:SHOWN_FAILURES]:
        print(f"  failed: {r['arm']} seed {r['seed']}: {r['error'][:200]}")
    if len(failed) > SHOWN_FAILURES:
        print(f"  ... {len(failed) - SHOWN_FAILURES} more failed runs in the table (rerun into --out to retry them)")
    print(f"table: {result.files['table_parquet']} and {result.files['table_csv']}; intervals: {result.files['json']}")
    return 0


def lines(intervals: list[dict]) -> list[str]:
    """One line per interval: the row, "median [95 % CI lo, hi] (n seeds)", the paper's number and the verdict."""
    from ballchain.intervals import Interval

    fields = set(Interval.__dataclass_fields__)
    out = []
    width = max((len(x["row"]) for x in intervals), default=0)
    for x in intervals:
        iv = Interval(**{k: v for k, v in x.items() if k in fields})
        paper = "-" if x.get("paper") is None else f"{x['paper']:g}"
        verdict = {True: "agrees", False: "disagrees", None: "-"}[x.get("verdict")]
        out.append(f"  {x['row']:<{width}}  {iv.text('{:.3g}')}  paper {paper}  {verdict}")
    return out
