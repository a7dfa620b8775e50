"""The tip force as report sections: paper Table I (statics and simulation), then its gap taken
apart effect by effect and the paper's clinical design in simulation.

Each section is a function ``(out, quick) -> (Section, data)`` and a headline builder
``(section, data)``; the registry (``registry.py``) pairs them.
"""

from __future__ import annotations

from pathlib import Path

from ballchain.drake_models import paper
from ballchain.infrastructure.safe_files import write_json
from ballchain.report import Section
from ballchain.reproduce.common import _agrees


def forces_section(out: Path, quick: bool) -> tuple[Section, dict]:
    """Paper Table I: the tip force on the pulmonary veins, statics beside the simulation."""
    from ballchain.experiments import forces

    veins = ("RSPV",) if quick else ("LSPV", "LIPV", "RSPV", "RIPV")
    # The grid must be fine enough to start Nelder-Mead in the best basin: with 6 x 5 directions
    # and 24 evaluations one case (LIPV, magnet on the left) stopped at 5.9 gf instead of 9.6 gf.
    data = forces.run(veins=veins, sleeves=(False,) if quick else (False, True), grid=4 if quick else 8,
                      refine_evaluations=8 if quick else 40, out=out / "forces")
    section = Section("Tip force on the pulmonary veins (paper Table I)")
    section.text(
        "Statics with the tip ball held on the vein's sensor pin; the pin's reaction is the "
        "constraint's multiplier, and the magnet orientation that maximises the force along the "
        "vein's axis is found by optimisation (a grid of dipole directions, then Nelder-Mead). "
        "Configuration 1: the prototype magnet 16.51 cm to the patient's right of the septal "
        "puncture; 2: to the left; both: the two magnets together, both orientations optimised "
        "(the paper adds the single-magnet forces). A chain of 16 balls, bare and in the sleeve. "
        "The simulation column is the same case in the MultibodyPlant (magnetic wrenches, ball "
        "contacts, quasi-static damped dynamics from the statics shape) with the pin a 500 N/m "
        "force sensor spring on the tip (`systems/force_sensor_pin.py`), read at steady state."
    )
    section.table(["vein", "config", "sleeve", "paper [gf]", "model statics [gf]", "model simulation [gf]",
                   "statics vs simulation [%]", "model: sum of singles [gf]"], _force_rows(data), resolution={6: 0.01})
    diffs = [abs(r["statics_dynamics_diff_pct"]) for r in data.rows if r.get("statics_dynamics_diff_pct") is not None]
    if diffs:
        section.text(f"Statics and simulation agree within {max(diffs):.2f} % on every row "
                     f"({len(diffs)} of {len(data.rows)} rows reached a steady state): two independent computations of the same force, "
                     "one an optimisation, one a time-stepped contact simulation with a spring sensor.")
    section.text(
        "The model's forces are an order of magnitude below the measured ones. The tip force is "
        "the torque on the bent chain, carried to the tip as the chain's push from the sheath, plus "
        "the field's gradient pull on the balls: with the prototype 16.5 cm away the pull is about "
        "a third of it (LSPV, magnet on the left: 3.5 of 9.4 gf; 7.0 gf with the gradient switched "
        "off, see the effects below). No constant was tuned; the next section sizes what the rig "
        "would have had to contain to read tens of grams."
    )
    section.figure(out / "forces" / "forces.png", "paper vs model, grams-force (log scale)")
    return section, data


def _force_rows(data) -> list[list]:
    return [[r["vein"], r["config"], "yes" if r["sleeve"] else "no", r["paper_gf"], r["statics_gf"],
             r.get("dynamics_gf"), r.get("statics_dynamics_diff_pct"), r.get("superposition_gf")] for r in data.rows]


def forces_headlines(section: Section, data) -> None:
    rows = _force_rows(data)
    # The row the next section takes apart (the largest single-magnet force in Table I), else the first.
    row = next((r for r in rows if r[:3] == ["LSPV", "2", "no"]), rows[0])
    ratios = [r[4] / r[3] for r in rows if r[3]]
    chain = "in the sleeve" if row[2] == "yes" else "bare chain"
    section.headline(f"tip force, {row[0]}, configuration {row[1]}, {chain} [gf]", row[3], row[4],
                     _agrees(row[3], row[4]),
                     f"every row {min(ratios):.2f} to {max(ratios):.2f} of the paper's, no constant tuned; only a "
                     "steel part at the pin reaches the measured size (next section)")


