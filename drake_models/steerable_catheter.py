"""The manual arm of the paper's comparison (Sec. V-C): an 8 Fr bidirectional steerable ablation
catheter, pushed, pulled and twisted through the transseptal sheath, its distal segment deflected
by a knob pulling one of two tendons.

This module holds the catheter's constants (each with its source, or the stated estimate that
sized it) and the law of its friction in the sheath; ``optimization.rod_statics`` solves the
distal rod's equilibrium in the atrium.

The catheter's mechanics, as modelled:

* The distal rod (the part beyond the sheath exit, up to ``model_length``): a discretised
  Kirchhoff rod, bending stiffness ``EI`` (the shaft's, the deflectable segment's) and torsional
  stiffness ``GJ``. Pulling a tendon gives the deflectable segment an intrinsic (commanded)
  curvature in its bending plane, one sign per tendon (a D-F catheter: a tighter curve one way than
  the other; the knob's travel sets the fraction of the side's largest curvature).
* The shaft from the handle to the sheath exit (``shaft_length``): in torsion and in tension a
  chain of elastic elements with Coulomb friction where it bears on the sheath's bends
  (``drake_models.sheath``: the bends' end forces and the capstan's |T| / R, ``ShaftChain``):
  static friction above kinetic gives stick-slip; the twist the handle puts in winds up in the
  shaft until the friction gives way, and is released in jumps (a quasi-static incremental model).
  (``CoulombChain``, friction spread evenly along the shaft, is the earlier model, kept for its
  closed-form tests.)

Sources of the constants (no constant was tuned to the paper's times):

* Diameter: 8 Fr, the French (Charriere) scale, 1 Fr = 1/3 mm: 2.67 mm (the paper: "Tactiflex D-F,
  Abbott; 8FR diameter").
* Deflectable segment's EI: 4.4e4 g mm^2 = 4.3e-4 N m^2, the small-deflection value measured on a
  commercial ablation catheter's tip by Khoshnam and Patel's large-deflection beam model (thesis,
  Western University, Fig. 2.6 "Relation between the catheter tip deflection and the value of EI":
  EI = (2.5 Phi^7.2 + 4.4) x 1e4 g mm^2, measured over tip bends Phi of 0.4-1.1 rad; at 1 rad of
  deflection 6.9e4, 1.57 times the small-bend value). The tip stiffens with its bend by this fit
  (``tip_EI_factor``, issue 45), held at 1.1 rad's 2.13 times beyond the measured range.
* Shaft's EI: a Pebax tube of the 8 Fr outer diameter and an assumed 1.5 mm lumen, flexural
  modulus 500 MPa (the top of the Pebax 33 series' 10-500 MPa range, Arkema's Pebax mechanical
  properties page, ISO 178), the braid neglected (a lower bound): E pi (D^4 - d^4) / 64.
* The plain tube's GJ = EI / (1 + nu) (an isotropic tube, J = 2 I), nu = 0.45 (a thermoplastic
  elastomer); the deflectable segment's likewise from its EI.
* The shaft's braid in torsion (``braid_GJ``, added to the plain tube's GJ): ablation-catheter
  shafts carry a stainless-steel braid (304V wire) embedded in the polymer wall for torque
  transmission (catheter-tubing makers' descriptions). Modelled by netting analysis: N wires, N/2
  each way, on helices at +-alpha to the axis, on a cylinder of radius R_b, each carrying only
  axial force (no bending of the wires, no slip at the crossings: an upper bound for the braid's
  share). Twisting the shaft by theta' per unit length strains a wire by
  eps = R_b theta' sin(alpha) cos(alpha) (one set stretched, the other compressed); a wire's length
  per unit of shaft is 1 / cos(alpha), so the strain energy per unit length is
  N E_w A_w eps^2 / (2 cos alpha) = GJ_braid theta'^2 / 2, that is

      GJ_braid = N E_w A_w R_b^2 sin(alpha)^2 cos(alpha),   A_w = pi d_w^2 / 4.

  Construction, assumptions at the level of typical catheter braids (no datasheet of the Tactiflex
  shaft was found): N = 16 wires (the common 16-carrier braider; 8-32 exist), round wire
  d_w = 0.002 in = 0.051 mm (catheter braid wire is 0.001-0.003 in), braid angle 60 degrees from
  the axis (a fine pick: 45-70 degrees; sin^2 cos varies by under 10 % over 45-65 degrees),
  R_b = 1.1 mm (under a jacket of about 0.2 mm of the 8 Fr wall), E_w = 193 GPa (304 stainless
  steel). GJ_braid = 2.8e-3 N m^2, 3.7 times the plain tube's 7.7e-4: the shaft's GJ is 4.7 times
  the braid-free value (d_w 0.001-0.003 in: 1.9-9.3 times). The braid also stiffens the shaft in
  bending; that is not counted (the shaft's EI stays the plain tube's, as the sheath's normal
  force, which is sized from it).
* Deflectable segment: 55 mm long, largest curvature 180 degrees over it on the tighter (D) side
  and 120 degrees on the wider (F) side: the size of a D-F bidirectional curve (a half turn of
  about 35 mm reach on the D side). No curve chart (the manufacturers' D-F curve sheets, an IFU's
  curve table, a paper measuring catheter curves) was found in the reference material available
  here (searched again: TactiFlex, TactiCath, FlexAbility, Safire, "D-F curve", "curve reach",
  bidirectional deflection studies, openFDA's device records): an assumption at datasheet level,
  not a measured value, sized by a sensitivity sweep (``docs/guide/manual_catheter.md``: the
  manual right ring with a 45 or 65 mm segment, or 160 or 200 degrees on the D side; a wider
  curve touched 3-4 targets fewer, a tighter one about as many). The one bend angle found for a cardiac ablation catheter's tendon-driven
  tip, a four-wire robotic prototype compared with manual catheters (184.7 and 170.4 degrees at
  11 mm of wire pull, its two planes; PubMed Central PMC4209906), puts a half turn within this
  class of device. ``reach_search`` (``experiments.manual_catheter``) says which right-ring
  targets the geometry decides (14, 15 and 16 out of reach; 1, 12, 13, 17 and 18 only with
  100-120 mm out, a loop around the atrium).
* Shaft length 1.15 m: the overall length of the TactiCath Quartz (NICE medtech innovation
  briefing MIB60, "Technology overview": "a single-use device with an overall length of 115 cm"),
  the contact-force catheter of the same maker that the TactiFlex succeeds; the handle's share of
  it is not subtracted (the friction chain's stiffness changes by a few per cent).
* Friction in the sheath: PTFE-lined sheath, kinetic coefficient 0.1 (Schroeder 1993,
  Cardiovasc. Intervent. Radiol. 16:93: a Teflon coating halves the sliding friction of steel,
  about 0.2 on polymer), static 0.15 (static above kinetic: the assumption that makes stick-slip).
  The normal force that presses the shaft on the sheath acts at the sheath's bends
  (``drake_models.sheath.SheathPath``: two of 25 mm radius, the transseptal sheath's distal
  curve and the turn from the inferior vena cava into the septum, wrap angles assumed): the couple
  EI / R at each end of a bend is carried by contact forces over a transition of order R,
  2 EI / R^2 at each end (a stated estimate), and the shaft's axial force T presses it on the bend
  with |T| / R per unit length (the capstan). The friction torque is mu N r (r the shaft's radius),
  the axial force mu N.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ballchain.drake_models.sheath import ShaftChain, SheathPath, shaft_chains
from ballchain.infrastructure.errors import UserInputError, require_finite_fields

FRENCH = 1e-3 / 3.0  # [m] per Fr (the Charriere scale)



TIP_FIT_MAX_BEND = 1.1  # [rad] the largest tip bend of Khoshnam and Patel's EI measurements (Fig. 2.6)
SHEATH_FRICTION = ("bends", "even")  # where the shaft's friction acts (SteerableCatheter.sheath_friction)
# [N/m] the stiffest compliant wall: a 1 N load indents it 1 micrometre, the rigid wall for every
# purpose here (and the SQP's Hessian stays within a few decades of the rod's own stiffness)
MAX_WALL_STIFFNESS = 1e6
MAX_BRAID_WIRES = 256  # a braiding machine's carriers: 16-64 in catheter shafts, at most a few hundred

@dataclass
class SteerableCatheter:
    """An 8 Fr bidirectional steerable ablation catheter (module docstring: the sources).

    Attributes:
        diameter: outer diameter [m].
        lumen_diameter: the inner lumen assumed for the shaft's section [m].
        flexural_modulus: of the shaft's Pebax [Pa].
        poisson: Poisson's ratio (GJ = EI / (1 + nu)).
        tip_EI: the deflectable segment's bending stiffness at small bends [N m^2].
        tip_stiffening: the deflectable segment stiffens with its bend (``tip_EI_factor``).
        deflectable_length: the deflectable segment's length [m].
        max_deflection_D, max_deflection_F: the segment's total bend at full knob, each tendon [rad].
        model_length: the distal length modelled as a rod (beyond it the shaft stays in the sheath) [m].
        segment_length: the rod's discretisation [m].
        shaft_length: handle to sheath exit [m].
        mu_static, mu_kinetic: shaft on the sheath's PTFE liner.
        wall_mu: Coulomb friction of the rod on the atrium's wall (``systems.rod_wall_friction``:
            a node touching the wall sticks while the tangential reaction is within wall_mu times
            the normal one); 0: the frictionless wall. An assumption (no measured coefficient of
            a catheter on endocardium was found; the module's docstring gives what was).
        wall_stiffness: the atrium wall's normal stiffness per rod node [N/m]
            (``systems.rod_wall_compliance``: a node indenting the wall by d meets N = k d, the
            rigid wall beyond a 3 mm cap); 0: the rigid wall (the rod's statics unchanged). The
            source's range (Ijima et al., ex vivo porcine tissue, a catheter tip pressed in: 0.11-0.14
            N/mm) and the values run: ``docs/guide/manual_catheter.md``.
        sheath: the sheath's path (``drake_models.sheath.SheathPath``: its bends, where the shaft
            bears on it).
        sheath_friction: "bends" (the friction where the shaft bears on the sheath's bends,
            ``drake_models.sheath``) or "even" (the earlier model: the bends' end forces spread
            evenly over ``shaft_elements`` nodes of a ``CoulombChain``, no axial load, no capstan).
        shaft_elements: the "even" model's elements.
        braid_wires: the shaft braid's wire count (0: no braid, the plain tube's GJ).
        braid_wire_diameter: its round wire's diameter [m].
        braid_angle: its wires' angle from the shaft's axis [rad].
        braid_radius: the braid's mean radius [m].
        braid_modulus: its wire's Young's modulus [Pa].
    """

    diameter: float = 8 * FRENCH
    lumen_diameter: float = 1.5e-3
    flexural_modulus: float = 500e6
    poisson: float = 0.45
    tip_EI: float = 4.4e4 * 9.80665e-3 * 1e-6
    tip_stiffening: bool = True
    deflectable_length: float = 55e-3
    max_deflection_D: float = np.pi
    max_deflection_F: float = np.radians(120.0)
    model_length: float = 120e-3
    segment_length: float = 3e-3
    shaft_length: float = 1.15
    mu_static: float = 0.15
    mu_kinetic: float = 0.10
    wall_mu: float = 0.0
    wall_stiffness: float = 0.0
    sheath: SheathPath = field(default_factory=SheathPath)
    sheath_friction: str = "even"
    shaft_elements: int = 8
    braid_wires: int = 16
    braid_wire_diameter: float = 0.002 * 25.4e-3
    braid_angle: float = np.radians(60.0)
    braid_radius: float = 1.1e-3
    braid_modulus: float = 193e9

    def validate(self) -> "SteerableCatheter":
        require_finite_fields(self)
        if not 0 < self.lumen_diameter < self.diameter:
            raise UserInputError(f"SteerableCatheter.lumen_diameter must be in (0, diameter), got {self.lumen_diameter}")
        for name in ("flexural_modulus", "tip_EI", "deflectable_length", "segment_length", "shaft_length",
                     "max_deflection_D", "max_deflection_F"):
            if not getattr(self, name) > 0:
                raise UserInputError(f"SteerableCatheter.{name} must be > 0, got {getattr(self, name)}")
        if not 0 <= self.mu_kinetic <= self.mu_static:
            raise UserInputError("SteerableCatheter: friction needs 0 <= mu_kinetic <= mu_static, got "
                                 f"{self.mu_kinetic}, {self.mu_static}")
        if not 0.0 <= self.wall_mu <= 2.0:
            raise UserInputError(f"SteerableCatheter.wall_mu must be in [0, 2] (0: a frictionless wall), got "
                                 f"{self.wall_mu}")
        if not 0.0 <= self.wall_stiffness <= MAX_WALL_STIFFNESS:
            raise UserInputError(f"SteerableCatheter.wall_stiffness must be in [0, {MAX_WALL_STIFFNESS:g}] N/m (0: the "
                                 f"rigid wall; tissue about 100-140 N/m), got {self.wall_stiffness}")
        if int(self.braid_wires) != self.braid_wires or not 0 <= self.braid_wires <= MAX_BRAID_WIRES \
                or self.braid_wires % 2:
            raise UserInputError(f"SteerableCatheter.braid_wires must be an even count in 0..{MAX_BRAID_WIRES} (half "
                                 f"each way; 0: no braid), got {self.braid_wires}")
        for name in ("braid_wire_diameter", "braid_modulus"):
            if not getattr(self, name) > 0:
                raise UserInputError(f"SteerableCatheter.{name} must be > 0, got {getattr(self, name)}")
        if not 0 < self.braid_angle < 0.5 * np.pi:
            raise UserInputError(f"SteerableCatheter.braid_angle must be in (0, pi/2) rad, got {self.braid_angle}")
        if self.braid_wires and not 0 < self.braid_radius < self.radius:
            raise UserInputError(f"SteerableCatheter.braid_radius must be in (0, diameter / 2), got {self.braid_radius}")
        if not self.deflectable_length <= self.model_length:
            raise UserInputError("SteerableCatheter: deflectable_length must be <= model_length")
        if not isinstance(self.sheath, SheathPath):
            raise UserInputError(f"SteerableCatheter.sheath must be a SheathPath, got {type(self.sheath).__name__}")
        self.sheath.validate(self.shaft_length)
        if self.sheath_friction not in SHEATH_FRICTION or self.shaft_elements < 1:
            raise UserInputError(f"SteerableCatheter.sheath_friction must be one of {SHEATH_FRICTION} (and "
                                 f"shaft_elements >= 1), got {self.sheath_friction!r}, {self.shaft_elements}")
        return self

    # ------------------------------------------------------------------ derived stiffnesses
    @property
    def radius(self) -> float:
        return 0.5 * self.diameter

    @property
    def shaft_EI(self) -> float:
        """E pi (D^4 - d^4) / 64 [N m^2]."""
        return self.flexural_modulus * np.pi * (self.diameter**4 - self.lumen_diameter**4) / 64.0

    @property
    def plain_GJ(self) -> float:
        """The plain (braid-free) tube's GJ = EI / (1 + nu) [N m^2]."""
        return self.shaft_EI / (1.0 + self.poisson)

    @property
    def braid_GJ(self) -> float:
        """The braid's torsional stiffness by netting analysis (module docstring) [N m^2]:
        N E_w (pi d_w^2 / 4) R_b^2 sin(alpha)^2 cos(alpha)."""
        area = np.pi * self.braid_wire_diameter**2 / 4.0
        a = self.braid_angle
        return self.braid_wires * self.braid_modulus * area * self.braid_radius**2 * np.sin(a) ** 2 * np.cos(a)

    @property
    def shaft_GJ(self) -> float:
        """The shaft's torsional stiffness: the plain tube's and the braid's [N m^2]."""
        return self.plain_GJ + self.braid_GJ

    @property
    def tip_GJ(self) -> float:
        return self.tip_EI / (1.0 + self.poisson)

    @property
    def shaft_EA(self) -> float:
        return self.flexural_modulus * np.pi * (self.diameter**2 - self.lumen_diameter**2) / 4.0

    @property
    def max_curvature(self) -> tuple[float, float]:
        """The deflectable segment's largest curvature on the D (+) and the F (-) side [1/m]."""
        return self.max_deflection_D / self.deflectable_length, self.max_deflection_F / self.deflectable_length

    def tip_EI_factor(self, kappa: float) -> float:
        """The deflectable segment's EI over its small-bend value at the commanded curvature
        ``kappa`` [1/m] (1 without ``tip_stiffening``): Khoshnam and Patel's fit to their
        measurements on an ablation catheter's tip, EI = (2.5 Phi^7.2 + 4.4) x 1e4 g mm^2 at the
        tip's bend Phi [rad] (module docstring), as a factor (2.5 Phi^7.2 + 4.4) / 4.4, Phi the
        commanded bend |kappa| times the segment's length, held at the fit's last measured angle
        (1.1 rad: 2.13 times) beyond it (the power law is not extrapolated: at pi it would give
        2000 times). 1.57 times at 1 rad."""
        if not self.tip_stiffening or kappa == 0.0:
            return 1.0
        phi = min(abs(float(kappa)) * self.deflectable_length, TIP_FIT_MAX_BEND)
        return (2.5 * phi**7.2 + 4.4) / 4.4

    def curvature(self, knob: float) -> float:
        """The commanded curvature [1/m] for a knob position in [-1, 1] (+: the D tendon)."""
        knob = float(np.clip(knob, -1.0, 1.0))
        d, f = self.max_curvature
        return knob * (d if knob >= 0 else f)

    def unloaded_shape(self, out: float, knob: float, n: int = 14) -> np.ndarray:
        """The rod beyond the exit with no load on it, in the exit's frame (z its axis, the D bend
        towards +x): straight, then the deflectable segment (what is out of it) at the knob's
        constant curvature; (n, 3) points from the exit to the tip sphere's centre [m] (the
        shape a hand expects, for a steerable sheath's plan: ``systems.catheter_station``). The
        tip sphere's centre lies a radius short of the rod's end, as in the rod's statics
        (``optimization.rod_statics``: its last half segment ends a radius short; before, the
        shape ended at the rod's end, 1.3 mm beyond the statics' unloaded tip)."""
        out = max(float(out), 0.0)
        bent = min(out, self.deflectable_length)
        kappa = self.curvature(knob)
        s = np.linspace(0.0, max(out - self.radius, 0.0), max(int(n), 2))
        u = np.clip(s - (out - bent), 0.0, None)
        if abs(kappa) < 1e-12:
            return np.column_stack([np.zeros_like(s), np.zeros_like(s), s])
        return np.column_stack([(1.0 - np.cos(kappa * u)) / kappa, np.zeros_like(s),
                                np.minimum(s, out - bent) + np.sin(kappa * u) / kappa])

    def sheath_normal_force(self) -> float:
        """The bends' end forces on the sheath, the shaft unloaded [N] (module docstring: 2 EI / R^2
        at each end of each bend)."""
        return len(self.sheath.bend_angles) * 4.0 * self.shaft_EI / self.sheath.bend_radius**2

    def chains(self) -> tuple:
        """The shaft in the sheath (torsion: handle twist [rad] to the twist at the exit, axial:
        handle advance [m] to the advance at the exit): ``sheath_friction`` "bends": through the
        sheath's bends (``drake_models.sheath.shaft_chains``, ShaftChain); "even": CoulombChains."""
        if self.sheath_friction == "bends":
            return shaft_chains(self.shaft_GJ, self.shaft_EA, self.shaft_EI, self.radius, self.shaft_length,
                                self.mu_static, self.mu_kinetic, self.sheath)
        n = self.shaft_elements
        N = self.sheath_normal_force() / n
        return (CoulombChain(n, n * self.shaft_GJ / self.shaft_length, self.mu_static * N * self.radius,
                             self.mu_kinetic * N * self.radius),
                CoulombChain(n, n * self.shaft_EA / self.shaft_length, self.mu_static * N, self.mu_kinetic * N))

    def twist_chain(self):
        """The shaft in torsion: handle twist [rad] to the twist at the sheath exit."""
        return self.chains()[0]

    def push_chain(self):
        """The shaft in tension/compression: handle advance [m] to the advance at the sheath exit."""
        return self.chains()[1]


