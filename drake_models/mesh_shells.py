"""The shells of a surface mesh: its openings (holes against seams left open), its connected
pieces, which one is nested in which, and each oriented by its nesting depth."""

from __future__ import annotations

import numpy as np

from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models.surface_tree import SurfaceTree

SEAM_GAP = 0.2e-3  # [m] rims closer than this belong to one opening (the two sides of a seam)
NESTED_FRACTION = 0.9  # a shell with this share of its vertices inside another is nested in it


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
