"""The held tip's analytic sensitivities (issue 48): the implicit function theorem on the held
equilibrium's KKT system (``optimization.held_sensitivity``) against central differences of
converged held equilibria, its compiled parts against numpy references, and the planner's
hardest-press searches on the compiled held solve (the same floats as the general solve)."""

import numpy as np
import pytest

from ballchain.drake_models.dipole_inversion import neutral_direction
from ballchain.drake_models.field_sources import FieldSources, MagnetSource, UniformField, rotation_with_z_along
from ballchain.drake_models.kernels import chart_frames, chart_vectors, configuration_vectors
from ballchain.drake_models.params import BallChain, CylinderMagnet
from ballchain.experiments import forces, planner
from ballchain.infrastructure.errors import UserInputError
from ballchain.optimization.compiled_sensitivity import (KKT_CURVATURE, KKT_OK, KKT_RANK, kkt_solve,
                                                         moment_columns)
from ballchain.optimization.held_sensitivity import reaction_sensitivity
from ballchain.optimization.inverse_statics import HeldTip, _predicted, pin_tip
from ballchain.optimization.reduced_chain import ReducedChain
from ballchain.optimization.statics import ChainStatics
from ballchain.optimization.wall_constraints import PointDipoles

# Central differences of held equilibria, each solved from an equilibrium a turn of a few
# degrees and 0.2 mm of touch away (several Newton steps: a solve warm-started a step of 1e-6
# away stops after one step, the decrease it predicts below its test, and its multiplier is that
# step's estimate, off by 3e-4 of the derivative here). Steps: 1e-6 for the direction rows,
# 1e-7 m for the touch offset (differences there agree with the law to 1e-8 of |J|).
STEP_M, STEP_O = 1e-6, 1e-7
TOLERANCE = 1e-6  # of the Jacobian's norm; the forward differences the planner used are off by 1e-5


def _held(heart, n_balls: int, target: str, two: bool):
    chain = BallChain(n_balls=n_balls)
    stand = planner.teleop_stand(heart, "right", chain.ball_diameter)
    centres = [stand.magnets["1"]]
    if two:  # a second unit mirrored across the statics frame's x-z plane
        centres.append(stand.magnets["1"] * np.array([1.0, -1.0, 1.0]))
    field_for = planner.field_for_centres(centres)
    m0 = np.array([neutral_direction(c, np.zeros(3), np.array([1.0, 0.0, 0.0])) for c in centres])
    centre, axis = stand.targets[target]
    solver = ChainStatics(chain, max_iterations=25)
    home = pin_tip(solver, field_for(m0), centre, None)
    assert home is not None and home.converged
    return HeldTip(solver, field_for, centre, axis, home, len(centres)), m0


def _central(held: HeldTip, x: np.ndarray) -> np.ndarray:
    away = np.r_[np.tile([0.03, -0.03, 0.03], held.k), 2e-4, -2e-4]
    held.restart()
    start = held.equilibrium(x + away)
    assert start is not None
    J = np.zeros((3, x.size))
    for i in range(x.size):
        h = STEP_M if i < 3 * held.k else STEP_O
        e = np.zeros_like(x)
        e[i] = h
        held._last = start
        Fp, _ = held.pressing(x + e)
        held._last = start
        Fm, _ = held.pressing(x - e)
        J[:, i] = (Fp - Fm) / (2 * h)
    return J


@pytest.mark.parametrize("n_balls, target, two, turn, offset", [
    (12, "right_1", False, 0.0, (0.0, 0.0)),  # one magnet, the target's centre, unit rows
    (12, "right_1", False, 0.1, (0.5e-3, -0.5e-3)),  # raw rows (not unit), an offset
    (16, "right_9", False, 0.1, (-0.8e-3, 0.3e-3)),
    (12, "right_1", True, 0.1, (0.5e-3, -0.5e-3)),  # two magnets
])
def test_the_analytic_jacobian_is_the_central_differences(heart, n_balls, target, two, turn, offset):
    held, m0 = _held(heart, n_balls, target, two)
    x = np.r_[(1.3 * m0 + turn * np.array([0.0, 1.0, 0.0])).ravel(), offset]
    F, J = held.value_and_jacobian(x)
    assert held.jacobians == {"analytic": 1, "fd": 0}
    J_c = _central(held, x)
    err = np.abs(J - J_c).max()
    assert err <= TOLERANCE * np.linalg.norm(J_c), (err, np.linalg.norm(J_c))
    # The directions' length does not matter: no derivative along the rows.
    for j in range(held.k):
        assert np.abs(J[:, 3 * j:3 * j + 3] @ x[3 * j:3 * j + 3]).max() <= 1e-9 * np.linalg.norm(J)
    # The forward differences (the fallback) agree to their own error only.
    held.restart()
    F_fd, J_fd = held.value_and_jacobian(x, method="fd")
    np.testing.assert_array_equal(F_fd, F)
    assert np.abs(J_fd - J_c).max() <= 1e-3 * np.linalg.norm(J_c)
    assert held.jacobians == {"analytic": 1, "fd": 1}