def clinical_section(out: Path, quick: bool) -> tuple[Section, dict]:
    """Table I's gap effect by effect, and the paper's clinical design in simulation."""
    from ballchain.experiments import clinical, table1_effects

    effects = table1_effects.run(quick=quick)
    case, grad = effects.case, effects.gradient
    section = Section("Table I's gap effect by effect, and the clinical design in simulation")
    section.text(
        f"The row taken apart: {case.vein}, the prototype magnet on the left (Configuration 2), bare chain: "
        f"model {case.model_gf:.2f} gf (this section's coarser search; Table I's above), paper "
        f"{case.paper_gf} gf, {case.shortfall_gf:.1f} gf short. By force balance the pin's push is the "
        f"field's gradient pull on balls 2..16 ({grad.gradient_pull_gf:.2f} gf) plus what the sheath pushes in "
        f"through ball 1, the torque on the bent chain carried to the tip ({grad.sheath_push_gf:.2f} gf); "
        "with the gradient switched off (each ball keeps the field it had) the held chain presses "
        + (f"{grad.without_gradient_gf:.2f} gf." if grad.without_gradient_gf is not None else "(did not converge).")
    )
    section.table(["effect", "model", "force range [gf]", f"could it bring {case.model_gf:.1f} gf to {case.paper_gf} gf?"],
                  [[r.effect, r.model,
                    "-" if r.force_range_gf is None else f"{r.force_range_gf[0]:.1f} to {r.force_range_gf[1]:.1f}",
                    r.could_reach_paper] for r in effects.table])
    _effects_text(section, effects)
    write_json(out / "table1_effects.json", effects)

    veins = ("RSPV",)  # one vein keeps this section under a minute; the command does the rest
    study = clinical.run(chains=("8Fr", "today"), ring_step=0, sizing=not quick, veins=veins, progress=False)
    study.files = clinical.write_files(study, out / "clinical")
    _clinical_design_text(section, study, out, quick)
    return section, {"effects": effects, "clinical": study}


def _effects_text(section: Section, effects) -> None:
    """Effects (a) to (e) of Table I's gap in numbers, and what the rig would have had to contain."""
    ferro = {r.gap_mm: r for r in effects.ferromagnetic}
    support = ", ".join(f"{r.free_balls} free: {r.force_gf:.1f}" for r in effects.side_support if r.force_gf is not None)
    cones = ", ".join(f"mu {r.mu:g}: {r.force_gf:.2f}" for r in effects.friction.cones)
    push = ", ".join(f"{r.field_mT:g} mT: {r.peak_gf:.1f}" for r in effects.push if r.peak_gf is not None)
    section.text(
        f"(a) Every Table I value is a whole number of 0.05 N steps ({effects.resolution.step_gf:.2f} gf; the "
        f"largest distance from a whole step is {effects.resolution.largest_distance_from_a_whole_step:.3f} steps): "
        f"the sensor would read the model's force as {effects.table[0].reading_of_model_gf:.1f} gf. "
        f"(b) Soft iron at the pin's face pulls the whole chain along the sensor's axis with "
        f"{ferro[0.0].chain_pull_along_axis_gf:.0f} gf when the tip ball touches it, "
        f"{ferro[0.25].chain_pull_along_axis_gf:.0f} gf through a 0.25 mm wall, "
        f"{ferro[1.0].chain_pull_along_axis_gf:.0f} gf at 1 mm, {ferro[2.0].chain_pull_along_axis_gf:.0f} gf at 2 mm "
        f"(the tip ball alone: {ferro[0.0].tip_ball_alone_normal_gf:.0f} gf normal, "
        f"{ferro[0.0].tip_ball_alone_parallel_gf:.0f} gf parallel, touching). "
        f"(c) Clamping the chain k balls before the pin, [gf]: {support}; a short free length pinned nearly in line with "
        "its clamp needs large forces to balance small torques"
        + ("; at some lengths the pin can only pull (negative). " if any(
            (r.force_gf or 0.0) < 0 for r in effects.side_support) else ". ")
        + f"(d) Holding the tip at the optimum takes friction {effects.friction.mu_needed:.2f} "
        f"(lateral {effects.friction.lateral_gf:.2f} gf); inside a cone the best force is [gf] {cones}. "
        f"(e) Advancing the chain continuously against a pin on the sheath's axis, field along it [gf]: {push}; "
        "the push rises to the buckling load and plateaus (no fold)."
    )
    section.text(
        "What the rig would have to have contained to read 91.8 gf: only a ferromagnetic part within about half a "
        "millimetre of the tip ball, on the sensor's fixed side (a steel sensor body or screw behind a plastic pin, "
        "or a steel pin in front of a separate load cell), reaches the measured size; a steel sensing element itself "
        "would feel the ball's push and its magnetic pull as equal and opposite parts of one load. A sideways "
        "support close to the pin adds tens of grams only in a narrow geometry. The sensor's step, friction at the "
        "pin and continuous insertion move the reading by a few grams at most. None is described in the paper; no "
        "constant was tuned."
    )


