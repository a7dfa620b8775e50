"""Many environments at once: Gymnasium's vector environments (``make_vector_env``) and rollouts
of many episodes on the project's Dask executor (``evaluate``; ``ballchain.executor.Executor``:
a LocalCluster, a job queue or a scheduler by address).

A policy is any picklable callable ``policy(obs) -> action`` (a numpy array of the action
space's shape), e.g. ``baseline.LinearPolicy``; on Dask each task builds one environment (its
station, about 2 s) and runs a chunk of the episodes, so a chunk should hold several episodes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from ballchain.experiments._result import Result
from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.rl.env import NavigationEnv

VECTOR_KINDS = ("sync", "async")


def make_vector_env(n: int, kind: str = "sync", **env_kwargs):
    """``n`` environments (``NavigationEnv(**env_kwargs)``) as a Gymnasium ``SyncVectorEnv`` (one
    process) or ``AsyncVectorEnv`` (one worker process each)."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise UserInputError(f"make_vector_env n must be a positive integer, got {short_repr(n)}")
    if kind not in VECTOR_KINDS:
        raise UserInputError(f"make_vector_env kind must be one of {VECTOR_KINDS}, got {short_repr(kind)}")
    fns = [lambda: NavigationEnv(**env_kwargs) for _ in range(n)]
    if kind == "sync":
        return gym.vector.SyncVectorEnv(fns)
    return gym.vector.AsyncVectorEnv(fns, shared_memory=False)


def _path_ratio(tips: list) -> float | None:
    """The true tip's path length over its net displacement (1: straight; None: it did not move)."""
    p = np.asarray(tips)
    net = np.linalg.norm(p[-1] - p[0])
    return None if len(p) < 2 or net < 1e-6 else float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)) / net)


def run_episode(env: NavigationEnv, policy, seed: int, target: str | None = None) -> dict:
    """One episode of ``policy`` on ``env`` from ``reset(seed=seed)``: its record."""
    options = None if target is None else {"target": target}
    obs, info = env.reset(seed=seed, options=options)
    start = info["target"]
    cpu, ret, steps, done = time.process_time(), 0.0, 0, False
    tips, actions, forces = [env.tip_true()], [], []
    while not done:
        action = np.asarray(policy(obs), np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        ret += reward
        steps += 1
        actions.append(action / env.action_space.high)
        if info["failure"] is None:
            tips.append(env.tip_true())
        forces.append(info["tip_force_gf"])
        done = terminated or truncated
    a = np.asarray(actions)
    return {"seed": int(seed), "target": start, "success": bool(info["success"]), "steps": steps,
            "time_s": round(info["time_s"], 3), "return": round(ret, 3), "failure": info["failure"],
            "targets_done": info["targets_done"], "final_distance_mm": round(info["distance_mm"], 3),
            "force_normal_gf": round(info["force_normal_gf"], 2) if info["success"] else None,
            "max_tip_force_gf": round(max(forces), 2), "path_ratio": _path_ratio(tips),
            "action_change_rms": float(np.sqrt(np.mean(np.sum(np.diff(a, axis=0) ** 2, axis=1)))) if len(a) > 1 else 0.0,
            "cpu_s": round(time.process_time() - cpu, 3)}


def rollout(policy, env_kwargs: dict, episodes: list) -> list[dict]:
    """Run ``episodes`` ([(seed, target or None)]) of ``policy`` on one ``NavigationEnv(**env_kwargs)``
    (built here: a Dask task's body)."""
    env = NavigationEnv(**env_kwargs)
    return [run_episode(env, policy, seed, target) for seed, target in episodes]


@dataclass
class EvaluationResult(Result):
    """What ``evaluate`` returns.

    Attributes:
        episodes: one record per episode (``run_episode``: seed, target, success, steps, time_s,
            return, failure, final_distance_mm, force_normal_gf, max_tip_force_gf, path_ratio,
            action_change_rms, cpu_s).
        summary: {episodes, success_rate, median_time_s (successes), mean_return, failures,
            steps, cpu_s (the episodes' own), wall_s, steps_per_cpu_s, executor}.
    """

    episodes: list
    summary: dict


def _summary(episodes: list, wall: float, executor: str) -> dict:
    ok = [e for e in episodes if e["success"]]
    steps, cpu = sum(e["steps"] for e in episodes), sum(e["cpu_s"] for e in episodes)
    return {"episodes": len(episodes), "success_rate": round(len(ok) / max(len(episodes), 1), 4),
            "median_time_s": float(np.median([e["time_s"] for e in ok])) if ok else None,
            "mean_return": round(float(np.mean([e["return"] for e in episodes])), 3) if episodes else None,
            "failures": sum(e["failure"] is not None for e in episodes), "steps": steps, "cpu_s": round(cpu, 2),
            "wall_s": round(wall, 2), "steps_per_cpu_s": round(steps / cpu, 1) if cpu > 0 else None,
            "executor": executor}


def evaluate(policy, n_episodes: int, executor=None, *, env_kwargs: dict | None = None, seed: int = 0,
             targets: list | None = None, chunk: int | None = None) -> EvaluationResult:
    """Roll out ``policy`` for ``n_episodes`` episodes, serially or on a Dask executor.

    Args:
        policy: a picklable ``policy(obs) -> action``.
        n_episodes: how many episodes; episode i starts from ``reset(seed=seed + i)``.
        executor: None (this process), an entered ``ballchain.executor.Executor`` or a
            ``distributed.Client``: chunks of episodes as tasks, one environment per task.
        env_kwargs: ``NavigationEnv``'s arguments.
        targets: None (reach: the target drawn from the seed), or the targets of the episodes
            in turn (cycled).
        chunk: episodes per task (default: spread evenly over the workers).
    """
    if isinstance(n_episodes, bool) or not isinstance(n_episodes, int) or n_episodes < 1:
        raise UserInputError(f"evaluate n_episodes must be a positive integer, got {short_repr(n_episodes)}")
    if not callable(policy):
        raise UserInputError(f"evaluate policy must be a callable policy(obs) -> action, got {short_repr(policy)}")
    env_kwargs = dict(env_kwargs or {})
    episodes = [(seed + i, None if not targets else targets[i % len(targets)]) for i in range(n_episodes)]
    client = getattr(executor, "client", executor)
    t0 = time.perf_counter()
    if client is None:
        records = rollout(policy, env_kwargs, episodes)
        return EvaluationResult(records, _summary(records, time.perf_counter() - t0, "serial"))
    workers = max(len(client.scheduler_info().get("workers", {})), 1)
    size = chunk or max(1, int(np.ceil(n_episodes / workers)))
    futures = [client.submit(rollout, policy, env_kwargs, episodes[i:i + size], pure=False)
               for i in range(0, n_episodes, size)]
    records = [r for part in client.gather(futures) for r in part]
    return EvaluationResult(records, _summary(records, time.perf_counter() - t0, f"dask, {workers} worker(s)"))
