"""Model-based steering (beyond the paper): inverse statics for each ablation target, and a plan.

For each target of a ring (Task I: the 20 around the left veins; Task II: the 18 around the
right veins) the tip ball is held touching the wall at the target (its centre a ball radius off
the wall along the wall's normal). The plan visits the targets in order; at each, a
MathematicalProgram (``optimization.inverse_statics.min_turn_orientation``, SNOPT) finds the
smallest magnet turn from the previous orientation whose held equilibrium presses the wall with
at least 10 gf, for each inserted length; the length that costs least time is taken. The plan's
time is what the hardware needs between consecutive equilibria: the magnet's turn at the
teleoperation speed and the feeder's insertion change at its speed. The magnet is the paper's teleoperation set-up: one
prototype unit 10 cm beyond the right carina, on the line from the atrium's centre.
"""

from __future__ import annotations

import math

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
from tqdm import tqdm

from ballchain.infrastructure.arg_checks import as_int_list, require_int, require_positive
from ballchain.drake_models import paper
from ballchain.drake_models.anatomy import (PROCEDURAL_FILE, Anatomy, AnatomyTargets, ellipsoid_inward_normal,
                                            load_anatomy)
from ballchain.drake_models.dipole_inversion import neutral_direction
from ballchain.infrastructure.errors import UserInputError, short_repr, quote_path
from ballchain.drake_models.field_sources import FieldSources, MagnetSource, rotation_with_z_along
from ballchain.drake_models.heart import LeftAtrium
from ballchain.drake_models.params import BallChain, CylinderMagnet, gram_force, newtons_from_gram_force
from ballchain.experiments._result import Result, optional
from ballchain.experiments.forces import Stand, max_normal_force
from ballchain.optimization.inverse_statics import HeldTip, min_turn_orientation, pin_tip
from ballchain.optimization.statics import ChainStatics, StaticsResult
from ballchain.systems.chain_plant import ContactConfig

TASKS = {"left": "left", "right": "right"}
PAPER = paper.TELEOP_TASKS
MIN_FORCE_GF = 10.0


def teleop_stand(atrium: LeftAtrium, task: str, ball_diameter: float, carina_distance: float = 0.10) -> Stand:
    """The ring's targets and the teleoperation magnet in the statics frame."""
    ring = atrium.rings[task]
    # The targets lie on the ellipsoidal endocardium (``anatomy.ellipsoid_inward_normal``).
    n_in = [ellipsoid_inward_normal(p_HT, atrium.semi_axes) for p_HT in ring.p_HT]
    carina = atrium.carinas["right"]
    p_HM = carina + carina_distance * carina / np.linalg.norm(carina)
    return target_stand(atrium, [f"{task}_{k + 1}" for k in range(len(ring.p_HT))], ring.p_HT, n_in, p_HM,
                        ball_diameter)


def target_stand(atrium, names: list[str], p_HT, n_in, p_HM, ball_diameter: float) -> Stand:
    """Targets (centres p_HT (n, 3) on the wall, unit normals n_in (n, 3) to the chain's side) and
    one magnet (centre p_HM) in the statics frame: the tip ball's centre a ball radius off the
    wall, its sensor axis into the wall (the direction the tip presses)."""
    R_HS = rotation_with_z_along(atrium.sheath_axis_H)[:, [2, 0, 1]]
    to_S = lambda p_H: R_HS.T @ (np.asarray(p_H) - atrium.p_HE)  # noqa: E731
    targets = {name: (to_S(p + 0.5 * ball_diameter * n), R_HS.T @ (-n)) for name, p, n in zip(names, p_HT, n_in)}
    return Stand(targets, {"1": to_S(p_HM)}, R_HS, atrium.p_HE)


