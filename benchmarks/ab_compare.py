"""Before/after in one run: this checkout against an earlier commit, in alternating processes.

The earlier commit (``--base``, e.g. the branch point) is exported with ``git archive`` into a
temporary folder and imported as ``ballchain`` in its own processes (a meta-path finder maps the
sub-packages as ``pyproject.toml`` does); the two sides run in turns, ``--rounds`` times each,
so that the load of the machine hits both alike. The measurements:

* ``station``: ``run_simulation`` of a named scenario for ``--duration`` simulated seconds,
  after an untimed two-step run in the same process: real-time factor (median over rounds) and
  the final ball positions, whose largest difference between the two sides says whether the
  results are the same.
* ``profile``: ``benchmarks/station_profile.py`` of each side (its own copy) on the scenario:
  exclusive microseconds per step per group of systems (wrench, actuation, monitor, C++ plant);
  with ``--set``, the scenario with those overrides and each actuation system a group of its
  own (``--by-system``).
* ``statics``: ``ballchain bench statics`` (16 balls by default): Newton cold and warm medians.
* ``pin``: the force-sensor pin (``forces_dynamics``) on the RSPV optimum of magnet 1 (16 bare
  balls, a 4 x 5 grid and 5 refinements): the settling run from the loaded statics
  (``pin_force_from_statics``) once, whose result (all but its wall time) must be the same on
  both sides, and ``--repeats`` timed runs of ``--duration`` simulated seconds that never settle
  (``rel_tol`` 0): the median time of build plus run.
* ``task``: a whole teleoperation task (``teleop.run``, ``--task``, world mapping, seed 0: Task
  II is "right") after an untimed one-target run in the same process: its CPU and wall time
  (both clocks are read, whatever ``--clock``), the simulated time and the task's summary,
  which must be the same on both sides (the times of the operator's targets are simulated).
* ``seeds``: the acceptance test of a change to the solver's iterates (docs/performance.md 18):
  every task of ``--task`` ("left,right": Tasks I and II) on every operator seed of ``--seeds``
  (default 0-23), world mapping, one child per side running at once (each after an untimed
  one-target run of each task): the targets touched, the
  targets only one side touched with a two-sided sign test on them (a seed's misses come in runs,
  so they are not independent and the test overstates the evidence either way), the seeds where
  one side touched fewer, and CPU time per simulated second. The operator's closed loop amplifies any
  change of an equilibrium (1e-7 m moves its next look), so one seed's run is a sample, not a
  verdict.

Times are the children's CPU time by default (``--clock cpu``: ``time.perf_counter`` is
replaced by ``time.process_time`` in them, so a real-time factor is simulated time over CPU
time): on a machine shared with other jobs, wall time mostly measures the others. Prints JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

# The package layout of pyproject.toml's [tool.setuptools] package-dir.
_BOOTSTRAP = r"""
import importlib.machinery, importlib.util, os, sys
ROOT = os.environ["AB_ROOT"]
DIRS = {"ballchain": "ballchain", "ballchain.commands": "ballchain/commands",
        "ballchain.experiments": "ballchain/experiments", "ballchain.drake_models": "drake_models",
        "ballchain.optimization": "optimization", "ballchain.systems": "systems"}
class _Finder:
    @classmethod
    def find_spec(cls, name, path=None, target=None):
        if name in DIRS:
            folder = os.path.join(ROOT, DIRS[name])
            return importlib.util.spec_from_file_location(
                name, os.path.join(folder, "__init__.py"), submodule_search_locations=[folder])
        parent, _, leaf = name.rpartition(".")
        if parent in DIRS:
            return importlib.machinery.PathFinder.find_spec(name, [os.path.join(ROOT, DIRS[parent])])
        return None
sys.meta_path.insert(0, _Finder)
"""

_STATION = r"""
import json, sys
from threadpoolctl import threadpool_limits
from ballchain.systems.chain_scenario import load_scenario
from ballchain.systems.chain_simulation import run_simulation
import ballchain
scenario = load_scenario(sys.argv[1], sys.argv[3] if len(sys.argv) > 3 else None)
with threadpool_limits(limits=1, user_api="blas"):
    # A short untimed run first: first-call costs (imports, loading compiled kernels) are not
    # the plant's speed.
    run_simulation(scenario=scenario, duration=2 * scenario.effective_time_step)
    r = run_simulation(scenario=scenario, duration=float(sys.argv[2]))
