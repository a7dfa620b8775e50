"""The manual hand's sheath plans of a ring, computed once and kept on disk (issue 45, H13).

What the hand asks a ``SheathPlan`` for a target (``ManualHand``: the sheath's setting ``plan``,
the curve it re-approaches with ``approach``, whether it dials with the sheath kept ``dials``) is
a function of the sheath, the catheter, the sheath's pose at the septum (p_S, R_S), the atrium's
wall as the planning sees it (the signed-distance grid's numbers), the target, the touch radius,
the hand's shortest (``min_out``), the plan's breadth (``top``), its force limit and the planning
code; not of the run's seed or the operator. ``RingSheathPlans`` answers the hand from a table of
every target of the target's ring, computed once (a coarse grid, then the local refinement with
rod-statics checks: 5-6 CPU-s for the right ring at 0.14 N/mm) and kept in the per-user cache of
the generated model files (``model_files.cache_dir() / FOLDER / <key>/FILE``), keyed by a hash
of exactly those inputs (``plan_inputs``) and of the source of the modules that compute them
(``PLAN_PACKAGES``, ``PLAN_MODULES``), as the autonomous navigator's plans
(``experiments.plan_cache``; the signing, the atomic write, the key's and the code's hashes and
the checks on reading are ``drake_models.result_cache``'s). A damaged or foreign entry is
recomputed (one line on stderr). A stored table answers with the numbers the plan computed, to
the last bit: the runs are the same with a cold cache, a warm one, or none.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ballchain.drake_models import model_files, result_cache
from ballchain.drake_models.sheath import SteerableSheath
from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.systems.sheath_plan import SheathPlan, force_limit
from ballchain.systems.target_contact import heart_targets

FORMAT = 1  # the layout of plans.npz; part of the key
FOLDER = "sheath_plans"
FILE = "plans.npz"
# The code that computes a sheath plan: every module of these packages (the rod's statics, the
# signed distance's kernel), then these single modules (found where they are installed, not
# imported); a change to any of them is another key.
PLAN_PACKAGES = ("ballchain.optimization", "ballchain.drake_models.kernels")
PLAN_MODULES = ("ballchain.systems.sheath_plan", "ballchain.systems.sheath_plan_cache",
                "ballchain.systems.rod_wall_compliance", "ballchain.systems.target_contact",
                "ballchain.drake_models.sheath", "ballchain.drake_models.steerable_catheter",
                "ballchain.drake_models.electrode", "ballchain.drake_models.wall_motion",
                "ballchain.drake_models.atrium_sdf", "ballchain.drake_models.vectors",
                "ballchain.drake_models.result_cache")


def cache_folder() -> Path:
    """The cache's folder: ``model_files.cache_dir() / FOLDER`` (one sub-folder per key)."""
    return model_files.cache_dir() / FOLDER


def code_hash() -> str:
    """A hash of the sheath planning code's source files (``PLAN_PACKAGES``, ``PLAN_MODULES``)."""
    return result_cache.code_hash(PLAN_PACKAGES, PLAN_MODULES)


GRID = ("origin", "spacing", "band", "values")  # what a wall keyed by ``wall_numbers`` has (``AtriumSDF``)


def wall_numbers(sdf) -> dict | None:
    """The atrium's wall as the plan sees it: the signed-distance grid's origin, spacing, clamp,
    shape and a SHA-256 of its node values (float64, as evaluated); None without a wall (free
    space). Raises AttributeError for a wall that is not such a grid (``GRID``)."""
    if sdf is None:
        return None
    values = np.ascontiguousarray(sdf.values, dtype=float)
    return {"origin": np.asarray(sdf.origin, float), "spacing": float(sdf.spacing), "band": float(sdf.band),
            "shape": list(values.shape), "values_sha256": hashlib.sha256(values.tobytes()).hexdigest()}


def plan_inputs(sheath: SteerableSheath, catheter: SteerableCatheter, p_S, R_S, wall: dict | None,
                target_radius: float, top: int, min_out: float, p_T, n_T) -> dict:
    """Everything a ring's sheath plans read, as numbers: the sheath's and the catheter's
    parameters, the sheath's pose at the septum, the wall (``wall_numbers``), the touch radius,
    the plan's breadth and the hand's shortest, the ring's targets (centres and wall normals, in
    order) and the planned curves' force limit (``sheath_plan.force_limit``)."""
    return {"sheath": asdict(sheath), "catheter": asdict(catheter), "p_S": np.asarray(p_S, float),
            "R_S": np.asarray(R_S, float), "wall": wall, "target_radius": float(target_radius), "top": int(top),
            "min_out": float(min_out), "p_T": np.asarray(p_T, float), "n_T": np.asarray(n_T, float),
            "force_limit_N": float(force_limit())}


