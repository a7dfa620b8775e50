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

from ballchain.commands._common import add_json_flag, float_in, print_json
from ballchain.drake_models.errors import UserInputError


MAX_DURATION = 3600.0  # [s] simulated (the scenario's cap, systems/chain_scenario.py)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", required=True,
                        help="scenario name in drake_models/station.scenarios.yaml (or 'list')")
    parser.add_argument("--duration", type=float_in(0.0, MAX_DURATION, lo_open=True), default=None,
                        help=f"simulated time in seconds, (0, {MAX_DURATION:g}] (default: the scenario's)")
    parser.add_argument("--mode", choices=("quasi-static", "dynamics"), default=None,
                        help="quasi-static (damped, 1e-3 s steps) or true dynamics (1e-4 s steps)")
    parser.add_argument("--set", dest="overrides", default=None, metavar="YAML",
                        help="inline YAML overriding scenario fields, e.g. '{n_balls: 10}'")
    parser.add_argument("--html", type=Path, default=None,
                        help="write a self-contained Meshcat recording (HTML) to this file")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    add_json_flag(parser)


def run(*, scenario: str, duration: float | None = None, mode: str | None = None,
        overrides: str | None = None, html: Path | None = None, progress: bool = False) -> dict:
    """Load the scenario, apply the overrides and the mode, simulate; returns the metrics.

    Raises:
        UserInputError: a bad scenario, override, mode, duration or output path (before any work).
    """
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import run_simulation

    from ballchain.drake_models.safe_files import check_output_file
    from ballchain.systems.chain_scenario import check_duration

    if html is not None:  # before the run: an unwritable path must not cost the results
        check_output_file(html, "--html")
    chosen = load_scenario(scenario, overrides)
    if mode is not None:
        if mode not in ("quasi-static", "dynamics"):
            raise UserInputError(f"--mode must be 'quasi-static' or 'dynamics', got {mode!r}")
        chosen.mode = mode
        chosen.validate()
    if duration is not None:
        check_duration(duration, chosen.effective_time_step, "--duration")
    result = run_simulation(scenario=chosen, duration=duration, html=html, progress=progress)
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
        if args.json:
            print_json({"scenarios": scenario_names()})
        else:
            print("\n".join(scenario_names()))
        return 0
    try:
        result = run(scenario=args.scenario, duration=args.duration, mode=args.mode,
                     overrides=args.overrides, html=args.html, progress=not args.no_progress)
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
