"""Teleoperation tasks (paper Sec. VI-B): a simulated operator touches the ablation targets in order.

Task "left" is the paper's Task I (the 20 targets around the left veins), "right" Task II (the 18
around the right veins). The station is the paper's teleoperation set-up (scenario
``teleop_right_unit``: the 16-ball chain in the procedural atrium, one rotating unit 10 cm beyond
the right carina, the stepper feeder), with the joystick and the feeder moved by
``systems.simulated_operator.SimulatedOperator`` instead of a script. Two joystick mappings:
"world" (the paper's: stick axes = magnet angular velocity about world x, y, z; the operator uses
all three axes) and "catheter" (the catheter-frame mapping, ``TeleoperationMapper(frame="tip")``:
axes 0/1 swing the field at the tip about the tip frame's z and -y; the operator uses those two).
Both at the unit's ``teleop_omega_max`` (0.5 rad/s), with the feeder.

A target counts as touched when the tip ball touches it within its 5 mm circle
(``target_contact.targets_touched``); per target the operator records the time it spent on it
and the accuracy: the distance from the tip ball's wall-side point to the target's centre, and for
a missed one the reason (``TargetRecord.reason``: jammed chain, out of reach, confused, timeout).

The chain is the quasi-static engine's (``engine: statics``, ``DEFAULT_ENGINE``: the equilibrium
with the atrium's wall every 50 ms; a whole task in seconds) unless the overrides name the engine
(``{engine: plant}``: the MultibodyPlant, minutes per task). ``run_seeds`` runs the tasks over
several operator seeds (the hand's tremor) and tabulates the spread.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from ballchain.infrastructure.errors import UserInputError
from ballchain.experiments._result import Result, optional

from ballchain.drake_models import paper
# The station handed over (teleop_station.py) and the live browser session (live_session.py),
# re-exported here.
from ballchain.experiments.teleop_station import (DEFAULT_ENGINE, MAPPINGS, SCENARIO,  # noqa: F401
                                                  hand_over, handed_over_engine, load_for_hand_over,
                                                  refuse_replaced)
from ballchain.experiments.live_session import (LIVE_CHUNK, LIVE_KEYS_ANCHOR, LIVE_PANEL_PERIOD,  # noqa: F401
                                                LIVE_POLL, LIVE_SCENARIOS, LIVE_STATUS_ANCHOR, LIVE_STATUS_PERIOD,
                                                MAX_LIVE_RATE, LiveResult, LiveSession, build_live,
                                                check_live_inputs, live_scenario_for, run_live)

TASKS = ("left", "right")
PAPER = paper.TELEOP_TASKS
REPLAY_PERIOD = 0.1  # [s] Meshcat replay frames (unless the overrides set visualization.publish_period)
# The plant at a 4 ms quasi-static step (same damping): replaying 15 s of an operator's recorded
# commands (68 mm of tip travel, sliding and pressing on the wall), the tip path stayed within
# 0.28 mm of the default 1 ms step's (0.09 mm at 2 ms), 3.2 times faster (real-time factor 0.23 ->
# 0.73); 8 ms breaks the chain apart. Closed-loop runs are chaotic: the operator's per-target times
# differ between steps as between any two runs, not systematically.
FAST = "{engine: plant, time_step: 0.004}"
MAX_SEED = 2**32 - 1
REPRODUCE_SEEDS = 5  # operator seeds of reproduce's seed spread besides seed 0 (a whole task takes seconds)


@dataclass
class TeleopSummary(Result):
    """Totals over a run's targets (``summarize``; times in s of simulated time, mm).

    Attributes:
        touched, targets: targets touched, and asked for.
        total_time_s: every target's time, touched or given up; median_time_s: the median over
            the touched ones (None: none touched).
        median_accuracy_mm, max_accuracy_mm: tip contact point to target centre, over the touched.
        missed: the targets not touched; missed_reasons: {target: reason}.
        struggled: missed, or more than twice the median time.
        sim_time_s: simulated time; realtime_factor: simulated time over wall_time_s (the
            simulation loop's wall time, Simulator Initialize + AdvanceTo, the build not counted).
        failure: the watchdog's message if it stopped the run, else None.
        build_time_s: the station's build [s]; realtime_factor_cpu: on the loop's process CPU
            time; rim_sinkings, rim_sinking_max_mm: balls tolerated sinking at a vein's rim (set by
            ``run``).
    """

    touched: int
    targets: int
    total_time_s: float
    median_time_s: float | None
    median_accuracy_mm: float | None
    max_accuracy_mm: float | None
    missed: list
    missed_reasons: dict
    struggled: list
    sim_time_s: float
    realtime_factor: float | None
    wall_time_s: float
    failure: str | None
    build_time_s: float | None = None
    realtime_factor_cpu: float | None = None
    rim_sinkings: int | None = None
    rim_sinking_max_mm: float | None = None


@dataclass
class TeleopResult(Result):
    """What ``run`` returns: one simulated operator doing one task with one mapping.

    Attributes:
        task: "left" or "right"; mapping: "world" or "catheter".
        rows: one per target: {target, touched, time_s (spent on it), t_touch_s, accuracy_mm (tip
            contact point to target centre), relearns (re-probing wiggles), bursts (feeding /
            retraction bursts), reason (a missed target's: "chain jammed", "out of reach",
            "confused", "timeout", "not reached" (the run ended first), else None), closest_mm}.
        summary: the totals (``TeleopSummary``).
        paper: the paper's operator on the task ({human_time_s, targets, ...}).
        settings: {engine, seed, overrides, statics_period_s, n_balls, time_step_s,
            teleop_omega_max_rad_s, operator_period_s, reaction_s, timeout_s, axes, time_limit_s}.
        html: the Meshcat replay written (only with ``html``).
        anatomy: the anatomy file's name, side, targets and magnets (only with ``anatomy``,
            ``Anatomy.describe``); task is then None (every target) or the names' prefix, and
            paper None unless it is the procedural atrium.
    """

    task: str | None
    mapping: str
    rows: list
    summary: TeleopSummary
    paper: dict | None
    settings: dict
    html: str | None = optional()
    anatomy: dict | None = optional()


@dataclass
class TeleopSeedsResult(Result):
    """What ``run_seeds`` returns.

    Attributes:
        table: one ``aggregate_seeds`` row per (task, mapping) (the columns of ``SEED_FIELDS``).
        runs: one per run: {task, mapping, seed, summary, rows} (``TeleopResult``'s parts).
        settings: {seeds, targets, overrides, engine}.
        files: {"csv", "json"}: the paths written (only with ``out``).
    """

    table: list
    runs: list
    settings: dict
    files: dict | None = optional()


def check_seed(seed, what: str = "seed") -> int:
    """The operator's seed (its hand's tremor) as an int; raises UserInputError unless it is an
    integer in 0..2**32-1."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= MAX_SEED:
        raise UserInputError(f"{what} must be an integer in 0..{MAX_SEED} (the operator's tremor), got {seed!r}")
    return int(seed)


