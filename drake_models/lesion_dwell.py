"""The tip ball's lesions in clinical conditions, and how long each dwell lasts (issue 44).

``lesion_surrogate`` tabulates the paper's bench (still saline, set power). Here a second table
(``DwellTableSpec``) holds the tip ball's lesion in a beating heart, run once per setting with
``lesion_clinical.simulate_clinical``: blood flowing past it (``lesion_boundary``), the generator
in power or temperature control with the magnet's limit (grade's limit less
``lesion_surrogate.MAGNET_MARGIN_C``) in its loop (``rf_generator``), over the indentation
(Hertz's law gives it from the force) and the RF time. The delivered power follows from the
physics: the table stores its running mean.

Each dwell ends by a lesion criterion (``LesionConditions.criterion``):

- "transmural": when the predicted depth reaches the local wall thickness,
- "contiguous": when it is transmural AND as wide as the distance to its farthest ring neighbour
  (so that neighbouring lesions overlap: the ring's gap rule, ``lesion_ring``),
- "fti": when the force-time integral reaches ``fti_target_gfs`` (EFFICAS II: target 20 g,
  range 10-30 g, at least 400 g s; Kautzner et al., Europace 17(8):1229-1235, 2015),
- "fixed": the procedure's own dwell,

never beyond ``time_limit_s``. The dwell is the RF time the lesion is computed for: the
simulated robot held the force for the procedure's dwell, and the lesion takes the dwell's mean
force as held for the criterion's time (reported per lesion).

The table is generated data, cached like ``lesion_surrogate``'s (keyed by a hash of the spec
and of the source of every module that makes it; 7 FEM runs, under a CPU-minute). The tables of
``SHIPPED_SPECS`` (the procedure report's clinical lesions) ship in the package
(``generated/lesion_dwell/<key>/``, with their SHA-1 list), so that a fresh machine does not
build them; after a change to the code that makes them (a new key), regenerate them with
``python -m ballchain.drake_models.lesion_dwell`` (``ship_tables``).
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

from ballchain.drake_models import lesion_boundary as boundary
from ballchain.drake_models import lesion_clinical as clinical
from ballchain.drake_models import lesion_fem as fem
from ballchain.drake_models import lesion_surrogate as surrogate
from ballchain.drake_models import model_files, params, rf_generator
from ballchain.drake_models import tissue as laws
from ballchain.drake_models.lesion_ring import DEFAULT_WALL_THICKNESS_M, AblationPoint, Lesion
from ballchain.infrastructure.errors import UserInputError, short_repr

CRITERIA = ("transmural", "contiguous", "fti", "fixed")
FTI_TARGET_GFS = 400.0  # [gf s] EFFICAS II's minimum force-time integral
TIME_LIMIT_S = 60.0  # [s] the longest RF application per point (clinical point-by-point PVI: 20-60 s)
DWELL_TABLE_VERSION = 1


@dataclass(frozen=True)
class LesionConditions:
    """How the procedure's lesions are made.

    Attributes:
        blood_flow: "none", "low" or "high" (``lesion_boundary.FLOW_COEFFICIENTS``).
        control: "power" or "temperature".
        power_W: the set power (power control) or the cap (temperature control) [W].
        target_C: the electrode's set point under temperature control [C].
        grade: the tip magnet's grade; its limit less the margin is held by the generator.
        criterion: "transmural", "fti" or "fixed" (module docstring).
        time_limit_s: the longest RF time [s].
        fti_target_gfs: the force-time integral target [gf s].
        wall_thickness_m: the local wall thickness (transmural criterion and verdict) [m].
    """

    blood_flow: str = "high"
    control: str = "power"
    power_W: float = 30.0
    target_C: float = rf_generator.CLINICAL_TARGET_C
    grade: str = "N52"
    criterion: str = "transmural"
    time_limit_s: float = TIME_LIMIT_S
    fti_target_gfs: float = FTI_TARGET_GFS
    wall_thickness_m: float = DEFAULT_WALL_THICKNESS_M

    def __post_init__(self) -> None:
        boundary.conditions(self.blood_flow)
        rf_generator.Generator(mode=self.control, power_W=self.power_W, target_C=self.target_C)
        params.magnet_grade(self.grade)
        if self.criterion not in CRITERIA:
            raise UserInputError(f"criterion must be one of {CRITERIA}, got {short_repr(self.criterion)}")
        for name, lo, hi in (("time_limit_s", 1.0, 120.0), ("fti_target_gfs", 1.0, 5000.0),
                             ("wall_thickness_m", 0.2e-3, 10e-3), ("power_W", 0.5, 100.0)):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and lo <= v <= hi):
                raise UserInputError(f"{name} must be in [{lo:g}, {hi:g}], got {short_repr(v)}")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> "LesionConditions":
        return cls(**data)

    def table_spec(self) -> "DwellTableSpec":
        return DwellTableSpec(blood_flow=self.blood_flow, control=self.control, power_W=self.power_W,
                              target_C=self.target_C, grade=self.grade)


@dataclass(frozen=True)
class DwellTableSpec:
    """The FEM runs of a clinical table: one per indentation, each read every ``output_every_s``."""

    blood_flow: str = "high"
    control: str = "power"
    power_W: float = 30.0
    target_C: float = rf_generator.CLINICAL_TARGET_C
    grade: str = "N52"
    indentations_m: tuple = (0.3e-3, 0.5e-3, 0.7e-3, 0.9e-3, 1.1e-3, 1.3e-3, 1.5e-3)
    duration_s: float = 120.0
    output_every_s: float = 2.0
    h_m: float = 0.2e-3
    dt_max_s: float = 1.0
    initial_temperature_C: float = surrogate.BODY_TEMPERATURE_C

    @property
    def durations_s(self) -> np.ndarray:
        n = int(round(self.duration_s / self.output_every_s))
        return np.arange(n + 1) * self.output_every_s

    def generator(self) -> rf_generator.Generator:
        limit = params.magnet_grade(self.grade).max_operating_C - surrogate.MAGNET_MARGIN_C
        return rf_generator.Generator(mode=self.control, power_W=self.power_W, target_C=self.target_C,
                                      electrode_limit_C=limit)

    def key(self) -> str:
        code = (model_files.source_hash(*fem.SOURCE_MODULES, laws, clinical, boundary, rf_generator)
                + repr(params.BallChain()))
        # The generator as the FEM runs get it: the magnet's limit less the margin, which live in
        # params and lesion_surrogate (a change to them is a new table).
        code += repr(self.generator())
        builder = inspect.getsource(build_dwell_table)
        text = repr(sorted(dataclasses.asdict(self).items())) + code + builder + str(DWELL_TABLE_VERSION)
        return hashlib.sha1(text.encode()).hexdigest()[:12]


def build_dwell_table(spec: DwellTableSpec, progress: bool = True) -> dict:
    """Run the FEM at every indentation of ``spec``.

    Returns:
        {"indentation_m", "duration_s" (0 first), "width_mm", "depth_mm", "magnet_peak_C",
        "mean_power_W" (each (n_ind, n_dur)), "cpu_s"}.
    """
    from tqdm import tqdm

    start = time.process_time()
    ind = np.asarray(spec.indentations_m, dtype=float)
    durations = spec.durations_s
    shape = (len(ind), len(durations))
    out = {k: np.zeros(shape) for k in ("width_mm", "depth_mm", "mean_power_W")}
    out["magnet_peak_C"] = np.full(shape, float(spec.initial_temperature_C))
    conditions = boundary.conditions(spec.blood_flow)
    for i, d in enumerate(tqdm(ind, desc="clinical lesion table (FEM runs)", unit="run", disable=not progress,
                               file=sys.stderr)):
        sim = clinical.simulate_clinical(fem.ball_chain_tip(indentation=d), generator=spec.generator(),
                                         duration_s=spec.duration_s, conditions=conditions,
                                         initial_temperature_C=spec.initial_temperature_C, h=spec.h_m,
                                         dt_max=spec.dt_max_s, output_every_s=spec.output_every_s)
        by_t = {round(g["t_s"], 6): g for g in sim.growth}
        dts = np.diff(np.concatenate([[0.0], sim.times]))
        for j, t in enumerate(durations[1:], start=1):
            g, upto = by_t[round(float(t), 6)], sim.times <= t + 1e-9
            out["width_mm"][i, j], out["depth_mm"][i, j] = g["omega_width_mm"], g["omega_depth_mm"]
            out["magnet_peak_C"][i, j] = float(sim.max_electrode_C[upto].max())
            out["mean_power_W"][i, j] = float(np.sum(sim.power[upto] * dts[upto]) / t)
    return {"indentation_m": ind, "duration_s": durations, **out,
            "cpu_s": np.array(time.process_time() - start)}


SHIPPED = surrogate.SHIPPED.parent / "lesion_dwell"
"""Tables shipped with the package (``<key>/dwell_table.npz`` + ``files.sha1``); used only when
the key and the digest match, otherwise the table is built into the cache."""
SHIPPED_SPECS = (DwellTableSpec(blood_flow="high"),)
"""The specs whose tables ship: the procedure report's ``CLINICAL_LESIONS.table_spec()`` (high
flow, power control at 30 W with the N52 magnet's limit in the loop; tests/test_lesion_dwell.py
checks that they agree)."""
SHIP_COMMAND = "python -m ballchain.drake_models.lesion_dwell"


def shipped_path(spec: DwellTableSpec) -> Path:
    """Where the shipped table of ``spec`` is (or would be) [path]."""
    return SHIPPED / spec.key() / "dwell_table.npz"


def ship_tables(specs=SHIPPED_SPECS, progress: bool = True) -> list[Path]:
    """Build the tables of ``specs`` into the package (``SHIPPED``), each with its SHA-1 list, and
    remove the shipped tables of older keys (``model_files.ship_arrays``). Returns the tables
    written."""
    tables = {spec.key(): build_dwell_table(spec, progress=progress) for spec in specs}
    return model_files.ship_arrays(SHIPPED, tables, shipped_path(specs[0]).name)


def cached_dwell_table(spec: DwellTableSpec, progress: bool = True) -> dict:
    """``build_dwell_table(spec)``: the copy shipped with the package when its key matches, else
    from the cache (built and written when missing or damaged)."""
    shipped = model_files.shipped_arrays(shipped_path(spec))
    if shipped is not None:
        return shipped

    def write(tmp):
        table = build_dwell_table(spec, progress=progress)
        with open(tmp["table"], "wb") as f:
            np.savez(f, **table)

    paths = model_files.cached_files(model_files.cache_dir() / "lesion_dwell" / spec.key(),
                                     {"table": "dwell_table.npz"}, write)
    with np.load(paths["table"]) as data:
        return {k: np.array(data[k]) for k in data.files}


class DwellSurrogate:
    """The clinical table, interpolated (bilinear in indentation and time)."""

    def __init__(self, spec: DwellTableSpec, progress: bool = True):
        self.spec = spec
        self.table = cached_dwell_table(spec, progress=progress)
        axes = (self.table["indentation_m"], self.table["duration_s"])
        self._interp = {k: RegularGridInterpolator(axes, self.table[k], method="linear")
                        for k in ("width_mm", "depth_mm", "magnet_peak_C", "mean_power_W")}

    def _indentation(self, force_N: float) -> float:
        ind = self.table["indentation_m"]
        return float(np.clip(surrogate.indentation_for_force(force_N), ind[0], ind[-1]))

    def predict(self, force_N: float, duration_s: float) -> dict:
        """{width_m, depth_m, magnet_peak_C, mean_power_W, indentation_m} of one dwell."""
        if not (math.isfinite(force_N) and force_N >= 0 and 0 <= duration_s <= self.spec.duration_s):
            raise UserInputError(f"force_N >= 0 and duration_s in [0, {self.spec.duration_s:g}] s, got "
                                 f"{short_repr(force_N)}, {short_repr(duration_s)}")
        if force_N == 0.0 or duration_s == 0.0:
            return {"width_m": 0.0, "depth_m": 0.0, "magnet_peak_C": self.spec.initial_temperature_C,
                    "mean_power_W": 0.0, "indentation_m": 0.0}
        x = np.array([[self._indentation(force_N), float(duration_s)]])
        v = {k: float(f(x)[0]) for k, f in self._interp.items()}
        return {"width_m": 1e-3 * v["width_mm"], "depth_m": 1e-3 * v["depth_mm"], "magnet_peak_C": v["magnet_peak_C"],
                "mean_power_W": v["mean_power_W"], "indentation_m": float(x[0, 0])}

    def dwell_for(self, force_N: float, conditions: LesionConditions, fixed_s: float,
                  width_target_m: float = 0.0) -> float:
        """The RF time the criterion gives at this force [s] (within the time limit and the table);
        ``width_target_m``: the width the "contiguous" criterion waits for [m]."""
        limit = min(conditions.time_limit_s, self.spec.duration_s)
        if conditions.criterion == "fixed" or force_N <= 0.0:
            return float(min(fixed_s, limit))
        if conditions.criterion == "fti":
            return float(min(conditions.fti_target_gfs / (force_N / params.GRAVITY * 1e3), limit))
        times = np.arange(0.0, limit + 1e-9, 0.25)
        x = np.c_[np.full(len(times), self._indentation(force_N)), times]
        done = 1e-3 * self._interp["depth_mm"](x) >= conditions.wall_thickness_m
        if conditions.criterion == "contiguous":
            done &= 1e-3 * self._interp["width_mm"](x) >= width_target_m
        reached = np.flatnonzero(done)
        return float(times[reached[0]]) if len(reached) else float(limit)


@functools.lru_cache(maxsize=8)
def dwell_surrogate(spec: DwellTableSpec) -> DwellSurrogate:
    """The surrogate of ``spec`` (built once per cache, loaded once per process)."""
    return DwellSurrogate(spec)


def neighbour_distances(points: list) -> dict:
    """Per ring point (dicts with "name" and "p_W", in ring order, a closed loop) the distance to
    its farthest neighbour [m]: the width its lesion needs to overlap both."""
    out = {}
    n = len(points)
    for k, pt in enumerate(points):
        p = np.asarray(pt["p_W"], float)
        near = [np.asarray(points[(k + d) % n]["p_W"], float) for d in (-1, 1)] if n > 1 else [p]
        out[pt["name"]] = float(max(np.linalg.norm(q - p) for q in near))
    return out


def lesion_for(name: str, p_W, n_W, force_N: float, fixed_s: float, conditions: LesionConditions,
               model: DwellSurrogate | None = None, width_target_m: float = 0.0) -> Lesion:
    """The lesion of one dwell under ``conditions``: its RF time by the criterion, its power the
    delivered mean, its depth judged against ``conditions.wall_thickness_m``."""
    model = model or dwell_surrogate(conditions.table_spec())
    rf_s = model.dwell_for(float(force_N), conditions, float(fixed_s), width_target_m)
    pred = model.predict(float(force_N), rf_s)
    point = AblationPoint(name, np.asarray(p_W, float), np.asarray(n_W, float), float(force_N), rf_s,
                          pred["mean_power_W"])
    return Lesion(point=point, width_m=pred["width_m"], depth_m=pred["depth_m"], magnet_peak_C=pred["magnet_peak_C"],
                  transmural=bool(pred["depth_m"] >= conditions.wall_thickness_m - 1e-9),
                  wall_thickness_m=conditions.wall_thickness_m, grade=conditions.grade)


if __name__ == "__main__":  # python -m ballchain.drake_models.lesion_dwell: (re)build the shipped tables
    for written in ship_tables():
        print(written)
