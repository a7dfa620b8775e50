"""Load and validate a user's segmented left-atrium surface (OBJ or STL), and give it a wall.

The surface must be the endocardial (blood-side) surface of the chamber: one closed,
consistently oriented triangle mesh (every edge shared by exactly two triangles). Its size
decides the units when they are not declared: a left atrium is about 30-80 mm across, so a
largest bounding-box side of 0.02-0.12 is read as metres and 20-120 as millimetres. Every check
that fails is reported in one ``AtriumMeshError`` listing what is wrong and how to fix it.

``UserAtrium`` turns a validated surface into an atrium the chain plant accepts (a wall grown
outward in two tetrahedra layers, a hole at the septal puncture, inside tests by winding
number); a scenario selects it with ``atrium_file`` and ``puncture``.

No third-party mesh library is needed: OBJ (``v``/``f`` records, polygons fanned into triangles,
``f a/b/c`` and negative indices accepted) and STL (ASCII or binary) are parsed here.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models.arg_checks import (as_array, as_vector, require_choice, require_int, require_positive,
                                               require_type)
from ballchain.drake_models.errors import UserInputError, short_repr

Units = Literal["auto", "m", "mm"]
SENSIBLE_EXTENT_MM = (30.0, 80.0)  # typical LA size; outside ACCEPTED_EXTENT_MM is refused
ACCEPTED_EXTENT_MM = (20.0, 120.0)
MAX_PUNCTURE_DISTANCE = 5e-3  # [m] a user's puncture may lie this far from the surface
DEGENERATE_VOLUME_FRACTION = 1e-6  # a wall tetrahedron this much smaller than the median is flat


class AtriumMeshError(UserInputError):
    """A user atrium surface that cannot be used; the message lists every problem found."""


@dataclass
class AtriumSurface:
    """A validated endocardial surface in metres, outward oriented.

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


OBJ_VERTEX = "'v x y z' with 3 finite numbers (more, e.g. colours, are ignored)"
OBJ_FACE = ("'f i j k ...' with 3 or more vertex indices (1 to the number of vertices so far, or -1 back "
            "to minus that number; 'i/t/n' forms accepted)")


def _mesh_text(path: Path, data: bytes, what: str) -> str:
    """The text of a mesh file: UTF-8 (or Latin-1), UTF-16/UTF-8 with a byte-order mark; a file
    of binary data is refused."""
    for bom, encoding in ((b"\xef\xbb\xbf", "utf-8-sig"), (b"\xff\xfe", "utf-16"), (b"\xfe\xff", "utf-16")):
        if data.startswith(bom):
            try:
                return data.decode(encoding)
            except UnicodeDecodeError:
                raise AtriumMeshError(f"{path}: starts like {encoding.upper()} text but does not decode as it; "
                                      f"save it as a plain-text {what} file") from None
    if b"\0" in data:
        raise AtriumMeshError(f"{path}: binary data, not a text {what} file (save the mesh as a plain-text {what})")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")  # only v/f records matter: their digits read the same


def _read_bytes(path: Path) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as err:
        raise AtriumMeshError(f"{path}: cannot read the file ({err.strerror or err})") from None


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (nv, 3) and triangles (nf, 3) of a Wavefront OBJ file (polygons fanned).

    Raises:
        AtriumMeshError: a line that is not a usable vertex or face, naming the file, the line
            number and what is allowed; a file that is not text, or has no vertices or faces.
    """
    text = _mesh_text(path, _read_bytes(path), "OBJ")
    V, F, lines = [], [], []

    def bad(lineno: int, line: str, why: str, allowed: str):
        return AtriumMeshError(f"{path}: line {lineno}: {why} in {short_repr(line.strip())}; allowed: {allowed}")

    for lineno, line in enumerate(text.splitlines(), start=1):
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            if len(parts) < 4:
                raise bad(lineno, line, f"a vertex with {len(parts) - 1} coordinates", OBJ_VERTEX)
            try:
                xyz = [float(x) for x in parts[1:4]]
            except ValueError:
                raise bad(lineno, line, "a vertex coordinate that is not a number", OBJ_VERTEX) from None
            if not all(np.isfinite(xyz)):
                raise bad(lineno, line, "a vertex coordinate that is not finite", OBJ_VERTEX)
            V.append(xyz)
        elif parts[0] == "f":
            if len(parts) < 4:
                raise bad(lineno, line, f"a face with {len(parts) - 1} vertices", OBJ_FACE)
            try:
                idx = [int(tok.split("/")[0]) for tok in parts[1:]]
            except ValueError:
                raise bad(lineno, line, "a vertex index that is not an integer", OBJ_FACE) from None
            # Negative indices count back from the last vertex read so far; positive ones are
            # checked against every vertex once the file is read.
            if any(i == 0 or i < -len(V) for i in idx):
                raise bad(lineno, line, f"vertex index {next(i for i in idx if i == 0 or i < -len(V))} "
                          f"(with {len(V)} vertices so far)", OBJ_FACE)
            idx = [i - 1 if i > 0 else len(V) + i for i in idx]
            for k in range(1, len(idx) - 1):
                F.append([idx[0], idx[k], idx[k + 1]])
                lines.append(lineno)
    if not V or not F:
        raise AtriumMeshError(f"{path}: {len(V)} vertices and {len(F)} faces found; an OBJ surface needs "
                              f"{OBJ_VERTEX} and {OBJ_FACE} records")
    beyond = [k for k, face in enumerate(F) if max(face) >= len(V)]
    if beyond:
        k = beyond[0]
        raise AtriumMeshError(f"{path}: line {lines[k]}: vertex index {max(F[k]) + 1} but the file has "
                              f"{len(V)} vertices; allowed: {OBJ_FACE}")
    return np.array(V, float), np.array(F, np.int64)


def _weld(points: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge coincident STL corners: unique vertices and triangles indexing them."""
    keys = np.round(points / tolerance).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return points[first], inverse.reshape(-1, 3)


