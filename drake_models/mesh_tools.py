"""Triangle and tetrahedral mesh helpers for the heart models (numpy only, SI units).

Surfaces are ``(V, F)`` pairs: V (nv, 3) vertex positions [m], F (nf, 3) int vertex indices,
counter-clockwise seen from the side the normals point to. Volume meshes are ``(V, T)`` with
T (nt, 4) positively oriented tetrahedra (Drake's convention: (v1-v0) x (v2-v0) . (v3-v0) > 0).

The wall of a hollow chamber is made by extruding its surface along the vertex normals in
``layers`` layers of prisms, each split into three tetrahedra with the global-index rule (the
diagonal of each side quad runs from the lower-index bottom vertex to the higher-index top
vertex), so neighbouring prisms share conforming faces. Drake's compliant-hydroelastic pressure
field is zero on the boundary of a volume mesh, so at least two layers are needed for any
vertex (the middle layer) to carry pressure (see docs/design.md, 5).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ballchain.drake_models.kernels._common import inline_kernel, kernel
from ballchain.drake_models.vectors import perpendicular_basis


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """A unit sphere made by subdividing an icosahedron.

    Args:
        subdivisions: number of 1-to-4 splits (4 gives 2562 vertices, 5120 faces).

    Returns:
        (V (nv, 3) unit vectors, F (nf, 3)) with outward-facing triangles.
    """
    t = (1.0 + 5.0**0.5) / 2.0
    V = [
        [-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0],
        [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
        [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1],
    ]  # fmt: skip
    F = [
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
        [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
        [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
        [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ]  # fmt: skip
    V = [np.array(v, float) / np.linalg.norm(v) for v in V]
    F = np.array(F)
    for _ in range(subdivisions):
        midpoint: dict[tuple[int, int], int] = {}

        def mid(i: int, j: int) -> int:
            key = (min(i, j), max(i, j))
            if key not in midpoint:
                v = V[i] + V[j]
                V.append(v / np.linalg.norm(v))
                midpoint[key] = len(V) - 1
            return midpoint[key]

        new = []
        for a, b, c in F:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        F = np.array(new)
    return np.array(V), F


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (nv, 3) of a triangle surface."""
    face_n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    N = np.zeros_like(V)
    for k in range(3):
        np.add.at(N, F[:, k], face_n)
    norm = np.linalg.norm(N, axis=1)
    if np.any(norm == 0.0):
        raise ValueError("vertex_normals: a vertex belongs to no face or to degenerate faces only")
    return N / norm[:, None]


def extrude_shell(
    V: np.ndarray, F: np.ndarray, N: np.ndarray, thickness: float, layers: int
) -> tuple[np.ndarray, np.ndarray]:
    """Tetrahedral shell made by extruding a surface along its normals.

    Args:
        V: (nv, 3) surface vertices [m].
        F: (nf, 3) triangles.
        N: (nv, 3) unit extrusion directions (the wall grows along +N).
        thickness: wall thickness [m].
        layers: tetrahedra layers through the thickness (>= 2 for compliant hydroelastics).

    Returns:
        (V_tet ((layers + 1) nv, 3), T (3 layers nf, 4)) positively oriented tetrahedra.
    """
    if layers < 1 or thickness <= 0:
        raise ValueError(f"extrude_shell: need layers >= 1 and thickness > 0, got {layers}, {thickness}")
    nv = V.shape[0]
    Vt = np.concatenate([V + N * (thickness * k / layers) for k in range(layers + 1)])
    Fs = np.sort(F, axis=1)  # a < b < c: the global-index rule for conforming diagonals
    tets = []
    for k in range(layers):
        a, b, c = (Fs[:, i] + k * nv for i in range(3))
        a2, b2, c2 = a + nv, b + nv, c + nv
        tets += [
            np.stack([a, b, c, c2], axis=1),
            np.stack([a, b, b2, c2], axis=1),
            np.stack([a, a2, b2, c2], axis=1),
        ]
    T = np.concatenate(tets)
    vol = signed_volumes(Vt, T)
    flip = vol < 0
    T[flip] = T[flip][:, [0, 2, 1, 3]]
    return Vt, T


