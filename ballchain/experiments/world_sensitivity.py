"""The sensorless force estimate under mismatch (issue 43): which uncertainty of the world
matters most to the autonomous navigator.

For each ring, the procedure (``procedure.run``, autonomous navigator) is run with the world
(``drake_models.world``) (a) perfect (``none``), (b) with each perturbation alone at its
``literature`` magnitude, (c) with all of them; a few seeds each (the seed draws the world and
the localisation noise). The ring is planned once (``procedure.plan_ring``) and the plans reused
by every run: the planner knows the nominal world only, so its plans do not depend on the world.

Per condition it reports, pooled over the seeds: the targets reached, the estimate's error over
the dwells (mean |error| per dwell, averaged; the worst), the fraction of the dwells with the
true force in the window, and the fraction of the dwells whose mean error exceeds a published
force sensor's mean absolute error (TactiCath 1.29 +- 0.99 g; SmartTouch 2.26 +- 2.70 g, worst
-22.6 g: Kueffer et al., "Comparison of the accuracy of contact force measurement in four
commercially available force-sensing ablation catheters", Europace 2022 (abstract
euac053.101) and its full report, in vitro, 0-60 g at 0-90 deg).

A procedure run costs tens of CPU seconds for a whole ring: ``targets`` keeps the first N of
each ring (the default 6) and the runs are cached in ``cache`` (one JSON, rewritten atomically
after each run): a run interrupted resumes where it stopped.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ballchain.drake_models.world import NAMES, PERTURBATIONS, PRESETS
from ballchain.experiments._result import Result
from ballchain.infrastructure.errors import UserInputError, short_repr

CONDITIONS = ("none", *NAMES, "all")
RINGS = ("right", "left")
TACTICATH_MAE_GF = 1.29  # Kueffer et al. 2022: mean absolute error 1.29 +- 0.99 g (0-60 g)
SMARTTOUCH_MAE_GF = 2.26  # the same study: 2.26 +- 2.70 g, worst -22.6 g


@dataclass
class SensitivityResult(Result):
    """What ``run`` returns (gf, s).

    Attributes:
        rows: per ring and condition: {ring, condition, magnitude (with its unit; None for
            none/all), seeds, reached, targets, dwells, estimate_mean_abs_error_gf (the mean over
            the dwells of each dwell's mean |error|), estimate_mean_error_gf (signed),
            estimate_worst_error_gf, in_window_fraction, worse_than_tacticath (fraction of the
            dwells whose mean |error| exceeds 1.29 gf), worse_than_smarttouch (2.26 gf),
            failures}.
        runs: per run: {ring, condition, seed, summary (the procedure's), dwell errors}.
        settings: {rings, seeds, targets, dwell_s, force_gf, conditions, magnitudes, cpu_time_s}.
    """

    rows: list
    runs: list
    settings: dict


def _world(condition: str, seed: int):
    if condition == "none":
        return "none"
    if condition == "all":
        return {"preset": "literature", "seed": seed}
    if condition.startswith("all x"):  # every perturbation at a multiple of its magnitude
        return {"preset": "literature", "seed": seed, "scale": float(condition[len("all x"):])}
    return {"preset": "literature", "only": [condition], "seed": seed}


def _run_one(ring: str, condition: str, seed: int, plans, targets: int, dwell_s: float) -> dict:
    from ballchain.experiments import procedure

    result = procedure.run(ring, "auto", seed=seed, targets=targets, dwell_s=dwell_s, plans=plans,
                           world=_world(condition, seed), progress=False, lesions=False)
    dwells = [{"target": r["target"], "mean_error_gf": r.get("estimate_mean_error_gf"),
               "worst_error_gf": r.get("estimate_worst_error_gf"), "in_window": r.get("in_window_fraction"),
               "force_true_mean_gf": r.get("force_true_mean_gf")}
              for r in result.rows if r.get("reached") and r.get("estimate_mean_error_gf") is not None]
    return {"ring": ring, "condition": condition, "seed": seed, "summary": result.summary, "dwells": dwells,
            "world": result.settings.get("world")}


def _row(ring: str, condition: str, runs: list) -> dict:
    dwells = [d for r in runs for d in r["dwells"]]
    errors = np.array([d["mean_error_gf"] for d in dwells], float)
    worst = [d["worst_error_gf"] for d in dwells]
    inside = [d["in_window"] for d in dwells if d["in_window"] is not None]
    unit = {name: u for name, _, u, _ in PERTURBATIONS}
    magnitude = None if condition in ("none", "all") else condition[len("all "):] if condition.startswith("all x") \
        else f"{PRESETS['literature'].to_dict()[condition]:.3g} {unit[condition]}"
    return {"ring": ring, "condition": condition, "magnitude": magnitude, "seeds": len(runs),
            "reached": sum(r["summary"]["reached"] for r in runs),
            "targets": sum(r["summary"]["targets"] for r in runs), "dwells": len(dwells),
            "estimate_mean_abs_error_gf": round(float(np.mean(np.abs(errors))), 3) if len(errors) else None,
            "estimate_mean_error_gf": round(float(np.mean(errors)), 3) if len(errors) else None,
            "estimate_worst_error_gf": round(float(max(worst)), 3) if worst else None,
            "in_window_fraction": round(float(np.mean(inside)), 4) if inside else None,
            "worse_than_tacticath": round(float(np.mean(np.abs(errors) > TACTICATH_MAE_GF)), 3) if len(errors) else None,
            "worse_than_smarttouch": round(float(np.mean(np.abs(errors) > SMARTTOUCH_MAE_GF)), 3) if len(errors) else None,
            "failures": sum(r["summary"].get("failure") is not None for r in runs)}


def _check(rings, seeds, targets, dwell_s, conditions, scales=()) -> None:
    if isinstance(rings, str) or not all(r in RINGS for r in rings) or not rings:
        raise UserInputError(f"rings must be some of {RINGS}, got {short_repr(rings)}")
    if isinstance(seeds, (str, bytes)) or not seeds or any(
            isinstance(s, bool) or not isinstance(s, int) or not 0 <= s <= 2**32 - 1 for s in seeds):
        raise UserInputError(f"seeds must be integers in 0..2**32-1, got {short_repr(seeds)}")
    if targets is not None and (isinstance(targets, bool) or not isinstance(targets, int) or targets < 1):
        raise UserInputError(f"targets must be a positive integer (the first N of each ring), got {short_repr(targets)}")
    if isinstance(dwell_s, bool) or not isinstance(dwell_s, (int, float)) or not math.isfinite(dwell_s) \
            or not 0 < dwell_s <= 120:
        raise UserInputError(f"dwell must be in (0, 120] s, got {short_repr(dwell_s)}")
    if isinstance(conditions, str) or not conditions or any(c not in CONDITIONS for c in conditions):
        raise UserInputError(f"conditions must be some of {', '.join(CONDITIONS)}, got {short_repr(conditions)}")
    if isinstance(scales, (str, bytes)) or any(isinstance(v, bool) or not isinstance(v, (int, float))
                                               or not math.isfinite(v) or not 0 < v <= 10 for v in scales):
        raise UserInputError(f"scales must be numbers in (0, 10] (every magnitude times it), got {short_repr(scales)}")


def run(rings=RINGS, seeds=(0, 1, 2), *, targets: int | None = 6, dwell_s: float = 10.0,
        conditions=CONDITIONS, scales=(), cache: Path | None = None, progress: bool = True) -> SensitivityResult:
    """The sensitivity table (module docstring).

    Args:
        rings: "right" (one unit) and/or "left" (two units).
        seeds: the seeds of each condition (the world's draw and the localisation noise).
        targets: the first N targets of each ring (None: all; the cost grows with N).
        dwell_s: the RF time per target [s].
        conditions: some of ``CONDITIONS``.
        scales: more conditions: every perturbation at each of these multiples of its magnitude
            (rows "all x0.5", ...): where the estimator stops being useful.
        cache: a JSON file keeping every finished run (resumed from when it exists).
        progress: a progress bar on stderr.

    Returns:
        A ``SensitivityResult``.
    """
    from tqdm import tqdm

    from ballchain.experiments import procedure
    from ballchain.infrastructure.safe_files import atomic_write_text, check_output_file

    rings, seeds, conditions, scales = tuple(rings), tuple(seeds), tuple(conditions), tuple(scales)
    _check(rings, seeds, targets, dwell_s, conditions, scales)
    conditions += tuple(f"all x{float(v):g}" for v in scales)
    settings = {"rings": list(rings), "seeds": list(seeds), "targets": targets, "dwell_s": dwell_s,
                "force_gf": procedure.FORCE_GF, "window_gf": list(procedure.WINDOW_GF), "conditions": list(conditions),
                "magnitudes": PRESETS["literature"].to_dict()}
    done: dict = {}
    if cache is not None:
        check_output_file(cache, "cache")
        if Path(cache).exists():
            saved = json.loads(Path(cache).read_text(encoding="utf-8"))
            if saved.get("settings", {}).get("targets") == targets and saved["settings"].get("dwell_s") == dwell_s:
                done = {(r["ring"], r["condition"], r["seed"]): r for r in saved.get("runs", [])}
    cpu0 = time.process_time()
    todo = [(ring, c, s) for ring in rings for c in conditions for s in seeds]
    bar = tqdm(total=len(todo), desc="sensitivity", unit="run", disable=not progress,
               initial=sum(k in done for k in todo))
    plans = {}
    for ring, condition, seed in todo:
        if (ring, condition, seed) in done:
            continue
        if ring not in plans:
            plans[ring] = procedure.plan_ring(ring, targets=targets)
        done[(ring, condition, seed)] = _run_one(ring, condition, seed, plans[ring], targets, dwell_s)
        if cache is not None:
            atomic_write_text(cache, json.dumps({"settings": settings, "runs": list(done.values())}))
        bar.update(1)
    bar.close()
    runs = [done[k] for k in todo]
    rows = [_row(ring, c, [r for r in runs if r["ring"] == ring and r["condition"] == c])
            for ring in rings for c in conditions]
    settings["cpu_time_s"] = round(time.process_time() - cpu0, 1)
    return SensitivityResult(rows=rows, runs=runs, settings=settings)
