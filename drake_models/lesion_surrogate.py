"""The lesion a dwell of the tip ball leaves, tabulated once from the electro-thermal FEM.

``lesion_fem.simulate`` takes seconds per application; a procedure ablates at 20-40 targets and
its planner asks "what power may I use here?" many times. The surrogate answers both from a
table of FEM runs over (indentation, power, duration), interpolated (trilinear: it reproduces
the FEM at the table's nodes, and keeps monotone data monotone).

Conditions of the procedure (not the paper's dish):

- Body temperature: tissue, saline and far field start at ``BODY_TEMPERATURE_C`` = 37 C (the
  FEM's default 22 C is the paper's bench bath).
- Contact force enters through the indentation. The tip ball on the wall is a rigid sphere on an
  elastic half space (Hertz): F = 4/3 E* sqrt(R) d^(3/2), E* = E / (1 - nu^2), with the
  myocardium's E = 75 kPa and nu = 0.49 of the contact-force RF models of Perez,
  Gonzalez-Suarez, Nadal and Berjano ("Computer modeling of radiofrequency cardiac ablation
  including heartbeat-induced electrode displacement", Comput. Biol. Med. 144:105346, 2022;
  bioRxiv 10.1101/2021.12.11.472212: a Neo-Hookean myocardium, 10-30 gf give 0.86-2.05 mm
  insertion of a 7 Fr tip). Cross-check: Hertz gives the same 7 Fr tip (R 1.17 mm) 0.78-1.62 mm,
  10-20 % shallower (a dome on a cylinder sinks deeper than a sphere, and Hertz is a small-strain
  law); for the 3.175 mm ball 20 gf -> 1.12 mm, the paper's "about 1 mm". The table's deepest
  node is 1.5 mm (31 gf, the ball almost to its equator, where the sleeve begins): larger forces
  are evaluated there.
- Durations come from one FEM run per (indentation, power): a lesion after D seconds of RF is the
  running lesion at D (``ablation.power_duration_map``); no cool-down is modelled (the lesion
  still grows for a few seconds after switch-off: thermal latency, a few tenths of a mm).
- The magnet's peak temperature is the hottest point of the tip ball over the dwell (the ball is
  hottest at switch-off: it cools from the first step after it).

What the FEM leaves out in vivo: blood flow. The blood pool is still saline (pure conduction; no
convective cooling of the ball and the wall, no irrigation) and the tissue has no perfusion.
Convective cooling removes heat at the electrode-blood interface, so in vivo, at the same power,
the magnet and the tissue surface are cooler: this surrogate OVERESTIMATES the magnet's
temperature (``choose_power`` is conservative) and, below the 100 C cut-off, the lesion for a
given power; where the cut-off limits the power, blood cooling would let the generator deliver
more and the in-vivo lesion can be deeper (the known effect of electrode cooling). Blood's own
conductivity (about 0.7 S/m) is also lower than saline's.

Mesh: h = 0.2 mm near the electrode (``TableSpec.h_m``), coarse where it costs little accuracy
(``ablation.mesh_convergence``: < 0.1 mm between 0.14 and 0.07 mm). Measured here at 37 C, 20 gf:
at 1.2 W / 30 s (N52's power) refining h = 0.2 -> 0.1 -> 0.07 mm moves the lesion by at most
0.09 mm (width 4.92 -> 4.89 -> 4.88 mm, depth 1.93 -> 1.99 -> 2.01 mm) and the magnet's peak by
+2.3 C (76.4, 77.3 at 0.15, 78.2, 78.7 C: the hottest point is the edge of the conducting cap,
where the current concentrates; it converges slowly); at 15 W / 30 s the width by 0.18 mm
(6.56 -> 6.37 mm, h 0.2 -> 0.1), the depth by 0.02 mm, the peak by 0.8 C. ``MAGNET_MARGIN_C``
covers the mesh's 2.3 C and the interpolation's error (``validation_table``).

The table is generated data: cached under ``model_files.cache_dir()`` in ``lesion_surrogate/``,
its name keyed by a hash of the ``TableSpec`` and of the source of everything that changes it
(the FEM, the tissue laws, the electrode's parameters and the functions here that run them), built with a progress bar on
stderr, written atomically and signed with the user's key (``model_files.cached_files``) with its
build's CPU time inside. The tables shipped in the package (``SHIPPED``) are checked against
their SHA-1 list only: they are as trusted as the code beside them.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import inspect
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from ballchain.drake_models import lesion_fem as fem
from ballchain.drake_models import model_files
from ballchain.drake_models import params
from ballchain.drake_models import tissue as laws
from ballchain.infrastructure.errors import UserInputError, short_repr

BODY_TEMPERATURE_C = 37.0
MYOCARDIUM_YOUNGS_MODULUS = 75e3  # [Pa] Perez et al. 2022 (module docstring)
MYOCARDIUM_POISSON = 0.49  # Perez et al. 2022
MAGNET_MARGIN_C = 5.0  # [C] choose_power keeps the surrogate's peak this far below the grade's limit
ONSET_DEPTH_MM = 0.5  # a lesion shallower than this is the surface ring before its core forms
TABLE_VERSION = 1


def tip_radius() -> float:
    """The tip ball's radius [m] (``params.BallChain``)."""
    return params.BallChain().ball_diameter / 2.0


