"""Inverse statics: the smallest magnet turn that presses a wall target hard enough."""

import numpy as np
import pytest

from ballchain.drake_models.params import BallChain, newtons_from_gram_force
from ballchain.experiments import planner
from ballchain.optimization.inverse_statics import HeldTip, min_turn_orientation, pin_tip
from ballchain.optimization.statics import ChainStatics

MU = 0.1
R = 2.5e-3


@pytest.fixture(scope="module")
def setup(heart):
    chain = BallChain(n_balls=12)
    stand = planner.teleop_stand(heart, "right", chain.ball_diameter)
    m0 = planner.neutral_dipole(stand)[None, :]
    centre, axis = stand.targets["right_1"]
    solver = ChainStatics(chain, max_iterations=25)
    field_for = planner._field_for(stand)
    home = pin_tip(solver, field_for(m0), centre, None)
    assert home is not None and home.converged
    return chain, stand, solver, field_for, m0, centre, axis, home


def test_held_tip_jacobian_matches_central_differences(setup):
    _, _, solver, field_for, m0, centre, axis, home = setup
    held = HeldTip(solver, field_for, centre, axis, home)
    x = np.r_[m0.ravel(), 0.5e-3, -0.5e-3]
    F, J = held.value_and_jacobian(x)
    for i, h in ((0, 1e-4), (2, 1e-4), (3, 1e-7)):
        dx = np.zeros_like(x)
        dx[i] = h
        held.restart()
        Fp, _ = held.pressing(x + dx)
        held.restart()
        Fm, _ = held.pressing(x - dx)
        np.testing.assert_allclose(J[:, i], (Fp - Fm) / (2 * h), rtol=2e-3, atol=1e-4 * np.abs(J).max())


@pytest.mark.slow
def test_min_turn_meets_every_constraint_and_one_is_active(setup):
    chain, _, solver, field_for, m0, centre, axis, home = setup
    f_min = newtons_from_gram_force(10.0)
    held = HeldTip(solver, field_for, centre, axis, home)
    plan = min_turn_orientation(held, m0, m0, f_min, R, MU)
    assert plan.feasible, plan.solver_status
    # Independent re-check: hold the tip at the planned touch point from the planned equilibrium.
    tip = held.tip_point(plan.offset)
    again = ChainStatics(chain).solve(field_for(plan.dipoles), plan.result, tip_target=tip)
    assert again.converged
    np.testing.assert_allclose(again.tip_position, tip, atol=1e-9)
    F = held.basis.T @ (-again.tip_reaction)
    assert F[0] >= f_min * (1 - 1e-4)
    assert np.hypot(F[1], F[2]) <= MU * F[0] * (1 + 1e-3)
    assert np.linalg.norm(plan.offset) <= R * (1 + 1e-6)
    # The magnet had to turn (the neutral orientation presses too little), so at the smallest
    # turn some constraint holds it back: the force, the friction cone or the circle is active.
    assert plan.turn_rad[0] > np.radians(5)
    active = [abs(F[0] / f_min - 1) < 1e-3, abs(plan.friction_needed / MU - 1) < 1e-3,
              abs(np.linalg.norm(plan.offset) / R - 1) < 1e-3]
    assert any(active), (F, plan.friction_needed, plan.offset)


def test_bad_input_is_refused(setup):
    _, _, solver, field_for, m0, centre, axis, home = setup
    held = HeldTip(solver, field_for, centre, axis, home)
    with pytest.raises(ValueError, match="min_force"):
        min_turn_orientation(held, m0, m0, 0.0, R, MU)
    with pytest.raises(ValueError, match="friction"):
        min_turn_orientation(held, m0, m0, 0.1, R, -0.1)
    with pytest.raises(ValueError, match="non-zero"):
        min_turn_orientation(held, np.zeros((1, 3)), m0, 0.1, R, MU)
