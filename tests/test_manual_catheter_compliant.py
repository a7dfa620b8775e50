"""The manual run on a compliant wall (issue 45, H10): what its JSON adds, and the watchdog's
test of a node the compliant wall holds past the wall's middle."""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.atrium_sdf import atrium_sdf
from ballchain.experiments import manual_catheter as mc
from ballchain.systems.rod_wall_compliance import INDENTATION_CAP
from ballchain.systems.station import atrium_for
from ballchain.systems.target_contact import heart_targets


def test_the_watchdog_tolerates_what_the_compliant_wall_holds_and_no_more():
    """A node over a target at an indentation d (its centre r - d off the wall along the normal):
    held within the cap, not beyond it (the signed distance checked at the point first)."""
    heart = atrium_for(mc.scenario_for())
    cat = mc.comparison_catheter()
    cat.wall_stiffness = 140.0
    holds = mc._within_compliance(heart, cat)
    sdf = atrium_sdf(heart)
    names, p_WT, n_W, _ = heart_targets(heart)
    for k in (names.index("right_15"), names.index("left_3")):
        for d, expected in ((1.5e-3, True), (INDENTATION_CAP - 0.2e-3, True), (INDENTATION_CAP + 0.5e-3, False)):
            p = p_WT[k] + (cat.radius - d) * n_W[k]
            depth = cat.radius - float(sdf(p[None], gradient=False)[0])
            assert abs(depth - d) < 0.1e-3, (names[k], d, depth)  # the wall locally flat at the target
            assert holds(p) is expected, (names[k], d)


def test_a_compliant_run_reports_its_wall_and_a_rigid_run_does_not():
    cat = mc.comparison_catheter()
    cat.wall_stiffness = 140.0
    soft = mc.run(task="left", targets=2, catheter=cat)
    assert soft.summary.failure is None and soft.summary.touched >= 1
    s = soft.settings
    assert s["wall_stiffness_N_per_m"] == 140.0
    assert s["peak_wall_force_N"] >= s["peak_tip_force_N"] >= 0.0
    assert set(s["wall_indentations"]) == {"recorded", "max_mm"}
    touched = [r["target"] for r in soft.rows if r["touched"]]
    assert sorted(s["touch_wall_force_N"]) == sorted(touched)
    for total, tip in s["touch_wall_force_N"].values():
        assert s["peak_wall_force_N"] + 1e-4 >= total >= tip >= 0.0
    rigid = mc.run(task="right", targets=1, time_limit=2.0, sheath="fixed", catheter=mc.comparison_catheter())
    assert not {"wall_stiffness_N_per_m", "peak_wall_force_N", "peak_tip_force_N",
                "wall_indentations", "touch_wall_force_N"} & set(rigid.settings)
