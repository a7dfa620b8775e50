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

TASKS = ("left", "right")
MAPPINGS = {"world": "world", "catheter": "tip"}  # user-facing name -> TeleoperationMapper frame
PAPER = paper.TELEOP_TASKS
SCENARIO = "teleop_right_unit"
REPLAY_PERIOD = 0.1  # [s] Meshcat replay frames (unless the overrides set visualization.publish_period)
# The station's engine unless the overrides say otherwise: the quasi-static engine
# (``systems/quasi_static_engine.py``: the chain's equilibrium with the atrium's wall every 50 ms),
# whole tasks in seconds. ``--set '{engine: plant}'`` runs the MultibodyPlant (minutes per task).
DEFAULT_ENGINE = "statics"
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


def handed_over_engine(mode: str, overrides: dict) -> str | None:
    """The engine ``hand_over`` gives a scenario of ``mode``: ``DEFAULT_ENGINE`` unless
    ``overrides`` (the parsed ``--set`` mapping) name one or the mode is not quasi-static (None:
    the scenario keeps its own)."""
    return DEFAULT_ENGINE if "engine" not in overrides and mode == "quasi-static" else None


def load_for_hand_over(name: str, overrides: str | None):
    """The named scenario with ``overrides`` applied, checked with the engine the hand-over will
    give it (``handed_over_engine``) rather than the file's: a field that needs the quasi-static
    engine (``wall_motion``) needs no ``engine: statics`` of its own, and one the run's engine
    would ignore is refused before the build.

    Raises:
        UserInputError: as ``chain_scenario.load_scenario``; overrides that leave no magnet unit
            (``units: []``: the operator steers one).
    """
    from ballchain.systems.chain_scenario import apply_overrides, load_scenario, parse_overrides

    changes = parse_overrides(overrides)
    scenario = load_scenario(name)
    engine = handed_over_engine(changes.get("mode", scenario.mode), changes)
    changes = changes if engine is None else {**changes, "engine": engine}
    scenario = apply_overrides(scenario, changes).validate() if changes else scenario
    if not scenario.units:
        raise UserInputError("--set: units is [], which leaves the station no magnet unit to steer; keep the "
                             "scenario's units (a list of mappings updates them: '{units: [{teleop_omega_max: "
                             "1.0}]}')")
    return scenario


def hand_over(scenario, mapping: str, n_balls: int | None, overrides: dict, units=None):
    """The station with the sticks of ``units`` (default: all) and the feeder left to an operator
    or a person: their scripted joysticks removed, the mapping set, the engine ``DEFAULT_ENGINE``
    unless ``overrides`` (the parsed ``--set`` mapping) name one or the mode is not quasi-static."""
    if n_balls is not None and "n_balls" in overrides:
        raise UserInputError(f"--balls {n_balls} and --set n_balls {overrides['n_balls']!r} both give the chain's "
                             "length: give one of them")
    refuse_replaced(scenario, overrides, mapping, scenario.units if units is None else units)
    engine = handed_over_engine(scenario.mode, overrides)
    if engine is not None:
        scenario.engine = engine
    if n_balls is not None:
        scenario.n_balls = n_balls
    for unit in scenario.units if units is None else units:
        unit.joystick = []
        unit.joystick_source = "external"
        unit.teleop_frame = MAPPINGS[mapping]
    ins = scenario.insertion
    ins.feeder, ins.feeder_command = True, "external"
    ins.final = ins.initial
    return scenario.validate()


