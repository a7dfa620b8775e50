"""Both devices' lesions as in a beating heart (issue 44): blood flow, irrigation, a clinical generator.

``ablation.run`` is the paper's bench: still saline, constant power with the cut-off at 100 C.
Here the same two electrodes run in ``drake_models/lesion_clinical.py``: blood flowing past the
electrode and the wall (Newton cooling, ``lesion_boundary``), the catheter open-irrigated or not,
the generator in power or temperature control (``rf_generator``), and the ball chain's tip magnet
held below its grade's limit less ``lesion_surrogate.MAGNET_MARGIN_C`` by the same loop. The
contact force sets the indentation through Hertz's law of ``lesion_surrogate`` (the ball's and
the catheter dome's radius). Each device reports the set and the delivered power (they differ
once a limit holds), the impedance and its drop, which limit set the power for how long, and
the magnet's peak.

Irrigation is the catheter's only: the ball chain's tip ball has no lumen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from ballchain.drake_models import lesion_boundary as boundary
from ballchain.drake_models import lesion_clinical as clinical
from ballchain.drake_models import lesion_surrogate as surrogate
from ballchain.drake_models import params
from ballchain.drake_models import rf_generator
from ballchain.drake_models import tissue as laws
from ballchain.experiments import ablation
from ballchain.experiments._result import Result
from ballchain.infrastructure.errors import UserInputError, short_repr

CONTROLS = rf_generator.MODES
INDENTATION_RANGE_MM = (0.1, 1.3)  # ablation.check_settings: the catheter's radius is 1.33 mm


@dataclass
class ClinicalSettings(Result):
    """The clinical choices (None contact force: ``indentation_mm`` as given).

    Attributes:
        blood_flow: "none", "low" or "high".
        irrigation: "none" or "open" (the catheter only).
        control: "power" or "temperature".
        target_temperature_C: the electrode's set point under temperature control [C].
        contact_force_gf: the contact force [gf] or None.
        magnet_grade: the tip ball's magnet grade (``params.MAGNET_GRADES``).
    """

    blood_flow: str = "none"
    irrigation: str = "none"
    control: str = "power"
    target_temperature_C: float = rf_generator.CLINICAL_TARGET_C
    contact_force_gf: float | None = None
    magnet_grade: str = "N52"

    def check(self) -> None:
        """UserInputError naming the setting when a value is not allowed."""
        boundary.conditions(self.blood_flow, self.irrigation)
        if self.control not in CONTROLS:
            raise UserInputError(f"control must be one of {CONTROLS}, got {short_repr(self.control)}")
        lo, hi = rf_generator.TARGET_RANGE_C
        t = self.target_temperature_C
        if not (isinstance(t, (int, float)) and math.isfinite(t) and lo <= t <= hi):
            raise UserInputError(f"target_temperature_C must be in [{lo:g}, {hi:g}] C, got {short_repr(t)}")
        f = self.contact_force_gf
        if f is not None and not (isinstance(f, (int, float)) and math.isfinite(f) and 1.0 <= f <= 100.0):
            raise UserInputError(f"contact_force_gf must be in [1, 100] gf, got {short_repr(f)}")
        params.magnet_grade(self.magnet_grade)


def electrode_radius_m(device: str) -> float:
    """The radius of the electrode's end pressed into the wall [m]."""
    return surrogate.tip_radius() if device == "ball_chain" else ablation.fem.CATHETER_8FR_DIAMETER / 2.0


def indentation_mm_for(device: str, contact_force_gf: float) -> float:
    """Hertz's indentation of the device's tip under the force [mm], within the model's range."""
    force = contact_force_gf * 1e-3 * params.GRAVITY
    d = 1e3 * float(surrogate.indentation_for_force(force, electrode_radius_m(device)))
    return float(np.clip(d, *INDENTATION_RANGE_MM))


def magnet_limit_C(grade: str) -> float:
    """The tip magnet's limit the generator holds it below [C]: the grade's less the margin."""
    return params.magnet_grade(grade).max_operating_C - surrogate.MAGNET_MARGIN_C


