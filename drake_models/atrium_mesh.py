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
"""

from __future__ import annotations

import struct
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models.arg_checks import (as_array, as_vector, require_choice, require_int, require_positive,
                                               require_type)
from ballchain.drake_models.errors import UserInputError, short_repr
from ballchain.drake_models.input_files import MAX_MESH_BYTES, check_input_file, read_input_file
from ballchain.drake_models.surface_tree import SurfaceTree

Units = Literal["auto", "m", "mm"]
SENSIBLE_EXTENT_MM = (30.0, 80.0)  # typical LA size; outside ACCEPTED_EXTENT_MM is refused
ACCEPTED_EXTENT_MM = (20.0, 120.0)
MAX_PUNCTURE_DISTANCE = 5e-3  # [m] a user's puncture may lie this far from the surface
MAX_OPENING_AREA = 1e-6  # [m^2] an opening (a seam not welded) up to this area is bridged, not refused
SEAM_GAP = 0.2e-3  # [m] rims closer than this belong to one opening (the two sides of a seam)
DECIMATE_ABOVE = 20_000  # triangles: a larger surface is decimated for contact and the signed distance
DECIMATE_TO = 10_000  # triangles after decimation (edges about 1.4 mm on a 50 mm atrium)
MAX_TRIANGLES = 2_000_000  # refused above (a segmentation at 0.1 mm voxels has about 1 million)
MAX_MITER = 3.0  # a wall vertex moves at most this many wall thicknesses (at a sharp corner)
MAX_SLIVER_FRACTION = 0.01  # triangles whose wall prism is flat: left out of the wall up to this share
NESTED_FRACTION = 0.9  # a shell with this share of its vertices inside another is nested in it
DEGENERATE_VOLUME_FRACTION = 1e-6  # a wall tetrahedron this much smaller than the median is flat


class AtriumMeshError(UserInputError):
    """A user atrium surface that cannot be used; the message lists every problem found."""


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


MESH_NOUN = "a mesh file (.obj, .stl, .ply or .vtk)"


def _read_bytes(path: Path) -> bytes:
    """The mesh file's bytes: a regular file of at most ``MAX_MESH_BYTES`` (``input_files``)."""
    try:
        return read_input_file(path, str(path), MAX_MESH_BYTES, MESH_NOUN)
    except AtriumMeshError:
        raise
    except UserInputError as err:
        raise AtriumMeshError(str(err)) from None


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (nv, 3) and triangles (nf, 3) of a Wavefront OBJ file (polygons fanned).

    Raises:
        AtriumMeshError: a line that is not a usable vertex or face, naming the file, the line
            number and what is allowed; a file that is not text, or has no vertices or faces.
    """
    text = _mesh_text(path, _read_bytes(path), "OBJ")
    V, F, lines = [], [], []

    def bad(lineno: int, line: str, why: str, allowed: str):  # the line is not quoted: the file may be no mesh
        return AtriumMeshError(f"{path}: line {lineno}: {why}; allowed: {allowed}")

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
                    xyz = None
                if xyz is None or len(xyz) != 3 or not all(np.isfinite(xyz)):
                    why = ("a coordinate that is not a number" if xyz is None else
                           f"{len(xyz)} coordinates" if len(xyz) != 3 else "a coordinate that is not finite")
                    raise AtriumMeshError(f"{path}: line {lineno}: bad vertex ({why}); allowed: {STL_VERTEX}")
                verts.append(xyz)
        corners = np.array(verts, float).reshape(-1, 3)
        if len(corners) % 3:
            raise AtriumMeshError(f"{path}: the ASCII STL has {len(corners)} vertices, not a multiple of 3 "
                                  f"(allowed: {STL_VERTEX})")
    if len(corners) == 0:
        raise AtriumMeshError(f"{path}: the STL has no triangles")
    extent = float(np.ptp(corners, axis=0).max()) or 1.0
    return _weld(corners, extent * 1e-9)


PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
             "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
             "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _ply_header(path: Path, data: bytes) -> tuple[str, list, int]:
    """(format, elements [(name, count, [(property, type, list count type or None)])], body offset)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise AtriumMeshError(f"{path}: not a PLY file (it must start with 'ply' and have an 'end_header' line)")
    body = data.index(b"\n", end) + 1
    fmt, elements = "", []
    for lineno, line in enumerate(data[:end].decode("latin-1").splitlines()[1:], start=2):
        parts = line.split()
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        try:
            if parts[0] == "format":
                fmt = parts[1]
            elif parts[0] == "element":
                elements.append((parts[1], int(parts[2]), []))
            elif parts[0] == "property" and parts[1] == "list":
                elements[-1][2].append((parts[4], PLY_TYPES[parts[3]], PLY_TYPES[parts[2]]))
            elif parts[0] == "property":
                elements[-1][2].append((parts[2], PLY_TYPES[parts[1]], None))
        except (IndexError, KeyError, ValueError):
            raise AtriumMeshError(f"{path}: PLY header line {lineno} is not understood (allowed: format, element, "
                                  "property, comment)") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise AtriumMeshError(f"{path}: the PLY header's format is {'unknown' if fmt else 'missing'}; allowed: "
                              "ascii, binary_little_endian, binary_big_endian")
    return fmt, elements, body


