"""The paper's clinical system in simulation: two spheres beside the patient.

The paper (Section V-A) sizes its clinical actuation by scaling Table I: two N52 spheres of
119 mm (6.6 kg), one each side of the patient, for an 8 Fr chain (balls of 2.17 mm in a 0.5 mm
sleeve, alpha = 0.32 of today's ball volume), and says they give 10 gf at the tip. Here the
same system is simulated with the project's physics:

* **Placement.** The paper's sizing equation puts each magnet's centre at d = d_c + d_d / 2
  from the heart (d_c = 29.65 cm, half the 99th-percentile bideltoid breadth, is the heart to
  the outside of the arm; the magnet must be outside the patient). The reference point of "the
  heart" is taken as the atrium's centre (the origin of the procedural atrium): the targets
  surround it, and the sizing's distance is one number for all of them. The magnets sit on the
  patient's left and right (+x and -x of the atrium frame), level with the centre.
* **Chains.** Today's chain (16 balls of 3.175 mm in today's sleeve, ID 3.0 / OD 3.5 mm) and the
  8 Fr chain: balls of 2.17 mm (2.17^3 / 3.175^3 = 0.319, the paper's alpha) as many as give
  at least today's inserted length (24 balls, 52.1 mm against 50.8 mm), in a sleeve of OD 2.67 mm (8 Fr)
  and ID 2.17 mm: the paper's "0.5 mm" is the OD - ID of today's sleeve (3.5 - 3.0 mm), same
  silicone.
* **Force per target.** The tip ball held on the target (the four vein ostia as Table I's pins,
  the 38 ring targets within their 5 mm circle); both magnets' dipole directions chosen to
  maximise the force pressed along the target's axis with the wall's tangential push inside
  the friction cone of the simulation's contact model (mu 0.1), as the planner does
  (``inverse_statics.max_force_orientation``, SNOPT over held equilibria), started from the
  best of a few field directions.
* **Sizing.** For a sphere of diameter D at d_c + D/2 the field in the atrium grows with D
  (D^3 / (d_c + D/2)^3), and so does each target's best force. The diameter at which a target
  reaches 10 gf is found by bracketed false position (Illinois) on log F against log D, a
  bisection that uses the curve's smoothness; the sizing for "every vein" is the largest of the
  veins', for 90 % / 100 % of the ring targets the quantiles of the targets'. A size where the
  search finds nothing inside the cone although a smaller one pressed is searched again from the
  seeds and then stepped over (2 % up, twice at most): the force grows with D, so such a point is
  the search's failure; where it persists the crossing found is an upper bound. Mass and the
  force between the two magnets follow from ``optimization.sizing``.

The tip force's make-up is measured at each optimum by force balance: the pin's push equals the
field's gradient pull on balls 2..n plus what the sheath pushes into the chain through ball 1
(the torque on the bent chain, carried to the tip); ``gradient_share`` is the first part's share.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from ballchain.drake_models.dipole import dipole_field
from ballchain.infrastructure.errors import UserInputError, check_in, short_repr
from ballchain.drake_models.heart import LeftAtrium
from ballchain.drake_models.params import BallChain, SphereMagnet, gram_force
from ballchain.infrastructure.safe_files import agg_pyplot, atomic_write_text, save_figure, write_csv
from ballchain.experiments._result import Result, optional
from ballchain.experiments.clinical_solver import (  # noqa: F401 (the stand and the solver; their old home re-exports)
    CHAINS,
    MIN_FORCE_GF,
    PAPER,
    TODAY_BALLS,
    VEINS,
    ClinicalField,
    TargetForce,
    TargetSolver,
    _slerp,
    _unit,
    clinical_stand,
    eight_french_chain,
    force_breakdown,
    magnet_distance,
    ring_names,
    seed_directions,
    threshold_diameter,
    todays_chain,
)
from ballchain.optimization.sizing import force_between_magnets
from ballchain.systems.chain_plant import ContactConfig



@dataclass
class ClinicalRow(Result):
    """One chain's best force on one target at the paper's diameter: the ``TargetForce`` with
    the chain, the target's group ("vein", "left ring", "right ring") and ``effective_gf``."""

    chain: str
    target: str
    group: str
    force_gf: float | None
    feasible: bool
    friction_needed: float | None
    gradient_pull_gf: float | None
    sheath_push_gf: float | None
    dipoles: list | None
    evaluations: int
    status: str
    effective_gf: float

    @classmethod
    def of(cls, chain: str, group: str, best: TargetForce) -> "ClinicalRow":
        """The row of ``best`` (its fields, then ``effective_gf``)."""
        return cls(chain=chain, group=group, effective_gf=best.effective_gf,
                   **{f.name: getattr(best, f.name) for f in fields(TargetForce)})


