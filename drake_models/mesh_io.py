"""Read and write a user's surface mesh: OBJ, STL (ASCII or binary), PLY (ASCII or binary) and
legacy ASCII VTK polydata, parsed here (no third-party reader); every file checked before it is
read (``input_files``). A file that cannot be read is one ``AtriumMeshError`` saying why.

OBJ: ``v``/``f`` records, polygons fanned into triangles, ``f a/b/c`` and negative indices accepted.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ballchain.infrastructure.errors import UserInputError
from ballchain.infrastructure.input_files import MAX_MESH_BYTES, check_input_file, read_input_file


class AtriumMeshError(UserInputError):
    """A user atrium surface that cannot be used; the message lists every problem found."""


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


def read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (nv, 3) and triangles (nf, 3) of an .obj, .stl, .ply or .vtk file, by its suffix.

    Raises:
        AtriumMeshError: not a regular file of at most ``MAX_MESH_BYTES``, another format, or a
            file its reader cannot parse.
    """
    try:
        check_input_file(path, str(path), MAX_MESH_BYTES, MESH_NOUN)
    except UserInputError as err:
        raise AtriumMeshError(str(err)) from None
    suffix = path.suffix.lower()
    readers = {".obj": read_obj, ".stl": read_stl, ".ply": read_ply, ".vtk": read_vtk_polydata}
    if suffix not in readers:
        raise AtriumMeshError(f"{path}: unsupported format {suffix!r} (use .obj, .stl, .ply or .vtk)")
    return readers[suffix](path)