def hertz_force(indentation_m, radius_m: float | None = None):
    """Hertz's force of a rigid sphere pressed ``indentation_m`` into myocardium [N]."""
    r = tip_radius() if radius_m is None else radius_m
    e_star = MYOCARDIUM_YOUNGS_MODULUS / (1.0 - MYOCARDIUM_POISSON**2)
    return 4.0 / 3.0 * e_star * math.sqrt(r) * np.asarray(indentation_m, dtype=float) ** 1.5


def indentation_for_force(force_N, radius_m: float | None = None):
    """The Hertz indentation of the tip ball under ``force_N`` [m] (the inverse of ``hertz_force``)."""
    r = tip_radius() if radius_m is None else radius_m
    e_star = MYOCARDIUM_YOUNGS_MODULUS / (1.0 - MYOCARDIUM_POISSON**2)
    f = np.maximum(np.asarray(force_N, dtype=float), 0.0)
    return (3.0 * f / (4.0 * e_star * math.sqrt(r))) ** (2.0 / 3.0)


@dataclass(frozen=True)
class TableSpec:
    """The FEM runs the table is made of.

    Attributes:
        indentations_m: the tip ball's indentations [m] (at most its radius, the equator).
        powers_W: generator powers [W] (> 0; the table adds P = 0: no lesion, magnet at body temperature).
        duration_s: the longest dwell [s]; durations every ``output_every_s`` up to it.
        output_every_s: spacing of the duration nodes [s].
        h_m: FEM mesh spacing near the electrode [m].
        dt_max_s: the FEM's largest time step [s].
        initial_temperature_C: tissue, saline and far field at the start [C].
        tissue: the FEM's tissue name.
    """

    indentations_m: tuple = (0.3e-3, 0.5e-3, 0.7e-3, 0.9e-3, 1.1e-3, 1.3e-3, 1.5e-3)
    powers_W: tuple = (0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 4.0, 6.0, 10.0, 15.0)
    duration_s: float = 90.0
    output_every_s: float = 2.0
    h_m: float = 0.2e-3
    dt_max_s: float = 1.0
    initial_temperature_C: float = BODY_TEMPERATURE_C
    tissue: str = "myocardium"

    @property
    def durations_s(self) -> np.ndarray:
        """The duration nodes, 0 first (no RF: no lesion) [s]."""
        n = int(round(self.duration_s / self.output_every_s))
        return np.arange(n + 1) * self.output_every_s

    def key(self) -> str:
        """A short hash of the spec and of the code that makes the table."""
        # The FEM and the tissue laws by their source; the ball and the sleeve by the values the FEM
        # reads (an unrelated constant added to params.py does not make a new table).
        code = model_files.source_hash(*fem.SOURCE_MODULES, laws) + repr(params.BallChain()) + repr(params.Sleeve())
        builder = "".join(inspect.getsource(f) for f in (_node_run, build_table))
        text = repr(sorted(dataclasses.asdict(self).items())) + code + builder + str(TABLE_VERSION)
        return hashlib.sha1(text.encode()).hexdigest()[:12]


