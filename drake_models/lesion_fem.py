"""Axisymmetric electro-thermal finite-element model of an RF ablation lesion (scikit-fem, P1).

The (r, z) half plane, z up, the undeformed tissue surface at z = 0, tissue below, 0.9 % saline
above (a domain for both the current and the heat: the paper's bath has no flow and no
irrigation). The electrode is pressed ``indentation`` into the tissue along the axis; the tissue
is taken to conform to it (flat surface around the contact, no dimple). The whole domain is a
half disc of radius ``outer_radius`` whose arc is the dispersive electrode (V = 0) and the bath
at its initial temperature (the far field: 30 mm away, beyond the reach of 90 s of diffusion).

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

Physics (laws in ``drake_models/tissue.py``): the quasi-static potential div(sigma(T) grad V) = 0
with V = V_gen on the active electrode surface, V = 0 at the dispersive electrode, insulation
elsewhere; the generator in constant-power mode sets V_gen each step so that V^2 G(T) = P.
Pennes' bioheat without perfusion (ex vivo): rho c dT/dt = div(k(T) grad T) + sigma |grad V|^2
in every domain (the electrode and holder conduct heat but carry no current). Implicit Euler,
conductivities lagged one step. The Arrhenius integral Omega at the nodes; the lesion is
Omega >= 1 and, beside it, the tissue that reached 50 C.

Mesh: a Delaunay triangulation (scipy) of points placed on every boundary and interface curve
and in the domains (a hexagonal lattice of spacing ``h`` within 5 mm of the contact, rings
growing away from it), so every curve is a chain of mesh edges.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import Delaunay, cKDTree
from skfem import BilinearForm, CellBasis, ElementTriP1, LinearForm, MeshTri, asm
from skfem.helpers import dot, grad

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


@BilinearForm
def _diffusion(u, v, w):
    return w.coef * dot(grad(u), grad(v)) * w.x[0]


@BilinearForm
def _mass(u, v, w):
    return w.coef * u * v * w.x[0]


@LinearForm
def _source(v, w):
    return w.q * v * w.x[0]


class ElectroThermalModel:
    """Material fields and FE operators on an ``AblationMesh`` for one tissue.

    Args:
        mesh: the triangulation.
        tissue_material: tissue properties (``tissue.MYOCARDIUM`` ...).
        saline: the bath's properties.
    """

    def __init__(self, mesh: AblationMesh, tissue_material: laws.Material = laws.MYOCARDIUM,
                 saline: laws.Material = laws.SALINE):
        self.am = mesh
        self.basis = CellBasis(mesh.mesh, ElementTriP1())
        self.materials = {TISSUE: tissue_material, SALINE: saline, ELECTRODE: mesh.electrode.material,
                          HOLDER: laws.POLYMER}
        nqp = self.basis.X.shape[1]
        self._dom = np.repeat(mesh.domain[:, None], nqp, axis=1)
        rho_c = np.zeros_like(self._dom, dtype=float)
        for d, mat in self.materials.items():
            rho_c[self._dom == d] = mat.volumetric_heat_capacity
        # Lumped (row-sum) heat capacity: with the consistent matrix, implicit Euler at small
        # steps undershoots the initial temperature and leaks heat to the far boundary at once.
        self.mass = sp.diags(np.asarray(asm(_mass, self.basis, coef=rho_c).sum(axis=1)).ravel()).tocsr()
        # Nodes touched by no conducting triangle carry no equation: fix them (at 0).
        live = [d for d in (TISSUE, SALINE) if self.materials[d].electrical_conductivity > 0]
        conducting = np.unique(mesh.mesh.t[:, np.isin(mesh.domain, live)])
        isolated = np.setdiff1d(np.arange(mesh.n_nodes), conducting)
        self.electric_fixed = np.unique(np.concatenate([mesh.active_nodes, mesh.ground_nodes, isolated]))
        self.electric_boundary = np.zeros(mesh.n_nodes)
        self.electric_boundary[mesh.active_nodes] = 1.0

    def _field(self, law, temperature_C):
        t_q = np.asarray(self.basis.interpolate(temperature_C))
        out = np.zeros_like(t_q)
        for d, mat in self.materials.items():
            sel = self._dom == d
            out[sel] = law(mat, t_q[sel])
        return out

    def sigma(self, temperature_C) -> np.ndarray:
        """sigma at the quadrature points (n_elements, n_qp) [S/m]; 0 in the electrode and holder."""
        out = self._field(laws.electrical_conductivity, temperature_C)
        out[(self._dom == ELECTRODE) | (self._dom == HOLDER)] = 0.0
        return out

    def unit_potential(self, temperature_C):
        """Potential for 1 V on the electrode and the load's conductance.

        Returns:
            (u (n_nodes,), conductance G [S], sigma |grad u|^2 at quadrature points [W/m^3 per V^2]).
        """
        sigma = self.sigma(temperature_C)
        A = asm(_diffusion, self.basis, coef=sigma)
        u = np.zeros(self.am.n_nodes)
        u[:] = self.electric_boundary
        free = np.setdiff1d(np.arange(self.am.n_nodes), self.electric_fixed)
        rhs = -(A[free][:, self.electric_fixed] @ u[self.electric_fixed])
        u[free] = spla.spsolve(A[free][:, free].tocsc(), rhs)
        g = self.basis.interpolate(u).grad
        density = sigma * (g[0] ** 2 + g[1] ** 2)
        conductance = 2.0 * math.pi * float(u @ (A @ u))
        return u, conductance, density

    def thermal_stiffness(self, temperature_C):
        """Conduction matrix with k(T) (r-weighted)."""
        return asm(_diffusion, self.basis, coef=self._field(laws.thermal_conductivity, temperature_C))

    def joule_load(self, density_W_m3):
        """Load vector of a heat source given at quadrature points (r-weighted)."""
        return asm(_source, self.basis, q=density_W_m3)


@dataclass
class LesionSimulation:
    """Result of ``simulate``: histories (per step) and fields (per node) in SI and C.

    Attributes:
        times: (n,) step end times [s].
        power: (n,) delivered power [W] (the Joule integral of the solved field).
        voltage: (n,) electrode voltage [V rms].
        impedance: (n,) load impedance [Ohm].
        max_tissue_C, max_electrode_C: (n,) peak temperatures [C].
        mean_electrode_C: (n,) the electrode's volume-mean temperature (the magnet's bulk) [C].
        limited: (n,) whether the cut-off at vaporisation reduced the power that step.
        snapshots: {time: temperature (n_nodes,)} at the requested output times.
        damage: (n_nodes,) Omega at the end.
        peak_temperature: (n_nodes,) highest temperature each node reached [C].
        growth: rows {t_s, width_mm, depth_mm, ...} at the output times.
        energy_delivered_J, energy_stored_J: electric energy in, heat stored at the end [J].
        energy_boundary_J: heat into the far boundary (conduction and the Joule heat of the
            elements at the dispersive electrode) [J].
    """

    mesh: AblationMesh
    times: np.ndarray
    power: np.ndarray
    voltage: np.ndarray
    impedance: np.ndarray
    max_tissue_C: np.ndarray
    max_electrode_C: np.ndarray
    mean_electrode_C: np.ndarray
    limited: np.ndarray
    snapshots: dict
    damage: np.ndarray
    peak_temperature: np.ndarray
    final_temperature: np.ndarray
    growth: list
    energy_delivered_J: float
    energy_stored_J: float
    energy_boundary_J: float
    vaporisation_time_s: float | None
    info: dict = field(default_factory=dict)


def lesion_extent(am: AblationMesh, values: np.ndarray, threshold: float) -> dict:
    """Width, depth and surface diameter of the tissue region where ``values`` >= ``threshold``.

    Exact for the piecewise-linear interpolant: the region's extreme points are nodes above the
    threshold or crossings on tissue edges.

    Returns:
        {"width_mm": 2 max r, "depth_mm": max -z (from the tissue surface), "surface_diameter_mm"}.
    """
    p = am.mesh.p
    t = am.mesh.t[:, am.domain == TISSUE]
    edges = np.unique(np.sort(np.hstack([t[[0, 1]], t[[1, 2]], t[[0, 2]]]), axis=0), axis=1)
    va, vb = values[edges[0]], values[edges[1]]
    cross = (va - threshold) * (vb - threshold) < 0
    s = (threshold - va[cross]) / (vb[cross] - va[cross])
    pts = p[:, edges[0, cross]] + s * (p[:, edges[1, cross]] - p[:, edges[0, cross]])
    nodes = np.unique(t)
    inside = nodes[values[nodes] >= threshold]
    allp = np.hstack([pts, p[:, inside]])
    if allp.shape[1] == 0:
        return {"width_mm": 0.0, "depth_mm": 0.0, "surface_diameter_mm": 0.0}
    on_surface = np.abs(allp[1]) <= 1e-9 * am.h
    surf = float(2 * allp[0, on_surface].max()) if np.any(on_surface) else 0.0
    return {"width_mm": float(2e3 * allp[0].max()), "depth_mm": float(-1e3 * allp[1].min()),
            "surface_diameter_mm": 1e3 * surf}


def time_steps(duration: float, dt_max: float, dt_first: float = 0.05, growth: float = 1.2,
               breakpoints=()) -> np.ndarray:
    """Step end times: small first steps (the electrode edge heats within a second), then ``dt_max``.

    Every time in ``breakpoints`` (within the duration) is a step end.
    """
    marks = sorted(b for b in breakpoints if 0 < b < duration - 1e-9) + [duration]
    times, t, dt = [], 0.0, dt_first
    for mark in marks:
        while t < mark - 1e-9:
            dt = min(dt, dt_max)
            t = mark if t + dt > mark - 1e-3 * dt else t + dt
            times.append(t)
            dt *= growth
    return np.array(times)


def simulate(electrode: Electrode, *, power_W: float, duration_s: float, tissue_name: str = "myocardium",
             initial_temperature_C: float = 22.0, h: float = 0.1e-3, dt_max: float = 1.0,
             cooldown_s: float = 0.0, output_every_s: float = 5.0, max_voltage_V: float | None = None,
             limit_C: float | None = laws.VAPORISATION_ONSET_C,
             saline: laws.Material = laws.SALINE, mesh: AblationMesh | None = None,
             progress=None) -> LesionSimulation:
    """Run an RF application at constant power, then (optionally) let the tissue cool.

    Args:
        electrode: the electrode geometry.
        power_W: generator power [W].
        duration_s: RF time [s].
        tissue_name: "myocardium" or "liver".
        initial_temperature_C: tissue and bath temperature at t = 0 [C] (also the far field).
        h: mesh spacing near the electrode [m].
        dt_max: largest time step [s].
        cooldown_s: time after switch-off during which damage still accrues [s].
        output_every_s: spacing of the growth rows and snapshots [s].
        max_voltage_V: generator voltage limit [V rms], None for none.
        limit_C: the cut-off at vaporisation (``tissue.temperature_limited_voltage_squared``):
            the power is reduced so that no tissue or saline exceeds it; None: pure constant power.
        saline: the bath's properties.
        mesh: a prebuilt mesh for this electrode (else built with ``h``).
        progress: optional callable(n_steps_done, n_steps_total).
    """
    if power_W < 0 or not math.isfinite(power_W):
        raise UserInputError(f"power must be a finite number >= 0 W, got {power_W}")
    if duration_s <= 0 or not math.isfinite(duration_s):
        raise UserInputError(f"duration must be positive, got {duration_s}")
    material, arrhenius = laws.tissue(tissue_name)
    am = mesh or build_mesh(electrode, h=h)
    model = ElectroThermalModel(am, material, saline)
    n = am.n_nodes
    T = np.full(n, float(initial_temperature_C))
    T0 = T.copy()
    fixed = am.ground_nodes
    free = np.setdiff1d(np.arange(n), fixed)
    tissue_nodes = am.nodes_of(TISSUE)
    electrode_nodes = am.nodes_of(ELECTRODE)
    water_nodes = am.nodes_of(TISSUE, SALINE)
    el_t, el_w = _electrode_volume_weights(am)
    output_times = np.arange(output_every_s, duration_s + 1e-9, output_every_s)
    rf_times = time_steps(duration_s, dt_max, breakpoints=output_times)
    cool_times = duration_s + time_steps(cooldown_s, dt_max, dt_first=dt_max) if cooldown_s > 0 else np.array([])
    all_times = np.concatenate([rf_times, cool_times])
    outputs = set(np.round(output_times, 9)) | {round(duration_s, 9)}
    damage = np.zeros(n)
    rate_prev = arrhenius.rate(T)
    peak = T.copy()
    hist = {k: [] for k in ("power", "voltage", "impedance", "max_tissue", "max_electrode", "mean_electrode",
                            "limited")}
    snapshots, growth = {}, []
    energy = 0.0
    outflow = 0.0
    vaporised_at = None
    t_prev = 0.0
    for i, t in enumerate(all_times):
        dt = t - t_prev
        rf_on = t <= duration_s + 1e-9
        A, lu, base, T_next = _conduction_step(model, T, T0, dt, free, fixed)
        voltage, delivered, impedance, limited = 0.0, 0.0, float("nan"), False
        if rf_on and power_W > 0:
            T_next, voltage, delivered, impedance, limited, load = _joule_heating(
                model, T, T_next, lu, free, water_nodes, power_W, max_voltage_V, limit_C)
        else:
            load = np.zeros(n)
        # Heat into the far boundary's fixed nodes (their equations are replaced by T = T0):
        # conduction across the arc plus the Joule heat at the dispersive electrode.
        outflow += 2.0 * math.pi * dt * float(np.sum((load + base - A @ T_next)[fixed]))
        T = T_next
        energy += delivered * dt
        rate = arrhenius.rate(T)
        damage += 0.5 * (rate + rate_prev) * dt
        rate_prev = rate
        peak = np.maximum(peak, T)
        hist["power"].append(delivered)
        hist["voltage"].append(voltage)
        hist["impedance"].append(impedance)
        hist["max_tissue"].append(float(T[tissue_nodes].max()))
        hist["max_electrode"].append(float(T[electrode_nodes].max()))
        hist["limited"].append(limited)
        hist["mean_electrode"].append(float(el_w @ T[el_t].mean(axis=0)))
        if vaporised_at is None and hist["max_tissue"][-1] >= laws.VAPORISATION_ONSET_C:
            vaporised_at = float(t)
        if round(float(t), 9) in outputs:
            snapshots[float(t)] = T.copy()
            growth.append(_growth_row(am, float(t), damage, peak))
        if progress is not None:
            progress(i + 1, len(all_times))
        t_prev = t
    stored = 2.0 * math.pi * float(np.sum(model.mass @ (T - T0)))
    return LesionSimulation(
        mesh=am, times=all_times, power=np.array(hist["power"]), voltage=np.array(hist["voltage"]),
        impedance=np.array(hist["impedance"]), limited=np.array(hist["limited"]), max_tissue_C=np.array(hist["max_tissue"]),
        max_electrode_C=np.array(hist["max_electrode"]), mean_electrode_C=np.array(hist["mean_electrode"]), snapshots=snapshots, damage=damage,
        peak_temperature=peak, final_temperature=T, growth=growth, energy_delivered_J=energy,
        energy_stored_J=stored, energy_boundary_J=outflow, vaporisation_time_s=vaporised_at,
        info={"nodes": n, "elements": am.mesh.t.shape[1], "steps": len(all_times), "tissue": tissue_name,
              "initial_temperature_C": initial_temperature_C, "h_mm": am.h * 1e3})


def _electrode_volume_weights(am: AblationMesh):
    """The electrode's triangles (3, m) and their volume weights (r x area, summing to one): the
    weights of its bulk (mean) temperature."""
    el_t = am.mesh.t[:, am.domain == ELECTRODE]
    el_p = am.mesh.p[:, el_t]
    el_w = el_p[0].mean(axis=0) * 0.5 * np.abs((el_p[0, 1] - el_p[0, 0]) * (el_p[1, 2] - el_p[1, 0])
                                               - (el_p[0, 2] - el_p[0, 0]) * (el_p[1, 1] - el_p[1, 0]))
    return el_t, el_w / el_w.sum()


def _conduction_step(model: ElectroThermalModel, T, T0, dt: float, free, fixed):
    """One implicit (backward Euler) step of conduction alone from T, the far boundary held at T0.

    Returns:
        ``(A, lu, base, T_next)``: the step's matrix ``M / dt + K(T)``, the LU factors of its free
        block, the right-hand side ``M T / dt`` and the temperature without Joule heat.
    """
    K = model.thermal_stiffness(T)
    A = (model.mass / dt + K).tocsr()
    lu = spla.splu(A[free][:, free].tocsc())
    base = model.mass @ T / dt
    T_next = T0.copy()
    T_next[free] = lu.solve(base[free] - A[free][:, fixed] @ T0[fixed])
    return A, lu, base, T_next


def _joule_heating(model: ElectroThermalModel, T, T_next, lu, free, water_nodes, power_W: float,
                   max_voltage_V: float | None, limit_C: float | None):
    """The step's Joule heat at constant power (voltage limit and cut-off at vaporisation), added
    to the conduction step's T_next (the temperature rise is linear in V^2, through ``lu``).

    Returns:
        ``(T_next, voltage [V rms], delivered [W], impedance [Ohm], limited, load (n_nodes,))``.
    """
    _, conductance, unit_density = model.unit_potential(T)
    impedance = 1.0 / conductance
    unit_load = model.joule_load(unit_density)
    rise = np.zeros(len(T))
    rise[free] = lu.solve(unit_load[free])
    v2_set = laws.constant_power_voltage(power_W, conductance, max_voltage_V) ** 2
    v2 = laws.temperature_limited_voltage_squared(v2_set, T_next[water_nodes], rise[water_nodes],
                                                  limit_C)
    limited = v2 < v2_set * (1 - 1e-12)
    voltage = math.sqrt(v2)
    T_next = T_next + v2 * rise
    # The load's integral (the shape functions sum to one): the Joule power delivered.
    delivered = 2.0 * math.pi * v2 * float(unit_load.sum())
    return T_next, voltage, delivered, impedance, limited, v2 * unit_load


def _growth_row(am: AblationMesh, t: float, damage, peak) -> dict:
    """The lesion's extent at time t: Omega >= 1 (``omega_*``) and the 50 C isotherm (``iso50_*``)."""
    row = {"t_s": t}
    for key, ext in (("omega", lesion_extent(am, damage, 1.0)),
                     ("iso50", lesion_extent(am, peak, laws.LESION_ISOTHERM_C))):
        row.update({f"{key}_{k}": v for k, v in ext.items()})
    return row


