"""The autonomous navigator's plans of a ring, computed once and kept on disk (issue 48).

A ring's plans (``procedure.target_plans``: the inverse statics of every target, tens of
CPU-seconds) are a function of the anatomy's targets and sheath, the units' magnet centres, the
chain, the force asked for and the planning code; not of the run's seed, its navigator's
feedback, or the world's perturbations (the plans are made on the nominal model). They are kept
in the per-user cache folder of the generated model files (``model_files.cache_dir``,
``procedure_plans/<key>/plans.npz``), keyed by a hash of exactly those inputs (``plan_key``):
the numbers the planning reads, not the names they come by, and the source of the modules that
compute them (``PLAN_MODULES``), so that other code never reuses another code's plans.

The set is signed like every cached model file (``model_files.cached_files``: an HMAC-SHA256
with this user's key), written atomically, and read without pickles; its content is checked
again on reading (its key, shapes, finite numbers). A damaged, foreign or unreadable entry is
never trusted: it is recomputed and written again (one line on stderr). The key's hashing, the
code's hash, the signed store and its checks are ``drake_models.result_cache``'s, shared with the
manual hand's sheath plans (``systems.sheath_plan_cache``).
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np

from ballchain.drake_models import model_files, result_cache
from ballchain.drake_models.params import BallChain, CylinderMagnet
from ballchain.experiments.planner import anatomy_stand
from ballchain.systems.autonomous_navigator import TargetPlan

FORMAT = 1  # the layout of plans.npz; part of the key
FOLDER = "procedure_plans"
FILE = "plans.npz"
# The code that computes a plan: every module of these packages, then these single modules
# (found where they are installed, not imported); a change to any of them is another key.
PLAN_PACKAGES = ("ballchain.optimization", "ballchain.drake_models.kernels")
PLAN_MODULES = ("ballchain.experiments.procedure", "ballchain.experiments.planner", "ballchain.experiments.forces",
                "ballchain.experiments.plan_cache", "ballchain.drake_models.field_sources",
                "ballchain.drake_models.params", "ballchain.drake_models.chain_energy",
                "ballchain.drake_models.dipole_inversion", "ballchain.drake_models.dipole",
                "ballchain.drake_models.vectors",
                "ballchain.drake_models.result_cache")  # (TargetPlan's fields: FORMAT)
_FIELDS = ("p_WT", "n_W", "dipoles_W", "inserted_length", "basis_W", "J_m", "J_o", "force_N", "aim_offset")


def code_hash() -> str:
    """A hash of the planning code's source files (``PLAN_PACKAGES``, ``PLAN_MODULES``)."""
    return result_cache.code_hash(PLAN_PACKAGES, PLAN_MODULES)


def plan_key(inputs: dict) -> str:
    """The cache key of a ring's plans: a SHA-256 of ``inputs`` (the numbers the planning reads,
    ``ring_inputs``), the chain's and magnets' parameters, the file layout and ``code_hash``."""
    return result_cache.content_key({"format": FORMAT, "inputs": inputs, "chain": asdict(BallChain()),
                                     "magnet": asdict(CylinderMagnet()), "code": code_hash()})


def ring_inputs(stand, p_WT, n_W, names, force_N: float, n_balls: int, inserted_length: float, magnets_W,
                touch_radius: float, tolerance: float, slack: float | None) -> dict:
    """Everything ``target_plans`` reads, as numbers: the targets in the statics frame (``stand``:
    centres and axes, its rotation and sheath exit), in the world (``p_WT``, ``n_W``), their names
    and touch radius, the units' centres, the chain's length and insertion, the force, the
    navigator's tolerance and the slack. World perturbations are no input: the plans are the
    nominal model's."""
    return {"names": list(names), "targets_S": [list(stand.targets[n]) for n in stand.targets],
            "R_HS": np.asarray(stand.R_HS, float), "p_HE": np.asarray(stand.p_HE, float),
            "p_WT": np.asarray(p_WT, float), "n_W": np.asarray(n_W, float), "force_N": float(force_N),
            "n_balls": int(n_balls), "inserted_length": float(inserted_length),
            "magnets_W": [np.asarray(p, float) for p in magnets_W], "touch_radius": float(touch_radius),
            "tolerance": float(tolerance), "slack": None if slack is None else float(slack)}