# Either side's code: SimulationMetrics (attributes) now, a dict before.
get = r.get if isinstance(r, dict) else lambda key: getattr(r, key)
keys = ("realtime_factor", "p_W_mm", "min_wall_clearance_mm", "max_penetration_um", "tip_wall_force_N")
print(json.dumps({"file": ballchain.__file__, **{key: get(key) for key in keys}}))
"""

_PROFILE = r"""
import importlib.util, json, os, sys
from threadpoolctl import threadpool_limits
import ballchain
root = os.environ.get("AB_ROOT") or sys.argv[3]
spec = importlib.util.spec_from_file_location("station_profile", os.path.join(root, "benchmarks", "station_profile.py"))
profile = importlib.util.module_from_spec(spec)
spec.loader.exec_module(profile)
with threadpool_limits(limits=1, user_api="blas"):
    options = dict(overrides=sys.argv[4] or None, by_system=True) if len(sys.argv) > 4 else {}
    profile.run(scenario=sys.argv[1], duration=0.01, top=1, **options)  # first-call costs
    r = profile.run(scenario=sys.argv[1], duration=float(sys.argv[2]), top=1, **options)
print(json.dumps({"file": ballchain.__file__, "realtime_factor": r["realtime_factor"],
                  "us_per_step": r["us_per_step"], "derivative_evaluations": r["derivative_evaluations"],
                  "n_steps": r["n_steps"]}))
"""

_STATICS = r"""
import json, sys
from threadpoolctl import threadpool_limits
try:
    from ballchain.experiments.statics_bench import run_statics
except ImportError:  # commits before the benchmark moved out of the CLI layer
    from ballchain.commands.bench import run_statics
import ballchain
with threadpool_limits(limits=1, user_api="blas"):
    r = run_statics(n_balls=int(sys.argv[1]), repeats=int(sys.argv[2]), progress=False)
r = r.to_dict() if hasattr(r, "to_dict") else r  # a StaticsBenchResult; a dict in older commits
print(json.dumps({"file": ballchain.__file__, "cold_median_ms": r["cold_median_ms"],
                  "warm_median_ms": r["warm_median_ms"], "baseline_median_ms": r["baseline_median_ms"],
                  "energy_J": r["energy_J"], "tip_position_mm": list(r["tip_position_mm"])}))
"""


_PIN = r"""
import json, sys, time
import numpy as np
from threadpoolctl import threadpool_limits
from ballchain.drake_models.params import BallChain
from ballchain.experiments import forces
from ballchain.experiments.forces_dynamics import PinSimulationConfig, pin_force_from_statics, simulate_pin_force
import ballchain
with threadpool_limits(limits=1, user_api="blas"):
    stand, chain = forces.build_stand(), BallChain(n_balls=16)
    best = forces.max_normal_force(chain, stand, "RSPV", ("1",), grid=4, refine_evaluations=5)
    target, axis = stand.targets["RSPV"]
    external = forces.stand_field(stand, ("1",), best["angles_rad"])
    settled = pin_force_from_statics(chain, external, target, axis, best["result"]).to_dict()
    settled.pop("wall_time_s")
    config = PinSimulationConfig(max_time=float(sys.argv[1]), rel_tol=0.0)
    times = []
    for _ in range(int(sys.argv[2])):
        t = time.perf_counter()
        long = simulate_pin_force(chain, external, target, axis, best["result"], config)
        times.append(time.perf_counter() - t)
print(json.dumps({"file": ballchain.__file__, "settled": settled, "median_s": float(np.median(times)),
                  "steps": long.steps, "reason": long.reason}))
"""


_TASK = r"""
import json, sys, time
from threadpoolctl import threadpool_limits
from ballchain.experiments import teleop
import ballchain
wall, cpu = getattr(time, "_wall_clock", time.perf_counter), time.process_time  # both clocks
with threadpool_limits(limits=1, user_api="blas"):
    teleop.run(task=sys.argv[1], mapping="world", targets=1, progress=False)  # first-call costs
    w, c = wall(), cpu()
    r = teleop.run(task=sys.argv[1], mapping="world", progress=False)
    w, c = wall() - w, cpu() - c
