"""The RF generator as a clinic runs it: power control or temperature control, with limits.

- Power control (``mode="power"``): the set power, reduced when the hottest tissue reaches the
  cut-off at vaporisation (``tissue.temperature_limited_voltage_squared``, the bench model's law).
- Temperature control (``mode="temperature"``): the power that holds the electrode's hottest
  point (the tip's thermocouple / thermistor) at ``target_C``, never above ``power_W`` (the
  power cap). Clinical non-irrigated RF: a target of 55-65 C with a 30-50 W cap (the usual
  settings of 4 mm-tip temperature-controlled ablation; the 50-60 C window of the generators'
  manuals). The tissue cut-off applies as well.
- The magnet's limit (``electrode_limit_C``): for the ball chain the electrode IS the tip ball's
  NdFeB magnet, so its hottest point is held below the grade's limit less a margin in either
  mode (``lesion_surrogate.MAGNET_MARGIN_C``): the same loop as temperature control, with the
  magnet's limit as its set point.

The loop is ideal: within each implicit step the temperatures are affine in V^2 (the Joule
source is sigma |grad V|^2 at the step's conductivities), so the largest V^2 meeting every limit
is solved exactly (no overshoot, no lag). A clinical PI loop settles in 1-3 s and overshoots by a
few C; over 30-60 s applications that is a small part of the dwell.

The delivered power (V^2 G) is what the model reports beside the set power: once a limit holds,
they differ (the "15 W is 2-4 W" finding of the bench model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ballchain.drake_models import tissue as laws
from ballchain.infrastructure.errors import UserInputError, short_repr

MODES = ("power", "temperature")
CLINICAL_TARGET_C = 60.0  # [C] the middle of the clinical 55-65 C window
TARGET_RANGE_C = (40.0, 95.0)


@dataclass(frozen=True)
class Generator:
    """The generator's settings.

    Attributes:
        mode: "power" (constant power) or "temperature" (electrode held at ``target_C``).
        power_W: the set power (power mode) or the power cap (temperature mode) [W].
        target_C: the electrode's set temperature (temperature mode) [C].
        electrode_limit_C: a limit on the electrode's hottest point in either mode (the magnet's), or None.
        cutoff_C: the tissue cut-off at vaporisation [C] or None.
        max_voltage_V: the generator's voltage limit [V rms] or None.
    """

    mode: str = "power"
    power_W: float = 30.0
    target_C: float = CLINICAL_TARGET_C
    electrode_limit_C: float | None = None
    cutoff_C: float | None = laws.VAPORISATION_ONSET_C
    max_voltage_V: float | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise UserInputError(f"generator mode must be one of {MODES}, got {short_repr(self.mode)}")
        if not (isinstance(self.power_W, (int, float)) and math.isfinite(self.power_W) and self.power_W >= 0):
            raise UserInputError(f"power_W must be a finite number >= 0, got {short_repr(self.power_W)}")
        lo, hi = TARGET_RANGE_C
        if self.mode == "temperature" and not (isinstance(self.target_C, (int, float))
                                               and lo <= self.target_C <= hi):
            raise UserInputError(f"target_C must be in [{lo:g}, {hi:g}] C, got {short_repr(self.target_C)}")

    @property
    def electrode_set_point_C(self) -> float | None:
        """The electrode's effective limit: the lower of the target (temperature mode) and the magnet's limit."""
        limits = [v for v in ((self.target_C if self.mode == "temperature" else None), self.electrode_limit_C)
                  if v is not None]
        return min(limits) if limits else None

    def voltage_squared(self, conductance_S: float, t_unpowered, t_per_v2, water_nodes, sensor_nodes) -> tuple:
        """The step's V^2 and which limit set it.

        Args:
            conductance_S: the load's conductance at the step's temperatures [S].
            t_unpowered: (n,) temperatures after the step without power [C].
            t_per_v2: (n,) their rise per V^2 [C/V^2].
            water_nodes: nodes of the tissue (and still fluid) under the cut-off.
            sensor_nodes: the electrode's nodes (the sensor, the magnet).
        Returns:
            (V^2 [V^2], "power" | "cutoff" | "electrode": the limit that set it).
        """
        v2 = laws.constant_power_voltage(self.power_W, conductance_S, self.max_voltage_V) ** 2
        which = "power"
        v2_cut = laws.temperature_limited_voltage_squared(v2, t_unpowered[water_nodes], t_per_v2[water_nodes],
                                                          self.cutoff_C)
        if v2_cut < v2 * (1 - 1e-12):
            v2, which = v2_cut, "cutoff"
        set_point = self.electrode_set_point_C
        if set_point is not None and len(sensor_nodes):
            v2_el = laws.temperature_limited_voltage_squared(v2, t_unpowered[sensor_nodes], t_per_v2[sensor_nodes],
                                                             set_point)
            if v2_el < v2 * (1 - 1e-12):
                v2, which = v2_el, "electrode"
        return v2, which
