"""Steering as report sections: model-based planning (beyond the paper), teleoperation with a
simulated operator (paper Sec. VI-B) and the robotic chain against a manual catheter (Sec. V-C).

Each section is a function ``(out, quick) -> (Section, data)`` and a headline builder
``(section, data)``; the registry (``registry.py``) pairs them.
"""

from __future__ import annotations

import math
from pathlib import Path

from ballchain.drake_models import paper
from ballchain.infrastructure.safe_files import write_json
from ballchain.intervals import Interval, agrees, interval, paired_interval, side_agrees
from ballchain.report import Section
from ballchain.experiments.trials import DEFAULT_SEEDS as TRIALS_SEEDS
from ballchain.reproduce.common import _say


def plan_section(out: Path, quick: bool) -> tuple[Section, dict]:
    """Beyond the paper: the ablation targets planned by inverse statics with one magnet."""
    from ballchain.experiments import planner

    n_targets = 2 if quick else None
    section = Section("Model-based steering: ablation targets by inverse statics (beyond the paper)")
    section.text(
        "One prototype magnet 10 cm beyond the right carina (the paper's teleoperation set-up). "
        "At each target in turn a MathematicalProgram (SNOPT over the magnet's dipole direction "
        "and the touch point within the target's 5 mm circle; each evaluation a held-tip "
        "equilibrium) finds the smallest magnet turn from the previous orientation whose "
        "equilibrium presses the wall with at least 10 gf, with the wall's tangential push inside "
        "the friction cone of the simulation's contact model (mu = 0.1). The plan's time counts "
        "the magnet's turns at 0.5 rad/s and the feeder's moves at 20 mm/s. "
        + ("This quick report plans the first 2 targets of each ring; " if quick else "")
        + "16 balls inserted (`ballchain plan --task left|right --balls 12 16` also tries 12; on the "
        "rings' targets 12 balls reached no target the 16 could not)."
    )
    rows, data = [], {}
    for task in ("left", "right"):
        result = planner.run(task=task, targets=n_targets, balls=(16,), grid=3 if quick else 4,
                             refine=5 if quick else 15)
        data[task] = result
        s = result.summary
        rows.append([task, f"{s.reached}/{s.targets}", s.force_gf_min, s.force_gf_max,
                     s.plan_time_s, s.compute_time_s])
        write_json(out / f"plan_{task}.json", result)
    section.table(["ring", "planned", "min force [gf]", "max force [gf]", "plan motion time [s]",
                   "compute time [s]"], rows)
    per_target = [[r["target"], "yes" if r["reached"] else "no", r["force_gf"], r["turn_deg"], r["friction_needed"],
                   r["offset_mm"], r["reason"] or "-"] for task in ("left", "right") for r in data[task].rows]
    section.table(["target", "planned", "force [gf]", "magnet turn [deg]", "F_t / F_n (friction needed)", "off centre [mm]",
                   "lengths without a plan"], per_target)
    left, right = data["left"].summary, data["right"].summary
    section.text(
        f"With the one magnet beside the right veins, {right.reached} of {right.targets} right-ring "
        f"targets and {left.reached} of {left.targets} left-ring targets can be pressed with 10 gf "
        "(the others: the search for the hardest-pressing orientation, tip held on the centre, found "
        "less than 10 gf; it is a local search). A second magnet on the left, as the paper proposes, "
        "is what the left ring needs. The plan's time is the hardware's motion time only (no "
        "perception or hesitation); the paper's operator took 40 s for the 20 left targets and 26 s "
        "for the 18 right ones."
    )
    return section, data


def plan_headlines(section: Section, data) -> None:
    right, left = data["right"].summary, data["left"].summary
    section.headline("targets pressed with 10 gf by one magnet (right ring, left ring)", None,
                     f"{right.reached}/{right.targets}, {left.reached}/{left.targets}", None,
                     "beyond the paper; the left ring needs the second magnet the paper proposes")