STL_VERTEX = "'vertex x y z' with 3 finite numbers, three per facet"


def read_stl(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of an ASCII or binary STL file (coincident corners welded).

    Raises:
        AtriumMeshError: neither format, a bad ASCII 'vertex' line (its number named), no
            triangles, or coordinates that are not finite.
    """
    data = _read_bytes(path)
    corners = None
    if len(data) >= 84:
        n = struct.unpack("<I", data[80:84])[0]
        if 84 + 50 * n == len(data):  # binary
            rec = np.frombuffer(data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]),
                                count=n, offset=84)
            corners = rec["v"].astype(float).reshape(-1, 3)
            if not np.all(np.isfinite(corners)):
                k = int(np.flatnonzero(~np.all(np.isfinite(rec["v"].reshape(n, -1)), axis=1))[0])
                raise AtriumMeshError(f"{path}: triangle {k + 1} of the binary STL has a coordinate that is not "
                                      "finite (NaN or inf)")
    if corners is None:
        text_bom = data.startswith((b"\xef\xbb\xbf", b"\xff\xfe", b"\xfe\xff"))
        if not data.lstrip().lower().startswith(b"solid") and not text_bom:
            raise AtriumMeshError(f"{path}: neither a binary STL (its size does not match the triangle count "
                                  "in its header) nor an ASCII STL (starting with 'solid')")
        text = _mesh_text(path, data, "STL")
        if not text.lstrip().lower().startswith("solid"):
            raise AtriumMeshError(f"{path}: neither a binary STL nor an ASCII STL (starting with 'solid')")
        verts = []
        for lineno, line in enumerate(text.splitlines(), start=1):
            parts = line.split()
            if parts and parts[0].lower() == "vertex":
                try:
                    xyz = [float(x) for x in parts[1:]]
                except ValueError:
                    xyz = []
                if len(xyz) != 3 or not all(np.isfinite(xyz)):
                    raise AtriumMeshError(f"{path}: line {lineno}: bad vertex {short_repr(line.strip())}; "
                                          f"allowed: {STL_VERTEX}")
                verts.append(xyz)
        corners = np.array(verts, float).reshape(-1, 3)
        if len(corners) % 3:
            raise AtriumMeshError(f"{path}: the ASCII STL has {len(corners)} vertices, not a multiple of 3 "
                                  f"(allowed: {STL_VERTEX})")
    if len(corners) == 0:
        raise AtriumMeshError(f"{path}: the STL has no triangles")
    extent = float(np.ptp(corners, axis=0).max()) or 1.0
    return _weld(corners, extent * 1e-9)


def write_stl_ascii(path: Path, V: np.ndarray, F: np.ndarray) -> Path:
    """Write an ASCII STL (for tests and round trips)."""
    lines = ["solid atrium"]
    for a, b, c in V[F]:
        n = np.cross(b - a, c - a)
        n = n / (np.linalg.norm(n) or 1.0)
        lines += [f"facet normal {n[0]:.6g} {n[1]:.6g} {n[2]:.6g}", "outer loop"]
        lines += [f"vertex {x:.9g} {y:.9g} {z:.9g}" for x, y, z in (a, b, c)]
        lines += ["endloop", "endfacet"]
    lines.append("endsolid atrium")
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


def write_stl_binary(path: Path, V: np.ndarray, F: np.ndarray) -> Path:
    """Write a binary STL (for tests and round trips)."""
    tri = V[F].astype("<f4")
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).astype("<f4")
    rec = np.zeros(len(F), dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]))
    rec["n"], rec["v"] = n, tri
    Path(path).write_bytes(b"\0" * 80 + struct.pack("<I", len(F)) + rec.tobytes())
    return Path(path)


def _guess_units(extent: float) -> str | None:
    if 0.02 <= extent <= 0.12:
        return "m"
    if 20.0 <= extent <= 120.0:
        return "mm"
    return None


def validate_surface(V: np.ndarray, F: np.ndarray, units: Units = "auto") -> AtriumSurface:
    """Check a surface and convert it to metres; raises AtriumMeshError listing every problem.

    Args:
        V: (nv, 3) vertices in the file's units.
        F: (nf, 3) triangles.
        units: "m", "mm", or "auto" (guessed from the size).
    """
    require_choice(units, ("auto", "m", "mm"), "units")
    V = np.asarray(V, dtype=float) if isinstance(V, np.ndarray) else as_array(V, "V", (-1, 3))
    F = as_array(F, "F", (-1, 3), integer=True)
    if V.ndim != 2 or V.shape[1] != 3:
        raise AtriumMeshError(f"V must be an array of shape (k, 3) of vertex coordinates, got shape {V.shape}")
    if len(F) and (F.min() < 0 or F.max() >= len(V)):
        raise AtriumMeshError(f"F must index the {len(V)} vertices (0 to {len(V) - 1}), got indices "
                              f"{int(F.min())} to {int(F.max())}")
    problems: list[str] = []
    notes: list[str] = []
    if not np.all(np.isfinite(V)):
        raise AtriumMeshError("the surface has NaN or infinite vertex coordinates")
    if len(F) < 4:
        raise AtriumMeshError(f"the surface has {len(F)} triangles: a closed surface needs at least 4")
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
    scale = 1e-3 if units == "mm" else 1.0
    V = V * scale
    extent_mm = np.ptp(V, axis=0) * 1e3
    if not ACCEPTED_EXTENT_MM[0] <= extent_mm.max() <= ACCEPTED_EXTENT_MM[1]:
        problems.append(
            f"size: the largest side is {extent_mm.max():.1f} mm in {units}, outside "
            f"{ACCEPTED_EXTENT_MM[0]:.0f}-{ACCEPTED_EXTENT_MM[1]:.0f} mm (a left atrium is about "
            f"{SENSIBLE_EXTENT_MM[0]:.0f}-{SENSIBLE_EXTENT_MM[1]:.0f} mm): wrong units or not an atrium?")
    elif not SENSIBLE_EXTENT_MM[0] <= extent_mm.max() <= SENSIBLE_EXTENT_MM[1]:
        notes.append(f"largest side {extent_mm.max():.1f} mm is outside the usual 30-80 mm")
    area2 = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    degenerate = int((area2 <= 1e-12 * max(extent_mm.max() * 1e-3, 1e-9) ** 2).sum())
    if degenerate:
        problems.append(f"{degenerate} degenerate (zero-area or repeated-vertex) triangles")
    edges, counts, balance = mt.edge_use_counts(F)
    open_edges = int((counts == 1).sum())
    non_manifold = int((counts > 2).sum())
    if open_edges:
        problems.append(
            f"not closed: {open_edges} boundary edges (holes); close the holes (e.g. cap the "
            "pulmonary veins and the mitral valve) so that the surface is watertight")
    if non_manifold:
        problems.append(f"not manifold: {non_manifold} edges shared by more than two triangles")
    flipped_edges = int(((counts == 2) & (balance != 0)).sum())
    if flipped_edges:
        problems.append(
            f"inconsistent orientation: {flipped_edges} edges between triangles facing opposite "
            "ways; make the triangle winding consistent")
    used = np.zeros(len(V), bool)
    used[F.ravel()] = True
    if not used.all():
        notes.append(f"{int((~used).sum())} unused vertices dropped")
        remap = -np.ones(len(V), int)
        remap[used] = np.arange(used.sum())
        V, F = V[used], remap[F]
    if problems:
        raise AtriumMeshError("atrium surface rejected:\n  - " + "\n  - ".join(problems))
    volume = mt.enclosed_volume(V, F)
    if volume < 0:
        F = F[:, [0, 2, 1]]
        volume = -volume
        notes.append("triangles faced inward: orientation flipped to outward")
    return AtriumSurface(V, F, units, guessed, extent_mm, volume * 1e6, notes)


def load_atrium_surface(path: Path | str, units: Units = "auto") -> AtriumSurface:
    """Read an OBJ or STL endocardial surface, validate it and return it in metres.

    Args:
        path: .obj or .stl file.
        units: "m", "mm" or "auto" (guessed from the size, see the module docstring).

    Raises:
        AtriumMeshError: unreadable file or an unusable surface (the message lists why).
    """
    require_type(path, (str, Path), "path", "a file name (str or Path)")
    require_choice(units, ("auto", "m", "mm"), "units")
    path = Path(path)
    if not path.exists():
        raise AtriumMeshError(f"{path}: no such file")
    if not path.is_file():
        raise AtriumMeshError(f"{path}: not a file (a folder?); give an .obj or .stl file")
    suffix = path.suffix.lower()
    if suffix == ".obj":
        V, F = read_obj(path)
    elif suffix == ".stl":
        V, F = read_stl(path)
    else:
        raise AtriumMeshError(f"{path}: unsupported format {suffix!r} (use .obj or .stl)")
    try:
        return validate_surface(V, F, units)
    except AtriumMeshError as err:
        raise AtriumMeshError(f"{path}: {err}") from None


@dataclass(frozen=True)
class UserAtriumParams:
    """Wall and sheath parameters of a user atrium (the counterpart of HeartParams).

    Attributes:
        wall_thickness: grown outward from the surface [m].
        wall_layers: tetrahedra layers through the wall (>= 2).
        puncture_diameter: hole cut for the sheath around the puncture [m].
        sheath_extension: how far the sheath reaches beyond the wall into the chamber [m].
    """

    wall_thickness: float = 2.5e-3
    wall_layers: int = 2
    puncture_diameter: float = 6e-3
    sheath_extension: float = 3e-3

    def __post_init__(self) -> None:
        require_positive(self.wall_thickness, "UserAtriumParams.wall_thickness", "m")
        require_int(self.wall_layers, "UserAtriumParams.wall_layers", 2)
        require_positive(self.puncture_diameter, "UserAtriumParams.puncture_diameter", "m")
        require_positive(self.sheath_extension, "UserAtriumParams.sheath_extension", "m", allow_zero=True)


class UserAtrium:
    """A user's segmented atrium, usable wherever the plant takes a ``LeftAtrium``.

    Args:
        surface: a validated endocardial surface (``load_atrium_surface``).
        p_HP: (3,) septal puncture [m]; it is moved onto the surface (nearest vertex).
        sheath_aim: (3,) point the sheath points to [m] (default: the surface's centroid).
        params: wall and sheath parameters.

    There are no ablation targets (``rings``, ``ostia`` and ``carinas`` are empty): a segmentation
    carries no ostia labels. Implements ``drake_models.atrium.Atrium``.
    """

    def __init__(self, surface: AtriumSurface, p_HP, sheath_aim=None, params: UserAtriumParams | None = None):
        require_type(surface, AtriumSurface, "UserAtrium surface", "an AtriumSurface (from load_atrium_surface)")
        as_vector(p_HP, "UserAtrium p_HP (the puncture)", unit="m")
        if sheath_aim is not None:
            as_vector(sheath_aim, "UserAtrium sheath_aim", unit="m")
        if params is not None:
            require_type(params, UserAtriumParams, "UserAtrium params", "a UserAtriumParams or None")
        self.surface = surface
        self.params = params or UserAtriumParams()
        if self.params.wall_layers < 2:
            raise UserInputError("UserAtriumParams.wall_layers must be >= 2")
        V, F = surface.V, surface.F
        p_HP = np.asarray(p_HP, float)
        if p_HP.shape != (3,) or not np.all(np.isfinite(p_HP)):
            raise UserInputError(f"puncture must be 3 finite coordinates [m], got {np.asarray(p_HP).tolist()}")
        # The puncture is snapped onto the surface: only a small correction is accepted, so a
        # mistyped point (or one in millimetres) is refused instead of silently moved far away.
        gap = float(mt.SurfaceDistance(V, F)(p_HP)[0])
        if gap > MAX_PUNCTURE_DISTANCE:
            raise UserInputError(
                f"puncture {np.round(p_HP, 6).tolist()} m is {gap * 1e3:.1f} mm from the atrium surface; it "
                f"must lie within {MAX_PUNCTURE_DISTANCE * 1e3:.0f} mm of it (coordinates in metres, in the "
                "surface's frame after its units are applied)")
        k = int(np.argmin(np.linalg.norm(V - p_HP, axis=1)))
        self.p_HP = V[k].copy()
        if sheath_aim is not None and (np.shape(sheath_aim) != (3,) or not np.all(np.isfinite(sheath_aim))):
            raise UserInputError(f"sheath_aim must be 3 finite coordinates [m], got {sheath_aim}")
        aim = V.mean(axis=0) if sheath_aim is None else np.asarray(sheath_aim, float)
        axis = aim - self.p_HP
        if np.linalg.norm(axis) == 0:
            raise UserInputError("UserAtrium: the sheath aim coincides with the puncture")
        self.sheath_axis_H = axis / np.linalg.norm(axis)
        self.p_HE = self.p_HP + self.params.sheath_extension * self.sheath_axis_H
        self.rings: dict = {}  # no ablation targets, ostia or carinas (the Atrium protocol)
        self.ostia: list = []
        self.carinas: dict = {}
        self._normals = mt.vertex_normals(V, F)
        c = V[F].mean(axis=1)
        rel = c - self.p_HP
        along = rel @ self.sheath_axis_H
        radial = np.linalg.norm(rel - along[:, None] * self.sheath_axis_H, axis=1)
        self.inner_faces = F[~((radial < 0.5 * self.params.puncture_diameter) & (np.abs(along) < 10e-3))]
        self._outer = V + self._normals * self.params.wall_thickness
        self.wall_distance = mt.SurfaceDistance(V, self.inner_faces)
        self._check_wall()

    def _check_wall(self) -> None:
        """Refuse a surface whose grown wall has flat tetrahedra (Drake cannot give them a
        pressure field: "A mesh field element was degenerate"), saying where they are."""
        Vt, T = self.wall_tetrahedra
        vol = mt.signed_volumes(Vt, T)
        bad = np.flatnonzero(vol <= DEGENERATE_VOLUME_FRACTION * np.median(np.abs(vol)))
        if len(bad):
            where = np.round(Vt[T[bad[0]]].mean(axis=0) * 1e3, 2).tolist()
            raise AtriumMeshError(
                f"atrium_file: the wall grown from this surface has {len(bad)} flat (zero-volume) tetrahedra, the "
                f"first near {where} mm: the surface has a zero-area triangle or a fold there; remesh it (e.g. "
                "remove degenerate faces) and try again")

    @property
    def wall_tetrahedra(self) -> tuple[np.ndarray, np.ndarray]:
        p = self.params
        return mt.extrude_shell(self.surface.V, self.inner_faces, self._normals, p.wall_thickness, p.wall_layers)

    @property
    def blood_surface(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (v, 3) [m], triangles (f, 3)) of the blood side: the user's surface."""
        return self.surface.V, self.surface.F

    def lumen_grid_contains(self, origin: np.ndarray, spacing: float, shape: tuple[int, int, int]) -> np.ndarray:
        """Whether the nodes of a grid (origin (3,) [m], spacing [m], shape) lie inside the closed
        surface: ray parity along +z (``mesh_tools.ray_parity_contains``) -> (nx, ny, nz) bool."""
        return mt.ray_parity_contains(self.surface.V, self.surface.F, origin, spacing, shape)

    lumen_key = "ray_parity"  # the lumen test depends on the triangles only

    def contains(self, p_H: np.ndarray) -> np.ndarray:
        """Whether points (k, 3) [m] lie within the outer wall (generalised winding number)."""
        return mt.winding_numbers(np.atleast_2d(p_H), self._outer, self.surface.F) > 0.5

    def write_files(self, directory: Path | None = None) -> dict[str, Path]:
        """Write the wall (VTK) and its boundary (OBJ) to the cache (reused when intact, see
        ``model_files.cached_files``); returns their paths."""
        import hashlib
        import sys

        from ballchain.drake_models.model_files import cache_dir, cached_files, source_hash

        key = hashlib.sha1(self.surface.V.tobytes() + self.inner_faces.tobytes() + repr(self.params).encode()
                           + source_hash(sys.modules[__name__], mt).encode()).hexdigest()[:12]
        directory = Path(directory) if directory else cache_dir() / f"user_atrium_{key}"

        def write(tmp: dict[str, Path]) -> None:
            V, T = self.wall_tetrahedra
            mt.write_vtk_tetrahedra(tmp["vtk"], V, T)
            mt.write_obj(tmp["obj"], V, mt.boundary_surface(V, T))

        return cached_files(directory, {"vtk": "atrium_wall.vtk", "obj": "atrium_wall.obj"}, write)
