"""A procedural left atrium (LA): chamber, pulmonary-vein ostia, septal puncture, ablation rings.

Frame H of the heart (used as the world frame W of the chain simulations), origin at the LA
centre: +x from the patient's right to left (transverse), +y from posterior to anterior, +z
from inferior to superior. The LA is modelled as an ellipsoid (the endocardial surface) with a
wall of uniform thickness grown outwards, four pulmonary veins (PVs) leaving its posterior wall
as short tubes, and a transseptal sheath entering through the right (septal) wall.

Default dimensions and where they come from (adult, normal-size LA; all are parameters):

* Antero-posterior diameter 38 mm: the echocardiographic LA AP diameter is normally < 40 mm
  (ASE/EACVI chamber quantification, Lang et al., J Am Soc Echocardiogr 28:1, 2015).
* Transverse (medial-lateral) 54 mm and supero-inferior 48 mm: CT/MRI LA diameters of about
  45-60 mm and 40-55 mm (e.g. Ho, Cabrera, Sanchez-Quintana, "Left atrial anatomy revisited",
  Circ Arrhythm Electrophysiol 5:220, 2012). The enclosed volume, about 52 ml, is in the normal
  range of LA maximal volume (about 40-70 ml).
* Wall 2.5 mm: the LA wall is mostly 1.5-3 mm thick (Ho et al. 2012; Beinart et al., J
  Cardiovasc Electrophysiol 22:1232, 2011).
* PV ostia 14-17 mm: CT ostial diameters are about 12-20 mm, superior veins larger than the
  inferior ones (Kato et al., Circulation 107:2004, 2003). Our defaults sit in the lower half
  so that the ipsilateral ostia are 3-5 mm apart (the carina) and the rings fit on the wall.
* The left veins leave the posterolateral wall, the right veins the posteromedial wall, the
  superior veins above the inferior ones; the carina is the wall ridge between ipsilateral
  ostia. The septal puncture is on the right (septal) wall, slightly anterior and inferior
  (fossa ovalis), and the left veins lie "directly in front of the septal puncture" (paper,
  Sec. V-D).
* Ablation targets: closed rings of 20 (left) and 18 (right) 5 mm targets that encircle the
  ipsilateral vein pairs (wide-area circumferential ablation), equally spaced along the curve
  where the endocardium leaves the convex hull of two balls centred on the ostia, of radius
  (ostium radius + ``ring_margin``): at least ``ring_margin`` from every ostium's edge. The
  paper reports path lengths of 115 mm (left) and 95 mm (right) on its phantom; ours are
  computed and reported (``ring_path_lengths``: 120.5 mm and 110.9 mm with the defaults, 6.0
  and 6.2 mm between targets), never tuned to match.
* Openings: the ostia and a ``puncture_diameter`` hole for the sheath are cut out of the wall;
  the veins are open tubes ``vein_length`` long.

These anatomical sources are quoted from general knowledge of the literature; the numbers are
typical values, not a fit to any one of them.

Everything is generated on demand into a cache directory (see ``model_files.cache_dir``): a
tetrahedral wall (VTK, ``wall_layers`` layers through the thickness) for compliant-hydroelastic
contact, and a finer closed visual surface (OBJ).
"""

from __future__ import annotations

import functools
import hashlib
import sys
from dataclasses import asdict, dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models import paper
from ballchain.drake_models.model_files import cache_dir, cached_files, source_hash
from ballchain.infrastructure.arg_checks import as_vector, require_int, require_type
from ballchain.infrastructure.errors import UserInputError, require_finite_fields

PV_NAMES = ("LSPV", "LIPV", "RSPV", "RIPV")