def teleop_section(out: Path, quick: bool) -> tuple[Section, dict]:
    """Paper Sec. VI-B: the teleoperation tasks with a simulated operator, and their spread over seeds."""
    from ballchain.experiments import teleop
    from ballchain.systems.chain_simulation import atrium_for

    # Whole tasks on the quasi-static engine (seconds each); --quick: the first 2 targets.
    n_targets = 2 if quick else None
    seeds = range(1, 3) if quick else range(1, teleop.REPRODUCE_SEEDS + 1)  # seed 0 is the table above
    replays = out / "replays"
    replays.mkdir(parents=True, exist_ok=True)
    _say(f"the teleoperation runs' Meshcat replays go to {replays}/ (self-contained pages to open in a browser)")
    section = Section("Teleoperation tasks with a simulated operator (paper Sec. VI-B)")
    section.text(
        "The paper's teleoperation station (16 balls in the atrium, one rotating unit 10 cm beyond "
        "the right carina, the stepper feeder) with a simulated operator on the joystick and the "
        "feeder (`systems/simulated_operator.py`): it sees only the tip (its camera), learns the "
        "stick-to-tip mapping by watching, and touches the targets in order; a target counts when "
        "the tip touches it within its 5 mm circle, and after 20 s on one it gives up. Two mappings: "
        "the paper's world frame and the catheter frame. The chain is the quasi-static engine's "
        "(`engine: statics`: its equilibrium with the atrium's wall every 50 ms; "
        "`ballchain teleop --set '{engine: plant}'` runs the MultibodyPlant, minutes per task). "
        + (f"This quick report runs the first {n_targets} targets of each task; " if quick else
           "Whole tasks (Task I: 20 left targets, Task II: 18 right ones), operator seed 0; ")
        + "the real-time factor is simulated time over the wall time of the simulation loop "
        "(the station's build not counted), on a shared machine."
    )
    heart = atrium_for(teleop.scenario_for("world"))
    rows, data = [], {}
    for task in teleop.TASKS:
        for mapping in teleop.MAPPINGS:
            html = replays / f"teleop_{task}_{mapping}.html"
            result = teleop.run(task=task, mapping=mapping, targets=n_targets, html=html, heart=heart)
            data[f"{task}_{mapping}"] = result
            s = result.summary
            rows.append([task, mapping, f"{s.touched}/{s.targets}", s.total_time_s, s.median_time_s,
                         s.median_accuracy_mm, result.paper["human_time_s"], s.realtime_factor,
                         s.failure or "-", f"replays/{html.name}"])
            write_json(out / f"teleop_{task}_{mapping}.json", result)
    section.table(["task", "mapping", "touched", "time [s]", "median per target [s]", "median accuracy [mm]",
                   "paper's operator [s]", "real-time factor", "failure", "Meshcat replay"], rows)
    per_target = [[k, r["target"], "yes" if r["touched"] else "no", r["time_s"], r["accuracy_mm"],
                   v.summary.missed_reasons.get(r["target"], "-"), r["closest_mm"]]
                  for k, v in data.items() for r in v.rows]
    section.table(["run", "target", "touched", "time on it [s]", "accuracy [mm]", "missed because",
                   "closest [mm]"], per_target)
    spread_targets = 1 if quick else None
    spread = teleop.run_seeds(seeds=seeds, targets=spread_targets, out=out / "teleop_seeds", heart=heart)
    data["seeds"] = spread
    section.text(
        f"The spread over operator seeds {', '.join(str(v) for v in spread.settings['seeds'])} (the "
        "hand's tremor: each seed is another operator run) per task and mapping"
        + (f", first {spread_targets} target" if quick else ", whole tasks")
        + "; total time counts every target's time, touched or given up "
        "(`ballchain.experiments.teleop.run_seeds`, `teleop_seeds/teleop_seeds.csv`)."
    )
    section.table(["task", "mapping", "runs", "touched min/median/max", "total time median (min-max) [s]",
                   "median per target [s]", "median accuracy [mm]", "paper's operator [s]", "missed because"],
                  [[r["task"], r["mapping"], r["runs"],
                    f"{r['touched_min']}/{r['touched_median']:g}/{r['touched_max']} of {r['targets']}",
                    f"{r['total_time_median_s']} ({r['total_time_min_s']}-{r['total_time_max_s']})",
                    r["per_target_time_median_s"], r["accuracy_median_mm"], r["paper_time_s"], r["missed_reasons"]]
                   for r in spread.table])
    section.text("The paper's operator took 40 s for all 20 left targets and 26 s for the 18 right ones "
                 "(with the world mapping, after learning).")
    data["intervals"] = teleop_intervals(data)
    write_json(out / "teleop_intervals.json", data["intervals"])
    section.text("The summary's rows for the world mapping: the median over the operator seeds with its 95 % "
                 "bootstrap interval (`ballchain/intervals.py`; `teleop_intervals.json` holds the per-seed values); "
                 "a row agrees only when the paper's number lies inside the interval. "
                 f"`ballchain trials` runs the same over {TRIALS_SEEDS} seeds and more.")
    return section, data


