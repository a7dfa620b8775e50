"""A user's atrium surface checked and made usable: units, size, holes, manifold edges and
winding (every problem listed in one ``AtriumMeshError``), decimated above ``DECIMATE_ABOVE``
triangles, its shells oriented by nesting depth, a shell that crosses itself noted or refused
(``validate_surface``; ``load_atrium_surface`` reads a file first)."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models.mesh_crossings import _self_crossing_problems
from ballchain.drake_models.mesh_io import AtriumMeshError, read_mesh
from ballchain.drake_models.mesh_shells import opening_areas, orient_shells
from ballchain.infrastructure.arg_checks import as_array, require_choice, require_type

Units = Literal["auto", "m", "mm"]
SENSIBLE_EXTENT_MM = (30.0, 80.0)  # typical LA size; outside ACCEPTED_EXTENT_MM is refused
ACCEPTED_EXTENT_MM = (20.0, 120.0)
MAX_OPENING_AREA = 1e-6  # [m^2] an opening (a seam not welded) up to this area is bridged, not refused
DECIMATE_ABOVE = 20_000  # triangles: a larger surface is decimated for contact and the signed distance
DECIMATE_TO = 10_000  # triangles after decimation (edges about 1.4 mm on a 50 mm atrium)
MAX_TRIANGLES = 2_000_000  # refused above (a segmentation at 0.1 mm voxels has about 1 million)


@dataclass
class AtriumSurface:
    """A validated surface in metres, each shell oriented by its nesting depth (outward, inward
    around a cavity).

    Attributes:
        V: (nv, 3) vertices [m].
        F: (nf, 3) triangles, outward (counter-clockwise seen from outside).
        units: the units the file was read in ("m" or "mm").
        units_guessed: whether ``units`` was guessed from the size.
        extent_mm: (3,) bounding-box sides [mm].
        volume_ml: enclosed volume [ml].
        notes: what was fixed or is unusual (e.g. "orientation flipped to outward").
    """

    V: np.ndarray
    F: np.ndarray
    units: str
    units_guessed: bool
    extent_mm: np.ndarray
    volume_ml: float
    notes: list[str] = field(default_factory=list)

    def wall(self, thickness: float = 2.5e-3, layers: int = 2) -> tuple[np.ndarray, np.ndarray]:
        """A tetrahedral wall grown outward along the vertex normals (V (m), T), as for the
        procedural atrium; thickness [m], layers >= 2 for compliant hydroelastics."""
        return mt.extrude_shell(self.V, self.F, mt.vertex_normals(self.V, self.F), thickness, layers)


def _guess_units(extent: float) -> str | None:
    if 0.02 <= extent <= 0.12:
        return "m"
    if 20.0 <= extent <= 120.0:
        return "mm"
    return None


def validate_surface(V: np.ndarray, F: np.ndarray, units: Units = "auto", progress: bool = True) -> AtriumSurface:
    """Check a surface and convert it to metres; raises AtriumMeshError listing every problem.

    Accepted beyond a single closed shell: several shells (each oriented by how deeply it is
    nested: outward, inward in a cavity, ...), seams left slightly open (openings up to
    ``MAX_OPENING_AREA``), and a mesh of up to ``MAX_TRIANGLES`` triangles, decimated above
    ``DECIMATE_ABOVE`` (see ``decimate``). A shell that crosses itself (``self_crossings``, on
    the surface as used, after decimation) is noted while its wrong-side parts lie within
    ``SELF_CROSSING_DEPTH`` of its boundary, and refused beyond.

    Args:
        V: (nv, 3) vertices in the file's units.
        F: (nf, 3) triangles.
        units: "m", "mm", or "auto" (guessed from the size).
        progress: say on stderr when a large mesh is decimated.
    """
    require_choice(units, ("auto", "m", "mm"), "units")
    V = np.asarray(V, dtype=float) if isinstance(V, np.ndarray) else as_array(V, "V", (-1, 3))
    F = as_array(F, "F", (-1, 3), integer=True)
    if V.ndim != 2 or V.shape[1] != 3:
        raise AtriumMeshError(f"V must be an array of shape (k, 3) of vertex coordinates, got shape {V.shape}")
    if len(F) and (F.min() < 0 or F.max() >= len(V)):
        raise AtriumMeshError(f"F must index the {len(V)} vertices (0 to {len(V) - 1}), got indices "
                              f"{int(F.min())} to {int(F.max())}")
    if not np.all(np.isfinite(V)):
        raise AtriumMeshError("the surface has NaN or infinite vertex coordinates")
    if len(F) < 4:
        raise AtriumMeshError(f"the surface has {len(F)} triangles: a closed surface needs at least 4")
    if len(F) > MAX_TRIANGLES:
        raise AtriumMeshError(
            f"the surface has {len(F):,} triangles, more than the {MAX_TRIANGLES:,} accepted (reading and "
            f"decimating it would take minutes; contact and the signed distance use {DECIMATE_TO:,}): "
            "decimate it first (e.g. quadric decimation in MeshLab or Blender)")
    notes: list[str] = []
    extent_raw = float(np.ptp(V, axis=0).max())
    guessed = units == "auto"
    if guessed:
        units = _guess_units(extent_raw)
        if units is None:
            raise AtriumMeshError(
                f"cannot tell the units: the largest bounding-box side is {extent_raw:.4g} (a left "
                f"atrium is about 30-80 mm: 0.03-0.08 in metres or 30-80 in millimetres); rescale "
                f"the mesh or declare its units")
        notes.append(f"units guessed as {units} from the size")
    V = V * (1e-3 if units == "mm" else 1.0)
    extent_mm = np.ptp(V, axis=0) * 1e3
    problems = _size_problems(extent_mm, units, notes) + _topology_problems(V, F, notes)
    if problems:
        raise AtriumMeshError("atrium surface rejected:\n  - " + "\n  - ".join(problems))
    V, F = _drop_unused(V, F, notes)
    decimated = len(F) > DECIMATE_ABOVE
    if decimated:
        V, F = decimate(V, F, DECIMATE_TO, notes, progress)
    F, volume = orient_shells(V, F, notes)
    problems = _self_crossing_problems(V, F, notes, progress, decimated)  # on the surface as used
    if problems:
        raise AtriumMeshError("atrium surface rejected:\n  - " + "\n  - ".join(problems))
    return AtriumSurface(V, F, units, guessed, extent_mm, volume * 1e6, notes)


def _size_problems(extent_mm: np.ndarray, units: str, notes: list[str]) -> list[str]:
    if not ACCEPTED_EXTENT_MM[0] <= extent_mm.max() <= ACCEPTED_EXTENT_MM[1]:
        return [f"size: the largest side is {extent_mm.max():.1f} mm in {units}, outside "
                f"{ACCEPTED_EXTENT_MM[0]:.0f}-{ACCEPTED_EXTENT_MM[1]:.0f} mm (a left atrium is about "
                f"{SENSIBLE_EXTENT_MM[0]:.0f}-{SENSIBLE_EXTENT_MM[1]:.0f} mm): wrong units or not an atrium?"]
    if not SENSIBLE_EXTENT_MM[0] <= extent_mm.max() <= SENSIBLE_EXTENT_MM[1]:
        notes.append(f"largest side {extent_mm.max():.1f} mm is outside the usual 30-80 mm")
    return []


def _topology_problems(V: np.ndarray, F: np.ndarray, notes: list[str]) -> list[str]:
    """Degenerate triangles, holes (openings larger than ``MAX_OPENING_AREA``; smaller ones, such
    as a seam left unwelded, are noted), non-manifold edges, a shell's inconsistent winding."""
    problems = []
    area2 = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    degenerate = int((area2 <= 1e-12 * max(float(np.ptp(V, axis=0).max()), 1e-9) ** 2).sum())
    if degenerate:
        problems.append(f"{degenerate} degenerate (zero-area or repeated-vertex) triangles")
    edges, counts, balance = mt.edge_use_counts(F)
    open_edges = int((counts == 1).sum())
    non_manifold = int((counts > 2).sum())
    if open_edges:
        openings = opening_areas(V, F)
        if openings.max() > MAX_OPENING_AREA:
            problems.append(
                f"not closed: {open_edges} boundary edges (holes, the largest {openings.max() * 1e6:.1f} mm^2 "
                f"> {MAX_OPENING_AREA * 1e6:.0f} mm^2); close the holes (e.g. cap the pulmonary veins and the "
                "mitral valve) so that the surface is watertight")
        else:
            notes.append(f"{open_edges} boundary edges in {len(openings)} narrow openings (seams, each under "
                         f"{MAX_OPENING_AREA * 1e6:.0f} mm^2): the winding-number inside test bridges them")
    if non_manifold:
        problems.append(f"not manifold: {non_manifold} edges shared by more than two triangles")
    flipped_edges = int(((counts == 2) & (balance != 0)).sum())
    if flipped_edges:
        problems.append(
            f"inconsistent orientation: {flipped_edges} edges between triangles facing opposite "
            "ways; make the triangle winding consistent")
    return problems