def plan_key(inputs: dict) -> str:
    """The cache key of a ring's sheath plans: a SHA-256 of ``inputs`` (``plan_inputs``), the file
    layout and ``code_hash``."""
    return result_cache.content_key({"format": FORMAT, "inputs": inputs, "code": code_hash()})


@dataclass(frozen=True)
class SheathTable:
    """A ring's sheath plans, one row per target (in the ring's order).

    Attributes:
        p_T, n_T: (n, 3) the targets' centres [m] and wall normals.
        settings: (n, 3) ``SheathPlan.plan``: the sheath's advance [m], rotation, deflection [rad].
        approaches: (n, 3) ``SheathPlan.approach``: push [m], knob, twist [rad].
        dials: (n,) ``SheathPlan.dials``.
    """

    p_T: np.ndarray
    n_T: np.ndarray
    settings: np.ndarray
    approaches: np.ndarray
    dials: np.ndarray

    def row(self, p_T, n_T) -> int | None:
        """The row of the target (p_T, n_T), the same numbers exactly; None when it is not here."""
        hit = np.flatnonzero(np.all(self.p_T == p_T, axis=1) & np.all(self.n_T == n_T, axis=1))
        return int(hit[0]) if len(hit) else None


def ring_table(plan: SheathPlan, p_T, n_T) -> SheathTable:
    """The plan's answers for each target (p_T[k], n_T[k]): what ``ManualHand`` asks."""
    p_T, n_T = np.asarray(p_T, float).reshape(-1, 3), np.asarray(n_T, float).reshape(-1, 3)
    settings, approaches, dials = [], [], []
    for p, n in zip(p_T, n_T):
        settings.append(plan.plan(p, n))
        approaches.append(plan.approach(p, n))
        dials.append(plan.dials(p, n))
    return SheathTable(p_T.copy(), n_T.copy(), np.array(settings, float).reshape(-1, 3),
                       np.array(approaches, float).reshape(-1, 3), np.array(dials, bool))


def _to_arrays(table: SheathTable, cpu_s: float) -> dict:
    return {"p_T": table.p_T, "n_T": table.n_T, "settings": table.settings, "approaches": table.approaches,
            "dials": table.dials, "cpu_s": np.array(float(cpu_s))}


def _from_arrays(data, p_T, n_T) -> SheathTable:
    """The table of a stored entry; raises ValueError when it is not the table of these targets."""
    n = len(p_T)
    arrays = {f: np.asarray(data[f]) for f in ("p_T", "n_T", "settings", "approaches", "dials")}
    for f, a in arrays.items():
        shape, dtype = ((n,), np.bool_) if f == "dials" else ((n, 3), np.float64)
        if a.shape != shape or a.dtype != dtype or (dtype == np.float64 and not np.all(np.isfinite(a))):
            raise ValueError(f"{f}: shape {a.shape}, dtype {a.dtype}")
    if not (np.array_equal(arrays["p_T"], p_T) and np.array_equal(arrays["n_T"], n_T)):
        raise ValueError("other targets")
    return SheathTable(**{f: a.copy() for f, a in arrays.items()})


def cached_table(inputs: dict, compute, folder: Path | None = None) -> tuple[SheathTable, float, bool]:
    """The ring's table of ``inputs`` (``plan_inputs``) from the cache, or ``compute()``d and stored.

    Args:
        inputs: what the plans are a function of: hashed into the key (its targets checked again
            on reading).
        compute: () -> the SheathTable (``ring_table``): the planning itself.
        folder: the cache's folder (None: ``cache_folder()``).

    Returns:
        (the table, the CPU time spent here [s], whether a stored entry answered).
    """
    cpu0 = time.process_time()
    key = plan_key(inputs)
    directory = (cache_folder() if folder is None else Path(folder)) / key[:32]
    table, reused = result_cache.cached_arrays(
        directory, FILE, key, compute, lambda t: _to_arrays(t, time.process_time() - cpu0),
        lambda data: _from_arrays(data, inputs["p_T"], inputs["n_T"]), "cached sheath plan")
    return table, time.process_time() - cpu0, reused


def heart_rings(heart) -> list[tuple[np.ndarray, np.ndarray]]:
    """The atrium's target rings, each as (p_WT (n, 3), n_W (n, 3)): ``heart_targets``' targets
    split where its rings (``heart.rings``, in order) end."""
    _, p_WT, n_W, _ = heart_targets(heart)
    ends = np.cumsum([len(ring.p_HT) for ring in heart.rings.values()])[:-1]
    return list(zip(np.split(p_WT, ends), np.split(n_W, ends)))