def _node_run(spec: TableSpec, indentation_m: float, power_W: float, mesh) -> tuple:
    """One FEM run: (width_mm, depth_mm, magnet_peak_C), each (n_durations - 1,) at the durations > 0."""
    electrode = fem.ball_chain_tip(indentation=indentation_m)
    sim = fem.simulate(electrode, power_W=power_W, duration_s=spec.duration_s, tissue_name=spec.tissue,
                       initial_temperature_C=spec.initial_temperature_C, dt_max=spec.dt_max_s,
                       output_every_s=spec.output_every_s, mesh=mesh)
    by_t = {round(g["t_s"], 6): g for g in sim.growth}
    width, depth, peak = [], [], []
    for t in spec.durations_s[1:]:
        g = by_t[round(float(t), 6)]
        width.append(g["omega_width_mm"])
        depth.append(g["omega_depth_mm"])
        peak.append(float(sim.max_electrode_C[sim.times <= t + 1e-9].max()))
    return np.array(width), np.array(depth), np.array(peak)


def build_table(spec: TableSpec, progress: bool = True) -> dict:
    """Run the FEM at every (indentation, power) of ``spec``.

    Returns:
        {"indentation_m", "power_W" (0 first), "duration_s" (0 first), "width_mm", "depth_mm",
        "magnet_peak_C" (each (n_ind, n_pow, n_dur)), "cpu_s": the build's CPU time [s]}.
    """
    from tqdm import tqdm

    start = time.process_time()
    ind = np.asarray(spec.indentations_m, dtype=float)
    powers = np.concatenate([[0.0], np.asarray(spec.powers_W, dtype=float)])
    durations = spec.durations_s
    shape = (len(ind), len(powers), len(durations))
    width, depth = np.zeros(shape), np.zeros(shape)
    peak = np.full(shape, float(spec.initial_temperature_C))
    bar = tqdm(total=len(ind) * len(spec.powers_W), desc="lesion table (FEM runs)", unit="run",
               disable=not progress, file=sys.stderr)
    for i, d in enumerate(ind):
        mesh = fem.build_mesh(fem.ball_chain_tip(indentation=d), h=spec.h_m)
        for j, p in enumerate(powers[1:], start=1):
            width[i, j, 1:], depth[i, j, 1:], peak[i, j, 1:] = _node_run(spec, d, p, mesh)
            bar.update()
    bar.close()
    return {"indentation_m": ind, "power_W": powers, "duration_s": durations, "width_mm": width,
            "depth_mm": depth, "magnet_peak_C": peak, "cpu_s": np.array(time.process_time() - start)}


SHIPPED = Path(__file__).parent / "generated" / "lesion_surrogate"
"""Tables shipped with the package (``<key>/lesion_table.npz`` + ``files.sha1``), so that a first run
does not pay the FEM runs (about 30 CPU-s for the default table with QDLDL, 1 CPU-min with SuperLU, 6 before issue 48); used only
when the key and the digest match, otherwise the table is built into the cache."""


SHIP_COMMAND = "python -m ballchain.drake_models.lesion_surrogate"


def shipped_path(spec: TableSpec) -> Path:
    """Where the shipped table of ``spec`` is (or would be) [path]."""
    return SHIPPED / spec.key() / "lesion_table.npz"


def shipped_table(spec: TableSpec) -> dict | None:
    """The table of ``spec`` shipped with the package, None when there is none intact for its key."""
    return model_files.shipped_arrays(shipped_path(spec))


