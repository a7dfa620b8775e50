"""Clinical actuation magnet sizing (paper Section V-A): sphere diameter, mass, force between magnets.

Solves alpha f_m d_m^4 V_d = f_d (d_c + d_d/2)^4 V_m with V_d the sphere's volume (the paper
prints (d_d/2)^4, a typo: its root is reported too), then the force between two such magnets
one each side of the patient (centre-to-centre 2 d) from the dipole laws, per orientation.
"""

from __future__ import annotations

import argparse
import math

from ballchain.commands._common import add_json_flag, print_json
from ballchain.drake_models.dipole import K_DIPOLE
from ballchain.drake_models.errors import UserInputError
from ballchain.drake_models.params import CylinderMagnet, gram_force, newtons_from_gram_force
from ballchain.optimization.sizing import (
    PAPER,
    SizingInputs,
    aligned_force_prefactors,
    force_between_magnets,
    size_clinical_magnet,
    solve_typo_equation,
)

MAX_VALUE = 1e6
# flag (without --) -> (default in the flag's unit, help)
_FLAGS: dict[str, tuple[float, str]] = {
    "alpha": (0.32, "chain dipole scale, prototype to clinical chain (8 Fr: 0.32) [-]"),
    "measured-force-gf": (132.6, "worst-case measured tip force f_m [gram-force]"),
    "desired-force-gf": (10.0, "desired clinical tip force f_d [gram-force]"),
    "measured-distance-cm": (16.51, "magnet-to-target distance of the measurement d_m [cm]"),
    "heart-to-surface-distance-cm": (29.65, "heart to outside of the arm d_c; d = d_c + d_d/2 [cm]"),
    "prototype-diameter-mm": (CylinderMagnet().diameter * 1e3, "prototype cylinder diameter (V_m) [mm]"),
    "prototype-length-mm": (CylinderMagnet().length * 1e3, "prototype cylinder length (V_m) [mm]"),
    "remanence-T": (1.44, "clinical magnet remanence Br (cancels in the sizing) [T]"),
    "density-kg-m3": (7500.0, "clinical magnet density, for its mass [kg/m^3]"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    for flag, (default, help_text) in _FLAGS.items():
        # Parsed as plain floats so that every bad value (NaN, 0, negative) gets the same
        # one-line message and exit status 2 from main(), naming the flag.
        parser.add_argument(f"--{flag}", type=float, default=default, help=f"{help_text} (default {default:g})")
    add_json_flag(parser)


def _checked(args: argparse.Namespace) -> dict[str, float]:
    values = {}
    for flag in _FLAGS:
        value = getattr(args, flag.replace("-", "_"))
        if not math.isfinite(value) or value <= 0:
            raise UserInputError(f"--{flag} must be a positive finite number, got {value}")
        if value > MAX_VALUE:  # in the flag's unit; beyond it the sizing's powers overflow
            raise UserInputError(f"--{flag} must be at most {MAX_VALUE:g} (in its unit), got {value}")
        values[flag] = value
    return values


def run(*, inputs: SizingInputs) -> dict:
    """Sizing, typo-equation root, magnet-magnet forces and the force-law check, edge units."""
    result = size_clinical_magnet(inputs)
    separation = 2.0 * result.distance
    forces = force_between_magnets(result.dipole_moment, separation)
    coaxial_N = forces["coaxial_head_to_tail"]["force_N"]
    units = (("m", 1.0), ("cm", 1e-2), ("mm", 1e-3))
    typo = {unit: solve_typo_equation(inputs, scale) for unit, scale in units}
    prefactors = aligned_force_prefactors((0.0, 45.0, 90.0))
    # Separation at which the coaxial (maximum) force would be the paper's 500 gf.
    f_500 = newtons_from_gram_force(PAPER["force_between_magnets_gf"])
    s_500 = (6.0 * K_DIPOLE * result.dipole_moment**2 / f_500) ** 0.25
    s_2dc = 2.0 * inputs.heart_to_surface
    coaxial_at_2dc = force_between_magnets(result.dipole_moment, s_2dc)["coaxial_head_to_tail"]["force_N"]
    return {
        "diameter_mm": result.diameter * 1e3,
        "mass_kg": result.mass,
        "force_between_magnets_gf": gram_force(coaxial_N),
        "typo_equation_diameter_mm": None if typo["m"] is None else typo["m"] * 1e3,
        "typo_equation_diameter_mm_by_length_unit": {
            unit: None if value is None else value * 1e3 for unit, value in typo.items()
        },
        "heart_to_magnet_distance_cm": result.distance * 1e2,
        "magnet_separation_cm": separation * 1e2,
        "dipole_moment_Am2": result.dipole_moment,
        "force_between_magnets_by_orientation": {
            name: {
                "force_gf": gram_force(f["force_N"]),
                "attractive": bool(f["attractive"]),
                "prefactor_mu0_m2_over_4pi_s4": f["prefactor"],
            }
            for name, f in forces.items()
        },
        "paper_500gf_check": {
            "separation_for_500gf_coaxial_cm": s_500 * 1e2,
            "coaxial_force_at_separation_2_d_c_gf": gram_force(coaxial_at_2dc),
            "separation_2_d_c_cm": s_2dc * 1e2,
        },
        "force_law_check": {
            "aligned_dipole_prefactor_by_polar_angle_deg": {f"{k:g}": v for k, v in prefactors.items()},
            "paper_prefactor": PAPER["force_law_prefactor"],
            "paper_prefactor_is": "the equator (90 deg) value, half the on-axis maximum 6; it cancels "
            "in the sizing ratio if the chain is in the same direction from the magnet in both cases",
        },
        "second_root_diameter_m": result.second_root_diameter,
        "max_diameter_for_existence_mm": result.max_diameter_for_existence * 1e3,
        "alpha_from_ball_diameters_2_17_over_3_175_cubed": (2.17 / 3.175) ** 3,
        "inputs": {
            "alpha": inputs.alpha,
            "measured_force_gf": gram_force(inputs.measured_force),
            "desired_force_gf": gram_force(inputs.desired_force),
            "measured_distance_cm": inputs.measured_distance * 1e2,
            "heart_to_surface_distance_cm": inputs.heart_to_surface * 1e2,
            "prototype_volume_cm3": inputs.prototype_volume * 1e6,
            "remanence_T": inputs.remanence,
            "density_kg_m3": inputs.density,
        },
        "paper": dict(PAPER),
        "assumptions": [
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
    }


def _print_table(out: dict) -> None:
    paper = out["paper"]
    print(f"clinical sphere diameter   {out['diameter_mm']:8.2f} mm   (paper {paper['diameter_mm']:g} mm)")
    print(f"clinical sphere mass       {out['mass_kg']:8.3f} kg   (paper about {paper['mass_kg']:g} kg)")
    typo = out["typo_equation_diameter_mm_by_length_unit"]
    shown = ", ".join(f"{v:.1f} mm in {u}" if v is not None else f"no root in {u}" for u, v in typo.items())
    print(f"typo (d_d/2)^4 equation    {shown}")
    print(
        f"heart-to-magnet distance   {out['heart_to_magnet_distance_cm']:8.2f} cm,  "
        f"separation {out['magnet_separation_cm']:.2f} cm, |m| = {out['dipole_moment_Am2']:.1f} A m^2"
    )
    print("force between the two clinical magnets (paper: about 500 gf):")
    for name, f in out["force_between_magnets_by_orientation"].items():
        kind = "attract" if f["attractive"] else "repel"
        print(f"  {name:28s} {f['force_gf']:8.1f} gf  {kind}")
    check = out["paper_500gf_check"]
    print(
        f"  500 gf (coaxial) needs a separation of {check['separation_for_500gf_coaxial_cm']:.1f} cm; "
        f"at 2 d_c = {check['separation_2_d_c_cm']:.1f} cm it is "
        f"{check['coaxial_force_at_separation_2_d_c_gf']:.1f} gf"
    )
    pre = out["force_law_check"]["aligned_dipole_prefactor_by_polar_angle_deg"]
    print(
        "aligned-dipole force prefactor (x mu0|m_i||m_a|/(4 pi d^4)): "
        + ", ".join(f"{v:.3f} at {k} deg" for k, v in pre.items())
        + "; paper uses 3 (equator)"
    )


def main(args: argparse.Namespace) -> int:
    v = _checked(args)
    inputs = SizingInputs(
        alpha=v["alpha"],
        measured_force=newtons_from_gram_force(v["measured-force-gf"]),
        desired_force=newtons_from_gram_force(v["desired-force-gf"]),
        measured_distance=v["measured-distance-cm"] * 1e-2,
        heart_to_surface=v["heart-to-surface-distance-cm"] * 1e-2,
        prototype_volume=CylinderMagnet(
            diameter=v["prototype-diameter-mm"] * 1e-3, length=v["prototype-length-mm"] * 1e-3
        ).volume,
        remanence=v["remanence-T"],
        density=v["density-kg-m3"],
    )
    out = run(inputs=inputs)
    if args.json:
        print_json(out)
    else:
        _print_table(out)
    return 0