def _ply_records(fmt: str, props: list, count: int, data: bytes, pos: int, tokens: list):
    """One element's records as lists of values (lists for list properties); the new position."""
    end = "<" if fmt == "binary_little_endian" else ">"
    rows = []
    for _ in range(count):
        row = []
        for _, typ, list_type in props:
            if fmt == "ascii":
                n = int(tokens[pos]) if list_type else 1
                values = [float(x) for x in tokens[pos + (1 if list_type else 0):pos + (1 if list_type else 0) + n]]
                pos += n + (1 if list_type else 0)
            else:
                if list_type:
                    n = int(np.frombuffer(data, end + list_type, 1, pos)[0])
                    pos += np.dtype(list_type).itemsize
                else:
                    n = 1
                values = np.frombuffer(data, end + typ, n, pos).tolist()
                pos += n * np.dtype(typ).itemsize
            row.append(values if list_type else values[0])
        rows.append(row)
    return rows, pos


def read_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a PLY file (ASCII or binary; the 'vertex' element's x, y, z and
    the 'face' element's index list, polygons fanned into triangles).

    Raises:
        AtriumMeshError: not a PLY, an unknown format or type, missing x/y/z or faces, a short file.
    """
    data = _read_bytes(path)
    fmt, elements, body = _ply_header(path, data)
    tokens = data[body:].split() if fmt == "ascii" else []
    pos = 0 if fmt == "ascii" else body
    V = F = None
    try:
        for name, count, props in elements:
            fast = fmt != "ascii" and all(t is None for _, _, t in props)
            if fast:  # fixed-size records: one read
                end = "<" if fmt == "binary_little_endian" else ">"
                rec = np.frombuffer(data, np.dtype([(p, end + t) for p, t, _ in props]), count, pos)
                pos += rec.nbytes
                rows = None
            else:
                rows, pos = _ply_records(fmt, props, count, data, pos, tokens)
            names = [p for p, _, _ in props]
            if name == "vertex":
                if not {"x", "y", "z"} <= set(names):
                    raise AtriumMeshError(f"{path}: the PLY vertex element has no x, y and z properties")
                V = (np.stack([rec[k].astype(float) for k in "xyz"], axis=1) if fast else
                     np.array([[row[names.index(k)] for k in "xyz"] for row in rows], float))
            elif name == "face":
                lists = [k for k, (_, _, t) in enumerate(props) if t]
                if not lists or rows is None:
                    raise AtriumMeshError(f"{path}: the PLY face element has no vertex index list")
                F = [[int(r[lists[0]][0]), int(r[lists[0]][k]), int(r[lists[0]][k + 1])]
                     for r in rows for k in range(1, len(r[lists[0]]) - 1)]
    except (ValueError, IndexError, TypeError):
        raise AtriumMeshError(f"{path}: the PLY body is shorter than its header says, or has a value that is "
                              "not a number") from None
    if V is None or not F:
        raise AtriumMeshError(f"{path}: the PLY file needs a 'vertex' element (x, y, z) and a 'face' element")
    F = np.array(F, np.int64)
    if F.min() < 0 or F.max() >= len(V):
        raise AtriumMeshError(f"{path}: a PLY face index is outside 0..{len(V) - 1}")
    if not np.all(np.isfinite(V)):
        raise AtriumMeshError(f"{path}: a PLY vertex coordinate is not finite (NaN or inf)")
    return V, F


def read_vtk_polydata(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a legacy ASCII VTK file with a POLYDATA data set (POINTS and
    POLYGONS, polygons fanned into triangles).

    Raises:
        AtriumMeshError: not ASCII POLYDATA, or a short or malformed POINTS/POLYGONS section.
    """
    text = _mesh_text(path, _read_bytes(path), "VTK")
    tokens = text.split()
    upper = [t.upper() for t in tokens[:200]]
    if "ASCII" not in upper or "POLYDATA" not in upper:
        raise AtriumMeshError(f"{path}: only legacy ASCII VTK files with 'DATASET POLYDATA' (POINTS and POLYGONS) "
                              "are read; save the surface as ASCII VTK, STL, OBJ or PLY")
    try:
        i = [t.upper() for t in tokens].index("POINTS")
        nv = int(tokens[i + 1])
        V = np.array(tokens[i + 3:i + 3 + 3 * nv], float).reshape(nv, 3)
        j = [t.upper() for t in tokens].index("POLYGONS")
        n, size = int(tokens[j + 1]), int(tokens[j + 2])
        flat = np.array(tokens[j + 3:j + 3 + size], np.int64)
    except (ValueError, IndexError):
        raise AtriumMeshError(f"{path}: the VTK POINTS or POLYGONS section is missing, short or not numbers") from None
    F, k = [], 0
    for _ in range(n):
        m = int(flat[k])
        poly = flat[k + 1:k + 1 + m]
        F += [[poly[0], poly[q], poly[q + 1]] for q in range(1, m - 1)]
        k += m + 1
    F = np.array(F, np.int64).reshape(-1, 3)
    if len(F) == 0 or F.min() < 0 or F.max() >= nv or not np.all(np.isfinite(V)):
        raise AtriumMeshError(f"{path}: the VTK POLYGONS are empty or index outside the {nv} points, or a point "
                              "is not finite")
    return V, F


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


# --- self-intersection: a shell that crosses itself --------------------------------------------------

SELF_CROSSING_DEPTH = 0.5e-3
"""[m] A shell that crosses itself is accepted with a note (on stderr) while every part of it that
is not a boundary between inside and outside lies within this distance of one; deeper, it is
refused. Where a shell overlaps itself, the winding-number inside test still gives the union (2
counts as inside), but the triangles buried in the overlap stay in the surface: the signed
distance and the contact wall are measured to them (a tube whose ends overlap: the distance off by
up to 6 mm inside the overlap), and a part turned inside out (winding -1) is outside. Overlapping
shells are not this case: their buried triangles are dropped (``UserAtrium._union_boundary``)."""


def self_crossings(V: np.ndarray, F: np.ndarray, shells: np.ndarray | None = None,
                   chunk: int = 200_000) -> np.ndarray:
    """The pairs of triangles (k, 2) of one shell (``shells``: each triangle's, default one) that
    cross each other: each has corners strictly on both sides of the other's plane and their
    spans along the planes' line overlap (Moeller 1997). Pairs that share a corner, coplanar pairs
    and pairs that only touch are left out. Candidates are the pairs whose bounding boxes share a
    cell of a uniform grid about one triangle wide: about 0.6 s for 80,000 triangles."""
    tri = V[F]
    if len(tri) < 2:
        return np.zeros((0, 2), int)
    eps = 1e-9 * float(np.ptp(V, axis=0).max())
    pairs = _box_pairs(tri)
    share = np.zeros(len(pairs), bool)
    for i in range(3):
        for j in range(3):
            share |= F[pairs[:, 0], i] == F[pairs[:, 1], j]
    pairs = pairs[~share]
    if shells is not None:
        pairs = pairs[shells[pairs[:, 0]] == shells[pairs[:, 1]]]
    hits = [c[_crossing(tri[c[:, 0]], tri[c[:, 1]], eps)] for c in
            (pairs[s:s + chunk] for s in range(0, len(pairs), chunk))]
    return np.concatenate(hits) if hits else np.zeros((0, 2), int)


def _box_pairs(tri: np.ndarray) -> np.ndarray:
    """(k, 2) pairs i < j of triangles whose bounding boxes overlap, found through a uniform grid
    (cell: the median box size, doubled until the boxes cover at most 64 cells per triangle)."""
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    nf = len(tri)
    h = float(np.median((hi - lo).max(axis=1))) or float((hi - lo).max()) or 1.0
    origin = lo.min(axis=0)
    while True:
        a = np.floor((lo - origin) / h).astype(np.int64)
        b = np.floor((hi - origin) / h).astype(np.int64)
        span = b - a + 1
        count = span.prod(axis=1)
        if count.sum() <= 64 * nf:
            break
        h *= 2.0
    owner = np.repeat(np.arange(nf), count)
    k = np.arange(len(owner)) - np.repeat(np.cumsum(count) - count, count)  # the cell's place in its box
    sx, sy = np.repeat(span[:, 0], count), np.repeat(span[:, 1], count)
    dims = b.max(axis=0) + 2
    cell = ((np.repeat(a[:, 0], count) + k % sx) * dims[1] + np.repeat(a[:, 1], count) + (k // sx) % sy) * dims[2] \
        + np.repeat(a[:, 2], count) + k // (sx * sy)
    order = np.lexsort((owner, cell))
    cell, owner = cell[order], owner[order]
    bounds = np.flatnonzero(np.r_[True, cell[1:] != cell[:-1], True])
    after = np.repeat(bounds[1:], np.diff(bounds)) - np.arange(len(cell)) - 1  # later entries of the same cell
    first = np.repeat(np.arange(len(cell)), after)
    second = first + 1 + np.arange(len(first)) - np.repeat(np.cumsum(after) - after, after)
    p, q = owner[first], owner[second]
    keep = p != q
    key = np.sort(np.minimum(p[keep], q[keep]) * nf + np.maximum(p[keep], q[keep]))
    key = key[np.r_[True, key[1:] != key[:-1]]]  # (np.unique hashes: several times slower here)
    p, q = key // nf, key % nf
    overlap = np.all((lo[p] <= hi[q]) & (lo[q] <= hi[p]), axis=1)
    return np.stack([p[overlap], q[overlap]], axis=1)


def _crossing(A: np.ndarray, B: np.ndarray, eps: float) -> np.ndarray:
    """Whether triangles A[k] and B[k] ((k, 3, 3) each) cross (see ``self_crossings``)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        nA = np.cross(A[:, 1] - A[:, 0], A[:, 2] - A[:, 0])
        nA /= np.linalg.norm(nA, axis=1)[:, None]
        nB = np.cross(B[:, 1] - B[:, 0], B[:, 2] - B[:, 0])
        nB /= np.linalg.norm(nB, axis=1)[:, None]
        dB = np.einsum("kij,kj->ki", B - A[:, :1], nA)  # B's corners' heights over A's plane
        dA = np.einsum("kij,kj->ki", A - B[:, :1], nB)
        dA[np.abs(dA) < eps] = 0.0
        dB[np.abs(dB) < eps] = 0.0
        through = (dA.max(axis=1) > 0) & (dA.min(axis=1) < 0) & (dB.max(axis=1) > 0) & (dB.min(axis=1) < 0)
        D = np.cross(nA, nB)
        a0, a1 = _span(dA, np.einsum("kij,kj->ki", A, D))
        b0, b1 = _span(dB, np.einsum("kij,kj->ki", B, D))
        return through & (np.maximum(a0, b0) < np.minimum(a1, b1) - eps)


def _span(d: np.ndarray, proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(start, end) along the planes' line of where each triangle (corner heights ``d`` over the
    other's plane, corners' positions ``proj`` along the line) meets the other's plane."""
    t = np.full((len(d), 6), np.inf)
    s = np.full((len(d), 6), -np.inf)
    for e, (u, v) in enumerate(((0, 1), (1, 2), (2, 0))):
        du, dv = d[:, u], d[:, v]
        cut = du * dv < 0
        x = proj[:, u] + (proj[:, v] - proj[:, u]) * du / np.where(cut, du - dv, 1.0)
        t[cut, e], s[cut, e] = x[cut], x[cut]
        on = du == 0
        t[on, 3 + u], s[on, 3 + u] = proj[on, u], proj[on, u]
    return t.min(axis=1), s.max(axis=1)


SUBSAMPLE = 4  # a triangle next to the wrong side is classified at (SUBSAMPLE + 1)(SUBSAMPLE + 2) / 2 points


def _wrong_side_depth(V: np.ndarray, F: np.ndarray) -> float:
    """How far the parts of one shell (``F``) that are not a boundary lie from the parts that are
    [m]: the largest distance the signed distance is off by there (it is measured to them).

    A point of the surface is on the boundary when, just in front of it and just behind it, one
    side is inside and the other outside (the shell's winding number, signed by its orientation,
    > 1/2); buried where the shell overlaps itself, both are inside; turned inside out, both
    outside. Each triangle is classified at its centroid; those next to a wrong one are
    classified again at ``SUBSAMPLE`` points per edge, so that the distance (from each wrong
    point to the nearest right one) is resolved to about a quarter of a triangle.
    """
    from scipy.spatial import cKDTree

    tri = V[F]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    tree = SurfaceTree.build(V, F)
    sign = 1.0 if mt.enclosed_volume(V, F) >= 0 else -1.0
    step = 1e-2 * float(np.median(np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1)))

    def right(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        inside = sign * tree.winding_numbers(np.concatenate([points + step * normals, points - step * normals])) > 0.5
        return inside[:len(points)] != inside[len(points):]

    ok = right(tri.mean(axis=1), n)
    if ok.all():
        return 0.0
    if not ok.any():
        return np.inf  # no part of it is a boundary
    band = np.isin(F, F[~ok]).any(axis=1)  # the wrong triangles and those sharing a corner with one
    ijk = np.array([(i, j, SUBSAMPLE - i - j) for i in range(SUBSAMPLE + 1) for j in range(SUBSAMPLE + 1 - i)])
    points = (np.einsum("sk,fkd->fsd", ijk / SUBSAMPLE, tri[band])).reshape(-1, 3)
    normals = np.repeat(n[band], len(ijk), axis=0)
    fine = right(points, normals)
    good = np.concatenate([points[fine], tri[~band].mean(axis=1)[ok[~band]]])
    if not len(good):
        return np.inf
    return float(cKDTree(good).query(points[~fine])[0].max()) if (~fine).any() else 0.0


def _self_crossing_problems(V: np.ndarray, F: np.ndarray, notes: list[str], progress: bool,
                            decimated: bool) -> list[str]:
    """A shell that crosses itself (``self_crossings``): how deep its parts that are not a boundary
    between inside and outside lie (their two sides both inside, buried where the shell overlaps
    itself, or both outside, turned inside out; by the winding numbers of the shell just in front
    of and behind each triangle). Up to ``SELF_CROSSING_DEPTH``: a note (and a line on stderr with
    ``progress``); deeper: the problem, for the refusal."""
    shells = shell_labels(F, V)
    pairs = self_crossings(V, F, shells)
    if not len(pairs):
        return []
    depth = 0.0
    for j in np.unique(shells[pairs[:, 0]]):
        depth = max(depth, _wrong_side_depth(V, F[shells == j]))
    where = np.round(V[F[pairs[0]]].reshape(-1, 3).mean(axis=0) * 1e3, 1).tolist()
    what = (f"the surface{f' as decimated to {len(F):,} triangles' if decimated else ''} intersects itself: "
            f"{len(pairs)} pairs of its triangles cross (the first near {where} mm)")
    if depth > SELF_CROSSING_DEPTH:
        deep = "everywhere" if np.isinf(depth) else f"up to {depth * 1e3:.1f} mm"
        return [f"{what}, and parts of it lie {deep} on the wrong side of it (inside where it overlaps itself, or "
                "turned inside out): the wall distance and the contact wall would be measured to them; remove the "
                f"self-intersections (a crossing within {SELF_CROSSING_DEPTH * 1e3:g} mm is accepted), e.g. "
                "re-export the segmentation, or a self-union in MeshLab or Blender"]
    note = (f"{what}; the parts on the wrong side of it lie within {depth * 1e3:.1f} mm of its boundary: the wall "
            "distance may be off by that much there")
    notes.append(note)
    if progress:
        print(f"atrium mesh: note: {note}", file=sys.stderr, flush=True)
    return []


def opening_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """The area [m^2] of each opening of a surface: per set of boundary edges connected through
    shared vertices or vertices closer than ``SEAM_GAP``, the length of its vector area (half the
    sum of a x b over its edges a -> b). A hole spans its area; a seam left open (two rims
    running side by side in opposite directions, welded or not) spans almost none, however
    long. Empty for a closed surface."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rim = _rim_edges(F)
    if len(rim) == 0:
        return np.zeros(0)
    links = np.concatenate([rim, _seam_links(V, rim)])
    graph = coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(len(V), len(V)))
    _, label = connected_components(graph, directed=False)
    parts = np.unique(label[rim[:, 0]], return_inverse=True)[1].ravel()
    area = np.zeros((parts.max() + 1, 3))
    np.add.at(area, parts, 0.5 * np.cross(V[rim[:, 0]], V[rim[:, 1]]))
    return np.linalg.norm(area, axis=1)


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


def _rim_edges(F: np.ndarray) -> np.ndarray:
    """The boundary edges (k, 2) of a surface, as its triangles run them."""
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    _, inverse, counts = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True, return_counts=True)
    return directed[counts[inverse.ravel()] == 1]


def _seam_links(V: np.ndarray, rim: np.ndarray) -> np.ndarray:
    """Pairs (k, 2) of boundary vertices closer than ``SEAM_GAP``: the two sides of a seam."""
    from scipy.spatial import cKDTree

    ends = np.unique(rim)
    if len(ends) < 2:
        return np.zeros((0, 2), np.int64)
    return ends[cKDTree(V[ends]).query_pairs(SEAM_GAP, output_type="ndarray")].reshape(-1, 2)


def shell_labels(F: np.ndarray, V: np.ndarray) -> np.ndarray:
    """The shell (connected piece) of each triangle (nf,), numbered from 0; pieces that meet
    along a seam left open (boundary vertices closer than ``SEAM_GAP``) are one shell."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    nv = len(V)
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], _seam_links(V, _rim_edges(F))])
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(nv, nv))
    _, label = connected_components(graph, directed=False)
    return np.unique(label[F[:, 0]], return_inverse=True)[1].ravel()


