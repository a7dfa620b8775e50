"""Tip forces on the pulmonary veins (paper Table I), from statics with the tip held on a sensor.

The stand: the transseptal sheath of the procedural left atrium (``drake_models.heart``), the
four pulmonary-vein ostia as force-sensor pins, and the prototype magnet 16.51 cm from the septal
puncture on the patient's right (Configuration 1) or left (Configuration 2), level with it.
For each vein the tip ball is held touching the pin (its centre a ball radius inside the ostium,
on the vein's axis); the statics' tip multiplier is the force the pin exerts, and the force the
chain presses along the vein's axis is the sensor's reading. The magnet orientation (and the
number of inserted balls) that maximise it are found by optimisation: a grid of dipole
directions, then Nelder-Mead on the best, each evaluation an equilibrium warm-started from the
last. "both" places the two magnets together and optimises both orientations.

The statics frame S is the canonical one: ball 1 (in the sheath's mouth) at the origin, the
sheath axis along +x; everything in the heart frame H is mapped into it.

Each optimum is then checked by simulation (``forces_dynamics``, ``run(dynamics=True)``): the
chain in the same field as a damped MultibodyPlant, the tip held by a force-sensor pin (a stiff
spring), run to steady state; the pin's reading along the axis is the row's ``dynamics_gf``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from ballchain.infrastructure.arg_checks import as_int_list
from ballchain.drake_models import paper
from ballchain.infrastructure.errors import UserInputError, check_in
from ballchain.drake_models.field_sources import FieldSources, MagnetSource, rotation_with_z_along
from ballchain.drake_models.heart import LeftAtrium
from ballchain.drake_models.params import BallChain, CylinderMagnet, Sleeve, gram_force
from ballchain.infrastructure.safe_files import agg_pyplot, check_output_dir, note_replacements, save_figure, write_csv
from ballchain.experiments._result import Result, optional
from ballchain.optimization.compiled_held_tip import held_solve
from ballchain.optimization.inverse_statics import pin_tip
from ballchain.optimization.statics import ChainStatics

PAPER_GF = paper.TABLE_I_GF
DISTANCE = paper.WORKING_DISTANCE
VEINS = ("LSPV", "LIPV", "RSPV", "RIPV")
# One azimuth is no search (--grid 1 once reported a negative "optimum"; an optimum that does not
# press is now reported as none); the caps bound the work (each evaluation is a statics solve).
GRID = (2, 64)
REFINE = (1, 2000)


@dataclass
class Stand:
    """The force stand in the statics frame S (sheath exit at the origin, sheath along +x)."""

    targets: dict  # vein -> (tip centre (3,), sensor axis (3,) pointing into the vein) [m]
    magnets: dict  # "1" / "2" -> magnet centre (3,) [m]
    R_HS: np.ndarray
    p_HE: np.ndarray


def build_stand(atrium: LeftAtrium | None = None, ball_diameter: float = BallChain().ball_diameter,
                distance: float = DISTANCE) -> Stand:
    atrium = atrium or LeftAtrium()
    R_HS = rotation_with_z_along(atrium.sheath_axis_H)[:, [2, 0, 1]]  # S's x along the sheath
    to_S = lambda p_H: R_HS.T @ (np.asarray(p_H) - atrium.p_HE)  # noqa: E731
    targets = {o.name: (to_S(o.p_HO - 0.5 * ball_diameter * o.axis_H), R_HS.T @ o.axis_H) for o in atrium.ostia}
    right, left = np.array([-1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
    magnets = {"1": to_S(atrium.p_HP + distance * right), "2": to_S(atrium.p_HP + distance * left)}
    return Stand(targets, magnets, R_HS, atrium.p_HE)


def _direction(angles) -> np.ndarray:
    az, el = angles
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def stand_field(stand: Stand, configs, angles, magnet=CylinderMagnet()) -> FieldSources:
    """The stand's magnets ``configs`` ("1", "2") with dipoles at (azimuth, elevation) ``angles``."""
    return FieldSources([
        MagnetSource(magnet, stand.magnets[c], rotation_with_z_along(_direction(angles[2 * k: 2 * k + 2])))
        for k, c in enumerate(configs)
    ])


