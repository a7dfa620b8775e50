"""Load and validate a user's anatomy surface (OBJ, STL, PLY or VTK), and give it a wall.

The surface is where the chain meets the anatomy: a segmented atrium's endocardial (blood-side)
surface, with the chain inside it (``side="lumen"``), or a printed phantom part, a wall section
with vein openings, with the chain outside it (``side="solid"``). Meshes nobody here generated
are accepted as they come: several shells (vein tubes overlapping the chamber join it; a shell
nested in another is a cavity, each oriented by its nesting depth), seams left slightly open
(openings up to ``MAX_OPENING_AREA``), inside-out winding; inside tests use the generalised
winding number of every shell (``surface_tree``). A surface above ``DECIMATE_ABOVE`` triangles
is decimated (quadric edge collapses) for contact and the signed distance; one above
``MAX_TRIANGLES`` is refused. A shell that crosses itself is noted on stderr when the crossing
is shallow and refused when parts of it lie deeper than ``SELF_CROSSING_DEPTH`` on the wrong side
(``self_crossings``: the inside test still holds there, the wall distance does not). Its size decides the units when they are not declared: a left
atrium is about 30-80 mm across, so a largest bounding-box side of 0.02-0.12 is read as metres
and 20-120 as millimetres. Every check that fails is reported in one ``AtriumMeshError``
listing what is wrong and how to fix it.

``UserAtrium`` turns a validated surface into an atrium the chain plant accepts (a wall grown
behind the surface in two tetrahedra layers, a hole at a lumen's septal puncture, inside tests
by winding number); a scenario selects it with ``atrium_file`` and ``puncture``.

No third-party mesh reader is needed: OBJ (``v``/``f`` records, polygons fanned into triangles,
``f a/b/c`` and negative indices accepted), STL (ASCII or binary), PLY (ASCII or binary) and
legacy ASCII VTK polydata are parsed here.

The modules: ``mesh_io.py`` (the readers and writers), ``atrium_surface.py`` (the checks, the
decimation, ``validate_surface``, ``load_atrium_surface``), ``mesh_shells.py`` (openings, shells,
their orientation), ``mesh_crossings.py`` (a shell that crosses itself) and this one
(``UserAtrium``: the wall, the puncture, the inside tests); the names of the others are
re-exported here.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ballchain.drake_models import mesh_tools as mt
from ballchain.infrastructure.arg_checks import as_vector, require_choice, require_int, require_positive, require_type
from ballchain.drake_models.atrium_surface import (ACCEPTED_EXTENT_MM, DECIMATE_ABOVE, DECIMATE_TO, MAX_OPENING_AREA,
                                                   MAX_TRIANGLES, SENSIBLE_EXTENT_MM, AtriumSurface, Units, decimate,
                                                   load_atrium_surface, validate_surface)
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.mesh_crossings import SELF_CROSSING_DEPTH, self_crossings
from ballchain.drake_models.mesh_io import (MESH_NOUN, AtriumMeshError, read_mesh, read_obj, read_ply, read_stl,
                                            read_vtk_polydata, write_stl_ascii, write_stl_binary)
from ballchain.drake_models.mesh_shells import (NESTED_FRACTION, SEAM_GAP, opening_areas, orient_shells,
                                                shell_containment, shell_labels)
from ballchain.drake_models.surface_tree import SurfaceTree
from ballchain.drake_models.model_files import cache_dir, cached_files, source_hash

MAX_PUNCTURE_DISTANCE = 5e-3  # [m] a user's puncture may lie this far from the surface
MAX_MITER = 3.0  # a wall vertex moves at most this many wall thicknesses (at a sharp corner)
MAX_SLIVER_FRACTION = 0.01  # triangles whose wall prism is flat: left out of the wall up to this share
DEGENERATE_VOLUME_FRACTION = 1e-6  # a wall tetrahedron this much smaller than the median is flat

__all__ = [  # this module's names and those of the modules it was split into (their old home)
    "ACCEPTED_EXTENT_MM", "DECIMATE_ABOVE", "DECIMATE_TO", "DEGENERATE_VOLUME_FRACTION", "MAX_MITER",
    "MAX_OPENING_AREA", "MAX_PUNCTURE_DISTANCE", "MAX_SLIVER_FRACTION", "MAX_TRIANGLES", "MESH_NOUN",
    "NESTED_FRACTION", "SEAM_GAP", "SELF_CROSSING_DEPTH", "SENSIBLE_EXTENT_MM", "AtriumMeshError", "AtriumSurface",
    "Units", "UserAtrium", "UserAtriumParams", "decimate", "grid_winding_inside", "load_atrium_surface",
    "opening_areas", "orient_shells", "read_mesh", "read_obj", "read_ply", "read_stl", "read_vtk_polydata",
    "self_crossings", "shell_containment", "shell_labels", "validate_surface", "wall_directions", "write_stl_ascii",
    "write_stl_binary",
]


@dataclass(frozen=True)
class UserAtriumParams:
    """Wall and sheath parameters of a user atrium (the counterpart of HeartParams).

    Attributes:
        wall_thickness: the wall behind the surface [m]: grown outward from a lumen, inward into
            a solid.
        wall_layers: tetrahedra layers through the wall (>= 2).
        puncture_diameter: hole cut for the sheath around the puncture [m] (lumen).
        sheath_extension: how far the sheath reaches beyond the wall into the chamber [m] (lumen;
            a solid's sheath ends at its given tip).
        working_margin: (solid) the chain works within the box around the solid and the sheath
            tip grown by this much [m]; a ball beyond it has left the scene.
    """

    wall_thickness: float = 2.5e-3
    wall_layers: int = 2
    puncture_diameter: float = 6e-3
    sheath_extension: float = 3e-3
    working_margin: float = 0.1

    def __post_init__(self) -> None:
        require_positive(self.wall_thickness, "UserAtriumParams.wall_thickness", "m")
        require_int(self.wall_layers, "UserAtriumParams.wall_layers", 2)
        require_positive(self.puncture_diameter, "UserAtriumParams.puncture_diameter", "m")
        require_positive(self.sheath_extension, "UserAtriumParams.sheath_extension", "m", allow_zero=True)
        require_positive(self.working_margin, "UserAtriumParams.working_margin", "m")


SIDES = ("lumen", "solid")
SHEATH_CHECK_LENGTH = 5e-3  # [m] the sheath's axis must stay on the chain's side this far past its exit
MIN_TIP_CLEARANCE = 1e-3  # [m] a solid's sheath tip stands at least this far from the surface


class UserAtrium:
    """A user's anatomy surface, usable wherever the plant takes a ``LeftAtrium``.

    Args:
        surface: a validated surface (``load_atrium_surface``).
        p_HP: (3,) [m]. ``side="lumen"``: the septal puncture, moved onto the surface (nearest
            vertex; at most ``MAX_PUNCTURE_DISTANCE`` away). ``side="solid"``: the sheath's tip
            in free space (its exit), at least ``MIN_TIP_CLEARANCE`` from the surface.
        sheath_aim: (3,) point the sheath points to [m] (default: the lumen's centroid; for a
            solid, the surface point nearest the tip).
        params: wall and sheath parameters.
        side: "lumen": the chain works inside the closed surface (a segmented atrium: several
            overlapping shells, such as vein tubes, join into one chamber, and disjoint pieces
            are refused); "solid": it works outside (a printed phantom part, a wall section with
            vein openings; several parts allowed): the signed distance, the wall, the inside
            test and the escape test are mirrored.

    There are no ablation targets (``rings``, ``ostia`` and ``carinas`` are empty): a mesh
    carries no ostia labels. Implements ``drake_models.atrium.Atrium``.
    """

    def __init__(self, surface: AtriumSurface, p_HP, sheath_aim=None, params: UserAtriumParams | None = None,
                 side: str = "lumen"):
        require_type(surface, AtriumSurface, "UserAtrium surface", "an AtriumSurface (from load_atrium_surface)")
        require_choice(side, SIDES, "UserAtrium side")
        p_HP = as_vector(p_HP, "UserAtrium p_HP (the puncture or the sheath tip)", unit="m")
        if sheath_aim is not None:
            sheath_aim = as_vector(sheath_aim, "UserAtrium sheath_aim", unit="m")
        if params is not None:
            require_type(params, UserAtriumParams, "UserAtrium params", "a UserAtriumParams or None")
        self.surface = surface
        self.side = side
        self.params = params or UserAtriumParams()
        V, F = surface.V, surface.F
        self._tree = SurfaceTree.build(V, F)
        self._chamber_faces = self._union_boundary()
        if side == "lumen":
            self._place_lumen_sheath(p_HP, sheath_aim)
        else:
            self._place_solid_sheath(p_HP, sheath_aim)
        self.rings: dict = {}  # no ablation targets, ostia or carinas (the Atrium protocol)
        self.ostia: list = []
        self.carinas: dict = {}
        grow = 1.0 if side == "lumen" else -1.0  # the wall lies behind the surface, seen from the chain
        self._wall_normals = grow * wall_directions(V, F)
        self._behind = SurfaceTree.build(V + self._wall_normals * self.params.wall_thickness, F)
        self.inner_faces = self._chamber_faces
        if side == "lumen":
            c = V[self.inner_faces].mean(axis=1)
            rel = c - self.p_HP
            along = rel @ self.sheath_axis_H
            radial = np.linalg.norm(rel - along[:, None] * self.sheath_axis_H, axis=1)
            self.inner_faces = self.inner_faces[~((radial < 0.5 * self.params.puncture_diameter)
                                                  & (np.abs(along) < 10e-3))]
        self.wall_distance = mt.SurfaceDistance(V, self.inner_faces)
        lo, hi = np.minimum(V.min(axis=0), self.p_HP), np.maximum(V.max(axis=0), self.p_HP)
        self.working_box = (lo - self.params.working_margin, hi + self.params.working_margin)
        self._check_wall()

    def _union_boundary(self) -> np.ndarray:
        """The triangles on the boundary of the union of the shells (lumen: the chamber with its
        vein tubes; solid: the parts): a shell's triangles inside another shell are dropped (as
        the procedural atrium's ostia are open), so that the wall does not close an ostium."""
        V, F = self.surface.V, self.surface.F
        shells = shell_labels(F, V)
        k = int(shells.max()) + 1
        if k == 1:
            return F
        if self.side == "lumen":
            self._require_one_chamber(shells)
        keep = np.ones(len(F), bool)
        centroids = V[F].mean(axis=1)
        for j in range(k):
            mine = F[shells == j]
            lo, hi = V[mine].reshape(-1, 3).min(axis=0), V[mine].reshape(-1, 3).max(axis=0)
            near = np.flatnonzero((shells != j) & np.all((centroids >= lo) & (centroids <= hi), axis=1))
            if len(near):
                keep[near] &= SurfaceTree.build(V, mine).winding_numbers(centroids[near]) <= 0.5
        return F[keep]

    def _require_one_chamber(self, shells: np.ndarray) -> None:
        """A lumen is one chamber: shells that neither overlap nor nest are refused."""
        V, F = self.surface.V, self.surface.F
        inside = shell_containment(V, F, shells)
        touching = (inside > 0) | (inside.T > 0)
        from scipy.sparse.csgraph import connected_components

        n, label = connected_components(touching, directed=False)
        if n > 1:
            sizes = [float(np.ptp(V[np.unique(F[np.isin(shells, np.flatnonzero(label == g))])], axis=0).max() * 1e3)
                     for g in range(n)]
            raise UserInputError(
                f"mesh: the surface has {n} disjoint pieces (largest sides {', '.join(f'{s:.1f}' for s in sizes)} "
                "mm) but with side: lumen the chain works inside one chamber; keep only the chamber (remove "
                "the other pieces), or use side: solid for separate phantom parts")

    def _place_lumen_sheath(self, p_HP: np.ndarray, sheath_aim) -> None:
        V = self.surface.V
        # The puncture is snapped onto the surface: only a small correction is accepted, so a
        # mistyped point (or one in millimetres) is refused instead of silently moved far away.
        gap = float(self._tree.distances(p_HP[None])[0])
        if gap > MAX_PUNCTURE_DISTANCE:
            raise UserInputError(
                f"puncture {np.round(p_HP, 6).tolist()} m is {gap * 1e3:.1f} mm from the atrium surface; it "
                f"must lie within {MAX_PUNCTURE_DISTANCE * 1e3:.0f} mm of it (coordinates in metres, in the "
                "surface's frame after its units are applied)")
        self.p_HP = V[int(np.argmin(np.linalg.norm(V - p_HP, axis=1)))].copy()
        aim = V.mean(axis=0) if sheath_aim is None else sheath_aim
        self.sheath_axis_H = self._axis(aim)
        self.p_HE = self.p_HP + self.params.sheath_extension * self.sheath_axis_H
        ahead = self.p_HE + np.linspace(0.0, SHEATH_CHECK_LENGTH, 6)[:, None] * self.sheath_axis_H
        if not np.all(self._free(ahead)):
            raise UserInputError(
                f"sheath_aim: the sheath from the puncture {np.round(self.p_HP * 1e3, 2).tolist()} mm towards "
                f"{np.round(np.asarray(aim) * 1e3, 2).tolist()} mm leaves the chamber within "
                f"{(self.params.sheath_extension + SHEATH_CHECK_LENGTH) * 1e3:.0f} mm: aim it into the lumen")

    def _place_solid_sheath(self, p_HP: np.ndarray, sheath_aim) -> None:
        gap = float(self._tree.distances(p_HP[None])[0])
        if not self._free(p_HP[None])[0] or gap < MIN_TIP_CLEARANCE:
            where = "inside the solid" if not self._free(p_HP[None])[0] else f"{gap * 1e3:.2f} mm from its surface"
            raise UserInputError(
                f"sheath tip {np.round(p_HP * 1e3, 2).tolist()} mm is {where}; with side: solid the sheath ends "
                f"in free space, at least {MIN_TIP_CLEARANCE * 1e3:.0f} mm from the surface")
        self.p_HP = p_HP.copy()
        if sheath_aim is None:  # towards the nearest vertex of the solid
            V = self.surface.V
            sheath_aim = V[int(np.argmin(np.linalg.norm(V - p_HP, axis=1)))]
        self.sheath_axis_H = self._axis(sheath_aim)
        self.p_HE = self.p_HP.copy()

    def _axis(self, aim) -> np.ndarray:
        axis = np.asarray(aim, float) - self.p_HP
        if np.linalg.norm(axis) == 0:
            raise UserInputError("sheath_aim: the sheath aim coincides with the puncture (or the sheath tip)")
        return axis / np.linalg.norm(axis)

    def _free(self, p_H: np.ndarray) -> np.ndarray:
        """Whether points (k, 3) lie on the chain's side of the surface (the lumen, or outside the solid)."""
        inside = self._tree.winding_numbers(p_H) > 0.5
        return inside if self.side == "lumen" else ~inside

    def _check_wall(self) -> None:
        """Leave out of the wall the triangles whose prisms have flat tetrahedra (slivers, as a
        boolean union leaves along its seams: Drake cannot give a flat element a pressure field,
        "A mesh field element was degenerate"); their neighbours' prisms cover the gap. More than
        ``MAX_SLIVER_FRACTION`` of them is refused, saying where the first is."""
        p = self.params
        faces = self.inner_faces
        Vt, T = mt.extrude_shell(self.surface.V, faces, self._wall_normals, p.wall_thickness, p.wall_layers)
        vol = mt.signed_volumes(Vt, T)
        bad = np.flatnonzero(vol <= DEGENERATE_VOLUME_FRACTION * np.median(np.abs(vol)))
        self.wall_faces = faces
        if len(bad) == 0:
            return
        slivers = np.unique(bad % len(faces))  # extrude_shell stacks the tetrahedra face by face
        if len(slivers) > MAX_SLIVER_FRACTION * len(faces):
            where = np.round(Vt[T[bad[0]]].mean(axis=0) * 1e3, 2).tolist()
            raise AtriumMeshError(
                f"atrium_file: the wall grown from this surface has {len(bad)} flat (zero-volume) tetrahedra, the "
                f"first near {where} mm: the surface has a zero-area triangle or a fold there; remesh it (e.g. "
                "remove degenerate faces) and try again")
        self.wall_faces = np.delete(faces, slivers, axis=0)
        self.surface.notes.append(f"{len(slivers)} sliver triangles left out of the contact wall")

    @property
    def wall_tetrahedra(self) -> tuple[np.ndarray, np.ndarray]:
        """The wall behind the surface (outward from a lumen, into a solid), as tetrahedra."""
        p = self.params
        return mt.extrude_shell(self.surface.V, self.wall_faces, self._wall_normals, p.wall_thickness,
                                p.wall_layers)

    @property
    def blood_surface(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (v, 3) [m], triangles (f, 3)) of the chain's side: the user's surface (the
        boundary of the union of its shells)."""
        return self.surface.V, self._chamber_faces

    def lumen_grid_contains(self, origin: np.ndarray, spacing: float, shape: tuple[int, int, int]) -> np.ndarray:
        """Whether the nodes of a grid lie where the chain works (inside a lumen, outside a solid)
        by the winding number of every shell (``surface_tree``; ``grid_winding_inside``)
        -> (nx, ny, nz) bool."""
        inside = grid_winding_inside(self._tree, origin, spacing, shape)
        return inside if self.side == "lumen" else ~inside

    @property
    def lumen_key(self) -> str:
        """The inside test (winding numbers of every shell, on this side) for the SDF cache key."""
        import hashlib

        digest = hashlib.sha1(self.surface.V.tobytes() + self.surface.F.tobytes()).hexdigest()[:12]
        return f"winding_{self.side}_{digest}"

    def grid_distances(self, points: np.ndarray, band: float) -> np.ndarray:
        """Distances (k,) [m] from points (k, 3) to ``blood_surface``, capped at ``band`` (the
        SDF's; the bounding-sphere tree, ``surface_tree``)."""
        V, F = self.blood_surface
        if getattr(self, "_blood_tree", None) is None:
            self._blood_tree = SurfaceTree.build(V, F)
        return self._blood_tree.distances(points, band)

    def contains(self, p_H: np.ndarray) -> np.ndarray:
        """Whether points (k, 3) [m] are where the chain may be: a lumen's points within its outer
        wall; a solid's outside its wall's far side and within ``working_box``."""
        p_H = np.atleast_2d(np.asarray(p_H, float))
        behind = self._behind.winding_numbers(p_H) > 0.5
        if self.side == "lumen":
            return behind
        lo, hi = self.working_box
        return ~behind & np.all((p_H >= lo) & (p_H <= hi), axis=1)

    def write_files(self, directory: Path | None = None) -> dict[str, Path]:
        """Write the wall (VTK) and its boundary (OBJ) to the cache (reused when intact, see
        ``model_files.cached_files``); returns their paths."""
        import hashlib

        key = hashlib.sha1(self.surface.V.tobytes() + self.wall_faces.tobytes() + repr(self.params).encode()
                           + self.side.encode() + source_hash(sys.modules[__name__], mt).encode()).hexdigest()[:12]
        directory = Path(directory) if directory else cache_dir() / f"user_atrium_{key}"

        def write(tmp: dict[str, Path]) -> None:
            V, T = self.wall_tetrahedra
            mt.write_vtk_tetrahedra(tmp["vtk"], V, T)
            mt.write_obj(tmp["obj"], V, mt.boundary_surface(V, T))

        return cached_files(directory, {"vtk": "atrium_wall.vtk", "obj": "atrium_wall.obj"}, write)


def wall_directions(V: np.ndarray, F: np.ndarray, cap: float = MAX_MITER) -> np.ndarray:
    """Per vertex, the displacement (nv, 3) for a wall one unit thick: along the angle-weighted
    normal (Thuermer and Wuethrich 1998: independent of how the faces around the vertex are
    triangulated, so a box corner's points along its diagonal), lengthened so that every face
    around the vertex moves at least one unit along its own normal (a mitred corner: a box's
    corner moves by (1, 1, 1)), at most ``cap`` units (a spike)."""
    tri = V[F]
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    face_n /= np.linalg.norm(face_n, axis=1)[:, None]
    N = np.zeros_like(V)
    for k in range(3):
        e1 = tri[:, (k + 1) % 3] - tri[:, k]
        e2 = tri[:, (k + 2) % 3] - tri[:, k]
        cos = np.einsum("ij,ij->i", e1, e2) / (np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1))
        np.add.at(N, F[:, k], np.arccos(np.clip(cos, -1.0, 1.0))[:, None] * face_n)
    N /= np.linalg.norm(N, axis=1)[:, None]
    least = np.full(len(V), np.inf)
    for k in range(3):
        np.minimum.at(least, F[:, k], np.einsum("ij,ij->i", N[F[:, k]], face_n))
    return N / np.clip(least, 1.0 / cap, 1.0)[:, None]


def grid_winding_inside(tree: SurfaceTree, origin: np.ndarray, spacing: float, shape: tuple[int, int, int]
                        ) -> np.ndarray:
    """Winding number > 1/2 at every node of a grid, evaluated where it can change.

    Nodes within 1.5 spacings of the surface get their own winding number. The others form
    connected regions (6-neighbours) that the surface does not cross (two neighbouring nodes
    farther than half a spacing from it see no surface between them); each region is decided by
    its nodes on a 4-spacing sub-grid (and one node at least), and evaluated node by node only
    if they disagree (a region reaching round an opening).
    """
    from scipy import ndimage

    axes = [origin[k] + spacing * np.arange(shape[k]) for k in range(3)]
    P = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    near = tree.distances(P, 1.5 * spacing) < 1.5 * spacing
    inside = np.zeros(len(P), bool)
    inside[near] = tree.winding_numbers(P[near]) > 0.5
    labels, n = ndimage.label(~near.reshape(shape))
    labels = labels.reshape(-1)
    ijk = np.indices(shape).reshape(3, -1).T
    coarse = np.all(ijk % 4 == 0, axis=1)
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(1, n + 2))
    for region in range(1, n + 1):
        members = order[bounds[region - 1]:bounds[region]]
        probe = members[coarse[members]]
        probe = probe if len(probe) else members[:1]
        votes = tree.winding_numbers(P[probe]) > 0.5
        if votes.all() or not votes.any():
            inside[members] = votes[0]
        else:
            inside[members] = tree.winding_numbers(P[members]) > 0.5
    return inside.reshape(shape)
