"""RF ablation lesions: the ball chain (15 W, 90 s) and a standard 8 Fr catheter (30 W, 90 s).

An axisymmetric electro-thermal finite-element model (scikit-fem): constant-power generator with
its cut-off at 100 C, temperature-dependent conductivity, Pennes bioheat without perfusion,
Arrhenius damage. Prints both lesions (Omega = 1 and the 50 C isotherm), the peak tissue and
electrode temperatures and the impedance beside the paper's lesions; writes the temperature
field with the lesion contours, the lesion growth over time and (``--map``) the power-duration
map of the ball chain.

Clinical conditions (issue 44): ``--blood-flow low|high`` (Newton cooling of the electrode and the
wall), ``--irrigation open`` (the catheter's tip held at the irrigant's temperature),
``--control temperature --target-temperature-C 60`` (the set power is then the cap),
``--contact-force-gf`` (the indentation by Hertz's law), ``--magnet-grade``: the ball chain's
magnet is held below its grade's limit less a margin. Each device then reports its delivered
power beside the set one and the magnet's peak. Without these flags it is the paper's bench.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ballchain.commands._common import add_json_flag, finite_float, path_arg, print_json
from ballchain.infrastructure.errors import UserInputError
from ballchain.infrastructure.safe_files import check_output_dir
from ballchain.experiments import ablation, ablation_clinical


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ball-power-W", type=finite_float, default=15.0, help="ball chain generator power [W]")
    parser.add_argument("--catheter-power-W", type=finite_float, default=30.0, help="catheter generator power [W]")
    parser.add_argument("--duration-s", type=finite_float, default=90.0, help="RF application time [s]")
    parser.add_argument("--indentation-mm", type=finite_float, default=1.0,
                        help="electrode depth below the tissue surface [mm]")
    parser.add_argument("--tissue", default="myocardium", help="tissue type: myocardium or liver")
    parser.add_argument("--bath-temperature-C", type=finite_float, default=22.0,
                        help="initial tissue and saline temperature [C] (not in the paper)")
    parser.add_argument("--contact-force-gf", type=finite_float, default=None,
                        help="contact force [gf]: sets each electrode's indentation (Hertz); overrides --indentation-mm")
    parser.add_argument("--irrigation", default="none", help="catheter irrigation: none or open")
    parser.add_argument("--blood-flow", default="none", help="blood flow past the electrode: none (still bath), low, high")
    parser.add_argument("--control", default="power",
                        help="generator mode: power, or temperature (the set power is then the cap)")
    parser.add_argument("--target-temperature-C", type=finite_float, default=60.0,
                        help="electrode set point under --control temperature [C] (clinical 55-65)")
    parser.add_argument("--magnet-grade", default="N52", help="the ball chain's magnet grade (N52, N42SH)")
    parser.add_argument("--mesh-mm", type=finite_float, default=0.1, help="mesh spacing near the electrode [mm]")
    parser.add_argument("--map", action="store_true", help="also run the ball chain's power-duration map")
    parser.add_argument("--sensitivity", action="store_true",
                        help="also vary the choices the paper leaves open (bath temperature, saline mixing, "
                             "indentation, cut-off) at the paper's settings")
    parser.add_argument("--out", type=path_arg, default=Path("results/ablation"), help="folder for the files")
    parser.add_argument("--no-files", action="store_true", help="write no files")
    add_json_flag(parser)


FLAGS = {"ball_power_W": "--ball-power-W", "catheter_power_W": "--catheter-power-W", "duration_s": "--duration-s",
         "indentation_mm": "--indentation-mm", "tissue": "--tissue", "initial_temperature_C": "--bath-temperature-C",
         "h_mm": "--mesh-mm"}


def _check(args: argparse.Namespace) -> None:
    """Validate every flag before any computation, naming the flag."""
    values = {"ball_power_W": args.ball_power_W, "catheter_power_W": args.catheter_power_W,
              "duration_s": args.duration_s, "indentation_mm": args.indentation_mm, "tissue": args.tissue,
              "initial_temperature_C": args.bath_temperature_C, "h_mm": args.mesh_mm}
    for key, value in values.items():
        try:
            if key.endswith("power_W"):
                ablation.check_settings(power_W=value, flag_power=key)
            else:
                ablation.check_settings(**{key: value})
        except UserInputError as err:
            raise UserInputError(str(err).replace(key, FLAGS[key], 1)) from None
    clinical = _clinical_settings(args)
    if clinical is not None and (args.map or args.sensitivity):
        raise UserInputError("--map and --sensitivity run the paper's bench; drop the clinical flags "
                             "(--contact-force-gf, --irrigation, --blood-flow, --control, --magnet-grade) to use them")
    if not args.no_files:
        check_output_dir(args.out, "--out")


CLINICAL_FLAGS = {"contact_force_gf": "--contact-force-gf", "irrigation": "--irrigation",
                  "blood_flow": "--blood-flow", "control": "--control",
                  "target_temperature_C": "--target-temperature-C", "magnet grade": "--magnet-grade"}


def _clinical_settings(args: argparse.Namespace):
    """The clinical settings (checked, naming the flag), or None for the paper's bench."""
    settings = ablation_clinical.ClinicalSettings(
        blood_flow=args.blood_flow, irrigation=args.irrigation, control=args.control,
        target_temperature_C=args.target_temperature_C, contact_force_gf=args.contact_force_gf,
        magnet_grade=args.magnet_grade)
    try:
        settings.check()
    except UserInputError as err:
        text = str(err)
        for key, flag in CLINICAL_FLAGS.items():
            if text.startswith(key):
                text = flag + text[len(key):]
                break
        raise UserInputError(text) from None
    bench = ablation_clinical.ClinicalSettings(magnet_grade=args.magnet_grade,
                                               target_temperature_C=args.target_temperature_C)
    return None if settings == bench else settings


