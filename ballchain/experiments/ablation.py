"""RF ablation with the ball chain beside a standard catheter (paper Sec. "Soft Tissue Ablation").

The paper: the tip ball of a 16-ball chain (insulated by shrink wrap except where it meets the
tissue) pressed about 1 mm into porcine ventricle in 0.9 % saline, no irrigation, 15 W for 90 s:
a lesion 5.7 mm wide and 3.1 mm deep; a standard 8 Fr catheter (3.5 mm tip) at 30 W: 5.4 mm and
3.3 mm. The criterion: transmural (deeper than 2.9 mm) and 5.2-6 mm wide.

Here both applications run in the axisymmetric electro-thermal model
(``drake_models/lesion_fem.py``, laws in ``drake_models/tissue.py``); the lesion is read from
the Arrhenius contour (Omega = 1) and from the 50 C isotherm (the tissue that reached 50 C).
Beyond the paper: the power-duration map of the ball chain (which settings give a transmural
lesion 5.2-6 mm wide) and where the tip ball's N52 magnet passes 80 C.

Nothing is tuned to the paper: every tissue constant is the literature's (see ``tissue.py``).
The bath's temperature is not in the paper: 22 C (room temperature; no heater is mentioned) by
default, 37 C as a sensitivity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ballchain.drake_models import lesion_fem as fem
from ballchain.drake_models import tissue as laws
from ballchain.infrastructure.errors import UserInputError
from ballchain.infrastructure.safe_files import atomic_write_text, check_output_dir, save_figure, write_csv
from ballchain.experiments._result import Result, not_in_json, optional

PAPER = {
    "ball_chain": {"power_W": 15.0, "duration_s": 90.0, "width_mm": 5.7, "depth_mm": 3.1},
    "catheter": {"power_W": 30.0, "duration_s": 90.0, "width_mm": 5.4, "depth_mm": 3.3},
}
CRITERION = {"min_depth_mm": 2.9, "width_range_mm": (5.2, 6.0)}
ELECTRODES = ("ball_chain", "catheter")  # the electrodes compared (the JSON's "device" values)
FULL_DAMAGE_OMEGA = 4.6  # 99 % of the protein denatured (1 - exp(-4.6)): closer to "full denaturation"


def meets_criterion(width_mm: float, depth_mm: float) -> bool:
    """The paper's criterion: transmural (deeper than 2.9 mm) and 5.2-6 mm wide."""
    lo, hi = CRITERION["width_range_mm"]
    return bool(depth_mm > CRITERION["min_depth_mm"] and lo <= width_mm <= hi)


def electrode_for(device: str, indentation_mm: float) -> fem.Electrode:
    """The model electrode of ``device`` ('ball_chain' or 'catheter') at an indentation [mm]."""
    if device == "ball_chain":
        return fem.ball_chain_tip(indentation=indentation_mm * 1e-3)
    if device == "catheter":
        return fem.catheter_8fr(indentation=indentation_mm * 1e-3)
    raise UserInputError(f"device must be one of {ELECTRODES}, got {device!r}")


@dataclass
class DeviceResult(Result):
    """One device's application: the lesion by both criteria, temperatures, impedance, energy.

    Lengths in mm, temperatures in C, impedance in Ohm (NaN: no RF step to read it at, null in
    the JSON). ``simulation`` holds the fields (for the figures; never in the JSON).
    """

    device: str
    label: str
    power_W: float
    duration_s: float
    indentation_mm: float
    omega_width_mm: float
    omega_depth_mm: float
    omega_surface_diameter_mm: float
    iso50_width_mm: float
    iso50_depth_mm: float
    omega99_width_mm: float
    omega99_depth_mm: float
    peak_tissue_C: float
    peak_electrode_C: float
    peak_electrode_mean_C: float
    impedance_initial_ohm: float
    impedance_final_ohm: float
    energy_J: float
    mean_power_W: float
    cutoff_from_s: float | None
    electrode_above_80C_s: float
    paper: dict
    meets_criterion: bool
    growth: list
    simulation: fem.LesionSimulation | None = not_in_json()
    clinical: dict | None = optional()


@dataclass
class AblationSettings(Result):
    """The settings both devices ran with, and the sources of the constants."""

    duration_s: float
    indentation_mm: float
    tissue: str
    initial_temperature_C: float
    h_mm: float
    dt_max_s: float
    tissue_source: str
    damage_source: str
    saline_source: str