def check_inputs(task: str | None, mapping: str, targets: int | None, n_balls: int | None,
                 time_limit: float | None, seed: int = 0, anatomy: bool = False) -> None:
    """Raises UserInputError with a clear message on bad input (with an anatomy file, ``task``
    is a prefix of its target names, or None for all)."""
    check_seed(seed)
    if task not in TASKS and not (anatomy and (task is None or isinstance(task, str))):
        raise UserInputError(f"task must be one of {TASKS} ('left': Task I, 'right': Task II), got {task!r}")
    if mapping not in MAPPINGS:
        raise UserInputError(f"mapping must be one of {tuple(MAPPINGS)}, got {mapping!r}")
    if targets is not None and (isinstance(targets, bool) or not isinstance(targets, (int, np.integer))
                                or targets < 1):
        raise UserInputError(f"targets must be a positive number of targets (the first N), got {targets!r}")
    if n_balls is not None and (isinstance(n_balls, bool) or not isinstance(n_balls, (int, np.integer))
                                or not 3 <= n_balls <= 64):
        raise UserInputError(f"balls must be an integer in 3..64 (ball 1 stays in the sheath), got {n_balls!r}")
    from ballchain.systems.chain_scenario import MAX_DURATION

    if time_limit is not None and not 0 < time_limit <= MAX_DURATION:  # NaN fails too
        raise UserInputError(f"time_limit must be in (0, {MAX_DURATION:g}] s of simulated time, got {time_limit}")


