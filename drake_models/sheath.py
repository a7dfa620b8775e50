"""The transseptal sheath's path and the shaft's friction where it bears on the sheath's bends.

The catheter's shaft runs from the handle through the sheath to the sheath's exit in the left
atrium. Where the sheath is straight the shaft does not press on it (gravity and the lumen's
clearance neglected); where the sheath bends the shaft bears on its wall, with a normal force of
two parts (an elastic rod in a curved lumen of radius R, quasi-static):

* **The bend's ends**: the shaft, straight outside the bend and curved (moment EI / R) inside it,
  takes up the change of moment over a transition of order R: contact forces of about
  2 EI / R^2 at each end (the estimate the catheter module has used since the comparison arm was
  built: 4 EI / R^2 per bend).
* **Its tension** (the capstan): an axial force T along a curve of curvature 1/R presses the
  shaft on the wall with T / R per unit length, T d(theta) over an arc of angle d(theta), for
  tension and compression alike (``|T|``). With Coulomb friction mu this gives the capstan (Euler-
  Eytelwein) relation for a shaft sliding axially through a bend of wrap angle theta:

      T_pull = T_load exp(mu theta)        (the hand-solved case ``capstan_ratio``).

  Twisting the shaft in a bend meets the friction torque mu r N (r the shaft's radius): the
  torque the handle can send to the tip is attenuated by the bend's normal force, which the
  shaft's tension raises: a pushed or pulled catheter twists less freely.

``ShaftChain`` is the shaft in one of its two loadings (``kind``: axial force, or torque about
its axis) between the handle (node 0, driven) and the part that bears on the sheath (node 1):
the shaft beyond the proximal bend's start, to the exit, taken as rigid (the bends lie within
150 mm of the exit, where the shaft's axial stiffness is some 10^4 N/m and its torsional one
some 20 times the proximal metre's; its own twist under the friction torque is about 5 deg
against a lead of 35-50 deg), joined to the handle by the proximal shaft's elastic element
(EA / l, GJ / l). Node 1 sticks while the load the handle's element puts on it stays within what
the bends hold against the distal load (the static coefficient); once beyond it, it slides to
where the element's load equals what the bends hold with the kinetic coefficient (the
quasi-static end of a slip) and sticks again: static above kinetic gives stick-slip, with jumps
of (mu_s - mu_k) N / k that emerge from the mechanics. In the axial loading the bends hold the
exact capstan relation (``axial_slip_force``: each bend's distal end force, its arc's
exp(mu theta), its proximal end force, distal bend first); in torsion the bends' normal force
is the end forces plus |T| theta at the shaft's mean axial force T (the axial chain's handle and
distal loads' mean).

The sheath's path (``SheathPath``): two bends of 25 mm radius, the transseptal sheath's distal
curve ending at the exit (wrap 45 deg) and the turn from the inferior vena cava through the right
atrium to the fossa ovalis (90 deg) 60 mm behind it. The radius is the catheter module's earlier
estimate; the wrap angles and the 60 mm are assumptions (no curve chart of a transseptal sheath
nor a measured venous route was found in the reference material available; SL-series sheath
curves are of this size).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ballchain.infrastructure.errors import UserInputError, require_finite_fields

KINDS = ("axial", "torsion")


@dataclass
class SheathPath:
    """The sheath's bends along the shaft (module docstring: the assumptions).

    Attributes:
        bend_radius: radius of every bend's centreline [m].
        bend_angles: each bend's wrap angle, distal first [rad].
        bend_ends: each bend's distal end, as the shaft's distance behind the sheath's exit [m]
            (distal first).
    """

    bend_radius: float = 25e-3
    bend_angles: tuple = (math.radians(45.0), math.radians(90.0))
    bend_ends: tuple = (0.0, 60e-3)

    def validate(self, shaft_length: float | None = None) -> "SheathPath":
        require_finite_fields(self)
        if not self.bend_radius > 0:
            raise UserInputError(f"SheathPath.bend_radius must be > 0, got {self.bend_radius}")
        if len(self.bend_angles) != len(self.bend_ends):
            raise UserInputError(f"SheathPath: bend_angles and bend_ends need one entry per bend, got "
                                 f"{len(self.bend_angles)} and {len(self.bend_ends)}")
        if any(not 0 < a <= 2 * math.pi for a in self.bend_angles):
            raise UserInputError(f"SheathPath.bend_angles must each be in (0, 2 pi] rad, got {self.bend_angles}")
        for k, e in enumerate(self.bend_ends):
            if e < 0 or (k and e < self.start(k - 1)):
                raise UserInputError(f"SheathPath.bend_ends must be >= 0 and each bend behind the last one ends "
                                     f"(distal first, no overlap), got {self.bend_ends}")
        if shaft_length is not None and self.bend_angles and self.start(-1) >= shaft_length:
            raise UserInputError(f"SheathPath: the bends reach {self.start(-1):.3f} m behind the exit, beyond the "
                                 f"shaft's {shaft_length:.3f} m")
        return self

    def start(self, k: int) -> float:
        """Bend k's proximal end, as the shaft's distance behind the exit [m]."""
        return float(self.bend_ends[k] + self.bend_radius * self.bend_angles[k])

    @property
    def total_angle(self) -> float:
        return float(sum(self.bend_angles))

    @property
    def bearing_length(self) -> float:
        """The shaft from the proximal bend's start to the exit (the part taken as rigid) [m]."""
        return self.start(-1) if self.bend_angles else 0.0