def anatomy_stand(anatomy: Anatomy, indices: list[int], ball_diameter: float) -> Stand:
    """The anatomy's targets ``indices`` (file order) and its first magnet unit in the statics frame."""
    return target_stand(anatomy.atrium(), [anatomy.target_names[k] for k in indices], anatomy.p_WT[indices],
                        anatomy.n_W[indices], anatomy.magnets[0], ball_diameter)


def neutral_dipole(stand: Stand) -> np.ndarray:
    """The magnet's neutral direction: its field at the sheath exit (the origin) along the sheath."""
    return neutral_direction(stand.magnets["1"], np.zeros(3), np.array([1.0, 0.0, 0.0]))


class _PointingMagnet(MagnetSource):
    """``MagnetSource(magnet, p_WM, rotation_with_z_along(direction))`` with the magnet and its
    centre checked by the caller and the direction finite and non-zero: its dipole moment
    computed from the direction alone (the same floats: the rotation's third column is the unit
    direction), the rotation itself built only when read (the general solve's field; the
    compiled held solve reads ``m_W`` only: ``compiled_model.field_arrays``). Issue 48: the
    planner asks for one source per held solve, and the rotation's cross products cost a sixth
    of a cold plan."""

    def __init__(self, magnet, p_WM: np.ndarray, direction: np.ndarray, unit: np.ndarray) -> None:
        self.magnet, self.p_WM, self.model, self.fd_step = magnet, p_WM, "dipole", MagnetSource.fd_step
        self._direction, self._unit, self._R = direction, unit, None

    @property
    def R_WM(self) -> np.ndarray:
        if self._R is None:
            self._R = rotation_with_z_along(self._direction)
        return self._R

    @property
    def m_W(self) -> np.ndarray:
        return self.magnet.dipole_moment * self._unit


def field_for_centres(centres) -> Callable[[np.ndarray], FieldSources]:
    """The prototype magnets' field at ``centres`` (k of (3,)) [m] as a function of their
    directions (k, 3): the magnets and their centres checked once here (``MagnetSource``'s
    checks), each call's sources without them (``_PointingMagnet``: the same fields, the same
    floats; a direction ``rotation_with_z_along`` would refuse goes through it and is refused),
    since the planner asks for sources at every held solve (issue 48)."""
    magnet = CylinderMagnet()
    p_M = [MagnetSource(magnet, p).p_WM for p in centres]

    def field(m: np.ndarray) -> FieldSources:
        m = np.asarray(m, dtype=float).reshape(-1, 3)
        sources = []
        for p, z in zip(p_M, m):
            norm = np.linalg.norm(z)  # as rotation_with_z_along normalises it
            if not (np.isfinite(norm) and norm > 0.0):
                sources.append(MagnetSource(magnet, p, rotation_with_z_along(z)))  # raises its error
            else:
                sources.append(_PointingMagnet(magnet, p, z, z / norm))
        return FieldSources(sources)

    return field


def _field_for(stand: Stand) -> Callable[[np.ndarray], FieldSources]:
    """The stand's one magnet's field as a function of its direction (1, 3) (``field_for_centres``)."""
    return field_for_centres([stand.magnets["1"]])


_HARDEST: dict = {}  # the last few hardest-press searches (``_hardest_press``)


def _hardest_press(chain: BallChain, stand: Stand, name: str, grid: int, refine: int) -> dict:
    """``forces.max_normal_force(chain, stand, name, ("1",), grid, refine)``, the last few kept:
    the search reads only these (the chain, the target, the magnet's centre, the effort) and
    answers the same floats every time, and a caller asking several forces of one target
    (``procedure._plan_step``: the force, then 3/4 and half of it) asked it again per force
    (issue 48: 14 of the right ring's 31 searches, a seventh of a cold plan)."""
    centre, axis = stand.targets[name]
    key = (chain, np.asarray(centre, float).tobytes(), np.asarray(axis, float).tobytes(),
           np.asarray(stand.magnets["1"], float).tobytes(), grid, refine)
    if key not in _HARDEST:
        if len(_HARDEST) >= 4:
            del _HARDEST[next(iter(_HARDEST))]  # the oldest
        _HARDEST[key] = max_normal_force(chain, stand, name, ("1",), grid, refine)
    return _HARDEST[key]


