"""The trials study (issue 43): the closed-loop arms over many seeds, each row with its 95 % interval.

Each arm is one closed-loop run per seed, the seed drawing the hand's tremor (the simulated
operator) or the localisation noise (the autonomous navigator):

* ``robotic_left``, ``robotic_right``: the teleoperation tasks I and II with the simulated
  operator on the robotic chain, the paper's world mapping (``teleop.run``; also the robotic arm
  of the comparison with the manual catheter);
* ``manual_left``, ``manual_right``: the same operator with the manual steerable catheter
  (``manual_catheter.run``);
* ``procedure_left_auto``, ``procedure_left_operator``, ``procedure_right_auto``,
  ``procedure_right_operator``: the ablation procedure on a ring by the autonomous navigator or
  the simulated operator (``procedure.run``; the navigator's plans, which do not depend on the
  seed, made once per ring and given to every seed's run).

The seeds x arms runs go through the project's Dask executor (``ballchain.executor``: a
LocalCluster by default, an existing scheduler by address, or this process with ``workers=0``).
Each finished run is written at once to ``out/runs/<arm>_seed<seed>.json`` (atomically) and
skipped when the study runs again into the same folder; a run that failed is run again. The
table of every run (``out/table.parquet``, ``out/table.csv``: the sweep's table writer) and the
intervals (``out/trials.json``) are written at the end.

The intervals (``ballchain.intervals``): per arm, the median of the targets touched (reached)
and of the total time with their 95 % bootstrap intervals, and the share of runs that isolate
the ring (the procedure; Clopper-Pearson); per comparison (robotic vs manual on a task,
navigator vs operator on a ring), the paired difference over the seeds both arms ran. Where the
paper gives a number, the row agrees only when it lies inside the interval; a comparison only
when the interval of the difference excludes 0 on the paper's side ("similar": holds 0), and
both arms' median runs touched every target (the report's rule: faster by giving up is not faster).
"""

from __future__ import annotations

import json
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

from ballchain.experiments._result import Result, optional
from ballchain.infrastructure.errors import UserInputError, short_repr

DEFAULT_SEEDS = 20
"""The seeds of the study by default (issue 43: at least 20 for an interval that means something;
``reproduce`` runs fewer and says so)."""
ARMS = {  # name -> (experiment, task/ring, navigator)
    "robotic_left": ("teleop", "left", None),
    "robotic_right": ("teleop", "right", None),
    "manual_left": ("manual", "left", None),
    "manual_right": ("manual", "right", None),
    "procedure_left_auto": ("procedure", "left", "auto"),
    "procedure_left_operator": ("procedure", "left", "operator"),
    "procedure_right_auto": ("procedure", "right", "auto"),
    "procedure_right_operator": ("procedure", "right", "operator"),
}
COMPARISONS = (("robotic_left", "manual_left"), ("robotic_right", "manual_right"),
               ("procedure_left_auto", "procedure_left_operator"),
               ("procedure_right_auto", "procedure_right_operator"))
"""Paired comparisons (a - b over the seeds both ran)."""
WORLDS = ("none", "literature")
"""The procedure's world (``procedure.run``'s ``world``): none (the model's own numbers) or literature
(perturbations at published magnitudes, drawn from each seed); the teleoperation arms ignore it."""
RUNS_FOLDER = "runs"
FIRST_COLUMNS = ("arm", "seed", "experiment_kind", "task", "navigator", "targets", "touched", "total_time_s")


@dataclass
class TrialsResult(Result):
    """What ``run`` returns.

    Attributes:
        rows: one per (arm, seed), in arm then seed order: {arm, seed, experiment_kind, task,
            navigator, targets, touched (reached), total_time_s, accuracy_median_mm (teleop,
            manual), in_window_fraction, estimate_mean_abs_error_gf, isolated, ring_gaps
            (procedure), wall_time_s, cpu_time_s, worker, error}.
        intervals: one per arm and quantity, and per comparison (``summarize``).
        settings: {arms, seeds, targets, executor, ran, skipped, failed, wall_time_s}.
        files: {table_parquet, table_csv, json, runs} (with ``out``).
    """

    rows: list
    intervals: list
    settings: dict
    files: dict | None = optional()


