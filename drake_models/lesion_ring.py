"""The ring of lesions a procedure leaves around a pair of pulmonary veins, and its verdict.

Each dwell of the tip ball on the wall (an ``AblationPoint``: where, which way the wall faces,
with what force, power and time) leaves a lesion (``Lesion``: the FEM surrogate's width and
depth, ``lesion_surrogate``). ``analyse_ring`` walks the ring's targets in order (a closed loop:
the last target's neighbour is the first) and says whether the veins are isolated:

- Inter-lesion distance: centre to centre (the straight line between the contact points; on a
  wall of 20-30 mm radius it is within 0.3 % of the arc at 6 mm).
- Gap: two neighbouring lesions that do not overlap (centre distance > the mean of their
  widths), or a target without a lesion (never reached).
- Transmural: depth >= the local wall thickness. Default: the procedural atrium's own 2.5 mm
  (``HeartParams.wall_thickness``: the LA wall is mostly 1.5-3 mm, Ho et al. 2012); CT wall
  thickness maps of the PV antrum put most segments at 1-2.5 mm (Int. J. Arrhythm. 22:22, 2021:
  the reconnected segments are the thicker ones), so 2.5 mm is the demanding end.
- Isolated: no gap and every lesion transmural.
- The clinical spacing rule, reported beside the verdict: neighbouring lesions no more than
  ``CLOSE_MAX_DISTANCE_M`` = 6 mm apart (the CLOSE protocol: Taghji et al., "Evaluation of a
  strategy aiming to enclose the pulmonary veins with contiguous and optimized radiofrequency
  lesions in paroxysmal atrial fibrillation", JACC Clin. Electrophysiol. 4:99, 2018).

Pictures: ``ring_figure`` (a PNG: the ring unrolled, lesions to scale, gaps marked, the distances
against the spacing rule, the depths against the wall) and ``draw_lesions`` (Meshcat patches on
the wall, oriented by its normal, coloured by transmurality, gaps marked).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from ballchain.drake_models import lesion_surrogate as surrogate
from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.drake_models.heart import HeartParams
from ballchain.drake_models.params import GRAVITY, magnet_grade
from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.infrastructure import safe_files

CLOSE_MAX_DISTANCE_M = 6e-3  # the CLOSE protocol's largest inter-lesion distance (Taghji et al. 2018)
DEFAULT_WALL_THICKNESS_M = HeartParams.wall_thickness


@dataclass(frozen=True)
class AblationPoint:
    """One dwell of the tip ball on the wall.

    Attributes:
        name: the target's name ("left_7").
        p_W: (3,) the contact point on the wall [m].
        n_W: (3,) unit wall normal at p_W, into the blood (out of the tissue).
        force_N: mean true contact force over the dwell [N].
        duration_s: RF time [s].
        power_W: generator power [W].
    """

    name: str
    p_W: np.ndarray
    n_W: np.ndarray
    force_N: float
    duration_s: float
    power_W: float


@dataclass(frozen=True)
class Lesion:
    """The lesion one dwell leaves.

    Attributes:
        point: the dwell.
        width_m: largest diameter (Omega = 1) [m].
        depth_m: depth below the wall's surface [m].
        magnet_peak_C: the tip magnet's hottest temperature over the dwell [C].
        transmural: depth >= ``wall_thickness_m``.
        wall_thickness_m: the local wall thickness it was judged against [m].
        grade: the magnet grade; ``magnet_ok``: its peak stayed below the grade's limit.
    """

    point: AblationPoint
    width_m: float
    depth_m: float
    magnet_peak_C: float
    transmural: bool
    wall_thickness_m: float = DEFAULT_WALL_THICKNESS_M
    grade: str = "N52"

    @property
    def name(self) -> str:
        return self.point.name

    @property
    def magnet_ok(self) -> bool:
        return bool(self.magnet_peak_C < magnet_grade(self.grade).max_operating_C)

    def to_dict(self) -> dict:
        """The lesion and its dwell for JSON (mm, gf, W, s, C)."""
        p = self.point
        return {"name": p.name, "position_mm": [round(1e3 * float(v), 4) for v in p.p_W],
                "force_gf": round(float(p.force_N) / GRAVITY * 1e3, 3), "power_W": round(float(p.power_W), 4),
                "duration_s": round(float(p.duration_s), 4), "width_mm": round(1e3 * self.width_m, 4),
                "depth_mm": round(1e3 * self.depth_m, 4), "magnet_peak_C": round(float(self.magnet_peak_C), 3),
                "transmural": bool(self.transmural), "grade": self.grade, "magnet_ok": self.magnet_ok}


def _check_point(k: int, p: AblationPoint) -> None:
    if not isinstance(p, AblationPoint):
        raise UserInputError(f"points[{k}] must be an AblationPoint, got {short_repr(p)}")
    for name in ("p_W", "n_W"):
        v = np.asarray(getattr(p, name), dtype=float)
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise UserInputError(f"points[{k}].{name} must be 3 finite numbers [m], got {short_repr(getattr(p, name))}")
    if abs(float(np.linalg.norm(p.n_W)) - 1.0) > 1e-6:
        raise UserInputError(f"points[{k}].n_W must be a unit vector, got {short_repr(p.n_W)}")


def lesions_for(points: list[AblationPoint], *, grade: str = "N52",
                wall_thickness_m: float = DEFAULT_WALL_THICKNESS_M) -> list[Lesion]:
    """The lesion of every dwell (the surrogate at its force, power and duration).

    Args:
        points: the dwells.
        grade: the tip magnet's grade (``params.MAGNET_GRADES``), for ``Lesion.magnet_ok``.
        wall_thickness_m: the local wall thickness [m] (one value for the ring).
    """
    magnet_grade(grade)
    if not (isinstance(wall_thickness_m, (int, float)) and math.isfinite(wall_thickness_m)
            and 0.0 < wall_thickness_m <= 20e-3):
        raise UserInputError(f"wall_thickness_m must be in (0, 0.02] m, got {short_repr(wall_thickness_m)}")
    for k, p in enumerate(points):
        _check_point(k, p)
    model = surrogate.default_surrogate() if points else None
    out = []
    for k, p in enumerate(points):
        try:
            pred = model.predict(p.force_N, p.power_W, p.duration_s)
        except UserInputError as err:
            raise UserInputError(f"points[{k}] ({p.name}): {err}") from None
        out.append(Lesion(point=p, width_m=pred.width_m, depth_m=pred.depth_m, magnet_peak_C=pred.magnet_peak_C,
                          transmural=bool(pred.depth_m >= wall_thickness_m), wall_thickness_m=float(wall_thickness_m),
                          grade=grade))
    return out


def choose_power(force_N: float, duration_s: float, *, grade: str = "N52") -> float:
    """``lesion_surrogate.choose_power``: the highest power keeping the magnet below its limit."""
    return surrogate.choose_power(force_N, duration_s, grade=grade)


@dataclass
class RingVerdict:
    """``analyse_ring``'s answer (SI units; ``to_dict`` gives mm).

    Attributes:
        order: the ring's target names in order (a closed loop).
        slots: per position around the ring, the index into the lesions, or None (a missing target).
        pairs: per neighbouring pair of lesions (last -> first included): {a, b, distance_m,
            mean_width_m, overlap, spacing_ok, across_missing: the targets without lesion between}.
        gaps: {kind: "no_overlap", a, b, distance_m, mean_width_m} and {kind: "missing", target}.
        missing: targets with no lesion; non_transmural: lesions not through the wall.
        transmural_fraction: of the lesions placed.
        isolated: no gap and every lesion transmural.
        spacing_ok: every neighbouring pair within ``spacing_rule_m`` (the CLOSE rule).
        spacing_rule_m, wall_thickness_m: what it was judged against.
    """

    order: list[str]
    slots: list
    pairs: list[dict]
    gaps: list[dict]
    missing: list[str]
    non_transmural: list[str]
    transmural_fraction: float
    isolated: bool
    spacing_ok: bool
    spacing_rule_m: float = CLOSE_MAX_DISTANCE_M
    wall_thickness_m: float = DEFAULT_WALL_THICKNESS_M
    lesion_names: list = field(default_factory=list)

    def to_dict(self) -> dict:
        """The verdict for JSON (lengths in mm)."""
        def mm(v):
            return round(1e3 * float(v), 4)

        def pair(p):
            return {"a": p["a"], "b": p["b"], "distance_mm": mm(p["distance_m"]),
                    "mean_width_mm": mm(p["mean_width_m"]), "overlap": bool(p["overlap"]),
                    "spacing_ok": bool(p["spacing_ok"]), "across_missing": list(p["across_missing"])}

        def gap(g):
            if g["kind"] == "missing":
                return {"kind": "missing", "target": g["target"]}
            return {"kind": g["kind"], "a": g["a"], "b": g["b"], "distance_mm": mm(g["distance_m"]),
                    "mean_width_mm": mm(g["mean_width_m"])}

        distances = [p["distance_m"] for p in self.pairs]
        return {"isolated": bool(self.isolated), "order": list(self.order), "n_targets": len(self.order),
                "n_lesions": len(self.lesion_names), "gaps": [gap(g) for g in self.gaps],
                "missing": list(self.missing), "non_transmural": list(self.non_transmural),
                "transmural_fraction": round(float(self.transmural_fraction), 4),
                "spacing_ok": bool(self.spacing_ok), "spacing_rule_mm": mm(self.spacing_rule_m),
                "wall_thickness_mm": mm(self.wall_thickness_m),
                "max_distance_mm": mm(max(distances)) if distances else None,
                "pairs": [pair(p) for p in self.pairs]}


def _slots(lesions: list[Lesion], order: list[str]) -> list[tuple[str, int | None]]:
    """The ring's positions in order: (target name, lesion index or None when it has none); a
    target ablated twice has two positions, in the lesions' order."""
    by_name: dict[str, list[int]] = {}
    for k, les in enumerate(lesions):
        by_name.setdefault(les.name, []).append(k)
    unknown = sorted(set(by_name) - set(order))
    if unknown:
        raise UserInputError(f"lesions at targets not in ring_order: {short_repr(unknown)}")
    return [(name, k) for name in order for k in by_name.get(name, [None])]


