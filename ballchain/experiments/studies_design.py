"""The ``design`` sweep study: tip force on a vein from statics (``forces.max_normal_force``) for a
ball diameter, an actuation magnet (the prototype cylinder or a sphere of any diameter, both
placed like the Table I stand, one each side) and its distance from the septal puncture.
``studies`` registers it and re-exports its names.
"""

# No ``from __future__ import annotations``: pydrake's yaml_load_typed reads the parameter
# dataclasses' field types as objects, not strings (as in systems/chain_scenario.py).
import dataclasses
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ballchain.drake_models import paper
from ballchain.infrastructure.errors import UserInputError, check_in, short_repr
from ballchain.experiments.study_helpers import _ok, _one_of, _positive, _savefig


VEINS = ("LSPV", "LIPV", "RSPV", "RIPV")
CONFIGS = {"1": ("1",), "2": ("2",), "both": ("1", "2")}
PROTOTYPE_BALLS = 16  # the paper's chain (16 x 3.175 mm)
TARGET_GF = 10.0  # the clinically relevant tip force the paper's sizing aims at [gf]
_SPHERE = re.compile(r"^sphere(\d+(?:\.\d+)?)$")


@dataclass
class DesignPoint:
    """One design: the chain, the actuation magnets and their distance, one vein.

    Attributes:
        ball_diameter_mm: 3.175 (the prototype's balls) or 2.17 (an 8 Fr chain in a 0.25 mm sleeve).
        n_balls: chain length; 0: the prototype chain's length (16 x 3.175 mm) in balls of this
            diameter (23 balls of 2.17 mm), so that every vein stays in reach.
        magnet: "cylinder" (the prototype's N52 76.2 x 38.1 mm) or "sphereD" (an N52 sphere of
            diameter D mm, e.g. "sphere119", the paper's clinical magnet).
        distance_cm: each magnet's centre from the septal puncture, to the patient's right ("1")
            and left ("2"), level with it (Table I's stand: 16.51 cm).
        vein: "LSPV", "LIPV", "RSPV" or "RIPV".
        config: "1" (magnet on the right), "2" (left) or "both" (both orientations optimised).
        sleeve: the Dragon Skin sleeve (ID 3.0, OD 3.5 mm: the prototype's).
        grid: azimuth samples of the orientation grid (forces.max_normal_force).
        refine_evaluations: Nelder-Mead evaluations from the best grid point.
    """

    ball_diameter_mm: float = 3.175
    n_balls: int = 0
    magnet: str = "cylinder"
    distance_cm: float = paper.WORKING_DISTANCE * 100
    vein: str = "LSPV"
    config: str = "both"
    sleeve: bool = False
    grid: int = 8
    refine_evaluations: int = 60


def design_magnet(name: str):
    """The magnet named ``cylinder`` or ``sphereD`` (D in mm)."""
    from ballchain.drake_models.params import CylinderMagnet, SphereMagnet

    if name == "cylinder":
        return CylinderMagnet()
    match = _SPHERE.match(name)
    if match is None or float(match.group(1)) <= 0:
        raise UserInputError(f"magnet must be 'cylinder' (the 76.2 mm prototype) or 'sphereD' with D the "
                             f"sphere's diameter in mm (e.g. sphere119), got {short_repr(name)}")
    return SphereMagnet(diameter=float(match.group(1)) * 1e-3)


def design_balls(p: DesignPoint) -> int:
    from ballchain.drake_models.params import BallChain

    if p.n_balls:
        return p.n_balls
    return round(PROTOTYPE_BALLS * BallChain().ball_diameter / (p.ball_diameter_mm * 1e-3))


def design_check(p: DesignPoint) -> None:
    """The ``forces`` command's grid and refine ranges, the statics' chain length, the scenario's
    magnet distance range and the parameter classes' own checks (a sleeve over the balls)."""
    from ballchain.drake_models.params import BallChain, Sleeve
    from ballchain.experiments.forces import GRID, REFINE
    from ballchain.experiments.statics_shape import MAX_BALLS
    from ballchain.systems.chain_scenario import MAX_DISTANCE

    _positive("ball_diameter_mm", p.ball_diameter_mm)
    if p.n_balls != 0 and not 3 <= p.n_balls <= MAX_BALLS:
        raise UserInputError(f"n_balls must be 0 (the prototype's length) or in 3..{MAX_BALLS}, got {p.n_balls}")
    # The count as a float first: a vanishing diameter makes it too large to round (inf).
    exact = p.n_balls or PROTOTYPE_BALLS * BallChain().ball_diameter / (p.ball_diameter_mm * 1e-3)
    n = design_balls(p) if exact <= MAX_BALLS + 1 else None
    if n is None or not 3 <= n <= MAX_BALLS:
        raise UserInputError(f"ball_diameter_mm {p.ball_diameter_mm:g} makes a chain of {exact:.4g} balls at the "
                             f"prototype's length (n_balls 0); it must have 3..{MAX_BALLS}")
    BallChain(n_balls=n, ball_diameter=p.ball_diameter_mm * 1e-3, sleeve=Sleeve() if p.sleeve else None)
    design_magnet(p.magnet)
    check_in("distance_cm", p.distance_cm, 0.0, MAX_DISTANCE * 100, lo_open=True, unit="cm")
    _one_of("vein", p.vein, VEINS)
    _one_of("config", p.config, CONFIGS)
    check_in("grid", p.grid, *GRID)
    check_in("refine_evaluations", p.refine_evaluations, *REFINE)