def max_normal_force(chain: BallChain, stand: Stand, vein: str, configs=("1",), grid: int = 8,
                     refine_evaluations: int = 60, seeds=(), magnet=CylinderMagnet()) -> dict:
    """The largest force the tip presses along the vein's axis, over the magnets' orientations.

    Args:
        chain: the inserted chain (ball 1 held in the sheath's mouth).
        stand: the stand.
        vein: "LSPV", "LIPV", "RSPV" or "RIPV".
        configs: which magnets are present ("1", "2", or both).
        grid: azimuth samples of the initial grid (elevations -60, -30, 0, 30, 60 deg).
        refine_evaluations: Nelder-Mead evaluations from the best grid point.
        seeds: extra orientation vectors (2 angles per magnet) tried first, e.g. the best
            single-magnet orientations when both magnets are present.
        magnet: the magnet at each configuration's place (CylinderMagnet or SphereMagnet;
            default the prototype cylinder).

    Returns:
        {"force_N", "force_gf", "angles_rad", "dipoles", "result" (StaticsResult), "evaluations",
        "refine_converged" (False when the refinement stopped at ``refine_evaluations`` before its
        tolerances: the force may be short of the optimum)} or {"force_N": None, ...} when no
        orientation holds the tip on the pin.
    """
    target, axis = stand.targets[vein]
    if np.linalg.norm(target) > (chain.n_balls - 1) * chain.ball_diameter:
        return {"force_N": None, "reason": "target out of reach of the inserted chain"}
    # A pinned equilibrium a small turn of the magnets away takes a few Newton steps; one that
    # needs many is on another branch (or none): give up on it and try the next orientation.
    solver = ChainStatics(chain, max_iterations=25)
    best = {"force_N": -np.inf, "result": None, "angles": None}
    cache: dict = {}
    evaluations = [0]

    def evaluate(angles, start):
        evaluations[0] += 1
        external = stand_field(stand, configs, angles, magnet)
        if start is None:  # bring the tip onto the pin from the free equilibrium
            result = pin_tip(solver, external, target, None)
        else:  # already on the pin: only the magnets turned (solver.solve's answer, compiled: issue 48)
            result = held_solve(solver, external, start, target)
            if not result.converged:  # no held equilibrium near this one: skip the orientation
                result = None
        if result is None:
            return None, -np.inf
        force = float(-result.tip_reaction @ axis)  # the chain pushes the pin into the vein
        if force > best["force_N"]:
            best.update(force_N=force, result=result, angles=np.array(angles, float))
        return result, force

    # Grid over one magnet's direction (the others start from the same direction), walked as a
    # serpentine so that each equilibrium starts from a neighbouring one.
    previous = None
    for seed in seeds:
        result, _ = evaluate(np.asarray(seed, float), previous)
        previous = result or previous
    for k, el in enumerate(np.radians([-60.0, -30.0, 0.0, 30.0, 60.0])):
        azimuths = np.linspace(0.0, 2 * np.pi, grid, endpoint=False)
        for az in azimuths if k % 2 == 0 else azimuths[::-1]:
            angles = np.tile([az, el], len(configs))
            result, _ = evaluate(angles, previous)
            previous = result or previous
    if best["result"] is None:
        return {"force_N": None, "reason": "no magnet orientation holds the tip on the pin",
                "evaluations": evaluations[0]}

    def objective(angles):
        key = tuple(np.round(angles, 12))
        if key not in cache:
            _, force = evaluate(angles, best["result"])
            cache[key] = -force if np.isfinite(force) else 1e3
        return cache[key]

    refined = minimize(objective, best["angles"], method="Nelder-Mead",
                       options={"maxfev": refine_evaluations, "xatol": 1e-3, "fatol": 1e-9})
    if best["force_N"] <= 0.0:  # the best held equilibrium pulls the tip off the pin: no press found
        return {"force_N": None, "reason": f"no orientation found that presses the pin (the best pulls with "
                f"{gram_force(-best['force_N']):.3g} gf): search a finer grid", "evaluations": evaluations[0]}
    angles = best["angles"]
    return {
        "force_N": best["force_N"],
        "force_gf": gram_force(best["force_N"]),
        "angles_rad": angles,
        "dipoles": [_direction(angles[2 * k: 2 * k + 2]) for k in range(len(configs))],
        "result": best["result"],
        "evaluations": evaluations[0],
        # False: Nelder-Mead stopped at its evaluation limit before its tolerances were met, so the
        # force may lie below the optimum (more refine_evaluations would say how far)
        "refine_converged": bool(refined.success),
    }


def _lateral_gf(force_W: np.ndarray, axis: np.ndarray) -> float:
    """The magnitude of a force across the (unit) axis [gf]."""
    return gram_force(float(np.linalg.norm(force_W - (force_W @ axis) * axis)))


