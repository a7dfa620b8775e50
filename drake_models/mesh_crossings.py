"""A shell that crosses itself: the pairs of its triangles that cross (``self_crossings``), how
deep its parts on the wrong side lie, and the note or the refusal that ``validate_surface`` gives."""

from __future__ import annotations

import sys

import numpy as np

from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models.mesh_shells import shell_labels
from ballchain.drake_models.surface_tree import SurfaceTree


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
