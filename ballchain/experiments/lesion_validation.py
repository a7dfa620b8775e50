"""The catheter's lesion model against published lesions (issue 44).

For each protocol point of ``drake_models.lesion_literature.PUBLISHED`` the open-irrigated 8 Fr
catheter runs in ``lesion_clinical`` (blood or saline flowing past it, the tip held at the
irrigant's temperature, the set power with the 100 C cut-off) at each contact force (and set
power) the published mean is over; the model's lesion is the mean of those runs. Reported: the
published and the model's depth (and maximum width where published), the error and the error in
units of the published SD, the model's delivered power (the cut-off's share of the RF time).
Nothing is fitted: every constant is the one the rest of the model uses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from ballchain.drake_models import lesion_boundary as boundary
from ballchain.drake_models import lesion_clinical as clinical
from ballchain.drake_models import lesion_literature as literature
from ballchain.drake_models import tissue as laws
from ballchain.drake_models.rf_generator import Generator
from ballchain.experiments import ablation_clinical
from ballchain.experiments._result import Result
from ballchain.experiments.ablation import electrode_for
from ballchain.infrastructure.errors import UserInputError


@dataclass
class ValidationResult(Result):
    """``run``'s rows (one per published point), the sources and the settings."""

    rows: list
    sources: dict
    h_mm: float
    dt_max_s: float
    summary: dict


def _run_once(power_W: float, duration_s: float, force_gf: float, flow: str, fluid: str, h_mm: float,
              dt_max_s: float) -> dict:
    indentation = ablation_clinical.indentation_mm_for("catheter", force_gf)
    electrode = electrode_for("catheter", indentation)
    sim = clinical.simulate_clinical(
        electrode, generator=Generator(power_W=power_W), duration_s=duration_s,
        conditions=boundary.conditions(flow, "open"), initial_temperature_C=37.0, h=h_mm * 1e-3,
        dt_max=dt_max_s, output_every_s=duration_s, fluid=boundary.BLOOD if fluid == "blood" else laws.SALINE)
    end = sim.growth[-1]
    return {"depth_mm": end["omega_depth_mm"], "width_mm": end["omega_width_mm"],
            "delivered_W": sim.info["mean_power_W"], "cutoff_share": sim.info["limit_share"]["cutoff"],
            "indentation_mm": indentation}


def run(points=literature.PUBLISHED, *, h_mm: float = 0.15, dt_max_s: float = 1.0,
        progress: bool = True) -> ValidationResult:
    """Every published point against the model (see the module docstring)."""
    if not (isinstance(h_mm, (int, float)) and 0.05 <= h_mm <= 0.3):
        raise UserInputError(f"h_mm must be in [0.05, 0.3] mm, got {h_mm!r}")
    jobs = sorted({(p_W, pt.duration_s, f, pt.blood_flow, pt.fluid) for pt in points
                   for p_W in pt.protocol_powers_W for f in pt.forces_gf})
    runs = {job: _run_once(*job, h_mm=h_mm, dt_max_s=dt_max_s)
            for job in tqdm(jobs, desc="published lesions (FEM runs)", unit="run", disable=not progress)}
    rows = []
    for pt in points:
        mine = [runs[(p_W, pt.duration_s, f, pt.blood_flow, pt.fluid)] for p_W in pt.protocol_powers_W
                for f in pt.forces_gf]
        model = {k: float(np.mean([m[k] for m in mine])) for k in mine[0]}
        row = {"key": pt.key, "source": pt.source, "preparation": pt.preparation,
               "power_W": list(pt.protocol_powers_W), "duration_s": pt.duration_s, "forces_gf": list(pt.forces_gf),
               "blood_flow": pt.blood_flow, "fluid": pt.fluid, "published_depth_mm": pt.depth_mm,
               "published_depth_sd_mm": pt.depth_sd_mm, "model_depth_mm": model["depth_mm"],
               "depth_error_mm": model["depth_mm"] - pt.depth_mm,
               "depth_error_sd": ((model["depth_mm"] - pt.depth_mm) / pt.depth_sd_mm if pt.depth_sd_mm else None),
               "published_width_mm": pt.width_mm, "published_width_sd_mm": pt.width_sd_mm,
               "model_width_mm": model["width_mm"],
               "width_error_mm": None if pt.width_mm is None else model["width_mm"] - pt.width_mm,
               "model_delivered_W": model["delivered_W"], "model_cutoff_share": model["cutoff_share"],
               "assumed": pt.assumed}
        rows.append(row)
    depth_err = [r["depth_error_mm"] for r in rows]
    within = [r for r in rows if r["depth_error_sd"] is not None and abs(r["depth_error_sd"]) <= 1.0]
    with_sd = [r for r in rows if r["depth_error_sd"] is not None]
    summary = {"points": len(rows), "sources": len({r["source"] for r in rows}),
               "depth_mean_error_mm": float(np.mean(depth_err)),
               "depth_rms_error_mm": float(math.sqrt(np.mean(np.square(depth_err)))),
               "depth_within_1sd": f"{len(within)}/{len(with_sd)}"}
    return ValidationResult(rows=rows, sources=dict(literature.SOURCES), h_mm=h_mm, dt_max_s=dt_max_s,
                            summary=summary)


def markdown_table(result: ValidationResult) -> str:
    """The rows as a Markdown table (depth and width: published mean +- SD / model / error)."""
    def pm(v, sd):
        return "-" if v is None else (f"{v:.1f}" if sd is None else f"{v:.1f} +- {sd:.1f}")

    lines = ["| point | source | P [W] | t [s] | CF [gf] | depth published [mm] | depth model [mm] | error [mm] (SD) "
             "| width published [mm] | width model [mm] | delivered [W] |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in result.rows:
        sd = "" if r["depth_error_sd"] is None else f" ({r['depth_error_sd']:+.1f})"
        lines.append(
            f"| {r['key']} | {r['source']} | {'/'.join(f'{p:g}' for p in r['power_W'])} | {r['duration_s']:g} | "
            f"{'/'.join(f'{f:g}' for f in r['forces_gf'])} | {pm(r['published_depth_mm'], r['published_depth_sd_mm'])} | "
            f"{r['model_depth_mm']:.1f} | {r['depth_error_mm']:+.1f}{sd} | "
            f"{pm(r['published_width_mm'], r['published_width_sd_mm'])} | {r['model_width_mm']:.1f} | "
            f"{r['model_delivered_W']:.1f} |")
    return "\n".join(lines)