def _pairs(lesions: list[Lesion], slots: list, rule_m: float) -> list[dict]:
    """Neighbouring lesions around the closed ring, with the targets without lesion between them."""
    placed = [q for q, (_, k) in enumerate(slots) if k is not None]
    n = len(slots)
    pairs = []
    for i, pos in enumerate(placed if len(placed) >= 2 else []):
        nxt = placed[(i + 1) % len(placed)]
        a, b = lesions[slots[pos][1]], lesions[slots[nxt][1]]
        end = nxt if nxt > pos else nxt + n
        dist = float(np.linalg.norm(np.asarray(a.point.p_W, float) - np.asarray(b.point.p_W, float)))
        mean_w = 0.5 * (a.width_m + b.width_m)
        pairs.append({"a": a.name, "b": b.name, "ia": slots[pos][1], "ib": slots[nxt][1], "distance_m": dist,
                      "mean_width_m": mean_w, "overlap": bool(dist <= mean_w), "spacing_ok": bool(dist <= rule_m),
                      "across_missing": [slots[q % n][0] for q in range(pos + 1, end)]})
    if len(pairs) == 2 and not pairs[0]["across_missing"] and not pairs[1]["across_missing"]:
        pairs = pairs[:1]  # two lesions side by side on a ring of two: one pair, not the same twice
    return pairs