def capstan_ratio(mu: float, angle: float) -> float:
    """The capstan (Euler-Eytelwein) ratio exp(mu theta): the axial force that pulls a shaft
    through a bend of wrap ``angle`` against a load, over the load (Coulomb friction ``mu``)."""
    return math.exp(mu * angle)


def axial_slip_force(path: SheathPath, end_force: float, distal: float, direction: float, mu: float) -> float:
    """The axial force at the bends' proximal side [N] (tension positive) while the shaft slides
    through them (``direction`` +1: forwards, into the atrium; -1: back) with ``distal`` at
    their distal side: from the distal bend, each bend's distal end (the friction mu P of its end
    force P, against the sliding), its arc (dT/ds = v mu |T| / R: the force grows or shrinks by
    exp(mu theta) in magnitude as the friction adds to it or takes from it), its proximal end."""
    v = 1.0 if direction > 0 else -1.0
    f = float(distal)
    for angle in path.bend_angles:
        f -= v * mu * end_force
        if f != 0.0:
            f *= math.exp(-v * math.copysign(1.0, f) * mu * angle)
        f -= v * mu * end_force
    return f


@dataclass
class ShaftChain:
    """The shaft in one loading, the handle's elastic element and the part bearing on the sheath's
    bends (module docstring).

    Attributes:
        kind: "axial" (x in m, loads in N) or "torsion" (x in rad, loads in N m).
        k: the handle's element's stiffness [N/m or N m/rad].
        path: the sheath's bends.
        end_force: each bend end's normal force [N].
        mu_static, mu_kinetic: the shaft on the sheath's liner.
        radius: the shaft's radius (the friction torque's lever) [m].
    """

    kind: str
    k: float
    path: SheathPath
    end_force: float
    mu_static: float
    mu_kinetic: float
    radius: float

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise UserInputError(f"ShaftChain.kind must be one of {KINDS}, got {self.kind!r}")
        if not self.k > 0 or not 0 <= self.mu_kinetic <= self.mu_static or self.end_force < 0:
            raise UserInputError(f"ShaftChain needs k > 0, end_force >= 0 and 0 <= mu_kinetic <= mu_static, got "
                                 f"{self.k}, {self.end_force}, {self.mu_kinetic}, {self.mu_static}")

    n = 1  # the sliding nodes

    def initial(self, x0: float = 0.0) -> np.ndarray:
        """The handle and the bearing part at ``x0``, unloaded."""
        return np.full(2, float(x0))

    def forces(self, x: np.ndarray) -> np.ndarray:
        """The handle's element's load (1,): tension [N] or torque [N m], positive when the distal
        node leads."""
        return np.array([self.k * (float(x[1]) - float(x[0]))])

    def normal_force(self, tension: float = 0.0) -> float:
        """The bends' normal force on the shaft [N]: the ends' and |T| theta."""
        return 2 * len(self.path.bend_angles) * self.end_force + abs(float(tension)) * self.path.total_angle

    def capacity(self, tension: float = 0.0, mu: float | None = None) -> float:
        """The torsional friction the bends hold [N m]: mu r N (``normal_force``)."""
        mu = self.mu_static if mu is None else mu
        return mu * self.radius * self.normal_force(tension)

    def holds(self, load: float, mu: float, tension: float = 0.0) -> tuple[float, float]:
        """The range of the handle element's load the bends hold against the distal ``load``
        (positive forward), with friction ``mu``: (the load at sliding back, at sliding forward)
        in the element's sign (tension / torque positive when the distal node leads)."""
        if self.kind == "axial":
            # Element tension T_h; at the bends' distal side the shaft carries the load as a pull.
            back = axial_slip_force(self.path, self.end_force, load, -1.0, mu)
            ahead = axial_slip_force(self.path, self.end_force, load, 1.0, mu)
            return ahead, back
        c = self.capacity(tension, mu)
        return load - c, load + c

    def lead(self, mu: float | None = None, tension: float = 0.0) -> float:
        """The handle's lead over the bearing part when it starts to turn (slide), no distal load
        (the windup's onset, the hand-solved case): what the bends hold over k."""
        mu = self.mu_static if mu is None else mu
        return -self.holds(0.0, mu, tension)[0] / self.k

    def step(self, x: np.ndarray, handle: float, load: float = 0.0, tension: float = 0.0) -> tuple[np.ndarray, int]:
        """The nodes after the handle moves to ``handle`` (``load`` on the bearing part, positive
        forward; ``tension``: the shaft's mean axial force, for the torsional chain's friction).

        Returns:
            (x (2,), slips: 1 when the bearing part slid, else 0).
        """
        handle, moved = float(handle), float(x[1])
        t = self.k * (moved - handle)
        lo, hi = self.holds(load, self.mu_static, tension)
        if lo - 1e-15 <= t <= hi + 1e-15:
            return np.array([handle, moved]), 0
        lo_k, hi_k = self.holds(load, self.mu_kinetic, tension)
        t = lo_k if t < lo else hi_k  # driven forward (the element compressed below what holds) or back
        return np.array([handle, handle + t / self.k]), 1

    def mean_tension(self, x: np.ndarray, load: float = 0.0) -> float:
        """The axial chain's mean axial force over the bends: the handle element's and the distal
        load's mean [N]."""
        return 0.5 * (float(self.forces(x)[0]) + float(load))