def _field(summary, name: str):
    """A run summary's field, from the dataclass or its JSON dict."""
    return summary[name] if isinstance(summary, dict) else getattr(summary, name)


def teleop_intervals(data: dict) -> dict:
    """Per task, world mapping: the targets touched and the total time over the operator seeds
    (seed 0's run of the table when it ran the same targets as the seed spread, and the spread's
    seeds), each a median with its 95 % interval and the per-seed values."""
    spread = data["seeds"]
    found = {}
    for task in paper.TELEOP_TASKS:
        runs = [(x["seed"], x["summary"]) for x in spread.runs if x["task"] == task and x["mapping"] == "world"]
        first = data.get(f"{task}_world")
        if first is not None and runs and first.summary.targets == _field(runs[0][1], "targets") \
                and all(seed != 0 for seed, _ in runs):
            runs.insert(0, (0, first.summary))
        if not runs:
            continue
        targets = _field(runs[0][1], "targets")
        found[task] = {"mapping": "world", "seeds": [seed for seed, _ in runs], "targets": targets,
                       "paper_targets": paper.TELEOP_TASKS[task]["targets"],
                       "paper_time_s": paper.TELEOP_TASKS[task]["human_time_s"],
                       "touched": interval([_field(x, "touched") for _, x in runs]).to_dict(),
                       "total_time_s": interval([_field(x, "total_time_s") for _, x in runs]).to_dict()}
    return found


def teleop_headlines(section: Section, data: dict) -> None:
    """Two headlines per task, world mapping (the paper's): the targets touched and the total time,
    each the median over the operator seeds with its 95 % interval; a row agrees only when the
    paper's number lies inside the interval (``ballchain.intervals``)."""
    for task, v in (data.get("intervals") or teleop_intervals(data)).items():
        touched, total = Interval(**v["touched"]), Interval(**v["total_time_s"])
        asked, whole = v["targets"], v["targets"] == v["paper_targets"]
        seeds = (f"{touched.n} operator seed{'s' if touched.n != 1 else ''} ({', '.join(map(str, v['seeds']))}); "
                 f"`ballchain trials` runs {TRIALS_SEEDS}")
        section.headline(f"{task} ring, world mapping: targets touched (median, 95 % CI)", f"{asked}/{asked}",
                         f"{touched.text('{:g}')} of {asked}", agrees(asked, touched),
                         f"{seeds}; the paper's operator touched all {v['paper_targets']}")
        section.headline(f"{task} ring, world mapping: total time [s] (median, 95 % CI)",
                         v["paper_time_s"] if whole else None, total.text("{:.1f}"),
                         agrees(v["paper_time_s"], total) if whole else None,
                         seeds + ("" if whole else f"; the first {asked} targets only, the paper's "
                                  f"{v['paper_time_s']:g} s is for all {v['paper_targets']}"))