summary = r.summary.to_dict() if hasattr(r.summary, "to_dict") else dict(vars(r.summary))
print(json.dumps({"file": ballchain.__file__, "wall_s": w, "cpu_s": c, "summary": summary,
                  "rows": [{k: row[k] for k in ("target", "touched", "time_s")} for row in r.rows]},
                 default=float))
"""


_SEEDS = r"""
import json, sys, time
from threadpoolctl import threadpool_limits
from ballchain.drake_models.heart import LeftAtrium
from ballchain.experiments import teleop
import ballchain
runs = []
with threadpool_limits(limits=1, user_api="blas"):
    heart = LeftAtrium()
    for task in sys.argv[1].split(","):  # first-call costs (loading or compiling the kernels)
        teleop.run(task=task, mapping="world", targets=1, progress=False, heart=heart)
    for task in sys.argv[1].split(","):
        for seed in [int(x) for x in sys.argv[2].split(",")]:
            c = time.process_time()
            r = teleop.run(task=task, mapping="world", seed=seed, progress=False, heart=heart)
            runs.append({"task": task, "seed": seed, "touched": r.summary.touched, "targets": r.summary.targets,
                         "missed": list(r.summary.missed), "sim_s": r.summary.sim_time_s,
                         "cpu_s": time.process_time() - c, "failure": r.summary.failure})
            print(f"{'base' if 'AB_ROOT' in __import__('os').environ else 'head'}: {task} seed {seed}: "
                  f"{r.summary.touched}/{r.summary.targets}", file=sys.stderr, flush=True)  # progress
