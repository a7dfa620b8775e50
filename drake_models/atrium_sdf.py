"""The atrium's signed distance on a cached grid: sdf > 0 in the blood pool, < 0 beyond the wall
(for a solid phantom part, ``side == "solid"``: > 0 in the free space around it, < 0 inside).

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
  column crosses the surface an even number of times; a node is inside after an odd number);
  a ``UserAtrium`` (a mesh of any origin, several shells, narrow open seams, either side) uses the
  generalised winding number of every shell (``surface_tree``, ``atrium_mesh.grid_winding_inside``)
  and its bounding-sphere tree for the distances.
  The procedural ``LeftAtrium`` uses ray parity on its faceted endocardium (holes closed) joined
  with its polygonal vein tubes: the sign changes exactly on the triangles the distance is
  measured to (the smooth ellipsoid would give the 0.05-0.1 mm between chord and arc the wrong
  sign). The atrium says which (``Atrium.lumen_grid_contains``; the tests are
  ``mesh_tools.ray_parity_contains`` and ``LeftAtrium.lumen_contains``).
* Interpolation: a quadratic B-spline of the node values (C1: the value, gradient and Hessian are
  derivatives of one function and the wall normal is continuous, as the statics' Newton steps
  need; trilinear interpolation's gradient jumps at every cell face).
* Cache: ``atrium_sdf_<hash>.npz`` next to the heart's generated files, the hash of the
  triangles, the inside test and the grid parameters, written atomically and signed with the
  user's key (``atrium_sdf_<hash>.hmac``, ``model_files.install_signed``): a grid not signed is
  rebuilt.
"""

from __future__ import annotations

import copy
import hashlib
import os
import threading
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models import model_files
from ballchain.drake_models.kernels.sdf import bspline_sdf
from ballchain.drake_models.model_files import report_rebuilt

SDF_VERSION = 2  # bump when the construction changes: it is part of the cache key


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
        sdf, grad, hess = bspline_sdf(self._padded, np.asarray(self.origin, float), float(self.spacing),
                                   self._shape.astype(float), P, order)
        if order == 0:
            return sdf
        return (sdf, grad, hess) if hessian else (sdf, grad)

    def translated(self, offset) -> "AtriumSDF":
        """The same wall moved rigidly by ``offset`` (3,) [m] (``wall_motion``): the grid's origin
        moves, its node values are shared (no copy, no new padding)."""
        moved = copy.copy(self)
        moved.origin = np.asarray(self.origin, float) + np.asarray(offset, float)
        moved.__dict__.pop("_compiled_arrays", None)  # compiled_model's view of the old origin
        return moved

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


def cache_key(V: np.ndarray, F: np.ndarray, inside: str, spacing: float, band: float, margin: float) -> str:
    """The grid's cache key: the triangles, the lumen test (``Atrium.lumen_key``), the grid."""
    h = hashlib.sha1()
    for a in (np.ascontiguousarray(V, np.float64), np.ascontiguousarray(F, np.int64)):
        h.update(a.tobytes())
    h.update(repr((SDF_VERSION, inside, float(spacing), float(band), float(margin))).encode())
    return h.hexdigest()[:16]


def _margin(heart, margin: float, band: float) -> float:
    """The grid's reach beyond the surface: at least ``band`` around a solid (the chain works
    outside it, so the grid's edge must hold the free space's clamped +band)."""
    return max(margin, band) if getattr(heart, "side", "lumen") == "solid" else margin


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
    V, F = heart.blood_surface
    margin = _margin(heart, margin, band)
    lo = V.min(axis=0) - margin
    shape = tuple(int(np.ceil(s)) + 1 for s in (V.max(axis=0) + margin - lo) / spacing)
    axes = [lo[k] + spacing * np.arange(shape[k]) for k in range(3)]
    P = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    inside = heart.lumen_grid_contains(lo, spacing, shape).reshape(-1)
    if hasattr(heart, "grid_distances"):  # a user's surface: its own bounding-sphere tree
        dist = heart.grid_distances(P, band)
        sdf = np.where(inside, 1.0, -1.0) * np.minimum(dist, band)
        return AtriumSDF(lo, spacing, sdf.reshape(shape).astype(np.float32), band)
    # Unsigned distance: exact within the band (candidates from the nearest face centroids).
    from scipy.spatial import cKDTree

    tri = V[F]
    centroids = tri.mean(axis=1)
    reach = float(np.linalg.norm(tri - centroids[:, None], axis=2).max())
    d_centroid, _ = cKDTree(centroids).query(P, k=1)
    dist = np.full(len(P), band)
    near = np.flatnonzero(d_centroid - reach < band)
    surface = mt.SurfaceDistance(V, F, compiled=False)  # numpy: the grids stay bit for bit
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


