"""Point functions of the sweep studies (``ballchain sweep``, ``ballchain/studies/*.yaml``).

Each experiment here is one point of a sweep: a parameter dataclass (its fields are what a spec's
grid or points may set, with their types and defaults), a function ``point(params, seed) ->
dict`` of scalar outputs that calls an existing experiment (never a re-typed law), a check of the
values (``UserInputError`` naming the field, run before any cluster starts), and optionally a
figure and a headline summary drawn from the finished table. The checks are the commands' own
(``statics_shape.check_inputs``, ``forces.GRID``/``REFINE``, ``teleop.check_inputs`` and the
station scenario's ``validate``, ``workspace.check_inputs``, the parameter classes' checks), so
that a value the command refuses is refused in a spec too, before any point runs.

- ``design``: tip force on a vein from statics (``forces.max_normal_force``) for a ball diameter,
  an actuation magnet (the prototype cylinder or a sphere of any diameter, both placed like the
  Table I stand, one each side) and its distance from the septal puncture.
- ``operators``: a simulated operator doing (the first targets of) a teleoperation task
  (``teleop.run``) with a mapping, an engine and a seed for its hand tremor.
- ``sleeve``: the workspace with one rotating magnet (``workspace.sweep``) of the chain bare and
  in a sleeve of a Young's modulus and wall thickness.
- ``statics``: one equilibrium in a uniform field (cheap: the executor's tests and examples).

``Experiment`` and the shared checks live in ``study_helpers``, the design study in
``studies_design``: both re-exported here.
"""

# No ``from __future__ import annotations``: pydrake's yaml_load_typed reads the parameter
# dataclasses' field types as objects, not strings (as in systems/chain_scenario.py).
import dataclasses
import functools
import inspect
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ballchain.drake_models import paper
from ballchain.infrastructure.errors import UserInputError, check_in
from ballchain.experiments.studies_design import (  # noqa: F401 (re-exported)
    CONFIG_WORDS,
    CONFIGS,
    DESIGN_KEY,
    PROTOTYPE_BALLS,
    TARGET_GF,
    VEINS,
    DesignPoint,
    _design_table,
    _SPHERE,
    design_balls,
    design_check,
    design_figure,
    design_magnet,
    design_point,
    design_summary,
)
from ballchain.experiments.study_helpers import Experiment, _ok, _one_of, _positive, _savefig  # noqa: F401
from ballchain.systems.device_model import engines


# --- statics: one equilibrium in a uniform field ---------------------------------------------------

@dataclass
class StaticsPoint:
    """The canonical chain in a uniform field reached by rotating it from +x.

    Attributes:
        n_balls: chain length.
        field_mT: field magnitude [mT].
        field_angle_deg: final field angle from +x towards +y [deg].
        step_deg: continuation step of the field angle [deg].
        sleeve: the Dragon Skin sleeve.
        max_iterations: Newton iteration limit per solve (a low limit makes the point fail).
    """

    n_balls: int = 8
    field_mT: float = 23.0
    field_angle_deg: float = 90.0
    step_deg: float = 22.5
    sleeve: bool = False
    max_iterations: int = 200


MAX_ITERATIONS = 10_000  # Newton converges in tens of iterations or not at all


def statics_check(p: StaticsPoint) -> None:
    """The ``statics`` command's ranges (``statics_shape.check_inputs``), under the spec's names."""
    from ballchain.experiments.statics_shape import check_inputs

    check_inputs(balls=p.n_balls, field_mT=p.field_mT, field_angle_deg=p.field_angle_deg, step_deg=p.step_deg,
                 names={"balls": "n_balls", "field_mT": "field_mT", "field_angle_deg": "field_angle_deg",
                        "step_deg": "step_deg"})
    if not 1 <= p.max_iterations <= MAX_ITERATIONS:
        raise UserInputError(f"max_iterations must be in 1..{MAX_ITERATIONS}, got {p.max_iterations}")