def _label(task: str | None, anatomy) -> str:
    """What the progress bar calls the run: the task, or the anatomy file's name (and its task)."""
    if anatomy is None:
        return str(task)
    name = anatomy.path.stem
    return name if task is None else f"{name} {task}"


def scenario_for(mapping: str, n_balls: int | None = None, overrides: str | None = None, anatomy=None):
    """The paper's teleoperation station with the stick and the feeder left to an operator; on
    a loaded ``anatomy`` (``drake_models.anatomy.Anatomy``) its unit stands at the file's first magnet.

    The engine is ``DEFAULT_ENGINE`` (the quasi-static engine) unless ``overrides`` name the
    engine, or a mode other than quasi-static (then the plant: the only one for dynamics); the
    overrides' other fields apply either way.
    """
    from ballchain.systems.chain_scenario import parse_overrides

    scenario = load_for_hand_over(SCENARIO, overrides)
    if anatomy is not None:
        from ballchain.systems.station import apply_anatomy

        apply_anatomy(scenario, anatomy, units=scenario.units[:1])
    return hand_over(scenario, mapping, n_balls, parse_overrides(overrides), units=scenario.units[:1])


def command_period(scenario, period: float) -> None:
    """The feeder's command comes from a system's periodic updates (an operator's, a navigator's
    looks every ``period`` [s]): the feeder steps in batches at them
    (``insertion.feeder_command_period``), when the period is a whole number of its 2 ms steps
    (else it steps on its own, as for any command)."""
    from ballchain.systems.feeder import FeederSpec, batch_steps

    ins = scenario.insertion
    if not (ins.feeder and ins.feeder_command == "external"):
        return
    try:
        batch_steps(period, FeederSpec().update_period)
    except UserInputError:
        return
    if period <= 1.0:
        ins.feeder_command_period = float(period)