def dynamics_columns(chain: BallChain, stand: Stand, vein: str, configs, best: dict | None, config=None) -> dict:
    """The row's simulation columns: the steady reading of a force-sensor pin holding the tip of the
    damped chain, for the statics optimum ``best`` (``forces_dynamics.simulate_pin_force``)."""
    from ballchain.experiments.forces_dynamics import PinSimulationConfig, pin_force_from_statics

    if best is None:
        return {"dynamics_gf": None, "dynamics_lateral_gf": None, "statics_dynamics_diff_pct": None,
                "dynamics_note": "no statics optimum to simulate"}
    target, axis = stand.targets[vein]
    sim = pin_force_from_statics(chain, stand_field(stand, configs, best["angles_rad"]), target, axis, best["result"],
                                 config or PinSimulationConfig())
    columns = {
        "dynamics_gf": sim.force_gf,
        "dynamics_lateral_gf": sim.lateral_gf,
        "statics_dynamics_diff_pct": None,
        "dynamics_note": sim.reason,
        "dynamics_sim_time_s": round(sim.sim_time_s, 6),
        "dynamics_wall_time_s": round(sim.wall_time_s, 3),
    }
    if sim.force_gf is not None and best["force_gf"] != 0.0:
        columns["statics_dynamics_diff_pct"] = 100.0 * (sim.force_gf - best["force_gf"]) / abs(best["force_gf"])
        columns["dynamics_deflection_um"] = float(np.linalg.norm(sim.deflection_m) * 1e6)
    if sim.statics_loaded_N is not None:  # the statics with the tip where the loaded pin holds it
        columns["statics_at_deflection_gf"] = gram_force(sim.statics_loaded_N)
    return columns

@dataclass
class ForcesResult(Result):
    """What ``run`` returns (edge units: gf, mm).

    Attributes:
        rows: one per vein, configuration ("1", "2", "both") and sleeve: {vein, config, sleeve,
            statics_gf, statics_lateral_gf, n_balls, magnet_dipoles (unit 3-vectors, one per
            magnet), paper_gf, refine_converged (False: the Nelder-Mead refinement stopped at its
            evaluation limit, so statics_gf may be short of the optimum), the simulation columns (``dynamics_columns``: dynamics_gf,
            dynamics_lateral_gf, statics_dynamics_diff_pct, dynamics_note, ...); the "both" row
            also superposition_gf (the sum of the single-magnet optima)}; None where no held
            equilibrium was found.
        paper: Table I, {"<vein> <config> bare|sleeve": gf}.
        stand: {targets_mm: {vein: (3,)}, magnets_mm: {config: (3,)}}.
        files: the paths written (only with ``out``).
    """

    rows: list
    paper: dict
    stand: dict
    files: list | None = optional()


def write_files(data: ForcesResult, out: Path) -> list[str]:
    """Write ``forces.csv`` and the bar chart ``forces.png`` into ``out``; returns their paths."""
    plt = agg_pyplot()
    note_replacements(out, ["forces.csv", "forces.png"], "forces")
    out.mkdir(parents=True, exist_ok=True)
    path = out / "forces.csv"
    keys = ["vein", "config", "sleeve", "statics_gf", "dynamics_gf", "statics_dynamics_diff_pct", "paper_gf",
            "statics_lateral_gf", "dynamics_lateral_gf", "n_balls", "superposition_gf", "dynamics_note",
            "refine_converged"]
    write_csv(path, data.rows, keys)
    rows = data.rows
    labels = [f"{r['vein']} {r['config']}{' S' if r['sleeve'] else ''}" for r in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(6, 0.45 * len(rows)), 4))
    simulated = any(r.get("dynamics_gf") is not None for r in rows)
    width = 0.27 if simulated else 0.4
    shift = width if simulated else 0.5 * width
    ax.bar(x - shift, [r["paper_gf"] for r in rows], width, label="paper (measured)")
    ax.bar(x + (0.0 if simulated else shift), [r["statics_gf"] or 0.0 for r in rows], width, label="model (statics)")
    if simulated:  # the statics optima simulated on the force-sensor pin (a missing one: no bar)
        ax.bar(x + width, [r.get("dynamics_gf") or 0.0 for r in rows], width, label="simulation")
    ax.set_xticks(x, labels, rotation=70, fontsize=7)
    ax.set_ylabel("tip force [gf]")
    ax.set_yscale("log")
    ax.legend()
    ax.set_title("Tip force on the veins: paper vs model (S = sleeve)")
    fig.tight_layout()
    png = out / "forces.png"
    save_figure(fig, png, dpi=110)
    return [str(path), str(png)]


