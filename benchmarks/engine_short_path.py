"""The engine's update with the compiled solve's short path (``compiled_model.HeartSolve``) against
the same update through ``ChainStatics.solve``, in one run: the recorded 1 kHz teleoperation path
of ``ballchain bench engine`` replayed through two engines, interleaved, the short path declined in
one of them. Prints the update's median and p99 (CPU time) for each, their ratio, how many solves
the short path answered, and whether the two engines' states were identical at every update
(they must be: the short path gives the kernel the same inputs).

    python benchmarks/engine_short_path.py --scenario teleop_right_unit
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def run(scenario: str = "teleop_right_unit", path_s: float = 0.7, rate_hz: float = 1000.0) -> dict:
    from ballchain.experiments import engine_bench as eb
    from ballchain.optimization import compiled_model as cm
    from ballchain.optimization.blas_threads import one_blas_thread

    engine, points, _ = eb.record_path(scenario, path_s, rate_hz)
    now = time.process_time
    solve = cm.HeartSolve.solve
    counts = [0, 0]

    def counting(self, *args, **kwargs):
        answer = solve(self, *args, **kwargs)
        counts[answer is None] += 1
        return answer

    def declining(self, *args, **kwargs):
        return None

    identical = True
    with one_blas_thread():
        cm.HeartSolve.solve = counting
        short = eb._Replay(engine, True, points[0], now)
        cm.HeartSolve.solve = declining
        full = eb._Replay(engine, True, points[0], now)
        try:
            for i, point in enumerate(points[1:]):
                order = ((short, counting), (full, declining))
                for replay, method in order if i % 2 == 0 else order[::-1]:
                    cm.HeartSolve.solve = method
                    replay.update(point, now)
                identical &= bool(np.array_equal(short.engine.state_vector(short.context),
                                                 full.engine.state_vector(full.context)))
        finally:
            cm.HeartSolve.solve = solve

    def q(times):
        t = np.asarray(times) * 1e3
        return {"median_ms": round(float(np.median(t)), 4), "p99_ms": round(float(np.percentile(t, 99)), 4)}

    a, b = q(short.times), q(full.times)
    return {"scenario": scenario, "updates": len(points) - 1, "short_path": a, "chain_statics_solve": b,
            "speedup_median": round(b["median_ms"] / a["median_ms"], 3), "speedup_p99": round(b["p99_ms"] / a["p99_ms"], 3),
            "short_path_answered": counts[0], "declined": counts[1], "states_identical": identical}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="teleop_right_unit")
    parser.add_argument("--path-s", type=float, default=0.7)
    parser.add_argument("--rate-hz", type=float, default=1000.0)
    args = parser.parse_args()
    print(json.dumps(run(args.scenario, args.path_s, args.rate_hz), indent=1))


if __name__ == "__main__":
    main()
