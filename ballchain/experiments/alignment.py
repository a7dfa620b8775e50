"""Tip-to-field alignment, the paper's model figure (Fig. 5).

Chains of 1..16 balls; a 23 mT field rotated from 0 to 180 deg in 22.5 deg steps with
continuation; the angle between the field and the tip ball's dipole. The paper claims less
than 1.4 deg for chains longer than 10 balls. Writes ``alignment.csv`` and ``alignment.png``
(tip angle against chain length) and ``alignment_shapes.png`` (the 10-ball chain's shapes).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ballchain.infrastructure.arg_checks import require_bool, require_int
from ballchain.infrastructure.errors import check_in
from ballchain.drake_models.field_sources import MAX_FIELD_T, UniformField
from ballchain.drake_models.params import BallChain, Sleeve
from ballchain.infrastructure.safe_files import agg_pyplot, check_output_dir, note_replacements, save_figure, write_csv
from ballchain.experiments._result import Result, optional
from ballchain.optimization.statics import ChainStatics, rotation_path, tip_angle_deg

PAPER_CLAIM_DEG = 1.4
MAX_BALLS = 64  # every length 1..max is solved at every angle


@dataclass
class AlignmentSummary(Result):
    """The alignment's headline numbers [deg].

    Attributes:
        max_tip_angle_deg_beyond_10_balls: the largest tip angle of chains longer than 10 balls
            over every field angle (None without such chains).
        max_tip_angle_deg_beyond_10_balls_at_180deg: the same at 180 deg.
        paper_claim_deg: the paper's bound (1.4 deg).
    """

    max_tip_angle_deg_beyond_10_balls: float | None
    max_tip_angle_deg_beyond_10_balls_at_180deg: float | None
    paper_claim_deg: float


@dataclass
class AlignmentResult(Result):
    """What ``run`` returns.

    Attributes:
        rows: one per chain length and field angle: {n_balls, field_angle_deg, tip_angle_deg,
            tip_x_mm, tip_y_mm}.
        shapes: {field angle [deg]: ball positions [mm], shape (n, 3)} of the 10-ball chain (the
            longest one if shorter).
        summary: the headline numbers.
        files: the paths written (only with ``out``).
    """

    rows: list
    shapes: dict
    summary: AlignmentSummary
    files: list | None = optional()

def write_files(data: AlignmentResult, out: Path) -> list[str]:
    """Write the CSV and the two figures into ``out``; returns their paths."""
    plt = agg_pyplot()
    note_replacements(out, ["alignment.csv", "alignment.png", "alignment_shapes.png"], "alignment")
    out.mkdir(parents=True, exist_ok=True)
    csv_path = write_csv(out / "alignment.csv", data.rows)
    fig, ax = plt.subplots(figsize=(6, 4))
    angles = sorted({r["field_angle_deg"] for r in data.rows})
    for angle in angles:
        if angle == 0.0:
            continue  # aligned with the chain: the angle is zero for every length
        pts = [(r["n_balls"], max(r["tip_angle_deg"], 1e-3)) for r in data.rows if r["field_angle_deg"] == angle]
        ax.plot(*zip(*pts), marker="o", ms=3, label=f"{angle:g} deg")
    ax.axhline(PAPER_CLAIM_DEG, color="k", ls="--", lw=1, label="paper: 1.4 deg")
    ax.set_xlabel("balls in the chain")
    ax.set_ylabel("angle between field and tip dipole [deg]")
    ax.set_yscale("log")
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("Tip alignment with a 23 mT field (model)")
    fig.tight_layout()
    png = out / "alignment.png"
    save_figure(fig, png, dpi=120)
    fig, ax = plt.subplots(figsize=(5, 5))
    for angle, p in data.shapes.items():
        ax.plot(p[:, 0], p[:, 1], "-o", ms=4, label=f"{angle:g} deg")
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.legend(fontsize=7)
    ax.set_title("10-ball chain, field rotated 0..180 deg")
    fig.tight_layout()
    shapes_png = out / "alignment_shapes.png"
    save_figure(fig, shapes_png, dpi=120)
    return [str(csv_path), str(png), str(shapes_png)]


def run(*, max_balls: int = 16, field_mT: float = 23.0, step_deg: float = 22.5, sleeve: bool = False,
        out: Path | None = None, progress: bool = True) -> AlignmentResult:
    """Tip angle against chain length as the field turns from 0 to 180 deg (continuation).

    Args:
        max_balls: longest chain (every length 1..max_balls is solved at every angle).
        field_mT: field magnitude [mT].
        step_deg: field angle step [deg].
        sleeve: with the Dragon Skin sleeve.
        out: folder for ``alignment.csv``, ``alignment.png``, ``alignment_shapes.png`` (None: no
            files); checked writable before the work.
        progress: a progress bar.

    Returns:
        An ``AlignmentResult`` (``files`` set with ``out``).

    Raises:
        UserInputError: a value out of range (named by its flag) or an unwritable ``out``.

    Example:
        Chains of 1 to 12 balls in a field turned to 90 and 180 deg::

            >>> from ballchain.experiments import alignment
            >>> result = alignment.run(max_balls=12, step_deg=90.0, progress=False)
            >>> round(result.summary.max_tip_angle_deg_beyond_10_balls, 2), result.summary.paper_claim_deg  # [deg]
            (0.37, 1.4)
    """
    require_int(max_balls, "--max-balls", 1, MAX_BALLS)
    require_bool(sleeve, "--sleeve")
    check_in("--field-mT", field_mT, 0.0, MAX_FIELD_T * 1e3, lo_open=True, unit="mT")
    check_in("--step-deg", step_deg, 0.5, 90.0, unit="deg")
    if out is not None:  # before the work: an unwritable folder must not cost the results
        check_output_dir(out, "--out")
    angles = rotation_path(0.0, 180.0, step_deg)
    rows, shapes = [], {}
    for n in tqdm(range(1, max_balls + 1), desc="alignment", unit="chain", disable=not progress):
        chain = BallChain(n_balls=n, sleeve=Sleeve() if sleeve else None)
        results = ChainStatics(chain).continuation(UniformField.in_plane(field_mT * 1e-3, np.radians(angle))
                                                   for angle in angles)
        for angle, result in zip(angles, results):
            direction = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle)), 0.0])
            rows.append({"n_balls": n, "field_angle_deg": float(angle),
                         "tip_angle_deg": tip_angle_deg(result, direction),
                         "tip_x_mm": result.positions[-1, 0] * 1e3, "tip_y_mm": result.positions[-1, 1] * 1e3})
            if n == min(10, max_balls):
                shapes[float(angle)] = result.positions * 1e3
    beyond = [r["tip_angle_deg"] for r in rows if r["n_balls"] > 10]
    summary = AlignmentSummary(
        max_tip_angle_deg_beyond_10_balls=max(beyond) if beyond else None,
        max_tip_angle_deg_beyond_10_balls_at_180deg=max(
            (r["tip_angle_deg"] for r in rows if r["n_balls"] > 10 and r["field_angle_deg"] == 180.0), default=None),
        paper_claim_deg=PAPER_CLAIM_DEG,
    )
    data = AlignmentResult(rows=rows, shapes=shapes, summary=summary)
    if out is not None:
        data.files = write_files(data, Path(out))
    return data
