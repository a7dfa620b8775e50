"""Simulate the ball chain in the left atrium (or free space) for a named scenario.

Prints realtime_factor, sim_time_s, tip_position_mm, min_wall_clearance_mm, max_neighbor_gap_um,
max_penetration_um, targets_touched (the ablation targets the tip ball touched, e.g. "left_3") and
peak_memory_MB (the process's peak resident set size); stops with a clear message (exit status 1)
on a NaN, a ball escaping the heart or the chain breaking apart.
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
    result = run_simulation(scenario=chosen, duration=duration, html=html)
    result["statics_tip_error_mm"] = statics_tip_error_mm(chosen, result)
    return result


def statics_tip_error_mm(scenario, result: dict) -> float | None:
    """Distance [mm] from the simulated tip to the statics equilibrium, for scenarios that settle
    on the canonical problem (free space, no sheath, ball 1 fixed at the origin, a uniform field,
    optionally a flat wall); None for the others (heart, magnets, units, moving feeder)."""
    import numpy as np

    from ballchain.drake_models.params import BallChain, Sleeve
    from ballchain.optimization.statics import uniform_field_equilibrium

    canonical = (not scenario.heart and not scenario.sheath and not scenario.magnets and not scenario.units
                 and scenario.insertion.initial == 0.0 and scenario.insertion.final == 0.0)
    if not canonical:
        return None
    chain = BallChain(n_balls=scenario.n_balls, sleeve=Sleeve() if scenario.sleeve else None)
    wall = None
    if scenario.wall_plane:
        wall = (np.array(scenario.wall_plane[:3]), np.array(scenario.wall_plane[3:]))
    statics = uniform_field_equilibrium(chain, scenario.uniform_field, scenario.gravity, wall)
    return float(np.linalg.norm(np.array(result["p_W_mm"][-1]) - statics.tip_position * 1e3))


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
