"""Clinical actuation-magnet sizing (paper Section V-A), with the paper's typo shown beside it.

The tip force of an aligned chain in the field of a magnet of moment ``m_a`` at distance ``d``
scales as ``|f| ~ |m_chain| |m_a| / d^4``. Scaling the measured prototype force ``f_m`` (chain
moment ``m_m``, magnet volume ``V_m``, distance ``d_m``) to the clinic (chain moment
``alpha m_m``, a sphere of diameter ``d_d`` at ``d = d_c + d_d / 2``) to reach ``f_d`` gives

    alpha f_m d_m^4 V_d = f_d d^4 V_m,      V_d = (4/3) pi (d_d / 2)^3      (physics)

The geometric prefactor of the force law (3, 6, ... times ``mu0 |m_i||m_a| / (4 pi d^4)``) and
the remanence cancel in this ratio when the chain sits in the same relative direction from the
magnet in the prototype and in the clinic. The paper prints ``(d_d / 2)^4`` in place of the sphere
volume's cube (docs/design.md, 4.3): that equation is dimensionally inconsistent, so its root
depends on the unit it is evaluated in; :func:`solve_typo_equation` reports it for comparison.

The physics equation ``g(r) = alpha f_m d_m^4 (4/3) pi r^3 - f_d V_m (d_c + r)^4 = 0`` has either
no or two roots: ``r^3 / (d_c + r)^4`` peaks at ``r = 3 d_c`` (a larger magnet must sit further
away). The clinical magnet is the smaller root, bracketed on ``(0, 3 d_c]``.

SI units throughout (m, m^3, N, kg, A m^2).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import brentq

from ballchain.drake_models import paper
from ballchain.drake_models.dipole import K_DIPOLE, dipole_field, dipole_field_gradient, force_on_dipole
from ballchain.drake_models.params import MAX_DENSITY, MAX_REMANENCE, CylinderMagnet, SphereMagnet, newtons_from_gram_force
from ballchain.infrastructure.arg_checks import as_number_list, require_positive, require_type
from ballchain.infrastructure.errors import UserInputError, short_repr

PAPER = {
    "diameter_mm": 119.0,
    "mass_kg": 6.6,
    "force_between_magnets_gf": 500.0,
    "force_law_prefactor": 3.0,
}
"""The paper's printed results (Section V-A)."""


@dataclass(frozen=True)
class SizingInputs:
    """Inputs of the clinical sizing; defaults are the paper's.

    Attributes:
        alpha: chain dipole scale from the prototype to the clinical chain (8 Fr: 0.32) [-].
        measured_force: worst-case measured tip force f_m (with sleeve, 132.6 gf) [N].
        desired_force: desired clinical tip force f_d (10 gf) [N].
        measured_distance: magnet-to-target distance of the measurement d_m (16.51 cm) [m].
        heart_to_surface: heart to the outside of the patient's arm d_c (29.65 cm) [m].
        prototype_volume: volume V_m of the prototype magnet (N52 cylinder 76.2 x 38.1 mm) [m^3].
        remanence: Br of the clinical magnet (cancels in the sizing; sets its moment) [T].
        density: of the clinical magnet, for its mass [kg/m^3].
    """

    alpha: float = paper.SIZING["alpha"]
    measured_force: float = newtons_from_gram_force(paper.SIZING["measured_force_gf"])
    desired_force: float = newtons_from_gram_force(paper.SIZING["desired_force_gf"])
    measured_distance: float = paper.WORKING_DISTANCE
    heart_to_surface: float = paper.CLINICAL_DISTANCE
    prototype_volume: float = CylinderMagnet().volume
    remanence: float = 1.44
    density: float = 7500.0

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or not math.isfinite(value)
                or value <= 0
            ):
                raise UserInputError(f"SizingInputs.{name} must be a positive finite number, got {short_repr(value)}")
            lo, hi = SIZING_RANGES[name]
            if not lo <= value <= hi:
                raise UserInputError(f"SizingInputs.{name} must be in [{lo:g}, {hi:g}] (SI), got {value:g}")


# What each input may be [SI]: physical values with room to spare. Outside them the sizing's
# fourth powers overflow (a desired force of 1e-300 N), or its sphere is of no size at all.
SIZING_RANGES = {
    "alpha": (1e-6, 100.0),
    "measured_force": (1e-6, 1e3),  # [N]: 0.1 mgf .. 100 kgf
    "desired_force": (1e-6, 1e3),
    "measured_distance": (1e-3, 10.0),  # [m]
    "heart_to_surface": (1e-3, 10.0),
    "prototype_volume": (1e-12, 1.0),  # [m^3]
    "remanence": (1e-3, MAX_REMANENCE),  # [T]
    "density": (1.0, MAX_DENSITY),  # [kg/m^3]
}


