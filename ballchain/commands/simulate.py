"""Simulate the ball chain in the left atrium (or free space) for a named scenario.

Prints realtime_factor, sim_time_s, tip_position_mm, min_wall_clearance_mm, max_neighbor_gap_um,
max_penetration_um, targets_touched (the ablation targets the tip ball touched, e.g. "left_3") and
peak_memory_MB (the process's peak resident set size); stops with a clear message (exit status 1)
on a NaN, a ball escaping the heart or the chain breaking apart. The experiment is
``ballchain.experiments.simulation``. ``--scenario list`` prints the scenarios with their engine,
mode and description; ``--engine`` and ``--mode`` set the scenario fields of the same names.
``--anatomy FILE`` runs the scenario on an anatomy file (``drake_models/anatomy.py``) instead of
the procedural atrium, its units standing at the file's magnets.
"""

from __future__ import annotations

import argparse
import sys

from ballchain.commands._common import YamlOnce, add_json_flag, float_in, path_arg, print_json
from ballchain.infrastructure.safe_files import to_jsonable
from ballchain.experiments.simulation import run
from ballchain.systems.chain_scenario import ENGINES, MAX_DURATION, MODES  # MAX_DURATION [s]: the scenario's cap


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", required=True,
                        help="scenario name in drake_models/station.scenarios.yaml; 'list' prints each name with "
                             "its engine, mode and description")
    parser.add_argument("--duration", type=float_in(0.0, MAX_DURATION, lo_open=True), default=None,
                        help=f"simulated time in seconds, (0, {MAX_DURATION:g}] (default: the scenario's)")
    parser.add_argument("--mode", choices=MODES, default=None,
                        help="quasi-static (damped, 1e-3 s steps) or true dynamics (1e-4 s steps) (default: the "
                             "scenario's mode)")
    parser.add_argument("--engine", choices=ENGINES, default=None,
                        help="the scenario's engine field: plant (the MultibodyPlant with contact, the reference) or "
                             "statics (the chain's equilibrium solved every statics_period, quasi-static mode only, "
                             "much faster) (default: the scenario's engine, plant unless it says otherwise)")
    parser.add_argument("--set", dest="overrides", default=None, metavar="YAML", action=YamlOnce,
                        help="inline YAML overriding scenario fields, e.g. '{n_balls: 10}'; a mapping changes only the "
                             "fields it names; a list of mappings (units, magnets, joystick) is the new list, each "
                             "entry updating the scenario's entry of the same unit name or position "
                             "('{units: [{teleop_omega_max: 1.0}]}' keeps the unit's placement; '{units: []}' "
                             "removes them)")
    parser.add_argument("--html", type=path_arg, default=None,
                        help="write a self-contained Meshcat recording (HTML) to this file")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    parser.add_argument("--anatomy", type=path_arg, default=None, metavar="FILE",
                        help="an anatomy file (YAML: mesh, length_unit, side, targets, sheath, magnets) to run the "
                             "scenario on; the units stand at its magnets, in order")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    from ballchain.systems.chain_simulation import SimulationFailure

    if args.scenario == "list":
        return _list_scenarios(args.json)
    try:
        result = run(scenario=args.scenario, duration=args.duration, mode=args.mode, engine=args.engine,
                     overrides=args.overrides, html=args.html, progress=not args.no_progress,
                     anatomy=args.anatomy)
    except SimulationFailure as failure:
        print(f"ballchain simulate: {failure}", file=sys.stderr)
        if args.json:
            print_json({**to_jsonable(failure.metrics or {}), "failure": str(failure)})
        return 1
    if args.json:
        print_json(result.public())
    else:
        for key, value in result.public().items():
            print(f"{key}: {value}")
    return 0


def _list_scenarios(as_json: bool) -> int:
    """``--scenario list``: each scenario's name, engine, mode and description."""
    from ballchain.systems.chain_scenario import load_scenario, scenario_descriptions

    rows = []
    for name, description in scenario_descriptions().items():
        scenario = load_scenario(name)
        rows.append({"name": name, "engine": scenario.engine, "mode": scenario.mode, "description": description})
    if as_json:
        print_json({"scenarios": [r["name"] for r in rows], "details": rows})
        return 0
    width = max(len(r["name"]) for r in rows)
    kinds = [f"{r['engine']}, {r['mode']}" for r in rows]
    kind_width = max(map(len, kinds))
    print(f"{'scenario':<{width}}  {'engine, mode':<{kind_width}}  description")
    for r, kind in zip(rows, kinds):
        print(f"{r['name']:<{width}}  {kind:<{kind_width}}  {r['description']}")
    print("\nrun one: ballchain simulate --scenario NAME [--engine plant|statics] [--set YAML]")
    return 0
