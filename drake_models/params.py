"""Parameter dataclasses of the physical world: the ball chain, its sleeve, the actuation magnets.

SI units throughout. Every dataclass checks itself on construction and says what is wrong.
Defaults are the paper's prototype (see docs/design.md, 2.4).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, replace

import numpy as np

from ballchain.drake_models.dipole import MU0
from ballchain.drake_models.tissue import N52_IRREVERSIBLE_LOSS_C
from ballchain.infrastructure.errors import UserInputError, short_repr

GRAVITY = 9.80665  # standard gravity [m/s^2]; also the grams-force conversion


def _require_positive(owner: str, **values: float) -> None:
    # numbers.Real takes numpy scalars too (np.float32, np.int64); bool is refused.
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) or value <= 0:
            raise UserInputError(f"{owner}.{name} must be a positive finite number, got {short_repr(value)}")


# What a chain of magnets can be: from beads to marbles; no permanent magnet reaches 2.5 T (NdFeB
# about 1.5); osmium, the densest element, is 22 590 kg/m^3.
BALL_DIAMETER_RANGE = (0.1e-3, 0.1)  # [m]
MAX_REMANENCE = 2.5  # [T]
MAX_DENSITY = 25000.0  # [kg/m^3]
MAX_SLEEVE_DIAMETER = 0.12  # [m]: over the largest balls
MAX_SLEEVE_MODULUS = 10e9  # [Pa]: the stiffest polymer tubes (PEEK about 4 GPa); silicone is 0.1-5 MPa
MAX_MAGNET_SIZE = 10.0  # [m]: a magnet's diameter or length; an MRI scanner's bore is under 1 m
MIN_MAGNET_SIZE = 1e-4  # [m]: 0.1 mm, below the smallest sintered NdFeB parts (a typo in metres, not a magnet)


@dataclass(frozen=True)
class Sleeve:
    """Soft silicone sleeve around the chain (Dragon Skin 10 NV by default).

    Attributes:
        youngs_modulus: E [Pa] (about 0.15 MPa for Dragon Skin 10).
        inner_diameter: ID [m].
        outer_diameter: OD [m].
    """

    youngs_modulus: float = 0.15e6
    inner_diameter: float = 3.0e-3
    outer_diameter: float = 3.5e-3

    def __post_init__(self) -> None:
        _require_positive(
            "Sleeve",
            youngs_modulus=self.youngs_modulus,
            inner_diameter=self.inner_diameter,
            outer_diameter=self.outer_diameter,
        )
        if self.outer_diameter <= self.inner_diameter:
            raise UserInputError(
                f"Sleeve.outer_diameter ({self.outer_diameter}) must exceed inner_diameter "
                f"({self.inner_diameter})"
            )
        if self.youngs_modulus > MAX_SLEEVE_MODULUS:
            raise UserInputError(f"Sleeve.youngs_modulus must be in (0, {MAX_SLEEVE_MODULUS * 1e-6:g}] MPa, got "
                                 f"{self.youngs_modulus * 1e-6:g} MPa")
        if self.outer_diameter > MAX_SLEEVE_DIAMETER:
            raise UserInputError(f"Sleeve.outer_diameter must be at most {MAX_SLEEVE_DIAMETER * 1e3:g} mm (a sleeve "
                                 f"over the largest balls), got {self.outer_diameter * 1e3:g} mm")

    @property
    def second_moment_of_area(self) -> float:
        """I = pi (OD^4 - ID^4) / 64 of the tube's cross section [m^4]."""
        return math.pi * (self.outer_diameter**4 - self.inner_diameter**4) / 64.0

    @property
    def bending_stiffness(self) -> float:
        """EI [N m^2]."""
        return self.youngs_modulus * self.second_moment_of_area


