"""The planner's held solves on the compiled path and its sources built without re-validation
(issue 48): the same plan as the general solve on validated ``MagnetSource``s, every number."""

import numpy as np
import pytest

from ballchain.drake_models.field_sources import FieldSources, MagnetSource, rotation_with_z_along
from ballchain.drake_models.params import BallChain, CylinderMagnet, newtons_from_gram_force
from ballchain.experiments import planner
from ballchain.optimization import inverse_statics
from ballchain.optimization.compiled_model import field_arrays
from ballchain.optimization.statics import ChainStatics
from statics_helpers import assert_same_statics


def _validated(stand):
    magnet, p_M = CylinderMagnet(), stand.magnets["1"]
    return lambda m: FieldSources([MagnetSource(magnet, p_M, rotation_with_z_along(m.reshape(-1, 3)[0]))])


def test_field_for_is_the_validated_source(heart):
    stand = planner.teleop_stand(heart, "right", BallChain().ball_diameter)
    fast, slow = planner._field_for(stand), _validated(stand)
    rng = np.random.default_rng(4)
    points = 0.03 * rng.normal(size=(9, 3))
    for _ in range(50):
        m = rng.normal(size=(1, 3)) * rng.uniform(0.01, 10.0)
        a, b = fast(m), slow(m)
        assert all(np.array_equal(x, y) for x, y in zip(field_arrays(a), field_arrays(b)))
        assert all(np.array_equal(x, y) for x, y in zip(a.field_and_gradient(points), b.field_and_gradient(points)))
        assert np.array_equal(a.sources[0].R_WM, b.sources[0].R_WM)
    with pytest.raises(ValueError, match="direction"):
        fast(np.zeros((1, 3)))


def _plan(heart, monkeypatch, before: bool):
    if before:
        monkeypatch.setattr(inverse_statics, "held_solve",
                            lambda s, e, w, t: ChainStatics.solve(s, e, w, tip_target=t))
        monkeypatch.setattr(planner, "_field_for", _validated)
    chain = BallChain(n_balls=12)
    stand = planner.teleop_stand(heart, "right", chain.ball_diameter)
    out = planner.plan_target(chain, stand, "right_1", planner.neutral_dipole(stand), None,
                              newtons_from_gram_force(10.0), 2.5e-3, 0.1, 2, 3)
    monkeypatch.undo()
    return out


def test_plan_target_is_the_same_as_before_the_wiring(heart, monkeypatch):
    a, b = _plan(heart, monkeypatch, False), _plan(heart, monkeypatch, True)
    assert a["feasible"] and b["feasible"] and a["how"] == b["how"]
    pa, pb = a["plan"], b["plan"]
    for name in ("dipoles", "turn_rad", "offset", "force_N"):
        assert np.array_equal(np.asarray(getattr(pa, name)), np.asarray(getattr(pb, name))), name
    assert np.array_equal(pa.result.positions, pb.result.positions)
    assert np.array_equal(pa.result.tip_reaction, pb.result.tip_reaction)


def test_held_solve_is_the_general_solve_with_two_magnets():
    """Procedure's plans with two units hold the tip under two magnets: ``held_solve`` (the
    planner's path now) against ``ChainStatics.solve`` on the same sources, warm-started along
    a homotopy of the tip and the magnets' directions, every result field the same."""

    from ballchain.optimization.compiled_held_tip import held_solve

    chain = BallChain(n_balls=16)
    fast, slow = ChainStatics(chain, max_iterations=25), ChainStatics(chain, max_iterations=25)
    centres = [np.array([0.02, 0.0, 0.11]), np.array([0.03, 0.1, -0.05])]
    field = planner.field_for_centres(centres)
    m0 = np.array([[0.0, 0.2, 1.0], [0.3, -1.0, 0.1]])
    first = slow.solve(field(m0))
    assert first.converged
    a = b = first
    rng = np.random.default_rng(7)
    compared = 0
    for k in range(10):
        m = m0 + 0.05 * k * rng.standard_normal((2, 3))
        target = first.tip_position + 1e-3 * k * np.array([0.2, 0.5, -0.3])
        a, b = held_solve(fast, field(m), a, target), slow.solve(field(m), b, tip_target=target)
        assert_same_statics(a, b)
        compared += a.converged
        if not a.converged:
            a = b = first
    assert compared >= 5