def run(task: str = "left", mapping: str = "world", targets: int | None = None, html: Path | None = None,
        progress: bool = True, time_limit: float | None = None, n_balls: int | None = None,
        overrides: str | None = None, operator=None, heart=None, seed: int = 0, anatomy=None,
        log_path: bool = False) -> TeleopResult:
    """Simulate the operator doing a task with a mapping.

    Args:
        task: "left" (Task I) or "right" (Task II); with ``anatomy``, only its targets named
            "{task}_..." (None: all of them, in file order).
        mapping: "world" (the paper's) or "catheter".
        targets: only the first N targets (None: all).
        html: write a Meshcat replay (self-contained HTML) here.
        progress: a tqdm progress bar on simulated time.
        time_limit: simulated-time limit [s]; default: every target's timeout plus 5 s (the
            operator gives up on a target after its timeout, so the run ends before).
        n_balls: chain length (default: the scenario's 16).
        overrides: inline YAML overrides of the scenario (e.g. "{engine: plant}"); the engine is
            the quasi-static one unless they name another (``scenario_for``).
        operator: OperatorParams (default: OperatorParams() with the mapping's axes and ``seed``).
        heart: a prebuilt LeftAtrium to reuse.
        seed: the operator's seed (its hand's tremor), 0..2**32-1; ignored when ``operator`` is given.
        anatomy: an anatomy file (``drake_models.anatomy``; its surface, targets, sheath, first
            magnet unit) instead of the procedural atrium's Task I or II.
        log_path: also return the tip's path and the operator's commands at its looks, in
            ``settings["path"]`` ({t, tip (k, 3) [m], stick (k, 3), feed (k,) [m/s]}).

    Returns:
        A ``TeleopResult`` (``html`` set when the replay was written).
    """
    from dataclasses import replace

    from ballchain.systems.chain_scenario import parse_overrides
    from ballchain.systems.chain_simulation import (ChainMonitor, MakeStation, after_updates, atrium_for,
                                                    near_ostium_rim, run_station)
    from ballchain.systems.simulated_operator import OperatorParams, SimulatedOperator
    from ballchain.systems.target_contact import heart_targets

    check_inputs(task, mapping, targets, n_balls, time_limit, seed, anatomy=anatomy is not None)
    from ballchain.infrastructure.arg_checks import require_type
    from ballchain.drake_models.atrium import Atrium

    if operator is not None:
        require_type(operator, OperatorParams, "teleop.run operator", "an OperatorParams or None")
    if heart is not None:
        require_type(heart, Atrium, "teleop.run heart", "an atrium (LeftAtrium, UserAtrium) or None")
    if html is not None:  # before the run: an unwritable replay path must not cost the results
        from ballchain.infrastructure.safe_files import check_output_file

        check_output_file(html, "--html")
    if anatomy is not None:
        from ballchain.experiments.planner import anatomy_targets

        anatomy, task, _ = anatomy_targets(anatomy, task)
        heart = anatomy.atrium()
    scenario = scenario_for(mapping, n_balls, overrides, anatomy)
    if "publish_period" not in parse_overrides(overrides).get("visualization", {}):
        scenario.visualization.publish_period = REPLAY_PERIOD  # a task lasts minutes: keep the replay small
    heart = heart or atrium_for(scenario)
    task_names = [n for n in heart_targets(heart)[0] if task is None or n.startswith(f"{task}_")]
    n_targets = len(task_names) if targets is None else min(int(targets), len(task_names))
    params = operator or OperatorParams(axes=(0, 1, 2) if mapping == "world" else (0, 1), seed=int(seed))
    command_period(scenario, params.period)
    handles = {}

    def add_operator(builder, ports):
        names, p_WT, n_W, radius = ports.targets
        chosen = [i for i, n in enumerate(names) if task is None or n.startswith(f"{task}_")][:n_targets]
        cp = ports.device  # any device, through its model's interface
        # What the console shows besides the camera: the sheath exit, the feeder's readout.
        seen = replace(params, ball_radius=cp.tip_radius, target_radius=radius,
                       p_WE=tuple(cp.p_WE), initial_length=cp.initial_inserted_length,
                       max_length=cp.max_inserted_length(),
                       keep_out=vein_openings(heart))
        op = builder.AddSystem(SimulatedOperator(
            cp.tip_body_index, cp.tip_base_body_index, [names[i] for i in chosen], p_WT[chosen], n_W[chosen], seen))
        builder.Connect(ports.body_poses, op.get_body_poses_input_port())
        (joystick,) = ports.joystick_inputs.values()
        builder.Connect(op.GetOutputPort("joystick"), joystick)
        builder.Connect(op.GetOutputPort("v_insert_cmd"), ports.feeder_command_input)
        handles["operator"] = op
        if log_path:
            from pydrake.systems.primitives import LogVectorOutput

            handles["logs"] = [LogVectorOutput(port, builder, params.period) for port in (
                cp.get_ball_positions_output_port(), op.GetOutputPort("joystick"), op.GetOutputPort("v_insert_cmd"))]
        return {"operator": op}

    limit = time_limit if time_limit is not None else n_targets * params.timeout + params.start_time + 5.0
    meshcat = None
    if html is not None:
        from ballchain.infrastructure.safe_files import check_output_file
        from ballchain.systems.chain_simulation import replay_bytes, replay_meshcat

        check_output_file(html, "--html", expected_bytes=replay_bytes(scenario, limit))  # room for the replay

        meshcat = replay_meshcat()
    built = time.perf_counter()
    cd = MakeStation(scenario, meshcat=meshcat, heart=heart, add_systems=add_operator)
    op = handles["operator"]
    built = time.perf_counter() - built
    chain_monitor = ChainMonitor(cd, tolerate_sinking=lambda p: near_ostium_rim(heart, p))
    # The run ends when the operator has touched or given up every target.
    run = run_station(cd, duration=limit, monitor=chain_monitor,
                      stop=after_updates(lambda c: op.is_done(op.GetMyContextFromRoot(c)), op.params.period),
                      progress=f"teleop {_label(task, anatomy)}/{mapping}" if progress else None, progress_step=0.1,
                      html=html, meshcat=meshcat)
    rows = op.rows(op.GetMyContextFromRoot(run.context))
    summary = _run_summary(run, rows, built, chain_monitor)
    settings_path = _logged_path(handles["logs"], run.context) if log_path else {}
    return TeleopResult(
        task=task, mapping=mapping, rows=rows, summary=summary,
        paper=PAPER[task] if anatomy is None or anatomy.procedural else None,
        settings={"engine": scenario.engine.name, "seed": int(params.seed), "overrides": overrides,
                  "statics_period_s": scenario.engine.own_period(scenario),
                  "n_balls": scenario.n_balls, "time_step_s": scenario.effective_time_step,
                  "teleop_omega_max_rad_s": scenario.units[0].teleop_omega_max,
                  "operator_period_s": params.period, "reaction_s": params.period * params.reaction_steps,
                  "timeout_s": params.timeout, "axes": list(params.axes), "time_limit_s": limit, **settings_path},
        html=None if html is None else str(html), anatomy=None if anatomy is None else anatomy.describe())