def shaft_chains(GJ: float, EA: float, EI: float, radius: float, shaft_length: float, mu_static: float,
                 mu_kinetic: float, path: SheathPath) -> tuple[ShaftChain, ShaftChain]:
    """The shaft's torsional and axial chains through the sheath's path (module docstring): the
    handle's element from the handle to the proximal bend's start, GJ / l and EA / l; each bend
    end's normal force 2 EI / R^2."""
    path.validate(shaft_length)
    free = shaft_length - path.bearing_length
    end_force = 2.0 * EI / path.bend_radius**2
    twist = ShaftChain("torsion", GJ / free, path, end_force, mu_static, mu_kinetic, radius)
    push = ShaftChain("axial", EA / free, path, end_force, mu_static, mu_kinetic, radius)
    return twist, push


# ------------------------------------------------------------------------ the steerable sheath
@dataclass
class SteerableSheath:
    """A deflectable (steerable) transseptal sheath's distal end in the left atrium: advanced or
    retracted through the septum, rotated about its axis, its distal ``deflectable_length``
    deflected in one plane (issue 45, the manual arm only: the robotic arm keeps the paper's fixed
    sheath).

    Geometry (quasi-static, the sheath rigid against the catheter inside it): the sheath crosses
    the septum at ``p_S`` along the fixed sheath's axis; ``advance`` of it lies beyond the
    septum: a straight part, then (the last ``min(advance, deflectable_length)``) an arc of
    curvature ``deflection / deflectable_length`` in the plane at ``rotation`` about the axis
    (rotation 0: the plane of the sheath frame's x axis, ``rod_statics.frame_along``); the exit is
    the arc's end, the catheter leaving it along the arc's tangent. A part of the deflectable
    length still in the septum does not bend.

    Sources and assumptions:

    * Deflection: 180 degrees each way: the 8.5 F steerable introducer of FDA 510(k) K191190
      (cleared 2019-08-01; "180 degrees bi-directional deflection", its curl size on the
      product labels, not given in the summary) and the class of the Agilis NxT (Abbott) and
      CARTO VIZIGO (Biosense Webster) bidirectional sheaths used for pulmonary-vein isolation
      (Vizigo's first real-world series: J. Interv. Card. Electrophysiol., 2022,
      doi 10.1007/s10840-022-01332-8). ``max_deflection`` 180 degrees on both sides.
    * Deflectable length 40 mm (a 180-degree curl of 25 mm across, 2 L / pi): an assumption at the
      level of a "medium curl" (no curl-size chart of these sheaths was found in the reference
      material available here).
    * Advance range 0-40 mm beyond the septum (the fixed sheath's exit lies 3.5 mm beyond it:
      ``nominal_advance``, measured on the atrium model as the exit's depth inside the wall along
      the axis): an assumption, the atrium's size.
    """

    deflectable_length: float = 40e-3
    max_deflection: float = math.pi
    max_advance: float = 40e-3
    nominal_advance: float = 3.5e-3

    def validate(self) -> "SteerableSheath":
        require_finite_fields(self)
        for name in ("deflectable_length", "max_deflection", "max_advance"):
            if not getattr(self, name) > 0:
                raise UserInputError(f"SteerableSheath.{name} must be > 0, got {getattr(self, name)}")
        if not self.max_deflection <= math.pi + 1e-12:
            raise UserInputError(f"SteerableSheath.max_deflection must be <= pi (a half turn), got {self.max_deflection}")
        if not 0.0 <= self.nominal_advance <= self.max_advance:
            raise UserInputError(f"SteerableSheath.nominal_advance must be in [0, max_advance = {self.max_advance}], "
                                 f"got {self.nominal_advance}")
        return self

    def clamp(self, advance: float, deflection: float) -> tuple[float, float]:
        """(advance, deflection) within the sheath's travel."""
        return (float(np.clip(advance, 0.0, self.max_advance)),
                float(np.clip(deflection, -self.max_deflection, self.max_deflection)))

    def local(self, advance: float, deflection: float, n: int = 2) -> tuple[np.ndarray, np.ndarray]:
        """The sheath's centreline beyond the septum in the fixed sheath's frame at rotation 0
        (z its axis, the bend towards +x for a positive deflection), the septum at the origin:
        (points (n, 3) from the septum to the exit [m], the exit's unit tangent (3,))."""
        advance, deflection = self.clamp(advance, deflection)
        a = deflection / self.deflectable_length * min(advance, self.deflectable_length)
        return self.points(advance, deflection, np.linspace(0.0, advance, max(int(n), 2))), \
            np.array([math.sin(a), 0.0, math.cos(a)])

    def points(self, advance: float, deflection: float, s) -> np.ndarray:
        """The centreline's points (k, 3) at the arc lengths ``s`` (k,) from the septum [m], in the
        frame of ``local``; s < 0: behind the septum, on the fixed sheath's axis."""
        advance, deflection = self.clamp(advance, deflection)
        bent = min(advance, self.deflectable_length)
        straight = advance - bent
        kappa = deflection / self.deflectable_length
        s = np.minimum(np.asarray(s, float), advance)
        u = np.clip(s - straight, 0.0, None)
        if abs(kappa) < 1e-12:
            x, z = np.zeros_like(s), s
        else:
            x = (1.0 - np.cos(kappa * u)) / kappa
            z = np.minimum(s, straight) + np.sin(kappa * u) / kappa
        return np.column_stack([x, np.zeros_like(s), z])

    def exit_pose(self, p_S, R_S, advance: float, rotation: float, deflection: float,
                  n: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The exit in the world: (p (3,), its frame R (3, 3), the centreline (n, 3)) for the
        septal crossing ``p_S`` and the fixed sheath's frame ``R_S`` (z its axis). R is ``R_S``
        carried along the arc (turned about the bending plane's normal by the bend: z the exit's
        axis): rotating the sheath does not twist the catheter inside it."""
        pts, tangent = self.local(advance, deflection, n)
        c, s = math.cos(rotation), math.sin(rotation)
        Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        R = np.asarray(R_S, float) @ Rz
        a = math.atan2(tangent[0], tangent[2])
        ca, sa = math.cos(a), math.sin(a)
        Ry = np.array([[ca, 0.0, sa], [0.0, 1.0, 0.0], [-sa, 0.0, ca]])
        world = np.asarray(p_S, float)[None, :] + pts @ R.T
        return world[-1], R @ Ry @ Rz.T, world

    def behind_exit(self, p_S, R_S, advance: float, rotation: float, deflection: float, d) -> np.ndarray:
        """Points (k, 3) ``d`` (k,) behind the exit along the sheath [m] (where the catheter's
        part still in the sheath lies), in the world as ``exit_pose``."""
        advance, deflection = self.clamp(advance, deflection)
        c, s = math.cos(rotation), math.sin(rotation)
        R = np.asarray(R_S, float) @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return np.asarray(p_S, float)[None, :] + self.points(advance, deflection, advance - np.asarray(d, float)) @ R.T
