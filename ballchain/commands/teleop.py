"""Teleoperation tasks (paper Sec. VI-B): a simulated operator touches the ablation targets in order.

Task I ("left": the 20 targets around the left veins) or Task II ("right": the 18 around the right
veins), with the paper's world-frame joystick mapping or the catheter-frame mapping; one unit 10 cm
beyond the right carina and the stepper feeder, the 16-ball chain in the procedural atrium. Prints
per-target times and accuracies (distance from the tip's contact point to the target's centre),
the totals beside the paper's operator times (40 s Task I, 26 s Task II), the reason for each
missed target, and writes a Meshcat replay with ``--html``. The chain is the quasi-static engine's
(a whole task in seconds) unless ``--set '{engine: plant}'``; ``--seed`` picks the operator's
tremor. The real-time factor is simulated time over the wall time of the simulation loop.

``--live`` instead opens Meshcat on localhost and lets a person steer the chain in real time with a
gamepad or the keyboard (``systems/meshcat_joystick.py``; the key map is printed on start and
shown on the page), until Escape, the gamepad's Start, Ctrl-C (exit status 130) or ``--duration``
simulated seconds; the clock starts when the first browser opens the page (``--no-wait``: at
once). The flags of the simulated operator's task (``--task``, ``--targets``, ``--seed``,
``--time-limit``, ``--html``, ``--no-progress``) do not apply to it and are refused, as the
live-only flags are without ``--live``.

``--anatomy FILE`` (with or without ``--live``) runs on an anatomy file instead of the procedural
atrium (``drake_models/anatomy.py``: a segmented atrium or a bench phantom, its targets, sheath and
magnet units): the simulated operator visits its targets in file order (``--task X``: only those
named X_...), the unit standing at the file's first magnet.
"""

from __future__ import annotations

import argparse

from ballchain.commands._common import (YamlOnce, add_json_flag, finite_float, non_negative_int, path_arg, print_json,
                                        run_status)


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task", default=None,
                        help="left (Task I, 20 targets) or right (Task II, 18 targets) (default: left)")
    parser.add_argument("--device", default=None,
                        help="ball_chain (the robotic chain) or steerable_catheter (the paper's manual "
                             "comparison arm: the same operator on an 8 Fr steerable catheter's handle, knob and push) (default: ball_chain)")
    parser.add_argument("--strategy", default=None,
                        help="with --device steerable_catheter: at the handle's windup switch (the opposite tendon "
                             "and back by half a turn) or keep (keep turning) (default: switch)")
    parser.add_argument("--braid", type=non_negative_int, default=None,
                        help="with --device steerable_catheter: the shaft braid's wire count, even (default 16, "
                             "the comparison's; 0: the braid neglected in torsion)")
    parser.add_argument("--sheath", default=None,
                        help="with --device steerable_catheter: fixed (the paper's sheath, the robotic arm's) or "
                             "steerable (a deflectable sheath the hand places per target, issue 45) "
                             "(default: steerable, the comparison's manual arm)")
    parser.add_argument("--wall-stiffness", type=finite_float, default=None, metavar="K",
                        help="with --device steerable_catheter: the atrium wall's normal stiffness per rod node in "
                             "N/mm (a compliant wall; tissue about 0.1-0.25 N/mm, Ijima et al.; 0: rigid) "
                             "(default: 0.14, the comparison's manual arm)")
    parser.add_argument("--mapping", default=None,
                        help="world (the paper's: stick = magnet angular velocity in world) or catheter "
                             "(stick swings the tip in the tip's frame) (default: world)")
    parser.add_argument("--targets", type=_int, default=None,
                        help="only the first N targets of the task (default: all)")
    parser.add_argument("--balls", type=_int, default=None,
                        help="chain length (default 16, the paper's; fewer is faster but not the paper's task)")
    parser.add_argument("--time-limit", type=finite_float, default=None,
                        help="simulated-time limit in seconds (default: every target's timeout plus 5 s)")
    parser.add_argument("--seed", type=_int, default=None,
                        help="the simulated operator's seed (its hand's tremor), an integer in 0..2**32-1 (default 0)")
    parser.add_argument("--set", dest="overrides", default=None, metavar="YAML", action=YamlOnce,
                        help="inline YAML overriding the station scenario (teleop_right_unit); the engine is the "
                             "quasi-static one (whole tasks in seconds) unless it says e.g. '{engine: plant}' "
                             "(the MultibodyPlant, minutes per task; '{engine: plant, time_step: 0.004}' is 3 "
                             "times faster, tip path within 0.3 mm of the default 1 ms step)")
    parser.add_argument("--html", type=path_arg, default=None, help="write a Meshcat replay (HTML) to this file")
    parser.add_argument("--anatomy", type=path_arg, default=None, metavar="FILE",
                        help="an anatomy file (YAML: mesh, length_unit, side, targets, sheath, magnets) instead of "
                             "the procedural atrium; the operator visits its targets in file order")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--live", action="store_true",
                        help="steer the chain yourself in Meshcat (localhost) with a gamepad or the keyboard, "
                             "in real time; prints the URL and the key map (--task, --targets, --seed, --time-limit, "
                             "--html and --no-progress do not apply)")
    parser.add_argument("--units", default=None,
                        help="with --live: one (the right unit) or two (both sides; N or the gamepad's RB switches) "
                             "(default: one)")
    parser.add_argument("--duration", type=finite_float, default=None,
                        help="with --live: stop after this many simulated seconds (default: until you quit)")
    parser.add_argument("--realtime-rate", type=finite_float, default=None,
                        help="with --live: target real-time rate (default 1; 0 runs as fast as possible)")
    parser.add_argument("--no-wait", action="store_true",
                        help="with --live: start the clock at once instead of when the first browser opens the page")
    add_json_flag(parser)