def _drop_unused(V: np.ndarray, F: np.ndarray, notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    used = np.zeros(len(V), bool)
    used[F.ravel()] = True
    if used.all():
        return V, F
    notes.append(f"{int((~used).sum())} unused vertices dropped")
    remap = -np.ones(len(V), int)
    remap[used] = np.arange(used.sum())
    return V[used], remap[F]


def decimate(V: np.ndarray, F: np.ndarray, target: int, notes: list[str], progress: bool = True
             ) -> tuple[np.ndarray, np.ndarray]:
    """Quadric-error decimation of a large surface to about ``target`` triangles
    (``fast_simplification``, Garland and Heckbert's edge collapses), for the contact wall and the
    signed distance; refused when the result is no longer a usable surface.

    Raises:
        AtriumMeshError: the decimated surface has degenerate triangles, new holes or folds.
    """
    import time

    import fast_simplification

    if progress:
        print(f"atrium mesh: decimating {len(F):,} triangles to about {target:,} (quadric decimation) ...",
              file=sys.stderr, flush=True)
    t0 = time.process_time()
    Vd, Fd = fast_simplification.simplify(np.ascontiguousarray(V), np.ascontiguousarray(F, np.int32),
                                          target_count=target)
    Vd, Fd = np.asarray(Vd, float), np.asarray(Fd, np.int64)
    cpu = time.process_time() - t0
    problems = _topology_problems(Vd, Fd, [])
    if problems:
        raise AtriumMeshError(
            f"the surface has {len(F):,} triangles (> {DECIMATE_ABOVE:,}) and its decimation to {target:,} is "
            f"not usable ({'; '.join(problems)}): decimate it yourself to at most {DECIMATE_ABOVE:,} triangles")
    Vd, Fd = _drop_unused(Vd, Fd, [])
    notes.append(f"decimated from {len(F):,} to {len(Fd):,} triangles for contact and the signed distance "
                 f"({cpu:.1f} s CPU)")
    if progress:
        print(f"atrium mesh: {len(F):,} -> {len(Fd):,} triangles in {cpu:.1f} s CPU", file=sys.stderr, flush=True)
    return Vd, Fd


def load_atrium_surface(path: Path | str, units: Units = "auto") -> AtriumSurface:
    """Read an OBJ, STL, PLY or VTK surface, validate it and return it in metres.

    Args:
        path: .obj, .stl, .ply or .vtk (legacy ASCII polydata) file.
        units: "m", "mm" or "auto" (guessed from the size, see the module docstring).

    Raises:
        AtriumMeshError: unreadable file or an unusable surface (the message lists why).
    """
    require_type(path, (str, Path), "path", "a file name (str or Path)")
    require_choice(units, ("auto", "m", "mm"), "units")
    path = Path(path)
    V, F = read_mesh(path)
    try:
        return validate_surface(V, F, units)
    except AtriumMeshError as err:
        raise AtriumMeshError(f"{path}: {err}") from None