def shell_containment(V: np.ndarray, F: np.ndarray, shells: np.ndarray, samples: int = 64) -> np.ndarray:
    """(k, k) fraction of shell i's sampled vertices that shell j encloses (|winding| > 1/2,
    either orientation); the diagonal is 0. 1: i nested in j; 0: apart or around j; between:
    the two overlap."""
    k = int(shells.max()) + 1
    inside = np.zeros((k, k))
    boxes, points = [], []
    rng = np.random.default_rng(0)
    for i in range(k):
        vi = np.unique(F[shells == i])
        boxes.append((V[vi].min(axis=0), V[vi].max(axis=0)))
        points.append(V[rng.choice(vi, min(samples, len(vi)), replace=False)])
    for j in range(k):
        tree = None
        for i in range(k):
            lo, hi = boxes[j]
            if i == j or np.any(boxes[i][0] > hi) or np.any(boxes[i][1] < lo):
                continue
            tree = tree or SurfaceTree.build(V, F[shells == j])
            inside[i, j] = np.mean(np.abs(tree.winding_numbers(points[i])) > 0.5)
    return inside


def orient_shells(V: np.ndarray, F: np.ndarray, notes: list[str]) -> tuple[np.ndarray, float]:
    """Orient each shell by its nesting depth (outward at even depth, inward in a cavity) so that
    winding numbers add up to 1 in the solid and 0 in cavities and outside; returns the
    re-oriented triangles and the enclosed volume [m^3]."""
    shells = shell_labels(F, V)
    k = int(shells.max()) + 1
    depth = (shell_containment(V, F, shells) > NESTED_FRACTION).sum(axis=1) if k > 1 else np.zeros(1, int)
    F = F.copy()
    flipped = 0
    volume = 0.0
    for i in range(k):
        mine = shells == i
        v = mt.enclosed_volume(V, F[mine])
        want = 1.0 if depth[i] % 2 == 0 else -1.0
        if v * want < 0:
            F[mine] = F[mine][:, [0, 2, 1]]
            flipped += 1
        volume += abs(v) * want
    if k > 1:
        notes.append(f"{k} shells (nesting depths {sorted(int(d) for d in depth)})")
    if flipped:
        notes.append("triangles faced inward: orientation flipped to outward" if k == 1 else
                     f"{flipped} of {k} shells faced the wrong way: re-oriented by nesting depth")
    return F, volume


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
    try:
        check_input_file(path, str(path), MAX_MESH_BYTES, MESH_NOUN)
    except UserInputError as err:
        raise AtriumMeshError(str(err)) from None
    suffix = path.suffix.lower()
    readers = {".obj": read_obj, ".stl": read_stl, ".ply": read_ply, ".vtk": read_vtk_polydata}
    if suffix not in readers:
        raise AtriumMeshError(f"{path}: unsupported format {suffix!r} (use .obj, .stl, .ply or .vtk)")
    V, F = readers[suffix](path)
    try:
        return validate_surface(V, F, units)
    except AtriumMeshError as err:
        raise AtriumMeshError(f"{path}: {err}") from None


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

        from ballchain.drake_models.model_files import cache_dir, cached_files, source_hash

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