@dataclass
class AblationResult(Result):
    """What ``run`` returns: both devices, the settings, the paper's lesions and criterion.

    Attributes:
        devices: the ball chain's and the catheter's application.
        settings: what they ran with.
        paper, criterion: the paper's lesions and its criterion (``PAPER``, ``CRITERION``).
        notes: one sentence per device, model vs paper.
        power_duration_map: ``power_duration_map``'s dict (only when it ran).
        sensitivity: ``sensitivity``'s rows (only when it ran).
        files: the paths written (only with files).
    """

    devices: list[DeviceResult]
    settings: AblationSettings
    paper: dict = field(default_factory=lambda: dict(PAPER))
    criterion: dict = field(default_factory=lambda: dict(CRITERION))
    notes: list = field(default_factory=list)
    power_duration_map: dict | None = optional()
    sensitivity: list | None = optional()
    files: list | None = optional()

    def device(self, name: str) -> DeviceResult:
        """The device ``name`` ('ball_chain' or 'catheter')."""
        return next(d for d in self.devices if d.device == name)


def run_device(device: str, *, power_W: float, duration_s: float = 90.0, indentation_mm: float = 1.0,
               tissue: str = "myocardium", initial_temperature_C: float = 22.0, h_mm: float = 0.1,
               dt_max_s: float = 1.0, output_every_s: float = 5.0, saline_mixing: float = 1.0,
               cutoff_C: float | None = laws.VAPORISATION_ONSET_C, progress: bool = True) -> DeviceResult:
    """Simulate one device's application and read its lesion.

    ``saline_mixing`` multiplies the saline's thermal conductivity: 1 is still saline (pure
    conduction, the model's default); a natural-convection Nusselt number of about 5-10 around
    the hot electrode makes an effective conductivity several times larger (a sensitivity, not
    a fitted constant). ``cutoff_C = None`` runs the pure constant-power law (no cut-off).
    """
    check_settings(dt_max_s=dt_max_s)
    electrode = electrode_for(device, indentation_mm)
    saline = replace(laws.SALINE, thermal_conductivity=laws.SALINE.thermal_conductivity * saline_mixing)
    bar = tqdm(total=1, desc=f"ablation {device}", unit="step", disable=not progress, leave=False)

    def tick(done, total):
        bar.total = total
        bar.n = done
        bar.refresh()

    sim = fem.simulate(electrode, power_W=power_W, duration_s=duration_s, tissue_name=tissue,
                       initial_temperature_C=initial_temperature_C, h=h_mm * 1e-3, dt_max=dt_max_s,
                       output_every_s=output_every_s, saline=saline, limit_C=cutoff_C, progress=tick)
    bar.close()
    return device_result(device, electrode, sim, power_W=power_W, duration_s=duration_s,
                         indentation_mm=indentation_mm)


def device_result(device: str, electrode: fem.Electrode, sim: fem.LesionSimulation, *, power_W: float,
                  duration_s: float, indentation_mm: float) -> DeviceResult:
    """The lesion, temperatures, impedance and energy of one simulated application."""
    end = sim.growth[-1]
    rf = sim.power > 0
    dts = np.diff(np.concatenate([[0.0], sim.times]))
    cut = np.flatnonzero(sim.limited)
    full_damage = fem.lesion_extent(sim.mesh, sim.damage, FULL_DAMAGE_OMEGA)
    return DeviceResult(
        device=device, label=electrode.label, power_W=power_W, duration_s=duration_s,
        indentation_mm=indentation_mm, omega_width_mm=end["omega_width_mm"], omega_depth_mm=end["omega_depth_mm"],
        omega_surface_diameter_mm=end["omega_surface_diameter_mm"], iso50_width_mm=end["iso50_width_mm"],
        iso50_depth_mm=end["iso50_depth_mm"], omega99_width_mm=full_damage["width_mm"],
        omega99_depth_mm=full_damage["depth_mm"], peak_tissue_C=float(sim.max_tissue_C.max()),
        peak_electrode_C=float(sim.max_electrode_C.max()), peak_electrode_mean_C=float(sim.mean_electrode_C.max()),
        impedance_initial_ohm=float(sim.impedance[0]), impedance_final_ohm=float(sim.impedance[rf][-1]) if rf.any() else math.nan,
        energy_J=sim.energy_delivered_J, mean_power_W=sim.energy_delivered_J / duration_s,
        cutoff_from_s=float(sim.times[cut[0]]) if len(cut) else None,
        electrode_above_80C_s=float(np.sum(dts[sim.max_electrode_C > laws.N52_IRREVERSIBLE_LOSS_C])),
        paper=PAPER[device], meets_criterion=meets_criterion(end["omega_width_mm"], end["omega_depth_mm"]),
        growth=sim.growth, simulation=sim)


