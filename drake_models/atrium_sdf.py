"""The atrium's signed distance on a cached grid: sdf > 0 in the blood pool, < 0 beyond the wall.

The statics engine keeps every free ball's centre at least a ball radius inside the lumen
(``optimization.wall_constraints``): it needs the distance to the blood-side surface and its
gradient at 16 points, hundreds of times a second. An exact point-to-mesh query costs about a
millisecond; a grid of the signed distance, built once per mesh and interpolated,
costs a few microseconds.

* Distance: the exact unsigned distance to the blood-side triangles (``mesh_tools``, the same
  surface ``wall_distance`` measures) at every node within ``band`` of the surface; further
  nodes hold +-``band`` (the wall rows of the statics are active only within about a millimetre,
  so nothing beyond the band is ever used).
* Sign (inside test): never from face normals, which flip at the vein ostia (a node closest to an
  ostium rim sees a rim edge, whose normal is meaningless: the distance jumped by 4 mm there in
  a prototype); a user's closed surface uses ray parity along +z (each grid
  column crosses the surface an even number of times; a node is inside after an odd number).
  The procedural ``LeftAtrium`` uses ray parity on its faceted endocardium (holes closed) joined
  with its polygonal vein tubes: the sign changes exactly on the triangles the distance is
  measured to (the smooth ellipsoid would give the 0.05-0.1 mm between chord and arc the wrong
  sign).
* Interpolation: a quadratic B-spline of the node values (C1: the value, gradient and Hessian are
  derivatives of one function and the wall normal is continuous, as the statics' Newton steps
  need; trilinear interpolation's gradient jumps at every cell face).
* Cache: ``atrium_sdf_<hash>.npz`` next to the heart's generated files, the hash of the
  triangles, the inside test and the grid parameters, written atomically.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from ballchain.drake_models import mesh_tools as mt

SDF_VERSION = 2  # bump when the construction changes: it is part of the cache key


def _tube_polygon_inside(o, n_around: int, rel: np.ndarray, along: np.ndarray) -> np.ndarray:
    """Inside the regular n-gon prism of a vein tube (``mesh_tools.cylinder_surface``'s frame)."""
    axis = o.axis_H
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    radial = rel - along[:, None] * axis
    angle = np.arctan2(radial @ e2, radial @ e1)
    sector = 2.0 * np.pi / n_around
    local = np.mod(angle, sector) - 0.5 * sector  # angle from the nearest face's mid-line
    apothem = 0.5 * o.diameter * np.cos(0.5 * sector)
    return np.linalg.norm(radial, axis=1) * np.cos(local) < apothem


def procedural_lumen_contains(heart, p_H: np.ndarray) -> np.ndarray:
    """Whether points (k, 3) [m] lie in the lumen of a procedural ``LeftAtrium``'s collision mesh.

    The lumen is the inside of the faceted endocardium (``closed_inner_surface``: the same
    triangles as the wall, holes closed; ray parity) together with the inside of each vein's
    polygonal tube, from half a diameter below the ostium centre (the hole cut in the
    endocardium) to the tube's end. The facets, not the smooth ellipsoid, so that the sign
    changes exactly on the triangles the distance is measured to, and it does not flip at the
    ostia.
    """
    p_H = np.atleast_2d(np.asarray(p_H, float))
    V, F = heart.closed_inner_surface
    inside = _points_inside_closed(V, F, p_H)
    tube_end = heart.params.vein_length + heart.params.wall_thickness
    for o in heart.ostia:
        rel = p_H - o.p_HO
        along = rel @ o.axis_H
        inside |= (along > -0.5 * o.diameter) & (along < tube_end) & _tube_polygon_inside(
            o, heart.params.vein_segments, rel, along)
    return inside


def _points_inside_closed(V: np.ndarray, F: np.ndarray, P: np.ndarray) -> np.ndarray:
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


@njit(cache=True)
def _bspline(padded, origin, spacing, shape, P, order):
    """Quadratic B-spline of the node values at points P (k, 3): the compiled form of the numpy
    reference in ``AtriumSDF.reference`` (same weights, same clamping); order 0, 1 or 2."""
    k = P.shape[0]
    sdf = np.zeros(k)
    grad = np.zeros((k, 3))
    hess = np.zeros((k, 3, 3))
    w = np.empty((3, 3))
    dw = np.empty((3, 3))
    d2 = np.array([1.0, -2.0, 1.0]) / spacing**2
    i0 = np.empty(3, np.int64)
    for n in range(k):
        for a in range(3):
            x = (P[n, a] - origin[a]) / spacing
            x = min(max(x, 0.0), shape[a] - 1.0)
            i0[a] = int(np.rint(x))
            u = x - i0[a]
            w[a, 0] = 0.5 * (0.5 - u) ** 2
            w[a, 1] = 0.75 - u * u
            w[a, 2] = 0.5 * (0.5 + u) ** 2
            dw[a, 0] = (u - 0.5) / spacing
            dw[a, 1] = -2.0 * u / spacing
            dw[a, 2] = (u + 0.5) / spacing
        for i in range(3):
            for j in range(3):
                for l in range(3):
                    v = padded[i0[0] + i, i0[1] + j, i0[2] + l]
                    sdf[n] += w[0, i] * w[1, j] * w[2, l] * v
                    if order >= 1:
                        grad[n, 0] += dw[0, i] * w[1, j] * w[2, l] * v
                        grad[n, 1] += w[0, i] * dw[1, j] * w[2, l] * v
                        grad[n, 2] += w[0, i] * w[1, j] * dw[2, l] * v
                    if order >= 2:
                        hess[n, 0, 0] += d2[i] * w[1, j] * w[2, l] * v
                        hess[n, 1, 1] += w[0, i] * d2[j] * w[2, l] * v
                        hess[n, 2, 2] += w[0, i] * w[1, j] * d2[l] * v
                        hess[n, 0, 1] += dw[0, i] * dw[1, j] * w[2, l] * v
                        hess[n, 0, 2] += dw[0, i] * w[1, j] * dw[2, l] * v
                        hess[n, 1, 2] += w[0, i] * dw[1, j] * dw[2, l] * v
        hess[n, 1, 0] = hess[n, 0, 1]
        hess[n, 2, 0] = hess[n, 0, 2]
        hess[n, 2, 1] = hess[n, 1, 2]
    return sdf, grad, hess


@dataclass
class AtriumSDF:
    """The signed distance to the atrium's blood-side surface on a regular grid.

    Attributes:
        origin: (3,) position of node (0, 0, 0) [m].
        spacing: node spacing h [m].
        values: (nx, ny, nz) signed distance at the nodes [m] (> 0 inside the lumen), clamped to
            +-``band``.
        band: the clamp [m].
        key: the content hash the cache file is named by.
    """

    origin: np.ndarray
    spacing: float
    values: np.ndarray
    band: float
    key: str = ""

    def __post_init__(self) -> None:
        self.values = np.ascontiguousarray(self.values, dtype=float)
        # One node of padding (edge values) so that every 3x3x3 stencil lies in the array.
        self._padded = np.pad(self.values, 1, mode="edge")
        self._shape = np.array(self.values.shape)

    def __call__(self, p: np.ndarray, gradient: bool = True, hessian: bool = False):
        """Signed distance at points p (k, 3) [m]: ``reference`` compiled (numba).

        Returns:
            as ``reference``.
        """
        P = np.ascontiguousarray(np.atleast_2d(np.asarray(p, float)))
        order = 2 if hessian else (1 if gradient else 0)
        sdf, grad, hess = _bspline(self._padded, np.asarray(self.origin, float), float(self.spacing),
                                   self._shape.astype(float), P, order)
        if order == 0:
            return sdf
        return (sdf, grad, hess) if hessian else (sdf, grad)

    def reference(self, p: np.ndarray, gradient: bool = True, hessian: bool = False):
        """Signed distance at points p (k, 3) [m], quadratic B-spline of the node values (numpy).

        The quadratic B-spline (27 nodes around each point) is C1: value, gradient and Hessian
        are exact derivatives of one function, and the gradient is continuous, which is what
        the statics' Newton steps and line search need (trilinear interpolation has a gradient
        that jumps at every cell face). It reproduces linear fields exactly and smooths curved
        ones by O(h^2 curvature). Points outside the grid see the boundary nodes' values.

        Returns:
            ``sdf`` (k,) [m]; with ``gradient``: ``(sdf, grad (k, 3))``; with ``hessian`` too:
            ``(sdf, grad, hess (k, 3, 3) [1/m])``.
        """
        x = (np.atleast_2d(np.asarray(p, float)) - self.origin) / self.spacing
        x = np.clip(x, 0.0, self._shape - 1.0)
        i0 = np.rint(x).astype(int)
        u = x - i0  # in [-1/2, 1/2]
        w = np.stack([0.5 * (0.5 - u) ** 2, 0.75 - u**2, 0.5 * (0.5 + u) ** 2], axis=-1)  # (k, 3 axes, 3)
        o = np.arange(3)  # padded index of node i0 - 1 + o
        idx = ((i0[:, 0, None] + o)[:, :, None, None], (i0[:, 1, None] + o)[:, None, :, None],
               (i0[:, 2, None] + o)[:, None, None, :])
        v = self._padded[idx]  # (k, 3, 3, 3)
        wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
        sdf = np.einsum("ka,kb,kc,kabc->k", wx, wy, wz, v)
        if not gradient and not hessian:
            return sdf
        h = self.spacing
        dw = np.stack([u - 0.5, -2.0 * u, u + 0.5], axis=-1) / h  # (k, 3 axes, 3)
        dx, dy, dz = dw[:, 0], dw[:, 1], dw[:, 2]
        grad = np.stack([np.einsum("ka,kb,kc,kabc->k", dx, wy, wz, v),
                         np.einsum("ka,kb,kc,kabc->k", wx, dy, wz, v),
                         np.einsum("ka,kb,kc,kabc->k", wx, wy, dz, v)], axis=1)
        if not hessian:
            return sdf, grad
        d2 = np.array([1.0, -2.0, 1.0]) / h**2
        k = len(sdf)
        d2x = np.broadcast_to(d2, (k, 3))
        H = np.empty((k, 3, 3))
        H[:, 0, 0] = np.einsum("ka,kb,kc,kabc->k", d2x, wy, wz, v)
        H[:, 1, 1] = np.einsum("ka,kb,kc,kabc->k", wx, d2x, wz, v)
        H[:, 2, 2] = np.einsum("ka,kb,kc,kabc->k", wx, wy, d2x, v)
        H[:, 0, 1] = H[:, 1, 0] = np.einsum("ka,kb,kc,kabc->k", dx, dy, wz, v)
        H[:, 0, 2] = H[:, 2, 0] = np.einsum("ka,kb,kc,kabc->k", dx, wy, dz, v)
        H[:, 1, 2] = H[:, 2, 1] = np.einsum("ka,kb,kc,kabc->k", wx, dy, dz, v)
        return sdf, grad, H


def _surface_for(heart) -> tuple[np.ndarray, np.ndarray, str]:
    """(V, F, inside-test name) of the blood-side surface of a LeftAtrium or a UserAtrium."""
    if hasattr(heart, "lumen_surface"):  # procedural
        V, F = heart.lumen_surface
        return V, F, "procedural"
    return heart.surface.V, heart.surface.F, "ray_parity"


def cache_key(V: np.ndarray, F: np.ndarray, inside: str, spacing: float, band: float, margin: float,
              extra: bytes = b"") -> str:
    h = hashlib.sha1()
    for a in (np.ascontiguousarray(V, np.float64), np.ascontiguousarray(F, np.int64)):
        h.update(a.tobytes())
    h.update(repr((SDF_VERSION, inside, float(spacing), float(band), float(margin))).encode() + extra)
    return h.hexdigest()[:16]


def build_atrium_sdf(heart, spacing: float = 0.5e-3, band: float = 5e-3, margin: float = 2e-3,
                     progress: bool = False) -> AtriumSDF:
    """Build the grid of a LeftAtrium or UserAtrium (no cache; see ``atrium_sdf``).

    Args:
        heart: the atrium.
        spacing: node spacing [m].
        band: distances beyond this are clamped [m].
        margin: the grid reaches this far beyond the surface's bounding box [m].
        progress: show a tqdm bar over the distance chunks.
    """
    V, F, inside_kind = _surface_for(heart)
    lo = V.min(axis=0) - margin
    shape = tuple(int(np.ceil(s)) + 1 for s in (V.max(axis=0) + margin - lo) / spacing)
    axes = [lo[k] + spacing * np.arange(shape[k]) for k in range(3)]
    P = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    if inside_kind == "procedural":
        inside = procedural_lumen_contains(heart, P)
    else:
        inside = ray_parity_contains(V, F, lo, spacing, shape).reshape(-1)
    # Unsigned distance: exact within the band (candidates from the nearest face centroids).
    from scipy.spatial import cKDTree

    tri = V[F]
    centroids = tri.mean(axis=1)
    reach = float(np.linalg.norm(tri - centroids[:, None], axis=2).max())
    d_centroid, _ = cKDTree(centroids).query(P, k=1)
    dist = np.full(len(P), band)
    near = np.flatnonzero(d_centroid - reach < band)
    surface = mt.SurfaceDistance(V, F)
    chunks = np.array_split(near, max(1, len(near) // 20000))
    iterator = chunks
    if progress:
        from tqdm import tqdm

        iterator = tqdm(chunks, desc="atrium SDF", unit="chunk")
    for chunk in iterator:
        dist[chunk] = surface(P[chunk])
    sdf = np.where(inside, 1.0, -1.0) * np.minimum(dist, band)
    # Stored as float32 (the cache's precision, 1e-9 m here): a built and a loaded grid agree.
    return AtriumSDF(lo, spacing, sdf.reshape(shape).astype(np.float32), band)


def atrium_sdf(heart, spacing: float = 0.5e-3, band: float = 5e-3, margin: float = 2e-3,
               directory: Path | None = None) -> AtriumSDF:
    """The atrium's SDF grid, from the cache when it was built before (else built and cached).

    The file ``atrium_sdf_<key>.npz`` goes next to the heart's generated files (``write_files``)
    or into ``directory``; the key hashes the surface's triangles, the inside test and the grid
    parameters, so a changed mesh never reads a stale grid.
    """
    V, F, inside_kind = _surface_for(heart)
    extra = b""
    if inside_kind == "procedural":  # the lumen test depends on the parameters, not only on F
        extra = heart.params.key().encode()
    key = cache_key(V, F, inside_kind, spacing, band, margin, extra)
    directory = Path(directory) if directory else Path(heart.write_files()["vtk"]).parent
    path = directory / f"atrium_sdf_{key}.npz"
    if path.exists():
        try:
            with np.load(path) as data:
                return AtriumSDF(data["origin"], float(data["spacing"]), data["values"].astype(float),
                                 float(data["band"]), key)
        except (OSError, KeyError, ValueError):
            pass  # a damaged file: rebuild it
    sdf = build_atrium_sdf(heart, spacing, band, margin)
    sdf.key = key
    directory.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
    np.savez_compressed(tmp, origin=sdf.origin, spacing=sdf.spacing, values=sdf.values.astype(np.float32),
                        band=sdf.band)
    os.replace(tmp, path)
    return sdf