@dataclass
class TargetSizing(Result):
    """One chain's sizing of one target: the diameter [mm] that gives it 10 gf (None: not within
    the search limit), the search's steps and its (diameter [mm], force [gf]) history."""

    chain: str
    target: str
    group: str
    reachable: bool
    diameter_mm: float | None
    steps: int
    history: list


@dataclass
class SizingRow(Result):
    """One chain's sizing by one criterion ("10 gf on every vein", "... 90 % of the ring
    targets", ...): the spheres' diameter [mm], mass [kg], centre distance [cm] and the force
    between the two magnets [gf] (None where no diameter meets it within the search limit)."""

    chain: str
    criterion: str
    diameter_mm: float | None
    mass_kg: float | None
    magnet_distance_cm: float | None
    force_between_magnets_gf: float | None
    size_steps: int
    force_between_side_by_side_gf: float | None = optional()


@dataclass
class ChainSummary(Result):
    """One chain at the paper's diameter: its vein forces and ring coverage [gf] (>= 10 gf inside
    the cone), the equilibria it took and the largest share of the gradient pull in a force."""

    vein_force_gf: dict
    vein_force_gf_min: float | None
    ring_targets: int
    ring_targets_out_of_reach: list
    ring_targets_at_least_10_gf: int
    ring_force_gf_min: float | None
    ring_force_gf_max: float | None
    equilibria: int
    gradient_share_max: float | None


@dataclass
class ChainInfo(Result):
    """A chain of the study: balls, ball diameter and length [mm], alpha (its ball volume over
    today's) and the sleeve's inner and outer diameters [mm]."""

    n_balls: int
    ball_diameter_mm: float
    length_mm: float
    alpha: float
    sleeve_id_od_mm: list


@dataclass
class ClinicalSetup(Result):
    """The placement and the inputs (mm, cm, kg, mT, gf)."""

    diameter_mm: float
    mass_kg: float
    reference: str
    heart_to_surface_cm: float
    magnet_distance_cm: float
    field_at_centre_coaxial_mT: float
    friction: float
    target_radius_mm: float
    ring_step: int
    ring_offset: int
    chains: dict[str, ChainInfo]
    min_force_gf: float
    max_diameter_mm: float


@dataclass
class ClinicalResult(Result):
    """What ``run`` returns (edge units: mm, cm, gf, kg).

    Attributes:
        setup: placement, magnets, chains, friction, targets.
        rows: one per chain and target at the paper's diameter.
        summary: per chain: vein forces and ring coverage (>= 10 gf inside the cone).
        sizing: per chain and criterion ("every vein", "90 % of ring targets", "100 % ...").
        target_sizing: per chain and target: the diameter that gives it 10 gf.
        solves: equilibria solved; compute_time_s: wall time.
        paper: the paper's numbers (``PAPER``).
        files: the paths ``write_files`` wrote (empty before).
    """

    setup: ClinicalSetup
    rows: list[ClinicalRow]
    summary: dict[str, ChainSummary]
    sizing: list[SizingRow]
    target_sizing: list[TargetSizing]
    solves: int
    compute_time_s: float
    paper: dict = field(default_factory=lambda: dict(PAPER))
    files: list = field(default_factory=list)


def _quantile_diameter(diameters: list, fraction: float) -> float | None:
    """The smallest D for which at least ``fraction`` of the targets reach the force (None: not
    within the search range)."""
    need = math.ceil(fraction * len(diameters) - 1e-9)
    finite = sorted(d for d in diameters if d is not None)
    return finite[need - 1] if len(finite) >= need and need > 0 else None