def analyse_ring(lesions: list[Lesion], ring_order: list[str] | None = None) -> RingVerdict:
    """The verdict on a closed ring of lesions.

    Args:
        lesions: the lesions (``lesions_for``).
        ring_order: the targets' names in order around the ring (a closed loop); targets with no
            lesion are gaps. None: the lesions' own order, nothing missing.
    """
    if ring_order is None:
        ring_order = list(dict.fromkeys(les.name for les in lesions))
    if not all(isinstance(n, str) for n in ring_order) or len(set(ring_order)) != len(ring_order):
        raise UserInputError(f"ring_order must be distinct target names, got {short_repr(ring_order)}")
    if not all(isinstance(les, Lesion) for les in lesions):
        raise UserInputError("lesions must be Lesion objects (lesions_for)")
    thickness = {les.wall_thickness_m for les in lesions}
    wall = thickness.pop() if len(thickness) == 1 else DEFAULT_WALL_THICKNESS_M
    slots = _slots(lesions, list(ring_order))
    pairs = _pairs(lesions, slots, CLOSE_MAX_DISTANCE_M)
    missing = [name for name, k in slots if k is None]
    gaps = [{"kind": "no_overlap", "a": p["a"], "b": p["b"], "distance_m": p["distance_m"],
             "mean_width_m": p["mean_width_m"]} for p in pairs if not p["overlap"]]
    gaps += [{"kind": "missing", "target": name} for name in missing]
    non_transmural = [les.name for les in lesions if not les.transmural]
    fraction = (len(lesions) - len(non_transmural)) / len(lesions) if lesions else 0.0
    return RingVerdict(order=list(ring_order), slots=[k for _, k in slots], pairs=pairs, gaps=gaps,
                       missing=missing, non_transmural=non_transmural, transmural_fraction=fraction,
                       isolated=bool(lesions) and not gaps and not non_transmural,
                       spacing_ok=bool(pairs) and all(p["spacing_ok"] for p in pairs),
                       wall_thickness_m=wall, lesion_names=[les.name for les in lesions])