# The grids this process has read and checked, by file: (the files' stamp, the grid); the last
# KEEP_READ used (a sweep over perturbed anatomies reads a new grid per anatomy, 27 MB each).
_READ: dict[str, tuple[tuple, AtriumSDF]] = {}
_READ_LOCK = threading.Lock()  # a Dask worker's threads share the process
KEEP_READ = 4


def _stamp(*paths: Path) -> tuple | None:
    """The files' (inode, size, modification time in ns), None when one is missing."""
    try:
        return tuple((st.st_ino, st.st_size, st.st_mtime_ns) for st in (os.stat(p) for p in paths))
    except OSError:
        return None


def atrium_sdf(heart, spacing: float = 0.5e-3, band: float = 5e-3, margin: float = 2e-3,
               directory: Path | None = None) -> AtriumSDF:
    """The atrium's SDF grid, from the cache when it was built before (else built and cached).

    The file ``atrium_sdf_<key>.npz`` goes next to the heart's generated files (``write_files``)
    or into ``directory``; the key hashes the surface's triangles, the inside test and the grid
    parameters, so a changed mesh never reads a stale grid. A grid this process has read and
    checked (one of the last ``KEEP_READ`` used) is not read again while its two files are
    unchanged (their inode, size and modification time): each call returns a shallow copy sharing
    the node values, which are never written (about 30 ms a station build, a few CPU-s of the
    main job).
    """
    V, F = heart.blood_surface
    margin = _margin(heart, margin, band)
    key = cache_key(V, F, heart.lumen_key, spacing, band, margin)
    directory = Path(directory) if directory else Path(heart.write_files()["vtk"]).parent
    path = directory / f"atrium_sdf_{key}.npz"
    listing = directory / f"atrium_sdf_{key}.hmac"  # its signature (model_files.install_signed)
    stamp = _stamp(path, listing)
    with _READ_LOCK:
        kept = _READ.pop(str(path), None)
        if stamp is not None and kept is not None and kept[0] == stamp:
            _READ[str(path)] = kept  # the most recently used last
            return copy.copy(kept[1])  # read and checked before in this process, the files unchanged
    damaged = False
    if path.exists() and listing.exists():  # a grid never signed (a killed run's) is built again quietly
        damaged = True  # unless it carries this user's signature and reads back whole
        if model_files.unsigned(listing, [path]) is None:  # else truncated, edited or planted
            try:
                with np.load(path) as data:
                    origin, values = data["origin"], data["values"]
                    stored = float(data["spacing"]), float(data["band"])
                if (origin.shape == (3,) and values.ndim == 3 and min(values.shape) >= 1
                        and stored == (float(spacing), float(band)) and np.all(np.isfinite(origin))
                        and np.all(np.isfinite(values))):
                    sdf = AtriumSDF(origin, stored[0], values.astype(float), stored[1], key)
                    with _READ_LOCK:
                        _READ[str(path)] = (stamp, sdf)
                        while len(_READ) > KEEP_READ:
                            del _READ[next(iter(_READ))]  # the least recently used
                    return copy.copy(sdf)
            except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, zlib.error):
                pass  # not an npz of the grid: rebuild it
    sdf = build_atrium_sdf(heart, spacing, band, margin)
    sdf.key = key
    directory.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
    np.savez_compressed(tmp, origin=sdf.origin, spacing=sdf.spacing, values=sdf.values.astype(np.float32),
                        band=sdf.band)
    model_files.install_signed(listing, {path: tmp})
    if damaged:
        report_rebuilt(path)
    return sdf