def check_inputs(arms, seeds, targets, world: str = "none") -> tuple[tuple[str, ...], tuple[int, ...]]:
    """The arms and seeds as tuples; raises UserInputError naming the argument, its value and what is allowed."""
    from ballchain.experiments.teleop import check_seeds  # lazy: teleop imports pydrake (a second)

    if isinstance(arms, str) or not hasattr(arms, "__iter__"):
        raise UserInputError(f"arms must be a list of {sorted(ARMS)}, got {short_repr(arms)}")
    arms = tuple(arms)
    bad = [a for a in arms if a not in ARMS]
    if not arms or bad or len(set(arms)) != len(arms):
        raise UserInputError(f"arms must be a non-empty list of distinct arms among {', '.join(ARMS)}, "
                             f"got {short_repr(list(arms))}")
    seeds = tuple(check_seeds(seeds))
    if world not in WORLDS:
        raise UserInputError(f"world must be one of {WORLDS}, got {short_repr(world)}")
    if targets is not None and (isinstance(targets, bool) or not isinstance(targets, int) or targets < 1):
        raise UserInputError(f"targets must be a positive integer (the first N of each task), got {short_repr(targets)}")
    return arms, seeds


def run_arm(arm: str, seed: int, targets: int | None = None, plans=None, world: str = "none") -> dict:
    """One run of an arm with a seed, as a table row (an exception in the run becomes its ``error``).

    BLAS pinned to one thread, as the sweep's points: the matrices are small and several worker
    processes share the cores.
    """
    from threadpoolctl import threadpool_limits

    from ballchain.executor import _worker_name
    from ballchain.infrastructure.errors import caused_by_interrupt

    kind, task, navigator = ARMS[arm]
    row = {"key": f"{arm}/seed{seed}", "experiment": "trials", "arm": arm, "seed": int(seed),
           "experiment_kind": kind, "task": task, "navigator": navigator}
    start, cpu = time.perf_counter(), time.process_time()
    error = None
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            row.update(_run(kind, task, navigator, int(seed), targets, plans, world))
    except Exception as err:  # noqa: BLE001: a failed run is a row with the reason
        if caused_by_interrupt(err):
            raise KeyboardInterrupt from err
        error = f"{type(err).__name__}: {err}"
    row.update(wall_time_s=round(time.perf_counter() - start, 3), cpu_time_s=round(time.process_time() - cpu, 3),
               worker=_worker_name(), error=error)
    return row


def _run(kind: str, task: str, navigator: str | None, seed: int, targets, plans, world: str = "none") -> dict:
    if kind == "procedure":
        from ballchain.experiments import procedure

        # The perfect world is procedure.run's default: named only when another is asked for.
        kwargs = {} if world == "none" else {"world": world}
        s = procedure.run(task, navigator, seed=seed, targets=targets, plans=plans, progress=False, **kwargs).summary
        return {"targets": s["targets"], "touched": s["reached"], "total_time_s": s["total_time_s"],
                "in_window_fraction": s.get("in_window_fraction"),
                "estimate_mean_abs_error_gf": s.get("estimate_mean_abs_error_gf"),
                "isolated": s.get("isolated"), "ring_gaps": s.get("ring_gaps"), "failure": s.get("failure"),
                "not_planned": len(s.get("not_planned") or ())}
    if kind == "teleop":
        from ballchain.experiments import teleop

        s = teleop.run(task=task, mapping="world", targets=targets, progress=False, seed=seed).summary
    else:
        from ballchain.experiments import manual_catheter

        s = manual_catheter.run(task=task, targets=targets, seed=seed).summary
    return {"targets": s.targets, "touched": s.touched, "total_time_s": s.total_time_s,
            "accuracy_median_mm": s.median_accuracy_mm, "failure": s.failure}


def run_file(out: Path, arm: str, seed: int) -> Path:
    return Path(out) / RUNS_FOLDER / f"{arm}_seed{seed}.json"


def _done(out: Path | None, arm: str, seed: int, targets, world: str) -> dict | None:
    """The earlier row of (arm, seed) in ``out`` when it finished without error with the same targets and world."""
    if out is None:
        return None
    path = run_file(out, arm, seed)
    try:
        if path.stat().st_size > 1_000_000:  # a row is a few hundred bytes: not ours
            return None
        row = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    ok = isinstance(row, dict) and row.get("arm") == arm and row.get("seed") == seed and row.get("error") is None
    return row if ok and row.get("asked_targets") == targets and row.get("world", "none") == world else None