def main(args: argparse.Namespace) -> int:
    _check(args)
    clinical = _clinical_settings(args)
    if clinical is not None:
        result = ablation_clinical.run(
            clinical, ball_power_W=args.ball_power_W, catheter_power_W=args.catheter_power_W,
            duration_s=args.duration_s, indentation_mm=args.indentation_mm, tissue=args.tissue,
            initial_temperature_C=args.bath_temperature_C, h_mm=args.mesh_mm, progress=not args.json)
        return _report(args, result)
    result = ablation.run(ball_power_W=args.ball_power_W, catheter_power_W=args.catheter_power_W,
                          duration_s=args.duration_s, indentation_mm=args.indentation_mm, tissue=args.tissue,
                          initial_temperature_C=args.bath_temperature_C, h_mm=args.mesh_mm,
                          progress=not args.json)
    if args.map:
        result.power_duration_map = ablation.power_duration_map(
            indentation_mm=args.indentation_mm, tissue=args.tissue, initial_temperature_C=args.bath_temperature_C,
            progress=not args.json)
    if args.sensitivity:
        result.sensitivity = ablation.sensitivity(progress=not args.json)
    return _report(args, result)


def _report(args: argparse.Namespace, result) -> int:
    if not args.no_files:
        result.files = ablation.write_files(result, args.out)
    if args.json:
        print_json(result)
        return 0
    for row in ablation.table_rows(result):
        print(f"{row[0]:>24} | {row[1]:<48} | paper {row[2]!s:>6} | model {row[3]:.2f}"
              if isinstance(row[3], float) else f"{row[0]:>24} | {row[1]:<48} | paper {row[2]!s:>6} | model {row[3]}")
    for note in result.notes:
        print(note)
    if result.power_duration_map is not None:
        print(result.power_duration_map["headline"])
    for r in result.sensitivity or []:
        print(f"{r['case']:>44} | {r['device']:>10} | {r['width_mm']:.2f} x {r['depth_mm']:.2f} mm (Omega = 1), "
              f"electrode {r['peak_electrode_C']:.0f} C, {r['energy_J']:.0f} J")
    return 0