@dataclass(frozen=True)
class HeartParams:
    """Parameters of the procedural left atrium (SI units, frame H described in the module).

    Attributes:
        semi_axes: (3,) endocardial semi-axes along x (transverse), y (AP), z (SI) [m].
        wall_thickness: [m].
        wall_layers: tetrahedra layers through the wall (>= 2 for hydroelastic pressure).
        subdivisions: icosphere subdivisions of the collision wall (3: edges of about 3 mm;
            each compliant tetrahedron costs Drake about 0.1 ms to set up, twice per run).
        visual_subdivisions: icosphere subdivisions of the visual surface (OBJ).
        vein_segments: segments around each vein tube of the collision wall.
        vein_max_edge: longest axial edge of the vein tubes of the collision wall [m].
        pv_directions: directions from the LA centre to the LSPV, LIPV, RSPV, RIPV ostia.
        pv_diameters: ostial diameters of the LSPV, LIPV, RSPV, RIPV [m].
        vein_length: length of each vein tube outside the wall [m].
        ring_margin: distance from the ostia's edges to the ablation ring [m].
        n_left_targets: targets around the left veins.
        n_right_targets: targets around the right veins.
        target_diameter: [m].
        puncture_direction: direction from the LA centre to the septal puncture.
        sheath_aim: point the transseptal sheath points to, in H [m].
        sheath_extension: how far the sheath reaches into the LA beyond the wall [m].
        puncture_diameter: diameter of the hole cut in the septal wall for the sheath [m].
        scale: multiplies every length (semi-axes, wall, veins, margins, sheath extension).
    """

    semi_axes: tuple[float, float, float] = (27e-3, 19e-3, 24e-3)
    wall_thickness: float = 2.5e-3
    wall_layers: int = 2
    subdivisions: int = 3
    visual_subdivisions: int = 4
    vein_segments: int = 20
    vein_max_edge: float = 3e-3
    pv_directions: tuple = ((0.8, -0.5, 0.55), (0.8, -0.5, -0.55), (-0.45, -0.8, 0.45), (-0.45, -0.8, -0.45))
    pv_diameters: tuple[float, float, float, float] = (17e-3, 15e-3, 16e-3, 14e-3)
    vein_length: float = 12e-3
    ring_margin: float = 5e-3
    n_left_targets: int = 20
    n_right_targets: int = 18
    target_diameter: float = 5e-3
    puncture_direction: tuple[float, float, float] = (-1.0, 0.3, -0.25)
    sheath_aim: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sheath_extension: float = 3e-3
    puncture_diameter: float = 6e-3
    scale: float = 1.0

    def __post_init__(self) -> None:
        as_vector(self.semi_axes, "HeartParams.semi_axes", unit="m")
        for name in ("wall_layers", "subdivisions", "visual_subdivisions"):
            require_int(getattr(self, name), f"HeartParams.{name}", 1)
        require_finite_fields(self)
        if len(self.semi_axes) != 3 or min(self.semi_axes) <= 0:
            raise UserInputError(f"HeartParams.semi_axes must be 3 positive lengths, got {self.semi_axes}")
        if self.wall_layers < 2:
            raise UserInputError(
                f"HeartParams.wall_layers must be >= 2 (a one-layer shell has no pressure inside), "
                f"got {self.wall_layers}"
            )
        if not 0 < self.wall_thickness < 0.5 * min(self.semi_axes):
            raise UserInputError(f"HeartParams.wall_thickness {self.wall_thickness} m is not plausible")
        if len(self.pv_directions) != 4 or len(self.pv_diameters) != 4:
            raise UserInputError("HeartParams needs 4 PV directions and diameters (LSPV, LIPV, RSPV, RIPV)")
        for name in ("subdivisions", "visual_subdivisions"):
            if not 1 <= getattr(self, name) <= 6:
                raise UserInputError(f"HeartParams.{name} must be in 1..6, got {getattr(self, name)}")
        if self.scale <= 0:
            raise UserInputError(f"HeartParams.scale must be positive, got {self.scale}")

    def key(self) -> str:
        """A short hash of the parameters and of the code that makes the meshes, naming the
        generated files."""
        code = source_hash(sys.modules[__name__], mt)
        return hashlib.sha1((repr(sorted(asdict(self).items())) + code).encode()).hexdigest()[:12]


@dataclass
class Ostium:
    """A pulmonary vein ostium: centre on the endocardial surface, outward axis, diameter (SI)."""

    name: str
    p_HO: np.ndarray
    axis_H: np.ndarray
    diameter: float
    tube_start: float = 0.0  # where the vein tube starts along the axis, from p_HO [m]