def run(arms=tuple(ARMS), seeds=range(DEFAULT_SEEDS), *, targets: int | None = None, world: str = "none",
        out: Path | None = None, workers: int | None = None, scheduler: str | None = None, client=None,
        progress: bool = True) -> TrialsResult:
    """Run every (arm, seed) not already done in ``out`` on the executor; the table and the intervals.

    Args:
        arms: among ``ARMS``.
        seeds: distinct seeds (0..2**32-1), the same for every arm (paired comparisons).
        targets: only the first N targets of each task or ring (None: whole tasks).
        world: the procedure arms' world, one of ``WORLDS`` (the other arms ignore it).
        out: a folder: each run's row as ``runs/<arm>_seed<seed>.json`` as it finishes, skipped on
            a rerun; at the end ``table.parquet``, ``table.csv`` and ``trials.json``.
        workers: LocalCluster worker processes (None: one per core); 0: this process, serially.
        scheduler: the address of an existing Dask scheduler (tcp://host:8786).
        client: an existing ``distributed.Client``.
        progress: a progress bar over the runs (stderr).

    Returns:
        A ``TrialsResult``.

    Example:
        Two seeds of the cheapest arm, the first target of Task II, in this process::

            >>> from ballchain.experiments import trials
            >>> r = trials.run(["robotic_right"], [1, 2], targets=1, workers=0, progress=False)  # doctest: +SKIP
            >>> [x["n"] for x in r.intervals if x["quantity"] == "touched"]  # doctest: +SKIP
            [2]
    """
    from tqdm import tqdm

    from ballchain.executor import Executor, _check_executor
    from ballchain.infrastructure.safe_files import check_output_dir, write_json

    arms, seeds = check_inputs(arms, seeds, targets, world)
    _check_executor(scheduler, workers, None)
    if out is not None:
        out = check_output_dir(out, "--out")
        (out / RUNS_FOLDER).mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    rows = {(a, s): _done(out, a, s, targets, world) for a in arms for s in seeds}
    # Seed by seed: a study stopped early has whole seeds of every arm (paired).
    todo = [(a, s) for s in seeds for a in arms if rows[(a, s)] is None]
    skipped = len(rows) - len(todo)

    def finish(row: dict) -> None:
        row["asked_targets"], row["world"] = targets, world
        rows[(row["arm"], row["seed"])] = row
        if out is not None:
            write_json(run_file(out, row["arm"], row["seed"]), row)
        bar.update(1)

    bar = tqdm(total=len(rows), initial=skipped, desc="trials", unit="run", disable=not progress)
    rings = sorted({ARMS[a][1] for a, _ in todo if ARMS[a][2] == "auto"})
    # Nothing left to run: no cluster to start.
    with Executor(scheduler=scheduler if todo else None, workers=workers if todo else 0,
                  client=client if todo else None) as ex:
        description = ex.description if todo else "nothing to run"
        if ex.client is None:
            plans = {r: _plan(r, targets) for r in rings}
            for a, s in todo:
                bar.set_postfix_str(f"{a} seed {s}")
                finish(run_arm(a, s, targets, plans.get(ARMS[a][1]) if ARMS[a][2] == "auto" else None, world))
        else:
            from distributed import as_completed  # distributed only on a cluster

            plans = {r: ex.client.submit(_plan, r, targets, pure=False) for r in rings}
            futures = [ex.client.submit(run_arm, a, s, targets, plans.get(ARMS[a][1]) if ARMS[a][2] == "auto"
                                        else None, world, pure=False) for a, s in todo]
            for future in as_completed(futures):
                if future.status == "error":
                    a, s = todo[futures.index(future)]
                    exc = future.exception()
                    finish({"key": f"{a}/seed{s}", "experiment": "trials", "arm": a, "seed": s,
                            "error": f"{type(exc).__name__}: {exc}"})
                else:
                    finish(future.result())
    bar.close()
    table = [rows[(a, s)] for a in arms for s in seeds]
    result = TrialsResult(rows=table, intervals=summarize(table),
                          settings={"arms": list(arms), "seeds": list(seeds), "targets": targets, "world": world,
                                    "executor": description, "ran": len(todo), "skipped": skipped,
                                    "failed": sum(1 for r in table if r.get("error")),
                                    "wall_time_s": round(time.perf_counter() - start, 2)})
    if out is not None:
        from ballchain.sweep.table import TABLE_CSV, TABLE_PARQUET, write_table

        write_table(out, table, FIRST_COLUMNS)
        result.files = {"table_parquet": str(out / TABLE_PARQUET), "table_csv": str(out / TABLE_CSV),
                        "json": str(out / "trials.json"), "runs": str(out / RUNS_FOLDER)}
        write_json(out / "trials.json", result)
    return result


