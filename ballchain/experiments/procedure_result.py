"""The procedure's result (``ProcedureResult``), each dwell's lesion and the ring's verdict
(``with_lesions``) and the files written (``write_outputs``). ``procedure`` re-exports them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ballchain.infrastructure.errors import UserInputError
from ballchain.experiments._result import Result, not_in_json, optional


@dataclass
class ProcedureResult(Result):
    """What ``run`` returns (edge units: gf, mm, s).

    Attributes:
        task: "left" or "right" (None: a user anatomy's every target); navigator: "auto" or
            "operator".
        rows: one per target: {target, reached, time_s, t_touch_s, dwell_s, force_true_mean_gf,
            force_true_min_gf, force_true_max_gf, in_window_fraction, estimate_mean_error_gf,
            estimate_worst_error_gf (auto only), retries, point: the ablation point {name, p_W,
            n_W, force_N, duration_s} (None when not reached); auto only: plan_force_gf (the
            planned press) and aim_offset_mm (the aim's distance from the target's centre, > 0
            for a target beyond the straight chain's reach: ``aim_point``)}.
        summary: {reached, targets, total_time_s, in_window_fraction (over every dwell),
            estimate_mean_abs_error_gf, estimate_worst_error_gf, sim_time_s, cpu_time_s,
            plan_cpu_time_s, failure}.
        settings: the run's settings (force, window, dwell, localisation, seed, engine).
        lesions: per reached target its lesion (``lesion_ring.Lesion.to_dict``: the FEM
            surrogate's width and depth at the dwell's mean true force, its duration and the
            highest power keeping the tip magnet below its grade's limit), or {name, reason}
            when the dwell lies outside the surrogate's range.
        ring: the ring's verdict (``lesion_ring.analyse_ring``: gaps, spacing, transmurality,
            isolated), the targets in ring order, the unreached ones gaps.
        html: the Meshcat replay (only with ``html``), the lesion patches on the wall.
        files: {"json", "ring_png"} written (only with ``out``).
        lesion_objects, verdict: the Lesions and the RingVerdict (not in the JSON).
    """

    task: str | None
    navigator: str
    rows: list
    summary: dict
    settings: dict
    lesions: list | None = optional()
    ring: dict | None = optional()
    html: str | None = optional()
    files: dict | None = optional()
    lesion_objects: list | None = not_in_json()
    verdict: object = not_in_json()


def with_lesions(result: ProcedureResult, ring_order: list[str]) -> ProcedureResult:
    """The result with each dwell's lesion and the ring's verdict (``drake_models.lesion_ring``):
    the generator power of a dwell is the highest that keeps the tip magnet below its grade's
    limit at the dwell's mean true force and duration (``choose_power``); a dwell outside the
    surrogate's range leaves no lesion (a gap, its reason in ``lesions``).

    With ``settings["lesions"]`` (``lesion_dwell.LesionConditions.to_dict``: blood flow, the
    generator with the magnet's limit in its loop, a dwell criterion), each lesion comes from the
    clinical table instead: its RF time by the criterion, its power the delivered mean (issue 44)."""
    from ballchain.drake_models.lesion_ring import AblationPoint, analyse_ring, choose_power, lesions_for

    clinical = (result.settings or {}).get("lesions")
    if clinical is not None:
        from ballchain.drake_models.lesion_dwell import LesionConditions, lesion_for, neighbour_distances

        clinical = LesionConditions.from_dict(clinical)
        reached = [row["point"] for row in result.rows if row.get("point") is not None]
        widths = neighbour_distances(reached)  # the "contiguous" criterion's width per target
    lesions, listed = [], []
    for row in result.rows:
        pt = row.get("point")
        if pt is None:
            continue
        try:
            if clinical is not None:
                lesion = lesion_for(pt["name"], pt["p_W"], pt["n_W"], pt["force_N"], pt["duration_s"], clinical,
                                    width_target_m=widths[pt["name"]])
                power = lesion.point.power_W
                pt["rf_duration_s"] = lesion.point.duration_s
            else:
                power = choose_power(pt["force_N"], pt["duration_s"])
                point = AblationPoint(pt["name"], np.asarray(pt["p_W"], float), np.asarray(pt["n_W"], float),
                                      float(pt["force_N"]), float(pt["duration_s"]), float(power))
                (lesion,) = lesions_for([point])
        except UserInputError as err:
            listed.append({"name": pt["name"], "reason": f"no lesion: {err}"})
            continue
        pt["power_W"] = float(power)
        lesions.append(lesion)
        listed.append(lesion.to_dict())
    verdict = analyse_ring(lesions, ring_order=list(ring_order))
    result.lesions, result.ring = listed, verdict.to_dict()
    result.lesion_objects, result.verdict = lesions, verdict
    result.summary["isolated"] = verdict.isolated
    result.summary["ring_gaps"] = len(verdict.gaps)
    return result


def write_outputs(result: ProcedureResult, out: Path) -> dict:
    """``procedure.json`` and ``ring.png`` (``lesion_ring.ring_figure``) in ``out`` (atomically)."""
    from ballchain.drake_models.lesion_ring import ring_figure
    from ballchain.infrastructure.safe_files import atomic_write_text

    out = Path(out)
    files = {"json": str(out / "procedure.json")}
    if result.verdict is not None:
        ring_figure(result.verdict, result.lesion_objects, out / "ring.png",  # written atomically
                    title=f"Lesion ring: {result.task or 'anatomy'} ({result.navigator})")
        files["ring_png"] = str(out / "ring.png")
    result.files = files
    atomic_write_text(out / "procedure.json", result.to_json())
    return files