@dataclass(frozen=True)
class SizingResult:
    """The clinical sphere that satisfies the physics equation.

    Attributes:
        diameter: d_d [m].
        distance: heart-to-centre distance d = d_c + d_d / 2 [m].
        mass: [kg].
        dipole_moment: Br V_d / mu0 [A m^2].
        max_diameter_for_existence: 2 * 3 d_c, where r^3 / (d_c + r)^4 peaks [m].
        second_root_diameter: the other (non-physical, huge) root of the cubic-quartic [m].
    """

    diameter: float
    distance: float
    mass: float
    dipole_moment: float
    max_diameter_for_existence: float
    second_root_diameter: float


def _residual(inputs: SizingInputs, radius: float) -> float:
    """g(r) = alpha f_m d_m^4 V_d(r) - f_d (d_c + r)^4 V_m  [N m^7]."""
    v_d = 4.0 / 3.0 * math.pi * radius**3
    return (
        inputs.alpha * inputs.measured_force * inputs.measured_distance**4 * v_d
        - inputs.desired_force * (inputs.heart_to_surface + radius) ** 4 * inputs.prototype_volume
    )


def size_clinical_magnet(inputs: SizingInputs = SizingInputs()) -> SizingResult:
    """Solve ``alpha f_m d_m^4 V_d = f_d (d_c + d_d/2)^4 V_m`` for the sphere diameter d_d.

    Args:
        inputs: the sizing inputs (SI).

    Returns:
        The smaller root (the clinical magnet) and what follows from it.

    Raises:
        ValueError: if no sphere of any size reaches the desired force (the residual is negative
            at its peak r = 3 d_c).
    """
    require_type(inputs, SizingInputs, "inputs", "a SizingInputs")
    r_peak = 3.0 * inputs.heart_to_surface
    g_peak = _residual(inputs, r_peak)
    if not g_peak > 0.0:
        raise UserInputError(
            "no spherical magnet of any diameter reaches the desired force: the force ratio "
            f"r^3/(d_c + r)^4 peaks at a diameter of {2 * r_peak * 1e3:.0f} mm and is still too small "
            "(lower the desired force or the distance, or raise alpha or the measured force)"
        )
    # g(0+) < 0 < g(3 d_c): exactly one root on (0, 3 d_c] (g / (d_c + r)^4 is increasing there).
    radius = brentq(lambda r: _residual(inputs, r), 0.0, r_peak, xtol=1e-12, rtol=1e-14)
    # The other root lies beyond the peak; g -> -inf as r -> inf. Expand the bracket to find it.
    hi = 2.0 * r_peak
    while _residual(inputs, hi) > 0.0:
        hi *= 2.0
    far_radius = brentq(lambda r: _residual(inputs, r), r_peak, hi, xtol=1e-9, rtol=1e-14)
    clinical = SphereMagnet(diameter=2.0 * radius, remanence=inputs.remanence, density=inputs.density)
    return SizingResult(
        diameter=2.0 * radius,
        distance=inputs.heart_to_surface + radius,
        mass=clinical.mass,
        dipole_moment=clinical.dipole_moment,
        max_diameter_for_existence=2.0 * r_peak,
        second_root_diameter=2.0 * far_radius,
    )