@dataclass
class TargetRing:
    """Ablation targets encircling a pair of veins: ordered, closed ring on the endocardium."""

    name: str
    p_HT: np.ndarray  # (n, 3) target centres [m]
    curve_length: float  # length of the smooth ring curve [m]
    polygon_length: float  # sum of the straight segments between consecutive targets [m]
    spacing: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (n,) centre-to-centre [m]


HULL_BALLS = 101  # balls along the segment between two ostia whose union is a target ring's hull
HULL_WINDOW = 8  # balls on each side of the nearest point of the continuous hull that are measured


def _hull_distance(centres: np.ndarray, radii: np.ndarray, x: np.ndarray, window: int = HULL_WINDOW) -> np.ndarray:
    """min over the balls (centres (k, 3), radii (k,)) of |x - c| - r for points x (n, 3): < 0
    inside their union. The balls are sampled along a segment with linearly varying radius, where
    f(s) = |x - c(s)| - r(s) is convex in the arc length s: the smallest sample lies next to f's
    continuous minimiser s* = a + kappa b / sqrt(1 - kappa^2) (a, b: x's coordinates along and
    across the segment, kappa = dr/ds), so only the ``window`` balls on each side of s* are
    measured, with the very arithmetic of measuring them all (the same floats:
    tests/test_heart.py). Without a window (0), or when one ball holds another (|kappa| >= 1),
    every ball is measured."""
    n_balls = len(centres)
    axis = centres[-1] - centres[0]
    length = float(np.sqrt(axis @ axis))
    kappa = (radii[-1] - radii[0]) / length if length > 0 else np.inf
    if window <= 0 or not abs(kappa) < 1.0 or 2 * window + 1 >= n_balls:
        return (np.linalg.norm(x[:, None, :] - centres[None], axis=2) - radii).min(axis=1)
    e = axis / length
    u = x - centres[0]
    a = u @ e
    b = np.sqrt(np.maximum((u * u).sum(axis=1) - a * a, 0.0))
    nearest = np.rint((a + kappa * b / np.sqrt(1.0 - kappa * kappa)) / length * (n_balls - 1))
    first = np.clip(nearest.astype(np.int64) - window, 0, n_balls - 1 - 2 * window)
    idx = first[:, None] + np.arange(2 * window + 1)
    return (np.linalg.norm(x[:, None, :] - centres[idx], axis=2) - radii[idx]).min(axis=1)


def _ellipsoid_radial_hit(directions: np.ndarray, semi_axes: np.ndarray) -> np.ndarray:
    """Where rays from the centre along ``directions`` (k, 3) meet the ellipsoid (k, 3)."""
    d = np.atleast_2d(directions)
    t = 1.0 / np.sqrt(((d / semi_axes) ** 2).sum(axis=1))
    return d * t[:, None]


def _ellipsoid_normals(p: np.ndarray, semi_axes: np.ndarray) -> np.ndarray:
    n = np.atleast_2d(p) / semi_axes**2
    return n / np.linalg.norm(n, axis=1)[:, None]


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