def _run_summary(run, rows: list, built: float, chain_monitor) -> TeleopSummary:
    """The task's summary from the run (``run_station``'s outcome), the operator's rows, the
    station's build time [s] and the monitor's tolerated rim sinkings."""
    summary = summarize(rows, run.sim_time, run.wall_time, run.failure)
    summary.build_time_s = round(built, 2)
    # On a shared machine wall time counts the waits for a core: the loop's process CPU time too.
    summary.realtime_factor_cpu = round(run.sim_time / run.cpu_time, 4) if run.cpu_time > 0 else None
    sinkings = chain_monitor.tolerated_sinkings
    summary.rim_sinkings = len(sinkings)
    summary.rim_sinking_max_mm = round(max(e[2] for e in sinkings) * 1e3, 3) if sinkings else None
    return summary


def _logged_path(logs: list, context) -> dict:
    """``{"path": {t, tip (k, 3) [m], stick (k, 3), feed (k,) [m/s]}}`` from the run's three loggers."""
    balls, stick, feed = (log.FindLog(context) for log in logs)
    return {"path": {"t": balls.sample_times().tolist(), "tip": balls.data()[-3:].T.tolist(),
                     "stick": stick.data().T.tolist(), "feed": feed.data()[0].tolist()}}


def vein_openings(heart) -> tuple:
    """The ipsilateral vein pairs' openings as the operator sees them (``OperatorParams.keep_out``)."""
    ostia = list(heart.ostia)
    pairs = [(ostia[0], ostia[1]), (ostia[2], ostia[3])] if len(ostia) == 4 else [(o, o) for o in ostia]
    return tuple((a.p_HO, b.p_HO, 0.5 * a.diameter, 0.5 * b.diameter, a.axis_H, b.axis_H) for a, b in pairs)


