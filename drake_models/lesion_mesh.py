"""The lesion FEM's geometry: the electrodes and the triangulated (r, z) half disc around them.

The (r, z) half plane, z up, the undeformed tissue surface at z = 0, tissue below, 0.9 % saline
above. The electrode is pressed ``indentation`` into the tissue along the axis; the tissue is
taken to conform to it (flat surface around the contact, no dimple). The whole domain is a half
disc of radius ``outer_radius`` whose arc is the dispersive electrode (V = 0) and the bath at its
initial temperature (the far field: 30 mm away, beyond the reach of 90 s of diffusion).

Electrodes (``Electrode``):

- ``ball_chain_tip``: the tip ball (d = 3.175 mm, ``params.BallChain``), nickel-plated NdFeB,
  an equipotential. Only the cap in contact with the tissue conducts: the shrink wrap
  insulates the rest electrically, and is taken as thermally thin (the ball exchanges heat with
  the saline through it). Above the ball's equator, the silicone sleeve (OD 3.5 mm) up to the
  domain's edge, an insulator of low thermal conductivity (the next ball's point contact is
  left out).
- ``catheter_8fr``: a 3.5 mm Pt-Ir tip electrode of 8 Fr (2.67 mm) diameter, a cylinder with a
  hemispherical end, perpendicular to the tissue; all of its surface conducts, in tissue and in
  saline (that is how a non-irrigated catheter loses most of its current to the bath); the
  polymer shaft above it.

Mesh (``build_mesh``): a Delaunay triangulation (scipy) of points placed on every boundary and
interface curve and in the domains (a hexagonal lattice of spacing ``h`` within 5 mm of the
contact, rings growing away from it), so every curve is a chain of mesh edges. Split out of
``lesion_fem`` (issue 48), which re-exports every name here.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, cKDTree
from skfem import MeshTri

from ballchain.drake_models import tissue as laws
from ballchain.drake_models.errors import UserInputError
from ballchain.drake_models.params import BallChain, Sleeve


TISSUE, SALINE, ELECTRODE, HOLDER = 0, 1, 2, 3
DOMAIN_NAMES = {TISSUE: "tissue", SALINE: "saline", ELECTRODE: "electrode", HOLDER: "holder"}
CATHETER_8FR_DIAMETER = 8.0 / 3.0 * 1e-3  # 8 French = 8/3 mm
CATHETER_TIP_LENGTH = 3.5e-3


@dataclass(frozen=True)
class Electrode:
    """An axisymmetric electrode pressed along its axis into the tissue.

    Attributes:
        kind: "ball" (sphere) or "catheter" (cylinder with a hemispherical end).
        radius: sphere or catheter radius [m].
        length: catheter electrode length including the dome [m] (ignored for a ball).
        indentation: depth of the lowest point below the tissue surface [m].
        holder_radius: radius of the insulating body above (sleeve or shaft) [m].
        material: the electrode's material (thermal properties).
        active_in_saline: whether the surface facing the saline conducts.
        label: name in reports.
    """

    kind: str
    radius: float
    length: float
    indentation: float
    holder_radius: float
    material: laws.Material
    active_in_saline: bool
    label: str

    def __post_init__(self) -> None:
        if self.kind not in ("ball", "catheter"):
            raise UserInputError(f"Electrode.kind must be 'ball' or 'catheter', got {self.kind!r}")
        if not 0.05e-3 <= self.indentation <= self.radius:
            raise UserInputError(
                f"indentation must be between 0.05 mm and the electrode radius {self.radius * 1e3:.3f} mm, "
                f"got {self.indentation * 1e3:.3f} mm")
        if self.kind == "catheter" and self.length <= self.radius:
            raise UserInputError(f"catheter electrode length must exceed its radius, got {self.length}")
        if self.holder_radius < self.radius:
            raise UserInputError("holder_radius must be at least the electrode radius")

    @property
    def centre_height(self) -> float:
        """z of the sphere's (dome's) centre [m]."""
        return self.radius - self.indentation

    @property
    def top_height(self) -> float:
        """z of the electrode's top: the ball's top, or the catheter electrode's end [m]."""
        if self.kind == "ball":
            return self.centre_height + self.radius
        return self.centre_height + self.length - self.radius

    @property
    def contact_radius(self) -> float:
        """Radius of the contact circle on the tissue surface [m]."""
        return math.sqrt(self.radius**2 - self.centre_height**2)

    @property
    def contact_area(self) -> float:
        """Area of the electrode surface inside the tissue (a spherical cap, 2 pi R h) [m^2]."""
        return 2.0 * math.pi * self.radius * self.indentation

    def inside(self, r, z):
        """Whether points lie inside the electrode."""
        r, z = np.asarray(r), np.asarray(z)
        zc = self.centre_height
        sphere = r**2 + (z - zc) ** 2 < self.radius**2
        if self.kind == "ball":
            return sphere
        return (sphere & (z <= zc)) | ((z > zc) & (z < self.top_height) & (r < self.radius))

    def inside_holder(self, r, z):
        """Whether points lie in the insulating body above the electrode."""
        r, z = np.asarray(r), np.asarray(z)
        if self.kind == "ball":
            return (r < self.holder_radius) & (z > self.centre_height) & ~self.inside(r, z)
        return (r < self.holder_radius) & (z >= self.top_height)

    def outline(self, n: int = 400) -> list[np.ndarray]:
        """Dense polylines (k, 2) of the electrode's and holder's boundaries, in (r, z) [m]."""
        zc, a = self.centre_height, self.radius
        curves = []
        # Arcs split at the contact circle (and the ball's equator) so that those points are nodes.
        th_contact = math.asin(-zc / a)
        if self.kind == "ball":
            for lo, hi in ((-np.pi / 2, th_contact), (th_contact, 0.0), (0.0, np.pi / 2)):
                th = np.linspace(lo, hi, n)
                curves.append(np.c_[a * np.cos(th), zc + a * np.sin(th)])
            rh = self.holder_radius
            if rh > a * (1 + 1e-9):
                curves.append(np.c_[np.linspace(a, rh, n // 8), np.full(n // 8, zc)])
            return curves + [self._holder_side(rh, zc, n)]
        for lo, hi in ((-np.pi / 2, th_contact), (th_contact, 0.0)):
            th = np.linspace(lo, hi, n)
            curves.append(np.c_[a * np.cos(th), zc + a * np.sin(th)])
        curves.append(np.c_[np.full(n, a), np.linspace(zc, self.top_height, n)])
        curves.append(np.c_[np.linspace(0.0, a, n // 2), np.full(n // 2, self.top_height)])
        return curves + [self._holder_side(self.holder_radius, self.top_height, n)]

    def _holder_side(self, rh: float, z0: float, n: int) -> np.ndarray:
        # Ends a little inside the outer arc; the arc's own points close it.
        return np.c_[np.full(n, rh), np.linspace(z0, 1.0, n)]


def ball_chain_tip(indentation: float = 1.0e-3, chain: BallChain | None = None,
                   sleeve: Sleeve | None = None) -> Electrode:
    """The ball chain's tip ball, insulated by shrink wrap except where it touches tissue."""
    chain = chain or BallChain()
    sleeve = sleeve or Sleeve()
    return Electrode(kind="ball", radius=chain.ball_diameter / 2.0, length=chain.ball_diameter,
                     indentation=indentation, holder_radius=sleeve.outer_diameter / 2.0,
                     material=laws.NDFEB, active_in_saline=False, label="ball chain")


def catheter_8fr(indentation: float = 1.0e-3) -> Electrode:
    """A standard 8 Fr ablation catheter's 3.5 mm tip electrode, perpendicular to the tissue."""
    radius = CATHETER_8FR_DIAMETER / 2.0
    return Electrode(kind="catheter", radius=radius, length=CATHETER_TIP_LENGTH, indentation=indentation,
                     holder_radius=radius, material=laws.PLATINUM_IRIDIUM, active_in_saline=True,
                     label="standard 8 Fr catheter")


@dataclass
class AblationMesh:
    """The triangulated (r, z) half disc with its domains.

    Attributes:
        mesh: skfem MeshTri (coordinates in m).
        domain: (n_elements,) domain index per triangle (TISSUE, SALINE, ELECTRODE, HOLDER).
        active_nodes: nodes of the conducting electrode surface.
        ground_nodes: nodes on the outer arc.
        electrode: the electrode.
        outer_radius: [m].
        h: mesh spacing near the electrode [m].
    """

    mesh: MeshTri
    domain: np.ndarray
    active_nodes: np.ndarray
    ground_nodes: np.ndarray
    electrode: Electrode
    outer_radius: float
    h: float

    @property
    def n_nodes(self) -> int:
        return self.mesh.p.shape[1]

    def nodes_of(self, *domains: int) -> np.ndarray:
        """Nodes of the triangles in the given domains."""
        return np.unique(self.mesh.t[:, np.isin(self.domain, domains)])

    @functools.cached_property
    def tissue_edges(self) -> np.ndarray:
        """(2, m) the edges of the tissue's triangles, each once (node pairs, sorted; computed once)."""
        t = self.mesh.t[:, self.domain == TISSUE]
        return np.unique(np.sort(np.hstack([t[[0, 1]], t[[1, 2]], t[[0, 2]]]), axis=0), axis=1)

    @functools.cached_property
    def tissue_nodes(self) -> np.ndarray:
        """The nodes of the tissue's triangles (computed once)."""
        return self.nodes_of(TISSUE)


def _resample(curve: np.ndarray, size, ) -> np.ndarray:
    """Points along a dense polyline spaced by the local mesh size ``size(points)``."""
    seg = np.linalg.norm(np.diff(curve, axis=0), axis=1)
    mid = 0.5 * (curve[1:] + curve[:-1])
    count = np.concatenate([[0.0], np.cumsum(seg / size(mid))])
    m = max(1, int(round(count[-1])))
    targets = np.linspace(0.0, count[-1], m + 1)
    return np.c_[np.interp(targets, count, curve[:, 0]), np.interp(targets, count, curve[:, 1])]


def build_mesh(electrode: Electrode, h: float = 0.1e-3, outer_radius: float = 30e-3,
               fine_radius: float = 5e-3, growth: float = 0.2, h_max: float = 3e-3) -> AblationMesh:
    """Triangulate the half disc around ``electrode``.

    Args:
        electrode: the electrode geometry.
        h: spacing within ``fine_radius`` of the contact point [m].
        outer_radius: radius of the dispersive electrode / far field [m].
        fine_radius: radius of the uniformly fine zone [m].
        growth: spacing growth per unit distance beyond the fine zone.
        h_max: largest spacing [m].
    """
    if not 0 < h <= 1e-3:
        raise UserInputError(f"mesh spacing h must be in (0, 1 mm], got {h}")

    def size(p):
        rho = np.hypot(p[..., 0], p[..., 1])
        return np.minimum(h_max, h + growth * np.maximum(rho - fine_radius, 0.0))

    R = outer_radius
    th = np.linspace(-np.pi / 2, np.pi / 2, 4000)
    arc = np.c_[R * np.cos(th), R * np.sin(th)]
    axis = np.c_[np.zeros(4000), np.linspace(-R, R, 4000)]
    rc = electrode.contact_radius
    surface = np.c_[np.linspace(rc, R, 4000), np.zeros(4000)]
    outline = electrode.outline()
    # The holder's side ends where it meets the arc.
    side = outline[-1]
    z_end = math.sqrt(R**2 - side[0, 0] ** 2)
    outline[-1] = np.c_[side[:, 0], np.linspace(side[0, 1], z_end, len(side))]
    curves = [arc, axis, surface] + outline
    sampled = [_resample(c, size) for c in curves]
    ends = np.vstack([c[[0, -1]] for c in sampled])
    curve_pts = np.vstack([ends] + sampled)

    # Interior points: a hexagonal lattice in the fine zone, rings beyond it.
    rows = np.arange(-fine_radius, fine_radius + h, h * math.sqrt(3) / 2)
    lattice = []
    for i, z in enumerate(rows):
        r = np.arange(0.0, fine_radius + h, h) + (h / 2 if i % 2 else 0.0)
        lattice.append(np.c_[r, np.full_like(r, z)])
    lattice = np.vstack(lattice)
    lattice = lattice[np.hypot(lattice[:, 0], lattice[:, 1]) < fine_radius]
    rings, rho = [], fine_radius
    while True:
        step = float(size(np.array([rho, 0.0])))
        rho += step
        if rho > R - 0.5 * step:
            break
        n = max(3, int(math.ceil(math.pi * rho / step)))
        t = np.linspace(-np.pi / 2, np.pi / 2, n + 1)[1:-1]
        rings.append(np.c_[rho * np.cos(t), rho * np.sin(t)])
    interior = np.vstack([lattice] + rings)
    # Keep interior points clear of the curves so that each curve becomes a chain of edges.
    dense = np.vstack([c for c in curves])
    dist, _ = cKDTree(dense).query(interior)
    keep = (dist > 0.5 * size(interior)) & (np.hypot(interior[:, 0], interior[:, 1]) < R)
    points = np.vstack([curve_pts, interior[keep]])
    points = points[(points[:, 0] >= -1e-12) & (np.hypot(points[:, 0], points[:, 1]) <= R * (1 + 1e-12))]
    points[:, 0] = np.maximum(points[:, 0], 0.0)
    # Merge points closer than a quarter spacing (shared curve ends), keeping the first listed.
    drop = np.zeros(len(points), dtype=bool)
    for i, j in sorted(cKDTree(points).query_pairs(0.25 * h)):
        if not drop[i] and not drop[j]:
            drop[j] = True
    points = points[~drop]

    tri = Delaunay(points)
    t = tri.simplices
    p = points
    e1, e2 = p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    t = t[area > 1e-8 * size(p[t].mean(axis=1)) ** 2]
    centroid = p[t].mean(axis=1)
    domain = np.where(centroid[:, 1] < 0.0, TISSUE, SALINE)
    domain[electrode.inside_holder(centroid[:, 0], centroid[:, 1])] = HOLDER
    domain[electrode.inside(centroid[:, 0], centroid[:, 1])] = ELECTRODE
    mesh = MeshTri(p.T.copy(), t.T.copy())

    conducting = np.unique(mesh.t[:, np.isin(domain, (TISSUE, SALINE))])
    on_electrode = np.unique(mesh.t[:, domain == ELECTRODE])
    interface = np.intersect1d(conducting, on_electrode)
    if not electrode.active_in_saline:
        interface = interface[p[interface, 1] <= 1e-9 * h]
    ground = np.flatnonzero(np.hypot(p[:, 0], p[:, 1]) > R * (1 - 1e-9))
    return AblationMesh(mesh=mesh, domain=domain, active_nodes=interface, ground_nodes=ground,
                        electrode=electrode, outer_radius=R, h=h)