class RingSheathPlans:
    """What ``ManualHand`` asks a ``SheathPlan`` (``nominal``, ``plan``, ``approach``, ``dials``),
    answered from each ring's table (module docstring): on the first target of a ring the whole
    ring's table is read from the cache or computed (``ring_table``) and stored. A target of no
    ring, or every target with ``cache`` False, is asked of the ``SheathPlan`` itself (made when
    first needed), as before this cache.

    Args (the first six and ``top``, ``min_out`` as ``SheathPlan``'s):
        rings: the rings' targets, each (p_T (n, 3), n_T (n, 3)) (``heart_rings``).
        folder: the cache's folder (None: ``cache_folder()``).
        cache: False: nothing read or stored (also for a wall that is not a grid, ``GRID``).

    Attributes:
        nominal: the fixed sheath's setting (``SheathPlan.nominal``).
        reused: {ring index: whether its table was read from the cache}; cpu_s: {ring index: the
            CPU time its table took, computed or read [s]}.
    """

    def __init__(self, sheath: SteerableSheath, catheter: SteerableCatheter, p_S, R_S, sdf, target_radius: float,
                 rings, top: int = 12, min_out: float = 6e-3, folder: Path | None = None, cache: bool = True) -> None:
        self.sheath = sheath.validate()
        self.nominal = (self.sheath.nominal_advance, 0.0, 0.0)
        self._args = (sheath, catheter, p_S, R_S, sdf, target_radius)
        self.top, self.min_out = int(top), float(min_out)
        self.rings = [(np.asarray(p, float).reshape(-1, 3), np.asarray(n, float).reshape(-1, 3)) for p, n in rings]
        self.folder = folder
        self.cache = bool(cache) and (sdf is None or all(hasattr(sdf, a) for a in GRID))
        self._wall = None  # wall_numbers(sdf), hashed when first needed
        self._plan: SheathPlan | None = None
        self._tables: dict[int, SheathTable] = {}
        self.reused: dict[int, bool] = {}
        self.cpu_s: dict[int, float] = {}

    def sheath_plan(self) -> SheathPlan:
        """The planning itself (``SheathPlan``), made when first needed."""
        if self._plan is None:
            self._plan = SheathPlan(*self._args, top=self.top, min_out=self.min_out)
        return self._plan

    def _table(self, i: int) -> SheathTable:
        if i not in self._tables:
            sheath, catheter, p_S, R_S, sdf, radius = self._args
            p_T, n_T = self.rings[i]
            if self._wall is None:
                self._wall = (wall_numbers(sdf),)
            inputs = plan_inputs(sheath, catheter, p_S, R_S, self._wall[0], radius, self.top, self.min_out, p_T, n_T)
            self._tables[i], self.cpu_s[i], self.reused[i] = cached_table(
                inputs, lambda: ring_table(self.sheath_plan(), p_T, n_T), self.folder)
        return self._tables[i]

    def _row(self, p_T, n_T) -> tuple[SheathTable, int] | None:
        """The table and row of the target (p_T, n_T), exactly one of a ring's; None otherwise."""
        if not self.cache:
            return None
        p_T, n_T = np.asarray(p_T, float), np.asarray(n_T, float)
        for i, (ring_p, ring_n) in enumerate(self.rings):
            if np.any(np.all(ring_p == p_T, axis=1) & np.all(ring_n == n_T, axis=1)):
                table = self._table(i)
                return table, table.row(p_T, n_T)
        return None

    def plan(self, p_T, n_T) -> tuple:
        """``SheathPlan.plan`` (the hand's default ``keep``) for the target."""
        found = self._row(p_T, n_T)
        if found is None:
            return self.sheath_plan().plan(p_T, n_T)
        table, k = found
        return tuple(float(v) for v in table.settings[k])

    def approach(self, p_T, n_T) -> tuple[float, float, float]:
        """``SheathPlan.approach`` for the target."""
        found = self._row(p_T, n_T)
        if found is None:
            return self.sheath_plan().approach(p_T, n_T)
        table, k = found
        return tuple(float(v) for v in table.approaches[k])

    def dials(self, p_T, n_T) -> bool:
        """``SheathPlan.dials`` for the target."""
        found = self._row(p_T, n_T)
        if found is None:
            return self.sheath_plan().dials(p_T, n_T)
        table, k = found
        return bool(table.dials[k])
