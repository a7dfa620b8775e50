"""Per-step cost of the chain-in-heart simulation: MagneticWrenchSystem vs the plant, and the
real-time factor of each mode (16 balls by default).

Prints medians over repeats: the wrench system's output calculation alone, and a whole diagram
step (plant, wrench, monitor-free) measured in the same run; their ratio is the wrench's share.
(Freezing the forces is no baseline: the chain then flies apart and the plant gets cheaper.)
"""

import argparse
import json
import time

import numpy as np


def _median_time(fn, repeats: int) -> float:
    samples = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t)
    return float(np.median(samples))


def run(*, scenario: str = "heart_left_quasi_static", n_steps: int = 200, repeats: int = 3) -> dict:
    """Measure one scenario in both modes; returns a dict of timings (seconds, medians)."""
    from pydrake.systems.analysis import Simulator

    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation

    out = {"scenario": scenario}
    for mode in ("quasi-static", "dynamics"):
        sc = load_scenario(scenario, f"{{mode: {mode}}}")
        cd = MakeStation(sc)
        sim = Simulator(cd.diagram)
        sim.Initialize()
        root = sim.get_mutable_context()
        wrench_ctx = cd.chain.wrench.GetMyContextFromRoot(root)
        port = cd.chain.wrench.get_spatial_forces_output_port()
        value = port.Allocate()
        wrench_s = _median_time(lambda: [cd.chain.wrench._calc_spatial_forces(wrench_ctx, value) for _ in range(100)],
                                repeats) / 100
        dt = sc.effective_time_step

        def advance():
            sim.AdvanceTo(root.get_time() + n_steps * dt)

        full_s = _median_time(advance, repeats) / n_steps
        out[mode] = {
            "time_step_s": dt,
            "wrench_us_per_step": round(wrench_s * 1e6, 1),
            "plant_and_rest_us_per_step": round((full_s - wrench_s) * 1e6, 1),
            "wrench_share": round(wrench_s / full_s, 3),
            "full_us_per_step": round(full_s * 1e6, 1),
            "realtime_factor": round(dt / full_s, 3),
        }
    return out


def main() -> None:
    from threadpoolctl import threadpool_limits

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--scenario", default="heart_left_quasi_static", help="scenario name")
    parser.add_argument("--steps", type=int, default=200, help="steps per timing sample")
    parser.add_argument("--repeats", type=int, default=3, help="timing samples (median)")
    args = parser.parse_args()
    with threadpool_limits(limits=1, user_api="blas"):  # as the CLI does
        result = run(scenario=args.scenario, n_steps=args.steps, repeats=args.repeats)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