def manual_section(out: Path, quick: bool) -> tuple[Section, dict]:
    """Paper Sec. V-C: the robotic chain against a manual steerable catheter, same simulated operator."""
    from ballchain.experiments import manual_catheter as mc

    seeds, targets = ((0,), 3) if quick else ((0, 1, 2), None)  # whole tasks: minutes of CPU time
    comparison = mc.compare(seeds=seeds, targets=targets)
    comparison["intervals"] = manual_intervals(comparison)
    write_json(out / "manual_comparison.json", comparison)
    mc.transition_figure(comparison, out / "manual_transitions.png")
    plain = mc.torsion_lead_deg(mc.comparison_catheter(0))
    cat = mc.comparison_catheter()
    from ballchain.systems.manual_hand import HandParams

    braided = mc.torsion_lead_deg(cat)
    section = Section("Robotic vs manual navigation (paper Sec. V-C)")
    section.text(
        "The same simulated operator (it sees only the tip, learns its inputs' effect, gives up after 20 s) "
        "on the robotic chain (world mapping, quasi-static engine) and on an 8 Fr steerable catheter "
        "(`systems/catheter_station.py`: a Kirchhoff rod in the atrium, tendon curvature both ways, stick-slip "
        "friction of the shaft in the sheath; the hand turns the handle, the knob and pushes at human rates and, "
        "when the handle's torque it feels reaches its threshold "
        f"({1e3 * HandParams().torque_threshold:.1f} mN m, a stated human parameter) or at the F tendon's end, "
        "switches tendon and turns back). "
        + (f"Quick report: the first {targets} targets, seed 0. " if quick else
           f"Whole tasks, operator seeds {', '.join(map(str, seeds))}; medians over the seeds. ")
        + "Smoothness: SPARC of the tip's speed per transition (Balasubramanian et al. 2015; closer to 0 is "
        f"smoother). The shaft's twist lags the handle by {braided['kinetic_deg']}-{braided['static_deg']} deg "
        f"with the shaft's steel braid in torsion ({cat.braid_wires} wires of {cat.braid_wire_diameter * 1e3:.3f} mm at "
        f"{math.degrees(cat.braid_angle):.0f} deg, netting analysis: GJ {cat.shaft_GJ / cat.plain_GJ:.1f} times the "
        f"plain tube's; `drake_models/steerable_catheter.py`), {plain['kinetic_deg']}-{plain['static_deg']} deg with "
        "it neglected: there the operator touches nothing. "
        f"The arms' sheaths and walls differ (issue 45): the manual arm has a {mc.MANUAL_SHEATH} sheath the hand "
        "places per target (as for pulmonary-vein isolation; `systems/sheath_plan.py`, its plans cached per ring) on a "
        f"compliant wall of {mc.MANUAL_WALL_STIFFNESS / 1e3:g} N/mm (Ijima et al.), the robotic arm the paper's fixed "
        "sheath and the quasi-static engine's rigid wall (its statics has no compliant wall yet). A tissue-like wall "
        "sped the robotic arm too where it could be run (the plant engine, one seed, `docs/guide/manual_catheter.md`), "
        "so these walls favour the manual arm.")
    section.table(["task", "device", "touched", "total [s]", "paper [s]", "transition median [s]",
                   "accuracy median [mm]", "SPARC median", "reversals", "handle revolutions / stick travel"],
                  [[r["task"], r["device"], f"{r['touched_median']:g}/{r['targets']}", r["total_time_median_s"],
                    r["paper_total_s"], r["transition_median_s"], r["accuracy_median_mm"], r["sparc_median"],
                    r["reversals_median"], r.get("handle_revolutions_median", r.get("stick_travel_median"))]
                   for r in comparison["table"]])
    windup = comparison["windup_13_14"]
    if windup:
        section.text("Left 13 -> 14 with the manual catheter (paper: 5.49 s, the hardest, after about 180 deg of "
                     "handle twist): " + "; ".join(
                         f"{w['time_s']} s, handle at {w['twist_at_first_deg']} -> {w['twist_at_second_deg']} deg, "
                         f"windup up to {w['max_windup_deg']} deg" for w in windup) + ".")
    section.figure(out / "manual_transitions.png", "Median time per target-to-target transition (grey: never completed).")
    return section, comparison