def signed_volumes(V: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Signed volumes (nt,) [m^3] of tetrahedra (positive for Drake's orientation)."""
    a, b, c, d = (V[T[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def boundary_surface(V: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Boundary triangles (nb, 3) of a tetrahedral mesh, oriented outward."""
    faces = np.concatenate([T[:, [1, 2, 3]], T[:, [0, 3, 2]], T[:, [0, 1, 3]], T[:, [0, 2, 1]]])
    keys = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    boundary = faces[counts[inverse.ravel()] == 1]
    return boundary  # tet faces above are outward for positively oriented tetrahedra


def edge_use_counts(F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Undirected edges (ne, 2), how many faces use each, and how many use it as (i -> j) minus (j -> i)."""
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    undirected = np.sort(directed, axis=1)
    sign = np.where(directed[:, 0] < directed[:, 1], 1, -1)
    edges, inverse, counts = np.unique(undirected, axis=0, return_inverse=True, return_counts=True)
    balance = np.zeros(len(edges), dtype=int)
    np.add.at(balance, inverse.ravel(), sign)
    return edges, counts, balance


def is_watertight(F: np.ndarray) -> bool:
    """Every edge used by exactly two faces, once in each direction (closed, consistently oriented)."""
    _, counts, balance = edge_use_counts(F)
    return bool(np.all(counts == 2) and np.all(balance == 0))


def enclosed_volume(V: np.ndarray, F: np.ndarray) -> float:
    """Volume [m^3] enclosed by a closed, outward-oriented triangle surface (divergence theorem)."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def winding_numbers(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Generalised winding number (k,) of a closed surface around each point (1 inside, 0 outside).

    Uses the solid angle of each triangle (Van Oosterom and Strackee 1983).
    """
    P = np.asarray(points, float)[:, None, :]
    a, b, c = V[F[:, 0]] - P, V[F[:, 1]] - P, V[F[:, 2]] - P
    la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
    det = np.einsum("kij,kij->ki", a, np.cross(b, c))
    den = (
        la * lb * lc
        + np.einsum("kij,kij->ki", a, b) * lc
        + np.einsum("kij,kij->ki", b, c) * la
        + np.einsum("kij,kij->ki", c, a) * lb
    )
    return np.arctan2(det, den).sum(axis=1) / (2.0 * np.pi)


def point_triangle_distances(points: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Distance [m] from each point to each of its candidate triangles.

    Args:
        points: (k, 3) [m].
        tri: (k, c, 3, 3) candidate triangles per point (vertex rows) [m].

    Returns:
        (k, c) distances.
    """
    p = points[:, None, :]
    a, b, c = tri[:, :, 0], tri[:, :, 1], tri[:, :, 2]
    n = np.cross(b - a, c - a)
    n2 = np.einsum("kij,kij->ki", n, n)
    w = p - a
    # Barycentric coordinates of the projection onto the plane.
    beta = np.einsum("kij,kij->ki", np.cross(w, c - a), n) / n2
    gamma = np.einsum("kij,kij->ki", np.cross(b - a, w), n) / n2
    inside = (beta >= 0) & (gamma >= 0) & (beta + gamma <= 1)
    plane = np.abs(np.einsum("kij,kij->ki", w, n)) / np.sqrt(n2)

    def segment(p0, p1):
        d = p1 - p0
        s = np.clip(np.einsum("kij,kij->ki", p - p0, d) / np.einsum("kij,kij->ki", d, d), 0.0, 1.0)
        return np.linalg.norm(p - (p0 + s[..., None] * d), axis=2)

    edges = np.minimum(np.minimum(segment(a, b), segment(b, c)), segment(c, a))
    return np.where(inside, plane, edges)


@kernel
def nearest_triangle_distances(points, tri):
    """``point_triangle_distances(points, tri).min(axis=1)`` compiled: the distance [m] from each
    point (k, 3) to the nearest of its candidate triangles (k, c, 3, 3), the same arithmetic term
    for term (numpy's cross products, the projection's barycentric coordinates, the clamped
    segment distances), without the (k, c, 3) temporaries."""
    k, c = tri.shape[0], tri.shape[1]
    out = np.empty(k)
    for i in range(k):
        p0, p1, p2 = points[i, 0], points[i, 1], points[i, 2]
        best = np.inf
        for j in range(c):
            a0, a1, a2 = tri[i, j, 0, 0], tri[i, j, 0, 1], tri[i, j, 0, 2]
            b0, b1, b2 = tri[i, j, 1, 0], tri[i, j, 1, 1], tri[i, j, 1, 2]
            c0, c1, c2 = tri[i, j, 2, 0], tri[i, j, 2, 1], tri[i, j, 2, 2]
            u0, u1, u2 = b0 - a0, b1 - a1, b2 - a2  # b - a
            v0, v1, v2 = c0 - a0, c1 - a1, c2 - a2  # c - a
            n0, n1, n2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
            nn = n0 * n0 + n1 * n1 + n2 * n2
            w0, w1, w2 = p0 - a0, p1 - a1, p2 - a2
            x0, x1, x2 = w1 * v2 - w2 * v1, w2 * v0 - w0 * v2, w0 * v1 - w1 * v0  # w x (c - a)
            beta = (x0 * n0 + x1 * n1 + x2 * n2) / nn
            y0, y1, y2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0  # (b - a) x w
            gamma = (y0 * n0 + y1 * n1 + y2 * n2) / nn
            if beta >= 0 and gamma >= 0 and beta + gamma <= 1:
                dist = abs(w0 * n0 + w1 * n1 + w2 * n2) / np.sqrt(nn)
            else:
                dist = min(min(_segment(p0, p1, p2, a0, a1, a2, b0, b1, b2), _segment(p0, p1, p2, b0, b1, b2, c0, c1, c2)),
                           _segment(p0, p1, p2, c0, c1, c2, a0, a1, a2))
            if dist < best:
                best = dist
        out[i] = best
    return out


@inline_kernel
def _segment(p0, p1, p2, a0, a1, a2, b0, b1, b2):
    """Distance from p to the segment a-b (``point_triangle_distances``'s ``segment``)."""
    d0, d1, d2 = b0 - a0, b1 - a1, b2 - a2
    s = ((p0 - a0) * d0 + (p1 - a1) * d1 + (p2 - a2) * d2) / (d0 * d0 + d1 * d1 + d2 * d2)
    s = min(max(s, 0.0), 1.0)
    e0, e1, e2 = p0 - (a0 + s * d0), p1 - (a1 + s * d1), p2 - (a2 + s * d2)
    return np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)


class SurfaceDistance:
    """Unsigned distance from points to a triangle surface, with a k-d tree over face centroids.

    ``compiled`` (the default) measures the candidates with ``nearest_triangle_distances`` (the
    watchdog's wall check at every few steps: 6 us instead of 270 for 12 balls); False with the
    numpy ``point_triangle_distances``, whose floats the signed-distance grids were built from
    (``atrium_sdf`` keeps it: the grids, and every equilibrium on them, stay bit for bit). The
    two agree to a few ulps (``tests/test_atrium_sdf.py``)."""

    def __init__(self, V: np.ndarray, F: np.ndarray, candidates: int = 24, compiled: bool = True):
        from scipy.spatial import cKDTree

        self._tri = V[F]  # (nf, 3, 3)
        self._tree = cKDTree(self._tri.mean(axis=1))
        self._k = min(candidates, len(F))
        self._compiled = compiled

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Distances (k,) [m] from points (k, 3) [m] to the surface."""
        points = np.atleast_2d(np.asarray(points, float))
        _, idx = self._tree.query(points, k=self._k)
        idx = np.atleast_2d(idx).reshape(len(points), -1)
        if self._compiled:
            return nearest_triangle_distances(np.ascontiguousarray(points), self._tri[idx])
        return point_triangle_distances(points, self._tri[idx]).min(axis=1)


def write_obj(path: Path, V: np.ndarray, F: np.ndarray, scale: float = 1.0) -> Path:
    """Write a triangle surface as Wavefront OBJ (vertex coordinates multiplied by ``scale``)."""
    path = Path(path)
    lines = ["# generated by ballchain.drake_models.mesh_tools"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in V * scale]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_vtk_tetrahedra(path: Path, V: np.ndarray, T: np.ndarray) -> Path:
    """Write a tetrahedral mesh as a legacy ASCII VTK unstructured grid (Drake reads it)."""
    path = Path(path)
    out = [
        "# vtk DataFile Version 3.0",
        "ballchain heart wall (tetrahedra)",
        "ASCII",
        "DATASET UNSTRUCTURED_GRID",
        f"POINTS {len(V)} double",
    ]
    out += [f"{x:.9g} {y:.9g} {z:.9g}" for x, y, z in V]
    out.append(f"CELLS {len(T)} {5 * len(T)}")
    out += [f"4 {a} {b} {c} {d}" for a, b, c, d in T]
    out.append(f"CELL_TYPES {len(T)}")
    out += ["10"] * len(T)
    path.write_text("\n".join(out) + "\n")
    return path


def read_vtk_tetrahedra(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read back a file written by ``write_vtk_tetrahedra``."""
    tokens = Path(path).read_text().split()
    i = tokens.index("POINTS")
    nv = int(tokens[i + 1])
    V = np.array(tokens[i + 3 : i + 3 + 3 * nv], float).reshape(nv, 3)
    j = tokens.index("CELLS")
    nt = int(tokens[j + 1])
    T = np.array(tokens[j + 3 : j + 3 + 5 * nt], int).reshape(nt, 5)[:, 1:]
    return V, T


def cylinder_surface(
    p_start: np.ndarray, axis: np.ndarray, radius: float, length: float, n_around: int = 32,
    max_edge: float = 1.5e-3,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An open cylindrical surface (no end caps) with outward radial normals.

    Args:
        p_start: (3,) centre of the start rim [m].
        axis: (3,) direction of the cylinder's axis.
        radius: [m].
        length: along the axis [m].
        n_around: vertices around each rim.
        max_edge: longest axial edge [m].

    Returns:
        (V, F, N): vertices (nv, 3), triangles (nf, 3) facing outward, unit radial normals (nv, 3).
    """
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    x, y = perpendicular_basis(axis)
    e1, e2 = -x, -y  # the rim starts on -x: the vertex order the meshes have always had
    n_along = max(2, int(np.ceil(length / max_edge)) + 1)
    angles = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    radial = np.cos(angles)[:, None] * e1 + np.sin(angles)[:, None] * e2  # (n_around, 3)
    s = np.linspace(0.0, length, n_along)
    V = (np.asarray(p_start, float) + s[:, None, None] * axis + radius * radial[None]).reshape(-1, 3)
    N = np.broadcast_to(radial[None], (n_along, n_around, 3)).reshape(-1, 3).copy()
    F = []
    for i in range(n_along - 1):
        for j in range(n_around):
            a, b = i * n_around + j, i * n_around + (j + 1) % n_around
            c, d = a + n_around, b + n_around
            F += [[a, b, d], [a, d, c]]  # outward for e1 x e2 = axis
    return V, np.array(F), N


def points_inside_closed(V: np.ndarray, F: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Ray parity (+z) of scattered points against a closed surface (bounding-box filtered)."""
    inside = np.zeros(len(P), bool)
    lo, hi = V.min(axis=0), V.max(axis=0)
    cand = np.flatnonzero(np.all((P >= lo) & (P <= hi), axis=1))
    if len(cand) == 0:
        return inside
    tri = V[F]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    ok = np.abs(det) > 0.0
    a, b, c, det = a[ok], b[ok], c[ok], det[ok]
    tlo, thi = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
    jitter = 1e-9 * np.array([np.sqrt(2.0), np.sqrt(3.0)])
    for chunk in np.array_split(cand, max(1, len(cand) // 2000)):
        x = P[chunk, 0:1] + jitter[0]
        y = P[chunk, 1:2] + jitter[1]
        box = (x >= tlo[None, :, 0]) & (x <= thi[None, :, 0]) & (y >= tlo[None, :, 1]) & (y <= thi[None, :, 1])
        k, t = np.nonzero(box)
        xk, yk = x[k, 0], y[k, 0]
        l1 = ((xk - a[t, 0]) * (c[t, 1] - a[t, 1]) - (c[t, 0] - a[t, 0]) * (yk - a[t, 1])) / det[t]
        l2 = ((b[t, 0] - a[t, 0]) * (yk - a[t, 1]) - (xk - a[t, 0]) * (b[t, 1] - a[t, 1])) / det[t]
        hit = (l1 >= 0) & (l2 >= 0) & (l1 + l2 <= 1)
        z = a[t, 2] + l1 * (b[t, 2] - a[t, 2]) + l2 * (c[t, 2] - a[t, 2])
        below = hit & (z < P[chunk[k], 2])
        counts = np.bincount(k[below], minlength=len(chunk))
        inside[chunk] = counts % 2 == 1
    return inside


def ray_parity_contains(V: np.ndarray, F: np.ndarray, origin: np.ndarray, spacing: float,
                        shape: tuple[int, int, int]) -> np.ndarray:
    """Inside test of a closed surface at every node of a grid, by ray parity along +z.

    Each triangle is rasterised onto the grid's (x, y) columns its projection covers; a column
    crosses it at one z. Nodes above an odd number of crossings are inside. The columns are
    shifted by an irrational fraction of the spacing in the crossing tests, so that no column
    passes exactly through an edge or a vertex of a mesh laid out on round numbers.

    Args:
        V, F: a closed, consistently oriented surface [m].
        origin: (3,) grid origin [m]; spacing: [m]; shape: (nx, ny, nz).

    Returns:
        (nx, ny, nz) bool.
    """
    nx, ny, nz = shape
    jitter = spacing * np.array([1e-4 * np.sqrt(2.0), 1e-4 * np.sqrt(3.0)])
    tri = V[F]
    cols_i, cols_j, zs = [], [], []
    xy0 = origin[:2] + jitter
    lo = np.floor((tri[:, :, :2].min(axis=1) - xy0) / spacing).astype(int)
    hi = np.ceil((tri[:, :, :2].max(axis=1) - xy0) / spacing).astype(int)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    for t in np.flatnonzero(np.abs(det) > 0.0):  # vertical triangles are never crossed
        ii, jj = np.meshgrid(np.arange(max(lo[t, 0], 0), min(hi[t, 0], nx - 1) + 1),
                             np.arange(max(lo[t, 1], 0), min(hi[t, 1], ny - 1) + 1), indexing="ij")
        ii, jj = ii.ravel(), jj.ravel()
        x = xy0[0] + ii * spacing
        y = xy0[1] + jj * spacing
        # Barycentric coordinates of (x, y) in the projected triangle.
        l1 = ((x - a[t, 0]) * (c[t, 1] - a[t, 1]) - (c[t, 0] - a[t, 0]) * (y - a[t, 1])) / det[t]
        l2 = ((b[t, 0] - a[t, 0]) * (y - a[t, 1]) - (x - a[t, 0]) * (b[t, 1] - a[t, 1])) / det[t]
        hit = (l1 >= 0) & (l2 >= 0) & (l1 + l2 <= 1)
        if np.any(hit):
            l1, l2 = l1[hit], l2[hit]
            cols_i.append(ii[hit])
            cols_j.append(jj[hit])
            zs.append(a[t, 2] + l1 * (b[t, 2] - a[t, 2]) + l2 * (c[t, 2] - a[t, 2]))
    crossings = np.zeros((nx, ny, nz), np.int32)
    if cols_i:
        ci, cj, z = np.concatenate(cols_i), np.concatenate(cols_j), np.concatenate(zs)
        k = np.clip(np.ceil((z - origin[2]) / spacing).astype(int), 0, nz)  # first node above
        keep = k < nz
        np.add.at(crossings, (ci[keep], cj[keep], k[keep]), 1)
    return (np.cumsum(crossings, axis=2) % 2) == 1