def _folded():
    """An 8-ball chain with its tip held near the sheath, two non-adjacent balls pressed
    together (an active rigidity row), under a uniform field and a point-dipole magnet."""
    chain = BallChain(n_balls=8)
    d = chain.ball_diameter
    solver = ChainStatics(chain, max_iterations=200)
    centre = np.array([0.02, 0.09, 0.0])
    moment = CylinderMagnet().dipole_moment * np.array([0.0, 0.6, 0.8])
    B0 = UniformField.in_plane(0.005, np.radians(90.0)).B_W

    def field(m):
        return PointDipoles(centre[None], m[None], B0)

    target = np.array([1.0, 1.0, 0.0]) * d
    return solver, field, moment, target


def _held_equilibrium(solver, external, target):
    return pin_tip(solver, external, target, None, steps=30)


def test_the_sensitivities_with_a_contact_row_are_the_central_differences():
    solver, field, moment, target = _folded()
    result = _held_equilibrium(solver, field(moment), target)
    assert result is not None and result.converged
    assert any(v > 1e-3 for v in result.multipliers.values()), result.multipliers  # a contact row holds
    dR_dm, dR_dt = reaction_sensitivity(solver, field(moment), result, target)
    h_m, h_t = 1e-6 * np.linalg.norm(moment), 1e-8
    for c in range(3):
        e = np.zeros(3)
        e[c] = h_m
        col = (_held_equilibrium(solver, field(moment + e), target).tip_reaction
               - _held_equilibrium(solver, field(moment - e), target).tip_reaction) / (2 * h_m)
        assert np.abs(col - dR_dm[:, c]).max() <= TOLERANCE * np.linalg.norm(dR_dm), (c, col, dR_dm[:, c])
        e = np.zeros(3)
        e[c] = h_t
        col = (_held_equilibrium(solver, field(moment), target + e).tip_reaction
               - _held_equilibrium(solver, field(moment), target - e).tip_reaction) / (2 * h_t)
        assert np.abs(col - dR_dt[:, c]).max() <= TOLERANCE * np.linalg.norm(dR_dt), (c, col, dR_dt[:, c])


def test_moment_columns_are_the_numpy_chain_rule(heart):
    """The kernel's columns against ``ReducedChain(backend="numpy")`` (``chain_energy``'s field
    energy and the dense chain rule): the gradient under each source's moment along each axis
    less the gradient without it."""
    held, _ = _held(heart, 12, "right_1", True)
    p, m = held.home.positions, held.home.dipoles
    chain, model = held.solver.chain, held.solver._model
    centres = np.array([s.p_WM for s in held.field_for(np.eye(3)[:2]).sources])
    r2 = np.zeros(len(centres))
    V = chart_vectors(np.zeros(model.nq), *chart_frames(configuration_vectors(p, m)))
    violation, C = moment_columns(V, p, m, model._params, centres, r2)
    assert violation == -1

    def gradient(external):
        reference = ReducedChain(chain, external, gravity=False, backend="numpy")
        reference.chart_from_configuration(p, m)
        return reference.evaluate(np.zeros(reference.nq), 1).gradient

    size = CylinderMagnet().dipole_moment  # a magnet's moment: the difference keeps its digits
    without = gradient(None)
    for j, c in np.ndindex(len(centres), 3):
        reference = (gradient(PointDipoles(centres[j:j + 1], size * np.eye(3)[c:c + 1])) - without) / size
        assert np.abs(C[:, 3 * j + c] - reference).max() <= 1e-9 * np.abs(reference).max(), (j, c)
    # A ball inside a source's bounding sphere is reported, not differentiated.
    assert moment_columns(V, p, m, model._params, p[3:4] + 1e-4, np.array([1e-6]))[0] == 3