def design_point(p: DesignPoint, seed: int) -> dict:
    """The largest force the tip presses along the vein's axis (statics, optimised magnet turn)."""
    from ballchain.drake_models.params import BallChain, Sleeve
    from ballchain.experiments.forces import build_stand, max_normal_force

    magnet = design_magnet(p.magnet)
    d = p.ball_diameter_mm * 1e-3
    chain = BallChain(n_balls=design_balls(p), ball_diameter=d, sleeve=Sleeve() if p.sleeve else None)
    stand = build_stand(ball_diameter=d, distance=p.distance_cm * 1e-2)
    configs = CONFIGS[p.config]
    # The magnet's surface must stay beyond the chain's reach from the sheath exit: closer, the
    # chain could touch (or be inside) it, and no stand would place a magnet there.
    clearance = min(float(np.linalg.norm(stand.magnets[c])) for c in configs) - magnet.bounding_radius - chain.length
    base = {"n_balls_used": chain.n_balls, "magnet_mass_kg": magnet.mass, "magnet_moment_Am2": magnet.dipole_moment,
            "chain_moment_Am2": chain.n_balls * chain.dipole_moment, "clearance_mm": clearance * 1e3}
    if clearance <= 0:
        return {**base, "force_gf": None, "lateral_gf": None, "reaches_target": None, "evaluations": 0,
                "note": "magnet within the chain's reach of the sheath exit"}
    out = max_normal_force(chain, stand, p.vein, configs, p.grid, p.refine_evaluations, magnet=magnet)
    if out.get("force_N") is None:
        return {**base, "force_gf": None, "lateral_gf": None, "reaches_target": False,
                "evaluations": out.get("evaluations", 0), "note": out.get("reason")}
    from ballchain.experiments.forces import _lateral_gf

    lateral = _lateral_gf(-out["result"].tip_reaction, stand.targets[p.vein][1])
    return {**base, "force_gf": out["force_gf"], "lateral_gf": lateral,
            "reaches_target": bool(out["force_gf"] >= TARGET_GF), "evaluations": out["evaluations"],
            "refine_converged": out["refine_converged"],
            "note": None if out["refine_converged"] else
            f"refinement stopped at {p.refine_evaluations} evaluations: the force may be short of the optimum"}


DESIGN_KEY = tuple(f.name for f in dataclasses.fields(DesignPoint) if f.name != "vein")  # what makes one design


def _design_table(rows) -> dict:
    """{design: {vein: force_gf}} of the rows that ran, a design being every grid field but the vein
    (``DESIGN_KEY``): rows that differ in any of them (n_balls, the sleeve, grid, ...) are other designs."""
    table: dict = {}
    for r in _ok(rows):
        table.setdefault(tuple(r.get(k) for k in DESIGN_KEY), {})[r["vein"]] = r["force_gf"]
    return table


