"""The moving wall: periodic rigid motion of the anatomy (respiration and the heart beat).

The motion law has its one home here. Two sinusoidal translations (no rotation) of frame H of
the heart in the world W of the magnets (the cart, the room):

* Respiration moves the whole heart, the sheath with it (the septal puncture holds the
  sheath's tip), relative to the magnets on the cart: ``heart_offset(t) = A_r sin(2 pi f_r t)
  u_r``. The feeder's inserted length is measured along the sheath and does not change (the
  sheath's slack in the veins takes the motion up): the chain's base moves with the heart.
* The heart beat moves the wall relative to the septal puncture (the sheath): the wall's
  offset in W is ``wall_offset(t) = heart_offset(t) + A_c sin(2 pi f_c t) u_c``.

Both start at zero (t = 0 is the rest pose), so a run with the wall moving starts where the
still one does. A amplitude is the sinusoid's (half the peak-to-peak excursion).

Defaults (adult, supine, sinus rhythm; typical values quoted from the literature, not a fit to
any one study):

* Respiration, 5 mm along +z (10 mm peak to peak, supero-inferior) at 0.25 Hz (15 breaths a
  minute). The heart moves mostly supero-inferiorly with the diaphragm, by about 0.6 of the
  diaphragm's excursion (Wang et al., "Respiratory motion of the heart: kinematics and the
  implications for the spatial resolution in coronary imaging", Magn Reson Med 33:713, 1995;
  McLeish et al., "A study of the motion and deformation of the heart due to respiration",
  IEEE Trans Med Imaging 21:1142, 2002), which is 10-20 mm in quiet breathing: about 6-12 mm
  for the heart; the left atrium and the pulmonary veins follow with the same order of
  magnitude, and respiratory gating of electro-anatomical maps is used in ablation for that
  reason (e.g. Szeplaki et al., J Interv Card Electrophysiol 46:115, 2016).
* Heart beat, 1 mm (2 mm peak to peak) at 1.2 Hz (72 beats a minute) along the heart's long
  axis (from the base towards the apex: left, anterior, inferior, (1, 1, -1)/sqrt(3) in H): the
  atrio-ventricular plane descends towards the apex in systole and pulls the atrium's floor and
  back wall with it. At the pulmonary-vein antra the wall moves by about a millimetre: the
  veins' ostial diameters change by 15 +- 8 % over the cycle ("Variation in pulmonary vein
  size during the cardiac cycle: implications for non-electrocardiogram-gated imaging",
  Am Heart J, 2006), i.e. about 2.4 mm on a 16 mm ostium, 1.2 mm on each side.

Where the quasi-static assumption stops holding (``inertial_and_viscous_forces``,
``quasi_static_limit``): the engine places the chain at its equilibrium for the wall's pose at
each update and ignores the forces the motion itself costs: the balls' inertia (with the
blood's added mass, half the displaced volume) and the blood's drag on them. Sized as an upper
bound (every free ball moving with the wall's full acceleration and speed through still blood,
no shielding between balls, the drag of a sphere at the ball's Reynolds number), for the 16
balls of the paper's chain against the 20 gf contact force (0.196 N): with the default cardiac
amplitude (1 mm) they are 0.07 % of the contact force at 1.2 Hz (0.14 mN, inertia 86 %) and
reach 10 % at 15 Hz; with the respiratory amplitude (5 mm) they are 0.02 % at 0.25 Hz and reach
10 % at 6.4 Hz (``tests/test_wall_motion.py`` recomputes these numbers). Both physiological
frequencies are far below: the quasi-static engine holds for the wall's motion; it does not
hold for motions of this size faster than a few hertz (a tremor, a flutter of the valve).
``docs/guide/moving_wall.md`` lists the numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ballchain.infrastructure.errors import UserInputError, short_repr

# Defaults (see the module docstring for the sources).
RESPIRATORY_AMPLITUDE = 5e-3  # [m]
RESPIRATORY_FREQUENCY = 0.25  # [Hz]
RESPIRATORY_DIRECTION = (0.0, 0.0, 1.0)  # supero-inferior, frame H
CARDIAC_AMPLITUDE = 1e-3  # [m]
CARDIAC_FREQUENCY = 1.2  # [Hz]
CARDIAC_DIRECTION = (1.0, 1.0, -1.0)  # the long axis, base to apex (normalised by Oscillation)

# Limits of the scenario's values: beyond them a number is a unit mistake, not a physiology.
MAX_AMPLITUDE = 0.02  # [m]: 2 cm is more than the heart moves in a deep breath
MAX_FREQUENCY = 5.0  # [Hz]: 300 beats a minute; the quasi-static engine stops holding near there

BLOOD_DENSITY = 1060.0  # [kg/m^3]
BLOOD_VISCOSITY = 3.5e-3  # [Pa s], whole blood at high shear rates
CONTACT_FORCE = 20e-3 * 9.80665  # [N]: 20 gf, the procedure's target contact force


@dataclass(frozen=True)
class Oscillation:
    """One sinusoidal translation ``amplitude sin(2 pi frequency t) direction``.

    Attributes:
        amplitude: [m] (>= 0; half the peak-to-peak excursion).
        frequency: [Hz] (> 0).
        direction: (3,) unit vector (normalised here).
    """

    amplitude: float
    frequency: float
    direction: tuple

    def __post_init__(self) -> None:
        check_oscillation(self.amplitude, self.frequency, self.direction, "Oscillation")
        d = np.asarray(self.direction, float)
        object.__setattr__(self, "direction", tuple(float(x) for x in d / np.linalg.norm(d)))

    @property
    def period(self) -> float:
        return 1.0 / self.frequency

    def offset(self, t: float) -> np.ndarray:
        """(3,) the displacement at time t [s] [m]."""
        return (self.amplitude * math.sin(2.0 * math.pi * self.frequency * t)) * np.asarray(self.direction)

    def velocity(self, t: float) -> np.ndarray:
        """(3,) d offset / dt [m/s]."""
        w = 2.0 * math.pi * self.frequency
        return (self.amplitude * w * math.cos(w * t)) * np.asarray(self.direction)


@dataclass(frozen=True)
class WallMotion:
    """The anatomy's motion (module docstring): respiration moves the heart and the sheath in
    the magnets' world, the heart beat moves the wall relative to the sheath.

    Attributes:
        respiratory: the heart's (and the sheath's) motion in the world.
        cardiac: the wall's motion relative to the sheath.
    """

    respiratory: Oscillation
    cardiac: Oscillation

    @classmethod
    def default(cls) -> WallMotion:
        return cls(Oscillation(RESPIRATORY_AMPLITUDE, RESPIRATORY_FREQUENCY, RESPIRATORY_DIRECTION),
                   Oscillation(CARDIAC_AMPLITUDE, CARDIAC_FREQUENCY, CARDIAC_DIRECTION))

    @property
    def still(self) -> bool:
        """Both amplitudes zero: nothing moves (the engine then runs exactly as without motion)."""
        return self.respiratory.amplitude == 0.0 and self.cardiac.amplitude == 0.0

    def to_dict(self) -> dict:
        """The motion in a results file's units: per part its amplitude [mm], frequency [Hz] and
        direction (unit vector; respiratory: the heart's in the world, cardiac: the wall's
        relative to the sheath)."""
        return {name: {"amplitude_mm": o.amplitude * 1e3, "frequency_hz": o.frequency, "direction": list(o.direction)}
                for name, o in (("respiratory", self.respiratory), ("cardiac", self.cardiac))}

    def heart_offset(self, t: float) -> np.ndarray:
        """(3,) where the heart and the sheath are at time t, from their rest pose [m]."""
        return self.respiratory.offset(t)

    def wall_offset(self, t: float) -> np.ndarray:
        """(3,) where the atrium's wall (and its targets) is at time t, from its rest pose [m]."""
        return self.respiratory.offset(t) + self.cardiac.offset(t)


