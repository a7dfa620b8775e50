"""Simulate the ball chain in the left atrium (or free space) for a named scenario.

Prints realtime_factor, sim_time_s, tip_position_mm, min_wall_clearance_mm, max_neighbor_gap_um
and max_penetration_um; stops with a clear message (exit status 1) on a NaN, a ball escaping
the heart or the chain breaking apart.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ballchain.commands._common import add_json_flag, finite_float, print_json


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", required=True,
                        help="scenario name in drake_models/station.scenarios.yaml (or 'list')")
    parser.add_argument("--duration", type=finite_float, default=None,
                        help="simulated time in seconds (default: the scenario's)")
    parser.add_argument("--mode", choices=("quasi-static", "dynamics"), default=None,
                        help="quasi-static (damped, 1e-3 s steps) or true dynamics (1e-4 s steps)")
    parser.add_argument("--set", dest="overrides", default=None, metavar="YAML",
                        help="inline YAML overriding scenario fields, e.g. '{n_balls: 10}'")
    parser.add_argument("--html", type=Path, default=None,
                        help="write a self-contained Meshcat recording (HTML) to this file")
    add_json_flag(parser)


def run(*, scenario: str, duration: float | None = None, mode: str | None = None,
        overrides: str | None = None, html: Path | None = None) -> dict:
    """Load the scenario, apply the overrides and the mode, simulate; returns the metrics."""
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import run_simulation

    chosen = load_scenario(scenario, overrides)
    if mode is not None:
        chosen.mode = mode
        chosen.validate()
    if duration is not None and duration < 0:
        raise ValueError(f"--duration must be >= 0, got {duration}")
    return run_simulation(scenario=chosen, duration=duration, html=html)


def main(args: argparse.Namespace) -> int:
    from ballchain.systems.chain_scenario import scenario_names
    from ballchain.systems.chain_simulation import SimulationFailure

    if args.scenario == "list":
        print("\n".join(scenario_names()))
        return 0
    try:
        result = run(scenario=args.scenario, duration=args.duration, mode=args.mode,
                     overrides=args.overrides, html=args.html)
    except SimulationFailure as failure:
        print(f"ballchain simulate: {failure}", file=sys.stderr)
        if args.json:
            print_json({**failure.metrics, "failure": str(failure)})
        return 1
    if args.json:
        result = {k: v for k, v in result.items() if k != "p_W_mm"}
        print_json(result)
    else:
        for key, value in result.items():
            if key != "p_W_mm":
                print(f"{key}: {value}")
    return 0