def sizing_row(chain_key: str, criterion: str, diameter: float | None, heart_to_surface: float,
               reference: str, size_steps: int) -> SizingRow:
    """The sizing row of a chain and criterion for spheres of ``diameter`` [m] (None: none found)."""
    if diameter is None:
        return SizingRow(chain_key, criterion, None, None, None, None, size_steps)
    sphere = SphereMagnet(diameter=diameter)
    r = magnet_distance(diameter, heart_to_surface, reference)
    between = force_between_magnets(sphere.dipole_moment, 2.0 * r)
    return SizingRow(chain_key, criterion, diameter_mm=1e3 * diameter, mass_kg=sphere.mass, magnet_distance_cm=1e2 * r,
                     force_between_magnets_gf=gram_force(max(v["force_N"] for v in between.values())),
                     size_steps=size_steps,
                     force_between_side_by_side_gf=gram_force(between["side_by_side_parallel"]["force_N"]))


MAX_DIAMETER_MM = 2000.0  # the largest sphere searched or given [mm]: beyond the widest cart
MAX_HEART_TO_SURFACE_CM = 100.0  # d_c [cm]: a torso is about 30 cm across
MAX_FRICTION = 10.0  # as the planner's --friction


def check_inputs(*, chains, ring_step: int, diameter_mm: float, heart_to_surface_cm: float, friction: float,
                 reference: str, max_diameter_mm: float, veins=VEINS) -> None:
    """Raise UserInputError for bad input, before any solve."""
    unknown = [c for c in chains if c not in CHAINS]
    if not chains or unknown:
        raise UserInputError(f"--chains must be some of {sorted(CHAINS)}, got {list(chains)}")
    if isinstance(ring_step, bool) or not isinstance(ring_step, int) or ring_step < 0:
        raise UserInputError(f"--ring-step must be an integer >= 0 (0: no ring targets), got {ring_step!r}")
    for name, value, hi, unit in (("diameter_mm", diameter_mm, MAX_DIAMETER_MM, "mm"),
                                  ("heart_to_surface_cm", heart_to_surface_cm, MAX_HEART_TO_SURFACE_CM, "cm"),
                                  ("max_diameter_mm", max_diameter_mm, MAX_DIAMETER_MM, "mm")):
        check_in(f"--{name.replace('_', '-')}", value, 0.0, hi, lo_open=True, unit=unit)
    if max_diameter_mm < diameter_mm:
        raise UserInputError(f"--max-diameter-mm ({max_diameter_mm}) must be >= --diameter-mm ({diameter_mm})")
    check_in("--friction", friction, 0.0, MAX_FRICTION)
    if isinstance(veins, str) or not all(isinstance(v, str) and v in VEINS for v in veins):
        raise UserInputError(f"veins must be some of {', '.join(VEINS)}, got {short_repr(veins)}")
    if reference not in ("surface", "centre"):
        raise UserInputError(f"--reference must be 'surface' or 'centre', got {reference!r}")