def main(args: argparse.Namespace) -> int:
    device = "ball_chain" if args.device is None else args.device
    if device not in DEVICE_RUNS:
        from ballchain.infrastructure.errors import UserInputError, short_repr

        raise UserInputError(f"--device must be {' or '.join(DEVICE_RUNS)}, got {short_repr(args.device)}")
    return DEVICE_RUNS[device](args)


def _main_chain(args: argparse.Namespace) -> int:
    from ballchain.experiments import teleop

    _refuse("without --device steerable_catheter", (("--strategy", args.strategy), ("--braid", args.braid),
                                                    ("--sheath", args.sheath),
                                                    ("--wall-stiffness", args.wall_stiffness)),
            "they set up the manual catheter")
    args.mapping = "world" if args.mapping is None else args.mapping
    if args.live:
        return _main_live(args)
    _refuse("without --live", (("--units", args.units), ("--duration", args.duration),
                               ("--realtime-rate", args.realtime_rate), ("--no-wait", args.no_wait or None)),
            "they steer the chain yourself")
    # teleop.run checks every input, the --html path and the --set YAML before the (slow) build.
    task = "left" if args.task is None and args.anatomy is None else args.task
    data = teleop.run(task=task, mapping=args.mapping, targets=args.targets,
                      html=args.html, progress=not args.no_progress, time_limit=args.time_limit, n_balls=args.balls,
                      overrides=args.overrides, seed=0 if args.seed is None else args.seed, anatomy=args.anatomy)
    if args.json:
        print_json(data)
        return run_status(data.summary.failure, "teleop")
    if data.anatomy is not None:
        a = data.anatomy
        print(f"anatomy {a['file']} ({a['side']} side, {len(a['targets'])} targets, the unit at "
              f"{a['magnets_mm'][0]} mm{' (the default place)' if a['magnets_default'] else ''})")
    for r in data.rows:
        if r["touched"]:
            print(f"{r['target']:9s} touched after {r['time_s']:6.2f} s (t = {r['t_touch_s']:6.2f} s), "
                  f"{r['accuracy_mm']:.2f} mm from the centre")
        else:
            spent = "not reached" if r["time_s"] is None else f"missed after {r['time_s']:.2f} s"
            why = data.summary.missed_reasons.get(r["target"])
            closest = "" if r["closest_mm"] is None else f", closest {r['closest_mm']:.1f} mm"
            print(f"{r['target']:9s} {spent} ({why}{closest})")
    s = data.summary
    median = "-" if s.median_time_s is None else f"{s.median_time_s:.2f} s"
    accuracy = "-" if s.median_accuracy_mm is None else f"{s.median_accuracy_mm:.2f} mm"
    human = ("" if data.paper is None else
             f"; operator in the paper: {data.paper['human_time_s']:.0f} s for the whole task")
    print(f"{data.task or 'every'} task, {data.mapping} mapping: {s.touched}/{s.targets} touched in "
          f"{s.total_time_s:.1f} s (median {median} per target, median accuracy {accuracy}){human}")
    print(f"simulated {s.sim_time_s:.1f} s in {s.wall_time_s:.1f} s of wall time in the simulation loop "
          f"(real-time factor {s.realtime_factor}; {data.settings['engine']} engine, operator seed "
          f"{data.settings['seed']})")
    if data.html is not None:
        print(f"replay: {data.html}")
    return run_status(s.failure, "teleop")