def ship_table(spec: TableSpec | None = None, progress: bool = True) -> Path:
    """Build the table of ``spec`` (default: ``TableSpec()``) into the package (``SHIPPED``) with its
    SHA-1 list and remove the shipped tables of older keys (``model_files.ship_arrays``); run it
    (``SHIP_COMMAND``) when the FEM, the tissue laws or the table's builder change its key.
    Returns the table written."""
    spec = TableSpec() if spec is None else spec
    path = shipped_path(spec)
    return model_files.ship_arrays(SHIPPED, {spec.key(): build_table(spec, progress=progress)}, path.name)[0]


def cached_table(spec: TableSpec, progress: bool = True) -> dict:
    """``build_table(spec)``: the copy shipped with the package when its key matches, else from the
    cache when it is there and intact (built and written otherwise)."""
    shipped = shipped_table(spec)
    if shipped is not None:
        return shipped
    directory = model_files.cache_dir() / "lesion_surrogate"

    def write(tmp):
        table = build_table(spec, progress=progress)
        with open(tmp["table"], "wb") as f:
            np.savez(f, **table)

    paths = model_files.cached_files(directory / spec.key(), {"table": "lesion_table.npz"}, write)
    with np.load(paths["table"]) as data:
        return {k: np.array(data[k]) for k in data.files}


@dataclass(frozen=True)
class LesionPrediction:
    """What the surrogate says one dwell leaves.

    Attributes:
        width_m: the lesion's largest diameter (Omega = 1) [m].
        depth_m: its depth below the tissue surface [m].
        magnet_peak_C: the tip ball's hottest temperature over the dwell [C].
        indentation_m: the indentation the force was evaluated at [m].
    """

    width_m: float
    depth_m: float
    magnet_peak_C: float
    indentation_m: float