# ------------------------------------------------------------------------------------------- pictures
TRANSMURAL_RGB = (0.10, 0.65, 0.25)  # green: through the wall
PARTIAL_RGB = (0.95, 0.55, 0.10)  # orange: not through the wall
GAP_RGB = (0.90, 0.10, 0.10)  # red: a gap


def _unrolled(lesions: list[Lesion], verdict: RingVerdict) -> tuple[list, float]:
    """Arc positions [m] of the ring's slots (centre-to-centre distances added up; a missing
    target evenly between its neighbours) and the ring's length (back to the first lesion)."""
    n = len(verdict.slots)
    s = [None] * n
    placed = [q for q, k in enumerate(verdict.slots) if k is not None]
    if not verdict.pairs:  # fewer than two lesions: the slots at the spacing rule's distance
        q0 = placed[0] if placed else 0
        return [((q - q0) % n) * CLOSE_MAX_DISTANCE_M for q in range(n)], n * CLOSE_MAX_DISTANCE_M
    s[placed[0]] = 0.0
    total = 0.0
    for p in verdict.pairs:
        pos = next(q for q in placed if verdict.slots[q] == p["ia"])
        nxt = next(q for q in placed if verdict.slots[q] == p["ib"])
        end = nxt if nxt > pos else nxt + n
        for step, q in enumerate(range(pos + 1, end), start=1):  # targets without lesion between
            s[q % n] = total + p["distance_m"] * step / (end - pos)
        if nxt != placed[0]:
            s[nxt] = total + p["distance_m"]
        total += p["distance_m"]
    if len(verdict.pairs) == 1:  # two lesions: back to the first along the same chord
        total *= 2.0
    return s, total


LABEL_PT = 9  # the smallest text of the ring figure [pt]: legible where a report shows it


def _name_prefix(names) -> str:
    """What every target name of the ring starts with, up to its last "_" ("right_" of right_1 ...
    right_18), so that the figure labels the targets by what tells them apart; "" if nothing."""
    common = os.path.commonprefix(list(names)) if names else ""
    prefix = common[: common.rfind("_") + 1]
    return prefix if all(len(n) > len(prefix) for n in names) else ""


def _prefix_note(names) -> str:
    prefix = _name_prefix(names)
    return f"; targets {prefix}N by their N" if prefix else ""