def statics_point(p: StaticsPoint, seed: int) -> dict:
    from ballchain.drake_models.field_sources import UniformField
    from ballchain.drake_models.params import BallChain, Sleeve
    from ballchain.optimization.statics import ChainStatics, rotation_path, tip_angle_deg

    solver = ChainStatics(BallChain(n_balls=p.n_balls, sleeve=Sleeve() if p.sleeve else None),
                          max_iterations=p.max_iterations)
    result, iterations = None, 0
    for angle in rotation_path(0.0, p.field_angle_deg, p.step_deg):
        result = solver.solve_or_raise(UniformField.in_plane(p.field_mT * 1e-3, math.radians(angle)), result)
        iterations += result.iterations
    a = math.radians(p.field_angle_deg)
    tip = result.positions[-1]
    return {"tip_x_mm": float(tip[0] * 1e3), "tip_y_mm": float(tip[1] * 1e3),
            "tip_angle_deg": tip_angle_deg(result, [math.cos(a), math.sin(a), 0.0]),
            "energy_J": float(result.energy), "iterations": iterations}


# --- operators: teleoperation tasks x mappings x operator seeds ------------------------------------

ENGINES = engines("ball_chain")  # the teleoperated chain's engines (the registry's, ``device_model``)


@dataclass
class OperatorsPoint:
    """One operator (a tremor seed) doing a teleoperation task with a mapping.

    Attributes:
        task: "left" (Task I, 20 targets) or "right" (Task II, 18 targets).
        mapping: "world" (the paper's) or "catheter".
        targets: only the first N targets; 0: all of them.
        engine: "statics" (the quasi-static engine: a whole task in seconds) or "plant" (the
            MultibodyPlant station: minutes per task), passed as the scenario override.
        time_step: quasi-static step [s]; 0: the scenario's (1 ms); 0.004 is ``teleop.FAST``.
        tremor: amplitude of the operator's hand tremor on each stick axis (its seed is the
            point's seed).
        n_balls: chain length (the paper's 16).
    """

    task: str = "right"
    mapping: str = "world"
    targets: int = 0
    engine: str = "statics"
    time_step: float = 0.0
    tremor: float = 0.1
    n_balls: int = 16


def _operators_overrides(p: OperatorsPoint) -> str:
    """The station scenario's overrides of a point (as ``teleop --set`` takes them)."""
    # The engine is always named: the teleop experiment's own default is the quasi-static engine.
    overrides = {"engine": p.engine}
    if p.time_step > 0:
        overrides["time_step"] = p.time_step
    return json.dumps(overrides)


@functools.lru_cache(maxsize=64)
def _check_station(mapping: str, n_balls: int, overrides: str) -> None:
    """The station scenario a point runs (``teleop.scenario_for``: the scenario's own checks, e.g.
    its time step's range); loaded once per distinct combination."""
    from ballchain.experiments.teleop import scenario_for

    scenario_for(mapping, n_balls, overrides)


def operators_check(p: OperatorsPoint) -> None:
    """The ``teleop`` command's checks (``teleop.check_inputs``) and the station scenario's."""
    from ballchain.experiments.teleop import check_inputs

    _one_of("engine", p.engine, ENGINES)
    if p.targets < 0:
        raise UserInputError(f"targets must be >= 0 (0: all), got {p.targets}")
    check_inputs(p.task, p.mapping, p.targets or None, p.n_balls, None)
    # The operator's stick axes are clipped to [-1, 1]: a larger tremor only saturates them.
    check_in("tremor", p.tremor, 0.0, 1.0)
    _positive("time_step", p.time_step, zero_ok=True)
    _check_station(p.mapping, p.n_balls, _operators_overrides(p))


def operators_point(p: OperatorsPoint, seed: int) -> dict:
    from ballchain.experiments import teleop
    from ballchain.systems.simulated_operator import OperatorParams

    overrides, engine_used, note = _operators_overrides(p), p.engine, None
    operator = OperatorParams(axes=(0, 1, 2) if p.mapping == "world" else (0, 1), tremor=p.tremor, seed=seed)
    result = teleop.run(task=p.task, mapping=p.mapping, targets=p.targets or None, progress=False,
                        n_balls=p.n_balls, overrides=overrides,
                        operator=operator)
    s = result.summary
    rows = result.rows
    return {
        "engine_used": engine_used, "note": note,
        "touched": s.touched, "n_targets": s.targets, "total_time_s": s.total_time_s,
        "median_time_s": s.median_time_s, "median_accuracy_mm": s.median_accuracy_mm,
        "max_accuracy_mm": s.max_accuracy_mm, "failure": s.failure, "sim_time_s": s.sim_time_s,
        "realtime_factor": s.realtime_factor,
        "target_names": [r["target"] for r in rows],
        "target_times_s": [r["time_s"] for r in rows],
        "target_accuracy_mm": [r["accuracy_mm"] for r in rows],
        "target_touched": [bool(r["touched"]) for r in rows],
        "paper_time_per_target_s": result.paper["human_time_s"] / result.paper["targets"],
    }