@dataclass
class CoulombChain:
    """A shaft as ``n`` elastic elements in series, each node held by Coulomb friction (quasi-static).

    Node 0 is driven (the handle), nodes 1..n slide against the sheath; element k joins node k-1
    and node k with stiffness ``k`` (per element). A node sticks while the net elastic load on it
    (plus, at the last node, the external load ``load``) stays within ``static``; once it slips, it
    moves to where the net load equals ``kinetic`` (the quasi-static end of a slip) and sticks there
    again. Relaxed node by node until nothing moves (Gauss-Seidel over the nodes), which is the
    incremental quasi-static answer for a small enough increment of the handle.

    Attributes:
        n: elements (and sliding nodes).
        k: stiffness of one element [N/m or N m/rad].
        static, kinetic: each sliding node's friction capacity (static >= kinetic) [N or N m].
    """

    n: int
    k: float
    static: float
    kinetic: float

    def initial(self, x0: float = 0.0) -> np.ndarray:
        """Nodes 0..n at ``x0``, unloaded."""
        return np.full(self.n + 1, float(x0))

    def net_loads(self, x: np.ndarray, load: float = 0.0) -> np.ndarray:
        """Net elastic (and external) load on nodes 1..n: positive pushes a node forward."""
        f = np.zeros(self.n)
        d = np.diff(x)  # element k's stretch x_k - x_{k-1}
        f -= self.k * d  # element k pulls node k back when stretched
        f[:-1] += self.k * d[1:]  # element k+1 pulls node k forward
        f[-1] += load
        return f

    def step(self, x: np.ndarray, handle: float, load: float = 0.0, max_sweeps: int = 500) -> tuple[np.ndarray, int]:
        """Nodes after the handle moves to ``handle`` (the external load ``load`` on the last node).

        Returns:
            (x (n + 1,), slips: how many node slips it took).
        """
        # On Python floats (the same IEEE arithmetic as numpy's scalars, without their overhead).
        x = [float(v) for v in np.asarray(x, float)]
        x[0] = float(handle)
        k, n, load = float(self.k), self.n, float(load)
        limit, kinetic = self.static * (1.0 + 1e-12), float(self.kinetic)
        slips = 0
        for _ in range(max_sweeps):
            moved = False
            for i in range(1, n + 1):
                if i < n:
                    f = k * (x[i - 1] - x[i]) + k * (x[i + 1] - x[i])
                    stiffness = k * 2.0
                else:
                    f = k * (x[i - 1] - x[i]) + load
                    stiffness = k
                if abs(f) > limit:
                    x[i] += (f - math.copysign(kinetic, f)) / stiffness
                    slips += 1
                    moved = True
            if not moved:
                break
        return np.array(x), slips

    def windup(self, x: np.ndarray) -> float:
        """The handle's lead over the distal node (x_0 - x_n)."""
        return float(x[0] - x[-1])

    def forces(self, x: np.ndarray) -> np.ndarray:
        """The elements' loads (n,), positive when the distal node leads."""
        return self.k * np.diff(np.asarray(x, float))

    def lead(self, mu_ratio: float = 1.0) -> float:
        """The handle's lead over the distal node with every node at ``mu_ratio`` times its static
        capacity: n (n + 1) / 2 static / k."""
        return self.n * (self.n + 1) / 2 * mu_ratio * self.static / self.k