def run_device(device: str, settings: ClinicalSettings, *, power_W: float, duration_s: float = 30.0,
               indentation_mm: float = 1.0, tissue: str = "myocardium", initial_temperature_C: float = 37.0,
               h_mm: float = 0.1, dt_max_s: float = 1.0, output_every_s: float = 5.0,
               progress: bool = True) -> ablation.DeviceResult:
    """One device's application in clinical conditions (``ablation.DeviceResult`` with ``clinical``)."""
    settings.check()
    if settings.contact_force_gf is not None:
        indentation_mm = indentation_mm_for(device, settings.contact_force_gf)
    ablation.check_settings(power_W=power_W, duration_s=duration_s, indentation_mm=indentation_mm, tissue=tissue,
                            initial_temperature_C=initial_temperature_C, h_mm=h_mm, dt_max_s=dt_max_s)
    electrode = ablation.electrode_for(device, indentation_mm)
    irrigation = settings.irrigation if device == "catheter" else "none"
    conditions = boundary.conditions(settings.blood_flow, irrigation)
    limit = magnet_limit_C(settings.magnet_grade) if device == "ball_chain" else None
    generator = rf_generator.Generator(mode=settings.control, power_W=power_W,
                                       target_C=settings.target_temperature_C, electrode_limit_C=limit)
    bar = tqdm(total=1, desc=f"ablation {device} (clinical)", unit="step", disable=not progress, leave=False)

    def tick(done, total):
        bar.total, bar.n = total, done
        bar.refresh()

    sim = clinical.simulate_clinical(electrode, generator=generator, duration_s=duration_s, conditions=conditions,
                                     tissue_name=tissue, initial_temperature_C=initial_temperature_C,
                                     h=h_mm * 1e-3, dt_max=dt_max_s, output_every_s=output_every_s, progress=tick)
    bar.close()
    result = ablation.device_result(device, electrode, sim, power_W=power_W, duration_s=duration_s,
                                    indentation_mm=indentation_mm)
    info = sim.info
    rf = sim.power > 0
    result.clinical = {
        "blood_flow": conditions.blood_flow, "irrigation": conditions.irrigation, "control": generator.mode,
        "target_temperature_C": generator.target_C if generator.mode == "temperature" else None,
        "contact_force_gf": settings.contact_force_gf, "set_power_W": power_W,
        "delivered_power_W": info["mean_power_W"],
        "delivered_power_final_W": float(sim.power[rf][-1]) if rf.any() else 0.0,
        "impedance_drop_ohm": float(sim.impedance[0] - sim.impedance[rf][-1]) if rf.any() else math.nan,
        "limit_share": info["limit_share"],
        "magnet_grade": settings.magnet_grade if device == "ball_chain" else None,
        "magnet_limit_C": limit, "magnet_peak_C": float(sim.max_electrode_C.max()) if device == "ball_chain" else None,
        "h_electrode_W_m2K": conditions.h_electrode, "h_tissue_W_m2K": conditions.h_tissue,
        "irrigant_C": conditions.irrigant_C if conditions.irrigation == "open" else None,
        "energy_convection_J": info["energy_convection_J"], "energy_blood_joule_J": info["energy_blood_joule_J"],
    }
    return result


def run(settings: ClinicalSettings, *, ball_power_W: float = 15.0, catheter_power_W: float = 30.0,
        duration_s: float = 30.0, indentation_mm: float = 1.0, tissue: str = "myocardium",
        initial_temperature_C: float = 37.0, h_mm: float = 0.1, dt_max_s: float = 1.0,
        progress: bool = True) -> ablation.AblationResult:
    """Both devices in clinical conditions (``ablation.AblationResult``; notes: set vs delivered power)."""
    settings.check()
    ablation.check_settings(power_W=ball_power_W, flag_power="ball_power_W")
    ablation.check_settings(power_W=catheter_power_W, flag_power="catheter_power_W")
    common = dict(duration_s=duration_s, indentation_mm=indentation_mm, tissue=tissue,
                  initial_temperature_C=initial_temperature_C, h_mm=h_mm, dt_max_s=dt_max_s, progress=progress)
    devices = [run_device("ball_chain", settings, power_W=ball_power_W, **common),
               run_device("catheter", settings, power_W=catheter_power_W, **common)]
    settings_row = ablation.AblationSettings(
        duration_s=duration_s, indentation_mm=indentation_mm, tissue=tissue,
        initial_temperature_C=initial_temperature_C, h_mm=h_mm, dt_max_s=dt_max_s,
        tissue_source=laws.TISSUES[tissue].source, damage_source=laws.DAMAGE_MODELS[tissue].source,
        saline_source=boundary.BLOOD.source if settings.blood_flow != "none" else laws.SALINE.source)
    result = ablation.AblationResult(devices=devices, settings=settings_row, notes=power_notes(devices))
    return result


def power_notes(devices: list) -> list:
    """One sentence per device: the lesion, the set and delivered power, which limit held it, the magnet."""
    notes = []
    for d in devices:
        c = d.clinical
        share = ", ".join(f"{k} {100 * v:.0f} %" for k, v in c["limit_share"].items() if v > 0)
        magnet = (f"; magnet peak {c['magnet_peak_C']:.1f} C (held below {c['magnet_limit_C']:.0f} C, "
                  f"{c['magnet_grade']})" if c["magnet_peak_C"] is not None else "")
        notes.append(f"{d.label}: {d.omega_width_mm:.1f} x {d.omega_depth_mm:.1f} mm (Omega = 1) at "
                     f"{d.indentation_mm:.2f} mm indentation; set {c['set_power_W']:g} W, delivered "
                     f"{c['delivered_power_W']:.1f} W on average ({c['delivered_power_final_W']:.1f} W at the end; "
                     f"power set by: {share}); impedance {d.impedance_initial_ohm:.0f} -> "
                     f"{d.impedance_final_ohm:.0f} Ohm{magnet}.")
    return notes