def missed_reason(row: dict, failure: str | None = None) -> str:
    """A missed target's reason: the operator's (``TargetRecord.reason``), "simulation stopped"
    when the watchdog ended the run on it or before it, "time limit" when the run's time limit
    came first."""
    if failure is not None and row["reason"] in (None, "not reached"):
        return "simulation stopped"
    if row["reason"] is None:  # open when the run ended: the time limit
        return "time limit"
    return row["reason"]


def summarize(rows: list[dict], sim_time: float, wall: float, failure: str | None = None) -> TeleopSummary:
    """Totals over the targets: touched count, total and median times, accuracies, and why each
    missed target was missed.

    Args:
        rows: the operator's rows (``SimulatedOperator.rows``).
        sim_time: simulated time [s].
        wall: wall time of the simulation loop [s] (the real-time factor is sim_time / wall).
        failure: the watchdog's message, if it stopped the run.
    """
    touched = [r for r in rows if r["touched"]]
    times = [r["time_s"] for r in touched]
    accuracy = [r["accuracy_mm"] for r in touched]
    spent = [r["time_s"] for r in rows if r["time_s"] is not None]
    return TeleopSummary(
        touched=len(touched), targets=len(rows),
        total_time_s=round(float(sum(spent)), 3),
        median_time_s=round(float(np.median(times)), 3) if times else None,
        median_accuracy_mm=round(float(np.median(accuracy)), 3) if accuracy else None,
        max_accuracy_mm=round(float(np.max(accuracy)), 3) if accuracy else None,
        missed=[r["target"] for r in rows if not r["touched"]],
        missed_reasons={r["target"]: missed_reason(r, failure) for r in rows if not r["touched"]},
        struggled=[r["target"] for r in rows if r["time_s"] is not None and (
            not r["touched"] or (times and r["time_s"] > 2.0 * float(np.median(times))))],
        sim_time_s=round(sim_time, 3),
        realtime_factor=round(sim_time / wall, 4) if wall > 0 else None,
        wall_time_s=round(wall, 2),
        failure=failure,
    )


# ---------------------------------------------------------------------------- spread over seeds
SEED_FIELDS = ("task", "mapping", "runs", "seeds", "touched_min", "touched_median", "touched_max", "targets",
               "total_time_median_s", "total_time_min_s", "total_time_max_s", "per_target_time_median_s",
               "accuracy_median_mm", "realtime_factor_median", "paper_time_s", "missed_reasons")


def check_seeds(seeds) -> list[int]:
    """The seeds as a list of distinct ints (``check_seed`` each); raises UserInputError."""
    if isinstance(seeds, (int, np.integer)) and not isinstance(seeds, bool):
        raise UserInputError(f"seeds must be a list of seeds, got the number {seeds!r} (e.g. range({seeds}))")
    try:
        seeds = list(seeds)
    except TypeError:
        raise UserInputError(f"seeds must be a list of integers, got {seeds!r}") from None
    if not seeds:
        raise UserInputError("seeds must name at least one seed")
    seeds = [check_seed(v, "each seed") for v in seeds]
    if len(set(seeds)) != len(seeds):
        raise UserInputError(f"seeds must be distinct, got {seeds}")
    return seeds


