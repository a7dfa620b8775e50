"""Workspace (paper Fig. 9): one magnet 16.51 cm away, rotated through its range.

The chain leaves the sheath at the origin along +x; the prototype cylinder sits beside the
insertion point at (0, -16.51 cm, 0) and turns about z. Starting from the straight chain (the
magnet's field along +x at the base), the magnet turns one way until the field at the base
points along -x through +y (one half workspace) and the other way through -y (the other half).
For 4, 9 and 16 balls, with and without sleeve, the tip positions trace two curves from the
straight chain to the field-along--x equilibrium; together they enclose the workspace (shoelace
formula on the closed loop), and the paper's "half workspace" is half of it. The magnet's pull
makes the two halves unequal, and near the end of the far-side sweep the chain snaps through to
the near side (reported with the field angle where it happens). The paper: 3345 mm^2 without
sleeve, 2939 mm^2 with (12 % less), tip-to-tip about 8 mm.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ballchain.infrastructure.arg_checks import as_int_list
from ballchain.drake_models import paper
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.params import BallChain, Sleeve
from ballchain.infrastructure.safe_files import agg_pyplot, atomic_write_text, check_output_dir, note_replacements, save_figure
from ballchain.experiments._result import Result, optional
from ballchain.experiments.magnet_poses import field_angle_for_magnet_angle, side_magnet
from ballchain.optimization.statics import ChainStatics

PAPER = paper.WORKSPACE
DISTANCE = paper.WORKING_DISTANCE


@dataclass
class WorkspaceSummary(Result):
    """The longest chain's workspace, bare and in the sleeve.

    Attributes:
        half_area_bare_mm2, half_area_sleeve_mm2: half the area enclosed by the two tip curves [mm^2].
        reduction_pct: the sleeve's reduction of it [%].
        tip_to_tip_max_mm: the largest distance between the bare and the sleeved tip at the same
            magnet angle [mm].
        chain_length_mm: the chain's length [mm].
        field_at_base_mT_range: [smallest, largest] field at the insertion point over the
            magnet's turn [mT].
    """

    half_area_bare_mm2: float
    half_area_sleeve_mm2: float
    reduction_pct: float
    tip_to_tip_max_mm: float
    chain_length_mm: float
    field_at_base_mT_range: list


@dataclass
class WorkspaceResult(Result):
    """What ``run`` returns (edge units: mm, mm^2, mT, deg).

    Attributes:
        curves: {(n_balls, sleeve, side): tip positions [mm], shape (k, 3)}, side +1 / -1 the
            magnet's rotation direction.
        rows: one per chain length and sleeve: {n_balls, sleeve, workspace_area_mm2,
            half_area_mm2, far_side_snap_field_angle_deg, near_side_snap_field_angle_deg (None: no
            snap-through)}.
        summary: the longest chain's areas and the sleeve's effect.
        paper: the paper's numbers; setup: the placement, in words.
        files: the paths written (only with ``out``).
    """

    curves: dict
    rows: list
    summary: WorkspaceSummary
    paper: dict
    setup: str
    files: list | None = optional()

    def public(self) -> dict:
        """The JSON-ready dict without the tip curves (what the command prints)."""
        data = self.to_dict()
        del data["curves"]
        return data


def polygon_area(points_xy: np.ndarray) -> float:
    """Area of the closed polygon through the points (shoelace), in the points' units squared."""
    x, y = points_xy[:, 0], points_xy[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def sweep(chain: BallChain, side: int, step_deg: float, distance: float = DISTANCE):
    """Tip positions [m] as the magnet turns from field +x to field -x on one side (+1: +y)."""
    phis = np.radians(180.0 - side * np.arange(0.0, 180.0 + 1e-9, step_deg))
    results = ChainStatics(chain).continuation(side_magnet(phi, distance) for phi in phis)
    tips = [result.positions[-1].copy() for result in results]
    field_angles = [np.degrees(field_angle_for_magnet_angle(phi)) for phi in phis]
    return np.array(tips), np.array(field_angles)

def write_files(data: WorkspaceResult, out: Path) -> list[str]:
    """Write ``workspace_tips.csv`` and ``workspace.png`` into ``out``; returns their paths."""
    plt = agg_pyplot()
    note_replacements(out, ["workspace_tips.csv", "workspace.png"], "workspace")
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "workspace_tips.csv"
    f = io.StringIO(newline="")
    writer = csv.writer(f)
    writer.writerow(["n_balls", "sleeve", "side", "tip_x_mm", "tip_y_mm", "tip_z_mm"])
    for (n, sleeve, side), tips in data.curves.items():
        for tip in tips:
            writer.writerow([n, sleeve, side, *tip])
    atomic_write_text(csv_path, f.getvalue())
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.5), sharex=True, sharey=True)
    balls = sorted({k[0] for k in data.curves})
    for ax, n in zip(axes, balls):
        for sleeve, style in ((False, "-"), (True, "--")):
            for side in (1, -1):
                tips = data.curves[(n, sleeve, side)]
                ax.plot(tips[:, 0], tips[:, 1], style, color="C0" if side > 0 else "C1",
                        label=f"{'sleeve' if sleeve else 'bare'}, {'+y' if side > 0 else '-y'} side")
        ax.plot([0], [0], "ks")
        ax.set_title(f"{n} balls")
        ax.set_aspect("equal")
        ax.set_xlabel("x [mm]")
    axes[0].set_ylabel("y [mm] (magnet towards -y)")
    axes[-1].legend(fontsize=7)
    fig.suptitle("Tip positions as the magnet turns (16.51 cm away)")
    fig.tight_layout()
    png = out / "workspace.png"
    save_figure(fig, png, dpi=110)
    return [str(csv_path), str(png)]