def _clinical_design_text(section: Section, study, out: Path, quick: bool) -> None:
    """The clinical design's set-up, its forces and sizing tables, the verdict on the paper's claim, the figures."""
    s = study.setup
    section.text(
        f"The paper's clinical design: two N52 spheres of {s.diameter_mm:.0f} mm ({s.mass_kg:.2f} kg), "
        f"centres {s.magnet_distance_cm:.2f} cm from the atrium's centre on the patient's left and right "
        "(d_c + D/2, the paper's sizing equation: the magnet outside the patient; the atrium's centre is the reference "
        f"because the targets surround it); at most {s.field_at_centre_coaxial_mT:.1f} mT there. The 8 Fr chain: "
        f"{s.chains['8Fr'].n_balls} balls of 2.17 mm (alpha {s.chains['8Fr'].alpha:.3f}) in a sleeve of "
        f"OD 2.67 mm; today's: 16 balls of 3.175 mm in today's sleeve. Both magnets' directions optimised for the "
        f"force along the target's axis with the wall's tangential push inside the friction cone (mu {s.friction}). "
        + "This report does the RSPV" + ("" if quick else " and its sizing (the diameter that gives it 10 gf)")
        + "; `ballchain clinical --ring-step 1` does all four veins and all 38 ring targets (tens of minutes here)."
    )
    section.table(["chain", "target", "best force [gf]", "friction needed", "gradient pull [gf]", "sheath push [gf]"],
                  [[r.chain, r.target, r.effective_gf, r.friction_needed, r.gradient_pull_gf, r.sheath_push_gf]
                   for r in study.rows])
    if study.sizing:
        section.table(["chain", "criterion", "diameter [mm]", "mass [kg]", "centre distance [cm]",
                       "force between the magnets, coaxial [gf]"],
                      [["paper (8 Fr)", "10 gf (scaled from Table I)", paper.SIZING["diameter_mm"], paper.SIZING["mass_kg"],
                        100 * paper.CLINICAL_DISTANCE + 0.05 * paper.SIZING["diameter_mm"],
                        paper.SIZING["force_between_magnets_gf"]]]
                      + [[r.chain, r.criterion.replace("every vein", "the RSPV"), r.diameter_mm,
                          r.mass_kg, r.magnet_distance_cm, r.force_between_magnets_gf] for r in study.sizing
                         if "ring" not in r.criterion])
    best_8fr = _best_8fr(study)
    section.text(
        f"The paper's claim (10 gf with two 119 mm magnets) does not hold in the model: with the 8 Fr chain the best "
        f"force on these targets is {best_8fr:.2f} gf. The force is almost all the sheath's push (the gradient pull "
        "of spheres this far away is a few hundredths of a gram), so it grows with the field, not as the paper's "
        "d^-4 lumped-dipole law."
    )
    # With one target the force-per-target figure would show one point per chain: the table says it.
    several_targets = len({r.target for r in study.rows}) > 1
    for name, caption in (("clinical_forces.png", "force per target, both chains"),
                          ("clinical_sizing.png", "force against the spheres' diameter")):
        if (out / "clinical" / name).exists() and (several_targets or name != "clinical_forces.png"):
            section.figure(out / "clinical" / name, caption)


def _best_8fr(study) -> float:
    return max((r.effective_gf for r in study.rows if r.chain == "8Fr"), default=0.0)


def clinical_headlines(section: Section, data) -> None:
    study = data["clinical"]
    best_8fr = _best_8fr(study)
    section.headline(f"clinical design: 8 Fr chain, two {study.setup.diameter_mm:.0f} mm spheres, best force [gf]",
                     paper.SIZING["desired_force_gf"], best_8fr, _agrees(paper.SIZING["desired_force_gf"], best_8fr),
                     "almost all of it is the sheath's push, which grows with the field, not as the paper's "
                     "d^-4 lumped-dipole law")