def run(*, ball_power_W: float = 15.0, catheter_power_W: float = 30.0, duration_s: float = 90.0,
        indentation_mm: float = 1.0, tissue: str = "myocardium", initial_temperature_C: float = 22.0,
        h_mm: float = 0.1, dt_max_s: float = 1.0, progress: bool = True, out: Path | None = None) -> AblationResult:
    """Both devices of the paper's ablation test.

    Args:
        ball_power_W, catheter_power_W: generator powers [W] (paper: 15 and 30).
        duration_s: RF time [s] (paper: 90).
        indentation_mm: electrode depth below the tissue surface [mm] (paper: about 1).
        tissue: "myocardium" (the paper's porcine ventricle) or "liver".
        initial_temperature_C: bath and tissue temperature [C] (not in the paper; 22 C).
        h_mm: mesh spacing near the electrode [mm].
        dt_max_s: largest time step [s].
        progress: show progress bars.
        out: a folder for ``write_files``' JSON, CSV and figures (checked writable before the
            work; None: no files), listed in ``files``.
    """
    check_settings(power_W=ball_power_W, duration_s=duration_s, indentation_mm=indentation_mm, tissue=tissue,
                   initial_temperature_C=initial_temperature_C, h_mm=h_mm, dt_max_s=dt_max_s,
                   flag_power="ball_power_W")
    check_settings(power_W=catheter_power_W, flag_power="catheter_power_W")
    if out is not None:
        check_output_dir(out, "--out")
    common = dict(duration_s=duration_s, indentation_mm=indentation_mm, tissue=tissue,
                  initial_temperature_C=initial_temperature_C, h_mm=h_mm, dt_max_s=dt_max_s, progress=progress)
    devices = [run_device("ball_chain", power_W=ball_power_W, **common),
               run_device("catheter", power_W=catheter_power_W, **common)]
    settings = AblationSettings(duration_s=duration_s, indentation_mm=indentation_mm, tissue=tissue,
                                initial_temperature_C=initial_temperature_C, h_mm=h_mm, dt_max_s=dt_max_s,
                                tissue_source=laws.TISSUES[tissue].source,
                                damage_source=laws.DAMAGE_MODELS[tissue].source, saline_source=laws.SALINE.source)
    result = AblationResult(devices=devices, settings=settings, notes=disagreement_notes(devices))
    if out is not None:
        result.files = write_files(result, Path(out))
    return result


def check_settings(*, power_W: float | None = None, duration_s: float | None = None,
                   indentation_mm: float | None = None, tissue: str | None = None,
                   initial_temperature_C: float | None = None, h_mm: float | None = None,
                   dt_max_s: float | None = None, flag_power: str = "power_W") -> None:
    """Raise UserInputError naming the setting if a value is outside what the model covers."""
    def bad(name, value, allowed):
        raise UserInputError(f"{name} = {value!r} is outside the model's range: {allowed}")

    def finite(v):
        return isinstance(v, (int, float)) and math.isfinite(v)

    if power_W is not None and not (finite(power_W) and 0 < power_W <= 100):
        bad(flag_power, power_W, "0 < power <= 100 W")
    if duration_s is not None and not (finite(duration_s) and 1 <= duration_s <= 600):
        bad("duration_s", duration_s, "1..600 s")
    if indentation_mm is not None and not (finite(indentation_mm) and 0.1 <= indentation_mm <= 1.3):
        bad("indentation_mm", indentation_mm, "0.1..1.3 mm (the catheter's radius is 1.33 mm)")
    if tissue is not None and tissue not in laws.TISSUES:
        bad("tissue", tissue, f"one of {sorted(laws.TISSUES)}")
    if initial_temperature_C is not None and not (finite(initial_temperature_C) and 0 <= initial_temperature_C <= 45):
        bad("initial_temperature_C", initial_temperature_C, "0..45 C")
    if h_mm is not None and not (finite(h_mm) and 0.03 <= h_mm <= 0.3):
        bad("h_mm", h_mm, "0.03..0.3 mm")
    # The steps grow from lesion_fem's 0.05 s first step to dt_max: 0 never ends, NaN never grows.
    if dt_max_s is not None and not (finite(dt_max_s) and 0.05 <= dt_max_s <= 10):
        bad("dt_max_s", dt_max_s, "0.05..10 s")