@dataclass(frozen=True)
class BallChain:
    """A chain of identical, uniformly magnetised spherical magnets (N52 by default).

    Attributes:
        n_balls: number of balls (>= 1).
        ball_diameter: d [m].
        remanence: Br [T].
        density: [kg/m^3].
        sleeve: the sleeve, or None for a bare chain.
    """

    n_balls: int = 16
    ball_diameter: float = 3.175e-3
    remanence: float = 1.44
    density: float = 7500.0
    sleeve: Sleeve | None = None

    def __post_init__(self) -> None:
        if isinstance(self.n_balls, bool) or not isinstance(self.n_balls, numbers.Integral) or self.n_balls < 1:
            raise UserInputError(f"BallChain.n_balls must be an integer >= 1, got {short_repr(self.n_balls)}")
        object.__setattr__(self, "n_balls", int(self.n_balls))  # a numpy integer becomes an int
        _require_positive(
            "BallChain",
            ball_diameter=self.ball_diameter,
            remanence=self.remanence,
            density=self.density,
        )
        for name, value, lo, hi, unit, scale in (
                ("ball_diameter", self.ball_diameter, *BALL_DIAMETER_RANGE, "mm", 1e3),
                ("remanence", self.remanence, 0.0, MAX_REMANENCE, "T", 1.0),
                ("density", self.density, 0.0, MAX_DENSITY, "kg/m^3", 1.0)):
            if not lo <= value <= hi:  # beyond these the energies overflow or divide by zero
                raise UserInputError(f"BallChain.{name} must be in {'(' if lo == 0.0 else '['}{lo * scale:g}, "
                                     f"{hi * scale:g}] {unit}, got {value * scale:g} {unit}")
        if self.sleeve is not None and not isinstance(self.sleeve, Sleeve):
            raise UserInputError(f"BallChain.sleeve must be a Sleeve or None, got {short_repr(self.sleeve)}")
        # The sleeve's inside may be a little smaller than the balls (the silicone stretches over
        # them: the paper's ID 3.0 mm on 3.175 mm balls), but its outside must contain them.
        if self.sleeve is not None and self.sleeve.outer_diameter <= self.ball_diameter:
            raise UserInputError(
                f"BallChain.sleeve.outer_diameter {self.sleeve.outer_diameter * 1e3:.3f} mm must exceed the "
                f"ball_diameter {self.ball_diameter * 1e3:.3f} mm (the sleeve covers the balls)")

    @property
    def ball_volume(self) -> float:
        """[m^3]"""
        return math.pi * self.ball_diameter**3 / 6.0

    @property
    def dipole_moment(self) -> float:
        """``|m| = Br V / mu0`` of one ball [A m^2] (0.0192 for the defaults)."""
        return self.remanence * self.ball_volume / MU0

    @property
    def ball_mass(self) -> float:
        """[kg] (0.126 g for the defaults)."""
        return self.density * self.ball_volume

    @property
    def length(self) -> float:
        """n d, the chain's length [m]."""
        return self.n_balls * self.ball_diameter

    def with_balls(self, n_balls: int) -> "BallChain":
        """The same chain with another number of balls."""
        return replace(self, n_balls=n_balls)


class _UniformMagnet:
    """Moment and mass of a uniformly magnetised body from its ``volume``, ``remanence``, ``density``."""

    @property
    def dipole_moment(self) -> float:
        """``|m| = Br V / mu0`` [A m^2] (about 199 A m^2 for the prototype cylinder)."""
        return self.remanence * self.volume / MU0

    @property
    def mass(self) -> float:
        """[kg]"""
        return self.density * self.volume

    def __post_init__(self) -> None:
        owner = type(self).__name__
        names = [f for f in self.__dataclass_fields__]
        _require_positive(owner, **{name: getattr(self, name) for name in names})
        limits = {"remanence": (MAX_REMANENCE, "T", 1.0), "density": (MAX_DENSITY, "kg/m^3", 1.0)}
        for name in names:
            hi, unit, scale = limits.get(name, (MAX_MAGNET_SIZE, "mm", 1e3))
            lo = 0.0 if name in limits else MIN_MAGNET_SIZE
            if not lo <= getattr(self, name) <= hi:  # beyond these the volume and the moment overflow
                interval = f"(0, {hi * scale:g}]" if lo == 0.0 else f"[{lo * scale:g}, {hi * scale:g}]"
                raise UserInputError(f"{owner}.{name} must be in {interval} {unit}, "
                                     f"got {getattr(self, name) * scale:g} {unit}")


