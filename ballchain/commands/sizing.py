"""Clinical actuation magnet sizing (paper Section V-A): sphere diameter, mass, force between magnets.

Solves alpha f_m d_m^4 V_d = f_d (d_c + d_d/2)^4 V_m with V_d the sphere's volume (the paper
prints (d_d/2)^4, a typo: its root is reported too), then the force between two such magnets
one each side of the patient (centre-to-centre 2 d) from the dipole laws, per orientation.
The experiment is ``ballchain.experiments.sizing_check``.
"""

from __future__ import annotations

import argparse
import math

from ballchain.drake_models import paper
from ballchain.commands._common import add_json_flag, print_json
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.params import MAX_MAGNET_SIZE, CylinderMagnet, newtons_from_gram_force
from ballchain.experiments.sizing_check import run
from ballchain.optimization.sizing import SIZING_RANGES, SizingInputs

# flag (without --) -> (default in the flag's unit, help)
_FLAGS: dict[str, tuple[float, str]] = {
    "alpha": (paper.SIZING["alpha"], "chain dipole scale, prototype to clinical chain (8 Fr: 0.32) [-]"),
    "measured-force-gf": (paper.SIZING["measured_force_gf"], "worst-case measured tip force f_m [gram-force]"),
    "desired-force-gf": (paper.SIZING["desired_force_gf"], "desired clinical tip force f_d [gram-force]"),
    "measured-distance-cm": (paper.WORKING_DISTANCE * 100, "magnet-to-target distance of the measurement d_m [cm]"),
    "heart-to-surface-distance-cm": (paper.CLINICAL_DISTANCE * 100, "heart to outside of the arm d_c; d = d_c + d_d/2 [cm]"),
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


# flag -> (the SizingInputs field whose range it takes, or the magnet's size; its unit; SI per unit)
_RANGES = {
    "alpha": ("alpha", "", 1.0),
    "measured-force-gf": ("measured_force", "gf", newtons_from_gram_force(1.0)),
    "desired-force-gf": ("desired_force", "gf", newtons_from_gram_force(1.0)),
    "measured-distance-cm": ("measured_distance", "cm", 1e-2),
    "heart-to-surface-distance-cm": ("heart_to_surface", "cm", 1e-2),
    "prototype-diameter-mm": (None, "mm", 1e-3),
    "prototype-length-mm": (None, "mm", 1e-3),
    "remanence-T": ("remanence", "T", 1.0),
    "density-kg-m3": ("density", "kg/m^3", 1.0),
}


def _checked(args: argparse.Namespace) -> dict[str, float]:
    """Each flag in its unit, within what ``SizingInputs`` (``SIZING_RANGES``) and the prototype
    magnet (``MAX_MAGNET_SIZE``) take: the message names the flag in its own unit."""
    values = {}
    for flag in _FLAGS:
        value = getattr(args, flag.replace("-", "_"))
        field, unit, si = _RANGES[flag]
        lo, hi = SIZING_RANGES[field] if field is not None else (1e-4, MAX_MAGNET_SIZE)
        if not math.isfinite(value) or value <= 0:
            raise UserInputError(f"--{flag} must be a positive finite number, got {value}")
        if not lo <= value * si <= hi:
            raise UserInputError(f"--{flag} must be in [{lo / si:.4g}, {hi / si:.4g}]{f' {unit}' if unit else ''}, "
                                 f"got {value:g}")
        values[flag] = value
    return values


def _print_table(out) -> None:
    paper = out.paper
    print(f"clinical sphere diameter   {out.diameter_mm:8.2f} mm   (paper {paper['diameter_mm']:g} mm)")
    print(f"clinical sphere mass       {out.mass_kg:8.3f} kg   (paper about {paper['mass_kg']:g} kg)")
    typo = out.typo_equation_diameter_mm_by_length_unit
    shown = ", ".join(f"{v:.1f} mm in {u}" if v is not None else f"no root in {u}" for u, v in typo.items())
    print(f"typo (d_d/2)^4 equation    {shown}")
    print(
        f"heart-to-magnet distance   {out.heart_to_magnet_distance_cm:8.2f} cm,  "
        f"separation {out.magnet_separation_cm:.2f} cm, |m| = {out.dipole_moment_Am2:.1f} A m^2"
    )
    print("force between the two clinical magnets (paper: about 500 gf):")
    for name, f in out.force_between_magnets_by_orientation.items():
        kind = "attract" if f["attractive"] else "repel"
        print(f"  {name:28s} {f['force_gf']:8.1f} gf  {kind}")
    check = out.paper_500gf_check
    print(
        f"  500 gf (coaxial) needs a separation of {check['separation_for_500gf_coaxial_cm']:.1f} cm; "
        f"at 2 d_c = {check['separation_2_d_c_cm']:.1f} cm it is "
        f"{check['coaxial_force_at_separation_2_d_c_gf']:.1f} gf"
    )
    pre = out.force_law_check["aligned_dipole_prefactor_by_polar_angle_deg"]
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
