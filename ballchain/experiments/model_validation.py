"""Model validation (paper Fig. 11): 5..10 balls, 23 mT at {0, 45, 90, 135, 180} deg.

The paper compares a uniform-field dipole model with webcam measurements: for 6 or more balls
median/max tip-angle error 5/8 deg; tip position error below 5 mm (5 balls), below 3 mm (6 or
more), median 3.7 mm (5 balls) and 1.5 mm (10 balls). Here the model is solved three ways:
the uniform 23 mT field the paper's model assumes, and the prototype cylinder on the rotary
stage (placed beside the base so that its point-dipole field there is 23 mT at the angle) as a
point dipole and with its exact field. The differences between them bound how much of the
measured error the field approximations can explain.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ballchain.infrastructure.arg_checks import as_int_list, as_number_list
from ballchain.infrastructure.errors import UserInputError, check_in
from ballchain.drake_models.field_sources import MAX_FIELD_T, UniformField
from ballchain.drake_models.params import BallChain
from ballchain.infrastructure.safe_files import check_output_dir, note_replacements, write_csv
from ballchain.drake_models.vectors import angle_between
from ballchain.experiments._result import Result, optional
from ballchain.experiments.magnet_poses import side_magnet_for_field
from ballchain.optimization.statics import ChainStatics, rotation_path, tip_angle_deg

PAPER = {
    "tip_angle_error_median_deg_6plus": 5.0,
    "tip_angle_error_max_deg_6plus": 8.0,
    "tip_position_error_max_mm_5plus": 5.0,
    "tip_position_error_max_mm_6plus": 3.0,
    "tip_position_error_median_mm_5": 3.7,
    "tip_position_error_median_mm_10": 1.5,
}
MODELS = ("uniform", "dipole", "exact")


@dataclass
class ValidationSummary(Result):
    """Medians and maxima over the chains of 6 or more balls [deg, mm].

    Attributes:
        uniform_model_tip_angle_median_deg_6plus: the uniform model's tip angle to its field.
        dipole_vs_exact_angle_median_deg_6plus, dipole_vs_exact_angle_max_deg_6plus,
            dipole_vs_exact_tip_max_mm_6plus: the point dipole against the exact cylinder.
        uniform_vs_exact_angle_median_deg_6plus, uniform_vs_exact_angle_max_deg_6plus,
            uniform_vs_exact_tip_median_mm_6plus, uniform_vs_exact_tip_max_mm_6plus: the uniform
            field against the exact cylinder.
    """

    uniform_model_tip_angle_median_deg_6plus: float
    dipole_vs_exact_angle_median_deg_6plus: float
    dipole_vs_exact_angle_max_deg_6plus: float
    dipole_vs_exact_tip_max_mm_6plus: float
    uniform_vs_exact_angle_median_deg_6plus: float
    uniform_vs_exact_angle_max_deg_6plus: float
    uniform_vs_exact_tip_median_mm_6plus: float
    uniform_vs_exact_tip_max_mm_6plus: float


@dataclass
class ValidationResult(Result):
    """What ``run`` returns (edge units: mm, deg).

    Attributes:
        rows: one per chain length, field angle and model: {n_balls, field_angle_deg, model,
            tip_angle_deg, tip_mm (3,)}.
        differences: one per chain length and field angle: {n_balls, field_angle_deg,
            dipole_vs_exact_angle_deg, dipole_vs_exact_tip_mm, uniform_vs_exact_angle_deg,
            uniform_vs_exact_tip_mm}.
        summary: medians and maxima of the differences over 6 or more balls.
        paper: the paper's measured errors; setup: the magnet's placement, in words.
        files: the paths written (only with ``out``).
    """

    rows: list
    differences: list
    summary: ValidationSummary
    paper: dict
    setup: str
    files: list | None = optional()


def _field(model: str, theta_deg: float, field_T: float):
    theta = np.radians(theta_deg)
    if model == "uniform":
        return UniformField.in_plane(field_T, theta)
    return side_magnet_for_field(theta, field_T, model=model)


def run(*, balls=range(5, 11), angles_deg=(0.0, 45.0, 90.0, 135.0, 180.0), field_T: float = 0.023,
        step_deg: float = 22.5, progress: bool = True, out: Path | None = None) -> ValidationResult:
    """Tip angle and position for every chain length, field angle and field model.

    Args:
        balls: chain lengths.
        angles_deg: field angles [deg].
        field_T: field at the chain's base [T], in (0, 1].
        step_deg: largest continuation step [deg].
        progress: a progress bar.
        out: folder for ``validation.csv`` (the differences; None: no file), checked writable
            before the work.

    Returns:
        A ``ValidationResult`` (``files`` set with ``out``).

    Raises:
        UserInputError: a field out of range (named by its flag, --field-mT) or an unwritable ``out``.
    """
    as_int_list(balls, "balls", 2)
    as_number_list(angles_deg, "angles_deg", -360.0, 360.0, unit="deg")
    check_in("step_deg", step_deg, 0.0, 90.0, lo_open=True, unit="deg")
    if not (isinstance(field_T, (int, float)) and 0 < field_T <= MAX_FIELD_T):
        shown = field_T * 1e3 if isinstance(field_T, (int, float)) else field_T
        raise UserInputError(f"--field-mT must be in (0, {MAX_FIELD_T * 1e3:g}] mT, got {shown}")
    if out is not None:  # before the work
        check_output_dir(out, "--out")
    rows = []
    jobs = [(n, model) for n in balls for model in MODELS]
    for n, model in tqdm(jobs, desc="model validation", unit="chain", disable=not progress):
        solver = ChainStatics(BallChain(n_balls=n))
        for theta in angles_deg:
            result = solver.continuation(_field(model, angle, field_T)
                                         for angle in rotation_path(0.0, theta, step_deg))[-1]
            direction = [np.cos(np.radians(theta)), np.sin(np.radians(theta)), 0.0]
            rows.append({"n_balls": n, "field_angle_deg": float(theta), "model": model,
                         "tip_angle_deg": tip_angle_deg(result, direction),
                         "tip_mm": result.positions[-1] * 1e3, "tip_dipole": result.dipoles[-1]})
    index = {(r["n_balls"], r["field_angle_deg"], r["model"]): r for r in rows}
    differences = []
    for n in balls:
        for theta in angles_deg:
            ex, dp, un = (index[(n, float(theta), m)] for m in ("exact", "dipole", "uniform"))

            def angle(a, b):
                return float(np.degrees(angle_between(a, b)))

            differences.append({
                "n_balls": n, "field_angle_deg": float(theta),
                "dipole_vs_exact_angle_deg": angle(dp["tip_dipole"], ex["tip_dipole"]),
                "dipole_vs_exact_tip_mm": float(np.linalg.norm(dp["tip_mm"] - ex["tip_mm"])),
                "uniform_vs_exact_angle_deg": angle(un["tip_dipole"], ex["tip_dipole"]),
                "uniform_vs_exact_tip_mm": float(np.linalg.norm(un["tip_mm"] - ex["tip_mm"])),
            })
    six_plus = [d for d in differences if d["n_balls"] >= 6]
    summary = ValidationSummary(
        uniform_model_tip_angle_median_deg_6plus=float(np.median(
            [r["tip_angle_deg"] for r in rows if r["model"] == "uniform" and r["n_balls"] >= 6])),
        dipole_vs_exact_angle_median_deg_6plus=float(np.median([d["dipole_vs_exact_angle_deg"] for d in six_plus])),
        dipole_vs_exact_angle_max_deg_6plus=float(max(d["dipole_vs_exact_angle_deg"] for d in six_plus)),
        dipole_vs_exact_tip_max_mm_6plus=float(max(d["dipole_vs_exact_tip_mm"] for d in six_plus)),
        uniform_vs_exact_angle_median_deg_6plus=float(np.median([d["uniform_vs_exact_angle_deg"] for d in six_plus])),
        uniform_vs_exact_angle_max_deg_6plus=float(max(d["uniform_vs_exact_angle_deg"] for d in six_plus)),
        uniform_vs_exact_tip_median_mm_6plus=float(np.median([d["uniform_vs_exact_tip_mm"] for d in six_plus])),
        uniform_vs_exact_tip_max_mm_6plus=float(max(d["uniform_vs_exact_tip_mm"] for d in six_plus)),
    )
    for r in rows:
        r.pop("tip_dipole")
    data = ValidationResult(rows=rows, differences=differences, summary=summary, paper=PAPER,
                            setup="magnet beside the base at (0, -r, 0), r chosen for a 23 mT point-dipole "
                                  "field at the base")
    if out is not None:
        note_replacements(out, ["validation.csv"], "validation")
        data.files = [str(write_csv(Path(out) / "validation.csv", differences))]
    return data
