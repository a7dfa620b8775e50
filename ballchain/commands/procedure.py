"""A simulated ablation procedure (beyond the paper): an autonomous navigator (or the simulated
operator) brings the tip to every target of a ring, presses it with a force estimated without a
force sensor, and holds it for the dwell (``experiments/procedure.py``).

Prints per target whether it was reached, the time, the true force over the dwell and the
estimate's error; ``--json`` the whole result; ``--out DIR`` writes ``procedure.json`` there
and the ring's map ``ring.png`` (atomically); ``--html FILE`` a Meshcat replay with the lesion
patches on the wall. Each dwell leaves a lesion (``drake_models.lesion_ring``), and the ring is
checked for gaps. ``--wall-motion`` moves the atrium (respiration, the heart beat or both, at the
defaults of ``drake_models.wall_motion``), ``--track-sheath`` gives the navigator the sheath's
tracked position (respiratory compensation); ``--set`` overrides the station's scenario fields.
"""

from __future__ import annotations

import argparse

from ballchain.commands._common import (YamlOnce, add_json_flag, float_in, int_in, path_arg, positive_int, print_json,
                                        run_status)
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.localisation import LATENCY_RANGE_S, NOISE_RANGE_M, RATE_RANGE_HZ, LocalisationParams
from ballchain.experiments import procedure
from ballchain.experiments.procedure_world import WORLDS
from ballchain.systems.chain_scenario import parse_overrides


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task", default=None,
                        help="the ring: left (20 targets) or right (18; the default); with --anatomy, the targets "
                             "named TASK_... (default: all, in file order)")
    parser.add_argument("--anatomy", type=path_arg, default=None, metavar="FILE",
                        help="an anatomy file (YAML: mesh, targets, sheath, magnets) instead of the procedural atrium")
    parser.add_argument("--navigator", choices=procedure.NAVIGATORS, default="auto",
                        help="auto (the model-based navigator) or operator (the simulated operator, no force estimate)")
    parser.add_argument("--seed", type=int_in(0, 2**32 - 1), default=0,
                        help="the localisation noise's seed (auto) or the operator's tremor's (operator)")
    parser.add_argument("--targets", type=positive_int, default=None, help="only the first N targets (default: all)")
    parser.add_argument("--force", type=float_in(0.0, 200.0, lo_open=True), default=procedure.FORCE_GF,
                        help="the contact force to hold [gf]")
    parser.add_argument("--dwell", type=float_in(0.0, procedure.MAX_DWELL_S), default=procedure.DWELL_S,
                        help="the RF time at each target [s]")
    defaults = LocalisationParams()
    scenario_note = "; not given: the scenario's localisation (--set), else "
    parser.add_argument("--noise", type=float_in(NOISE_RANGE_M[0] * 1e3, NOISE_RANGE_M[1] * 1e3),
                        default=None, help="localisation noise, per-axis std [mm]" + scenario_note +
                        f"{defaults.noise_std * 1e3:.3g}: the NDI Aurora's 0.70 mm RMS over three axes")
    parser.add_argument("--rate", type=float_in(*RATE_RANGE_HZ), default=None,
                        help=f"localisation update rate [Hz]{scenario_note}{defaults.rate:g}")
    parser.add_argument("--latency", type=float_in(*LATENCY_RANGE_S), default=None,
                        help=f"localisation latency [s] (a whole number of samples){scenario_note}{defaults.latency:g}")
    parser.add_argument("--wall-motion", choices=procedure.WALL_MOTIONS, default="off",
                        help="move the atrium: on (respiration, 5 mm at 0.25 Hz, and the heart beat, 1 mm at 1.2 Hz), "
                             "respiration or beat alone, or off (the still wall); the quasi-static engine follows it")
    parser.add_argument("--track-sheath", action="store_true",
                        help="respiratory compensation: the navigator tracks the sheath (a localisation sensor on it, "
                             "the tip's noise, rate and latency) and moves its force model's sheath and its targets "
                             "with it (default: both held at rest, motion-blind)")
    parser.add_argument("--world", choices=WORLDS, default="none",
                        help="the world the engine plays, unknown to the planner and the navigator: none (the model's "
                             "own numbers) or literature (magnets, balls, sheath, anatomy registration and tracker "
                             "bias perturbed at published magnitudes, drawn from --seed; docs/guide/world.md)")
    parser.add_argument("--set", dest="overrides", default=None, metavar="YAML", action=YamlOnce,
                        help="inline YAML overriding the station scenario's fields, e.g. "
                             "'{wall_motion: {enabled: true, cardiac: {amplitude: 0.002}}}' (not with --wall-motion)")
    parser.add_argument("--out", type=path_arg, default=None, metavar="DIR", help="write procedure.json here")
    parser.add_argument("--html", type=path_arg, default=None, metavar="FILE", help="write a Meshcat replay here")
    lesion = parser.add_argument_group("lesions as in a beating heart (issue 44; default: the paper's still bench)")
    lesion.add_argument("--blood-flow", choices=("none", "low", "high"), default="none",
                        help="blood flow cooling the tip ball and the wall (low, high); none: the still bench")
    lesion.add_argument("--control", choices=("power", "temperature"), default="power",
                        help="generator mode for the lesions (the magnet's limit is in its loop either way)")
    lesion.add_argument("--target-temperature-C", type=float_in(40.0, 95.0), default=60.0,
                        help="the tip's set point under --control temperature [C]")
    lesion.add_argument("--lesion-power-W", type=float_in(0.5, 100.0), default=30.0,
                        help="set power (or the cap under temperature control) of the clinical lesions [W]")
    lesion.add_argument("--magnet-grade", default="N52", help="the tip magnet's grade (N52, N42SH)")
    lesion.add_argument("--dwell-criterion", choices=("fixed", "transmural", "contiguous", "fti"), default="fixed",
                        help="each lesion's RF time: the --dwell (fixed), until transmural, until transmural and as "
                             "wide as the distance to its ring neighbours (contiguous), or until the force-time "
                             "integral reaches 400 gf s (EFFICAS II)")
    lesion.add_argument("--rf-time-limit-s", type=float_in(1.0, 120.0), default=60.0,
                        help="the longest RF time per lesion under a dwell criterion [s]")
    add_json_flag(parser)


