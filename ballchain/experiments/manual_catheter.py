"""The paper's comparison arm (Sec. V-C): the simulated operator does Task I or II with the manual
steerable catheter (``systems/catheter_station.py``) instead of the robotic chain.

The same operator model as the robotic teleoperation (``systems.simulated_operator``: it sees
only the tip, learns the input-to-tip mapping online, presses towards each target and gives up
after its timeout), its stick's two axes now on the catheter's handle (axis 0 turns it, axis 1
the knob) and its feeder command the hand's push and pull, within the hand's rate limits
(``HandParams``), with the windup strategy ``switch`` (the opposite tendon and back by half a
turn when the hand feels the shaft's torque reach its threshold, ``HandParams.torque_threshold``,
also at the F tendon's end) or ``keep`` (keep turning). The catheter's 3.5 mm distal electrode
touches a target with its whole surface (``drake_models.electrode``). The operator keeps at least the
catheter's starting length (20 mm) out of the sheath (``min_length``): with less out the knob
and the handle move the tip less (the 55 mm deflectable segment mostly in the sheath), and
without the floor its retraction bursts drew the catheter back to 0-5 mm, where it stayed for
the right ring's last five targets (seed 0). Per target the rows of the robotic task (time,
accuracy), and beside them the tip's path (for the smoothness) and the handle's twist.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from pydrake.systems.primitives import LogVectorOutput

from ballchain.infrastructure.arg_checks import require_type
from ballchain.drake_models.atrium import Atrium
from ballchain.infrastructure.errors import UserInputError
from ballchain.infrastructure.safe_files import check_output_file
from ballchain.drake_models.sheath import SteerableSheath
from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.experiments import teleop
from ballchain.systems.catheter_station import CatheterParams, HandParams
from ballchain.systems.chain_simulation import ChainMonitor, after_updates, replay_meshcat, run_station
from ballchain.systems.simulated_operator import OperatorParams, SimulatedOperator
from ballchain.systems.station import MakeStation, atrium_for

STRATEGIES = ("switch", "keep")


def comparison_catheter(braid_wires: int | None = None, wall_stiffness: float | None = None):
    """The comparison's manual arm: the catheter with its shaft's braid in torsion
    (``SteerableCatheter.braid_GJ``: a netting calculation from the braid's construction);
    ``braid_wires`` 0 neglects the braid (the shaft's static friction then holds the tip until the
    handle leads it by about 140 degrees, ``torsion_lead_deg``); ``wall_stiffness`` [N/m] a
    compliant wall (``SteerableCatheter.wall_stiffness``; None: the default, rigid)."""
    from ballchain.drake_models.steerable_catheter import SteerableCatheter

    kwargs = {} if braid_wires is None else {"braid_wires": braid_wires}
    if wall_stiffness is not None:
        kwargs["wall_stiffness"] = wall_stiffness
    return SteerableCatheter(**kwargs).validate()


def torsion_lead_deg(catheter) -> dict:
    """How far the handle leads the tip in twist before the tip turns [deg], the shaft unloaded:
    the twist chain's static lead (every node at its static friction, ``CapstanChain.lead``) and
    kinetic one (each just after a slip)."""
    chain = catheter.twist_chain()
    if catheter.sheath_friction == "bends":
        static, kinetic = chain.lead(catheter.mu_static), chain.lead(catheter.mu_kinetic)
    else:
        static, kinetic = chain.lead(), chain.lead(chain.kinetic / chain.static)
    return {"static_deg": round(float(np.degrees(static)), 1), "kinetic_deg": round(float(np.degrees(kinetic)), 1)}


def scenario_for():
    """The teleoperation station's atrium and sheath with the manual catheter instead of the chain."""
    from ballchain.systems.chain_scenario import load_scenario

    scenario = load_scenario(teleop.SCENARIO)
    scenario.units = []
    scenario.device = "steerable_catheter"
    scenario.engine = "statics"
    return scenario.validate()


def check_inputs(task: str, targets, time_limit, seed, strategy: str) -> None:
    """Raises UserInputError with a clear message on bad input."""
    teleop.check_inputs(task, "world", targets, None, time_limit, seed)
    if strategy not in STRATEGIES:
        raise UserInputError(f"strategy must be one of {STRATEGIES} (at the windup: the opposite tendon and "
                             f"back, or keep turning), got {strategy!r}")


# A catheter replay's size (``Meshcat.StaticHtml``): the page with the atrium's mesh, plus one pose
# per rod node per frame (the chain's replay's figures, ``chain_simulation.replay_bytes``).
REPLAY_BODY_FRAME_BYTES = 200.0
REPLAY_BASE_BYTES = 2.5e6


def _run_settings(used, seed: int, hand, scenario, params, limit: float, device: dict, path: dict) -> dict:
    """A manual run's settings: the catheter's, the hand's and the operator's, and what the run did
    (``device``: the catheter model's metrics)."""
    return {"device": "steerable_catheter", "seed": seed, "strategy": hand.strategy,
            "braid_wires": used.braid_wires,
            "shaft_GJ_over_plain": round(used.shaft_GJ / used.plain_GJ, 3), "torsion_lead": torsion_lead_deg(used),
            "statics_period_s": scenario.statics_period, "operator_period_s": params.period,
            "reaction_s": params.period * params.reaction_steps, "timeout_s": params.timeout,
            "axes": list(params.axes), "time_limit_s": limit, "push_speed_m_s": hand.push_speed,
            "twist_rate_deg_s": round(float(np.degrees(hand.twist_rate)), 3), "knob_rate_per_s": hand.knob_rate,
            "switches": device["switches"], "slips": device["slips"], "rod_warnings": device["rod_warnings"],
            "path": path}


SHEATHS = ("steerable", "fixed")  # the manual arm's sheath: a steerable one the hand moves, or the paper's fixed one
# The manual arm as the comparison runs it (issue 45, session 50): the steerable sheath the hand places
# per target, as clinicians use one for pulmonary-vein isolation, on a compliant wall of 0.14 N/mm
# (Ijima et al.'s atrial tissue, the source of ``systems/rod_wall_compliance``'s range). The robotic
# arm keeps the paper's fixed sheath and its engine's rigid wall: the ball chain's statics has no
# compliant wall yet (docs/design.md 8), so the comparison's walls favour the manual arm
# (docs/guide/manual_catheter.md: Fairness). ``run`` and ``teleop --device steerable_catheter``
# default to these; ``sheath="fixed"`` and ``wall_stiffness=0`` give the arm before.
MANUAL_SHEATH = "steerable"
MANUAL_WALL_STIFFNESS = 140.0  # [N/m]


def manual_arm_catheter(braid_wires: int | None = None, wall_stiffness: float | None = None):
    """``comparison_catheter`` on the manual arm's wall: ``wall_stiffness`` [N/m], None: the
    comparison's ``MANUAL_WALL_STIFFNESS`` (0: the rigid wall)."""
    return comparison_catheter(braid_wires, MANUAL_WALL_STIFFNESS if wall_stiffness is None else wall_stiffness)


def run(task: str = "left", targets: int | None = None, seed: int = 0, strategy: str = "switch",
        time_limit: float | None = None, heart=None, hand=None, catheter=None, html=None,
        sheath: str = MANUAL_SHEATH) -> teleop.TeleopResult:
    """The operator does ``task`` with the manual catheter (default: ``manual_arm_catheter()``, on
    the compliant wall of ``MANUAL_WALL_STIFFNESS``)
    in the station ``MakeStation`` builds for ``device: steerable_catheter``, run by
    ``run_station``; with ``html`` (a path) a Meshcat replay of the rod in the atrium is written
    there (frames every ``teleop.REPLAY_PERIOD``). ``sheath`` "fixed" (the paper's, as the robotic
    arm's) or "steerable" (``drake_models.sheath.SteerableSheath``, placed by the hand per target:
    ``systems.catheter_station.SheathPlan``, each ring's plans computed once and kept in the cache:
    ``systems.sheath_plan_cache``, H13; the operator waits while the hand moves it, its
    input ``hand_hold``; the hand re-approaches a target with the plan's curve once the operator has
    failed on it three times, its output ``attempts``, H14; issue 45: the comparison's default,
    ``MANUAL_SHEATH``; with the compliant wall of 0.14 N/mm it touches 17/18 on the right ring and
    20/20 on the left, see ``docs/guide/manual_catheter.md``).

    Returns:
        a ``teleop.TeleopResult`` (mapping "manual"); its settings add the catheter's and the
        hand's, and ``path`` {t, tip (k, 3) [m], twist (k,) handle twist [rad], exit_twist (k,)}
        sampled at the operator's looks, ``switches``, ``slips`` (the device's metrics) and
        ``smoothness`` {sparc_median, transitions (``transitions``)}; on a compliant wall
        (``SteerableCatheter.wall_stiffness`` > 0, issue 45, H10) also ``wall_stiffness_N_per_m``,
        ``peak_wall_force_N`` and ``peak_tip_force_N`` (the largest total and tip wall force at any
        update), ``touch_wall_force_N`` ({target: [total, tip]} at each touch) and ``wall_indentations`` {recorded, max_mm} (the watchdog's nodes past the wall's
        middle that the compliant wall holds, ``_within_compliance``: recorded, not fatal).
    """
    check_inputs(task, targets, time_limit, seed, strategy)
    if sheath not in SHEATHS:
        raise UserInputError(f"sheath must be one of {SHEATHS} (a steerable sheath the hand moves, or the paper's "
                             f"fixed one), got {sheath!r}")
    for value, types, name, what in ((heart, Atrium, "heart", "an atrium (LeftAtrium) or None"),
                                     (hand, HandParams, "hand", "a HandParams or None"),
                                     (catheter, SteerableCatheter, "catheter", "a SteerableCatheter or None")):
        if value is not None:
            require_type(value, types, f"manual_catheter.run {name}", what)
    if html is not None:  # before the run: an unwritable replay path must not cost the results
        check_output_file(html, "--html")
    scenario = scenario_for()
    heart = heart or atrium_for(scenario)
    ring = heart.rings[task]
    n_targets = len(ring.p_HT) if targets is None else min(int(targets), len(ring.p_HT))
    used = catheter or manual_arm_catheter()
    hand = hand or HandParams(strategy=strategy, f_over_d=used.max_deflection_F / used.max_deflection_D)
    params = OperatorParams(axes=(0, 1), seed=int(seed), feeder_speed=hand.push_speed, dead_band=hand.dead_band)
    handles = {}

    def add_operator(builder, ports):
        names, p_WT, n_W, radius = ports.targets
        chosen = [i for i, n in enumerate(names) if n.startswith(f"{task}_")][:n_targets]
        device = ports.device
        # With the steerable sheath the exit moves: no feed cap from the fixed exit's distance.
        seen = replace(params, ball_radius=device.tip_radius, target_radius=radius,
                       p_WE=None if sheath == "steerable" else tuple(device.p_WE),
                       electrode_length=device.electrode.length,
                       initial_length=device.initial_inserted_length, min_length=device.initial_inserted_length,
                       max_length=device.max_inserted_length(), keep_out=teleop.vein_openings(heart))
        op = builder.AddSystem(SimulatedOperator(device.tip_body_index, device.tip_base_body_index,
                                                 [names[i] for i in chosen], p_WT[chosen], n_W[chosen], seen))
        builder.Connect(ports.body_poses, op.get_body_poses_input_port())
        (joystick,) = ports.joystick_inputs.values()
        builder.Connect(op.GetOutputPort("joystick"), joystick)
        builder.Connect(op.GetOutputPort("v_insert_cmd"), ports.feeder_command_input)
        if device.hand.plan is not None:  # the hand places the steerable sheath for the operator's target
            builder.Connect(op.GetOutputPort("target"), device.hand.GetInputPort("target"))
            builder.Connect(device.hand.GetOutputPort("hold"), op.GetInputPort("hand_hold"))
            builder.Connect(op.GetOutputPort("attempts"), device.hand.GetInputPort("attempts"))  # H14
        handles["tip"] = LogVectorOutput(device.system.GetOutputPort("tip_position"), builder, params.period)
        handles["windup"] = LogVectorOutput(device.system.GetOutputPort("windup"), builder, params.period)
        if used.wall_stiffness > 0:  # the wall force at each touch (compliant wall only: the default diagram kept)
            handles["wall"] = LogVectorOutput(device.system.GetOutputPort("wall_force"), builder, params.period)
        handles["operator"] = op
        return {"operator": op}

    limit = time_limit if time_limit is not None else n_targets * params.timeout + params.start_time + 5.0
    meshcat = _replay_meshcat(html, scenario, limit, used)
    built = time.perf_counter()
    station = MakeStation(scenario, meshcat=meshcat, heart=heart, add_systems=add_operator,
                          device_params=CatheterParams(catheter=used, hand=hand,
                                                       sheath=SteerableSheath() if sheath == "steerable" else None))
    built = time.perf_counter() - built
    op = handles["operator"]
    # The run ends when the operator has touched or given up every target.
    # A compliant wall (``SteerableCatheter.wall_stiffness``) is indented by design, up to its cap:
    # the watchdog records those nodes instead of stopping the run (deeper stays fatal).
    monitor = (ChainMonitor(station, tolerate_sinking=_within_compliance(heart, used))
               if used.wall_stiffness > 0 else None)
    outcome = run_station(station, duration=limit, html=html, meshcat=meshcat, monitor=monitor,
                          stop=after_updates(lambda c: op.is_done(op.GetMyContextFromRoot(c)), op.params.period))
    root = outcome.context
    rows = op.rows(op.GetMyContextFromRoot(root))
    summary = teleop.summarize(rows, outcome.sim_time, outcome.wall_time, outcome.failure)
    summary.build_time_s = round(built, 2)
    summary.realtime_factor_cpu = round(outcome.sim_time / outcome.cpu_time, 4) if outcome.cpu_time > 0 else None
    tip_log = handles["tip"].FindLog(root)
    wind_log = handles["windup"].FindLog(root)
    path = {"t": tip_log.sample_times().tolist(), "tip": tip_log.data().T.tolist(),
            "twist": wind_log.data()[0].tolist(), "exit_twist": wind_log.data()[1].tolist()}
    metrics = station.device.metrics(root)
    settings = _run_settings(used, int(seed), hand, scenario, params, limit, metrics, path)
    settings["sheath"] = ("steerable (drake_models.sheath.SteerableSheath, placed by the hand per target)"
                          if sheath == "steerable" else "fixed (the paper's)")
    if used.wall_mu > 0:  # the wall's Coulomb friction at the tip (systems.rod_wall_friction); 0: none, not listed
        settings["wall_mu"] = used.wall_mu
    if used.wall_stiffness > 0:  # the compliant wall (systems.rod_wall_compliance); 0: rigid, not listed
        settings["wall_stiffness_N_per_m"] = used.wall_stiffness
        settings["peak_wall_force_N"] = round(metrics["peak_wall_force_N"], 4)
        settings["peak_tip_force_N"] = round(metrics["peak_tip_force_N"], 4)
        settings["touch_wall_force_N"] = _touch_forces(rows, handles["wall"].FindLog(root))
        sunk = outcome.monitor.tolerated_sinkings
        settings["wall_indentations"] = {"recorded": len(sunk),
                                         "max_mm": round(max(e[2] for e in sunk) * 1e3, 3) if sunk else None}
    result = teleop.TeleopResult(task=task, mapping="manual", rows=rows, summary=summary, paper=teleop.PAPER[task],
                                 settings=settings, html=None if html is None else str(html))
    # The smoothness beside the time (issue 45): SPARC of each touched-to-touched movement.
    moves = transitions(result)
    settings["smoothness"] = {"sparc_median": _median([m["sparc"] for m in moves]), "transitions": moves}
    return result


def _touch_forces(rows, log) -> dict:
    """{target: [total, tip] wall force [N]} at each touched target's touch (the last logged
    update at or before its ``t_touch_s``)."""
    times, data = log.sample_times(), log.data()
    out = {}
    for row in rows:
        if row.get("touched") and row.get("t_touch_s") is not None and len(times):
            i = max(int(np.searchsorted(times, row["t_touch_s"] + 1e-9, side="right")) - 1, 0)
            out[row["target"]] = [round(float(data[0, i]), 4), round(float(data[1, i]), 4)]
    return out


def _within_compliance(heart, catheter):
    """The watchdog's test of a node past the wall's middle on a compliant wall: whether the
    wall's model holds it there (its indentation r - sdf within ``INDENTATION_CAP`` and the
    signed-distance grid's 0.1 mm against the mesh's distance the watchdog measures)."""
    from ballchain.drake_models.atrium_sdf import atrium_sdf
    from ballchain.systems.rod_wall_compliance import INDENTATION_CAP

    sdf = atrium_sdf(heart)

    def holds(p) -> bool:
        return bool(catheter.radius - float(sdf(np.asarray(p, float)[None], gradient=False)[0])
                    <= INDENTATION_CAP + 1e-4)
    return holds


def _replay_meshcat(html, scenario, duration: float, catheter):
    """A recording Meshcat for a replay at ``html`` (None: no replay), once the replay's room on
    the disk is checked; the scenario's publish period becomes the replay's frame period."""
    if html is None:
        return None
    scenario.visualization.publish_period = teleop.REPLAY_PERIOD
    nodes = int(round(catheter.model_length / catheter.segment_length)) + 1
    check_output_file(html, "--html", expected_bytes=REPLAY_BASE_BYTES + duration / teleop.REPLAY_PERIOD * nodes
                      * REPLAY_BODY_FRAME_BYTES)
    return replay_meshcat()


def reach_map(task: str = "right", n_twist: int = 12, n_knob: int = 5, step: float = 5e-3, heart=None,
              catheter=None, twist_indices=None) -> list[dict]:
    """Can the catheter press each of the task's targets at all, whoever holds it? The device's
    side of a missed target, apart from the operator's: a grid over the shaft's twist at the sheath
    exit (``n_twist`` in a turn) and the knob (``n_knob`` in [-1, 1]), along each the rod pushed
    out from 10 mm to all of it in ``step`` (the rod's equilibrium in the atrium, warm-started
    along the push), and at each the tip against every target's touch test
    (``target_contact.targets_touched``). ``twist_indices`` maps only those of the ``n_twist``
    twists (a part of the map, e.g. for separate processes; their rows combine by the least
    ``closest_mm`` and the sum of ``touching``).

    Returns:
        per target: {target, reachable (some grid point touches it), touching (grid points that
        do), closest_mm (the least distance from a touch: lateral beyond the target's circle and
        height beyond the ball's touch, combined), at (length mm, twist deg, knob) of the closest}.
    """
    from ballchain.drake_models.atrium_sdf import atrium_sdf
    from ballchain.optimization.rod_statics import RodStatics
    from ballchain.systems.station import atrium_for
    from ballchain.systems.target_contact import heart_targets, targets_touched

    teleop.check_inputs(task, "world", None, None, None, 0)
    heart = heart or atrium_for(scenario_for())
    cat = catheter or comparison_catheter()
    rod = RodStatics(cat, heart.p_HE, heart.sheath_axis_H, atrium_sdf(heart))
    names, p_WT, n_W, radius = heart_targets(heart)
    chosen = [i for i, n in enumerate(names) if n.startswith(f"{task}_")]
    p_WT, n_W = p_WT[chosen], n_W[chosen]
    out = [{"target": names[i], "reachable": False, "touching": 0, "closest_mm": np.inf, "at": None} for i in chosen]
    twists = np.linspace(0.0, 2 * np.pi, n_twist, endpoint=False)
    for twist in twists if twist_indices is None else twists[list(twist_indices)]:
        for knob in np.linspace(-1.0, 1.0, n_knob):
            q = None
            for length in np.arange(10e-3, rod.max_length + 1e-9, step):
                sol = rod.solve(length, twist, cat.curvature(knob), q0=q)
                q, c = sol.q, sol.pose.tip_centre
                miss = touch_miss(c, p_WT, n_W, cat.radius, radius)
                hit = targets_touched(c, p_WT, n_W, cat.radius, radius)
                for row, m, t in zip(out, miss, hit):
                    row["touching"] += int(t)
                    if m < row["closest_mm"]:
                        row["closest_mm"] = m
                        row["at"] = (round(length * 1e3), round(float(np.degrees(twist))), round(knob, 2))
    for row in out:
        row["reachable"] = row["touching"] > 0
        row["closest_mm"] = round(float(row["closest_mm"]) * 1e3, 2)
    return out


def touch_miss(centre, p_WT, n_W, ball_radius: float, target_radius: float) -> np.ndarray:
    """How far a tip sphere centred at ``centre`` is from touching each target [m] (0: it
    touches, as ``target_contact.targets_touched`` tests): its lateral distance beyond the
    target's circle and its height beyond the ball's touch, combined."""
    from ballchain.systems.target_contact import TOUCH_TOLERANCE

    rel = np.asarray(centre, float) - p_WT
    h = (rel * n_W).sum(axis=1)
    lateral = np.sqrt(np.maximum((rel * rel).sum(axis=1) - h * h, 0.0))
    return np.hypot(np.maximum(lateral - target_radius, 0.0),
                    np.maximum(np.abs(h) - ball_radius - TOUCH_TOLERANCE, 0.0))


SEARCH_STEPS = (np.radians(15.0), 0.15, 5e-3)  # the search's first steps: twist [rad], knob, push [m]


def reach_search(grid: list[dict], task: str = "right", only=None, max_solves: int = 120, step: float = 5e-3,
                 heart=None, catheter=None) -> list[dict]:
    """Can the catheter touch the targets the grid (``reach_map``) misses? A local search per
    target from the grid's closest point: minimise the tip's distance from a touch
    (``touch_miss``) over the shaft's twist at the sheath exit, the knob and the push, by
    Nelder-Mead (first steps ``SEARCH_STEPS``: half the default grid's), every rod equilibrium
    warm-started from the grid point's (reached as the grid reached it: pushed out from 10 mm in
    ``step`` at the grid point's twist and knob); it stops at a touch or after ``max_solves``.

    Args:
        grid: ``reach_map``'s rows (on the same catheter and atrium).
        only: the target names to search (default: every row the grid did not reach).

    Returns:
        per searched target: {target, grid_closest_mm, closest_mm, reachable (the search touched
        it), at (length mm, twist deg, knob) of the closest, solves}.
    """
    from ballchain.drake_models.atrium_sdf import atrium_sdf
    from ballchain.optimization.rod_statics import RodStatics
    from ballchain.systems.station import atrium_for
    from ballchain.systems.target_contact import heart_targets

    teleop.check_inputs(task, "world", None, None, None, 0)
    heart = heart or atrium_for(scenario_for())
    cat = catheter or comparison_catheter()
    rod = RodStatics(cat, heart.p_HE, heart.sheath_axis_H, atrium_sdf(heart))
    names, p_WT, n_W, radius = heart_targets(heart)
    wanted = set(only) if only is not None else {r["target"] for r in grid if not r["reachable"]}
    out = []
    for row in grid:
        if row["target"] not in wanted or row["at"] is None:
            continue
        k = names.index(row["target"])
        x0 = np.array([np.radians(row["at"][1]), row["at"][2], row["at"][0] * 1e-3])  # twist, knob, push
        q0 = None
        for length in np.arange(10e-3, x0[2] + 1e-9, step):  # the grid's continuation to its point
            q0 = rod.solve(length, x0[0], cat.curvature(x0[1]), q0=q0).q
        best = _search_target(rod, p_WT[k:k + 1], n_W[k:k + 1], radius, x0, q0, max_solves)
        length, twist, knob = best["x"]
        out.append({"target": row["target"], "grid_closest_mm": row["closest_mm"],
                    "closest_mm": round(best["miss"] * 1e3, 2), "reachable": best["miss"] == 0.0,
                    "at": (round(length * 1e3, 1), round(float(np.degrees(twist)), 1), round(knob, 3)),
                    "solves": best["solves"]})
    return out


def _search_target(rod, p_WT, n_W, radius: float, x0: np.ndarray, q0, max_solves: int) -> dict:
    """``reach_search`` on one target (p_WT, n_W (1, 3)) from x0 = (twist [rad], knob, push [m])
    with the rod's equilibrium there, q0: Nelder-Mead on ``touch_miss``, its first simplex
    ``SEARCH_STEPS`` from x0 (into the knob's and the push's ranges). Returns {miss [m], x (push,
    twist, knob) of the least, solves}."""
    from scipy.optimize import minimize

    cat = rod.catheter
    best = {"miss": np.inf, "x": None, "solves": 0}

    def miss(x):
        if best["miss"] == 0.0 or best["solves"] >= max_solves:
            return best["miss"] + 1.0  # done: the search only winds down
        best["solves"] += 1
        length = float(np.clip(x[2], 10e-3, rod.max_length))
        sol = rod.solve(length, x[0], cat.curvature(x[1]), q0=q0)
        m = float(touch_miss(sol.pose.tip_centre, p_WT, n_W, cat.radius, radius)[0])
        if m < best["miss"]:
            best.update(miss=m, x=(length, float(x[0]), float(np.clip(x[1], -1.0, 1.0))))
        return m

    direction = np.array([1.0, -1.0 if x0[1] > 0 else 1.0, -1.0 if x0[2] + SEARCH_STEPS[2] > rod.max_length else 1.0])
    simplex = np.vstack([x0, x0 + np.diag(np.array(SEARCH_STEPS) * direction)])
    minimize(miss, x0, method="Nelder-Mead",
             options={"initial_simplex": simplex, "maxfev": max_solves + 4, "xatol": 1e-5, "fatol": 1e-7})
    return best


# ------------------------------------------------------------------------------ the comparison
ARMS = ("robotic", "manual")  # the arms of the comparison (the JSON keys "robotic", "manual")
PAPER_COMPARISON = {  # Sec. V-C, after learning: total times [s], the hardest manual transition
    "left": {"robotic_s": 40.0, "manual_s": 40.0, "hardest_manual": ("left_13", "left_14", 5.49)},
    "right": {"robotic_s": 26.0, "manual_s": 33.0, "hardest_manual": None},
}
SPARC_CUTOFF_HZ = 10.0  # the metric's recommended cut-off for reaching movements
SPARC_THRESHOLD = 0.05  # amplitude threshold of the normalised spectrum
SPARC_PADDING = 4  # zero padding: 2**4 times the next power of two


def sparc(speed: np.ndarray, fs: float, cutoff: float = SPARC_CUTOFF_HZ, threshold: float = SPARC_THRESHOLD,
          padding: int = SPARC_PADDING) -> float | None:
    """The spectral arc length (SPARC) of a speed profile: the negative arc length of its
    normalised Fourier magnitude spectrum up to an adaptive cut-off (the last frequency below
    ``cutoff`` where the spectrum is still above ``threshold``); closer to 0 is smoother
    (Balasubramanian, Melendez-Calderon, Roby-Brami, Burdet, "On the analysis of movement
    smoothness", J. NeuroEng. Rehabil. 12:112, 2015). None for fewer than 4 samples or no motion."""
    speed = np.asarray(speed, float)
    if len(speed) < 4 or not np.any(speed > 0):
        return None
    n_fft = int(2 ** (np.ceil(np.log2(len(speed))) + padding))
    freq = np.arange(n_fft) * fs / n_fft
    mag = np.abs(np.fft.fft(speed, n_fft))
    mag = mag / mag.max()
    keep = freq <= cutoff
    freq, mag = freq[keep], mag[keep]
    above = np.flatnonzero(mag >= threshold)
    freq, mag = freq[above[0]:above[-1] + 1], mag[above[0]:above[-1] + 1]
    if len(freq) < 2:
        return 0.0
    return -float(np.sum(np.sqrt((np.diff(freq) / (freq[-1] - freq[0])) ** 2 + np.diff(mag) ** 2)))


def transitions(result: teleop.TeleopResult) -> list[dict]:
    """Target to target: {pair "k->k+1", time_s (from touching k to touching k+1; None when
    either was missed), sparc (of the tip's speed over that movement), accuracy_mm (at k+1)}."""
    path = result.settings["path"]
    t, tip = np.asarray(path["t"]), np.asarray(path["tip"])
    fs = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    out = []
    for a, b in zip(result.rows[:-1], result.rows[1:]):
        pair = f"{a['target'].split('_')[1]}->{b['target'].split('_')[1]}"
        if not (a["touched"] and b["touched"]):
            out.append({"pair": pair, "time_s": None, "sparc": None, "accuracy_mm": b["accuracy_mm"]})
            continue
        t0, t1 = a["t_touch_s"], b["t_touch_s"]
        inside = (t >= t0 - 1e-9) & (t <= t1 + 1e-9)
        speed = np.linalg.norm(np.diff(tip[inside], axis=0), axis=1) * fs
        value = sparc(speed, fs)
        out.append({"pair": pair, "time_s": round(t1 - t0, 3), "sparc": None if value is None else round(value, 3),
                    "accuracy_mm": b["accuracy_mm"]})
    return out


def effort(result: teleop.TeleopResult) -> dict:
    """The hands' work over the run: manual: handle revolutions (|twist| travel / 2 pi), twist
    reversals, push travel [mm]; robotic: the stick's travel (sum of |change| over its axes)
    and reversals, feeder travel [mm]."""
    path = result.settings["path"]
    dt = float(np.median(np.diff(path["t"]))) if len(path["t"]) > 1 else 0.0

    def reversals(x):
        d = np.diff(np.asarray(x, float))
        d = d[np.abs(d) > 1e-9]
        return int(np.count_nonzero(np.diff(np.sign(d)) != 0)) if len(d) > 1 else 0

    if "twist" in path:
        twist = np.asarray(path["twist"])
        return {"handle_revolutions": round(float(np.abs(np.diff(twist)).sum() / (2 * np.pi)), 3),
                "reversals": reversals(twist), "switches": result.settings["switches"]}
    stick = np.asarray(path["stick"])
    feed = np.asarray(path["feed"])
    return {"stick_travel": round(float(np.abs(np.diff(stick, axis=0)).sum()), 3),
            "reversals": int(sum(reversals(stick[:, k]) for k in range(stick.shape[1]))),
            "feed_travel_mm": round(float(np.abs(feed).sum() * dt * 1e3), 3)}


def run_device(device: str, task: str, seed: int, targets: int | None, heart, catheter=None) -> teleop.TeleopResult:
    """One run of a device on a task (robotic: the paper's world mapping on the quasi-static engine)."""
    if device == "robotic":
        return teleop.run(task=task, mapping="world", targets=targets, progress=False, heart=heart, seed=seed,
                          log_path=True)
    return run(task=task, targets=targets, seed=seed, heart=heart, catheter=catheter)


def windup_at(result: teleop.TeleopResult, first: str, second: str) -> dict | None:
    """The manual run's handle twist when it touched ``first`` and ``second`` [deg], the tendon
    switches between (the hand's), and the twist at the sheath exit meanwhile."""
    rows = {r["target"]: r for r in result.rows}
    a, b = rows.get(first), rows.get(second)
    path = result.settings["path"]
    if a is None or b is None or not (a["touched"] and b["touched"]) or "twist" not in path:
        return None
    t = np.asarray(path["t"])
    twist, exit_twist = np.degrees(path["twist"]), np.degrees(path["exit_twist"])
    i0, i1 = int(np.searchsorted(t, a["t_touch_s"])), int(np.searchsorted(t, b["t_touch_s"]))
    i1 = min(i1, len(t) - 1)
    return {"twist_at_first_deg": round(float(twist[min(i0, len(t) - 1)]), 1),
            "twist_at_second_deg": round(float(twist[i1]), 1),
            "max_windup_deg": round(float(np.max(np.abs(twist[i0:i1 + 1] - exit_twist[i0:i1 + 1]))), 1),
            "time_s": round(b["t_touch_s"] - a["t_touch_s"], 3)}


def compare(tasks=teleop.TASKS, seeds=(0, 1, 2), targets: int | None = None, heart=None, catheter=None) -> dict:
    """Both devices on the tasks over the operator seeds: a row per (task, device) with medians
    over the seeds, the per-transition median times, and the manual windup at the left ring's
    13 -> 14 transition. Returns {table, transitions {task: {device: [median time per pair]}},
    pairs {task: [pair names]}, windup, runs}."""
    from ballchain.systems.station import atrium_for

    heart = heart or atrium_for(scenario_for())
    table, trans, pairs, windups, runs = [], {}, {}, [], []
    for task in tasks:
        trans[task] = {}
        for device in ARMS:
            results = [run_device(device, task, s, targets, heart, catheter) for s in seeds]
            per = [transitions(r) for r in results]
            pairs[task] = [p["pair"] for p in per[0]]
            trans[task][device] = [_median([p[k]["time_s"] for p in per]) for k in range(len(per[0]))]
            efforts = [effort(r) for r in results]
            row = {"task": task, "device": device, "runs": len(results),
                   "touched_median": _median([r.summary.touched for r in results]), "targets": results[0].summary.targets,
                   "total_time_median_s": _median([r.summary.total_time_s for r in results]),
                   "transition_median_s": _median([p["time_s"] for q in per for p in q]),
                   "accuracy_median_mm": _median([r.summary.median_accuracy_mm for r in results]),
                   "sparc_median": _median([p["sparc"] for q in per for p in q]),
                   "reversals_median": _median([e["reversals"] for e in efforts]),
                   "paper_total_s": PAPER_COMPARISON[task][f"{device}_s"]}
            if device == "manual":
                row["handle_revolutions_median"] = _median([e["handle_revolutions"] for e in efforts])
                row["switches_median"] = _median([e["switches"] for e in efforts])
                if task == "left":
                    windups += [w for w in (windup_at(r, "left_13", "left_14") for r in results) if w]
            else:
                row["stick_travel_median"] = _median([e["stick_travel"] for e in efforts])
            table.append(row)
            runs += [{"task": task, "device": device, "seed": s, "summary": r.summary, "rows": r.rows,
                      "transitions": p, "effort": e} for s, r, p, e in zip(seeds, results, per, efforts)]
    return {"table": table, "transitions": trans, "pairs": pairs, "windup_13_14": windups, "runs": runs,
            "seeds": list(seeds), "targets": targets}


def _median(values):
    values = [v for v in values if v is not None]
    return round(float(np.median(values)), 3) if values else None


def transition_figure(comparison: dict, path) -> None:
    """The per-transition median times as colour maps, a row per device, a panel per task
    (as the paper's target-to-target colour coding); grey: a transition never completed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ballchain.infrastructure.safe_files import save_figure

    tasks = list(comparison["transitions"])
    fig, axes = plt.subplots(len(tasks), 1, figsize=(10, 1.6 * len(tasks) + 0.6), squeeze=False)
    vmax = max([v for t in tasks for d in ARMS for v in comparison["transitions"][t][d] if v is not None] or [1.0])
    for ax, task in zip(axes[:, 0], tasks):
        grid = np.array([[np.nan if v is None else v for v in comparison["transitions"][task][d]] for d in ARMS])
        cmap = matplotlib.colormaps["viridis"].with_extremes(bad="0.8")
        image = ax.imshow(np.ma.masked_invalid(grid), aspect="auto", cmap=cmap, vmin=0.0, vmax=vmax)
        ax.set_yticks(range(len(ARMS)), ARMS)
        ax.set_xticks(range(grid.shape[1]), comparison["pairs"][task], rotation=90, fontsize=7)
        ax.set_title(f"Task {'I' if task == 'left' else 'II'} ({task} ring): median time per transition [s]",
                     fontsize=9)
        fig.colorbar(image, ax=ax, fraction=0.02)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)