def design_summary(rows) -> dict:
    """Per design (every field of ``DesignPoint`` but the vein) the weakest vein's force; which
    designs give 10 gf on every vein; the paper's clinical claim (two 119 mm spheres, 8 Fr chain,
    29.65 cm / 35.6 cm) checked.

    Each design: its fields, ``forces_gf`` {vein: gf or None}, ``veins_swept`` (the veins the grid
    ran for it), ``weakest_swept_gf`` (the weakest of those: None if one has no force),
    ``min_force_gf`` (the weakest of all four veins: None unless all four were swept and pressed)
    and ``every_vein_10gf``.
    """
    designs = []
    for key, forces in sorted(_design_table(rows).items(), key=lambda kv: tuple(map(str, kv[0]))):
        values = [forces.get(v) for v in VEINS]
        complete = all(v is not None for v in values)
        swept = [v for v in VEINS if v in forces]
        weakest = None if any(forces[v] is None for v in swept) else min(forces[v] for v in swept)
        designs.append({**dict(zip(DESIGN_KEY, key)), "min_force_gf": min(values) if complete else None,
                        "veins_swept": swept, "weakest_swept_gf": weakest,
                        "forces_gf": dict(zip(VEINS, values)), "every_vein_10gf": complete and min(values) >= TARGET_GF})
    clinical = [d for d in designs if d["ball_diameter_mm"] == 2.17 and d["magnet"] == "sphere119"
                and d["config"] == "both"]
    return {"target_gf": TARGET_GF, "designs": designs,
            "designs_with_10gf_on_every_vein": [d for d in designs if d["every_vein_10gf"]],
            "paper_claim": "two 119 mm spheres, one each side, 8 Fr chain (2.17 mm balls), magnet centre "
                           "d_c + d_d/2 = 35.6 cm from the heart (d_c = 29.65 cm): 10 gf",
            "clinical_119mm": clinical}


CONFIG_WORDS = {"1": "one magnet, patient's right", "2": "one magnet, patient's left", "both": "two magnets"}


def design_figure(rows, out: Path) -> Path | str:
    """The weakest swept vein's force against distance: a panel per ball size, a line per design
    that the grid varies besides the distance (magnet, chain length, sleeve, configuration, ...),
    drawn from the rows' own values. When no design has a force at two distances or more, no
    figure (a line of single points says nothing the table does not): the reason, as a str."""
    designs = [d for d in design_summary(rows)["designs"] if d["weakest_swept_gf"] is not None]
    # The fields that tell the lines apart: those the grid varies, besides the ball size (panels)
    # and the distance (the x-axis).
    varied = [k for k in DESIGN_KEY if k not in ("ball_diameter_mm", "distance_cm")
              and len({d[k] for d in designs}) > 1]
    lines: dict = {}
    for d in designs:
        lines.setdefault((d["ball_diameter_mm"], tuple(d[k] for k in varied), d["magnet"], d["config"]), []).append(
            (d["distance_cm"], d["weakest_swept_gf"]))
    if not any(len(pts) >= 2 for pts in lines.values()):
        return ("no figure: it draws the force against distance_cm, and no design of this grid has a force at "
                "two distances or more")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    balls = sorted({key[0] for key in lines}, reverse=True)
    fig, axes = plt.subplots(1, len(balls), figsize=(5.5 * len(balls), 4.2), sharex=True, sharey=True,
                             squeeze=False)
    distances = [x for pts in lines.values() for x, _ in pts]
    veins = sorted({v for d in designs for v in d["veins_swept"]}, key=VEINS.index)
    for ax, ball in zip(axes[0], balls):
        for (b, values, magnet, config), pts in sorted(lines.items(), key=lambda kv: tuple(map(str, kv[0]))):
            if b != ball:
                continue
            label = "76.2 mm cylinder (prototype)" if magnet == "cylinder" else f"{magnet[6:]} mm sphere"
            extra = ", ".join(f"{k} {v}" for k, v in zip(varied, values) if k != "magnet")
            ax.plot(*zip(*sorted(pts)), "o-", label=label + (f" ({extra})" if extra else ""))
        ax.axhline(TARGET_GF, color="k", ls="--", lw=1, label="10 gf")
        configs = sorted({key[3] for key in lines if key[0] == ball})
        clinical_cm = paper.CLINICAL_DISTANCE * 100
        if min(distances) <= clinical_cm <= max(distances):
            ax.axvline(clinical_cm, color="grey", ls=":", lw=1, label=f"d_c = {clinical_cm:g} cm")
        if ball < 3 and configs == ["both"] and min(distances) <= 35.6 <= max(distances):
            # the paper's claim: two 119 mm spheres, centres d_c + d_d/2 away, 10 gf
            ax.plot([35.6], [TARGET_GF], "*", color="C2", ms=14, mec="k", label="paper's claim (119 mm, 35.6 cm)")
        ax.set_yscale("log")
        ax.set_xlabel("magnet centre to septal puncture [cm]")
        ax.set_title(f"balls {ball} mm ({'prototype' if ball > 3 else '8 Fr' if ball == 2.17 else 'own'}), "
                     + "; ".join(CONFIG_WORDS[c] for c in configs))
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel(f"tip force on {veins[0]} [gf]" if len(veins) == 1 else
                          "tip force on the weakest of the four veins [gf]" if veins == list(VEINS)
                          else f"tip force on the weakest of {', '.join(veins)} [gf]")
    axes[0][-1].legend(fontsize=8)
    return _savefig(fig, Path(out) / "design.png")