def refuse_replaced(scenario, overrides: dict, mapping: str, handed) -> None:
    """Refuse the overrides that ``hand_over`` would replace without a word: a handed unit's
    scripted stick (``joystick_source``, ``joystick``: the operator cannot drive a script), its
    mapping (``teleop_frame``: ``--mapping``'s) and the feeder's own motion (``insertion``'s
    ``feeder``, ``feeder_command``, ``final``: the operator feeds the chain). ``scenario`` has the
    overrides applied (its ``units[i]`` is the override's ``units[i]``).

    Raises:
        UserInputError: naming the field, the value and what the run does instead.
    """
    from ballchain.infrastructure.errors import short_repr

    other = "catheter" if mapping == "world" else "world"
    for i, entry in enumerate(overrides.get("units") or []):
        if not isinstance(entry, dict) or i >= len(scenario.units) or not any(scenario.units[i] is u for u in handed):
            continue
        name = scenario.units[i].name
        stick = (f"the stick of unit {name!r} is the operator's (joystick_source: external), who cannot drive a "
                 "script (a scripted stick runs with `ballchain simulate`)")
        allowed = {"joystick_source": ("external", stick), "joystick": ([], stick),
                   "teleop_frame": (MAPPINGS[mapping], f"the mapping of unit {name!r} is --mapping {mapping}'s "
                                                       f"({MAPPINGS[mapping]!r}; --mapping {other} gives "
                                                       f"{MAPPINGS[other]!r})")}
        for key, (kept, why) in allowed.items():
            if key in entry and entry[key] != kept:
                raise UserInputError(f"--set units[{i}].{key}: {short_repr(entry[key])} would be ignored: {why}; "
                                     f"leave {key} out")
    insertion = overrides.get("insertion")
    if isinstance(insertion, dict):
        kept = {"feeder": True, "feeder_command": "external", "final": scenario.insertion.initial}
        for key, value in kept.items():
            if key in insertion and insertion[key] != value:
                raise UserInputError(f"--set insertion.{key}: {short_repr(insertion[key])} would be ignored: the "
                                     f"operator feeds the chain (feeder: true, feeder_command: external, the "
                                     f"insertion starting at insertion.initial); leave {key} out")


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
        settings={"engine": scenario.engine, "seed": int(params.seed), "overrides": overrides,
                  "statics_period_s": scenario.statics_period if scenario.engine == "statics" else None,
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


# ----------------------------------------------------------------------------------- live steering
@dataclass
class LiveResult(Result):
    """What ``run_live`` returns.

    Attributes:
        url: the Meshcat URL.
        ended: "quit", "duration" or "failure" (the watchdog stopped it with nobody watching); a
            live view a person watches pauses on a failure instead (see ``stops``).
        failure: the last watchdog message (None: none).
        stops: every watchdog message, in order, with the simulated time it came at
            [{t_s, reason}]; restarts: how often the person started over after one.
        sim_time_s, wall_time_s: simulated time since the last start and the wall time since the
            clock started (the first browser connected) [s]; realtime_factor: simulated time over
            wall time in the advances (pauses not counted); target_realtime_rate: the one asked for.
        wait_s: wall time spent waiting for a browser [s].
        targets_touched: the targets' names; n_targets: how many the station has.
        tip_wall_force_N: the wall's force on the tip ball at the end (3,) [N].
        settings: {mapping, units, n_balls, time_step_s, overrides}.
    """

    url: str
    ended: str
    failure: str | None
    stops: list
    restarts: int
    sim_time_s: float
    wall_time_s: float
    realtime_factor: float | None
    target_realtime_rate: float
    wait_s: float
    targets_touched: list
    n_targets: int
    tip_wall_force_N: list
    settings: dict


LIVE_SCENARIOS = {"one": SCENARIO, "two": "teleop_two_units"}  # --units: the right unit, or both
LIVE_CHUNK = 0.05  # [s] simulated time per advance: quit, Ctrl-C and the readouts between chunks
LIVE_STATUS_PERIOD = 2.0  # [s] wall time between console status lines
# [s] wall time between updates of the page's readout panel: each is a new picture the page
# decodes (a software-drawing browser under load took over 0.5 s to; at 1.5 s the pictures show).
LIVE_PANEL_PERIOD = 1.5
LIVE_POLL = 0.05  # [s] wall time between looks at Meshcat while waiting (a browser, a reset)
# Where the page's panels go (``TextPanel``: top-left corners, screen heights from the centre):
# the readouts top left, the key map bottom left, the heart in the middle of the screen.
LIVE_STATUS_ANCHOR, LIVE_KEYS_ANCHOR = (-0.7, 0.44), (-0.7, -0.34)


MAX_LIVE_RATE = 100.0  # a person steering at more than 100 times real time sees nothing of it


def check_live_inputs(mapping: str, units: str, n_balls: int | None, duration: float | None,
                      realtime_rate: float) -> None:
    """Raises UserInputError naming the flag on bad input for ``run_live``."""
    from ballchain.infrastructure.errors import UserInputError, short_repr
    from ballchain.systems.chain_scenario import MAX_DURATION

    if mapping not in MAPPINGS:
        raise UserInputError(f"--mapping must be one of {tuple(MAPPINGS)}, got {short_repr(mapping)}")
    if units not in LIVE_SCENARIOS:
        raise UserInputError(f"--units must be one of {tuple(LIVE_SCENARIOS)} (the right unit, or both), "
                             f"got {short_repr(units)}")
    if n_balls is not None and n_balls < 3:
        raise UserInputError(f"--balls must be >= 3 (ball 1 stays in the sheath), got {n_balls}")
    if duration is not None and not (np.isfinite(duration) and 0 < duration <= MAX_DURATION):
        raise UserInputError(f"--duration must be in (0, {MAX_DURATION:g}] s of simulated time, got {duration}")
    if not (np.isfinite(realtime_rate) and 0 <= realtime_rate <= MAX_LIVE_RATE):
        raise UserInputError(f"--realtime-rate must be in [0, {MAX_LIVE_RATE:g}] (0: as fast as possible), "
                             f"got {realtime_rate}")


def live_scenario_for(mapping: str, units: str = "one", n_balls: int | None = None, overrides: str | None = None,
                      anatomy=None):
    """The teleoperation station with every unit's stick and the feeder left to a person.

    Args:
        mapping: "world" or "catheter" (every unit).
        units: "one" (``teleop_right_unit``) or "two" (``teleop_two_units``: both sides).
        n_balls: chain length (default: the scenario's 16).
        overrides: inline YAML overrides of the scenario (``--set``), applied first. The engine is
            ``DEFAULT_ENGINE`` (the quasi-static engine: real time for 16 balls; the plant runs at
            about a fifth of it) unless they name one, e.g. ``{engine: plant}``.
        anatomy: a loaded ``Anatomy``: the station on it, the units at its magnets (in order).
    """
    from ballchain.infrastructure.errors import UserInputError
    from ballchain.systems.chain_scenario import parse_overrides

    try:
        scenario = load_for_hand_over(LIVE_SCENARIOS[units], overrides)
    except UserInputError:
        raise
    except ValueError as err:
        raise UserInputError(f"--set: {err}") from None
    if anatomy is not None:
        from ballchain.systems.station import apply_anatomy

        apply_anatomy(scenario, anatomy)
    return hand_over(scenario, mapping, n_balls, parse_overrides(overrides))


class LiveSession:
    """A station driven by ``MeshcatJoystick``, ready to be advanced (``build_live``).

    The run loop is the station's (``chain_simulation.StationRunner``, as ``run_station``'s): the
    scenario's simulator_config, the watchdog, the quit button as the stop condition, advanced
    in chunks, and started over after a stop (``restart``).

    Attributes:
        cd: the Station; ``cd.added["meshcat_joystick"]`` is the joystick system.
        runner: the StationRunner; simulator: its Simulator; root: its root context.
        meshcat: the Meshcat (localhost).
        joystick: the MeshcatJoystick.
        chain_monitor: the ChainMonitor (watchdog).
        status: the page's readout panel (``TextPanel``, set by ``run_live``), or None.
    """

    def __init__(self, cd, runner, meshcat, joystick):
        self.cd, self.runner, self.meshcat, self.joystick = cd, runner, meshcat, joystick
        self.status = None
        self.simulator, self.root, self.chain_monitor = runner.simulator, runner.context, runner.monitor

    def advance_to(self, t: float) -> str | None:
        """Advance the simulation to time t [s].

        Returns:
            None (reached t), "quit" (the person asked to quit) or the watchdog's failure message.
        """
        failure = self.runner.advance_to(t)
        if failure is None and self.runner.stopped:
            return "quit"
        return failure

    def restart(self) -> None:
        """Start over from the initial state (after the watchdog stopped the run)."""
        self.runner.restart()

    def touched(self) -> list[str]:
        tracker = self.cd.target_touches
        return [] if tracker is None else tracker.touched_names(tracker.GetMyContextFromRoot(self.root))

    def tip_force_N(self) -> np.ndarray:
        """The wall's force on the tip ball now [N] (as the overlay's orange arrow)."""
        overlays = self.cd.meshcat_overlays
        if overlays is None:
            return np.zeros(3)
        return overlays.tip_contact_force(overlays.GetMyContextFromRoot(self.root))[0]

    def ball_1_along_sheath(self) -> float:
        """Ball 1's centre along the sheath axis from the sheath exit [m]: the chain's actual
        insertion (the feeder's speed is its rate of change)."""
        chain = self.cd.chain
        p = chain.ball_positions(chain.system.GetMyContextFromRoot(self.root))
        return float((p[0] - chain.p_WE) @ chain.sheath_axis_W)

    def joystick_state(self) -> tuple[str, np.ndarray, float]:
        """(selected unit, stick axes (3,), feeder command [m/s]) as sent now."""
        j = self.joystick
        ctx = j.GetMyContextFromRoot(self.root)
        unit = j.selected_unit(ctx)
        return unit, j.get_joystick_output_port(unit).Eval(ctx), float(j.GetOutputPort("v_insert_cmd").Eval(ctx)[0])

    def clicks(self, action: str) -> float:
        """Clicks so far of the key bound to ``action`` (Meshcat's count; read while paused)."""
        return sum(self.meshcat.GetButtonClicks(k.label) for k in self.joystick.keys if k.action == action)


def build_live(*, mapping: str = "world", units: str = "one", n_balls: int | None = None,
               overrides: str | None = None, meshcat=None, heart=None, realtime_rate: float = 1.0,
               joystick_period: float = 0.02, anatomy=None) -> LiveSession:
    """Build the station with ``MeshcatJoystick`` driving every unit's stick and the feeder.

    Args:
        mapping, units, n_balls, overrides: as ``live_scenario_for``.
        meshcat: a Meshcat to use (default: a new one on localhost).
        heart: a prebuilt atrium to reuse.
        realtime_rate: the simulator's target real-time rate (0: as fast as possible); the
            scenario's simulator_config applies otherwise.
        joystick_period: how often the joystick reads Meshcat [s] (simulated time).
        anatomy: an anatomy file or a loaded ``Anatomy`` (its surface, targets, sheath, units at
            its magnets) instead of the procedural atrium.
    """
    from pydrake.geometry import Meshcat, MeshcatParams

    from ballchain.systems.chain_simulation import (ChainMonitor, MakeStation, StationRunner, atrium_for,
                                                    near_ostium_rim, without_stop_signals)
    from ballchain.systems.meshcat_joystick import MeshcatJoystick

    check_live_inputs(mapping, units, n_balls, None, realtime_rate)
    if anatomy is not None:
        from ballchain.drake_models.anatomy import Anatomy, load_anatomy

        anatomy = anatomy if isinstance(anatomy, Anatomy) else load_anatomy(anatomy)
        heart = anatomy.atrium()
    scenario = live_scenario_for(mapping, units, n_balls, overrides, anatomy)
    meshcat = meshcat if meshcat is not None else without_stop_signals(
        lambda: Meshcat(MeshcatParams(host="localhost")))
    heart = heart or atrium_for(scenario)

    def add_joystick(builder, ports):
        j = builder.AddSystem(MeshcatJoystick(meshcat, list(ports.joystick_inputs), period=joystick_period))
        for name, port in ports.joystick_inputs.items():
            builder.Connect(j.get_joystick_output_port(name), port)
        builder.Connect(j.GetOutputPort("v_insert_cmd"), ports.feeder_command_input)
        return {"meshcat_joystick": j}

    cd = MakeStation(scenario, meshcat=meshcat, heart=heart, add_systems=add_joystick)
    joystick = cd.added["meshcat_joystick"]
    chain_monitor = ChainMonitor(cd, tolerate_sinking=lambda p: near_ostium_rim(heart, p))
    # The quit button ends an advance (a termination).
    runner = StationRunner(cd, monitor=chain_monitor, realtime_rate=realtime_rate, restartable=True,
                           stop=lambda context: joystick.quit_requested(joystick.GetMyContextFromRoot(context)))
    return LiveSession(cd, runner, meshcat, joystick)


def _panel_lines(session, mapping: str, omega: float) -> list[str]:
    """The page's key-map panel: the mapping and every binding, in a few lines."""
    from ballchain.systems.meshcat_joystick import key_map_compact

    head = (f"world mapping: stick axes 0, 1, 2 turn the magnet about world x, y, z (up to {omega:g} rad/s)"
            if mapping == "world" else
            f"catheter mapping: axes 0, 1 swing the tip's field about its z, -y (up to {omega:g} rad/s)")
    return [head] + key_map_compact(session.joystick.keys)


def run_live(*, mapping: str = "world", units: str = "one", n_balls: int | None = None,
             overrides: str | None = None, duration: float | None = None, realtime_rate: float = 1.0,
             meshcat=None, heart=None, echo=print, status_period: float = LIVE_STATUS_PERIOD,
             wait_for_browser: bool = True, freeze_gc: bool = False, anatomy=None) -> LiveResult:
    """Let a person steer the chain live in Meshcat with a gamepad or the keyboard.

    Opens Meshcat on localhost (or uses ``meshcat``), prints its URL and the key map, waits for a
    browser to open the page (the simulated clock starts then), and runs the station in real
    time (``realtime_rate``) until the person quits (Escape, Start), Ctrl-C, or ``duration``
    simulated seconds have passed. When the station is slower than real time it runs as fast as
    it can. The page shows the key map and a readout panel (time, the real-time rate achieved,
    targets touched, the wall's force on the tip, the feeder's actual speed: ball 1's along the
    sheath). When the watchdog stops the run (a ball out of the heart, the chain broken, a
    failed solve) while a browser is connected, the view pauses with the reason on the page
    until the person starts over (R) or quits; with nobody connected the run ends as a failure.

    Args:
        mapping: "world" or "catheter".
        units: "one" (the right unit) or "two" (both; N or RB switches the stick between them).
        n_balls: chain length (default 16).
        overrides: inline YAML overrides of the scenario (``--set``), e.g. the engine.
        duration: simulated-time limit [s] (None: until the person quits).
        realtime_rate: target real-time rate (1: real time; 0: as fast as possible).
        meshcat: a Meshcat to use (default: a new one on localhost).
        heart: a prebuilt atrium to reuse.
        echo: where the URL, the key map and the status lines go (``print``).
        status_period: wall time between status lines [s].
        wait_for_browser: start the clock when the first browser connects (False: at once).
        freeze_gc: freeze the objects alive after the build for the session
            (``chain_simulation.frozen_gc``; the command line asks for it).
        anatomy: an anatomy file or a loaded ``Anatomy`` instead of the procedural atrium
            (``build_live``).

    Returns:
        A ``LiveResult``.

    Raises:
        KeyboardInterrupt: Ctrl-C (after the summary line and removing the buttons).
    """
    from ballchain.systems.chain_simulation import frozen_gc

    check_live_inputs(mapping, units, n_balls, duration, realtime_rate)
    session = build_live(mapping=mapping, units=units, n_balls=n_balls, overrides=overrides, meshcat=meshcat,
                         heart=heart, realtime_rate=realtime_rate, anatomy=anatomy)
    scenario = session.cd.scenario
    meshcat = session.meshcat
    tracker = session.cd.target_touches
    n_targets = 0 if tracker is None else len(tracker.names)
    unit_names = session.joystick.unit_names
    status = _announce_live(session, mapping, realtime_rate, duration, echo)

    ended, stops, restarts = "duration", [], 0
    limit = np.inf if duration is None else float(duration)
    waited = time.perf_counter()
    advancing, simulated = 0.0, 0.0  # wall and simulated time in the advances [s] (pauses not counted)
    start = time.perf_counter()
    try:
        if wait_for_browser and meshcat.GetNumActiveConnections() == 0:
            _wait_for_browser(meshcat, status, echo)
        waited = time.perf_counter() - waited
        start = time.perf_counter()
        readout = _LiveReadout(session, status, echo, n_targets, status_period, start)
        with frozen_gc(freeze_gc):
            while session.root.get_time() < limit - 1e-12:
                t0, sim0 = time.perf_counter(), session.root.get_time()
                reason = session.advance_to(min(sim0 + LIVE_CHUNK, limit))
                advancing += time.perf_counter() - t0
                simulated += session.root.get_time() - sim0
                if reason == "quit":
                    ended = "quit"
                    break
                if reason is not None:
                    t_stop = session.root.get_time()
                    stops.append({"t_s": round(t_stop, 4), "reason": reason})
                    echo(f"stopped at t = {t_stop:.2f} s: {reason}")
                    if meshcat.GetNumActiveConnections() == 0:
                        ended = "failure"
                        break
                    if _pause_until_choice(session, status, reason, echo) == "quit":
                        ended = "quit"
                        break
                    session.restart()
                    restarts += 1
                    echo("started over")
                    readout.start_over(time.perf_counter())
                    continue
                readout.maybe_show(time.perf_counter())
    except KeyboardInterrupt:
        _end_live(session, echo, "interrupted", stops, time.perf_counter() - start, n_targets)
        raise
    wall = time.perf_counter() - start
    touched = _end_live(session, echo, ended, stops, wall, n_targets)
    sim_time = session.root.get_time()
    rate = round(simulated / advancing, 4) if advancing > 0 else None
    return LiveResult(url=meshcat.web_url(), ended=ended, failure=stops[-1]["reason"] if stops else None,
                      stops=stops, restarts=restarts, sim_time_s=round(sim_time, 4), wall_time_s=round(wall, 3),
                      realtime_factor=rate, target_realtime_rate=realtime_rate, wait_s=round(waited, 3),
                      targets_touched=touched, n_targets=n_targets,
                      tip_wall_force_N=[round(float(v), 6) for v in session.tip_force_N()],
                      settings={"mapping": mapping, "units": unit_names, "n_balls": scenario.n_balls,
                                "time_step_s": scenario.effective_time_step, "overrides": overrides,
                                "anatomy": scenario.anatomy or None})


def _announce_live(session, mapping: str, realtime_rate: float, duration: float | None, echo):
    """The URL, the settings and the key map on the terminal; the key-map panel on the page.

    Returns the page's status panel (also kept as ``session.status``).
    """
    from ballchain.systems.meshcat_joystick import key_map_text
    from ballchain.systems.meshcat_overlays import TextPanel

    scenario, meshcat = session.cd.scenario, session.meshcat
    omega = scenario.units[0].teleop_omega_max
    echo(f"Meshcat: {meshcat.web_url()}  (open it in a browser on this machine)")
    echo(f"steering {', '.join(session.joystick.unit_names)} with the {mapping} mapping, {scenario.n_balls} balls, "
         f"time step {scenario.effective_time_step * 1e3:g} ms, target real-time rate {realtime_rate:g}"
         + (f", for {duration:g} s" if duration is not None else ", until you quit (Escape, Start or Ctrl-C)"))
    echo(_panel_lines(session, mapping, omega)[0])
    echo(key_map_text(session.joystick.keys))
    echo("the targets turn green when the tip touches them; the orange arrow is the wall's force on the tip")
    keys = TextPanel(meshcat, "keys", anchor=LIVE_KEYS_ANCHOR, width_px=1150)
    keys.show(_panel_lines(session, mapping, omega))
    keys.flush()
    status = session.status = TextPanel(meshcat, "status", anchor=LIVE_STATUS_ANCHOR, width_px=1150)
    return status


def _status_panel(status, lines: list[str], paused: bool = False) -> None:
    """The status panel's lines: white on dark grey, or yellow on red while paused."""
    status.show(lines, colour=(255, 235, 120) if paused else (255, 255, 255),
                background=(150, 20, 20) if paused else (20, 20, 20))


def _wait_for_browser(meshcat, status, echo) -> None:
    """Wait until a browser has the page open (the simulated clock starts then)."""
    echo("waiting for a browser to open the page (the clock starts then)")
    _status_panel(status, ["waiting for the page to connect"])
    status.flush()
    while meshcat.GetNumActiveConnections() == 0:
        time.sleep(LIVE_POLL)


def _pause_until_choice(session, status, reason: str, echo) -> str:
    """The watchdog's reason on the page until the person starts over or quits: "restart" or "quit"."""
    echo("paused: press R (or 'start over' in Meshcat's controls) to start over, Escape to quit")
    _status_panel(status, ["PAUSED: the watchdog stopped the run", *_wrap(reason, 80),
                           "R: start over from the beginning    Escape: quit"], paused=True)
    reset0, quit0 = session.clicks("reset"), session.clicks("quit")
    paused = time.perf_counter()
    while session.clicks("reset") == reset0 and session.clicks("quit") == quit0:
        if time.perf_counter() - paused > LIVE_PANEL_PERIOD:
            status.flush()  # the page has decoded the pause panel by now
            status.redraw()
            paused = time.perf_counter()
        time.sleep(LIVE_POLL)
    return "quit" if session.clicks("quit") != quit0 else "restart"


class _LiveReadout:
    """The live readout: the page's status panel every ``LIVE_PANEL_PERIOD`` and a status line every
    ``status_period`` of wall time, with rates measured since the last readout."""

    def __init__(self, session, status, echo, n_targets: int, status_period: float, now: float):
        self.session, self.status, self.echo = session, status, echo
        self.n_targets, self.status_period = n_targets, status_period
        self.start_over(now)

    def start_over(self, now: float) -> None:
        """Measure from ``now`` and the chain's start (at the session's start and after a restart)."""
        self.last_wall = self.last_panel = self.last_line = now
        self.last_sim, self.last_ball_1 = 0.0, self.session.ball_1_along_sheath()

    def maybe_show(self, now: float) -> None:
        """The panel and the status line, each when due."""
        from ballchain.drake_models.params import gram_force

        session, n_targets = self.session, self.n_targets
        panel_due = now - self.last_panel >= LIVE_PANEL_PERIOD
        line_due = now - self.last_line >= self.status_period
        if not (panel_due or line_due):
            return
        t = session.root.get_time()
        unit, stick, v_cmd = session.joystick_state()
        ball_1 = session.ball_1_along_sheath()
        # Measured since the last readout: the chain's actual insertion, not the command.
        v_ball_1 = (ball_1 - self.last_ball_1) / (t - self.last_sim) if t > self.last_sim else 0.0
        rate = (t - self.last_sim) / (now - self.last_wall)
        f_gf = gram_force(float(np.linalg.norm(session.tip_force_N())))
        touched = session.touched()
        if panel_due:
            _status_panel(self.status, [
                f"t = {t:.1f} s   real-time rate {rate:.2f}   {unit}",
                f"targets touched {len(touched)}/{n_targets}" + (f": {', '.join(touched[-4:])}" if touched else ""),
                f"tip force on the wall {f_gf:.1f} gf",
                f"feeder: ball 1 moves {v_ball_1 * 1e3:+.1f} mm/s (command {v_cmd * 1e3:+.1f} mm/s)"])
            session.meshcat.SetRealtimeRate(rate)
            self.last_panel = now
        if line_due:
            self.echo(f"t = {t:7.2f} s  real-time rate {rate:5.2f}  targets {len(touched)}/{n_targets}  "
                      f"tip force {f_gf:5.1f} gf  {unit} stick {np.round(stick, 2).tolist()}  "
                      f"feeder: ball 1 {v_ball_1 * 1e3:+.1f} mm/s (command {v_cmd * 1e3:+.1f})")
            self.last_line = now
        self.last_wall, self.last_sim, self.last_ball_1 = now, t, ball_1


def _wrap(text: str, width: int) -> list[str]:
    import textwrap

    return textwrap.wrap(text, width) or [""]


def _end_live(session, echo, ended: str, stops: list, wall: float, n_targets: int) -> list[str]:
    """The summary line; the buttons removed from the page and the panel says the session ended."""
    sim_time = session.root.get_time()
    touched = session.touched()
    failure = stops[-1]["reason"] if ended == "failure" else None
    echo(f"ended ({ended}{': ' + failure if failure else ''}) at t = {sim_time:.2f} s after {wall:.1f} s, "
         f"{len(touched)}/{n_targets} targets touched" + (f" ({', '.join(touched)})" if touched else "")
         + (f", {len(stops)} stop(s)" if stops else ""))
    session.joystick.remove_buttons()
    session.status.show([f"the session ended ({ended}) at t = {sim_time:.1f} s"])
    session.status.flush()
    return touched