def solve_typo_equation(inputs: SizingInputs = SizingInputs(), length_unit: float = 1.0) -> float | None:
    """Root d_d of the paper's printed (typo) equation, evaluated in a chosen length unit.

    ``alpha (4/3) pi f_m d_m^4 (d_d/2)^4 - f_d (d_c + d_d/2)^4 V_m = 0``. It mixes m^8 and m^7, so
    its root depends on the unit the lengths are written in: ``length_unit`` is that unit in
    metres (1 for m, 0.01 for cm, 1e-3 for mm). Forces enter as a ratio, so their unit cancels.

    Args:
        inputs: the sizing inputs (SI).
        length_unit: the length unit in which the equation is evaluated [m].

    Returns:
        The diameter [m] (converted back to SI), or None if the equation has no positive root.
    """
    require_type(inputs, SizingInputs, "inputs", "a SizingInputs")
    require_positive(length_unit, "length_unit", "m")
    if not (math.isfinite(length_unit) and length_unit > 0):
        raise UserInputError(f"length_unit must be a positive finite number of metres, got {length_unit!r}")
    d_m = inputs.measured_distance / length_unit
    d_c = inputs.heart_to_surface / length_unit
    v_m = inputs.prototype_volume / length_unit**3
    coeff = inputs.alpha * 4.0 / 3.0 * math.pi * inputs.measured_force * d_m**4
    rhs = inputs.desired_force * v_m

    def residual(r: float) -> float:
        return coeff * r**4 - rhs * (d_c + r) ** 4

    # Both sides are fourth powers: a positive root exists iff coeff > rhs (then it is unique).
    if not coeff > rhs:
        return None
    hi = d_c
    while residual(hi) < 0.0:
        hi *= 2.0
    radius = brentq(residual, 0.0, hi, xtol=1e-14 * hi, rtol=1e-14)
    return 2.0 * radius * length_unit


# Relative orientations of two magnets on the x axis: (m_A direction, m_B direction).
ORIENTATIONS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "coaxial_head_to_tail": ((1.0, 0.0, 0.0), (1.0, 0.0, 0.0)),
    "coaxial_head_to_head": ((1.0, 0.0, 0.0), (-1.0, 0.0, 0.0)),
    "side_by_side_parallel": ((0.0, 0.0, 1.0), (0.0, 0.0, 1.0)),
    "side_by_side_antiparallel": ((0.0, 0.0, 1.0), (0.0, 0.0, -1.0)),
}
"""Dipole directions of magnet A (at the origin) and magnet B (on +x)."""


def force_between_magnets(moment: float, separation: float) -> dict[str, dict[str, float]]:
    """Force between two equal point dipoles (exact for uniformly magnetised spheres).

    Args:
        moment: |m| of each magnet [A m^2].
        separation: centre-to-centre distance [m].

    Returns:
        For each orientation in :data:`ORIENTATIONS`: ``force_N`` (magnitude on magnet B),
        ``attractive`` (1.0 if B is pulled towards A, else 0.0) and ``prefactor`` (the force in
        units of ``mu0 m^2 / (4 pi s^4)``).
    """
    require_positive(moment, "moment", "A m^2")
    require_positive(separation, "separation", "m")
    if not (math.isfinite(moment) and moment > 0 and math.isfinite(separation) and separation > 0):
        raise UserInputError(f"moment and separation must be positive finite, got {moment!r}, {separation!r}")
    r_AB = np.array([separation, 0.0, 0.0])
    out = {}
    for name, (u_a, u_b) in ORIENTATIONS.items():
        m_a = moment * np.asarray(u_a)
        m_b = moment * np.asarray(u_b)
        f_b = force_on_dipole(m_b, dipole_field_gradient(r_AB, m_a))
        unit = K_DIPOLE * moment**2 / separation**4
        out[name] = {
            "force_N": float(np.linalg.norm(f_b)),
            "attractive": float(f_b[0] < 0.0),
            "prefactor": float(np.linalg.norm(f_b) / unit),
        }
    return out


def aligned_force_prefactors(polar_angles_deg=(0.0, 45.0, 90.0)) -> dict[float, float]:
    """Force on a dipole aligned with a point dipole's field, in units of mu0 |m_i||m_a| / (4 pi d^4).

    The force on a freely aligning dipole is ``|m_i| grad|B|``; its magnitude is
    ``c(theta) mu0 |m_i||m_a| / (4 pi d^4)`` with ``c = 6`` on the axis, ``3`` on the equator.
    The paper's ``|f| = 3 mu0 |m_i||m_a| / (4 pi d^4)`` is the equatorial value (the smallest).

    Args:
        polar_angles_deg: angles from the source dipole's axis [deg].

    Returns:
        ``{angle_deg: c}``.
    """
    as_number_list(polar_angles_deg, "polar_angles_deg", 0.0, 180.0, unit="deg")
    m_a = np.array([0.0, 0.0, 1.0])
    out = {}
    for angle in polar_angles_deg:
        t = math.radians(angle)
        r = np.array([math.sin(t), 0.0, math.cos(t)])  # unit distance
        B = dipole_field(r, m_a)
        m_i = B / np.linalg.norm(B)
        f = force_on_dipole(m_i, dipole_field_gradient(r, m_a))
        out[float(angle)] = float(np.linalg.norm(f) / K_DIPOLE)
    return out