def _per_target(rows) -> dict:
    """(task, mapping) -> target -> {"times": [...], "accuracy": [...], "missed": n}."""
    out: dict = {}
    for r in _ok(rows):
        names = json.loads(r["target_names"])
        times, acc, touched = (json.loads(r[k]) for k in ("target_times_s", "target_accuracy_mm", "target_touched"))
        for name, t, a, ok in zip(names, times, acc, touched):
            cell = out.setdefault((r["task"], r["mapping"]), {}).setdefault(name, {"times": [], "accuracy": [],
                                                                                  "missed": 0})
            if ok:
                cell["times"].append(t)
                cell["accuracy"].append(a)
            else:
                cell["missed"] += 1
    return out


def operators_summary(rows) -> dict:
    """Per task, mapping and target: median, quartiles of time and accuracy over the seeds."""
    from ballchain.experiments.teleop import PAPER

    table = []
    for (task, mapping), targets in sorted(_per_target(rows).items()):
        for name, c in targets.items():
            t, a = np.array(c["times"]), np.array(c["accuracy"])
            table.append({"task": task, "mapping": mapping, "target": name, "runs": len(t) + c["missed"],
                          "missed": c["missed"],
                          "time_median_s": float(np.median(t)) if len(t) else None,
                          "time_q25_s": float(np.percentile(t, 25)) if len(t) else None,
                          "time_q75_s": float(np.percentile(t, 75)) if len(t) else None,
                          "time_mean_s": float(np.mean(t)) if len(t) else None,
                          "accuracy_median_mm": float(np.median(a)) if len(a) else None,
                          "paper_mean_time_per_target_s": PAPER[task]["human_time_s"] / PAPER[task]["targets"]})
    engines = sorted({r.get("engine_used") for r in _ok(rows)})
    return {"per_target": table, "engines_used": engines,
            "paper": "the paper's operator, 5 trials after learning, world mapping: Task I 40 s for 20 targets "
                     "(2.0 s a target), Task II 26 s for 18 (1.44 s a target; manual catheter 33 s)"}