def joule_share(am: AblationMesh, temperature_C=None, tissue_material: laws.Material = laws.MYOCARDIUM) -> dict:
    """Fractions of the Joule power dissipated in the tissue and in the saline (at uniform 22 C by default)."""
    model = ElectroThermalModel(am, tissue_material)
    temperature = np.full(am.n_nodes, 22.0) if temperature_C is None else temperature_C
    _, _, density = model.unit_potential(temperature)
    weights = np.asarray(model.basis.dx) * np.asarray(model.basis.interpolate(am.mesh.p[0]))
    per_element = (density * weights).sum(axis=1)
    total = per_element.sum()
    return {DOMAIN_NAMES[d]: float(per_element[am.domain == d].sum() / total) for d in (TISSUE, SALINE)}


def electrode_resistance(am: AblationMesh, sigma: float, saline_sigma: float | None = None) -> float:
    """The electrode's resistance to the ground arc with uniform conductivities [Ohm].

    The check against the analytic spreading resistance: ``saline_sigma = 0`` insulates the
    tissue surface (a half space); None gives the saline ``sigma`` too.
    """
    def uniform(s):
        return laws.Material(name="uniform", electrical_conductivity=s, sigma_temperature_coefficient=0.0,
                             thermal_conductivity=1.0, k_temperature_slope=0.0, density=1.0, specific_heat=1.0)

    model = ElectroThermalModel(am, uniform(sigma), uniform(sigma if saline_sigma is None else saline_sigma))
    _, conductance, _ = model.unit_potential(np.full(am.n_nodes, 37.0))
    return 1.0 / conductance
