"""Sensitivity of the manual arm to its unsourced constants: the manual right ring (the hardest
task, where the catheter's reach matters) with one constant changed at a time from the built
value, the operator's seeds 0, 1, 2 (``docs/guide/manual_catheter.md``, "The hand's rates" and
"The D-F curve").

The hand's rates change through ``HandParams`` (``hand=``), the D-F curve through
``SteerableCatheter``'s fields (``catheter=``: the deflectable segment's length, the full-knob
bends; F keeps its 120/180 ratio to D, and the hand's ``f_over_d`` follows the catheter's), both
through ``manual_catheter.run``'s public arguments; no constant is edited. Optionally
``--reach`` runs ``reach_search`` (120 rod solves each) for the targets out of the built
catheter's reach, from the built catheter's closest grid points (``reach_map``, mapped once), on
each curve variant. Prints one JSON line per run (touched, total time, the run's process CPU time)
and per variant's search.

    python benchmarks/manual_sweep.py --variants curve [--seeds 0 1 2] [--reach]
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace

import numpy as np

# The hand's rates: halved and doubled (twist: 60 and 120 deg/s) from HandParams' defaults.
RATES = {"push 10 mm/s": {"push_speed": 0.01}, "push 40 mm/s": {"push_speed": 0.04},
         "twist 60 deg/s": {"twist_rate": np.radians(60.0)}, "twist 120 deg/s": {"twist_rate": np.radians(120.0)},
         "knob 0.5 /s": {"knob_rate": 0.5}, "knob 2 /s": {"knob_rate": 2.0}}
F_OVER_D = 120.0 / 180.0  # the built curve's ratio, kept when D changes
CURVE = {"segment 45 mm": {"deflectable_length": 45e-3}, "segment 65 mm": {"deflectable_length": 65e-3},
         "D 160 deg": {"max_deflection_D": np.radians(160.0), "max_deflection_F": np.radians(160.0 * F_OVER_D)},
         "D 200 deg": {"max_deflection_D": np.radians(200.0), "max_deflection_F": np.radians(200.0 * F_OVER_D)}}
UNREACHED = ("right_14", "right_15", "right_16")  # out of the built catheter's reach (reach_search)


def variant(name: str):
    """(hand overrides, catheter overrides) of a named variant ("as built": none)."""
    if name == "as built":
        return {}, {}
    if name in RATES:
        return RATES[name], {}
    return {}, CURVE[name]


def run_variant(name: str, seeds, heart) -> list[dict]:
    """The manual right ring for each seed with the variant; one row per seed."""
    from ballchain.experiments import manual_catheter as mc
    from ballchain.systems.catheter_station import HandParams

    hand_over, cat_over = variant(name)
    cat = replace(mc.comparison_catheter(), **cat_over).validate()
    hand = replace(HandParams(f_over_d=cat.max_deflection_F / cat.max_deflection_D), **hand_over).validate()
    rows = []
    for seed in seeds:
        cpu = time.process_time()
        result = mc.run(task="right", seed=seed, heart=heart, hand=hand, catheter=cat)
        rows.append({"variant": name, "seed": seed, "touched": result.summary.touched,
                     "total_s": round(result.summary.total_time_s, 2),
                     "touched_targets": [r["target"] for r in result.rows if r["touched"]],
                     "cpu_s": round(time.process_time() - cpu, 1)})
    return rows


def reach_variant(name: str, heart, grid: list[dict]) -> dict:
    """``reach_search`` on the built catheter's unreached targets with the variant's catheter,
    from the built catheter's grid points (``grid``)."""
    from ballchain.experiments import manual_catheter as mc

    cat = replace(mc.comparison_catheter(), **variant(name)[1]).validate()
    cpu = time.process_time()
    found = mc.reach_search(grid, "right", only=[r["target"] for r in grid], heart=heart, catheter=cat)
    return {"variant": name, "reach": [{k: r[k] for k in ("target", "reachable", "closest_mm", "at")} for r in found],
            "cpu_s": round(time.process_time() - cpu, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--variants", nargs="+", default=["curve"],
                        help="'rates', 'curve', 'as built' or variant names: " + ", ".join([*RATES, *CURVE]))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--reach", action="store_true", help="reach_search for the unreached targets instead")
    args = parser.parse_args()
    names = []
    for v in args.variants:
        names += list(RATES) if v == "rates" else list(CURVE) if v == "curve" else [v]
    from ballchain.experiments import manual_catheter as mc
    from ballchain.systems.station import atrium_for

    heart = atrium_for(mc.scenario_for())
    start = time.process_time()
    if args.reach:
        cpu = time.process_time()
        grid = [r for r in mc.reach_map("right", heart=heart) if r["target"] in UNREACHED]
        print(json.dumps({"grid": grid, "cpu_s": round(time.process_time() - cpu, 1)}), flush=True)
        for name in names:
            print(json.dumps(reach_variant(name, heart, grid)), flush=True)
    else:
        for name in names:
            for row in run_variant(name, args.seeds, heart):
                print(json.dumps(row), flush=True)
    print(json.dumps({"sweep_cpu_s": round(time.process_time() - start, 1)}), flush=True)


if __name__ == "__main__":
    main()
