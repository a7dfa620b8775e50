"""The simulated procedure over seeds: the autonomous navigator and the simulated operator on the same rings.

Both rings of the procedural atrium (left: both units, right: the unit beyond the right carina;
``procedure.default_units``), both navigators (``procedure.run``), each over the same seeds: the
seed draws the localisation noise for the navigator and the hand's tremor for the operator. The
navigator's feed-forward (inverse statics, ``procedure.plan_ring``) does not depend on the seed:
it is made once per ring and given to every seed's run, which gives the same result as planning
in each run. The runs are independent and run side by side on worker processes
(``sweep.run_sections``): first the rings' plans, then every run, seed by seed.

Per ring and navigator, over the seeds: the median and the range of the total simulated time,
the targets reached, the fraction of the dwells with the true force in the window, the true
force's extremes, the estimate's error (the navigator only: the operator has no estimate), the
ring's gaps and in how many runs the lesions close into a ring (``lesion_ring``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import time
from copy import deepcopy
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ballchain.drake_models.lesion_dwell import LesionConditions
from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.experiments import procedure
from ballchain.experiments._result import Result, optional
from ballchain.experiments.procedure_result import with_lesions

SEEDS = (0, 1, 2)
"""The main job's seeds (issue 48: the main job within 3 CPU-minutes; a whole ring is 8-12 CPU-s a run).
The study with its intervals over 20 seeds and more is ``ballchain trials`` on a Dask cluster
(docs/guide/trials.md)."""
RINGS = ("left", "right")
QUICK_TARGETS = 3


@dataclass
class ProcedureReport(Result):
    """What ``run`` returns.

    Attributes:
        table: one row per (ring, navigator): medians and ranges over the seeds (``_aggregate``).
        runs: one per (ring, navigator, seed): {ring, navigator, seed, summary, rows, ring_verdict,
            lesions, cpu_time_s (the whole job: build, run, lesions, files)}.
        plans: per ring {targets, missing, cpu_time_s} of its plans (made once).
        settings: {seeds, rings, targets, dwell_s, workers, cpu_time_s (every job's, summed)}.
        files: {"figure", "rings" ({ring/navigator: map of the first seed}), "runs" (folder of
            each run's ``procedure.json``)} (with ``out``).
    """

    table: list
    runs: list
    plans: dict
    settings: dict
    files: dict | None = optional()


def check_inputs(seeds, rings, targets) -> tuple[int, ...]:
    """The seeds as a tuple; raises UserInputError naming the argument, its value and what is allowed."""
    from ballchain.experiments.teleop import check_seed

    if isinstance(seeds, (str, bytes)) or not hasattr(seeds, "__iter__"):
        raise UserInputError(f"seeds must be a list of distinct integers, got {short_repr(seeds)}")
    seeds = tuple(seeds)
    for s in seeds:
        check_seed(s)
    if not seeds or len(set(seeds)) != len(seeds):
        raise UserInputError(f"seeds must be a non-empty list of distinct integers, got {short_repr(seeds)}")
    if isinstance(rings, str) or not rings or any(r not in RINGS for r in rings):
        raise UserInputError(f"rings must be a non-empty list of {RINGS}, got {short_repr(rings)}")
    if targets is not None and (isinstance(targets, bool) or not isinstance(targets, int) or targets < 1):
        raise UserInputError(f"targets must be a positive integer (the first N), got {short_repr(targets)}")
    return seeds


def _plan_job(ring: str, targets, out: Path, quick: bool):
    cpu0 = time.process_time()
    plans = procedure.plan_ring(ring, targets=targets)
    return plans, time.process_time() - cpu0


def _run_job(ring: str, navigator: str, seed: int, targets, dwell_s: float, plans, folder, out: Path,
             quick: bool) -> dict:
    """One run, its ``procedure.json`` and ring map written to ``folder`` (when given); a compact record."""
    cpu0 = time.process_time()
    result = procedure.run(ring, navigator, seed=seed, targets=targets, dwell_s=dwell_s, plans=plans,
                           progress=False)
    if folder is not None:
        procedure.write_outputs(result, Path(folder) / f"{ring}_{navigator}_seed{seed}")
    return {"ring": ring, "navigator": navigator, "seed": seed, "summary": result.summary, "rows": result.rows,
            "ring_verdict": result.ring, "lesions": result.lesions, "units": result.settings["units"],
            "clinical_verdict": clinical_verdict(result),
            "cpu_time_s": round(time.process_time() - cpu0, 2)}


CLINICAL_LESIONS = LesionConditions(blood_flow="high", criterion="contiguous", time_limit_s=90.0)
"""The lesions of the report's second verdict: high blood flow, the generator holding the tip
magnet below its limit, each lesion run until transmural and as wide as its farthest ring
neighbour, at most 90 s (``lesion_dwell``; docs/guide/ablation.md)."""


def clinical_verdict(result) -> dict:
    """The ring's verdict with ``CLINICAL_LESIONS`` on the run's own dwells (a copy of the result:
    the run's bench lesions stay). An assumption, stated in the report: each RF time the
    criterion asks for is held at the dwell's mean true force and place, although the run dwelt
    for its 10 s only. {gaps, isolated, rf_time_s (the ring's RF time in all)}."""
    copy = dataclasses.replace(result, rows=deepcopy(result.rows),
                               settings={**(result.settings or {}), "lesions": CLINICAL_LESIONS.to_dict()})
    with_lesions(copy, [row["target"] for row in copy.rows])
    rf = sum(row["point"].get("rf_duration_s", 0.0) for row in copy.rows if row.get("point"))
    return {"gaps": len(copy.ring["gaps"]), "isolated": bool(copy.ring["isolated"]), "rf_time_s": round(rf, 1)}


def default_workers() -> int:
    """2 worker processes (the cores of the machine the report is sized for; at most its cores),
    1 (this process) inside a worker process, which cannot start its own."""
    import multiprocessing
    import os

    if multiprocessing.current_process().daemon:
        return 1
    try:
        from distributed import get_worker

        get_worker()
        return 1
    except (ImportError, ValueError):
        return max(1, min(2, os.cpu_count() or 1))


def _map(jobs: list, out: Path, workers: int, what: str, client=None) -> list:
    from ballchain.sections import run_sections

    return [r.value for r in run_sections(jobs, out, False, workers=workers, client=client, progress=what)]


@contextlib.contextmanager
def _cluster(workers: int):
    """One LocalCluster of ``workers`` processes for the plans and the runs (its client), or None
    (1: this process): the plans' and the runs' maps share its workers, which import the package
    and load the compiled kernels once (issue 48: a cluster per map started two more)."""
    if workers == 1:
        yield None
        return
    from ballchain.executor import Executor

    with Executor(workers=workers) as ex:
        yield ex.client


def run(seeds=SEEDS, *, rings=RINGS, targets: int | None = None, dwell_s: float = procedure.DWELL_S,
        workers: int | None = None, out: Path | None = None) -> ProcedureReport:
    """Both navigators on the rings over the seeds (module docstring).

    Args:
        seeds: the seeds (distinct, 0..2**32-1), the same for both navigators.
        rings: among "left", "right".
        targets: only the first N targets of each ring (None: whole rings).
        dwell_s: the RF time per target [s].
        workers: worker processes (None: ``default_workers``; 1: this process, serially).
        out: a folder: each run's ``procedure.json`` and ring map under ``out/runs``, the figure
            ``procedure_forces.png`` (atomically).

    Returns:
        A ``ProcedureReport``.
    """
    seeds = check_inputs(seeds, rings, targets)
    procedure.check_inputs(rings[0], "auto", 0, targets, procedure.FORCE_GF, procedure.WINDOW_GF, dwell_s)
    workers = default_workers() if workers is None else workers
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise UserInputError(f"workers must be a positive integer, got {short_repr(workers)}")
    folder = None
    if out is not None:
        from ballchain.infrastructure.safe_files import check_output_dir

        out = check_output_dir(out, "out")
        folder = out / "runs"
    base = Path(out) if out is not None else Path(".")
    with _cluster(workers) as client:
        done = _map([(f"plan {r}", functools.partial(_plan_job, r, targets)) for r in rings], base, workers,
                    "procedure plans", client)
        plans = dict(zip(rings, done))
        # Seed by seed (the costliest run first in each), so that an interrupted run has whole seeds.
        jobs = [(f"{r} {n} {s}", functools.partial(_run_job, r, n, s, targets, dwell_s,
                                                   plans[r][0] if n == "auto" else None, folder))
                for s in seeds for r in rings for n in procedure.NAVIGATORS]
        runs = _map(jobs, base, workers, "procedure runs", client)
    runs.sort(key=lambda x: (rings.index(x["ring"]), procedure.NAVIGATORS.index(x["navigator"]), seeds.index(x["seed"])))
    table = [_aggregate([x for x in runs if x["ring"] == r and x["navigator"] == n])
             for r in rings for n in procedure.NAVIGATORS]
    cpu = sum(x["cpu_time_s"] for x in runs) + sum(p[1] for p in plans.values())
    report = ProcedureReport(
        table=table, runs=runs,
        plans={r: {"targets": len(p.plans) + len(p.missing), "missing": list(p.missing), "cpu_time_s": round(c, 2)}
               for r, (p, c) in plans.items()},
        settings={"seeds": list(seeds), "rings": list(rings), "targets": targets, "dwell_s": dwell_s,
                  "workers": workers, "cpu_time_s": round(cpu, 1)})
    if out is not None:
        report.files = {"figure": str(force_figure(report, out / "procedure_forces.png")), "runs": str(folder),
                        "rings": {f"{r}/{n}": str(folder / f"{r}_{n}_seed{seeds[0]}" / "ring.png")
                                  for r in rings for n in procedure.NAVIGATORS}}
    return report


def _spread(values: list) -> dict:
    """Median, min and max of the values that exist (None for all three when none does)."""
    values = [float(v) for v in values if v is not None]
    if not values:
        return {"median": None, "min": None, "max": None}
    return {"median": round(float(np.median(values)), 3), "min": round(min(values), 3),
            "max": round(max(values), 3)}


def _aggregate(runs: list) -> dict:
    """One (ring, navigator)'s row over its seeds."""
    first = runs[0]
    reached_rows = [row for x in runs for row in x["rows"]
                    if row.get("reached") and row.get("force_true_min_gf") is not None]
    rings = [x["ring_verdict"] for x in runs if x["ring_verdict"] is not None]
    failures = sorted({x["summary"]["failure"] for x in runs if x["summary"].get("failure")})
    return {
        "ring": first["ring"], "navigator": first["navigator"], "units": first["units"], "runs": len(runs),
        "targets": first["summary"]["targets"],
        "reached": _spread([x["summary"]["reached"] for x in runs]),
        "total_time_s": _spread([x["summary"]["total_time_s"] for x in runs]),
        "in_window_fraction": _spread([x["summary"].get("in_window_fraction") for x in runs]),
        "force_true_min_gf": min((r["force_true_min_gf"] for r in reached_rows), default=None),
        "force_true_max_gf": max((r["force_true_max_gf"] for r in reached_rows), default=None),
        "estimate_mean_abs_error_gf": _spread([x["summary"].get("estimate_mean_abs_error_gf") for x in runs]),
        "estimate_worst_error_gf": max((x["summary"]["estimate_worst_error_gf"] for x in runs
                                        if x["summary"].get("estimate_worst_error_gf") is not None), default=None),
        "ring_gaps": _spread([len(v["gaps"]) for v in rings]),
        "isolated_runs": sum(bool(v["isolated"]) for v in rings),
        "clinical_ring_gaps": _spread([x["clinical_verdict"]["gaps"] for x in runs if x.get("clinical_verdict")]),
        "clinical_isolated_runs": sum(bool(x["clinical_verdict"]["isolated"]) for x in runs if x.get("clinical_verdict")),
        "clinical_rf_time_s": _spread([x["clinical_verdict"]["rf_time_s"] for x in runs if x.get("clinical_verdict")]),
        "cpu_time_s": _spread([x["cpu_time_s"] for x in runs]),
        "failures": failures,
    }


def force_figure(report: ProcedureReport, path: Path) -> Path:
    """The navigator's estimate against the true force, one point per dwell (its means; the bar
    spans the true force's min..max over the dwell), every seed, a colour per ring; beside it the
    operator's true force per dwell. The clinical window shaded."""
    from ballchain.infrastructure.safe_files import agg_pyplot, save_figure

    plt = agg_pyplot()
    fig, (ax, ax_o) = plt.subplots(1, 2, figsize=(11, 4.6), gridspec_kw={"width_ratios": [1.3, 1.0]})
    lo, hi = procedure.WINDOW_GF
    top = hi * 1.25
    colours = {"left": "tab:blue", "right": "tab:orange"}
    for x in report.runs:
        rows = [r for r in x["rows"] if r.get("reached") and r.get("force_true_mean_gf") is not None]
        if not rows:
            continue
        true = np.array([r["force_true_mean_gf"] for r in rows])
        span = np.array([[r["force_true_mean_gf"] - r["force_true_min_gf"], r["force_true_max_gf"] - r["force_true_mean_gf"]]
                         for r in rows]).T
        top = max(top, float((true + span[1]).max()) * 1.05)
        label = x["ring"] if x["seed"] == report.settings["seeds"][0] else None
        if x["navigator"] == "auto":
            est = true + np.array([r["estimate_mean_error_gf"] for r in rows])
            ax.errorbar(true, est, xerr=span, fmt="o", ms=3, lw=0.6, alpha=0.6, color=colours[x["ring"]], label=label)
        else:
            k = np.arange(len(rows)) + 0.15 * report.settings["seeds"].index(x["seed"])
            ax_o.errorbar(k, true, yerr=span, fmt="o", ms=3, lw=0.6, alpha=0.6, color=colours[x["ring"]], label=label)
    ax.plot([0, top], [0, top], "k--", lw=0.8, label="estimate = true")
    ax.axvspan(lo, hi, color="0.9", zorder=0)
    ax.set(xlim=(0, top), ylim=(0, top), xlabel="true force over the dwell [gf] (mean, min..max)",
           ylabel="navigator's estimate [gf] (mean)", title="Autonomous navigator: estimate vs true force")
    ax_o.axhspan(lo, hi, color="0.9", zorder=0)
    ax_o.set(ylim=(0, top), xlabel="target (in ring order; seeds side by side)", ylabel="true force [gf]",
             title="Simulated operator: true force per dwell")
    for a in (ax, ax_o):
        a.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    return Path(path)
