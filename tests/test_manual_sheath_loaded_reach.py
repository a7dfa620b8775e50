"""The loaded curves' reach (``benchmarks/manual_sheath_reach.py --loaded``, issue 45: the loop or
prolapse against the wall): its bookkeeping over the force limits, and its rows against the rod's
statics solved again independently."""

from __future__ import annotations

import numpy as np
import pytest

from ballchain.drake_models.atrium_sdf import atrium_sdf
from ballchain.drake_models.electrode import CATHETER_ELECTRODE_LENGTH, axis_start
from ballchain.drake_models.sheath import SteerableSheath
from ballchain.experiments import manual_catheter as mc
from ballchain.optimization.rod_statics import RodStatics
from ballchain.systems.station import atrium_for
from ballchain.systems.target_contact import heart_targets, targets_touched
from script_helpers import load_benchmark

TARGETS = ["right_15", "right_16", "right_17"]


@pytest.fixture(scope="module")
def reach():
    module = load_benchmark("manual_sheath_reach")
    heart = atrium_for(mc.scenario_for())
    return module, heart, atrium_sdf(heart), SteerableSheath().validate()


def _resolve(heart, sdf, row):
    """The row's equilibrium reached again as the benchmark reaches it (pushed out from 6 mm in
    3 mm), on a fresh rod at the fixed exit: (wall force [N], misses [m] per TARGETS, 0 a touch)."""
    cat = mc.comparison_catheter()
    rod = RodStatics(cat, heart.p_HE, heart.sheath_axis_H, sdf)
    twist, kappa = np.radians(row["twist_deg"]), cat.curvature(row["knob"])
    q = None
    for out in np.arange(6e-3, row["out_mm"] * 1e-3 + 1e-9, 3e-3):
        sol = rod.solve(out, twist, kappa, q0=q)
        q = sol.q
    names, p_WT, n_W, radius = heart_targets(heart)
    ks = [names.index(t) for t in TARGETS]
    c = sol.pose.tip_centre
    a = axis_start(c, sol.pose.tip_direction, cat.radius, CATHETER_ELECTRODE_LENGTH)
    touch = targets_touched(c, p_WT[ks], n_W[ks], cat.radius, radius, axis_start=a)
    return float(sol.wall_forces.sum()), np.where(touch, 0.0, mc.touch_miss(c, p_WT[ks], n_W[ks], cat.radius, radius))


def test_free_rod_rows_have_no_force_and_the_unloaded_miss(reach):
    """Pushed out only as far as the rod stays off the wall (30 mm at this twist and knob), every
    limit's row is the same equilibrium, with no wall force, and its miss is the rod's own."""
    module, heart, sdf, sheath = reach
    out = module.loaded_reach(heart, sdf, sheath, [(sheath.nominal_advance, 0.0, 0.0)], TARGETS,
                              [np.radians(210.0)], [1.0], max_out=30e-3)
    assert out["solves"] == 9 and out["not_converged"] == 0
    for j, t in enumerate(TARGETS):
        rows = out["targets"][t]
        assert {r["wall_force_N"] for r in rows.values()} == {0.0}
        assert len({(r["miss_mm"], r["out_mm"]) for r in rows.values()}) == 1
        force, miss = _resolve(heart, sdf, rows["any"])
        assert force == 0.0
        assert rows["any"]["miss_mm"] == pytest.approx(miss[j] * 1e3, abs=0.006)


# (22 loaded rod solves, 3.5 CPU-s: the full suite; the free rows' check stays quick)
@pytest.mark.slow
def test_loaded_rows_keep_their_force_limits_and_match_the_rods_statics(reach):
    """Pushed on until the shaft bears on the wall (the fixed exit, the D curve, 69 mm: a loop):
    each limit's row has a wall force within it, a looser limit never misses by more, and the
    'any' row's equilibrium solved again has its force and its miss."""
    module, heart, sdf, sheath = reach
    out = module.loaded_reach(heart, sdf, sheath, [(sheath.nominal_advance, 0.0, 0.0)], TARGETS,
                              [np.radians(210.0)], [1.0], max_out=69e-3)
    assert out["solves"] == 22
    forces = []
    for j, t in enumerate(TARGETS):
        rows = out["targets"][t]
        misses = [rows[k]["miss_mm"] for k in ("0.39", "1.0", "2.0", "any")]
        assert misses == sorted(misses, reverse=True)
        for key, bound in zip(("0.39", "1.0", "2.0"), module.WALL_FORCE_LIMITS):
            assert rows[key]["wall_force_N"] <= bound
        force, miss = _resolve(heart, sdf, rows["any"])
        assert rows["any"]["wall_force_N"] == pytest.approx(force, abs=1e-3)
        assert rows["any"]["miss_mm"] == pytest.approx(miss[j] * 1e3, abs=0.006)
        forces.append(rows["any"]["wall_force_N"])
    assert max(forces) > 1.0  # the loop bears on the wall (2.55 N at 69 mm, measured)