class LeftAtrium:
    """The procedural left atrium built from ``HeartParams`` (geometry and anatomical features).

    Implements ``drake_models.atrium.Atrium`` (as ``UserAtrium`` does).

    Attributes:
        params: the parameters (lengths already include ``scale``).
        ostia: the four Ostium, in PV_NAMES order.
        carinas: {"left", "right"}: (3,) carina point between ipsilateral ostia on the wall [m].
        rings: {"left", "right"}: TargetRing.
        p_HP: (3,) septal puncture on the endocardial surface [m].
        sheath_axis_H: (3,) unit direction of the transseptal sheath (into the LA).
        p_HE: (3,) sheath exit in the LA [m].
    """

    side = "lumen"  # the chain works inside the chamber (``drake_models.atrium.Atrium``)

    def __init__(self, params: HeartParams | None = None):
        if params is not None:
            require_type(params, HeartParams, "LeftAtrium params", "a HeartParams or None")
        params = params or HeartParams()
        s = params.scale
        if s != 1.0:
            params = replace(
                params,
                semi_axes=tuple(a * s for a in params.semi_axes),
                wall_thickness=params.wall_thickness * s,
                pv_diameters=tuple(d * s for d in params.pv_diameters),
                vein_length=params.vein_length * s,
                ring_margin=params.ring_margin * s,
                target_diameter=params.target_diameter * s,
                sheath_aim=tuple(a * s for a in params.sheath_aim),
                sheath_extension=params.sheath_extension * s,
                puncture_diameter=params.puncture_diameter * s,
                scale=1.0,
            )
        self.params = params
        self.semi_axes = np.asarray(params.semi_axes, float)
        self._build_features()

    # ----------------------------------------------------------------------------- features
    def _build_features(self) -> None:
        p, ax = self.params, self.semi_axes
        dirs = np.asarray(p.pv_directions, float)
        centres = _ellipsoid_radial_hit(dirs, ax)
        normals = _ellipsoid_normals(centres, ax)
        self.ostia = [
            Ostium(name, c, n, float(dia))
            for name, c, n, dia in zip(PV_NAMES, centres, normals, p.pv_diameters)
        ]
        for o in self.ostia:
            o.tube_start = self._tube_start(o)
        for i in range(4):
            for j in range(i + 1, 4):
                a, b = self.ostia[i], self.ostia[j]
                gap = np.linalg.norm(a.p_HO - b.p_HO) - 0.5 * (a.diameter + b.diameter)
                if gap < 2e-3:
                    raise UserInputError(
                        f"ostia {a.name} and {b.name} overlap or nearly touch (gap {gap * 1e3:.1f} mm): "
                        "change pv_directions or pv_diameters"
                    )
        self.carinas = {}
        for side, (i, j) in (("left", (0, 1)), ("right", (2, 3))):
            mid = 0.5 * (self.ostia[i].p_HO + self.ostia[j].p_HO)
            self.carinas[side] = _ellipsoid_radial_hit(mid, ax)[0]
        self.rings = {
            "left": self._ring("left", self.ostia[0], self.ostia[1], p.n_left_targets),
            "right": self._ring("right", self.ostia[2], self.ostia[3], p.n_right_targets),
        }
        self.p_HP = _ellipsoid_radial_hit(np.asarray(p.puncture_direction, float), ax)[0]
        axis = np.asarray(p.sheath_aim, float) - self.p_HP
        self.sheath_axis_H = axis / np.linalg.norm(axis)
        # The sheath crosses the wall at the puncture and reaches sheath_extension beyond it.
        self.p_HE = self.p_HP + p.sheath_extension * self.sheath_axis_H

    def _tube_start(self, o: Ostium) -> float:
        """Axial offset where the vein's cylinder meets the endocardium (median over its rim)."""
        helper = np.array([0.0, 0.0, 1.0]) if abs(o.axis_H[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = np.cross(o.axis_H, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(o.axis_H, e1)
        a = np.linspace(0, 2 * np.pi, 24, endpoint=False)
        rim = o.p_HO + 0.5 * o.diameter * (np.cos(a)[:, None] * e1 + np.sin(a)[:, None] * e2)
        # Solve |(rim + t axis) / semi_axes| = 1 for t (the root nearest 0).
        A = ((o.axis_H / self.semi_axes) ** 2).sum()
        B = 2 * ((rim / self.semi_axes) * (o.axis_H / self.semi_axes)).sum(axis=1)
        C = ((rim / self.semi_axes) ** 2).sum(axis=1) - 1.0
        t = (-B + np.sqrt(np.maximum(B * B - 4 * A * C, 0.0))) / (2 * A)
        return float(np.median(t))

    def _ring(self, name: str, o1: Ostium, o2: Ostium, n: int) -> TargetRing:
        """The ring where the endocardium leaves the convex hull of two balls centred on the
        ostia with radii (ostium radius + ring_margin): every ring point is ring_margin from the
        nearest ostium disc or further (3D distance), and it encircles both veins."""
        ax = self.semi_axes
        margin = self.params.ring_margin
        c1, c2 = o1.p_HO, o2.p_HO
        r1, r2 = 0.5 * o1.diameter + margin, 0.5 * o2.diameter + margin
        t = np.linspace(0.0, 1.0, HULL_BALLS)
        centres = c1 + t[:, None] * (c2 - c1)  # union of these balls = the hull of the end balls
        radii = r1 + t * (r2 - r1)
        inside_hull = functools.partial(_hull_distance, centres, radii)

        mid = _ellipsoid_radial_hit(0.5 * (c1 + c2), ax)[0]
        nrm = _ellipsoid_normals(mid, ax)[0]
        e1 = c1 - c2
        e1 -= nrm * (e1 @ nrm)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(nrm, e1)
        phi = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
        d = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
        lo = np.zeros(len(phi))
        hi = np.full(len(phi), 2.0 * ax.max())
        on_surface = lambda s: _ellipsoid_radial_hit(mid + s[:, None] * d, ax)  # noqa: E731
        if np.any(inside_hull(on_surface(hi)) < 0):
            raise UserInputError(f"the {name} ring does not close on the wall: reduce ring_margin or the ostia")
        for _ in range(50):  # bisection to well below a micrometre
            s_mid = 0.5 * (lo + hi)
            inside = inside_hull(on_surface(s_mid)) < 0
            lo = np.where(inside, s_mid, lo)
            hi = np.where(inside, hi, s_mid)
        dense = on_surface(0.5 * (lo + hi))
        seg = np.linalg.norm(np.roll(dense, -1, axis=0) - dense, axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        length = float(s[-1])
        # Start at the ring's most inferior point and go round at equal arc length.
        closed = np.vstack([dense, dense[:1]])
        i0 = int(np.argmin(dense[:, 2]))
        s_targets = (s[i0] + length * np.arange(n) / n) % length
        targets = np.stack([np.interp(s_targets, s, closed[:, k]) for k in range(3)], axis=1)
        targets = _ellipsoid_radial_hit(targets, ax)
        spacing = np.linalg.norm(np.roll(targets, -1, axis=0) - targets, axis=1)
        return TargetRing(name, targets, length, float(spacing.sum()), spacing)

    @property
    def ring_path_lengths(self) -> dict[str, float]:
        """Smooth ring lengths [m]: {"left": ..., "right": ...} (paper: 115 mm and 95 mm)."""
        return {k: r.curve_length for k, r in self.rings.items()}

    # ----------------------------------------------------------------------------- meshes
    def _closed_surface(self, subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
        U, F = mt.icosphere(subdivisions)
        return U * self.semi_axes, F

    @cached_property
    def closed_inner_surface(self) -> tuple[np.ndarray, np.ndarray]:
        """The endocardial ellipsoid without holes (V, F), outward (for inside tests)."""
        return self._closed_surface(self.params.subdivisions)

    def _holed_surface(self, subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
        """The endocardium with the four ostia and the septal puncture cut out (V, F)."""
        V, F = self._closed_surface(subdivisions)
        c = V[F].mean(axis=1)
        keep = np.ones(len(F), bool)
        for o in self.ostia:
            rel = c - o.p_HO
            along = rel @ o.axis_H
            radial = np.linalg.norm(rel - along[:, None] * o.axis_H, axis=1)
            keep &= ~((radial < 0.5 * o.diameter) & (along > -0.5 * o.diameter))
        # The transseptal puncture: a hole the sheath passes through.
        rel = c - self.p_HP
        along = rel @ self.sheath_axis_H
        radial = np.linalg.norm(rel - along[:, None] * self.sheath_axis_H, axis=1)
        keep &= ~((radial < 0.5 * self.params.puncture_diameter) & (np.abs(along) < 10e-3))
        return V, F[keep]

    @cached_property
    def inner_surface(self) -> tuple[np.ndarray, np.ndarray]:
        """The endocardium with its openings, at the collision resolution (V, F)."""
        return self._holed_surface(self.params.subdivisions)

    def _vein_tubes(self, n_around: int, max_edge: float):
        """Inner surfaces (V, F, N) of the four vein tubes, from the endocardium outward."""
        p = self.params
        for o in self.ostia:
            start = o.p_HO + o.tube_start * o.axis_H
            length = p.vein_length + p.wall_thickness - o.tube_start
            yield mt.cylinder_surface(start, o.axis_H, 0.5 * o.diameter, length, n_around, max_edge)

    def _wall(self, subdivisions: int, layers: int, n_around: int, max_edge: float):
        p = self.params
        V, F = self._holed_surface(subdivisions)
        N = _ellipsoid_normals(V, self.semi_axes)
        pieces = [mt.extrude_shell(V, F, N, p.wall_thickness, layers)]
        pieces += [mt.extrude_shell(cv, cf, cn, p.wall_thickness, layers)
                   for cv, cf, cn in self._vein_tubes(n_around, max_edge)]
        offsets = np.cumsum([0] + [len(v) for v, _ in pieces[:-1]])
        return (np.concatenate([v for v, _ in pieces]),
                np.concatenate([t + o for (_, t), o in zip(pieces, offsets)]))

    @cached_property
    def wall_tetrahedra(self) -> tuple[np.ndarray, np.ndarray]:
        """The wall with its vein tubes as one tetrahedral mesh (V (nv, 3) [m], T (nt, 4)), at
        the collision resolution (``subdivisions``, ``wall_layers``)."""
        p = self.params
        return self._wall(p.subdivisions, p.wall_layers, p.vein_segments, p.vein_max_edge)

    @cached_property
    def visual_surface(self) -> tuple[np.ndarray, np.ndarray]:
        """The wall's closed boundary at the visual resolution (V, F), outward."""
        p = self.params
        V, T = self._wall(p.visual_subdivisions, 1, 2 * p.vein_segments, 0.5 * p.vein_max_edge)
        F = mt.boundary_surface(V, T)
        used = np.unique(F)
        remap = np.zeros(len(V), int)
        remap[used] = np.arange(len(used))
        return V[used], remap[F]

    @cached_property
    def lumen_surface(self) -> tuple[np.ndarray, np.ndarray]:
        """The blood-side surfaces (endocardium with holes and the veins' inner walls)."""
        p = self.params
        V, F = self.inner_surface
        Vs, Fs = [V], [F]
        for cv, cf, _ in self._vein_tubes(p.vein_segments, p.vein_max_edge):
            Vs.append(cv)
            Fs.append(cf)
        offsets = np.cumsum([0] + [len(v) for v in Vs[:-1]])
        return np.concatenate(Vs), np.concatenate([f + o for f, o in zip(Fs, offsets)])

    @property
    def blood_surface(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (v, 3) [m], triangles (f, 3)) of the blood side: ``lumen_surface``."""
        return self.lumen_surface

    def lumen_contains(self, p_H: np.ndarray) -> np.ndarray:
        """Whether points (k, 3) [m] lie in the lumen of the collision mesh (the SDF's sign).

        The lumen is the inside of the faceted endocardium (``closed_inner_surface``: the same
        triangles as the wall, holes closed; ray parity) together with the inside of each vein's
        polygonal tube, from half a diameter below the ostium centre (the hole cut in the
        endocardium) to the tube's end. The facets, not the smooth ellipsoid, so that the sign
        changes exactly on the triangles the distance is measured to, and it does not flip at the
        ostia.
        """
        p_H = np.atleast_2d(np.asarray(p_H, float))
        V, F = self.closed_inner_surface
        return mt.points_inside_closed(V, F, p_H) | self.in_veins(p_H, outer=False)

    def lumen_grid_contains(self, origin: np.ndarray, spacing: float, shape: tuple[int, int, int]) -> np.ndarray:
        """``lumen_contains`` at every node of a grid (origin (3,) [m], spacing [m], shape) ->
        (nx, ny, nz) bool."""
        axes = [origin[k] + spacing * np.arange(shape[k]) for k in range(3)]
        P = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        return self.lumen_contains(P).reshape(shape)

    @property
    def lumen_key(self) -> str:
        """What the lumen test depends on besides the blood-side triangles (cache keys): the
        parameters (the vein tubes' polygons)."""
        return "procedural" + self.params.key()

    @cached_property
    def wall_distance(self) -> mt.SurfaceDistance:
        """Distance [m] from points to the blood-side surface: ``heart.wall_distance(p (k, 3))``."""
        return mt.SurfaceDistance(*self.lumen_surface)

    def contains(self, p_H: np.ndarray) -> np.ndarray:
        """Whether points (k, 3) [m] are inside the chamber (within its outer wall) or a vein."""
        p_H = np.atleast_2d(np.asarray(p_H, float))
        outer = self.semi_axes + self.params.wall_thickness
        return (((p_H / outer) ** 2).sum(axis=1) <= 1.0) | self.in_veins(p_H, outer=True)

    def in_veins(self, p_H: np.ndarray, outer: bool = False) -> np.ndarray:
        """Whether points (k, 3) [m] lie in a vein: the one rule of what a vein holds, for every
        containment test (``lumen_contains``: the SDF's sign; ``contains``: the watchdog's escape
        test).

        Along each vein's axis, from half a diameter below the ostium centre (where the hole is
        cut in the endocardium) to the tube's open end, ``vein_length + wall_thickness`` beyond
        the ostium centre (where ``_vein_tubes``' mesh ends); across it, inside the lumen of the
        tube's collision mesh (its regular polygon), or with ``outer`` within the tube's outer
        wall (radius plus the wall thickness, a circle: the wall's outside).
        """
        p_H = np.atleast_2d(np.asarray(p_H, float))
        tube_end = self.params.vein_length + self.params.wall_thickness
        inside = np.zeros(len(p_H), bool)
        for o in self.ostia:
            rel = p_H - o.p_HO
            along = rel @ o.axis_H
            span = (along > -0.5 * o.diameter) & (along < tube_end)
            if outer:
                radial = np.linalg.norm(rel - along[:, None] * o.axis_H, axis=1)
                inside |= span & (radial <= 0.5 * o.diameter + self.params.wall_thickness)
            else:
                inside |= span & _tube_polygon_inside(o, self.params.vein_segments, rel, along)
        return inside

    @property
    def volume(self) -> float:
        """Volume enclosed by the endocardial ellipsoid [m^3]."""
        return 4.0 / 3.0 * np.pi * float(np.prod(self.semi_axes))

    def write_files(self, directory: Path | None = None) -> dict[str, Path]:
        """Write the wall (VTK, collision) and its visual surface (OBJ); returns their paths.

        Files go to ``directory`` or to ``model_files.cache_dir()/heart_<key>``, and are reused
        when they already exist intact (``model_files.cached_files``).
        """
        def write(tmp: dict[str, Path]) -> None:
            mt.write_vtk_tetrahedra(tmp["vtk"], *self.wall_tetrahedra)
            mt.write_obj(tmp["obj"], *self.visual_surface)

        directory = Path(directory) if directory else cache_dir() / f"heart_{self.params.key()}"
        return cached_files(directory, {"vtk": "left_atrium_wall.vtk", "obj": "left_atrium_wall.obj"}, write)

    def summary_mm(self) -> dict:
        """Dimensions and features in mm (for reports)."""
        return {
            "diameters_mm": (2e3 * self.semi_axes).round(1).tolist(),
            "wall_mm": self.params.wall_thickness * 1e3,
            "volume_ml": round(self.volume * 1e6, 1),
            "ostia_mm": {o.name: round(o.diameter * 1e3, 1) for o in self.ostia},
            "ring_path_mm": {k: round(v * 1e3, 1) for k, v in self.ring_path_lengths.items()},
            "ring_polygon_mm": {k: round(r.polygon_length * 1e3, 1) for k, r in self.rings.items()},
            "target_spacing_mm": {
                k: [round(r.spacing.min() * 1e3, 2), round(r.spacing.max() * 1e3, 2)]
                for k, r in self.rings.items()
            },
            "paper_ring_path_mm": {k: v["path_mm"] for k, v in paper.TELEOP_TASKS.items()},
        }
