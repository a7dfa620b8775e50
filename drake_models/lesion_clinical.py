"""The lesion FEM in clinical conditions: blood flow, open irrigation, a temperature-controlled generator.

``simulate_clinical`` runs the same axisymmetric electro-thermal problem as
``lesion_fem.simulate`` (mesh, materials, laws, implicit Euler, Arrhenius damage) with:

- the surroundings of ``lesion_boundary.ThermalConditions``: with flowing blood the fluid
  domain conducts the current (``lesion_boundary.BLOOD``) but is held at the blood's temperature
  (its Joule heat carried away), and Newton conditions h_E, h_T cool the electrode's and the
  wall's wetted surfaces; with open irrigation the electrode is held at the irrigant's
  temperature;
- the generator of ``rf_generator.Generator``: power or temperature control, the tissue cut-off,
  the magnet's limit on the electrode.

With still fluid, no irrigation and power control it is ``lesion_fem.simulate`` step for step
(``tests/test_lesion_clinical.py`` checks the two agree to 1e-9 C). Energy: delivered =
stored + far boundary + held nodes (blood, irrigated tip) + convection + the blood's Joule heat.
"""

from __future__ import annotations

import math
import numpy as np
import scipy.sparse as sp
from skfem import asm

from ballchain.drake_models import lesion_boundary as boundary
from ballchain.drake_models import lesion_fem as fem
from ballchain.drake_models import tissue as laws
from ballchain.drake_models.lesion_assembly import mass_form  # the bench FEM's form
from ballchain.drake_models.lesion_mesh import ELECTRODE, HOLDER, SALINE, TISSUE
from ballchain.drake_models.rf_generator import Generator
from ballchain.infrastructure.errors import UserInputError


class ClinicalModel:
    """The FEM operators with the fluid excluded from the heat problem when it flows.

    Args:
        am: the mesh.
        tissue_material: the tissue.
        conditions: blood flow and irrigation.
        fluid: the fluid's material (None: saline when still, blood when flowing).
        initial_temperature_C: the blood's (and far field's) temperature [C].
    """

    def __init__(self, am: fem.AblationMesh, tissue_material: laws.Material,
                 conditions: boundary.ThermalConditions, fluid: laws.Material | None = None,
                 initial_temperature_C: float = 37.0):
        self.am, self.conditions = am, conditions
        fluid = fluid or (boundary.BLOOD if conditions.flowing else laws.SALINE)
        self.em = fem.ElectroThermalModel(am, tissue_material, fluid)
        thermal = [TISSUE, ELECTRODE, HOLDER] + ([] if conditions.flowing else [SALINE])
        self.thermal_domains = tuple(thermal)
        self.thermal_elements = np.isin(am.domain, thermal)
        self._qp_mask = np.repeat(self.thermal_elements[:, None], self.em.basis.X.shape[1], axis=1)
        if conditions.flowing:
            rho_c = np.zeros(self._qp_mask.shape)
            for d, mat in self.em.materials.items():
                rho_c[self.em._dom == d] = mat.volumetric_heat_capacity
            rho_c[~self._qp_mask] = 0.0
            self.capacity = np.asarray(asm(mass_form, self.em.basis, coef=rho_c).sum(axis=1)).ravel()
            self.mass = sp.diags(self.capacity).tocsr()
        else:
            self.capacity, self.mass = self.em.capacity, self.em.mass
        n = am.n_nodes
        t_b = float(initial_temperature_C)
        facets = boundary.interface_facets(am)
        r_e, l_e = boundary.robin_operator(am, facets["electrode"], conditions.h_electrode, t_b)
        r_t, l_t = boundary.robin_operator(am, facets["tissue"], conditions.h_tissue, t_b)
        self.robin, self.robin_load = (r_e + r_t).tocsr(), l_e + l_t
        self._robin_data = self.em.ops.data_of(self.robin) if self.robin.nnz else None
        # Held nodes: the far arc, the nodes of no heat-conducting element (the flowing blood), the
        # irrigated electrode.
        in_thermal = np.zeros(n, dtype=bool)
        in_thermal[np.unique(am.mesh.t[:, self.thermal_elements])] = True
        held = [am.ground_nodes, np.flatnonzero(~in_thermal)]
        self.held_value = np.full(n, t_b)
        if conditions.irrigation == "open":
            tip = am.nodes_of(ELECTRODE)
            held.append(tip)
            self.held_value[tip] = conditions.irrigant_C
        self.fixed = np.unique(np.concatenate(held))
        self.free = np.setdiff1d(np.arange(n), self.fixed)
        self.block = self.em.ops.block(self.free)

    def stiffness(self, temperature_C) -> np.ndarray:
        """Conduction (k(T), the flowing blood excluded) plus the Newton conditions, as data of the
        mesh's pattern (``em.ops``)."""
        k = self.em.conduction(temperature_C, self.thermal_domains)
        return k + self._robin_data if self._robin_data is not None else k

    def joule(self, temperature_C):
        """(conductance [S], load per V^2 into the heat problem, load per V^2 of every element)."""
        _, conductance, density = self.em.unit_potential(temperature_C)
        full = self.em.joule_load(density)
        if not self.conditions.flowing:
            return conductance, full, full
        return conductance, self.em.joule_load(np.where(self._qp_mask, density, 0.0)), full