def run(*, chains=("8Fr", "today"), ring_step: int = 3, ring_offset: int = 0, sizing: bool = True,
        diameter_mm: float = PAPER["diameter_mm"], heart_to_surface_cm: float = PAPER["heart_to_surface_cm"],
        friction: float = ContactConfig().friction, reference: str = "surface",
        max_diameter_mm: float = 1000.0, veins=VEINS, progress: bool = True) -> ClinicalResult:
    """The paper's clinical design in simulation, and the model's own sizing.

    Args:
        chains: which chains ("8Fr", "today").
        ring_step: every ``ring_step``-th target of each ring (1: all 38; 0: none).
        ring_offset: the first ring target taken (0-based), so runs can split a ring.
        sizing: also find each target's 10 gf diameter and the sizing quantiles.
        diameter_mm: the spheres' diameter for the forces table (the paper's 119 mm).
        heart_to_surface_cm: d_c.
        friction: the tip-wall friction coefficient (the simulation's contact model's 0.1).
        reference: "surface" (magnet centre at d_c + D/2 from the atrium centre, the paper's
            sizing) or "centre" (at d_c).
        max_diameter_mm: the sizing's search limit.
        veins: which veins.
    """
    from tqdm import tqdm

    check_inputs(chains=chains, ring_step=ring_step, diameter_mm=diameter_mm,
                 heart_to_surface_cm=heart_to_surface_cm, friction=friction, reference=reference,
                 max_diameter_mm=max_diameter_mm, veins=veins)
    if isinstance(ring_offset, bool) or not isinstance(ring_offset, int) or not 0 <= ring_offset < 18:
        raise UserInputError(f"ring_offset must be an integer in [0, 18), got {ring_offset!r}")
    t0 = time.perf_counter()
    atrium = LeftAtrium()
    D0, d_c, D_max = diameter_mm * 1e-3, heart_to_surface_cm * 1e-2, max_diameter_mm * 1e-3
    target_radius = 0.5 * atrium.params.target_diameter
    rows, target_sizing, sizing_rows, summary, chain_info = [], [], [], {}, {}
    solves = 0
    for key in chains:
        chain = CHAINS[key]()
        stand = clinical_stand(chain, D0, d_c, reference, atrium)
        rings = {task: [n for n in stand.targets if n.startswith(task + "_")] for task in ("left", "right")}
        picked = list(veins)
        if ring_step:
            for task in ("left", "right"):
                picked += rings[task][ring_offset::ring_step]
        chain_info[key] = ChainInfo(n_balls=chain.n_balls, ball_diameter_mm=1e3 * chain.ball_diameter,
                                    length_mm=1e3 * chain.length, alpha=chain.ball_volume / BallChain().ball_volume,
                                    sleeve_id_od_mm=[1e3 * chain.sleeve.inner_diameter,
                                                     1e3 * chain.sleeve.outer_diameter])
        for name in tqdm(picked, desc=f"clinical {key}", unit="target", disable=not progress):
            group = "vein" if name in VEINS else name.split("_")[0] + " ring"
            solver = TargetSolver(chain, name, friction, 0.0 if name in VEINS else target_radius, d_c, reference,
                                  atrium)
            best = solver.solve(D0)
            rows.append(ClinicalRow.of(key, group, best))
            if sizing:
                found = threshold_diameter(solver, best, D0, max_diameter=D_max)
                target_sizing.append(TargetSizing(
                    chain=key, target=name, group=group, reachable=best.status != "out of reach",
                    diameter_mm=None if found["diameter_m"] is None else 1e3 * found["diameter_m"],
                    steps=found["steps"], history=[(1e3 * d, f) for d, f in found["history"]]))
            solves += solver.solves
        chain_solves = solves - sum(v.equilibria for v in summary.values())
        mine = [r for r in rows if r.chain == key]
        veins_gf = [r.effective_gf for r in mine if r.group == "vein"]
        ring_gf = [r.effective_gf for r in mine if r.group != "vein"]
        summary[key] = ChainSummary(
            vein_force_gf={r.target: r.effective_gf for r in mine if r.group == "vein"},
            vein_force_gf_min=min(veins_gf) if veins_gf else None,
            ring_targets=len(ring_gf),
            ring_targets_out_of_reach=[r.target for r in mine if r.status == "out of reach"],
            ring_targets_at_least_10_gf=sum(f >= MIN_FORCE_GF * (1 - 1e-4) for f in ring_gf),
            ring_force_gf_min=min(ring_gf) if ring_gf else None,
            ring_force_gf_max=max(ring_gf) if ring_gf else None,
            equilibria=chain_solves,
            gradient_share_max=max((abs(r.gradient_pull_gf) / r.force_gf for r in mine if r.force_gf), default=None),
        )
        if sizing:
            mine_s = [t for t in target_sizing if t.chain == key]
            steps = sum(t.steps for t in mine_s)
            vein_d = [t.diameter_mm for t in mine_s if t.group == "vein"]
            ring_d = [t.diameter_mm for t in mine_s if t.group != "vein" and t.reachable]
            unreachable = sum(1 for t in mine_s if t.group != "vein" and not t.reachable)
            every_vein = None if (not vein_d or None in vein_d) else max(vein_d) * 1e-3
            sizing_rows.append(sizing_row(key, "10 gf on every vein", every_vein, d_c, reference, steps))
            for fraction, label in ((0.9, "90 %"), (1.0, "100 %")):
                q = _quantile_diameter(ring_d, fraction) if ring_d else None
                criterion = f"10 gf on {label} of the ring targets" + (
                    f" it reaches ({unreachable} of {unreachable + len(ring_d)} out of its reach)" if unreachable else "")
                sizing_rows.append(sizing_row(key, criterion, None if q is None else 1e-3 * q, d_c, reference, steps))
    magnet = SphereMagnet(diameter=D0)
    r0 = magnet_distance(D0, d_c, reference)
    setup = ClinicalSetup(
        diameter_mm=diameter_mm, mass_kg=magnet.mass, reference=reference,
        heart_to_surface_cm=heart_to_surface_cm, magnet_distance_cm=1e2 * r0,
        # Both dipoles along the line through them: the largest field the pair makes at the centre.
        field_at_centre_coaxial_mT=1e3 * 2 * float(np.linalg.norm(dipole_field(np.array([r0, 0.0, 0.0]),
                                                                                np.array([magnet.dipole_moment, 0.0, 0.0])))),
        friction=friction, target_radius_mm=1e3 * target_radius, ring_step=ring_step, ring_offset=ring_offset,
        chains=chain_info, min_force_gf=MIN_FORCE_GF, max_diameter_mm=max_diameter_mm,
    )
    return ClinicalResult(setup, rows, summary, sizing_rows, target_sizing, solves, time.perf_counter() - t0)