def run(*, veins=("LSPV", "LIPV", "RSPV", "RIPV"), sleeves=(False, True), n_balls=(16,), grid: int = 8,
        refine_evaluations: int = 60, progress: bool = True, dynamics: bool = True,
        out: Path | None = None) -> ForcesResult:
    """Table I: every vein x configuration x sleeve, with the paper's number beside it.

    ``statics_gf`` is the statics optimum; with ``dynamics`` each optimum is also simulated
    (``forces_dynamics``): the chain in the same field, its tip held by a force-sensor pin,
    run to steady state; ``dynamics_gf`` is the pin's reading along the vein's axis,
    ``dynamics_lateral_gf`` its size across it, ``statics_dynamics_diff_pct`` the simulation
    against the statics, and ``dynamics_note`` says why a row has no simulated force. With
    ``out`` (a folder, checked writable before any work) it writes ``forces.csv`` and
    ``forces.png`` there and lists them under ``files``. Returns a ``ForcesResult``.

    Raises:
        UserInputError: an unknown vein or sleeve option, a grid or refine out of range, or an
            unwritable ``out`` (checked before any work; named by the command's flags).
    """
    from tqdm import tqdm

    if not veins or any(v not in VEINS for v in veins):
        raise UserInputError(f"--veins must be among {', '.join(VEINS)}, got {list(veins)}")
    if not sleeves or any(s not in (False, True) for s in sleeves):
        raise UserInputError(f"--sleeve: the sleeve cases must be False (bare) and/or True, got {list(sleeves)}")
    check_in("--grid", grid, *GRID)
    check_in("--refine", refine_evaluations, *REFINE)
    as_int_list(n_balls, "n_balls", 2)
    if out is not None:
        check_output_dir(out, "--out")

    stand = build_stand()
    jobs = [(v, s) for v in veins for s in sleeves]
    rows = []
    for vein, sleeve in tqdm(jobs, desc="tip forces", unit="case", disable=not progress):
        per_config = {}
        for configs, label in ((("1",), "1"), (("2",), "2"), (("1", "2"), "both")):
            best = None
            for n in n_balls:
                chain = BallChain(n_balls=n, sleeve=Sleeve() if sleeve else None)
                seeds = ()
                if label == "both" and per_config.get("1") and per_config.get("2"):
                    seeds = (np.concatenate([per_config["1"]["angles_rad"], per_config["2"]["angles_rad"]]),)
                found = max_normal_force(chain, stand, vein, configs, grid, refine_evaluations, seeds)
                if found.get("force_N") is not None and (best is None or found["force_N"] > best["force_N"]):
                    best = dict(found, n_balls=n)
            per_config[label] = best
            row = {
                "vein": vein, "config": label, "sleeve": sleeve,
                "statics_gf": None if best is None else best["force_gf"],
                "statics_lateral_gf": None if best is None else _lateral_gf(-best["result"].tip_reaction,
                                                                             stand.targets[vein][1]),
                "n_balls": None if best is None else best["n_balls"],
                "magnet_dipoles": None if best is None else [list(map(float, d)) for d in best["dipoles"]],
                "paper_gf": PAPER_GF[(vein, label, sleeve)],
                "refine_converged": None if best is None else best["refine_converged"],
            }
            if dynamics:
                chain = None if best is None else BallChain(n_balls=best["n_balls"],
                                                            sleeve=Sleeve() if sleeve else None)
                row.update(dynamics_columns(chain, stand, vein, configs, best))
            else:
                row.update(dynamics_gf=None, dynamics_lateral_gf=None, statics_dynamics_diff_pct=None,
                           dynamics_note="not simulated")
            rows.append(row)
        singles = [per_config[c]["force_gf"] for c in ("1", "2") if per_config[c] is not None]
        rows[-1]["superposition_gf"] = sum(singles) if len(singles) == 2 else None
    data = ForcesResult(rows=rows,
                        paper={f"{k[0]} {k[1]} {'sleeve' if k[2] else 'bare'}": v for k, v in PAPER_GF.items()},
                        stand={"targets_mm": {k: v[0] * 1e3 for k, v in stand.targets.items()},
                               "magnets_mm": {k: v * 1e3 for k, v in stand.magnets.items()}})
    if out is not None:
        data.files = write_files(data, Path(out))
    return data