def manual_intervals(comparison: dict) -> dict:
    """Per task: each device's total time over the seeds and the paired difference robotic - manual
    (the same operator seed drives both), medians with their 95 % intervals and the per-seed values."""
    found = {}
    for task in dict.fromkeys(r["task"] for r in comparison["runs"]):
        arm = {d: {x["seed"]: _field(x["summary"], "total_time_s") for x in comparison["runs"]
                   if x["task"] == task and x["device"] == d} for d in ("robotic", "manual")}
        seeds = [s for s in arm["robotic"] if s in arm["manual"]]
        if not seeds:
            continue
        robot, hand = [arm["robotic"][s] for s in seeds], [arm["manual"][s] for s in seeds]
        found[task] = {"seeds": seeds, "robotic_total_s": interval(robot).to_dict(),
                       "manual_total_s": interval(hand).to_dict(),
                       "difference_s": paired_interval(robot, hand).to_dict()}
    return found


def manual_headlines(section: Section, comparison: dict) -> None:
    _manual_headlines(section, comparison["table"], comparison.get("intervals"))


def _manual_headlines(section: Section, table: list[dict], intervals: dict | None = None) -> None:
    """Per task: robotic vs manual total time (the paper: similar on Task I, 26 vs 33 s on Task II) and
    which tip path is smoother (the paper: the robot's).

    The time's verdict is on the paired difference robotic - manual over the seeds (``intervals``,
    from ``manual_intervals``; without them, the table's medians as a point): "similar" agrees when
    its 95 % interval holds 0, "the robot faster" when it lies below 0 (``intervals.side_agrees``);
    a device whose median run missed targets does not agree."""
    rows = {(r["task"], r["device"]): r for r in table}
    for task in ("left", "right"):
        robot, hand = rows.get((task, "robotic")), rows.get((task, "manual"))
        if robot is None or hand is None:
            continue
        r_t, h_t = robot["total_time_median_s"], hand["total_time_median_s"]
        p_r, p_h = robot["paper_total_s"], hand["paper_total_s"]
        if r_t is not None and h_t is not None:
            v = (intervals or {}).get(task)
            diff = Interval(**v["difference_s"]) if v else paired_interval([r_t], [h_t])
            every = all(r["touched_median"] == r["targets"] for r in (robot, hand))
            side = "similar" if p_r == p_h else ("lower" if p_r < p_h else "higher")
            seeds = f"{diff.n} operator seed{'s' if diff.n != 1 else ''}"
            section.headline(f"{task} ring: total time robotic / manual [s]",
                             f"{p_r:g} / {p_h:g}; {p_r - p_h:+g}",
                             f"{r_t:.1f} / {h_t:.1f}; {diff.text('{:+.1f}')}", every and side_agrees(diff, side),
                             f"the paper: {'similar' if side == 'similar' else 'the robot faster'}; {seeds}, "
                             f"`ballchain trials` runs {TRIALS_SEEDS}; the manual catheter touched "
                             f"{hand['touched_median']:g}/{hand['targets']} targets (median over seeds), driven by "
                             "the robotic arm's operator model, not a trained hand")
        r_s, h_s = robot["sparc_median"], hand["sparc_median"]
        if r_s is not None and h_s is not None:  # None: no transition completed (a --quick run's few targets)
            section.headline(f"{task} ring: smoother tip path (SPARC, closer to 0)", "robotic",
                             f"{r_s:.2f} vs {h_s:.2f}", r_s > h_s, "median over transitions and seeds")