def _main_manual(args: argparse.Namespace) -> int:
    """The simulated operator's task with the manual steerable catheter."""
    from ballchain.experiments import manual_catheter

    _refuse("to --device steerable_catheter", (("--live", args.live or None), ("--mapping", args.mapping),
                                               ("--balls", args.balls), ("--set", args.overrides),
                                               ("--units", args.units),
                                               ("--duration", args.duration), ("--realtime-rate", args.realtime_rate),
                                               ("--no-wait", args.no_wait or None)),
            "they set up the robotic chain or the live view")
    strategy = "switch" if args.strategy is None else args.strategy
    manual_catheter.check_inputs("left" if args.task is None else args.task, args.targets, args.time_limit,
                                 0 if args.seed is None else args.seed, strategy)
    sheath = manual_catheter.MANUAL_SHEATH if args.sheath is None else args.sheath
    if sheath not in manual_catheter.SHEATHS:
        from ballchain.infrastructure.errors import UserInputError, short_repr

        raise UserInputError(f"--sheath must be one of {', '.join(manual_catheter.SHEATHS)} (a steerable sheath the "
                             f"hand moves, or the paper's fixed one), got {short_repr(args.sheath)}")
    catheter = manual_catheter.manual_arm_catheter(args.braid, _wall_stiffness(args.wall_stiffness))
    data = manual_catheter.run(task="left" if args.task is None else args.task, targets=args.targets,
                               seed=0 if args.seed is None else args.seed, strategy=strategy,
                               time_limit=args.time_limit, catheter=catheter, html=args.html, sheath=sheath)
    if args.json:
        print_json(data)
        return 0
    for r in data.rows:
        if r["touched"]:
            print(f"{r['target']:9s} touched after {r['time_s']:6.2f} s, {r['accuracy_mm']:.2f} mm from the centre")
        else:
            spent = "not reached" if r["time_s"] is None else f"missed after {r['time_s']:.2f} s"
            print(f"{r['target']:9s} {spent} ({data.summary.missed_reasons.get(r['target'])})")
    s = data.summary
    k = data.settings.get("wall_stiffness_N_per_m")
    wall = "rigid wall" if not k else f"{k / 1e3:g} N/mm wall"
    print(f"{data.task} task, manual catheter ({sheath} sheath, {wall}, {strategy} at the windup): "
          f"{s.touched}/{s.targets} touched in "
          f"{s.total_time_s:.1f} s; tendon switches {data.settings['switches']}; operator in the paper: "
          f"{manual_catheter.PAPER_COMPARISON[data.task]['manual_s']:.0f} s")
    if data.html is not None:
        print(f"replay: {data.html}")
    return 0


def _wall_stiffness(n_per_mm) -> float | None:
    """``--wall-stiffness`` [N/mm] as the catheter's ``wall_stiffness`` [N/m] (None: not given, the
    manual arm's, ``manual_catheter.MANUAL_WALL_STIFFNESS``); UserInputError naming the flag outside
    [0, the catheter's most]."""
    from ballchain.drake_models.steerable_catheter import MAX_WALL_STIFFNESS
    from ballchain.infrastructure.errors import UserInputError

    if n_per_mm is None:
        return None
    if not 0.0 <= n_per_mm <= MAX_WALL_STIFFNESS / 1e3:
        raise UserInputError(f"--wall-stiffness must be in [0, {MAX_WALL_STIFFNESS / 1e3:g}] N/mm (0: the rigid wall; "
                             f"tissue about 0.1-0.25 N/mm), got {n_per_mm:g}")
    return float(n_per_mm) * 1e3


def _refuse(where: str, flags, why: str) -> None:
    """UserInputError naming the first of ``flags`` ((flag, value or None), ...) that was given."""
    from ballchain.infrastructure.errors import UserInputError, short_repr

    for flag, value in flags:
        if value is not None:
            shown = "" if value is True else f" (got {short_repr(value)})"
            raise UserInputError(f"{flag} does not apply {where}{shown}: {why}")


def _main_live(args: argparse.Namespace) -> int:
    import sys

    from ballchain.experiments import teleop

    _refuse("to --live", (("--task", args.task), ("--targets", args.targets), ("--seed", args.seed),
                          ("--time-limit", args.time_limit), ("--html", args.html),
                          ("--no-progress", args.no_progress or None)),
            "they set up the simulated operator's task; use --duration to bound a live run")
    units = "one" if args.units is None else args.units
    rate = 1.0 if args.realtime_rate is None else args.realtime_rate
    teleop.check_live_inputs(args.mapping, units, args.balls, args.duration, rate)
    # With --json the console lines go to stderr, so that stdout is the JSON alone.
    stream = sys.stderr if args.json else sys.stdout
    echo = lambda line: print(line, file=stream, flush=True)  # noqa: E731
    # Ctrl-C: run_live prints its summary and lets the KeyboardInterrupt go on (exit status 130).
    data = teleop.run_live(mapping=args.mapping, units=units, n_balls=args.balls, overrides=args.overrides,
                           duration=args.duration, realtime_rate=rate, echo=echo,
                           wait_for_browser=not args.no_wait, freeze_gc=True, anatomy=args.anatomy)
    if args.json:
        print_json(data)
    return 0


# --device: the run of each device (the robotic chain's teleop task or the manual catheter's).
DEVICE_RUNS = {"ball_chain": _main_chain, "steerable_catheter": _main_manual}