def ring_figure(verdict: RingVerdict, lesions: list[Lesion], path, *, title: str = "Lesion ring") -> None:
    """A PNG map of the ring: unrolled along the ring (lesions drawn to scale by their width, green
    through the wall, orange not, missing targets and gaps in red, the first lesion drawn again at
    the end for the last -> first pair), the distances against the 6 mm spacing rule and the mean
    widths (overlap), and the depths against the wall thickness."""
    plt = safe_files.agg_pyplot()
    s, total = _unrolled(lesions, verdict)
    # Drawn at the width a report shows it (about 1000 px), every text at least LABEL_PT points.
    fig, (ax, ax_d, ax_z) = plt.subplots(3, 1, figsize=(10, 9), gridspec_kw={"height_ratios": [1.0, 1, 1]})
    for q, k in enumerate(verdict.slots):
        x = 1e3 * s[q]
        if k is None:
            ax.add_patch(plt.Circle((x, 0), 2.0, fill=False, ls="--", color=GAP_RGB))
            ax.text(x, 0, "x", color=GAP_RGB, ha="center", va="center", fontsize=12, fontweight="bold")
            continue
        les = lesions[k]
        copies = [x, 1e3 * total] if q == next(i for i, v in enumerate(verdict.slots) if v is not None) else [x]
        for c, xc in enumerate(copies):
            colour = TRANSMURAL_RGB if les.transmural else PARTIAL_RGB
            ax.add_patch(plt.Circle((xc, 0), 0.5e3 * les.width_m, color=colour, alpha=0.45 if c == 0 else 0.2, lw=0))
            ax.plot(xc, 0, ".", color="k", ms=3)
    names = [n for n, _ in _slots(lesions, verdict.order)]
    first = next((q for q, k in enumerate(verdict.slots) if k is not None), None)
    labels = list(zip(s, names)) + ([(total, f"{names[first]} again")] if first is not None else [])
    for x, name in labels:
        ax.text(1e3 * x, -5.0, name[len(_name_prefix(verdict.order)):], rotation=90, ha="center", va="top", fontsize=LABEL_PT)
    for p in verdict.pairs:
        if not p["overlap"]:
            qa = verdict.slots.index(p["ia"])
            xa = 1e3 * s[qa]
            ax.annotate("", xy=(xa + 1e3 * p["distance_m"], 4.8), xytext=(xa, 4.8),
                        arrowprops={"arrowstyle": "<->", "color": GAP_RGB})
            ax.text(xa + 0.5e3 * p["distance_m"], 5.3, "gap", color=GAP_RGB, ha="center", fontsize=LABEL_PT)
    ax.set_xlim(-6, 1e3 * total + 6)
    ax.set_ylim(-14.5, 7.5)
    ax.set_aspect("equal")
    ax.set_yticks([])
    ax.set_xlabel("distance along the ring [mm] (centre to centre)" + _prefix_note(verdict.order),
                  fontsize=LABEL_PT + 1)
    ax.tick_params(labelsize=LABEL_PT)
    _distance_panel(ax_d, verdict)
    _depth_panel(ax_z, lesions, verdict)
    state = "ISOLATED" if verdict.isolated else f"NOT isolated: {len(verdict.gaps)} gap(s)"
    if verdict.non_transmural:
        state += f", {len(verdict.non_transmural)} not transmural"
    ax.set_title(f"{title}: {state}; spacing rule {'met' if verdict.spacing_ok else 'broken'}", fontsize=LABEL_PT + 2)
    fig.tight_layout()
    safe_files.save_figure(fig, path, dpi=110)
    plt.close(fig)


def _distance_panel(ax, verdict: RingVerdict) -> None:
    """Inter-lesion distances (bars; red: no overlap) against the spacing rule and the mean widths."""
    cut = len(_name_prefix(verdict.order))
    labels = [f"{p['a'][cut:]}-{p['b'][cut:]}" for p in verdict.pairs]
    x = np.arange(len(labels))
    dist = [1e3 * p["distance_m"] for p in verdict.pairs]
    colours = [GAP_RGB if not p["overlap"] else (0.35, 0.45, 0.75) for p in verdict.pairs]
    ax.bar(x, dist, color=colours, width=0.7, label="centre distance (red: no overlap)")
    ax.plot(x, [1e3 * p["mean_width_m"] for p in verdict.pairs], "k_", ms=14, mew=2,
            label="mean width (overlap below it)")
    ax.axhline(1e3 * verdict.spacing_rule_m, color="k", ls="--", lw=1,
               label=f"spacing rule {1e3 * verdict.spacing_rule_m:g} mm (CLOSE)")
    ax.set_xticks(x, labels, rotation=90, fontsize=LABEL_PT)
    ax.tick_params(axis="y", labelsize=LABEL_PT)
    ax.set_ylabel("inter-lesion\ndistance [mm]", fontsize=LABEL_PT + 1)
    ax.set_xlim(-0.6, max(len(labels), 1) - 0.4)
    ax.set_ylim(0, 1.45 * max(dist + [1e3 * verdict.spacing_rule_m]))
    ax.legend(fontsize=LABEL_PT, loc="upper right", ncol=2)