def disagreement_notes(devices: list) -> list:
    """One sentence per device comparing the model's Omega = 1 lesion with the paper's."""
    notes = []
    for d in devices:
        p = d.paper
        notes.append(
            f"{d.label}: model {d.omega_width_mm:.1f} x {d.omega_depth_mm:.1f} mm (width x depth, Omega = 1) vs "
            f"paper {p['width_mm']} x {p['depth_mm']} mm; the generator delivered {d.energy_J:.0f} J of the "
            f"{d.power_W * d.duration_s:.0f} J set (" + (f"cut-off at 100 C from {d.cutoff_from_s:.2f} s)."
                                                          if d.cutoff_from_s is not None else "no cut-off).")
        )
    return notes


def mesh_convergence(device: str, *, h_mm=(0.14, 0.1, 0.07), duration_s: float = 90.0,
                     dt_max_s: float = 1.0, progress: bool = True) -> list:
    """The paper's application of ``device`` on successively refined meshes.

    Returns:
        rows {h_mm, nodes, width_mm, depth_mm, iso50_width_mm, iso50_depth_mm, impedance_initial_ohm,
        peak_electrode_C, energy_J}.
    """
    rows = []
    for h in tqdm(h_mm, desc=f"mesh convergence ({device})", unit="mesh", disable=not progress):
        d = run_device(device, power_W=PAPER[device]["power_W"], duration_s=duration_s, h_mm=h,
                       dt_max_s=dt_max_s, output_every_s=duration_s, progress=False)
        rows.append({"h_mm": h, "nodes": d.simulation.info["nodes"], "width_mm": d.omega_width_mm,
                     "depth_mm": d.omega_depth_mm, "iso50_width_mm": d.iso50_width_mm,
                     "iso50_depth_mm": d.iso50_depth_mm, "impedance_initial_ohm": d.impedance_initial_ohm,
                     "peak_electrode_C": d.peak_electrode_C, "energy_J": d.energy_J})
    return rows


SENSITIVITIES = {
    "baseline": {},
    "bath and tissue at 37 C": {"initial_temperature_C": 37.0},
    "saline mixing: k x 5 (natural convection)": {"saline_mixing": 5.0},
    "indentation 0.5 mm": {"indentation_mm": 0.5},
    "indentation 1.3 mm": {"indentation_mm": 1.3},
    "no cut-off (pure constant power)": {"cutoff_C": None},
}
"""The model choices the paper leaves open, each varied alone (no tissue constant is varied)."""


def sensitivity(*, cases: dict = SENSITIVITIES, h_mm: float = 0.15, dt_max_s: float = 2.0,
                progress: bool = True) -> list:
    """Both devices at the paper's settings under each case of ``cases``.

    Returns:
        rows {case, device, width_mm, depth_mm, iso50_width_mm, iso50_depth_mm, peak_tissue_C,
        peak_electrode_C, energy_J}.
    """
    rows = []
    jobs = [(case, device) for case in cases for device in ELECTRODES]
    for case, device in tqdm(jobs, desc="ablation sensitivity", unit="run", disable=not progress):
        kw = dict(cases[case])
        d = run_device(device, power_W=PAPER[device]["power_W"], duration_s=PAPER[device]["duration_s"],
                       h_mm=h_mm, dt_max_s=dt_max_s, output_every_s=PAPER[device]["duration_s"], progress=False, **kw)
        rows.append({"case": case, "device": device, "width_mm": d.omega_width_mm, "depth_mm": d.omega_depth_mm,
                     "iso50_width_mm": d.iso50_width_mm, "iso50_depth_mm": d.iso50_depth_mm,
                     "peak_tissue_C": d.peak_tissue_C, "peak_electrode_C": d.peak_electrode_C, "energy_J": d.energy_J})
    return rows


MAP_POWERS_W = (1.0, 1.5, 2.0, 3.0, 5.0, 15.0)
MAP_DURATIONS_S = (30.0, 60.0, 90.0, 120.0, 180.0)