def check_oscillation(amplitude, frequency, direction, where: str, direction_name: str = "direction") -> None:
    """An amplitude in [0, MAX_AMPLITUDE] m, a frequency in (0, MAX_FREQUENCY] Hz and a direction
    of 3 finite components, not all zero.

    Raises:
        UserInputError: naming ``where``'s field, the value and what is allowed.
    """
    real = (int, float, np.floating, np.integer)
    if isinstance(amplitude, bool) or not isinstance(amplitude, real) or not 0.0 <= amplitude <= MAX_AMPLITUDE:
        raise UserInputError(f"{where}.amplitude must be a number in [0, {MAX_AMPLITUDE:g}] m (half the peak-to-peak "
                             f"excursion; 5 mm is 0.005), got {short_repr(amplitude)}")
    if isinstance(frequency, bool) or not isinstance(frequency, real) or not 0.0 < frequency <= MAX_FREQUENCY:
        raise UserInputError(f"{where}.frequency must be a number in (0, {MAX_FREQUENCY:g}] Hz, "
                             f"got {short_repr(frequency)}")
    try:
        d = np.asarray(direction, float)
    except (TypeError, ValueError):
        d = None
    if d is None or d.shape != (3,) or not np.all(np.isfinite(d)) or not np.any(d):
        raise UserInputError(f"{where}.{direction_name} must be 3 finite components, not all zero, "
                             f"got {short_repr(direction)}")