class LesionSurrogate:
    """The interpolated table: ``predict(force, power, duration)``.

    Args:
        spec: the table's FEM runs (built on first use, then cached).
        progress: show the build's progress on stderr.
    """

    def __init__(self, spec: TableSpec | None = None, progress: bool = True):
        self.spec = spec or TableSpec()
        self.table = cached_table(self.spec, progress=progress)
        axes = (self.table["indentation_m"], self.table["power_W"], self.table["duration_s"])
        self._interp = {k: RegularGridInterpolator(axes, self.table[k], method="linear")
                        for k in ("width_mm", "depth_mm", "magnet_peak_C")}

    @property
    def build_cpu_s(self) -> float:
        """CPU time the table's FEM runs took when it was built [s]."""
        return float(self.table["cpu_s"])

    @property
    def force_range_N(self) -> tuple[float, float]:
        """Forces of the table's smallest and largest indentation [N]."""
        ind = self.table["indentation_m"]
        return float(hertz_force(ind[0])), float(hertz_force(ind[-1]))

    @property
    def max_power_W(self) -> float:
        return float(self.table["power_W"][-1])

    @property
    def max_duration_s(self) -> float:
        return float(self.table["duration_s"][-1])

    def check(self, force_N, power_W, duration_s) -> None:
        """UserInputError naming the argument when it is outside what the table covers."""
        for name, value, hi in (("force_N", force_N, math.inf), ("power_W", power_W, self.max_power_W),
                                ("duration_s", duration_s, self.max_duration_s)):
            ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
            if not (ok and math.isfinite(value) and 0.0 <= value <= hi):
                raise UserInputError(f"{name} must be a finite number in [0, {hi:g}] for the lesion "
                                     f"surrogate, got {short_repr(value)}")

    def predict(self, force_N: float, power_W: float, duration_s: float) -> LesionPrediction:
        """The lesion and the magnet's peak for one dwell (force [N], power [W], duration [s]).

        No force (or no power, or no time) makes no lesion and leaves the magnet at body
        temperature; forces outside the table's range are evaluated at its ends (its deepest
        indentation above it).
        """
        self.check(force_N, power_W, duration_s)
        ind = self.table["indentation_m"]
        d = float(np.clip(indentation_for_force(force_N), ind[0], ind[-1]))
        if force_N <= 0.0:
            return LesionPrediction(0.0, 0.0, float(self.spec.initial_temperature_C), 0.0)
        x = np.array([[d, float(power_W), float(duration_s)]])
        w, dp, t = (float(self._interp[k](x)[0]) for k in ("width_mm", "depth_mm", "magnet_peak_C"))
        return LesionPrediction(width_m=1e-3 * w, depth_m=1e-3 * dp, magnet_peak_C=t, indentation_m=d)

    def across_onset(self, force_N: float, power_W: float, duration_s: float) -> bool:
        """Whether the table cell around the point straddles the lesion's onset.

        The lesion forms in two jumps: Omega = 1 first appears as a shallow ring around the cap's
        edge (3-4 mm wide, < 0.5 mm deep), then its core below the ball joins it (the depth jumps
        to 1.5-2 mm) within a fraction of a watt or a few seconds. In a cell with a corner on
        each side of a jump (no lesion and a lesion, or a depth below ``ONSET_DEPTH_MM`` and one
        above) the interpolated lesion is only bounded by the corners' values."""
        ind, powers, times = (self.table[k] for k in ("indentation_m", "power_W", "duration_s"))
        d = float(np.clip(indentation_for_force(force_N), ind[0], ind[-1]))
        cell = [slice(max(np.searchsorted(axis, x, side="right") - 1, 0), None) for axis, x in
                ((ind, d), (powers, power_W), (times, duration_s))]
        cell = tuple(slice(c.start, min(c.start + 2, len(a))) for c, a in zip(cell, (ind, powers, times)))
        width, depth = self.table["width_mm"][cell], self.table["depth_mm"][cell]
        return bool(width.min() == 0.0 < width.max() or depth.min() < ONSET_DEPTH_MM <= depth.max())

    def choose_power(self, force_N: float, duration_s: float, *, grade: str = "N52",
                     margin_C: float = MAGNET_MARGIN_C) -> float:
        """The highest power [W] keeping the magnet's peak at least ``margin_C`` below the grade's
        limit (the table's largest power when even it does; 0 when no power does)."""
        limit = params.magnet_grade(grade).max_operating_C - margin_C
        self.check(force_N, 0.0, duration_s)

        def peak(p):
            return self.predict(force_N, p, duration_s).magnet_peak_C

        lo, hi = 0.0, self.max_power_W
        if peak(hi) <= limit:
            return hi
        if peak(lo) > limit:
            return 0.0
        # The peak rises with power along every table line: bisection to 1 mW.
        while hi - lo > 1e-3:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if peak(mid) <= limit else (lo, mid)
        return lo


@functools.lru_cache(maxsize=1)
def default_surrogate() -> LesionSurrogate:
    """The surrogate of the default ``TableSpec`` (built once per cache, loaded once per process)."""
    return LesionSurrogate()


def choose_power(force_N: float, duration_s: float, *, grade: str = "N52") -> float:
    """The highest generator power [W] keeping the tip magnet below its grade's limit.

    The magnet's peak over a dwell of ``duration_s`` at contact force ``force_N`` stays at least
    ``MAGNET_MARGIN_C`` (5 C: the coarse mesh reads the peak 2.3 C low, the interpolation's error
    at held-out points is below 2 C) below the grade's maximum operating temperature (``params.MAGNET_GRADES``: N52 80 C,
    N42SH 150 C). When even the table's largest power keeps it there (N42SH: the 100 C cut-off
    caps the tissue), that power is returned.
    """
    return default_surrogate().choose_power(force_N, duration_s, grade=grade)


def predict(force_N: float, power_W: float, duration_s: float) -> LesionPrediction:
    """``default_surrogate().predict``."""
    return default_surrogate().predict(force_N, power_W, duration_s)


# ------------------------------------------------------------------------------------- validation
HELD_OUT = ((0.4e-3, 5.0), (0.8e-3, 1.125), (1.0e-3, 1.625), (1.2e-3, 2.25), (1.4e-3, 0.875), (1.0e-3, 12.5))
"""(indentation [m], power [W]) between the default table's nodes, for ``validation_table``."""
HELD_OUT_DURATIONS_S = (9.0, 31.0, 61.0, 89.0)  # between the 2 s duration nodes