def _lesion_conditions(args: argparse.Namespace):
    """The clinical lesion conditions (``lesion_dwell.LesionConditions``), or True (the bench)."""
    from ballchain.drake_models.lesion_dwell import LesionConditions  # only when asked: builds no table here

    bench = (args.blood_flow == "none" and args.control == "power" and args.dwell_criterion == "fixed"
             and args.magnet_grade == "N52")
    if bench:
        return True
    try:
        return LesionConditions(blood_flow=args.blood_flow, control=args.control, power_W=args.lesion_power_W,
                                target_C=args.target_temperature_C, grade=args.magnet_grade,
                                criterion=args.dwell_criterion, time_limit_s=args.rf_time_limit_s)
    except UserInputError as err:
        raise UserInputError(str(err).replace("magnet grade", "--magnet-grade", 1)) from None


def main(args: argparse.Namespace) -> int:
    from ballchain.infrastructure.safe_files import check_output_dir, check_output_file

    if args.anatomy is None and args.task is None:
        args.task = "right"
    if args.anatomy is None and args.task not in procedure.TASKS:
        raise UserInputError(f"--task must be left or right, got {args.task!r}")
    localisation = _localisation(args)
    lesions = _lesion_conditions(args)
    if args.anatomy is not None and (args.out is not None or args.html is not None):
        from ballchain.drake_models.anatomy import load_anatomy

        # Loaded once, here: its files are then this run's inputs, which the output checks refuse.
        args.anatomy = load_anatomy(args.anatomy)
    if args.html is not None:
        check_output_file(args.html, "--html")
    if args.out is not None:
        check_output_dir(args.out, "--out", names=("procedure.json", "ring.png"))
    data = procedure.run(args.task, args.navigator, args.anatomy, args.seed, targets=args.targets,
                         force_gf=args.force, dwell_s=args.dwell, localisation=localisation, html=args.html,
                         overrides=args.overrides, wall_motion=args.wall_motion, track_sheath=args.track_sheath,
                         world=args.world, lesions=lesions)
    if args.out is not None:
        procedure.write_outputs(data, args.out)
    if args.json:
        print_json(data)
        return run_status(data.summary["failure"], "procedure")
    for r in data.rows:
        if not r["reached"]:
            print(f"{r['target']:9s} missed ({r.get('reason') or 'gave up'})")
            continue
        estimate = ("" if r["estimate_mean_error_gf"] is None else f", estimate error "
                    f"{r['estimate_mean_error_gf']} gf mean, {r['estimate_worst_error_gf']} gf worst")
        print(f"{r['target']:9s} reached in {r['time_s']} s; dwell {r['dwell_s']} s, true force "
              f"{r['force_true_mean_gf']} gf ({r['force_true_min_gf']}..{r['force_true_max_gf']}), in window "
              f"{100 * (r['in_window_fraction'] or 0):.0f}%{estimate}")
    s = data.summary
    if data.settings.get("world"):  # the drawn world (docs/guide/world.md), unknown to the navigator
        w = data.settings["world"]
        print(f"world {args.world} (seed {w['seed']}), unknown to the navigator: magnets off by "
              f"{', '.join(f'{sum(v * v for v in o) ** 0.5:.2f}' for o in w['magnet_offsets_mm'])} mm, anatomy by "
              f"{sum(v * v for v in w['anatomy_offset_mm']) ** 0.5:.2f} mm, tracker bias "
              f"{sum(v * v for v in w['localisation_bias_mm']) ** 0.5:.2f} mm (--json: all of it)")
    if data.settings.get("wall_motion"):
        print("wall moving: " + ", ".join(f"{name} {m['amplitude_mm']:g} mm at {m['frequency_hz']:g} Hz" for name, m in
                                          data.settings["wall_motion"].items() if m["amplitude_mm"] > 0))
    print(f"{s['reached']}/{s['targets']} reached in {s['total_time_s']} s; force in window "
          f"{s.get('in_window_fraction')}; estimate error {s.get('estimate_mean_abs_error_gf')} gf mean |.|, "
          f"{s.get('estimate_worst_error_gf')} gf worst")
    if data.ring is not None:
        ring = data.ring
        print(f"ring: {'isolated' if ring['isolated'] else 'NOT isolated'}, {ring['n_lesions']}/{ring['n_targets']} "
              f"lesions, {len(ring['gaps'])} gap(s), transmural {100 * ring['transmural_fraction']:.0f}%, "
              f"largest spacing {ring['max_distance_mm']} mm")
    return run_status(s["failure"], "procedure")


def _localisation(args: argparse.Namespace) -> LocalisationParams | None:
    """The tip tracker's figures from ``--noise --rate --latency`` (the others at their defaults),
    or None when none is given: the run then takes the scenario's ``localisation``."""
    given = {"noise_std": None if args.noise is None else args.noise * 1e-3, "rate": args.rate, "latency": args.latency}
    given = {k: v for k, v in given.items() if v is not None}
    if not given:
        return None
    if args.overrides is not None and "localisation" in parse_overrides(args.overrides):
        flags = ", ".join(f"--{'noise' if k == 'noise_std' else k}" for k in given)
        raise UserInputError(f"{flags} and --set localisation both set the tip tracker; give only one of them")
    return LocalisationParams(**given)