def operators_figure(rows, out: Path) -> Path:
    """Per-target time (box over seeds) for each task and mapping, the paper's mean per target."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ballchain.experiments.teleop import PAPER

    per = _per_target(rows)
    tasks = sorted({k[0] for k in per})
    fig, axes = plt.subplots(2, len(tasks), figsize=(6 * len(tasks), 7), squeeze=False)
    for col, task in enumerate(tasks):
        for row, (what, unit) in enumerate((("times", "time on target [s]"), ("accuracy", "accuracy [mm]"))):
            ax = axes[row][col]
            mappings = sorted(m for t, m in per if t == task)
            names = list(per[(task, mappings[0])])
            width = 0.8 / len(mappings)
            for j, mapping in enumerate(mappings):
                data = [per[(task, mapping)].get(n, {what: []})[what] or [np.nan] for n in names]
                pos = np.arange(len(names)) + (j - (len(mappings) - 1) / 2) * width
                bp = ax.boxplot(data, positions=pos, widths=width * 0.9, patch_artist=True, manage_ticks=False)
                for box in bp["boxes"]:
                    box.set_facecolor(f"C{j}")
                    box.set_alpha(0.6)
                ax.plot([], [], "s", color=f"C{j}", label=mapping)
            if what == "times":
                ax.axhline(PAPER[task]["human_time_s"] / PAPER[task]["targets"], color="k", ls="--", lw=1,
                           label="paper: mean per target (total / targets)")
            ax.set_xticks(range(len(names)), names, rotation=45, fontsize=8)
            ax.set_ylabel(unit)
            ax.set_title(f"task {task} ({'I' if task == 'left' else 'II'})")
            ax.legend(fontsize=8)
    fig.tight_layout()
    return _savefig(fig, Path(out) / "operators.png")


# --- sleeve: workspace against the sleeve's stiffness ----------------------------------------------

@dataclass
class SleevePoint:
    """The workspace of a chain in a sleeve, beside the bare chain's.

    Attributes:
        youngs_modulus_MPa: the sleeve's E [MPa] (Dragon Skin 10 NV: about 0.15).
        wall_thickness_mm: (OD - ID) / 2 [mm] (the prototype's 0.25).
        inner_diameter_mm: ID [mm] (3.0).
        n_balls: chain length.
        step_deg: magnet turn step of the workspace sweep [deg].
        distance_cm: the magnet's distance beside the insertion point [cm] (16.51).
    """

    youngs_modulus_MPa: float = 0.15
    wall_thickness_mm: float = 0.25
    inner_diameter_mm: float = 3.0
    n_balls: int = 16
    step_deg: float = 5.0
    distance_cm: float = paper.WORKING_DISTANCE * 100


def sleeve_check(p: SleevePoint) -> None:
    """The ``workspace`` command's step and distance ranges (``workspace.check_inputs``), the
    statics' chain length and the parameter classes' own checks (a sleeve over the balls)."""
    from ballchain.drake_models.params import BallChain
    from ballchain.experiments.statics_shape import MAX_BALLS
    from ballchain.experiments.workspace import check_inputs

    _positive("youngs_modulus_MPa", p.youngs_modulus_MPa)
    _positive("wall_thickness_mm", p.wall_thickness_mm)
    _positive("inner_diameter_mm", p.inner_diameter_mm)
    if not 2 <= p.n_balls <= MAX_BALLS:
        raise UserInputError(f"n_balls must be in 2..{MAX_BALLS}, got {p.n_balls}")
    check_inputs(p.step_deg, p.distance_cm * 1e-2, names=("step_deg", "distance_cm"))
    BallChain(n_balls=p.n_balls, sleeve=_sleeve(p))


def _sleeve(p: SleevePoint):
    from ballchain.drake_models.params import Sleeve

    return Sleeve(youngs_modulus=p.youngs_modulus_MPa * 1e6, inner_diameter=p.inner_diameter_mm * 1e-3,
                  outer_diameter=(p.inner_diameter_mm + 2 * p.wall_thickness_mm) * 1e-3)


def sleeve_point(p: SleevePoint, seed: int) -> dict:
    from ballchain.drake_models.params import BallChain
    from ballchain.experiments.workspace import sweep, tip_to_tip_distance, workspace_area

    sleeve = _sleeve(p)
    curves = {}
    for label, s in (("bare", None), ("sleeve", sleeve)):
        chain = BallChain(n_balls=p.n_balls, sleeve=s)
        curves[label] = {side: sweep(chain, side, p.step_deg, p.distance_cm * 1e-2)[0] * 1e3 for side in (1, -1)}
    bare = 0.5 * workspace_area(curves["bare"][1], curves["bare"][-1])
    sleeved = 0.5 * workspace_area(curves["sleeve"][1], curves["sleeve"][-1])
    return {"bending_stiffness_Nm2": sleeve.bending_stiffness, "half_area_bare_mm2": bare,
            "half_area_sleeve_mm2": sleeved, "reduction_pct": 100.0 * (1.0 - sleeved / bare),
            "tip_to_tip_max_mm": tip_to_tip_distance(curves["sleeve"], curves["bare"])}


def sleeve_summary(rows) -> dict:
    from ballchain.experiments.workspace import PAPER

    ok = sorted(_ok(rows), key=lambda r: (r["wall_thickness_mm"], r["youngs_modulus_MPa"]))
    paper_like = [r for r in ok if r["reduction_pct"] >= PAPER["reduction_pct"]]
    # The reduction is (nearly) a function of EI alone: interpolate where it crosses the paper's,
    # in log EI, between the neighbouring points of the whole table.
    by_ei = sorted((r["bending_stiffness_Nm2"], r["reduction_pct"]) for r in ok)
    crossing = None
    for (e0, r0), (e1, r1) in zip(by_ei, by_ei[1:]):
        if r0 < PAPER["reduction_pct"] <= r1:
            w = (PAPER["reduction_pct"] - r0) / (r1 - r0)
            crossing = float(np.exp(np.log(e0) + w * (np.log(e1) - np.log(e0))))
            break
    from ballchain.drake_models.params import Sleeve

    return {"paper": PAPER, "ei_for_paper_reduction_Nm2": crossing,
            "dragon_skin_ei_Nm2": Sleeve().bending_stiffness, "rows": [{k: r[k] for k in ("youngs_modulus_MPa", "wall_thickness_mm",
                                                        "bending_stiffness_Nm2", "half_area_sleeve_mm2",
                                                        "reduction_pct", "tip_to_tip_max_mm")} for r in ok],
            "softest_with_paper_reduction": min(paper_like, key=lambda r: r["bending_stiffness_Nm2"],
                                                default=None)}


def sleeve_figure(rows, out: Path) -> Path:
    """Workspace reduction and tip-to-tip distance against the sleeve's bending stiffness EI
    (E times the tube's second moment of area), one line per wall thickness."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ballchain.drake_models.params import Sleeve
    from ballchain.experiments.workspace import PAPER

    ok = _ok(rows)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for t in sorted({r["wall_thickness_mm"] for r in ok}):
        pts = sorted((r["bending_stiffness_Nm2"], r["reduction_pct"], r["tip_to_tip_max_mm"], r["youngs_modulus_MPa"])
                     for r in ok if r["wall_thickness_mm"] == t)
        ei, red, ttt, e = zip(*pts)
        axes[0].plot(ei, red, "o-", label=f"wall {t} mm (E {min(e):g}-{max(e):g} MPa)")
        axes[1].plot(ei, ttt, "o-", label=f"wall {t} mm")
    axes[0].axhline(PAPER["reduction_pct"], color="k", ls="--", lw=1, label="paper (measured): 12 %")
    axes[1].axhline(PAPER["tip_to_tip_mm"], color="k", ls="--", lw=1, label="paper: about 8 mm")
    for ax in axes:
        ax.axvline(Sleeve().bending_stiffness, color="grey", ls=":", lw=1)
        ax.set_xscale("log")
        ax.set_xlabel("sleeve bending stiffness EI [N m^2] (dotted: Dragon Skin 10, 0.15 MPa, 0.25 mm wall)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("half-workspace reduction by the sleeve [%]")
    axes[1].set_ylabel("largest tip-to-tip distance, sleeve vs bare [mm]")
    n = ok[0]["n_balls"] if ok else 16
    fig.suptitle(f"{n} balls, one magnet {ok[0]['distance_cm'] if ok else 16.51} cm away, sleeve ID 3.0 mm "
                 "(tip-to-tip jumps where one chain snaps through and the other does not)")
    fig.tight_layout()
    return _savefig(fig, Path(out) / "sleeve.png")


def field_docs(params: type) -> dict[str, str]:
    """{field: its description} from a parameter dataclass's ``Attributes:`` docstring section
    (Google style: ``name: text`` with indented continuation lines); for the sweep reference."""
    docs: dict[str, str] = {}
    lines = inspect.cleandoc(params.__doc__ or "").splitlines()
    if "Attributes:" not in lines:
        return docs
    name = None
    for line in lines[lines.index("Attributes:") + 1:]:
        if not line.strip():
            break
        field = re.match(r"^    (\w+): (.*)$", line)
        if field and field.group(1) in {f.name for f in dataclasses.fields(params)}:
            name = field.group(1)
            docs[name] = field.group(2).strip()
        elif name is not None:
            docs[name] += " " + line.strip()
    return docs


# What each experiment's points return: the columns of the sweep's table after the parameters.
STATICS_OUTPUTS = {
    "tip_x_mm": "the tip ball's centre along the insertion direction +x [mm]",
    "tip_y_mm": "the tip ball's centre along +y, the field's turning side [mm]",
    "tip_angle_deg": "angle between the tip ball's dipole and the final field [deg]",
    "energy_J": "the chain's total potential energy at equilibrium [J]",
    "iterations": "Newton iterations of the continuation, summed over its steps",
}
DESIGN_OUTPUTS = {
    "n_balls_used": "the chain length simulated (n_balls, or the prototype's length in balls of this size)",
    "magnet_mass_kg": "one actuation magnet's mass [kg] (N52, 7500 kg/m^3)",
    "magnet_moment_Am2": "one actuation magnet's dipole moment [A m^2]",
    "chain_moment_Am2": "the chain's summed dipole moment [A m^2]",
    "clearance_mm": "the nearest magnet's surface beyond the chain's reach from the sheath exit [mm] "
                    "(<= 0: no force computed)",
    "force_gf": "the largest tip force along the vein's axis over the magnets' orientations [gf] "
                "(empty: no orientation presses the pin)",
    "lateral_gf": "the tip force across the vein's axis at that optimum [gf]",
    "reaches_target": "force_gf >= 10 gf, the paper's clinically relevant force (empty: not computed)",
    "evaluations": "statics solves of the orientation search (grid and Nelder-Mead)",
    "refine_converged": "whether Nelder-Mead met its tolerances within refine_evaluations (false: force_gf may "
                        "be short of the optimum)",
    "note": "why a row has no force, or that the refinement stopped short",
}
OPERATORS_OUTPUTS = {
    "engine_used": "the station's engine (statics: quasi-static; plant: MultibodyPlant)",
    "note": "a remark on the run (empty when none)",
    "touched": "targets touched by the tip",
    "n_targets": "targets asked for",
    "total_time_s": "simulated time of the whole task [s]",
    "median_time_s": "median time from one target to the next [s]",
    "median_accuracy_mm": "median distance of the touch from the target's centre [mm]",
    "max_accuracy_mm": "largest such distance [mm]",
    "failure": "why the run stopped early (empty: it ended normally)",
    "sim_time_s": "simulated time [s]",
    "realtime_factor": "simulated seconds per wall-clock second",
    "target_names": "JSON list: the targets in order",
    "target_times_s": "JSON list: each target's time [s] (null: not touched)",
    "target_accuracy_mm": "JSON list: each touch's distance from the centre [mm]",
    "target_touched": "JSON list: whether each target was touched",
    "paper_time_per_target_s": "the paper's operator's time per target on this task [s]",
}
SLEEVE_OUTPUTS = {
    "bending_stiffness_Nm2": "the sleeve's bending stiffness E I [N m^2]",
    "half_area_bare_mm2": "half the area swept by the bare chain's tip as the magnet turns [mm^2]",
    "half_area_sleeve_mm2": "the same for the chain in this sleeve [mm^2]",
    "reduction_pct": "the sleeve's loss of workspace: 100 (1 - sleeve / bare) [%]",
    "tip_to_tip_max_mm": "largest distance between the two tips at the same magnet angle [mm]",
}


EXPERIMENTS: dict[str, Experiment] = {
    e.name: e for e in (
        Experiment("statics", StaticsPoint, statics_point, statics_check,
                   description="one equilibrium of the canonical chain in a uniform field", typical_s=0.05,
                   shown=("tip_x_mm", "tip_y_mm", "tip_angle_deg", "iterations"), outputs=STATICS_OUTPUTS),
        Experiment("design", DesignPoint, design_point, design_check, design_figure, design_summary,
                   "ball size x actuation magnet x distance -> tip force on a vein (statics)", typical_s=10.0,
                   shown=("n_balls_used", "force_gf", "lateral_gf", "reaches_target", "note"), outputs=DESIGN_OUTPUTS),
        Experiment("operators", OperatorsPoint, operators_point, operators_check, operators_figure,
                   operators_summary, "simulated operators on the teleoperation tasks", typical_s=10.0,
                   shown=("touched", "n_targets", "total_time_s", "median_accuracy_mm", "failure"),
                   outputs=OPERATORS_OUTPUTS),
        Experiment("sleeve", SleevePoint, sleeve_point, sleeve_check, sleeve_figure, sleeve_summary,
                   "workspace against the sleeve's Young's modulus and wall thickness", typical_s=15.0,
                   shown=("half_area_bare_mm2", "half_area_sleeve_mm2", "reduction_pct", "tip_to_tip_max_mm"),
                   outputs=SLEEVE_OUTPUTS),
    )
}
