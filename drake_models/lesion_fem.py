"""Axisymmetric electro-thermal finite-element model of an RF ablation lesion (scikit-fem, P1).

The geometry (``lesion_mesh``, its names re-exported here): the (r, z) half disc around an
electrode pressed into the tissue, tissue below z = 0, 0.9 % saline above (a domain for both the
current and the heat: the paper's bath has no flow and no irrigation), the arc the dispersive
electrode and the far field; the tip ball (``ball_chain_tip``) or an 8 Fr catheter
(``catheter_8fr``).

Physics (laws in ``drake_models/tissue.py``): the quasi-static potential div(sigma(T) grad V) = 0
with V = V_gen on the active electrode surface, V = 0 at the dispersive electrode, insulation
elsewhere; the generator in constant-power mode sets V_gen each step so that V^2 G(T) = P.
Pennes' bioheat without perfusion (ex vivo): rho c dT/dt = div(k(T) grad T) + sigma |grad V|^2
in every domain (the electrode and holder conduct heat but carry no current). Implicit Euler,
conductivities lagged one step. The Arrhenius integral Omega at the nodes; the lesion is
Omega >= 1 and, beside it, the tissue that reached 50 C.

The forms and their per-step assembly: ``lesion_assembly`` (the r-weighted diffusion and source
forms assembled on a fixed sparsity pattern from precomputed element products, the same
discretisation as ``skfem.asm`` of the forms; the free-node blocks factorised in an order
computed once).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from skfem import CellBasis, ElementTriP1, asm

from ballchain.drake_models import lesion_assembly, lesion_mesh
from ballchain.drake_models import tissue as laws
from ballchain.drake_models.errors import UserInputError
from ballchain.drake_models.lesion_assembly import BlockFactor, OrderedBlock, P1Operators, mass_form
from ballchain.drake_models.lesion_mesh import (  # noqa: F401 - the geometry's names, re-exported
    CATHETER_8FR_DIAMETER, CATHETER_TIP_LENGTH, DOMAIN_NAMES, ELECTRODE, HOLDER, SALINE, TISSUE, AblationMesh,
    Electrode, ball_chain_tip, build_mesh, catheter_8fr)

SOURCE_MODULES = (lesion_mesh, lesion_assembly, sys.modules[__name__])
"""The modules whose source makes the FEM's results: the generated tables' keys hash them."""


class ElectroThermalModel:
    """Material fields and FE operators on an ``AblationMesh`` for one tissue.

    Args:
        mesh: the triangulation.
        tissue_material: tissue properties (``tissue.MYOCARDIUM`` ...).
        saline: the bath's properties.

    Attributes:
        ops: the mesh's P1 operators (``lesion_assembly.P1Operators``).
        mass: the lumped heat capacity (diagonal matrix, r-weighted); ``capacity`` its diagonal.
        electric: the electric solve's block (the nodes not held by a Dirichlet condition).
    """

    def __init__(self, mesh: AblationMesh, tissue_material: laws.Material = laws.MYOCARDIUM,
                 saline: laws.Material = laws.SALINE):
        self.am = mesh
        self.basis = CellBasis(mesh.mesh, ElementTriP1())
        self.ops = P1Operators(self.basis)
        self.materials = {TISSUE: tissue_material, SALINE: saline, ELECTRODE: mesh.electrode.material,
                          HOLDER: laws.POLYMER}
        nqp = self.basis.X.shape[1]
        self._dom = np.repeat(mesh.domain[:, None], nqp, axis=1)
        self._at = {d: np.flatnonzero(self._dom.ravel() == d) for d in self.materials}
        rho_c = np.zeros_like(self._dom, dtype=float)
        for d, mat in self.materials.items():
            rho_c[self._dom == d] = mat.volumetric_heat_capacity
        # Lumped (row-sum) heat capacity: with the consistent matrix, implicit Euler at small
        # steps undershoots the initial temperature and leaks heat to the far boundary at once.
        self.capacity = np.asarray(asm(mass_form, self.basis, coef=rho_c).sum(axis=1)).ravel()
        self.mass = sp.diags(self.capacity).tocsr()
        # Nodes touched by no conducting triangle carry no equation: fix them (at 0).
        live = [d for d in (TISSUE, SALINE) if self.materials[d].electrical_conductivity > 0]
        conducting = np.unique(mesh.mesh.t[:, np.isin(mesh.domain, live)])
        isolated = np.setdiff1d(np.arange(mesh.n_nodes), conducting)
        self.electric_fixed = np.unique(np.concatenate([mesh.active_nodes, mesh.ground_nodes, isolated]))
        self.electric_boundary = np.zeros(mesh.n_nodes)
        self.electric_boundary[mesh.active_nodes] = 1.0
        self.electric = self.ops.block(np.setdiff1d(np.arange(mesh.n_nodes), self.electric_fixed))

    def _field(self, law, temperature_C, domains=None):
        """``law(material, T)`` at the quadrature points (n_elements, n_qp) of ``domains`` (all: None), 0 elsewhere."""
        t_q = self.ops.at_quadrature(np.asarray(temperature_C, dtype=float)).ravel()
        out = np.zeros_like(t_q)
        for d in self.materials if domains is None else domains:
            at = self._at[d]
            out[at] = law(self.materials[d], t_q[at])
        return out.reshape(self._dom.shape)

    def sigma(self, temperature_C) -> np.ndarray:
        """sigma at the quadrature points (n_elements, n_qp) [S/m]; 0 in the electrode and holder."""
        return self._field(laws.electrical_conductivity, temperature_C, (TISSUE, SALINE))

    def unit_potential(self, temperature_C):
        """Potential for 1 V on the electrode and the load's conductance.

        Returns:
            (u (n_nodes,), conductance G [S], sigma |grad u|^2 at quadrature points [W/m^3 per V^2]).
        """
        sigma = self.sigma(temperature_C)
        data = self.ops.diffusion(sigma)
        A = self.ops.matrix(data)
        u = self.electric_boundary.copy()
        # The free rows of -A u_boundary (u_boundary is 0 on them): -A[free][:, fixed] u[fixed].
        u[self.electric.rows] = self.electric.factor(data).solve(-(A @ self.electric_boundary))
        g_r, g_z = self.ops.gradient(u)
        density = sigma * (g_r**2 + g_z**2)[:, None]
        conductance = 2.0 * math.pi * float(u @ (A @ u))
        return u, conductance, density

    def conduction(self, temperature_C, domains=None) -> np.ndarray:
        """The conduction matrix with k(T) (r-weighted) as data of ``ops``'s pattern; ``domains``:
        the heat-conducting domains (None: all)."""
        return self.ops.diffusion(self._field(laws.thermal_conductivity, temperature_C, domains))

    def joule_load(self, density_W_m3):
        """Load vector of a heat source given at quadrature points (r-weighted)."""
        return self.ops.source(density_W_m3)


@dataclass
class LesionSimulation:
    """Result of ``simulate``: histories (per step) and fields (per node) in SI and C.

    Attributes:
        times: (n,) step end times [s].
        power: (n,) delivered power [W] (the Joule integral of the solved field).
        voltage: (n,) electrode voltage [V rms].
        impedance: (n,) load impedance [Ohm].
        max_tissue_C, max_electrode_C: (n,) peak temperatures [C].
        mean_electrode_C: (n,) the electrode's volume-mean temperature (the magnet's bulk) [C].
        limited: (n,) whether the cut-off at vaporisation reduced the power that step.
        snapshots: {time: temperature (n_nodes,)} at the requested output times.
        damage: (n_nodes,) Omega at the end.
        peak_temperature: (n_nodes,) highest temperature each node reached [C].
        growth: rows {t_s, width_mm, depth_mm, ...} at the output times.
        energy_delivered_J, energy_stored_J: electric energy in, heat stored at the end [J].
        energy_boundary_J: heat into the far boundary (conduction and the Joule heat of the
            elements at the dispersive electrode) [J].
    """

    mesh: AblationMesh
    times: np.ndarray
    power: np.ndarray
    voltage: np.ndarray
    impedance: np.ndarray
    max_tissue_C: np.ndarray
    max_electrode_C: np.ndarray
    mean_electrode_C: np.ndarray
    limited: np.ndarray
    snapshots: dict
    damage: np.ndarray
    peak_temperature: np.ndarray
    final_temperature: np.ndarray
    growth: list
    energy_delivered_J: float
    energy_stored_J: float
    energy_boundary_J: float
    vaporisation_time_s: float | None
    info: dict = field(default_factory=dict)


def lesion_extent(am: AblationMesh, values: np.ndarray, threshold: float) -> dict:
    """Width, depth and surface diameter of the tissue region where ``values`` >= ``threshold``.

    Exact for the piecewise-linear interpolant: the region's extreme points are nodes above the
    threshold or crossings on tissue edges.

    Returns:
        {"width_mm": 2 max r, "depth_mm": max -z (from the tissue surface), "surface_diameter_mm"}.
    """
    p = am.mesh.p
    edges = am.tissue_edges
    va, vb = values[edges[0]], values[edges[1]]
    cross = (va - threshold) * (vb - threshold) < 0
    s = (threshold - va[cross]) / (vb[cross] - va[cross])
    pts = p[:, edges[0, cross]] + s * (p[:, edges[1, cross]] - p[:, edges[0, cross]])
    nodes = am.tissue_nodes
    inside = nodes[values[nodes] >= threshold]
    allp = np.hstack([pts, p[:, inside]])
    if allp.shape[1] == 0:
        return {"width_mm": 0.0, "depth_mm": 0.0, "surface_diameter_mm": 0.0}
    on_surface = np.abs(allp[1]) <= 1e-9 * am.h
    surf = float(2 * allp[0, on_surface].max()) if np.any(on_surface) else 0.0
    return {"width_mm": float(2e3 * allp[0].max()), "depth_mm": float(-1e3 * allp[1].min()),
            "surface_diameter_mm": 1e3 * surf}


def time_steps(duration: float, dt_max: float, dt_first: float = 0.05, growth: float = 1.2,
               breakpoints=()) -> np.ndarray:
    """Step end times: small first steps (the electrode edge heats within a second), then ``dt_max``.

    Every time in ``breakpoints`` (within the duration) is a step end.
    """
    marks = sorted(b for b in breakpoints if 0 < b < duration - 1e-9) + [duration]
    times, t, dt = [], 0.0, dt_first
    for mark in marks:
        while t < mark - 1e-9:
            dt = min(dt, dt_max)
            t = mark if t + dt > mark - 1e-3 * dt else t + dt
            times.append(t)
            dt *= growth
    return np.array(times)


def simulate(electrode: Electrode, *, power_W: float, duration_s: float, tissue_name: str = "myocardium",
             initial_temperature_C: float = 22.0, h: float = 0.1e-3, dt_max: float = 1.0,
             cooldown_s: float = 0.0, output_every_s: float = 5.0, max_voltage_V: float | None = None,
             limit_C: float | None = laws.VAPORISATION_ONSET_C,
             saline: laws.Material = laws.SALINE, mesh: AblationMesh | None = None,
             progress=None) -> LesionSimulation:
    """Run an RF application at constant power, then (optionally) let the tissue cool.

    Args:
        electrode: the electrode geometry.
        power_W: generator power [W].
        duration_s: RF time [s].
        tissue_name: "myocardium" or "liver".
        initial_temperature_C: tissue and bath temperature at t = 0 [C] (also the far field).
        h: mesh spacing near the electrode [m].
        dt_max: largest time step [s].
        cooldown_s: time after switch-off during which damage still accrues [s].
        output_every_s: spacing of the growth rows and snapshots [s].
        max_voltage_V: generator voltage limit [V rms], None for none.
        limit_C: the cut-off at vaporisation (``tissue.temperature_limited_voltage_squared``):
            the power is reduced so that no tissue or saline exceeds it; None: pure constant power.
        saline: the bath's properties.
        mesh: a prebuilt mesh for this electrode (else built with ``h``).
        progress: optional callable(n_steps_done, n_steps_total).
    """
    if power_W < 0 or not math.isfinite(power_W):
        raise UserInputError(f"power must be a finite number >= 0 W, got {power_W}")
    if duration_s <= 0 or not math.isfinite(duration_s):
        raise UserInputError(f"duration must be positive, got {duration_s}")
    material, arrhenius = laws.tissue(tissue_name)
    am = mesh or build_mesh(electrode, h=h)
    model = ElectroThermalModel(am, material, saline)
    n = am.n_nodes
    T = np.full(n, float(initial_temperature_C))
    T0 = T.copy()
    fixed = am.ground_nodes
    block = model.ops.block(np.setdiff1d(np.arange(n), fixed))
    tissue_nodes = am.nodes_of(TISSUE)
    electrode_nodes = am.nodes_of(ELECTRODE)
    water_nodes = am.nodes_of(TISSUE, SALINE)
    el_t, el_w = _electrode_volume_weights(am)
    output_times = np.arange(output_every_s, duration_s + 1e-9, output_every_s)
    rf_times = time_steps(duration_s, dt_max, breakpoints=output_times)
    cool_times = duration_s + time_steps(cooldown_s, dt_max, dt_first=dt_max) if cooldown_s > 0 else np.array([])
    all_times = np.concatenate([rf_times, cool_times])
    outputs = set(np.round(output_times, 9)) | {round(duration_s, 9)}
    damage = np.zeros(n)
    rate_prev = arrhenius.rate(T)
    peak = T.copy()
    hist = {k: [] for k in ("power", "voltage", "impedance", "max_tissue", "max_electrode", "mean_electrode",
                            "limited")}
    snapshots, growth = {}, []
    energy = 0.0
    outflow = 0.0
    vaporised_at = None
    t_prev = 0.0
    for i, t in enumerate(all_times):
        dt = t - t_prev
        rf_on = t <= duration_s + 1e-9
        A, lu, base, T_next = implicit_step(model.ops, block, model.conduction(T), model.capacity, T, T0, dt)
        voltage, delivered, impedance, limited = 0.0, 0.0, float("nan"), False
        if rf_on and power_W > 0:
            T_next, voltage, delivered, impedance, limited, load = _joule_heating(
                model, T, T_next, lu, water_nodes, power_W, max_voltage_V, limit_C)
        else:
            load = np.zeros(n)
        # Heat into the far boundary's fixed nodes (their equations are replaced by T = T0):
        # conduction across the arc plus the Joule heat at the dispersive electrode.
        outflow += 2.0 * math.pi * dt * float(np.sum((load + base - A @ T_next)[fixed]))
        T = T_next
        energy += delivered * dt
        rate = arrhenius.rate(T)
        damage += 0.5 * (rate + rate_prev) * dt
        rate_prev = rate
        peak = np.maximum(peak, T)
        hist["power"].append(delivered)
        hist["voltage"].append(voltage)
        hist["impedance"].append(impedance)
        hist["max_tissue"].append(float(T[tissue_nodes].max()))
        hist["max_electrode"].append(float(T[electrode_nodes].max()))
        hist["limited"].append(limited)
        hist["mean_electrode"].append(float(el_w @ T[el_t].mean(axis=0)))
        if vaporised_at is None and hist["max_tissue"][-1] >= laws.VAPORISATION_ONSET_C:
            vaporised_at = float(t)
        if round(float(t), 9) in outputs:
            snapshots[float(t)] = T.copy()
            growth.append(_growth_row(am, float(t), damage, peak))
        if progress is not None:
            progress(i + 1, len(all_times))
        t_prev = t
    stored = 2.0 * math.pi * float(np.sum(model.mass @ (T - T0)))
    return LesionSimulation(
        mesh=am, times=all_times, power=np.array(hist["power"]), voltage=np.array(hist["voltage"]),
        impedance=np.array(hist["impedance"]), limited=np.array(hist["limited"]), max_tissue_C=np.array(hist["max_tissue"]),
        max_electrode_C=np.array(hist["max_electrode"]), mean_electrode_C=np.array(hist["mean_electrode"]), snapshots=snapshots, damage=damage,
        peak_temperature=peak, final_temperature=T, growth=growth, energy_delivered_J=energy,
        energy_stored_J=stored, energy_boundary_J=outflow, vaporisation_time_s=vaporised_at,
        info={"nodes": n, "elements": am.mesh.t.shape[1], "steps": len(all_times), "tissue": tissue_name,
              "initial_temperature_C": initial_temperature_C, "h_mm": am.h * 1e3})


def _electrode_volume_weights(am: AblationMesh):
    """The electrode's triangles (3, m) and their volume weights (r x area, summing to one): the
    weights of its bulk (mean) temperature."""
    el_t = am.mesh.t[:, am.domain == ELECTRODE]
    el_p = am.mesh.p[:, el_t]
    el_w = el_p[0].mean(axis=0) * 0.5 * np.abs((el_p[0, 1] - el_p[0, 0]) * (el_p[1, 2] - el_p[1, 0])
                                               - (el_p[0, 2] - el_p[0, 0]) * (el_p[1, 1] - el_p[1, 0]))
    return el_t, el_w / el_w.sum()


def implicit_step(ops: P1Operators, block: OrderedBlock, stiffness, capacity, T, held, dt: float, load=None):
    """One implicit (backward Euler) step of ``C dT/dt + K T = load`` from T, the nodes outside
    ``block`` held at ``held`` (conduction alone in the bench; the clinical model adds its Newton
    conditions to K and their load).

    Args:
        ops: the mesh's operators.
        block: the free nodes' block.
        stiffness: K as data of ``ops``'s pattern (not modified).
        capacity: the lumped heat capacity (n,).
        T: the temperature at the step's start (n,).
        held: (n,) the held nodes' values (its free entries are not read).
        dt: the step [s].
        load: a constant load (n,) or None.
    Returns:
        ``(A, lu, base, T_next)``: the step's matrix ``C / dt + K`` (CSR), the factors of its free
        block (``lesion_assembly.BlockFactor``), the right-hand side ``C T / dt (+ load)`` and the
        temperature without Joule heat.
    """
    data = stiffness.copy()
    data[ops.diagonal] += capacity / dt
    A = ops.matrix(data)
    lu = block.factor(data)
    base = capacity * T / dt if load is None else capacity * T / dt + load
    fixed_part = held.copy()
    fixed_part[block.rows] = 0.0
    T_next = held.copy()
    # The free rows of base - A T_held: base[free] - A[free][:, fixed] held[fixed].
    T_next[block.rows] = lu.solve(base - A @ fixed_part)
    return A, lu, base, T_next


def _joule_heating(model: ElectroThermalModel, T, T_next, lu: BlockFactor, water_nodes, power_W: float,
                   max_voltage_V: float | None, limit_C: float | None):
    """The step's Joule heat at constant power (voltage limit and cut-off at vaporisation), added
    to the conduction step's T_next (the temperature rise is linear in V^2, through ``lu``).

    Returns:
        ``(T_next, voltage [V rms], delivered [W], impedance [Ohm], limited, load (n_nodes,))``.
    """
    _, conductance, unit_density = model.unit_potential(T)
    impedance = 1.0 / conductance
    unit_load = model.joule_load(unit_density)
    rise = np.zeros(len(T))
    rise[lu.rows] = lu.solve(unit_load)
    v2_set = laws.constant_power_voltage(power_W, conductance, max_voltage_V) ** 2
    v2 = laws.temperature_limited_voltage_squared(v2_set, T_next[water_nodes], rise[water_nodes],
                                                  limit_C)
    limited = v2 < v2_set * (1 - 1e-12)
    voltage = math.sqrt(v2)
    T_next = T_next + v2 * rise
    # The load's integral (the shape functions sum to one): the Joule power delivered.
    delivered = 2.0 * math.pi * v2 * float(unit_load.sum())
    return T_next, voltage, delivered, impedance, limited, v2 * unit_load


def _growth_row(am: AblationMesh, t: float, damage, peak) -> dict:
    """The lesion's extent at time t: Omega >= 1 (``omega_*``) and the 50 C isotherm (``iso50_*``)."""
    row = {"t_s": t}
    for key, ext in (("omega", lesion_extent(am, damage, 1.0)),
                     ("iso50", lesion_extent(am, peak, laws.LESION_ISOTHERM_C))):
        row.update({f"{key}_{k}": v for k, v in ext.items()})
    return row