def simulate_clinical(electrode: fem.Electrode, *, generator: Generator, duration_s: float,
                      conditions: boundary.ThermalConditions | None = None, tissue_name: str = "myocardium",
                      initial_temperature_C: float = 37.0, h: float = 0.1e-3, dt_max: float = 1.0,
                      output_every_s: float = 5.0, fluid: laws.Material | None = None,
                      mesh: fem.AblationMesh | None = None, progress=None) -> fem.LesionSimulation:
    """One RF application in clinical conditions (see the module docstring).

    Args:
        electrode: the electrode.
        generator: its control mode, power (or cap), target and limits.
        duration_s: RF time [s].
        conditions: blood flow and irrigation (None: still fluid, no irrigation).
        tissue_name: "myocardium" or "liver".
        initial_temperature_C: tissue, fluid and far field at t = 0; the flowing blood's temperature [C].
        h: mesh spacing near the electrode [m].
        dt_max: largest time step [s].
        output_every_s: spacing of the growth rows [s].
        fluid: the fluid's material (None: saline when still, blood when flowing).
        mesh: a prebuilt mesh for this electrode.
        progress: optional callable(n_steps_done, n_steps_total).
    Returns:
        ``lesion_fem.LesionSimulation``; its ``info`` adds set_power_W, mean_power_W, limit_share
        (fraction of the RF time each limit set the power), energy_convection_J,
        energy_held_J, energy_blood_joule_J and the conditions.
    """
    if duration_s <= 0 or not math.isfinite(duration_s):
        raise UserInputError(f"duration must be positive, got {duration_s}")
    conditions = conditions or boundary.ThermalConditions()
    material, arrhenius = laws.tissue(tissue_name)
    am = mesh or fem.build_mesh(electrode, h=h)
    model = ClinicalModel(am, material, conditions, fluid, initial_temperature_C)
    n = am.n_nodes
    T = np.full(n, float(initial_temperature_C))
    T[model.fixed] = model.held_value[model.fixed]
    T0 = T.copy()
    fixed = model.fixed
    tissue_nodes = am.nodes_of(TISSUE)
    electrode_nodes = am.nodes_of(ELECTRODE)
    water_nodes = am.nodes_of(TISSUE, SALINE)
    el_t, el_w = fem._electrode_volume_weights(am)  # noqa: SLF001 - the bench FEM's own helper
    output_times = np.arange(output_every_s, duration_s + 1e-9, output_every_s)
    times = fem.time_steps(duration_s, dt_max, breakpoints=output_times)
    outputs = set(np.round(output_times, 9)) | {round(duration_s, 9)}
    damage = np.zeros(n)
    rate_prev = arrhenius.rate(T)
    peak = T.copy()
    hist = {k: [] for k in ("power", "voltage", "impedance", "max_tissue", "max_electrode", "mean_electrode",
                            "limited", "which")}
    growth, snapshots = [], {}
    energy = held_out = convected = blood_joule = 0.0
    vaporised_at, t_prev = None, 0.0
    for i, t in enumerate(times):
        dt = t - t_prev
        A, lu, base, T_next = fem.implicit_step(model.em.ops, model.block, model.stiffness(T), model.capacity, T, T0,
                                                dt, model.robin_load)
        conductance, unit_load, unit_all = model.joule(T)
        rise = np.zeros(n)
        rise[lu.rows] = lu.solve(unit_load)
        v2, which = generator.voltage_squared(conductance, T_next, rise, water_nodes, electrode_nodes)
        T_next = T_next + v2 * rise
        load = v2 * unit_load
        delivered = 2.0 * math.pi * v2 * float(unit_all.sum())
        blood_joule += dt * (delivered - 2.0 * math.pi * v2 * float(unit_load.sum()))
        held_out += 2.0 * math.pi * dt * float(np.sum((load + base - A @ T_next)[fixed]))
        convected += 2.0 * math.pi * dt * float(np.sum(model.robin @ T_next - model.robin_load))
        T = T_next
        energy += delivered * dt
        rate = arrhenius.rate(T)
        damage += 0.5 * (rate + rate_prev) * dt
        rate_prev = rate
        peak = np.maximum(peak, T)
        hist["power"].append(delivered)
        hist["voltage"].append(math.sqrt(v2))
        hist["impedance"].append(1.0 / conductance)
        hist["max_tissue"].append(float(T[tissue_nodes].max()))
        hist["max_electrode"].append(float(T[electrode_nodes].max()))
        hist["mean_electrode"].append(float(el_w @ T[el_t].mean(axis=0)))
        hist["limited"].append(which != "power")
        hist["which"].append(which)
        if vaporised_at is None and hist["max_tissue"][-1] >= laws.VAPORISATION_ONSET_C:
            vaporised_at = float(t)
        if round(float(t), 9) in outputs:
            snapshots[float(t)] = T.copy()
            growth.append(fem._growth_row(am, float(t), damage, peak))  # noqa: SLF001 - same rows as the bench
        if progress is not None:
            progress(i + 1, len(times))
        t_prev = t
    stored = 2.0 * math.pi * float(np.sum(model.mass @ (T - T0)))
    dts = np.diff(np.concatenate([[0.0], times]))
    share = {k: float(np.sum(dts[np.array(hist["which"]) == k]) / duration_s)
             for k in ("power", "cutoff", "electrode")}
    return fem.LesionSimulation(
        mesh=am, times=times, power=np.array(hist["power"]), voltage=np.array(hist["voltage"]),
        impedance=np.array(hist["impedance"]), limited=np.array(hist["limited"]),
        max_tissue_C=np.array(hist["max_tissue"]), max_electrode_C=np.array(hist["max_electrode"]),
        mean_electrode_C=np.array(hist["mean_electrode"]), snapshots=snapshots, damage=damage,
        peak_temperature=peak, final_temperature=T, growth=growth, energy_delivered_J=energy,
        energy_stored_J=stored, energy_boundary_J=held_out, vaporisation_time_s=vaporised_at,
        info={"nodes": n, "elements": am.mesh.t.shape[1], "steps": len(times), "tissue": tissue_name,
              "initial_temperature_C": initial_temperature_C, "h_mm": am.h * 1e3,
              "set_power_W": generator.power_W, "mean_power_W": energy / duration_s, "limit_share": share,
              "energy_convection_J": convected, "energy_held_J": held_out, "energy_blood_joule_J": blood_joule,
              "blood_flow": conditions.blood_flow, "irrigation": conditions.irrigation,
              "control": generator.mode, "electrode_set_point_C": generator.electrode_set_point_C})

