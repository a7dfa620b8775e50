"""Electro-thermal properties and laws for RF ablation: tissue, saline, electrodes, damage, generator.

One place for every law the lesion model (``lesion_fem.py``) uses:

- material properties (electrical and thermal) with their literature source;
- the temperature dependence of the electrical conductivity (+1.5 %/C in tissue, +2 %/C in
  saline) and its roll-off at vaporisation (two decades between 100 and 105 C);
- the thermal conductivity's temperature dependence;
- the Arrhenius damage integral (Omega = 1 is the lesion boundary) and the 50 C isotherm;
- the generator in constant-power mode (the voltage that delivers the set power);
- the analytic spreading resistances used to check the electric solve;
- the magnet's temperature limits (N52).

SI units except temperatures, which are in degrees Celsius (Kelvin only inside the Arrhenius
law). Sources are cited in each docstring; the numbers were taken as published, never tuned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ballchain.drake_models.errors import UserInputError

GAS_CONSTANT = 8.314462618  # R [J/(mol K)]
KELVIN = 273.15
LESION_ISOTHERM_C = 50.0  # the 50 C isotherm: the usual thermal proxy for the lesion boundary
VAPORISATION_ONSET_C = 100.0
VAPORISATION_END_C = 105.0
VAPORISATION_DROP = 1e-2  # sigma falls by two decades between 100 and 105 C

# N52 sintered NdFeB: maximum operating temperature about 80 C (irreversible loss of
# magnetisation above it, grade-dependent: N52 is rated 60-80 C); Curie temperature about 310 C.
N52_IRREVERSIBLE_LOSS_C = 80.0
NDFEB_CURIE_C = 310.0


@dataclass(frozen=True)
class Material:
    """An electro-thermal material.

    Attributes:
        name: label.
        electrical_conductivity: sigma at ``reference_temperature_C`` [S/m] (0 for insulators).
        sigma_temperature_coefficient: relative rise of sigma per degree [1/C].
        thermal_conductivity: k at ``reference_temperature_C`` [W/(m K)].
        k_temperature_slope: dk/dT below 100 C [W/(m K C)].
        density: rho [kg/m^3].
        specific_heat: c [J/(kg K)].
        reference_temperature_C: temperature of the reference values [C].
        vaporises: whether sigma rolls off at 100 C (water-based media).
        source: where the numbers come from.
    """

    name: str
    electrical_conductivity: float
    sigma_temperature_coefficient: float
    thermal_conductivity: float
    k_temperature_slope: float
    density: float
    specific_heat: float
    reference_temperature_C: float = 37.0
    vaporises: bool = False
    source: str = ""

    @property
    def volumetric_heat_capacity(self) -> float:
        """rho c [J/(m^3 K)]."""
        return self.density * self.specific_heat


MYOCARDIUM = Material(
    name="myocardium",
    electrical_conductivity=0.54,
    sigma_temperature_coefficient=0.015,
    thermal_conductivity=0.56,
    k_temperature_slope=0.0012,
    density=1081.0,
    specific_heat=3686.0,
    vaporises=True,
    source=(
        "sigma 0.54 S/m at 500 kHz, 37 C (Tungjitkusolmun et al., IEEE TBME 47:32, 2000, the value "
        "of most cardiac RF models); +1.5 %/C and k + 0.0012 W/(m K) per C (Berjano, Biomed. Eng. "
        "Online 5:24, 2006); rho 1081 kg/m^3, c 3686 J/(kg K), k 0.56 W/(m K) for heart muscle "
        "(IT'IS tissue database, Hasgall et al.)"
    ),
)
"""Porcine/human heart muscle (the paper's ventricle specimen)."""

LIVER = Material(
    name="liver",
    electrical_conductivity=0.148,
    sigma_temperature_coefficient=0.015,
    thermal_conductivity=0.52,
    k_temperature_slope=0.0012,
    density=1079.0,
    specific_heat=3540.0,
    vaporises=True,
    source=(
        "sigma 0.148 S/m at 500 kHz (Tungjitkusolmun et al., IEEE TBME 49:3, 2002); +1.5 %/C "
        "(Berjano 2006); rho 1079, c 3540, k 0.52 (IT'IS tissue database)"
    ),
)
"""Liver: the other common ex-vivo ablation tissue (for comparison)."""

SALINE = Material(
    name="saline 0.9 %",
    electrical_conductivity=1.6,
    sigma_temperature_coefficient=0.02,
    thermal_conductivity=0.60,
    k_temperature_slope=0.0,
    density=1000.0,
    specific_heat=4180.0,
    reference_temperature_C=25.0,
    vaporises=True,
    source=(
        "0.154 mol/L NaCl: molar conductivity about 106 S cm^2/mol at 25 C gives 1.6 S/m "
        "(Kohlrausch tables); +2 %/C, the usual coefficient of dilute NaCl; water's k, rho, c"
    ),
)
"""0.9 % NaCl. Its 1.6 S/m is at 25 C: at 37 C it is about 2.0 S/m."""

NDFEB = Material(
    name="NdFeB N52 (nickel plated)",
    electrical_conductivity=6.7e5,
    sigma_temperature_coefficient=0.0,
    thermal_conductivity=9.0,
    k_temperature_slope=0.0,
    density=7500.0,
    specific_heat=440.0,
    source=(
        "sintered NdFeB datasheet values: resistivity 1.5 uOhm m, k about 9 W/(m K), c about "
        "440 J/(kg K); density as drake_models.params.BallChain. The Ni-Cu-Ni plating (10-20 um, "
        "Ni 1.4e7 S/m) carries the current along the chain's surface; too thin to matter thermally. "
        "The chain's series resistance is negligible: a 2.2 N ball-ball contact has a Hertz radius of "
        "about 25 um, a Holm constriction resistance rho_Ni / (2 a) of about 1.4 mOhm, 16 of them "
        "about 0.02 Ohm against the tissue's 100 Ohm"
    ),
)
"""The balls. Their conductivity (6.7e5 S/m, 1e6 times tissue) makes the ball an equipotential."""

PLATINUM_IRIDIUM = Material(
    name="platinum-iridium",
    electrical_conductivity=4.0e6,
    sigma_temperature_coefficient=0.0,
    thermal_conductivity=71.0,
    k_temperature_slope=0.0,
    density=21500.0,
    specific_heat=132.0,
    source="Pt-Ir tip electrode as in the RF models reviewed by Berjano (2006): k 71, rho 21500, c 132",
)
"""A standard catheter's tip electrode."""

POLYMER = Material(
    name="polymer (shaft, sleeve, shrink wrap)",
    electrical_conductivity=0.0,
    sigma_temperature_coefficient=0.0,
    thermal_conductivity=0.2,
    k_temperature_slope=0.0,
    density=1100.0,
    specific_heat=1500.0,
    source="generic polyurethane / silicone: k about 0.2 W/(m K); an insulator",
)
"""The catheter shaft and the chain's silicone sleeve above the electrode (insulating)."""

TISSUES = {"myocardium": MYOCARDIUM, "liver": LIVER}


@dataclass(frozen=True)
class Arrhenius:
    """First-order damage kinetics: dOmega/dt = A exp(-Ea / (R T)).

    Attributes:
        frequency_factor: A [1/s].
        activation_energy: Ea [J/mol].
        source: where the constants come from.
    """

    frequency_factor: float
    activation_energy: float
    source: str = ""

    def rate(self, temperature_C):
        """dOmega/dt [1/s] at temperatures [C] (any shape)."""
        t_k = np.asarray(temperature_C, dtype=float) + KELVIN
        return self.frequency_factor * np.exp(-self.activation_energy / (GAS_CONSTANT * t_k))

    def damage(self, temperatures_C, times_s):
        """Omega = integral of the rate over a temperature history (trapezoid rule).

        Args:
            temperatures_C: (n_times, ...) temperatures [C].
            times_s: (n_times,) increasing times [s].
        Returns:
            Omega at the end, shape of one temperature sample.
        """
        rates = self.rate(temperatures_C)
        dt = np.diff(np.asarray(times_s, dtype=float))
        return np.tensordot(dt, 0.5 * (rates[1:] + rates[:-1]), axes=(0, 0))


ARRHENIUS_MYOCARDIUM = Arrhenius(
    frequency_factor=2.94e39,
    activation_energy=2.596e5,
    source="cardiac tissue, Chang & Nguyen, Biomed. Eng. Online 3:27, 2004 (used by most cardiac RF models)",
)
ARRHENIUS_LIVER = Arrhenius(
    frequency_factor=7.39e39,
    activation_energy=2.577e5,
    source="liver coagulation (Jacques; as in Chang & Nguyen 2004)",
)
DAMAGE_MODELS = {"myocardium": ARRHENIUS_MYOCARDIUM, "liver": ARRHENIUS_LIVER}


def vaporisation_factor(temperature_C):
    """sigma multiplier for water-based media: 1 below 100 C, log-linear to 1e-2 at 105 C and beyond.

    The usual way RF models (Berjano 2006) represent desiccation and vapour at the electrode:
    the tissue stops conducting. Latent heat is not modelled (the temperature is free to rise
    past 100 C, which the model reports as vaporisation).
    """
    t = np.asarray(temperature_C, dtype=float)
    frac = np.clip((t - VAPORISATION_ONSET_C) / (VAPORISATION_END_C - VAPORISATION_ONSET_C), 0.0, 1.0)
    return VAPORISATION_DROP**frac


def electrical_conductivity(material: Material, temperature_C):
    """sigma(T) = sigma_ref (1 + alpha (T - T_ref)) [S/m], rolled off at vaporisation.

    The linear rise is clipped at 100 C (the roll-off takes over) and never below 10 % of the
    reference value (cold saline far from the electrode stays conductive).
    """
    t = np.asarray(temperature_C, dtype=float)
    linear = 1.0 + material.sigma_temperature_coefficient * (np.minimum(t, VAPORISATION_ONSET_C)
                                                             - material.reference_temperature_C)
    sigma = material.electrical_conductivity * np.maximum(linear, 0.1)
    if material.vaporises:
        sigma = sigma * vaporisation_factor(t)
    return sigma


def thermal_conductivity(material: Material, temperature_C):
    """k(T) = k_ref + slope (T - T_ref), the slope held above 100 C [W/(m K)]."""
    t = np.minimum(np.asarray(temperature_C, dtype=float), VAPORISATION_ONSET_C)
    return material.thermal_conductivity + material.k_temperature_slope * (t - material.reference_temperature_C)


def constant_power_voltage(power_W: float, conductance_S: float, max_voltage_V: float | None = None) -> float:
    """The generator in constant-power mode: V = sqrt(P / G), limited to ``max_voltage_V``.

    The electric problem is linear for fixed conductivities, so the current at 1 V is the load's
    conductance G and V^2 G = P delivers the set power exactly.

    Args:
        power_W: set power [W].
        conductance_S: load conductance G = 1/Z at the present temperatures [S].
        max_voltage_V: the generator's voltage limit [V rms], or None for none.
    Returns:
        electrode voltage [V rms].
    """
    if conductance_S <= 0:
        raise ValueError(f"load conductance must be positive, got {conductance_S}")
    voltage = math.sqrt(max(power_W, 0.0) / conductance_S)
    return voltage if max_voltage_V is None else min(voltage, max_voltage_V)


def temperature_limited_voltage_squared(v2_set: float, t_unpowered, t_per_v2, limit_C: float | None) -> float:
    """The generator's cut-off at vaporisation: the largest V^2 <= ``v2_set`` keeping T <= ``limit_C``.

    Over one implicit step the temperature is affine in V^2: T = t_unpowered + V^2 t_per_v2
    (Joule heat is sigma |grad V|^2 with sigma fixed over the step). Water-based media do not
    heat past boiling while they hold water: desiccation and vapour at the electrode raise the
    impedance and the generator's delivered power falls (an electrosurgical unit's output
    drops above its rated load). This law idealises that: full set power until the hottest
    tissue or saline point reaches ``limit_C``, then the power that holds it there (0 if the
    unpowered step already exceeds it). ``limit_C = None`` is the pure constant-power law.

    Args:
        v2_set: V^2 of the constant-power law [V^2].
        t_unpowered: (n,) temperatures after the step without power [C].
        t_per_v2: (n,) temperature rise per V^2 [C/V^2].
        limit_C: the cut-off temperature [C] or None.
    Returns:
        V^2 to apply [V^2].
    """
    if limit_C is None:
        return v2_set
    t_unpowered = np.asarray(t_unpowered, dtype=float)
    t_per_v2 = np.asarray(t_per_v2, dtype=float)
    if np.any(t_unpowered >= limit_C):
        return 0.0
    heated = t_per_v2 > 0
    if not np.any(heated):
        return v2_set
    return float(min(v2_set, np.min((limit_C - t_unpowered[heated]) / t_per_v2[heated])))


def spreading_resistance_hemisphere(sigma: float, radius: float, outer_radius: float = math.inf) -> float:
    """R of a hemispherical electrode in a half space (ground at ``outer_radius``) [Ohm].

    R = (1/a - 1/b) / (2 pi sigma); b -> infinity gives 1 / (2 pi sigma a).
    """
    return (1.0 / radius - 1.0 / outer_radius) / (2.0 * math.pi * sigma)


def spreading_resistance_disc(sigma: float, radius: float) -> float:
    """R of a flat disc electrode on the surface of a half space: 1 / (4 sigma a) [Ohm]."""
    return 1.0 / (4.0 * sigma * radius)


def tissue(name: str) -> tuple[Material, Arrhenius]:
    """The tissue's properties and damage kinetics by name ('myocardium' or 'liver')."""
    if name not in TISSUES:
        raise UserInputError(f"tissue {name!r} is not known; choose one of {sorted(TISSUES)}")
    return TISSUES[name], DAMAGE_MODELS[name]