def aggregate_seeds(task: str, mapping: str, results: list[TeleopResult]) -> dict:
    """One row of the seed table from the runs of a (task, mapping) (``run`` results).

    Touched: min / median / max over the runs; total time (every target's time, touched or
    not): median, min, max; per-target time: the median over the runs of each run's median over
    its touched targets; accuracy likewise; the missed targets' reasons counted over the runs.
    """
    s = [r.summary for r in results]
    touched = [x.touched for x in s]
    total = [x.total_time_s for x in s]
    per_target = [x.median_time_s for x in s if x.median_time_s is not None]
    accuracy = [x.median_accuracy_mm for x in s if x.median_accuracy_mm is not None]
    rtf = [x.realtime_factor for x in s if x.realtime_factor is not None]
    reasons: dict[str, int] = {}
    for x in s:
        for why in x.missed_reasons.values():
            reasons[why] = reasons.get(why, 0) + 1

    def med(values):
        return round(float(np.median(values)), 3) if values else None

    return {"task": task, "mapping": mapping, "runs": len(results),
            "seeds": [r.settings["seed"] for r in results],
            "touched_min": int(min(touched)), "touched_median": med(touched), "touched_max": int(max(touched)),
            "targets": s[0].targets,
            "total_time_median_s": med(total), "total_time_min_s": round(float(min(total)), 3),
            "total_time_max_s": round(float(max(total)), 3),
            "per_target_time_median_s": med(per_target), "accuracy_median_mm": med(accuracy),
            "realtime_factor_median": med(rtf), "paper_time_s": PAPER[task]["human_time_s"],
            "missed_reasons": "; ".join(f"{k}: {v}" for k, v in sorted(reasons.items())) or "-"}


def run_seeds(tasks=TASKS, mappings=tuple(MAPPINGS), seeds=range(5), *, targets: int | None = None,
              out: Path | None = None, progress: bool = True, overrides: str | None = None,
              n_balls: int | None = None, heart=None) -> TeleopSeedsResult:
    """The spread over operator seeds: every (task, mapping) run once per seed, serially.

    (``ballchain sweep`` runs the same study in parallel on Dask; this is the plain serial
    version that ``reproduce`` uses.)

    Args:
        tasks: among "left", "right".
        mappings: among "world", "catheter".
        seeds: the operator seeds (distinct integers, 0..2**32-1).
        targets: only the first N targets of each task (None: whole tasks).
        out: a folder: writes ``teleop_seeds.csv`` and ``teleop_seeds.json`` there (atomically).
        progress: a progress bar over the runs.
        overrides, n_balls: as ``run`` (the engine is the quasi-static one unless overridden).
        heart: a prebuilt atrium (default: built once for all runs).

    Returns:
        A ``TeleopSeedsResult`` (``files`` set with ``out``).
    """
    from tqdm import tqdm

    from ballchain.systems.chain_simulation import atrium_for

    tasks, mappings = tuple(tasks), tuple(mappings)
    for task in tasks:
        for mapping in mappings:
            check_inputs(task, mapping, targets, n_balls, None)
    if not tasks or not mappings:
        raise UserInputError("run_seeds needs at least one task and one mapping")
    seeds = check_seeds(seeds)
    files = None
    if out is not None:  # before the runs
        from ballchain.infrastructure.safe_files import check_output_dir

        out = check_output_dir(out, "out")
        files = {"csv": out / "teleop_seeds.csv", "json": out / "teleop_seeds.json"}
    heart = heart or atrium_for(scenario_for(mappings[0], n_balls, overrides))
    table, runs = [], []
    bar = tqdm(total=len(tasks) * len(mappings) * len(seeds), desc="teleop seeds", unit="run", disable=not progress)
    for task in tasks:
        for mapping in mappings:
            results = []
            for seed in seeds:
                bar.set_postfix_str(f"{task}/{mapping} seed {seed}")
                r = run(task=task, mapping=mapping, targets=targets, progress=False, n_balls=n_balls,
                        overrides=overrides, heart=heart, seed=seed)
                results.append(r)
                runs.append({"task": task, "mapping": mapping, "seed": seed, "summary": r.summary,
                             "rows": r.rows})
                bar.update(1)
            table.append(aggregate_seeds(task, mapping, results))
    bar.close()
    result = TeleopSeedsResult(table=table, runs=runs,
                               settings={"seeds": seeds, "targets": targets, "overrides": overrides,
                                         "engine": results[0].settings["engine"]})
    if files is not None:
        from ballchain.infrastructure.safe_files import write_csv, write_json

        write_csv(files["csv"], table, SEED_FIELDS)
        write_json(files["json"], result)
        result.files = {k: str(v) for k, v in files.items()}
    return result