print(json.dumps({"file": ballchain.__file__, "runs": runs}))
"""


_CPU_CLOCK = r"""
import time
time._wall_clock = time.perf_counter  # the real one, for a child that reads both (task)
time.perf_counter = time.process_time  # every timer in the child counts this process's CPU time
"""


def _child(root: Path | None, code: str, args: list[str], clock: str = "cpu", progress: bool = False) -> dict:
    """Run ``code`` in a fresh interpreter (the base commit's package when ``root`` is given);
    its last stdout line as JSON. ``progress``: the child's stderr goes to ours as it runs."""
    env = dict(os.environ)
    if clock == "cpu":
        code = _CPU_CLOCK + code
    if root is not None:
        env["AB_ROOT"] = str(root)
        code = _BOOTSTRAP + code
    proc = subprocess.run([sys.executable, "-c", code, *args], env=env, stdout=subprocess.PIPE,
                          stderr=None if progress else subprocess.PIPE, text=True, timeout=1800)
    if proc.returncode != 0:
        why = "see its output above" if progress else proc.stderr[-3000:]
        raise RuntimeError(f"child failed ({'base' if root else 'head'}):\n{why}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run(*, base: str, what: str = "station", scenario: str = "heart_left_quasi_static", duration: float = 0.1,
        overrides: str | None = None, rounds: int = 3, n_balls: int = 16, repeats: int = 7,
        clock: str = "cpu", task: str = "right", seeds: list[int] | None = None) -> dict:
    """Alternate ``rounds`` runs of the base commit and of this checkout; returns medians and diffs.

    ``clock="cpu"`` makes every timer of the children (``time.perf_counter``) count the process's
    CPU time: on a machine shared with other jobs, wall time mostly measures the others.
    """
    with tempfile.TemporaryDirectory(prefix="ballchain-ab-") as tmp:
        archive = subprocess.run(["git", "-C", str(REPO), "archive", base], capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        if what == "station":
            code, args = _STATION, [scenario, str(duration)] + ([overrides] if overrides else [])
        elif what == "profile":
            code, args = _PROFILE, [scenario, str(duration), str(REPO)] + ([overrides] if overrides else [])
        elif what == "pin":
            code, args = _PIN, [str(duration), str(repeats)]
        elif what == "task":
            code, args = _TASK, [task]
        else:
            code, args = _STATICS, [str(n_balls), str(repeats)]
        if what == "seeds":  # one long child per side, both at once (CPU time is per process)
            return _seeds(base, task, seeds, tmp, clock)
        sides = {"base": [], "head": []}
        for _ in range(rounds):
            sides["base"].append(_child(Path(tmp), code, args, clock))
            sides["head"].append(_child(None, code, args, clock))
    out = {"base": base, "what": what, "rounds": rounds, "clock": clock,
           "files": {k: v[0]["file"] for k, v in sides.items()}}
    if what == "profile":
        out.update(scenario=scenario, duration_s=duration,
                   realtime_factor={k: [r["realtime_factor"] for r in v] for k, v in sides.items()},
                   derivative_evaluations={k: v[0]["derivative_evaluations"] for k, v in sides.items()},
                   n_steps={k: v[0]["n_steps"] for k, v in sides.items()},
                   us_per_step={k: {g: float(np.median([r["us_per_step"][g] for r in v]))
                                    for g in v[0]["us_per_step"]} for k, v in sides.items()})
    elif what == "station":
        rtf = {k: [r["realtime_factor"] for r in v] for k, v in sides.items()}
        out.update(scenario=scenario, overrides=overrides, duration_s=duration, realtime_factor=rtf,
                   median_rtf={k: float(np.median(v)) for k, v in rtf.items()})
        out["speedup"] = out["median_rtf"]["head"] / out["median_rtf"]["base"]
        p_base = np.array(sides["base"][0]["p_W_mm"])
        p_head = np.array(sides["head"][0]["p_W_mm"])
        out["max_position_diff_mm"] = float(np.abs(p_base - p_head).max())
        out["repeatable"] = {k: float(max(np.abs(np.array(r["p_W_mm"]) - np.array(v[0]["p_W_mm"])).max()
                                          for r in v)) for k, v in sides.items()}
        for key in ("min_wall_clearance_mm", "max_penetration_um", "tip_wall_force_N"):
            out[key] = {k: v[0][key] for k, v in sides.items()}
    elif what == "pin":
        out.update(duration_s=duration, repeats=repeats,
                   median_s={k: float(np.median([r["median_s"] for r in v])) for k, v in sides.items()},
                   steps={k: v[0]["steps"] for k, v in sides.items()},
                   settled_identical=sides["base"][0]["settled"] == sides["head"][0]["settled"],
                   settled={k: {f: v[0]["settled"][f] for f in ("force_N", "steps", "sim_time_s", "settled", "reason")}
                            for k, v in sides.items()})
        out["speedup"] = out["median_s"]["base"] / out["median_s"]["head"]
    elif what == "task":
        out.update(task=task, **{key: {k: [r[key] for r in v] for k, v in sides.items()} for key in ("wall_s", "cpu_s")})
        out["median_wall_s"] = {k: float(np.median(v)) for k, v in out["wall_s"].items()}
        out["median_cpu_s"] = {k: float(np.median(v)) for k, v in out["cpu_s"].items()}
        out["speedup_wall"] = out["median_wall_s"]["base"] / out["median_wall_s"]["head"]
        out["summary"] = {k: v[0]["summary"] for k, v in sides.items()}
        out["rows_identical"] = sides["base"][0]["rows"] == sides["head"][0]["rows"]
    else:
        for key in ("cold_median_ms", "warm_median_ms", "baseline_median_ms"):
            out[key] = {k: float(np.median([r[key] for r in v])) for k, v in sides.items()}
        out["speedup_cold"] = out["cold_median_ms"]["base"] / out["cold_median_ms"]["head"]
        out["speedup_warm"] = out["warm_median_ms"]["base"] / out["warm_median_ms"]["head"]
        out["energy_J"] = {k: v[0]["energy_J"] for k, v in sides.items()}
        out["tip_diff_mm"] = float(np.linalg.norm(np.subtract(sides["base"][0]["tip_position_mm"],
                                                              sides["head"][0]["tip_position_mm"])))
    return out


def _seeds(base: str, tasks: str, seeds: list[int], tmp: str, clock: str) -> dict:
    """``--what seeds``: every task on every operator seed with each side's code; the touched
    targets, the targets only one side touched (the paired comparison of a closed loop that
    amplifies any change of the iterates), and CPU time per simulated second."""
    from concurrent.futures import ThreadPoolExecutor

    args = [tasks, ",".join(str(s) for s in seeds)]
    with ThreadPoolExecutor(2) as pool:
        futures = {"base": pool.submit(_child, Path(tmp), _SEEDS, args, clock, True),
                   "head": pool.submit(_child, None, _SEEDS, args, clock, True)}
        sides = {k: {(r["task"], r["seed"]): r for r in f.result()["runs"]} for k, f in futures.items()}
    out = {"base": base, "what": "seeds", "seeds": seeds, "clock": clock, "tasks": {}}
    for task in tasks.split(","):
        keys = [(task, s) for s in seeds]
        b, h = ([sides[k][key] for key in keys] for k in ("base", "head"))
        only_base = sum(len(set(y["missed"]) - set(x["missed"])) for x, y in zip(b, h))
        only_head = sum(len(set(x["missed"]) - set(y["missed"])) for x, y in zip(b, h))
        out["tasks"][task] = {
            "targets": sum(r["targets"] for r in b),
            "touched": {"base": sum(r["touched"] for r in b), "head": sum(r["touched"] for r in h)},
            "touched_only_by": {"base": only_base, "head": only_head},
            "sign_test_p": _sign_test(only_base, only_head),
            "seeds_head_worse": sum(y["touched"] < x["touched"] for x, y in zip(b, h)),
            "seeds_head_better": sum(y["touched"] > x["touched"] for x, y in zip(b, h)),
            "cpu_ms_per_sim_s": {k: 1e3 * sum(r["cpu_s"] for r in v) / sum(r["sim_s"] for r in v)
                                 for k, v in (("base", b), ("head", h))},
            "median_cpu_s": {k: float(np.median([r["cpu_s"] for r in v])) for k, v in (("base", b), ("head", h))},
            "failures": {k: [r["seed"] for r in v if r["failure"]] for k, v in (("base", b), ("head", h))},
            "per_seed": {k: [{f: r[f] for f in ("seed", "touched", "sim_s", "cpu_s")} for r in v]
                         for k, v in (("base", b), ("head", h))},
        }
    return out


def _sign_test(a: int, b: int) -> float:
    """Two-sided exact sign test of a against b successes (binomial, p = 1/2)."""
    n = a + b
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, k) for k in range(min(a, b) + 1)) / 2.0**n
    return min(1.0, 2.0 * tail)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--base", required=True, help="the earlier commit (any git revision)")
    parser.add_argument("--what", choices=("station", "profile", "statics", "pin", "task", "seeds"), default="station",
                        help="what to compare")
    parser.add_argument("--scenario", default="heart_left_quasi_static", help="station: scenario name")
    parser.add_argument("--set", dest="overrides", default=None, help="station, profile: inline YAML overrides")
    parser.add_argument("--duration", type=float, default=0.1, help="station, pin: simulated time [s]")
    parser.add_argument("--rounds", type=int, default=3, help="runs of each side, alternating")
    parser.add_argument("--balls", type=int, default=16, help="statics: number of balls")
    parser.add_argument("--repeats", type=int, default=7,
                        help="statics: timed solves per case; pin: timed runs per round")
    parser.add_argument("--task", default="right",
                        help='task: "left" (Task I) or "right" (Task II); seeds: a comma-separated list')
    parser.add_argument("--seeds", default="0-23", help='seeds: the operator seeds, "a-b" or a comma-separated list')
    parser.add_argument("--clock", choices=("cpu", "wall"), default="cpu",
                        help="what the children's timers count (default cpu: the process's CPU time)")
    args = parser.parse_args()
    try:
        seeds = _seed_list(args.seeds)
    except ValueError as err:
        parser.error(f"--seeds: {err}")
    if args.what == "seeds" and not set(args.task.split(",")) <= {"left", "right"}:
        parser.error(f'--task: {args.task!r} is not a comma-separated list of "left" and "right"')
    print(json.dumps(run(base=args.base, what=args.what, scenario=args.scenario, duration=args.duration,
                         overrides=args.overrides, rounds=args.rounds, n_balls=args.balls,
                         repeats=args.repeats, clock=args.clock, task=args.task,
                         seeds=seeds), indent=1))


def _seed_list(text: str) -> list[int]:
    """``"0-23"`` or ``"0,3,5"`` as a list of seeds (each 0 .. 2**32 - 1, at least one); a
    ValueError saying what is allowed otherwise."""
    allowed = f'seeds are "a-b" (a <= b) or a comma-separated list of integers 0 .. 2**32 - 1, got {text!r}'
    try:
        if "-" in text:
            a, b = (int(x) for x in text.split("-"))
            seeds = list(range(a, b + 1)) if 0 <= a <= b <= 2**32 - 1 else []
        else:
            seeds = [int(x) for x in text.split(",")]
    except ValueError:
        raise ValueError(allowed) from None
    if not seeds or min(seeds) < 0 or max(seeds) > 2**32 - 1:
        raise ValueError(allowed)
    return seeds


if __name__ == "__main__":
    main()