def validation_table(model: LesionSurrogate | None = None, points=HELD_OUT, durations_s=HELD_OUT_DURATIONS_S,
                     progress: bool = True) -> list[dict]:
    """The surrogate against direct FEM runs (same mesh spacing and time step as the table) at
    held-out (indentation, power) points, each read at ``durations_s``.

    Returns:
        rows {force_gf, indentation_mm, power_W, duration_s, then for width_mm, depth_mm and
        magnet_peak_C: fem_*, surrogate_*, error_* (surrogate - FEM)}.
    """
    from tqdm import tqdm

    model = model or default_surrogate()
    spec = model.spec
    rows = []
    for d, p in tqdm(points, desc="lesion surrogate vs FEM", unit="run", disable=not progress, file=sys.stderr):
        electrode = fem.ball_chain_tip(indentation=d)
        sim = fem.simulate(electrode, power_W=p, duration_s=max(durations_s), tissue_name=spec.tissue,
                           initial_temperature_C=spec.initial_temperature_C, h=spec.h_m, dt_max=spec.dt_max_s,
                           output_every_s=1.0)
        by_t = {round(g["t_s"], 6): g for g in sim.growth}
        force = float(hertz_force(d))
        for t in durations_s:
            g = by_t[round(float(t), 6)]
            truth = {"width_mm": g["omega_width_mm"], "depth_mm": g["omega_depth_mm"],
                     "magnet_peak_C": float(sim.max_electrode_C[sim.times <= t + 1e-9].max())}
            pred = model.predict(force, p, t)
            guess = {"width_mm": 1e3 * pred.width_m, "depth_mm": 1e3 * pred.depth_m,
                     "magnet_peak_C": pred.magnet_peak_C}
            row = {"force_gf": force / params.GRAVITY * 1e3, "indentation_mm": 1e3 * d, "power_W": p,
                   "duration_s": t, "across_onset": model.across_onset(force, p, t)}
            for k in truth:
                row.update({f"fem_{k}": truth[k], f"surrogate_{k}": guess[k], f"error_{k}": guess[k] - truth[k]})
            rows.append(row)
    return rows


def format_error_table(rows: list[dict]) -> str:
    """``validation_table``'s rows as a text table (* : across the lesion's onset, see
    ``LesionSurrogate.across_onset``), with the largest absolute errors last, without and with
    those rows."""
    head = (f"{'F [gf]':>7} {'d [mm]':>6} {'P [W]':>5} {'t [s]':>5} | {'width FEM/sur [mm]':>18} "
            f"{'depth FEM/sur [mm]':>18} {'magnet FEM/sur [C]':>18}")
    lines = [head, "-" * len(head)]
    for r in rows:
        cells = [f"{r[f'fem_{k}']:7.2f}/{r[f'surrogate_{k}']:<7.2f}"[:18].rjust(18)
                 for k in ("width_mm", "depth_mm", "magnet_peak_C")]
        lines.append(f"{r['force_gf']:7.1f} {r['indentation_mm']:6.2f} {r['power_W']:5.2f} {r['duration_s']:5.0f} | "
                     + " ".join(cells) + (" *" if r["across_onset"] else ""))
    for label, subset in (("", [r for r in rows if not r["across_onset"]]), (" (with *)", rows)):
        if not subset:
            continue
        worst = {k: max(abs(r[f"error_{k}"]) for r in subset) for k in ("width_mm", "depth_mm", "magnet_peak_C")}
        lines.append(f"largest |error|{label}: width {worst['width_mm']:.3f} mm, depth {worst['depth_mm']:.3f} mm, "
                     f"magnet {worst['magnet_peak_C']:.2f} C")
    return "\n".join(lines)


if __name__ == "__main__":  # python -m ballchain.drake_models.lesion_surrogate: (re)build the shipped table
    print(ship_table())