@dataclass(frozen=True)
class CylinderMagnet(_UniformMagnet):
    """Axially magnetised cylindrical permanent magnet (the prototype's N52 76.2 x 38.1 mm).

    Attributes:
        diameter: [m].
        length: along the magnetisation axis [m].
        remanence: Br [T].
        density: [kg/m^3].
    """

    diameter: float = 76.2e-3
    length: float = 38.1e-3
    remanence: float = 1.44
    density: float = 7500.0

    @property
    def volume(self) -> float:
        """[m^3]"""
        return math.pi * (self.diameter / 2.0) ** 2 * self.length

    @property
    def bounding_radius(self) -> float:
        """Radius of the smallest sphere enclosing the cylinder [m]."""
        return math.hypot(self.diameter / 2.0, self.length / 2.0)

    def contains(self, p_M):
        """Whether points given in the magnet frame (axis = z) lie inside the body."""
        p_M = np.asarray(p_M, dtype=float)
        radial = np.hypot(p_M[..., 0], p_M[..., 1])
        return (radial < self.diameter / 2.0) & (np.abs(p_M[..., 2]) < self.length / 2.0)


@dataclass(frozen=True)
class SphereMagnet(_UniformMagnet):
    """Uniformly magnetised spherical permanent magnet (the clinical actuation magnet).

    A uniformly magnetised sphere's outside field is exactly that of a point dipole at its
    centre, so the dipole model is exact for it.

    Attributes:
        diameter: [m] (119 mm from the paper's sizing).
        remanence: Br [T].
        density: [kg/m^3].
    """

    diameter: float = 119e-3
    remanence: float = 1.44
    density: float = 7500.0

    @property
    def volume(self) -> float:
        """[m^3]"""
        return math.pi * self.diameter**3 / 6.0

    @property
    def bounding_radius(self) -> float:
        return self.diameter / 2.0

    def contains(self, p_M):
        """Whether points given in the magnet frame lie inside the sphere."""
        p_M = np.asarray(p_M, dtype=float)
        return np.linalg.norm(p_M, axis=-1) < self.diameter / 2.0


@dataclass(frozen=True)
class MagnetGrade:
    """A permanent-magnet grade the chain's balls can be made of.

    Attributes:
        name: the grade ("N52", "N42SH").
        remanence: typical Br at 20 C [T].
        max_operating_C: the highest temperature without irreversible loss of magnetisation [C].
        source: where the numbers come from.
    """

    name: str
    remanence: float
    max_operating_C: float
    source: str = ""


MAGNET_GRADES = {
    "N52": MagnetGrade(
        name="N52", remanence=BallChain.remanence, max_operating_C=N52_IRREVERSIBLE_LOSS_C,
        source="the prototype's balls (BallChain.remanence; tissue.N52_IRREVERSIBLE_LOSS_C)"),
    "N42SH": MagnetGrade(
        name="N42SH", remanence=1.30, max_operating_C=150.0,
        source=("sintered NdFeB, 'SH' (HcJ >= 20 kOe) grade: Br 1.29-1.33 T, maximum operating temperature "
                "150 C (Arnold Magnetic Technologies, Neodymium-Iron-Boron Magnet Grades catalogue; "
                "K&J Magnetics specifications table); Br -0.12 %/C as N52")),
}
"""Grades of the balls by name: N52 (the prototype) and a high-temperature option. A weaker
grade's balls have a proportionally smaller moment (``BallChain(remanence=...)``)."""


def magnet_grade(name: str) -> MagnetGrade:
    """The grade ``name`` (a UserInputError naming the allowed ones otherwise)."""
    if not isinstance(name, str) or name not in MAGNET_GRADES:
        raise UserInputError(f"magnet grade must be one of {sorted(MAGNET_GRADES)}, got {short_repr(name)}")
    return MAGNET_GRADES[name]


def gram_force(newtons: float) -> float:
    """Newtons to grams-force (the paper's force unit)."""
    return newtons / GRAVITY * 1e3


def newtons_from_gram_force(gf: float) -> float:
    return gf * 1e-3 * GRAVITY
