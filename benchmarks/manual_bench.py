"""Before/after in one run for the robotic-vs-manual comparison: this checkout against an earlier
commit, in alternating processes (``ab_compare``'s machinery: the earlier commit exported with
``git archive`` and imported as ``ballchain``; every timer in the children is CPU time).

Each child runs, after an untimed 0.2 s warm-up of each (imports, compiled kernels), the manual
catheter (``manual_catheter.run``) and the robotic chain (``teleop.run``, world mapping,
quasi-static engine) on ``--task`` for the first ``--targets`` targets with operator ``--seed``
(for ``--time-limit`` simulated seconds, or until the targets are done),
and reports each run's process CPU time and its results (the operator's rows and the logged tip
path). Prints JSON: the median CPU seconds per side and device, their ratio (base / head), and
whether the results are bit-identical between the sides.

    python benchmarks/manual_bench.py --base HEAD~1 --targets 6 --rounds 2
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ab_compare import REPO, _child  # noqa: E402

_CODE = r"""
import json, sys, time
from ballchain.experiments import manual_catheter as mc, teleop
from ballchain.systems.station import atrium_for
task, targets, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
limit = None if sys.argv[4] == "none" else float(sys.argv[4])
heart = atrium_for(mc.scenario_for())


def run(device, targets, limit):
    if device == "robotic":
        return teleop.run(task=task, mapping="world", targets=targets, progress=False, heart=heart, seed=seed,
                          log_path=True, time_limit=limit)
    return mc.run(task=task, targets=targets, seed=seed, heart=heart, time_limit=limit)


run("manual", 1, 0.2)  # warm-up: imports, compiled kernels
run("robotic", 1, 0.2)
out = {"file": mc.__file__}
for device in ("manual", "robotic"):
    cpu = time.process_time()
    r = run(device, targets, limit)
    out[device] = {"cpu_s": time.process_time() - cpu, "rows": r.rows,
                   "path": {k: v for k, v in r.settings.get("path", {}).items()}}
print(json.dumps(out))
"""


def run(base: str, task: str = "left", targets: int = 6, seed: int = 0, rounds: int = 2,
        time_limit: float | None = None, together: bool = False) -> dict:
    import subprocess

    sides = {"base": [], "head": []}
    with tempfile.TemporaryDirectory(prefix="ballchain-ab-") as tmp:
        archive = subprocess.run(["git", "-C", str(REPO), "archive", base], capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        args = [task, str(targets), str(seed), "none" if time_limit is None else str(time_limit)]
        for _ in range(rounds):
            if together:  # both sides at once, in two processes: the same load on both
                from concurrent.futures import ThreadPoolExecutor

                with ThreadPoolExecutor(2) as pool:
                    pair = [pool.submit(_child, root, _CODE, args) for root in (Path(tmp), None)]
                    sides["base"].append(pair[0].result())
                    sides["head"].append(pair[1].result())
                continue
            sides["base"].append(_child(Path(tmp), _CODE, args))
            sides["head"].append(_child(None, _CODE, args))
    out = {"base": base, "task": task, "targets": targets, "seed": seed, "time_limit_s": time_limit,
           "rounds": rounds, "clock": "cpu"}
    for device in ("manual", "robotic"):
        cpu = {k: float(np.median([r[device]["cpu_s"] for r in v])) for k, v in sides.items()}
        b, h = sides["base"][0][device], sides["head"][0][device]
        out[device] = {"cpu_s": cpu, "speedup": cpu["base"] / cpu["head"],
                       "identical": b["rows"] == h["rows"] and b["path"] == h["path"],
                       "touched": sum(r["touched"] for r in h["rows"])}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--base", required=True, help="the earlier commit (any git revision)")
    parser.add_argument("--task", default="left", help="left or right")
    parser.add_argument("--targets", type=int, default=6, help="the first N targets of the task")
    parser.add_argument("--seed", type=int, default=0, help="the operator's seed")
    parser.add_argument("--rounds", type=int, default=2, help="runs of each side, alternating")
    parser.add_argument("--time-limit", type=float, default=None, help="simulated seconds of each run (default: "
                        "until the targets are done)")
    parser.add_argument("--together", action="store_true", help="run the two sides of a round at once (two "
                        "processes) instead of one after the other")
    a = parser.parse_args()
    print(json.dumps(run(a.base, a.task, a.targets, a.seed, a.rounds, a.time_limit, a.together), indent=1))


if __name__ == "__main__":
    main()
