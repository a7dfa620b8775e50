"""The catheter-tip localisation system's figures: what a clinical navigator knows of the tip.

A magnetic ablation system does not see the chain; it sees one tracked point. Clinical
electroanatomical mapping (CARTO 3) and stand-alone electromagnetic trackers (NDI Aurora) report
a sensor coil's position a few tens of times a second, with a random error of a fraction of a
millimetre and a delay of a sample or two. ``LocalisationParams`` holds those three figures; the
defaults are the NDI Aurora's published ones, the sensor being a 5-DOF coil in the tip ball:

* ``noise_std``: 0.40 mm per axis. The Aurora's data sheet gives 0.70 mm RMS (3-D) position
  accuracy for a 5-DOF sensor in its cube measurement volume; an isotropic Gaussian with that
  RMS has a per-axis standard deviation of 0.70 / sqrt(3) = 0.40 mm. (CARTO 3's magnetic
  location is quoted below 1 mm, the same order.)
* ``rate``: 40 Hz, the Aurora's update rate with up to eight 5-DOF sensors.
* ``latency``: 50 ms, two samples at 40 Hz: the tracker's own filter and the transfer to the
  navigation computer. No data sheet states it; it is an assumption of this model, in the range
  reported for electromagnetic trackers' end-to-end delays (tens of milliseconds).

The error is modelled as white (independent per sample): the static field distortions of a real
catheter lab (a repeatable bias near metal) are not modelled.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from ballchain.infrastructure.errors import UserInputError, short_repr

NOISE_RANGE_M = (0.0, 5e-3)  # [m] per-axis standard deviation allowed
RATE_RANGE_HZ = (1.0, 1000.0)
LATENCY_RANGE_S = (0.0, 1.0)


def check_figures(noise_std, rate, latency, where: str) -> None:
    """The tracker's three figures: numbers (not bools) in their ranges, the latency a whole
    number of samples. ``where`` prefixes each field's name in the message ("localisation ",
    or "scenario localisation." for a scenario's fields).

    Raises:
        UserInputError: naming the field, the value and what is allowed.
    """
    values = {"noise_std": noise_std, "rate": rate, "latency": latency}
    for name, (lo, hi), unit in (("noise_std", NOISE_RANGE_M, "m"), ("rate", RATE_RANGE_HZ, "Hz"),
                                 ("latency", LATENCY_RANGE_S, "s")):
        value = values[name]
        if isinstance(value, bool) or not isinstance(value, numbers.Real) or not lo <= value <= hi:
            raise UserInputError(f"{where}{name} must be a number in {lo:g}..{hi:g} {unit}, got {short_repr(value)}")
    samples = latency * rate
    if abs(samples - round(samples)) > 1e-6:
        raise UserInputError(f"{where}latency must be a whole number of samples (1/rate = {1.0 / rate:g} s), "
                             f"got {short_repr(latency)} s at {rate:g} Hz")


@dataclass(frozen=True)
class LocalisationParams:
    """The tip tracker's figures (SI; module docstring for the defaults' sources).

    Attributes:
        noise_std: per-axis standard deviation of the position error [m].
        rate: samples per second [Hz].
        latency: delay from sampling to the reading's availability [s]; the sensor holds it as a
            whole number of samples (``delay_samples``).
    """

    noise_std: float = 0.70e-3 / math.sqrt(3.0)
    rate: float = 40.0
    latency: float = 0.05

    def __post_init__(self) -> None:
        check_figures(self.noise_std, self.rate, self.latency, "localisation ")

    @property
    def period(self) -> float:
        """Time between samples [s]."""
        return 1.0 / self.rate

    @property
    def delay_samples(self) -> int:
        """The latency in samples."""
        return int(round(self.latency * self.rate))
