"""The paper's clinical system in simulation: two 119 mm N52 spheres beside the patient.

Each sphere's centre sits d_c + D/2 from the atrium's centre (the paper's sizing equation:
the magnet outside the patient; ``--reference centre`` puts it at d_c), on the patient's left
and right. For the 8 Fr chain (24 balls of 2.17 mm in an OD 2.67 mm sleeve) and today's
chain (16 balls of 3.175 mm, today's sleeve): the best tip force on the four veins and on the
ring targets (both magnets' directions optimised, the wall's tangential push inside the
friction cone), and the model's own sizing: the sphere diameter that gives 10 gf on every
vein and on 90 % / 100 % of the ring targets, with its mass and the force between the two
magnets. Writes a CSV, the JSON and two figures (force per target; force against diameter).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ballchain.commands._common import add_json_flag, finite_float, non_negative_int, path_arg, print_json
from ballchain.infrastructure.safe_files import check_output_dir
from ballchain.experiments import clinical


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--chains", nargs="+", default=["8Fr", "today"],
                        help=f"which chains, some of {sorted(clinical.CHAINS)}")
    parser.add_argument("--ring-step", type=non_negative_int, default=3,
                        help="every N-th target of each ring (1: all 38; 0: veins only)")
    parser.add_argument("--ring-offset", type=non_negative_int, default=0,
                        help="first ring target taken (0-based; with --ring-step 2, 0 and 1 split the rings)")
    parser.add_argument("--no-sizing", action="store_true", help="forces at --diameter-mm only, no sizing")
    parser.add_argument("--diameter-mm", type=finite_float, default=clinical.PAPER["diameter_mm"],
                        help="the spheres' diameter for the force table [mm]")
    parser.add_argument("--heart-to-surface-cm", type=finite_float, default=clinical.PAPER["heart_to_surface_cm"],
                        help="d_c, the heart to the outside of the arm [cm]")
    parser.add_argument("--reference", choices=["surface", "centre"], default="surface",
                        help="magnet centre at d_c + D/2 (surface, the paper's sizing) or d_c (centre) from the atrium")
    parser.add_argument("--friction", type=finite_float, default=None,
                        help="tip-wall friction coefficient (default: the simulation's contact model, 0.1)")
    parser.add_argument("--max-diameter-mm", type=finite_float, default=1000.0, help="the sizing's search limit [mm]")
    parser.add_argument("--out", type=path_arg, default=Path("results/clinical"), help="folder for the CSV, JSON, PNGs")
    parser.add_argument("--no-files", action="store_true", help="write no files")
    add_json_flag(parser)


def run(*, chains=("8Fr", "today"), ring_step: int = 3, ring_offset: int = 0, sizing: bool = True,
        diameter_mm: float = clinical.PAPER["diameter_mm"],
        heart_to_surface_cm: float = clinical.PAPER["heart_to_surface_cm"], reference: str = "surface",
        friction: float | None = None, max_diameter_mm: float = 1000.0, out: Path | None = None,
        progress: bool = True, veins=clinical.VEINS) -> clinical.ClinicalResult:
    """Check the inputs (and ``out``) before any solve, run the study, write its files into ``out``."""
    extra = {} if friction is None else {"friction": friction}
    clinical.check_inputs(chains=chains, ring_step=ring_step, diameter_mm=diameter_mm,
                          heart_to_surface_cm=heart_to_surface_cm, friction=0.0 if friction is None else friction,
                          reference=reference, max_diameter_mm=max_diameter_mm)
    if out is not None:
        check_output_dir(out, "--out")
    result = clinical.run(chains=tuple(chains), ring_step=ring_step, ring_offset=ring_offset, sizing=sizing,
                          diameter_mm=diameter_mm,
                          heart_to_surface_cm=heart_to_surface_cm, reference=reference,
                          max_diameter_mm=max_diameter_mm, veins=tuple(veins), progress=progress, **extra)
    if out is not None:
        result.files = clinical.write_files(result, Path(out))
    return result


def main(args: argparse.Namespace) -> int:
    result = run(chains=args.chains, ring_step=args.ring_step, ring_offset=args.ring_offset, sizing=not args.no_sizing,
               diameter_mm=args.diameter_mm,
               heart_to_surface_cm=args.heart_to_surface_cm, reference=args.reference, friction=args.friction,
               max_diameter_mm=args.max_diameter_mm, out=None if args.no_files else args.out)
    if args.json:
        print_json(result)
        return 0
    fmt = lambda v, spec: "-" if v is None else format(v, spec)  # noqa: E731
    s = result.setup
    print(f"two {s.diameter_mm:.0f} mm spheres ({s.mass_kg:.2f} kg) at {s.magnet_distance_cm:.2f} cm "
          f"from the atrium's centre; friction {s.friction}")
    for key, v in result.summary.items():
        veins = ", ".join(f"{k} {f:.2f}" for k, f in v.vein_force_gf.items())
        print(f"{key}: veins [gf] {veins}; ring {v.ring_targets_at_least_10_gf}/{v.ring_targets} >= 10 gf "
              f"({fmt(v.ring_force_gf_min, '.2f')}-{fmt(v.ring_force_gf_max, '.2f')} gf)")
    for r in result.sizing:
        print(f"{r.chain:6s} {r.criterion:36s} D {fmt(r.diameter_mm, '.1f')} mm, {fmt(r.mass_kg, '.1f')} kg, "
              f"between the magnets {fmt(r.force_between_magnets_gf, '.0f')} gf")
    return 0