def inertial_and_viscous_forces(amplitude: float, frequency: float, n_balls: int, ball_diameter: float,
                                ball_density: float) -> tuple[float, float]:
    """Upper bounds of the forces a sinusoidal motion costs the chain (module docstring).

    Every one of ``n_balls`` balls moves with the wall's peak acceleration and peak speed
    through still blood: inertia ``n (m + m_added) A w^2`` (m_added half the displaced blood),
    drag ``n 1/2 rho v^2 C_d pi r^2`` with ``C_d = 24/Re (1 + 0.15 Re^0.687)`` (a sphere's
    steady drag, Schiller-Naumann, Re < 800) at ``v = A w``.

    Returns:
        ``(inertial, viscous)`` peak forces [N].
    """
    w = 2.0 * math.pi * frequency
    r = 0.5 * ball_diameter
    volume = math.pi * ball_diameter**3 / 6.0
    inertial = n_balls * (ball_density + 0.5 * BLOOD_DENSITY) * volume * amplitude * w * w
    v = amplitude * w
    if v == 0.0:
        return inertial, 0.0
    re = BLOOD_DENSITY * v * ball_diameter / BLOOD_VISCOSITY
    cd = 24.0 / re * (1.0 + 0.15 * re**0.687)
    viscous = n_balls * 0.5 * BLOOD_DENSITY * v * v * cd * math.pi * r * r
    return inertial, viscous


def quasi_static_limit(amplitude: float, n_balls: int, ball_diameter: float, ball_density: float,
                       contact_force: float = CONTACT_FORCE, fraction: float = 0.1) -> float:
    """The frequency [Hz] at which a motion of ``amplitude`` [m] costs the chain (inertia plus
    drag, ``inertial_and_viscous_forces``) ``fraction`` of ``contact_force`` [N]: above it the
    quasi-static engine's answer is off by more than that fraction. Both forces grow with the
    frequency: bisection on a log scale from 1 mHz to 1 kHz (inf when even 1 kHz stays below)."""
    def excess(f):
        return sum(inertial_and_viscous_forces(amplitude, f, n_balls, ball_diameter, ball_density)) \
            - fraction * contact_force

    lo, hi = 1e-3, 1e3
    if excess(hi) < 0.0:
        return math.inf
    if excess(lo) >= 0.0:
        return lo
    for _ in range(100):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if excess(mid) < 0.0 else (lo, mid)
    return hi