def joule_share(am: AblationMesh, temperature_C=None, tissue_material: laws.Material = laws.MYOCARDIUM) -> dict:
    """Fractions of the Joule power dissipated in the tissue and in the saline (at uniform 22 C by default)."""
    model = ElectroThermalModel(am, tissue_material)
    temperature = np.full(am.n_nodes, 22.0) if temperature_C is None else temperature_C
    _, _, density = model.unit_potential(temperature)
    weights = np.asarray(model.basis.dx) * np.asarray(model.basis.interpolate(am.mesh.p[0]))
    per_element = (density * weights).sum(axis=1)
    total = per_element.sum()
    return {DOMAIN_NAMES[d]: float(per_element[am.domain == d].sum() / total) for d in (TISSUE, SALINE)}


def electrode_resistance(am: AblationMesh, sigma: float, saline_sigma: float | None = None) -> float:
    """The electrode's resistance to the ground arc with uniform conductivities [Ohm].

    The check against the analytic spreading resistance: ``saline_sigma = 0`` insulates the
    tissue surface (a half space); None gives the saline ``sigma`` too.
    """
    def uniform(s):
        return laws.Material(name="uniform", electrical_conductivity=s, sigma_temperature_coefficient=0.0,
                             thermal_conductivity=1.0, k_temperature_slope=0.0, density=1.0, specific_heat=1.0)

    model = ElectroThermalModel(am, uniform(sigma), uniform(sigma if saline_sigma is None else saline_sigma))
    _, conductance, _ = model.unit_potential(np.full(am.n_nodes, 37.0))
    return 1.0 / conductance