def _depth_panel(ax, lesions: list[Lesion], verdict: RingVerdict) -> None:
    """Lesion depths (green: transmural) against the wall thickness."""
    x = np.arange(len(lesions))
    ax.bar(x, [1e3 * les.depth_m for les in lesions], width=0.7,
           color=[TRANSMURAL_RGB if les.transmural else PARTIAL_RGB for les in lesions])
    ax.axhline(1e3 * verdict.wall_thickness_m, color="k", ls="--", lw=1,
               label=f"wall {1e3 * verdict.wall_thickness_m:g} mm (green: transmural)")
    cut = len(_name_prefix(verdict.order))
    ax.set_xticks(x, [les.name[cut:] for les in lesions], rotation=90, fontsize=LABEL_PT)
    ax.tick_params(axis="y", labelsize=LABEL_PT)
    ax.set_ylabel("lesion depth [mm]", fontsize=LABEL_PT + 1)
    ax.set_xlim(-0.6, max(len(lesions), 1) - 0.4)
    ax.set_ylim(0, 1.35 * max([1e3 * les.depth_m for les in lesions] + [1e3 * verdict.wall_thickness_m]))
    ax.legend(fontsize=LABEL_PT, loc="upper right")


def draw_lesions(meshcat, lesions: list[Lesion], verdict: RingVerdict, prefix: str = "lesions",
                 targets: dict | None = None) -> None:
    """Lesions as patches on the wall in Meshcat, and the ring's gaps.

    Each lesion is a disc of its width, 0.4 mm thick, on the wall at its contact point (0.2 mm
    into the blood so that the wall does not hide it) with its axis along the wall normal: green
    when transmural, orange otherwise. A gap between two lesions is a red bar from one centre to
    the other; a target with no lesion is a red ball at its position when ``targets`` (name ->
    (3,) [m]) gives it. Opaque (see ``meshcat_overlays``: a transparent patch vanishes behind the
    semi-transparent heart). Paths: ``{prefix}/<name>[_k]``, ``{prefix}/gaps/<a>__<b>``,
    ``{prefix}/missing/<name>``.
    """
    from pydrake.geometry import Cylinder, Rgba, Sphere
    from pydrake.math import RigidTransform, RotationMatrix

    meshcat.Delete(prefix)
    seen: dict[str, int] = {}
    for les in lesions:
        k = seen[les.name] = seen.get(les.name, -1) + 1
        path = f"{prefix}/{les.name}" + (f"_{k}" if k else "")
        n = np.asarray(les.point.n_W, float)
        rgba = Rgba(*(TRANSMURAL_RGB if les.transmural else PARTIAL_RGB), 1.0)
        meshcat.SetObject(path, Cylinder(max(0.5 * les.width_m, 1e-4), 0.4e-3), rgba)
        meshcat.SetTransform(path, RigidTransform(RotationMatrix(rotation_with_z_along(n)),
                                                  np.asarray(les.point.p_W, float) + 0.2e-3 * n))
    red = Rgba(*GAP_RGB, 1.0)
    for p in verdict.pairs:
        if p["overlap"]:
            continue
        a, b = lesions[p["ia"]], lesions[p["ib"]]
        pa = np.asarray(a.point.p_W, float) + 0.6e-3 * np.asarray(a.point.n_W, float)
        pb = np.asarray(b.point.p_W, float) + 0.6e-3 * np.asarray(b.point.n_W, float)
        u = (pb - pa) / max(float(np.linalg.norm(pb - pa)), 1e-12)
        pa, pb = pa + 0.5 * a.width_m * u, pb - 0.5 * b.width_m * u  # the bar spans the gap itself
        path = f"{prefix}/gaps/{p['a']}__{p['b']}"
        meshcat.SetObject(path, Cylinder(0.35e-3, max(float(np.linalg.norm(pb - pa)), 1e-5)), red)
        meshcat.SetTransform(path, RigidTransform(RotationMatrix(rotation_with_z_along(pb - pa)), 0.5 * (pa + pb)))
    for name in verdict.missing:
        if targets is None or name not in targets:
            continue
        meshcat.SetObject(f"{prefix}/missing/{name}", Sphere(1.2e-3), red)
        meshcat.SetTransform(f"{prefix}/missing/{name}", RigidTransform(np.asarray(targets[name], float)))
