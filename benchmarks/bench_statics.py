"""Statics benchmark: ChainStatics (Newton, SNOPT; cold and warm) against the naive SLSQP baseline.

A thin script over ``ballchain.experiments.statics_bench`` (the one implementation, also run as
``ballchain bench statics``); it takes the same flags and prints JSON: median wall times [ms],
the speedup of the Newton solve over the baseline measured in the same run, iterations, and the
differences of every solver's minimum from the Newton cold solve.
"""

from __future__ import annotations

import sys

from ballchain.experiments.statics_bench import StaticsBenchResult, run_statics


def run(*, n_balls: int = 16, repeats: int = 5, progress: bool = True, **options) -> StaticsBenchResult:
    """The benchmark's result; ``options`` are ``run_statics``'s other keywords."""
    return run_statics(n_balls=n_balls, repeats=repeats, progress=progress, **options)


def main() -> None:
    from ballchain.cli import main as cli_main

    sys.exit(cli_main(["bench", "statics", "--json", "--compile-cost", *sys.argv[1:]]))


if __name__ == "__main__":
    main()
