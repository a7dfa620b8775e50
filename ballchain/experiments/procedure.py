"""A simulated ablation procedure (beyond the paper): every target of a ring pressed and held.

The station is the teleoperation set-up (``teleop.scenario_for``: the 16-ball chain in the
atrium, the unit 10 cm beyond the right carina, the stepper feeder, the quasi-static engine
unless the overrides name the plant). Two navigators:

* ``"auto"``: ``systems.autonomous_navigator.AutonomousNavigator``. Ahead of the run, for each
  target in order (warm-started target to target), inverse statics
  (``planner.plan_target``: the smallest magnet turn whose held equilibrium presses the target
  with the commanded force, frictionless as the engine) gives the feed-forward dipoles, and
  ``HeldTip.value_and_jacobian`` the sensitivities of the pressing force. In the run it sees
  the localisation sensor's tip (``systems.localisation_sensor``, NDI-Aurora-like noise, rate
  and latency), the magnets' measured dipoles and the feeder's length; it estimates the contact
  force from the model (no force sensor) and holds the commanded force for the dwell.
* ``"operator"``: the simulated operator (``systems.simulated_operator``, world mapping): it
  touches each target as in the teleoperation tasks, then holds still for the dwell
  (``OperatorParams.dwell``); it has no force estimate.

Per target: reached, the time spent, and over its dwell the true contact force
(``Station.tip_wall_force``) and the estimate (auto only): their mean error and worst case, and
the fraction of the dwell with the true force inside the window; the ablation point (where the
tip touched, the wall's normal, the mean true force, the RF time).

The dwell is 10 s by default: the short end of the point-by-point RF applications of clinical
practice (10-30 s at 25-40 W), long enough for the force record to show whether the contact is
stable, and the cost driver of the simulation (one equilibrium per 50 ms).

The result and its lesions live in ``procedure_result``, the runs (the station with either
navigator, the rows, the summary) in ``procedure_runs``: both re-exported here.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.drake_models.localisation import LocalisationParams
from ballchain.drake_models.params import gram_force, newtons_from_gram_force
from ballchain.experiments.procedure_result import ProcedureResult, with_lesions, write_outputs  # noqa: F401
from ballchain.experiments.procedure_runs import (  # noqa: F401 (re-exported)
    _add_auto,
    _add_operator,
    _add_sheath_tracker,
    _check_batches,
    _dwell_row,
    _estimator,
    _fed_every,
    _finisher,
    _operator_row,
    _settings,
    _simulate,
    _simulate_operator,
    _summary,
)
from ballchain.experiments.procedure_world import with_world
from ballchain.experiments.teleop import check_seed

TASKS = ("left", "right")
NAVIGATORS = ("auto", "operator")
FORCE_GF = 20.0
WINDOW_GF = (10.0, 40.0)
DWELL_S = 10.0
MAX_DWELL_S = 120.0
UNITS = ("one", "two")
# The plans' chain length by the number of units (``target_plans``'s ``slack``): with two units,
# the fewest balls whose straight chain reaches 2 diameters beyond the target (the whole chain left
# 4-5 diameters of slack at left_16-left_20, and on the way to left_18 its bend carried the tip
# over a vein's rim into the vein: left_18 missed in 2 of 5 seeds); with one unit the whole chain (with
# the fewest balls right_17 had no press it could hold in seeds 0 and 1). docs/guide/procedure.md.
PLAN_SLACK_BALLS = {1: None, 2: 2.0}
WALL_MOTIONS = ("off", "on", "respiration", "beat")


def default_units(task: str | None, anatomy) -> str:
    """The right ring with the unit beyond the right carina alone (the paper's set-up); the left
    ring, and a user anatomy with two magnet places, with both units (the right unit alone
    cannot press the left ring's targets: no feasible inverse statics)."""
    if anatomy is not None and not anatomy.procedural:
        return "two" if len(anatomy.magnets) >= 2 else "one"
    return "one" if task == "right" else "two"


def scenario_for(units: str, overrides: str | None, anatomy):
    """The teleoperation station (world mapping) with one or both units and the feeder left to
    the navigator; on a user anatomy the units stand at its magnets."""
    from ballchain.experiments import teleop
    from ballchain.systems.chain_scenario import parse_overrides
    from ballchain.systems.station import apply_anatomy

    if units == "one":
        scenario = teleop.scenario_for("world", None, overrides, None if anatomy.procedural else anatomy)
    else:  # checked with the engine the hand-over gives it (a wall_motion needs no engine: statics)
        scenario = teleop.load_for_hand_over("teleop_two_units", overrides)
        if not anatomy.procedural:
            apply_anatomy(scenario, anatomy)
        teleop.hand_over(scenario, "world", None, parse_overrides(overrides))
    scenario.visualization.publish_period = 0.1  # a procedure lasts minutes: a small replay
    return scenario


def check_inputs(task, navigator, seed, targets, force_gf, window_gf, dwell_s) -> None:
    """Raises UserInputError naming the argument, its value and what is allowed."""
    check_seed(seed)
    if navigator not in NAVIGATORS:
        raise UserInputError(f"navigator must be one of {NAVIGATORS}, got {short_repr(navigator)}")
    if task is not None and not isinstance(task, str):
        raise UserInputError(f"task must be 'left' or 'right' (or an anatomy's prefix), got {short_repr(task)}")
    if targets is not None and (isinstance(targets, bool) or not isinstance(targets, int) or targets < 1):
        raise UserInputError(f"targets must be a positive integer (the first N), got {short_repr(targets)}")
    if isinstance(window_gf, (str, bytes)) or not hasattr(window_gf, "__len__") or len(window_gf) != 2:
        raise UserInputError(f"window_gf must be (low, high) in gf, got {short_repr(window_gf)}")
    lo, hi = window_gf
    for name, v in (("force", force_gf), ("window low", lo), ("window high", hi), ("dwell", dwell_s)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise UserInputError(f"{name} must be a finite number, got {short_repr(v)}")
    if not 0 < lo <= hi <= 200:
        raise UserInputError(f"the force window {lo:g}..{hi:g} gf must have 0 < low <= high <= 200 gf")
    if not lo <= force_gf <= hi:
        raise UserInputError(f"force {force_gf:g} gf must lie in its window {lo:g}..{hi:g} gf")
    if not 0 <= dwell_s <= MAX_DWELL_S:
        raise UserInputError(f"dwell must be in 0..{MAX_DWELL_S:g} s, got {short_repr(dwell_s)}")


def with_wall_motion(overrides: str | None, wall_motion: str) -> str | None:
    """The scenario overrides with the moving wall ``wall_motion`` added (``drake_models.wall_motion``
    at its literature defaults, through the scenario's): "off" adds nothing (the still wall), "on"
    respiration and the heart beat, "respiration" or "beat" only that one (the other's amplitude 0).
    The quasi-static engine the hand-over gives the run follows the wall (``teleop.load_for_hand_over``).

    Returns:
        The overrides (a YAML flow mapping) or ``overrides`` itself for "off".

    Raises:
        UserInputError: another choice, or overrides that name ``wall_motion`` too.
    """
    import json

    from ballchain.systems.chain_scenario import parse_overrides

    if wall_motion not in WALL_MOTIONS:
        raise UserInputError(f"--wall-motion must be one of {', '.join(WALL_MOTIONS)}, got {short_repr(wall_motion)}")
    changes = parse_overrides(overrides)  # its YAML and fields checked here, before the atrium is built
    if wall_motion == "off":
        return overrides
    if "wall_motion" in changes:
        raise UserInputError(f"--wall-motion {wall_motion} and --set wall_motion: "
                             f"{short_repr(changes['wall_motion'])} both set the moving wall; give only one of them")
    motion: dict = {"enabled": True}
    if wall_motion == "respiration":
        motion["cardiac"] = {"amplitude": 0.0}
    elif wall_motion == "beat":
        motion["respiratory"] = {"amplitude": 0.0}
    return json.dumps({**changes, "wall_motion": motion})


def _plan_step(chain, stand, name: str, m_prev: np.ndarray, previous, forces_N, radius: float) -> dict:
    """One target's inverse statics with every magnet of ``stand``, asking for each force of
    ``forces_N`` in turn (the first answered is kept).

    k = 1: ``planner.plan_target`` (frictionless). k > 1: ``min_turn_orientation`` with k magnets
    from each of two warm starts, every start at a force before the next force: the magnets
    where they are (the tip slid onto the target from the previous held equilibrium), then the
    orientation that presses hardest with the tip held on the centre (``forces.max_normal_force``).
    The second start is tried whatever that hardest press is: it is a press held by the wall's
    tangential reaction too, no bound on the frictionless press the program asks for (on the
    left ring's far targets it is below the asked force while the program from it answers).

    Returns:
        {"feasible", "plan" (the OrientationPlan), "start" (which warm start answered),
        "asked_N" (the force asked for)}, or {"feasible": False, "reason"}.
    """
    from ballchain.experiments.forces import max_normal_force
    from ballchain.experiments.planner import field_for_centres, plan_target
    from ballchain.optimization.inverse_statics import HeldTip, min_turn_orientation, pin_tip
    from ballchain.optimization.statics import ChainStatics

    keys = sorted(stand.magnets)
    if len(keys) == 1:
        out = {}
        for f in forces_N:
            out = plan_target(chain, stand, name, m_prev, previous, f, radius, 0.0, 4, 15)
            if out.get("feasible"):
                return {**out, "start": out.get("how"), "asked_N": f}
        return {**out, "feasible": False}
    field_for = field_for_centres([stand.magnets[key] for key in keys])  # the same sources, checked once

    centre, axis = stand.targets[name]
    solver = ChainStatics(chain, max_iterations=25)
    starts = []
    home = pin_tip(solver, field_for(m_prev), centre, previous)
    if home is not None:
        starts.append(("previous target", m_prev, home))
    best = max_normal_force(chain, stand, name, tuple(keys), 4, 15)
    if best.get("force_N") is not None:
        starts.append(("hardest press", np.asarray(best["dipoles"]).reshape(-1, 3), best["result"]))
    if not starts:
        return {"feasible": False, "reason": best.get("reason", "no held equilibrium on the target")}
    statuses = []
    for f in forces_N:
        for how, m_start, home_k in starts:
            plan = min_turn_orientation(HeldTip(solver, field_for, centre, axis, home_k, len(keys)), m_start, m_prev,
                                        f, radius, 0.0)
            if plan.feasible:
                return {"feasible": True, "plan": plan, "start": how, "asked_N": f}
            statuses.append(f"{gram_force(f):.3g} gf from the {how}: {plan.solver_status}")
    return {"feasible": False, "reason": "; ".join(statuses)}


def aim_point(centre: np.ndarray, axis: np.ndarray, reach: float, radius: float, tolerance: float):
    """(the tip's aim (3,), its distance from the target's centre [m]) in the statics frame.

    A target whose centre (``centre``: the tip ball's centre touching it, ball 1 at the origin)
    lies beyond ``reach`` (the straight chain's) is aimed at the point of its circle nearest
    ball 1 that keeps every tip within ``tolerance`` of the aim inside the target's circle
    (``radius``): moved ``radius - tolerance`` along the wall towards the origin. Any other
    target is aimed at its centre (distance 0).
    """
    centre = np.asarray(centre, float)
    n = np.asarray(axis, float) / np.linalg.norm(axis)
    towards = -(centre - (centre @ n) * n)  # along the wall, towards ball 1
    shift = radius - tolerance
    if np.linalg.norm(centre) < reach or shift <= 0.0 or np.linalg.norm(towards) < 1e-12:
        return centre, 0.0
    return centre + shift * towards / np.linalg.norm(towards), float(shift)


def target_plans(anatomy, chosen: list[int], force_N: float, n_balls: int, inserted_length: float,
                 magnets_W: list, progress: bool = False, tolerance: float = 0.0,
                 slack: float | None = None) -> tuple[list, list]:
    """The feed-forward of every target, in order (``TargetPlan``s) and the names not planned.

    Each target: inverse statics (``_plan_step``: frictionless, the engine's contact) from the
    previous target's dipoles and held equilibrium, asking for ``force_N`` (then 3/4 and half of
    it when that has no answer: the most the model can press), with the units at ``magnets_W``
    ((k, 3) centres [m]), and the held equilibrium's force sensitivities there. A target beyond
    the straight chain's reach is aimed inside its circle (``aim_point``; ``tolerance``: how far
    from the aim the navigator counts the tip on it [m]), the touch point then free within the
    circle around the aim that stays inside the target's.

    ``slack`` (None: every target with ``n_balls`` and ``inserted_length``): each target with
    the fewest balls whose straight chain reaches ``slack`` ball diameters beyond its centre
    (at most ``n_balls``), inserted (n - 1/2) diameters (ball 1 at the sheath exit).
    """
    from tqdm import tqdm

    if slack is not None and (isinstance(slack, bool) or not isinstance(slack, (int, float))
                              or not math.isfinite(slack) or slack < 0.0):
        raise UserInputError(f"target_plans slack must be None or a finite number of ball diameters >= 0, "
                             f"got {short_repr(slack)}")
    from ballchain.drake_models.dipole_inversion import neutral_direction
    from ballchain.drake_models.params import BallChain
    from ballchain.experiments.forces import Stand
    from ballchain.experiments.planner import anatomy_stand, field_for_centres
    from ballchain.optimization.inverse_statics import HeldTip
    from ballchain.optimization.statics import ChainStatics
    from ballchain.systems.autonomous_navigator import TargetPlan

    chain = BallChain(n_balls=n_balls)
    base = anatomy_stand(anatomy, chosen, chain.ball_diameter)
    R = base.R_HS
    centres = [R.T @ (np.asarray(p, float) - base.p_HE) for p in magnets_W]
    stand = Stand(dict(base.targets), {str(j + 1): c for j, c in enumerate(centres)}, R, base.p_HE)
    m_now = np.array([neutral_direction(c, np.zeros(3), np.array([1.0, 0.0, 0.0])) for c in centres])
    m_now /= np.linalg.norm(m_now, axis=1, keepdims=True)

    field_for = field_for_centres(centres)  # the same sources, checked once (issue 48)
    held, plans, missing = None, [], []
    d = chain.ball_diameter
    for k, name in zip(tqdm(chosen, desc="plan", unit="target", disable=not progress), stand.targets):
        centre, axis = stand.targets[name]
        lengths = [n_balls]
        if slack is not None:  # the fewest balls first, then one more until a plan answers
            n_few = int(min(n_balls, max(2, np.ceil(np.linalg.norm(centre) / d + slack) + 1)))
            lengths = list(range(n_few, n_balls + 1))
        for n_k in lengths:
            s_k = inserted_length if slack is None else (n_k - 0.5) * d
            chain = BallChain(n_balls=n_k)
            start = held if held is not None and len(held.positions) == n_k else None  # warm: same length only
            aim, shift = aim_point(centre, axis, (n_k - 1) * d, anatomy.touch_radius, tolerance)
            stand.targets[name] = (aim, axis)
            out = _plan_step(chain, stand, name, m_now, start, (force_N, 0.75 * force_N, 0.5 * force_N),
                             anatomy.touch_radius - shift)  # the most it can press, down to half
            if out.get("feasible"):
                break
        if not out.get("feasible"):
            missing.append(name)
            continue
        plan, centre = out["plan"], aim
        held_tip = HeldTip(ChainStatics(chain, max_iterations=25), field_for, centre, axis, plan.result, len(centres))
        _, J = held_tip.value_and_jacobian(np.concatenate([plan.dipoles.reshape(-1), plan.offset]))
        m_now, held = plan.dipoles.reshape(-1, 3), plan.result
        J_m = np.hstack([J[:, 3 * j:3 * j + 3] @ R.T for j in range(len(centres))])
        p_aim = anatomy.p_WT[k] + R @ (aim - base.targets[name][0])
        plans.append(TargetPlan(name, p_aim, anatomy.n_W[k], (R @ m_now.T).T, s_k,
                                R @ held_tip.basis, J_m, J[:, 3 * len(centres):], float(plan.force_N), shift))
    return plans, missing


def _with_lesion_conditions(finish, lesions):
    """``finish`` with the clinical lesion conditions (``lesion_dwell.LesionConditions``) put in
    the result's settings first, where ``with_lesions`` reads them (issue 44)."""
    if isinstance(lesions, bool):
        return finish
    if not callable(getattr(lesions, "to_dict", None)):
        raise UserInputError(f"lesions must be true, false or a LesionConditions, got {short_repr(lesions)}")

    def finish_clinical(result, cd, meshcat):
        result.settings["lesions"] = lesions.to_dict()
        return finish(result, cd, meshcat)

    return finish_clinical


def run(task: str | None = "right", navigator: str = "auto", anatomy=None, seed: int = 0, *,
        targets: int | None = None, force_gf: float = FORCE_GF, window_gf=WINDOW_GF, dwell_s: float = DWELL_S,
        localisation: LocalisationParams | None = None, overrides: str | None = None, progress: bool = True,
        html: Path | None = None, units: str | None = None, lesions: bool = True,
        wall_motion: str = "off", track_sheath: bool = False,
        plans: "RingPlans | None" = None, world="none") -> ProcedureResult:
    """Simulate the procedure on a ring: every target reached, pressed and held for the dwell.

    Args:
        task: "left" (20 targets) or "right" (18) on the procedural atrium; with ``anatomy``,
            its targets named "{task}_..." (None: all, in file order).
        navigator: "auto" (the autonomous navigator) or "operator" (the simulated operator).
        anatomy: an anatomy file (``drake_models.anatomy``) instead of the procedural atrium.
        seed: the localisation noise's seed (auto) or the operator's tremor's, 0..2**32-1.
        targets: only the first N targets (None: all).
        force_gf, window_gf: the commanded contact force and its window [gf].
        dwell_s: the RF time per target [s].
        localisation: the tip tracker's figures (default: the scenario's ``localisation``, whose
            defaults are ``LocalisationParams()``'s).
        overrides: inline YAML overrides of the station's scenario.
        progress: progress bars on stderr.
        html: write a Meshcat replay here.
        units: "one" (the unit beyond the right carina) or "two" (both carinas' units); None:
            ``default_units``.
        lesions: each dwell's lesion and the ring's verdict (``with_lesions``); a
            ``lesion_dwell.LesionConditions``: the lesions as in a beating heart (blood flow,
            the generator's loop, the dwell by a lesion criterion), kept in ``settings["lesions"]``.
        wall_motion: the moving wall, one of ``WALL_MOTIONS`` (``with_wall_motion``); the motion
            the run used is in ``settings["wall_motion"]``.
        track_sheath: the autonomous navigator tracks the sheath (a localisation sensor on it,
            ``_add_sheath_tracker``) and moves its force model's sheath and its targets with it:
            respiratory compensation; off, it holds them at rest (motion-blind).
        plans: the ring's plans made ahead (``plan_ring``, same task, targets, force, units and
            overrides; auto only): the run skips its planning (same result as planning it).
        world: the world the engine plays, unknown to the planner and the navigator
            (``procedure_world.with_world``): "none" (the model's own numbers), "literature", or
            {preset, only, scale, seed} (the seed defaulting to ``seed``); drawn in
            ``settings["world"]``. The plans do not depend on it.

    Returns:
        A ``ProcedureResult``.
    """
    from ballchain.experiments.planner import anatomy_targets
    from ballchain.systems.autonomous_navigator import NavigatorParams

    check_inputs(task, navigator, seed, targets, force_gf, tuple(window_gf), dwell_s)
    overrides = with_world(with_wall_motion(overrides, wall_motion), world, seed)
    if not isinstance(track_sheath, bool):
        raise UserInputError(f"track_sheath must be true or false, got {short_repr(track_sheath)}")
    if track_sheath and navigator != "auto":
        raise UserInputError(f"--track-sheath needs navigator auto (the simulated operator has no force model "
                             f"and no targets to move), got navigator {short_repr(navigator)}")
    if units not in (None, *UNITS):
        raise UserInputError(f"units must be one of {UNITS} (or None: by the ring), got {short_repr(units)}")
    if localisation is not None and not isinstance(localisation, LocalisationParams):
        raise UserInputError(f"localisation must be a LocalisationParams, got {short_repr(localisation)}")
    if plans is not None and not isinstance(plans, RingPlans):
        raise UserInputError(f"plans must be a RingPlans (``plan_ring``), got {short_repr(plans)}")
    if html is not None:
        from ballchain.infrastructure.safe_files import check_output_file

        check_output_file(html, "--html")
    anatomy, task, chosen = anatomy_targets(anatomy, task)
    chosen = chosen[:targets] if targets else chosen
    if navigator == "operator" and units == "two":
        raise UserInputError("units 'two' needs navigator 'auto': the simulated operator steers one unit")
    units = units if units is not None else "one" if navigator == "operator" else default_units(task, anatomy)
    scenario = scenario_for(units, overrides, anatomy)
    localisation = localisation if localisation is not None else scenario.localisation.params()
    params = NavigatorParams(force_command=newtons_from_gram_force(force_gf),
                             force_window=tuple(newtons_from_gram_force(v) for v in window_gf), dwell=dwell_s)
    ring_order = [anatomy.target_names[k] for k in chosen]
    finish = _with_lesion_conditions(_finisher(bool(lesions), ring_order, html), lesions)
    if navigator == "operator":
        return finish(*_simulate_operator(task, anatomy, chosen, scenario, params, seed, progress, html, overrides))
    key = _plans_key(anatomy, chosen, scenario, force_gf)
    if plans is not None and plans.key != key:
        raise UserInputError(f"plans were made for another ring, force or station ({plans.key[0]}); these runs "
                             f"need {key[0]}: make them with plan_ring and the same task, targets, force, "
                             "units and overrides")
    if plans is None:
        plans = _plan_ring(anatomy, chosen, scenario, force_gf, key, progress)
        plan_cpu = plans.cpu_time_s
    else:
        plan_cpu = 0.0  # made once ahead, for every seed
    return finish(*_simulate(task, anatomy, scenario, list(plans.plans), list(plans.missing), params, localisation,
                             seed, plan_cpu, progress, html, overrides, track_sheath))


@dataclass(frozen=True)
class RingPlans:
    """The autonomous navigator's feed-forward of a ring (``target_plans``), made once
    (``plan_ring``) and given to every run that differs only in its seed: the plans do not
    depend on the seed (the localisation noise's).

    Attributes:
        plans: the ``TargetPlan``s in order; missing: the targets with no plan.
        cpu_time_s: the CPU time the planning took [s] (reading them, when ``cached``).
        key: what they were made for: (a one-line description, the targets, the force [gf],
            the chain's length, the units' centres [m]); ``run`` refuses plans of another key.
        cached: read from the on-disk cache of plans (``plan_cache``), not computed.
    """

    plans: tuple
    missing: tuple
    cpu_time_s: float
    key: tuple
    cached: bool = False


def _plans_key(anatomy, chosen: list[int], scenario, force_gf: float) -> tuple:
    from ballchain.systems.station import add_field_sources

    names = tuple(anatomy.target_names[k] for k in chosen)
    configs = add_field_sources(scenario, anatomy.atrium()).unit_configs
    magnets_W = tuple(tuple(float(v) for v in c.p_WM) for c in configs)
    said = f"{len(names)} targets from {names[0]}, {force_gf:g} gf, {len(magnets_W)} unit(s)"
    return said, names, float(force_gf), int(scenario.n_balls), magnets_W


def _plan_ring(anatomy, chosen: list[int], scenario, force_gf: float, key: tuple, progress: bool,
               cache: bool = True) -> RingPlans:
    """``target_plans`` for the station of ``scenario``: its chain beyond the sheath, its units;
    through the on-disk cache of plans (``plan_cache``) unless ``cache`` is False."""
    from ballchain.drake_models.params import BallChain
    from ballchain.experiments.plan_cache import ring_plans
    from ballchain.systems.autonomous_navigator import NavigatorParams

    cpu0 = time.process_time()
    n = scenario.n_balls
    # The plan's statics clamps ball 1 at the sheath exit; the station puts ball 1's centre at
    # p_WE + (s - (n - 1/2) d) u (``chain_plant``): that is s = (n - 1/2) d, not (n - 1) d (ball 1
    # half a ball inside, the chain 1.6 mm short of the plan's reach).
    s_full = (n - 0.5) * BallChain().ball_diameter
    slack = PLAN_SLACK_BALLS[min(len(key[4]), 2)]
    args = (anatomy, chosen, newtons_from_gram_force(force_gf), n, s_full, [np.array(p) for p in key[4]])
    tolerance = NavigatorParams().touch_radius
    plans, missing, reused = ring_plans(*args, tolerance, slack,
                                        lambda: target_plans(*args, progress, tolerance, slack), cache)
    return RingPlans(tuple(plans), tuple(missing), time.process_time() - cpu0, key, reused)


def plan_ring(task: str | None = "right", anatomy=None, *, targets: int | None = None,
              force_gf: float = FORCE_GF, units: str | None = None, overrides: str | None = None,
              progress: bool = False, cache: bool = True) -> RingPlans:
    """The autonomous navigator's plans for a ring, to give to ``run(..., plans=)`` for each seed
    (arguments as ``run``'s; the planning is about half of an autonomous run's cost). ``cache``:
    read and keep them in the on-disk cache of plans (``plan_cache``; False: computed afresh)."""
    from ballchain.experiments.planner import anatomy_targets

    check_inputs(task, "auto", 0, targets, force_gf, (force_gf, force_gf), DWELL_S)  # the force alone
    if units not in (None, *UNITS):
        raise UserInputError(f"units must be one of {UNITS} (or None: by the ring), got {short_repr(units)}")
    anatomy, task, chosen = anatomy_targets(anatomy, task)
    chosen = chosen[:targets] if targets else chosen
    scenario = scenario_for(units if units is not None else default_units(task, anatomy), overrides, anatomy)
    return _plan_ring(anatomy, chosen, scenario, force_gf, _plans_key(anatomy, chosen, scenario, force_gf), progress,
                      cache)