def _plan(ring: str, targets):
    """The autonomous navigator's plans for a ring (``procedure.plan_ring``), made once for every seed."""
    from ballchain.experiments import procedure

    return procedure.plan_ring(ring, targets=targets)


def paper_values(arm: str) -> dict:
    """The paper's numbers for an arm's quantities ({} beyond the paper: the procedure)."""
    from ballchain.drake_models import paper
    from ballchain.experiments.manual_catheter import PAPER_COMPARISON

    kind, task, _ = ARMS[arm]
    if kind == "procedure":
        return {}
    device = "robotic" if kind == "teleop" else "manual"
    return {"touched": paper.TELEOP_TASKS[task]["targets"], "total_time_s": PAPER_COMPARISON[task][f"{device}_s"]}


def summarize(rows: list[dict]) -> list[dict]:
    """The intervals of every arm's quantities and every comparison whose arms both ran (module docstring).

    Each entry: {row, arm or comparison, quantity, paper, verdict (True/False/None), and the
    interval's fields (statistic, value, lo, hi, n, confidence, method, paired, values)}.
    """
    from ballchain.intervals import agrees, interval, paired_interval, proportion_interval, side_agrees

    ok = [r for r in rows if not r.get("error")]
    by_arm: dict[str, dict[int, dict]] = {}
    for r in ok:
        by_arm.setdefault(r["arm"], {})[r["seed"]] = r
    found = []
    for arm, runs in by_arm.items():
        whole = all(r.get("asked_targets") is None for r in runs.values())
        paper = paper_values(arm) if whole else {}
        for quantity in ("touched", "total_time_s"):
            values = [r[quantity] for r in runs.values() if r.get(quantity) is not None]
            if values:
                iv = interval(values)
                found.append({"row": f"{arm}: {quantity}", "arm": arm, "quantity": quantity,
                              "paper": paper.get(quantity), "verdict": agrees(paper.get(quantity), iv), **iv.to_dict()})
        isolated = [bool(r["isolated"]) for r in runs.values() if r.get("isolated") is not None]
        if isolated:
            iv = proportion_interval(sum(isolated), len(isolated))
            found.append({"row": f"{arm}: ring isolated", "arm": arm, "quantity": "isolated", "paper": None,
                          "verdict": None, **iv.to_dict()})
    for a, b in COMPARISONS:
        if a not in by_arm or b not in by_arm:
            continue
        seeds = sorted(set(by_arm[a]) & set(by_arm[b]))
        whole = all(by_arm[x][s].get("asked_targets") is None for x in (a, b) for s in seeds)
        for quantity in ("touched", "total_time_s"):
            pairs = [(by_arm[a][s].get(quantity), by_arm[b][s].get(quantity)) for s in seeds]
            pairs = [p for p in pairs if None not in p]
            if not pairs:
                continue
            iv = paired_interval([p[0] for p in pairs], [p[1] for p in pairs])
            pa, pb = paper_values(a).get(quantity), paper_values(b).get(quantity)
            claim = None
            if whole and quantity == "total_time_s" and pa is not None and pb is not None:
                claim = "similar" if pa == pb else ("lower" if pa < pb else "higher")
            # As the report's rule: a device whose median run missed targets does not agree (faster by giving up).
            every = _all_touched(by_arm[a]) and _all_touched(by_arm[b])
            found.append({"row": f"{a} - {b}: {quantity}", "comparison": [a, b], "quantity": quantity,
                          "paper": None if claim is None else pa - pb, "claim": claim,
                          "verdict": None if claim is None else every and side_agrees(iv, claim), **iv.to_dict()})
    return found


def _all_touched(runs: dict) -> bool:
    """Whether an arm's median run touched (reached) every target asked for."""
    return statistics.median([r["touched"] for r in runs.values()]) == next(iter(runs.values()))["targets"]