def write_files(result: ClinicalResult, out: Path) -> list[str]:
    """CSV of the rows, the JSON, the force-per-target figure and the sizing curves."""
    plt = agg_pyplot()
    out.mkdir(parents=True, exist_ok=True)
    keys = ["chain", "target", "group", "force_gf", "effective_gf", "feasible", "friction_needed",
            "gradient_pull_gf", "sheath_push_gf", "status"]
    files = [write_csv(out / "clinical.csv", [{k: getattr(r, k) for k in keys} for r in result.rows], keys),
             atomic_write_text(out / "clinical.json", result.to_json())]
    D = result.setup.diameter_mm
    fig, ax = plt.subplots(figsize=(10, 4))
    for key, marker in zip(result.summary, "os^"):
        rows = [r for r in result.rows if r.chain == key]
        forces = [float("nan") if r.status == "out of reach" else r.effective_gf for r in rows]  # a gap
        ax.plot(range(len(rows)), forces, marker, linestyle="-",
                label=f"{key} ({result.setup.chains[key].n_balls} balls)")
        ax.set_xticks(range(len(rows)), [r.target for r in rows], rotation=75, fontsize=7)
    ax.axhline(MIN_FORCE_GF, color="k", linestyle="--", linewidth=1, label="10 gf (paper's goal)")
    ax.set_ylabel("best tip force inside the friction cone [gf]")
    ax.set_ylim(bottom=0.0)
    ax.set_title(f"Two {D:.0f} mm N52 spheres at {result.setup.magnet_distance_cm:.1f} cm: force per target "
                 "(veins, then left and right rings)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    files.append(out / "clinical_forces.png")
    save_figure(fig, files[-1], dpi=110)
    if result.target_sizing:
        fig, ax = plt.subplots(figsize=(6, 4.5))
        colours = {"8Fr": "tab:blue", "today": "tab:orange"}
        for t in result.target_sizing:
            h = sorted(t.history)
            if len(h) < 2:  # out of the chain's reach
                continue
            ax.plot([p[0] for p in h], [max(p[1], 0.3) for p in h], ".-", color=colours.get(t.chain, "k"),
                    alpha=0.35 if t.group != "vein" else 0.9, linewidth=1.5 if t.group == "vein" else 0.8)
        for key, colour in colours.items():
            ax.plot([], [], color=colour, label=key)
        ax.axhline(MIN_FORCE_GF, color="k", linestyle="--", linewidth=1)
        ax.axvline(PAPER["diameter_mm"], color="grey", linestyle=":", label="paper: 119 mm")
        for s in result.sizing:
            if s.diameter_mm and s.criterion.startswith("10 gf on every vein"):
                ax.axvline(s.diameter_mm, color=colours.get(s.chain, "k"), linestyle="--", linewidth=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("sphere diameter D [mm]")
        ax.set_ylabel("best tip force [gf]")
        ax.set_title("Sizing: each target's force against the spheres' size (veins bold)")
        ax.legend(fontsize=8)
        fig.tight_layout()
        files.append(out / "clinical_sizing.png")
        save_figure(fig, files[-1], dpi=110)
    return [str(f) for f in files]
