"""Clinical actuation magnet sizing (paper Section V-A): sphere diameter, mass, force between magnets.

Solves alpha f_m d_m^4 V_d = f_d (d_c + d_d/2)^4 V_m with V_d the sphere's volume (the paper
prints (d_d/2)^4, a typo: its root is reported too), then the force between two such magnets
one each side of the patient (centre-to-centre 2 d) from the dipole laws, per orientation.
"""

from __future__ import annotations

from dataclasses import dataclass

from ballchain.infrastructure.arg_checks import require_type
from ballchain.drake_models.params import gram_force, newtons_from_gram_force
from ballchain.optimization.sizing import (
    PAPER,
    SizingInputs,
    aligned_force_prefactors,
    force_between_magnets,
    size_clinical_magnet,
    solve_typo_equation,
)
from ballchain.experiments._result import Result


@dataclass
class SizingCheckResult(Result):
    """What ``run`` returns (edge units: mm, cm, kg, gf).

    Attributes:
        diameter_mm, mass_kg: the clinical sphere.
        force_between_magnets_gf: the largest (coaxial) force between the two clinical magnets.
        typo_equation_diameter_mm: the root of the printed (d_d/2)^4 equation in SI units (None:
            no root); typo_equation_diameter_mm_by_length_unit: {"m", "cm", "mm": root [mm] or None}.
        heart_to_magnet_distance_cm, magnet_separation_cm: d = d_c + d_d/2 and 2 d.
        dipole_moment_Am2: the clinical sphere's dipole moment [A m^2].
        force_between_magnets_by_orientation: {orientation: {force_gf, attractive,
            prefactor_mu0_m2_over_4pi_s4}}.
        paper_500gf_check: {separation_for_500gf_coaxial_cm, coaxial_force_at_separation_2_d_c_gf,
            separation_2_d_c_cm}.
        force_law_check: the aligned-dipole force prefactors by polar angle against the paper's.
        second_root_diameter_m: the equation's larger root [m]; max_diameter_for_existence_mm.
        alpha_from_ball_diameters_2_17_over_3_175_cubed: the 8 Fr chain's alpha from its balls.
        inputs: the inputs in edge units; paper: the paper's numbers; assumptions: text.
    """

    diameter_mm: float
    mass_kg: float
    force_between_magnets_gf: float
    typo_equation_diameter_mm: float | None
    typo_equation_diameter_mm_by_length_unit: dict
    heart_to_magnet_distance_cm: float
    magnet_separation_cm: float
    dipole_moment_Am2: float
    force_between_magnets_by_orientation: dict
    paper_500gf_check: dict
    force_law_check: dict
    second_root_diameter_m: float | None
    max_diameter_for_existence_mm: float
    alpha_from_ball_diameters_2_17_over_3_175_cubed: float
    inputs: dict
    paper: dict
    assumptions: list


def run(*, inputs: SizingInputs) -> SizingCheckResult:
    """Sizing, typo-equation root, magnet-magnet forces and the force-law check, edge units.

    Args:
        inputs: the sizing's inputs (SI; ``SizingInputs()`` is the paper's case).

    Returns:
        A ``SizingCheckResult``.
    """
    require_type(inputs, SizingInputs, "inputs", "a SizingInputs")
    result = size_clinical_magnet(inputs)
    separation = 2.0 * result.distance
    forces = force_between_magnets(result.dipole_moment, separation)
    coaxial_N = forces["coaxial_head_to_tail"]["force_N"]
    units = (("m", 1.0), ("cm", 1e-2), ("mm", 1e-3))
    typo = {unit: solve_typo_equation(inputs, scale) for unit, scale in units}
    prefactors = aligned_force_prefactors((0.0, 45.0, 90.0))
    # Separation at which the coaxial (maximum) force would be the paper's 500 gf: the dipole
    # law's force falls as 1 / s^4.
    f_500 = newtons_from_gram_force(PAPER["force_between_magnets_gf"])
    s_500 = separation * (coaxial_N / f_500) ** 0.25
    s_2dc = 2.0 * inputs.heart_to_surface
    coaxial_at_2dc = force_between_magnets(result.dipole_moment, s_2dc)["coaxial_head_to_tail"]["force_N"]
    return SizingCheckResult(
        diameter_mm=result.diameter * 1e3,
        mass_kg=result.mass,
        force_between_magnets_gf=gram_force(coaxial_N),
        typo_equation_diameter_mm=None if typo["m"] is None else typo["m"] * 1e3,
        typo_equation_diameter_mm_by_length_unit={
            unit: None if value is None else value * 1e3 for unit, value in typo.items()
        },
        heart_to_magnet_distance_cm=result.distance * 1e2,
        magnet_separation_cm=separation * 1e2,
        dipole_moment_Am2=result.dipole_moment,
        force_between_magnets_by_orientation={
            name: {
                "force_gf": gram_force(f["force_N"]),
                "attractive": bool(f["attractive"]),
                "prefactor_mu0_m2_over_4pi_s4": f["prefactor"],
            }
            for name, f in forces.items()
        },
        paper_500gf_check={
            "separation_for_500gf_coaxial_cm": s_500 * 1e2,
            "coaxial_force_at_separation_2_d_c_gf": gram_force(coaxial_at_2dc),
            "separation_2_d_c_cm": s_2dc * 1e2,
        },
        force_law_check={
            "aligned_dipole_prefactor_by_polar_angle_deg": {f"{k:g}": v for k, v in prefactors.items()},
            "paper_prefactor": PAPER["force_law_prefactor"],
            "paper_prefactor_is": "the equator (90 deg) value, half the on-axis maximum 6; it cancels "
            "in the sizing ratio if the chain is in the same direction from the magnet in both cases",
        },
        second_root_diameter_m=result.second_root_diameter,
        max_diameter_for_existence_mm=result.max_diameter_for_existence * 1e3,
        alpha_from_ball_diameters_2_17_over_3_175_cubed=(2.17 / 3.175) ** 3,
        inputs={
            "alpha": inputs.alpha,
            "measured_force_gf": gram_force(inputs.measured_force),
            "desired_force_gf": gram_force(inputs.desired_force),
            "measured_distance_cm": inputs.measured_distance * 1e2,
            "heart_to_surface_distance_cm": inputs.heart_to_surface * 1e2,
            "prototype_volume_cm3": inputs.prototype_volume * 1e6,
            "remanence_T": inputs.remanence,
            "density_kg_m3": inputs.density,
        },
        paper=dict(PAPER),
        assumptions=[
            "force on the chain ~ |m_chain||m_a|/d^4 with the same geometric prefactor in the "
            "prototype and the clinic (it and Br cancel in the ratio)",
            "V_d is the sphere's volume (4/3) pi (d_d/2)^3; the paper's printed (d_d/2)^4 is a typo "
            "(dimensionally inconsistent: its root depends on the length unit)",
            "f_m (132.6 gf) is the worst-case total of the two one-magnet configurations with the "
            "sleeve (Table I), and f_d (10 gf) the total from two clinical magnets, so the two-magnet "
            "doubling cancels too",
            "the clinical magnet is the smaller root of the equation (r^3/(d_c + r)^4 peaks at r = 3 d_c)",
            "force between magnets: point dipoles (exact for uniformly magnetised spheres), one each "
            "side of the patient at d = d_c + d_d/2 from the heart (centre-to-centre 2 d)",
        ],
    )