def power_duration_map(*, device: str = "ball_chain", powers_W=MAP_POWERS_W, durations_s=MAP_DURATIONS_S,
                       indentation_mm: float = 1.0, tissue: str = "myocardium",
                       initial_temperature_C: float = 22.0, h_mm: float = 0.2,
                       dt_max_s: float = 2.0, progress: bool = True) -> dict:
    """Lesion size over a power x duration grid (one run per power, read at each duration).

    A lesion after D seconds of RF is the running lesion at t = D (nothing after D affects it;
    no cool-down is modelled), so one run to the longest duration gives every duration.

    Returns:
        {"rows": [{power_W, duration_s, width_mm, depth_mm, iso50_*, peak_electrode_C,
        meets_criterion, magnet_above_80C}], "headline": str, ...}
    """
    durations = sorted(float(d) for d in durations_s)
    check_settings(duration_s=durations[-1], indentation_mm=indentation_mm, tissue=tissue,
                   initial_temperature_C=initial_temperature_C, h_mm=h_mm)
    electrode = electrode_for(device, indentation_mm)
    mesh = fem.build_mesh(electrode, h=h_mm * 1e-3)
    step = math.gcd(*[int(round(d)) for d in durations])
    rows = []
    for power in tqdm(powers_W, desc=f"power-duration map ({device})", unit="power", disable=not progress):
        check_settings(power_W=power)
        sim = fem.simulate(electrode, power_W=float(power), duration_s=durations[-1], tissue_name=tissue,
                           initial_temperature_C=initial_temperature_C, dt_max=dt_max_s,
                           output_every_s=float(step), mesh=mesh)
        by_t = {round(g["t_s"], 6): g for g in sim.growth}
        for dur in durations:
            g = by_t[round(dur, 6)]
            hot = float(sim.max_electrode_C[sim.times <= dur + 1e-9].max())
            rows.append({"power_W": float(power), "duration_s": dur, "width_mm": g["omega_width_mm"],
                         "depth_mm": g["omega_depth_mm"], "iso50_width_mm": g["iso50_width_mm"],
                         "iso50_depth_mm": g["iso50_depth_mm"], "peak_electrode_C": hot,
                         "energy_J": float(np.sum(sim.power[sim.times <= dur + 1e-9]
                                                  * np.diff(np.concatenate([[0.0], sim.times]))[sim.times <= dur + 1e-9])),
                         "meets_criterion": meets_criterion(g["omega_width_mm"], g["omega_depth_mm"]),
                         "magnet_above_80C": hot > laws.N52_IRREVERSIBLE_LOSS_C})
    good = [r for r in rows if r["meets_criterion"]]
    safe = [r for r in good if not r["magnet_above_80C"]]

    def fmt(rs):
        return ", ".join(f"{r['power_W']:g} W {r['duration_s']:g} s" for r in rs) or "none"

    # The lowest power above which the lesion no longer depends on the set power (within 0.1 mm):
    # the cut-off at 100 C then sets the delivered power.
    top = max(powers_W)
    by = {(r["power_W"], r["duration_s"]): r for r in rows}
    saturated = [p for p in sorted(powers_W)
                 if all(abs(by[(q, d)][k] - by[(top, d)][k]) < 0.1 for q in powers_W if q >= p
                        for d in durations for k in ("width_mm", "depth_mm"))]
    saturation = saturated[0] if saturated else None
    cool = [r for r in rows if not r["magnet_above_80C"]]
    headline = (f"{device}: transmural and 5.2-6 mm wide at {fmt(good)}; of these the magnet stays below 80 C at "
                f"{fmt(safe)}. The magnet stays below 80 C only at {fmt(cool)}. From {saturation:g} W up the lesion "
                "no longer depends on the set power (within 0.1 mm): the cut-off at 100 C sets the delivered power."
                if saturation is not None else "")
    headline = headline or (f"{device}: transmural and 5.2-6 mm wide at {fmt(good)}; magnet below 80 C at {fmt(cool)}.")
    return {"device": device, "rows": rows, "headline": headline, "saturation_power_W": saturation,
            "powers_W": list(map(float, powers_W)),
            "durations_s": durations, "h_mm": h_mm, "dt_max_s": dt_max_s,
            "initial_temperature_C": initial_temperature_C, "tissue": tissue}


# ------------------------------------------------------------------------------------------ figures