def workspace_area(tips_plus: np.ndarray, tips_minus: np.ndarray) -> float:
    """Area enclosed by the tip curves of the two rotation directions (each (k, 3), same unit,
    from the straight chain to the field-along--x equilibrium), in that unit squared; the
    paper's half workspace is half of it."""
    return polygon_area(np.vstack([tips_plus[:, :2], tips_minus[::-1, :2]]))


def tip_to_tip_distance(curves_a: dict, curves_b: dict) -> float:
    """Largest distance between the tips of two chains at the same magnet angle, over both
    rotation directions (``curves[side]`` (k, 3) from ``sweep``, same unit)."""
    return max(float(np.max(np.linalg.norm(curves_a[s] - curves_b[s], axis=1))) for s in (1, -1))


def check_inputs(step_deg, distance, names=("--step-deg", "--distance-cm")) -> None:
    """The ranges of ``run``'s step [deg] and distance [m] (the command's flags, or a sweep's
    fields: ``names``); raises UserInputError naming it."""
    if not (isinstance(step_deg, (int, float)) and 0.5 <= step_deg <= 45):
        raise UserInputError(f"{names[0]} must be in [0.5, 45], got {step_deg}")
    if not (isinstance(distance, (int, float)) and 0.1 < distance <= 1.0):
        raise UserInputError(f"{names[1]} must be in (10, 100] cm (closer, the magnet would touch the "
                             f"chain), got {distance * 100:g}")


def run(*, balls=(4, 9, 16), step_deg: float = 5.0, distance: float = DISTANCE, progress: bool = True,
        out: Path | None = None) -> WorkspaceResult:
    """Tip curves, half-workspace areas and the sleeve's effect.

    Args:
        balls: chain lengths.
        step_deg: magnet rotation step [deg], in [0.5, 45].
        distance: magnet to insertion point [m], in (0.1, 1] (closer, it would touch the chain).
        progress: a progress bar.
        out: folder for ``workspace_tips.csv`` and ``workspace.png`` (None: no files), checked
            writable before the work.

    Returns:
        A ``WorkspaceResult`` (``files`` set with ``out``).

    Raises:
        UserInputError: a step or distance out of range (named by its flag), an unwritable ``out``.
    """
    as_int_list(balls, "balls", 1)
    check_inputs(step_deg, distance)
    if out is not None:  # before the work
        check_output_dir(out, "--out")
    curves, rows, snaps = {}, [], {}
    jobs = [(n, sleeve) for n in balls for sleeve in (False, True)]
    d_mm = BallChain().ball_diameter * 1e3
    for n, sleeve in tqdm(jobs, desc="workspace", unit="chain", disable=not progress):
        chain = BallChain(n_balls=n, sleeve=Sleeve() if sleeve else None)
        for side in (+1, -1):
            tips, angles = sweep(chain, side, step_deg, distance)
            curves[(n, sleeve, side)] = tips * 1e3
            jumps = np.linalg.norm(np.diff(tips, axis=0), axis=1) * 1e3
            # A smooth step moves the tip by at most about L x (field step, <= 2 x magnet step);
            # a jump over a quarter of the chain's length is a snap-through to another branch.
            threshold = max(0.25 * n * d_mm, 1.5 * n * d_mm * np.radians(2 * step_deg))
            if np.any(jumps > threshold):
                snaps[(n, sleeve, side)] = float(abs(angles[int(np.argmax(jumps > threshold)) + 1]))
        area = workspace_area(curves[(n, sleeve, 1)], curves[(n, sleeve, -1)])
        rows.append({"n_balls": n, "sleeve": sleeve, "workspace_area_mm2": area,
                     "half_area_mm2": 0.5 * area,
                     "far_side_snap_field_angle_deg": snaps.get((n, sleeve, 1)),
                     "near_side_snap_field_angle_deg": snaps.get((n, sleeve, -1))})
    longest = max(balls)
    half = {r["sleeve"]: r["half_area_mm2"] for r in rows if r["n_balls"] == longest}
    tip_to_tip = tip_to_tip_distance({s: curves[(longest, True, s)] for s in (1, -1)},
                                     {s: curves[(longest, False, s)] for s in (1, -1)})
    summary = WorkspaceSummary(
        half_area_bare_mm2=half[False],
        half_area_sleeve_mm2=half[True],
        reduction_pct=100.0 * (1.0 - half[True] / half[False]),
        tip_to_tip_max_mm=tip_to_tip,
        chain_length_mm=longest * BallChain().ball_diameter * 1e3,
        field_at_base_mT_range=[1e3 * side_magnet(np.pi, distance).field([[0, 0, 0]])[0, 0],
                                1e3 * np.linalg.norm(side_magnet(np.pi / 2, distance).field([[0, 0, 0]]))],
    )
    data = WorkspaceResult(curves=curves, rows=rows, summary=summary, paper=PAPER,
                           setup=f"magnet at (0, -{distance * 100:.2f} cm, 0) turning about z; half area = half "
                                 "the loop of both tip curves")
    if out is not None:
        data.files = write_files(data, Path(out))
    return data
