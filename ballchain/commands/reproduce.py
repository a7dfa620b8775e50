"""``ballchain reproduce``: a thin adapter of ``ballchain.reproduce.run`` (the main job; its
docstring says what is written and how an interrupted run resumes)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ballchain.commands._common import add_json_flag, path_arg, positive_int, print_json
from ballchain.reproduce import AGREES_WITHIN, run
from ballchain.executor import MAX_WORKERS_PER_CORE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=path_arg, default=Path("results"), help="output folder")
    parser.add_argument("--quick", action="store_true", help="short versions of every experiment")
    parser.add_argument("--resume", action="store_true",
                        help="reuse the sections an interrupted run of the same code finished (checked by "
                             "a hash of the section's inputs and the code, and of its files)")
    parser.add_argument("--sections", nargs="+", default=None, metavar="NAME",
                        help="run only these sections (names as in the report's run-time table, e.g. "
                             "alignment sizing) (default: all)")
    parser.add_argument("--workers", type=positive_int, default=1,
                        help="run the sections in parallel on this many worker processes (a Dask "
                             f"LocalCluster on this machine, at most {MAX_WORKERS_PER_CORE} per core; default 1: one after the other, "
                             "in this process)")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    data = run(out=args.out, quick=args.quick, resume=args.resume, sections=args.sections, workers=args.workers)
    if args.json:
        print_json(data)
    else:
        reused = f" (reused {len(data['reused'])} finished sections)" if data["reused"] else ""
        print(f"wrote {data['report_md']} and {data['report_html']} in {data['total_seconds']:.1f} s{reused}")
        if data["headlines"]:
            print(f"what it found, paper vs model (agrees: within {100 * AGREES_WITHIN:g} %, or for a closed-loop "
                  "row the paper's number inside the 95 % interval over the seeds; the report's summary says more):")
            print("\n".join(f"  {line}" for line in data["headlines"]))
        print(f"open {data['report_html']}")
    return 0