def _mirrored_triangulation(am: fem.AblationMesh):
    import matplotlib.tri as mtri

    p = am.mesh.p * 1e3
    n = p.shape[1]
    x = np.concatenate([p[0], -p[0]])
    y = np.concatenate([p[1], p[1]])
    t = np.hstack([am.mesh.t, am.mesh.t + n]).T
    dom = np.concatenate([am.domain, am.domain])
    return mtri.Triangulation(x, y, t), dom


def figure_fields(result: AblationResult, path) -> None:
    """Temperature at the end of RF with the Omega = 1 contour and 50 C isotherm, both devices."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), sharey=True)
    for ax, d in zip(axes, result.devices):
        sim = d.simulation
        am = sim.mesh
        tri, dom = _mirrored_triangulation(am)
        T_end = sim.snapshots[max(sim.snapshots)]
        temp = np.concatenate([T_end, T_end])
        levels = np.linspace(result.settings.initial_temperature_C, 100, 17)
        cs = ax.tricontourf(tri, temp, levels=levels, cmap="inferno", extend="both")
        tissue_mask = dom != fem.TISSUE
        tri.set_mask(tissue_mask)
        omega = np.concatenate([sim.damage, sim.damage])
        peak = np.concatenate([sim.peak_temperature, sim.peak_temperature])
        ax.tricontour(tri, omega, levels=[1.0], colors="cyan", linewidths=1.6)
        ax.tricontour(tri, peak, levels=[laws.LESION_ISOTHERM_C], colors="lime", linewidths=1.0, linestyles="--")
        tri.set_mask(None)
        for r_sign in (1, -1):
            for c in am.electrode.outline():
                keep = c[:, 1] < 6e-3
                ax.plot(r_sign * c[keep, 0] * 1e3, c[keep, 1] * 1e3, color="w", lw=0.8)
        ax.axhline(0, color="0.7", lw=0.6)
        ax.axhline(-fem_criterion_depth(), color="0.5", lw=0.6, ls=":")
        ax.set_xlim(-7, 7)
        ax.set_ylim(-6, 4)
        ax.set_aspect("equal")
        ax.set_xlabel("r [mm]")
        ax.set_title(f"{d.label}, {d.power_W:g} W {d.duration_s:g} s\nOmega=1: {d.omega_width_mm:.1f} x "
                     f"{d.omega_depth_mm:.1f} mm (paper {d.paper['width_mm']} x {d.paper['depth_mm']})", fontsize=9)
    axes[0].set_ylabel("z [mm] (tissue below 0)")
    fig.colorbar(cs, ax=axes, label="temperature at switch-off [C]", shrink=0.85)
    fig.suptitle("Lesion: Omega = 1 (cyan), 50 C reached (green dashed), 2.9 mm depth (dotted)", fontsize=10)
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def fem_criterion_depth() -> float:
    return CRITERION["min_depth_mm"]


def figure_growth(result: AblationResult, path) -> None:
    """Lesion width and depth over time, both devices, both criteria, with the paper's lesions."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for i, d in enumerate(result.devices):
        t = [g["t_s"] for g in d.growth]
        for ax, key, paper_key in ((axes[0], "width_mm", "width_mm"), (axes[1], "depth_mm", "depth_mm")):
            ax.plot(t, [g[f"omega_{key}"] for g in d.growth], color=f"C{i}", label=f"{d.label}, Omega = 1")
            ax.plot(t, [g[f"iso50_{key}"] for g in d.growth], color=f"C{i}", ls="--", label=f"{d.label}, 50 C")
            ax.plot([d.duration_s], [d.paper[paper_key]], "o", color=f"C{i}", label=f"{d.label}, paper")
    lo, hi = CRITERION["width_range_mm"]
    axes[0].axhspan(lo, hi, color="0.9", zorder=0)
    axes[1].axhline(CRITERION["min_depth_mm"], color="0.5", ls=":")
    axes[0].set_ylabel("lesion width [mm]")
    axes[1].set_ylabel("lesion depth [mm]")
    for ax in axes:
        ax.set_xlabel("time [s]")
    axes[0].legend(fontsize=7)
    fig.suptitle("Lesion growth (grey band: 5.2-6 mm; dotted: 2.9 mm transmural)", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def figure_map(data: dict, path) -> None:
    """The power-duration map: width and depth, the criterion's cells and where the magnet passes 80 C."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    P, D = data["powers_W"], data["durations_s"]
    grid = {(r["power_W"], r["duration_s"]): r for r in data["rows"]}
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, p in enumerate(P):
        for j, d in enumerate(D):
            r = grid[(p, d)]
            color = "tab:green" if r["meets_criterion"] else "0.92"
            ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, color=color))
            ax.text(j, i, f"{r['width_mm']:.1f} x {r['depth_mm']:.1f}\n{r['peak_electrode_C']:.0f} C",
                    ha="center", va="center", fontsize=7,
                    color="red" if r["magnet_above_80C"] else "black")
    ax.set_xticks(range(len(D)), [f"{d:g}" for d in D])
    ax.set_yticks(range(len(P)), [f"{p:g}" for p in P])
    ax.set_xlim(-0.5, len(D) - 0.5)
    ax.set_ylim(-0.5, len(P) - 0.5)
    ax.set_xlabel("duration [s]")
    ax.set_ylabel("power [W]")
    ax.set_title(f"{data['device']}: width x depth [mm] (Omega = 1), peak ball temperature\n"
                 "green: transmural and 5.2-6 mm wide; red text: magnet above 80 C", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def table_rows(result: AblationResult) -> list[list]:
    """Model vs paper, one row per quantity and device."""
    rows = []
    for d in result.devices:
        rows += [
            [d.label, "width [mm], Omega = 1", d.paper["width_mm"], d.omega_width_mm],
            [d.label, "depth [mm], Omega = 1", d.paper["depth_mm"], d.omega_depth_mm],
            [d.label, "width [mm], 50 C isotherm", d.paper["width_mm"], d.iso50_width_mm],
            [d.label, "depth [mm], 50 C isotherm", d.paper["depth_mm"], d.iso50_depth_mm],
            [d.label, "width [mm], Omega = 4.6 (99 % denatured)", d.paper["width_mm"], d.omega99_width_mm],
            [d.label, "depth [mm], Omega = 4.6 (99 % denatured)", d.paper["depth_mm"], d.omega99_depth_mm],
            [d.label, "surface diameter [mm], Omega = 1", "-", d.omega_surface_diameter_mm],
            [d.label, "meets criterion (> 2.9 mm deep, 5.2-6 mm wide)",
             meets_criterion(d.paper["width_mm"], d.paper["depth_mm"]), d.meets_criterion],
            [d.label, "peak tissue temperature [C]", "-", d.peak_tissue_C],
            [d.label, "peak electrode temperature [C]", "-", d.peak_electrode_C],
            [d.label, "electrode volume-mean temperature, highest [C]", "-", d.peak_electrode_mean_C],
            [d.label, "time with the electrode above 80 C [s]", "-", d.electrode_above_80C_s],
            [d.label, "impedance at start / end [Ohm]", "-",
             f"{d.impedance_initial_ohm:.0f} / {d.impedance_final_ohm:.0f}"],
            [d.label, "energy delivered [J] (set: P x t)", d.power_W * d.duration_s, d.energy_J],
            [d.label, "cut-off at 100 C from [s]", "-", d.cutoff_from_s],
        ]
    return rows


def write_files(result: AblationResult, out: Path) -> list[str]:
    """JSON, CSV (growth, map) and the figures, each written atomically.

    ``ablation.json`` is the result's JSON without the sensitivity rows and the file list (the
    power-duration map is in it when it ran); the map's CSV and figure only then.
    """
    out.mkdir(parents=True, exist_ok=True)
    files = []
    sweep = result.power_duration_map
    path = out / "ablation.json"
    atomic_write_text(path, replace(result, sensitivity=None, files=None).to_json())
    files.append(path)
    lines = ["device,t_s,omega_width_mm,omega_depth_mm,iso50_width_mm,iso50_depth_mm"]
    for d in result.devices:
        for g in d.growth:
            lines.append(f"{d.device},{g['t_s']:.3f},{g['omega_width_mm']:.4f},{g['omega_depth_mm']:.4f},"
                         f"{g['iso50_width_mm']:.4f},{g['iso50_depth_mm']:.4f}")
    path = out / "ablation_growth.csv"
    atomic_write_text(path, "\n".join(lines) + "\n")
    files.append(path)
    for name, draw in (("ablation_fields.png", figure_fields), ("ablation_growth.png", figure_growth)):
        draw(result, out / name)
        files.append(out / name)
    if sweep is not None:
        path = out / "ablation_map.csv"
        write_csv(path, sweep["rows"])
        files.append(path)
        figure_map(sweep, out / "ablation_map.png")
        files.append(out / "ablation_map.png")
    return [str(f) for f in files]