def ring_plans(anatomy, chosen: list[int], force_N: float, n_balls: int, inserted_length: float, magnets_W,
               tolerance: float, slack: float | None, compute: Callable[[], tuple[list, list]],
               cache: bool = True) -> tuple[list, list, bool]:
    """``compute()`` (``procedure.target_plans`` of these arguments) through the cache
    (``cached_plans``; ``cache`` False: computed, nothing read or stored).

    Returns:
        (the TargetPlans, the names not planned, whether a stored set answered).
    """
    if not cache:
        return (*compute(), False)
    stand = anatomy_stand(anatomy, chosen, BallChain(n_balls=n_balls).ball_diameter)
    inputs = ring_inputs(stand, anatomy.p_WT[chosen], anatomy.n_W[chosen], [anatomy.target_names[k] for k in chosen],
                         force_N, n_balls, inserted_length, magnets_W, anatomy.touch_radius, tolerance, slack)
    plans, missing, _, reused = cached_plans(inputs, compute)
    return plans, missing, reused


def _to_arrays(key: str, plans: list, missing: list, cpu_s: float) -> dict:
    out = {"key": np.array(key), "names": np.array([p.name for p in plans], dtype=str),
           "missing": np.array(list(missing), dtype=str), "cpu_s": np.array(float(cpu_s))}
    for f in _FIELDS:
        out[f] = np.array([np.asarray(getattr(p, f), float) for p in plans], dtype=float)
    return out


def _from_arrays(data, key: str) -> tuple[list, list, float]:
    """The plans of a stored set; raises ValueError when it is not a set of ``key``'s shape."""
    if str(data["key"]) != key:
        raise ValueError("another key")
    names, missing = [str(n) for n in data["names"]], [str(n) for n in data["missing"]]
    n = len(names)
    arrays = {f: np.asarray(data[f]) for f in _FIELDS}
    k = arrays["dipoles_W"].shape[1] if n and arrays["dipoles_W"].ndim == 3 else 0
    shapes = {"p_WT": (n, 3), "n_W": (n, 3), "dipoles_W": (n, k, 3), "inserted_length": (n,), "basis_W": (n, 3, 3),
              "J_m": (n, 3, 3 * k), "J_o": (n, 3, 2), "force_N": (n,), "aim_offset": (n,)}
    for f, shape in shapes.items():
        a = arrays[f]
        if n and (a.shape != shape or a.dtype != np.float64 or not np.all(np.isfinite(a))):
            raise ValueError(f"{f}: shape {a.shape}, dtype {a.dtype}")
    plans = [TargetPlan(names[i], arrays["p_WT"][i].copy(), arrays["n_W"][i].copy(), arrays["dipoles_W"][i].copy(),
                        float(arrays["inserted_length"][i]), arrays["basis_W"][i].copy(), arrays["J_m"][i].copy(),
                        arrays["J_o"][i].copy(), float(arrays["force_N"][i]), float(arrays["aim_offset"][i]))
             for i in range(n)]
    return plans, missing, float(data["cpu_s"])


def cached_plans(inputs: dict, compute: Callable[[], tuple[list, list]],
                 folder: Path | None = None) -> tuple[list, list, float, bool]:
    """The plans of ``inputs`` (``ring_inputs``) from the cache, or ``compute()``d and stored.

    Args:
        inputs: what the plans are a function of (``ring_inputs``): hashed into the key.
        compute: () -> (the TargetPlans, the names not planned): the planning itself.
        folder: the cache's folder (None: ``model_files.cache_dir() / FOLDER``).

    Returns:
        (plans, missing, the CPU time spent here [s], reused): ``reused`` when a stored set
        answered (the time is then the reading's).
    """
    cpu0 = time.process_time()
    key = plan_key(inputs)
    directory = (model_files.cache_dir() / FOLDER if folder is None else Path(folder)) / key[:32]
    (plans, missing), reused = result_cache.cached_arrays(
        directory, FILE, key, compute, lambda result: _to_arrays(key, *result, time.process_time() - cpu0),
        lambda data: _from_arrays(data, key)[:2], "cached plan")
    return plans, missing, time.process_time() - cpu0, reused
