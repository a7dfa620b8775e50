"""Environment steps per CPU-second of ``ballchain.rl`` (issue 47; docs/guide/rl.md, "Speed").

One step is one control period (50 ms of simulated time at the default 20 Hz): the quasi-static
engine's equilibrium with the atrium's wall (the walk of ``engine_system`` when the magnet moved
far), the unit's wheel drive and Hall estimator (5 ms updates), the feeder, the localisation
sensor, the watchdog, and the observation and reward. Measured, in one process unless stated,
each ``--repeats`` times after an untimed warm-up, medians printed:

* ``bare``: the same station advanced by a ``StationRunner`` one control period at a time with
  the same actions, no Gymnasium around it: the same-run baseline of the environment's overhead;
* ``single``: ``NavigationEnv.step`` with a policy (the CEM baseline if its weights are shipped,
  else random actions held for 10 steps);
* ``sync``: ``gymnasium.vector.SyncVectorEnv`` of ``--envs`` environments (steps counted per
  environment);
* ``async``: ``AsyncVectorEnv`` of ``--envs`` (the workers' CPU time read with psutil);
* ``dask``: ``ballchain.rl.evaluate`` on a LocalCluster of ``--workers`` (the episodes' own CPU
  time, in the workers);
* ``reset_ms`` (restart of the cached diagram) against ``build_s`` (a new station);
* the profile: where a step's time goes (cProfile of the single environment, grouped).

CPU time is process time (the machine is shared: wall time counts the waits).

    python benchmarks/rl_bench.py --steps 400 --repeats 3 --json /tmp/rl_bench.json
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import time
from pathlib import Path

import numpy as np

from ballchain.infrastructure.safe_files import atomic_write_text, check_output_file


def _policy(env):
    from ballchain.rl.baseline import LinearPolicy

    weights = Path(__file__).resolve().parents[1] / "ballchain" / "rl" / "baseline_weights.json"
    if weights.exists():
        return LinearPolicy.for_env(env, json.loads(weights.read_text())["theta"]), "CEM baseline"
    rng = np.random.default_rng(0)
    held = {"a": None, "k": 0}

    def random_policy(obs):
        if held["k"] % 10 == 0:
            held["a"] = env.action_space.high * rng.uniform(-1, 1, env.action_space.shape)
        held["k"] += 1
        return held["a"]

    return random_policy, "random, held 10 steps"


def _run_single(env, policy, steps: int, seed: int, record: list | None = None) -> tuple[int, float, float]:
    obs, _ = env.reset(seed=seed)
    c0, w0, n = time.process_time(), time.perf_counter(), 0
    episode = 0
    while n < steps:
        action = policy(obs)
        if record is not None:
            record.append((episode, action))
        obs, _, terminated, truncated, _ = env.step(action)
        n += 1
        if terminated or truncated:
            episode += 1
            obs, _ = env.reset(seed=seed + episode)
    return n, time.process_time() - c0, time.perf_counter() - w0


def _run_bare(env, actions: list, seed: int) -> tuple[int, float, float]:
    """The same station and actions through the StationRunner alone (no observation, reward)."""
    env.reset(seed=seed)
    runner, c0, w0 = env.runner, time.process_time(), time.perf_counter()
    t, last = runner.context.get_time(), 0
    for episode, action in actions:
        if episode != last:
            env.reset(seed=seed + episode)
            t, last = runner.context.get_time(), episode
        for stick, axes in zip(env._sticks, env.sticks(action)):
            stick.GetMutableData().get_mutable_value().SetFromVector(axes)
        env._feed.GetMutableData().get_mutable_value().SetFromVector(np.asarray(action[-1:], float))
        t += env.period
        runner.advance_to(t)
    return len(actions), time.process_time() - c0, time.perf_counter() - w0


def _children_cpu() -> float:
    import psutil

    total = 0.0
    for child in psutil.Process().children(recursive=True):
        try:
            c = child.cpu_times()
            total += c.user + c.system
        except psutil.Error:
            pass
    return total


def _run_vector(kind: str, n_envs: int, steps: int, seed: int, policy_for) -> tuple[int, float, float]:
    from ballchain.rl import make_vector_env

    venv = make_vector_env(n_envs, kind)
    obs, _ = venv.reset(seed=[seed + i for i in range(n_envs)])
    probe = venv.envs[0] if kind == "sync" else None
    policy = policy_for(probe)
    c0, k0, w0 = time.process_time(), _children_cpu(), time.perf_counter()
    for _ in range(steps):
        actions = np.stack([policy(o) for o in obs])
        obs, *_ = venv.step(actions)  # autoreset: a finished episode restarts at the next step
    cpu = time.process_time() - c0 + _children_cpu() - k0
    wall = time.perf_counter() - w0
    venv.close()
    return steps * n_envs, cpu, wall


def _profile(env, policy, steps: int, seed: int) -> dict:
    """Where the time of ``steps`` single-environment steps goes: the cumulative time of the entry
    points (cProfile; their fractions of the whole loop, the profiler's own overhead included)."""
    prof = cProfile.Profile()
    prof.enable()
    _run_single(env, policy, steps, seed)
    prof.disable()
    stats = pstats.Stats(prof).stats

    def cum(file_part: str, name: str) -> float:
        return sum(v[3] for (path, _, fn), v in stats.items() if file_part in path and fn == name)

    total = cum("rl_bench", "_run_single")
    step, advance = cum("rl/env", "step"), cum("chain_simulation", "advance_to")
    parts = {"engine: equilibria with the wall (engine_system._update)": cum("engine_system", "_update"),
             "actuation unit: drive, Hall sensor, estimator (5 ms updates)": cum("actuation_unit", "_update"),
             "watchdog (ChainMonitor)": cum("chain_monitor", "__call__"),
             "localisation sensor": cum("localisation_sensor", "_update"),
             "feeder and target tracker": cum("feeder", "_update") + cum("target_contact", "_update"),
             "observation and reward (step minus the simulation)": step - advance,
             "policy": cum("rl/baseline", "__call__"), "reset (restart, first period)": cum("rl/env", "reset")}
    parts["Drake Simulator and the systems' outputs (the rest of the simulation)"] = advance - sum(
        v for k, v in parts.items() if k.split(":")[0] in ("engine", "actuation unit") or k.startswith(
            ("watchdog", "localisation", "feeder")))
    return {k: round(v / total, 3) for k, v in sorted(parts.items(), key=lambda kv: -kv[1])}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=400, help="steps per measurement (per environment)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--envs", type=int, default=2, help="environments of the vector runs")
    parser.add_argument("--workers", type=int, default=2, help="Dask LocalCluster workers (0: skip Dask)")
    parser.add_argument("--episodes", type=int, default=8, help="Dask episodes")
    parser.add_argument("--skip-async", action="store_true")
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    args = parser.parse_args(argv)
    if args.json:  # the output checked before the minutes of measuring
        check_output_file(args.json, "--json")

    from ballchain.rl import NavigationEnv, evaluate

    t0 = time.perf_counter()
    env = NavigationEnv()
    build_s = time.perf_counter() - t0
    policy, policy_name = _policy(env)
    _run_single(env, policy, 20, 999)  # warm-up
    rows: dict[str, list] = {"bare": [], "single": [], "sync": [], "async": [], "dask": []}
    for r in range(args.repeats):
        actions: list = []
        n, cpu, wall = _run_single(env, policy, args.steps, 10 * r, record=actions)
        rows["single"].append((n / cpu, n / wall))
        n, cpu, wall = _run_bare(env, actions, 10 * r)
        rows["bare"].append((n / cpu, n / wall))
        n, cpu, wall = _run_vector("sync", args.envs, args.steps // args.envs, 10 * r,
                                   lambda e: _policy(e)[0] if e is not None else policy)
        rows["sync"].append((n / cpu, n / wall))
        if not args.skip_async:
            n, cpu, wall = _run_vector("async", args.envs, args.steps // args.envs, 10 * r, lambda e: policy)
            rows["async"].append((n / cpu, n / wall))
        print(f"repeat {r + 1}: " + ", ".join(f"{k} {v[-1][0]:.0f}" for k, v in rows.items() if v), flush=True)
    resets = []
    for k in range(20):
        w = time.perf_counter()
        env.reset(seed=k)
        resets.append(time.perf_counter() - w)
    if args.workers:
        from ballchain.executor import Executor

        with Executor(workers=args.workers) as ex:
            res = evaluate(policy, args.episodes, ex, seed=500)
        rows["dask"].append((res.summary["steps_per_cpu_s"], res.summary["steps"] / res.summary["wall_s"]))
    profile = _profile(env, policy, min(args.steps, 200), 77)
    table = {k: {"steps_per_cpu_s": round(float(np.median([v[0] for v in vals])), 1),
                 "steps_per_wall_s": round(float(np.median([v[1] for v in vals])), 1), "runs": len(vals)}
             for k, vals in rows.items() if vals}
    out = {"policy": policy_name, "control_rate_hz": 1.0 / env.period, "steps": args.steps, "envs": args.envs,
           "workers": args.workers, "table": table,
           "env_over_bare_cpu": round(table["single"]["steps_per_cpu_s"] / table["bare"]["steps_per_cpu_s"], 3),
           "reset_ms_median": round(1e3 * float(np.median(resets)), 2), "build_s": round(build_s, 2),
           "profile_fraction": profile}
    print(json.dumps(out, indent=1))
    if args.json is not None:
        atomic_write_text(args.json, json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