def test_kkt_solve_is_numpy_and_refuses_singular_systems():
    rng = np.random.default_rng(7)
    n, r, k = 20, 4, 5
    Q = rng.normal(size=(n, n))
    H = Q @ Q.T + 0.1 * np.eye(n)
    A = rng.normal(size=(r, n))
    top, bottom = rng.normal(size=(n, k)), rng.normal(size=(r, k))
    status, x, y = kkt_solve(H, A, top, bottom, 1e-10, 1e-9)
    assert status == KKT_OK
    K = np.block([[H, A.T], [A, np.zeros((r, r))]])
    ref = np.linalg.solve(K, np.vstack([top, bottom]))
    np.testing.assert_allclose(np.vstack([x, y]), ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    # Indefinite H, positive definite on A's null space: a regular system.
    H_ind = H - (A.T @ A) * 50.0
    assert np.linalg.eigvalsh(H_ind)[0] < 0
    assert kkt_solve(H_ind, A, top, bottom, 1e-10, 1e-9)[0] == KKT_OK
    # Degenerate rows, curvature negative on the null space: refused.
    assert kkt_solve(H, np.vstack([A, A[:1]]), top, np.vstack([bottom, bottom[:1]]), 1e-10, 1e-9)[0] == KKT_RANK
    assert kkt_solve(-H, A, top, bottom, 1e-10, 1e-9)[0] == KKT_CURVATURE


def test_a_field_the_kernels_do_not_evaluate_falls_back_to_differences(heart):
    held, m0 = _held(heart, 12, "right_1", False)
    stand = planner.teleop_stand(heart, "right", held.solver.chain.ball_diameter)
    magnet, p_M = CylinderMagnet(), stand.magnets["1"]
    held.field_for = lambda m: FieldSources([MagnetSource(magnet, p_M, rotation_with_z_along(m[0]), "exact")])
    assert reaction_sensitivity(held.solver, held.field_for(m0), held.home, held.centre) is None
    x = np.r_[m0.ravel(), 0.0, 0.0]
    F, J = held.value_and_jacobian(x)
    assert F is not None and held.jacobians == {"analytic": 0, "fd": 1}
    with pytest.raises(UserInputError, match="method must be 'analytic' or 'fd', got 'exact'"):
        held.value_and_jacobian(x, method="exact")


def test_hardest_press_on_the_compiled_held_solve_is_the_general_solve(heart, monkeypatch):
    """``forces.max_normal_force`` holds the tip through ``held_solve``: the same floats as
    ``ChainStatics.solve``; the planner keeps its last searches (the same answer again)."""
    chain = BallChain(n_balls=12)
    stand = planner.teleop_stand(heart, "right", chain.ball_diameter)
    fast = forces.max_normal_force(chain, stand, "right_4", ("1",), 2, 8)
    monkeypatch.setattr(forces, "held_solve", lambda s, e, w, t: ChainStatics.solve(s, e, w, tip_target=t))
    general = forces.max_normal_force(chain, stand, "right_4", ("1",), 2, 8)
    monkeypatch.undo()
    assert fast["force_N"] is not None and fast["evaluations"] == general["evaluations"]
    assert fast["force_N"] == general["force_N"]
    np.testing.assert_array_equal(fast["angles_rad"], general["angles_rad"])
    for name in ("positions", "dipoles", "tip_reaction"):
        np.testing.assert_array_equal(getattr(fast["result"], name), getattr(general["result"], name))
    planner._HARDEST.clear()
    kept = planner._hardest_press(chain, stand, "right_4", 2, 8)
    assert kept["force_N"] == fast["force_N"] and planner._hardest_press(chain, stand, "right_4", 2, 8) is kept
    assert planner._hardest_press(chain, stand, "right_4", 2, 9) is not kept  # another effort: searched again


def test_the_tangent_predicts_the_next_held_equilibrium_to_second_order(heart):
    """``pressing_sensitivity``'s dq/dx: the configuration it predicts a step away is off by
    O(step^2) (halving the step quarters the error) and far closer than the equilibrium it
    starts from; the held solve from it finds the same equilibrium as from there."""
    held, m0 = _held(heart, 12, "right_1", True)
    x = np.r_[(1.3 * m0 + 0.1 * np.array([0.0, 1.0, 0.0])).ravel(), 0.5e-3, -0.5e-3]
    held.value_and_jacobian(x)
    base = held._last
    direction = np.r_[np.tile([0.02, -0.03, 0.01], held.k), 1e-4, 2e-4]
    errors = []
    for s in (1.0, 0.5):
        guess = _predicted(held.solver, held._tangent, x + s * direction)
        held._last, held.predict = base, False
        _, truth = held.pressing(x + s * direction)
        errors.append(np.abs(guess.positions - truth.positions).max())
        assert errors[-1] < 0.05 * np.abs(base.positions - truth.positions).max()
        held._last, held.predict = base, True  # the tangent is still base's
        _, predicted = held.pressing(x + s * direction)
        np.testing.assert_allclose(predicted.positions, truth.positions, rtol=0, atol=1e-9)
        np.testing.assert_allclose(predicted.tip_reaction, truth.tip_reaction, rtol=0,
                                   atol=1e-7 * np.abs(truth.tip_reaction).max())
    assert 3.0 < errors[0] / errors[1] < 5.0, errors