def plan_target(chain: BallChain, stand: Stand, name: str, m_previous: np.ndarray,
                previous: StaticsResult | None, min_force_N: float, target_radius: float, friction: float,
                grid: int, refine: int) -> dict:
    """The smallest magnet turn from ``m_previous`` that presses target ``name`` with at least
    ``min_force_N`` in a contact equilibrium (``inverse_statics.min_turn_orientation``).

    The program starts from the magnet where it is, with the tip slid onto the target from the
    previous held equilibrium (``previous``, same chain) or from the free chain; when that
    start has no held equilibrium or the program finds no feasible answer, it restarts from the
    orientation that presses hardest with the tip held on the centre (grid + Nelder-Mead,
    ``forces.max_normal_force``).
    """
    centre, axis = stand.targets[name]
    solver = ChainStatics(chain, max_iterations=25)
    field_for = _field_for(stand)
    m_previous = np.asarray(m_previous, float).reshape(1, 3)
    attempts = []
    home = pin_tip(solver, field_for(m_previous), centre, previous)
    if home is not None:
        attempts.append((m_previous, home, "from the current orientation"))
    plan, max_force, how = None, None, ""
    for k in range(2):
        for m_start, home_k, how in attempts:  # noqa: B007 (how is returned)
            held = HeldTip(solver, field_for, centre, axis, home_k)
            plan = min_turn_orientation(held, m_start, m_previous, min_force_N, target_radius, friction)
            if plan.feasible:
                break
        if (plan is not None and plan.feasible) or k == 1:
            break
        best = _hardest_press(chain, stand, name, grid, refine)
        if best.get("force_N") is None:
            return {"reached": False, "feasible": False, "reason": best.get("reason", "no held equilibrium")}
        max_force = best["force_N"]
        if max_force < min_force_N:
            return {"reached": True, "feasible": False, "max_force_N": max_force,
                    "reason": f"at most {gram_force(max_force):.2f} gf even with the tip held on the centre"}
        attempts = [(np.asarray(best["dipoles"]).reshape(1, 3), best["result"],
                     "from the hardest-pressing orientation")]
    return {"reached": plan.result is not None, "feasible": plan.feasible, "plan": plan, "how": how,
            "max_force_N": max_force, "reason": "" if plan.feasible else f"no feasible answer ({plan.solver_status})"}


@dataclass
class PlanSummary(Result):
    """Totals over a plan's targets (edge units: gf, s, mm).

    Attributes:
        targets: targets asked for; reached: targets with a plan; with_at_least_10_gf: of those,
            pressing at least the force asked for.
        force_gf_min, force_gf_max: over the planned targets (None: none planned).
        plan_time_s: the hardware's motion time, magnet_turn_time_s + insertion_time_s.
        ring_path_mm: the ring's length; compute_time_s: wall time of the planning.
    """

    targets: int
    reached: int
    with_at_least_10_gf: int
    force_gf_min: float | None
    force_gf_max: float | None
    plan_time_s: float
    magnet_turn_time_s: float
    insertion_time_s: float
    ring_path_mm: float
    compute_time_s: float


@dataclass
class PlanResult(Result):
    """What ``run`` returns (edge units: gf, deg, mm, s).

    Attributes:
        task: "left" or "right" (None: a user anatomy's every target).
        rows: one per target in order: {target, reached, force_gf, n_balls, dipole (unit (3,), in the
            statics frame: x along the sheath), dipole_W (the same in the world frame),
            turn_deg, friction_needed, offset_mm, how, reason} (None where not reached; the reason,
            each chain length's, only where no length reached the target: "" otherwise).
        summary: the totals (``PlanSummary``).
        paper: the paper's operator on the task; min_force_gf: the force asked for;
        friction: the tip's Coulomb coefficient; target_radius_mm: the targets' radius.
        anatomy: the user anatomy's file, side, targets and magnets (``Anatomy.describe``; left
            out for the procedural atrium).
    """

    task: str | None
    rows: list
    summary: PlanSummary
    paper: dict | None
    min_force_gf: float
    friction: float
    target_radius_mm: float
    anatomy: dict | None = optional()


def run(*, task: str | None = None, targets: int | None = None, balls=(16,), grid: int = 4, refine: int = 15,
        min_force_gf: float = MIN_FORCE_GF, friction: float = ContactConfig().friction, omega_max: float = 0.5,
        feeder_speed: float = 0.02, progress: bool = True, anatomy=None) -> PlanResult:
    """A plan that visits every target of a task through held equilibria pressing >= min_force_gf.

    For each target in order and each inserted length, the smallest magnet turn from the
    previous orientation that holds the tip on the target with at least ``min_force_gf``
    (``plan_target``); the length whose turn and feeder move take least time is taken. The
    plan's time is the hardware's motion time between consecutive equilibria: the magnet's turn
    at ``omega_max`` and the feeder's length change at ``feeder_speed``.

    Args:
        task: "left" (Task I) or "right" (Task II) on the procedural atrium (None: "left"); on a
            user's anatomy, only its targets named "{task}_..." (None: every target, in file order).
        targets: only the first ``targets`` targets (None: all).
        balls: inserted chain lengths to try for each target.
        grid, refine: effort of the fallback search for the hardest-pressing orientation
            (see ``forces.max_normal_force``).
        min_force_gf: the force each equilibrium must press [gf] (10: an ablation).
        friction: the tip's Coulomb friction coefficient on the wall, by default the one the
            simulation's contact model uses (``chain_plant.ContactConfig``), so that the plan's
            equilibria are contact equilibria of the simulated station (0: frictionless).
        omega_max: magnet angular speed [rad/s] (the teleoperation mapper's full stick).
        feeder_speed: insertion speed [m/s].
        anatomy: an anatomy file (``drake_models.anatomy``) or a loaded ``Anatomy``: its targets,
            touch radius, sheath and first magnet unit (None: the procedural atrium's file).

    Returns:
        A ``PlanResult``.
    """
    if targets is not None:
        require_int(targets, "targets", 1)
    as_int_list(balls, "balls", 2)
    require_int(grid, "grid", 1)
    require_int(refine, "refine", 0)
    if targets is not None and targets < 1:
        raise UserInputError(f"targets must be >= 1, got {targets}")
    if not (math.isfinite(min_force_gf) and min_force_gf > 0):
        raise UserInputError(f"min_force_gf must be a finite number > 0, got {min_force_gf}")
    if not (math.isfinite(friction) and friction >= 0):  # a NaN once ran and reported "no feasible answer"
        raise UserInputError(f"friction must be a finite number >= 0, got {friction}")
    require_positive(omega_max, "omega_max", "rad/s")  # the plan's times divide by both
    require_positive(feeder_speed, "feeder_speed", "m/s")
    if not balls or any(n < 2 for n in balls):
        raise UserInputError(f"balls must be chain lengths >= 2, got {balls}")
    anatomy, task, chosen = anatomy_targets(anatomy, task)
    d = BallChain().ball_diameter
    stand = anatomy_stand(anatomy, chosen, d)
    names = list(stand.targets)[: targets or None]
    min_force_N = newtons_from_gram_force(min_force_gf)
    target_radius = anatomy.touch_radius
    m_now, n_now = neutral_dipole(stand), None
    held = {n: None for n in balls}  # the last held equilibrium of each length
    rows, turn_time, feed_time = [], 0.0, 0.0
    t0 = time.perf_counter()
    for name in tqdm(names, desc=f"plan {task or anatomy.name}", unit="target", disable=not progress):
        options, reasons = [], []
        for n in balls:
            out = plan_target(BallChain(n_balls=n), stand, name, m_now, held[n], min_force_N, target_radius,
                              friction, grid, refine)
            if out.get("feasible"):
                plan = out["plan"]
                cost = float(plan.turn_rad[0]) / omega_max + (abs(n - n_now) * d / feeder_speed if n_now else 0.0)
                options.append((cost, n, plan, out["how"]))
            else:
                reasons.append(f"{n} balls: {out.get('reason', '')}")
        row = {"target": name, "reached": bool(options), "force_gf": None, "n_balls": None, "dipole": None,
               "dipole_W": None,
               "turn_deg": None, "friction_needed": None, "offset_mm": None, "how": None,
               "reason": "" if options else "; ".join(reasons)}  # why not: only on a row not reached
        if options:
            cost, n, plan, how = min(options, key=lambda o: o[0])
            turn_time += float(plan.turn_rad[0]) / omega_max
            feed_time += abs(n - n_now) * d / feeder_speed if n_now else 0.0
            for _, n_k, plan_k, _ in options:
                held[n_k] = plan_k.result
            m_now, n_now = plan.dipoles[0], n
            row.update(friction_needed=plan.friction_needed, offset_mm=float(1e3 * np.linalg.norm(plan.offset)))
            row.update(force_gf=gram_force(plan.force_N), n_balls=n, dipole=plan.dipoles[0].tolist(),
                       dipole_W=(stand.R_HS @ plan.dipoles[0]).tolist(),
                       turn_deg=float(np.degrees(plan.turn_rad[0])), how=how)
        rows.append(row)
    reached = [r for r in rows if r["reached"]]
    forces_gf = [r["force_gf"] for r in reached]
    summary = PlanSummary(
        targets=len(rows), reached=len(reached),
        with_at_least_10_gf=sum(f >= min_force_gf * (1 - 1e-4) for f in forces_gf),
        force_gf_min=min(forces_gf) if forces_gf else None,
        force_gf_max=max(forces_gf) if forces_gf else None,
        plan_time_s=turn_time + feed_time, magnet_turn_time_s=turn_time, insertion_time_s=feed_time,
        ring_path_mm=1e3 * (anatomy.atrium().rings[task].curve_length if anatomy.procedural else
                            AnatomyTargets([], anatomy.p_WT[chosen], None, 0.0).polygon_length),
        compute_time_s=time.perf_counter() - t0,
    )
    return PlanResult(task=task, rows=rows, summary=summary, paper=PAPER.get(task) if anatomy.procedural else None,
                      min_force_gf=min_force_gf, friction=friction, target_radius_mm=1e3 * target_radius,
                      anatomy=None if anatomy.path == PROCEDURAL_FILE else anatomy.describe())


def anatomy_targets(anatomy, task: str | None) -> tuple[Anatomy, str | None, list[int]]:
    """(the loaded anatomy, the task, the indices of its targets to visit): the procedural
    atrium's ring ``task`` ("left" when None), or a user anatomy's targets named "{task}_..."
    (all when None), in file order.

    Raises:
        UserInputError: a task the anatomy has no targets for (naming the file).
    """
    if anatomy is None:
        anatomy = PROCEDURAL_FILE
    if not isinstance(anatomy, Anatomy):
        anatomy = load_anatomy(anatomy)
    if anatomy.procedural and task is None:
        task = "left"
    if anatomy.procedural and task not in TASKS:
        raise UserInputError(f"task must be 'left' or 'right' on the procedural atrium, got {short_repr(task)}")
    chosen = anatomy.indices(task)
    if not chosen:
        raise UserInputError(f"task {short_repr(task)}: anatomy file {quote_path(anatomy.path)} has no "
                             f"targets named {task}_... (leave the task out for all its targets)")
    return anatomy, task, chosen
