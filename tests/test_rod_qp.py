"""The catheter rod's QP on the compiled kernels (``active_set_qp.compiled_dense_qp``, the rod's
``RodStatics.qp``) against the numpy reference ``active_set_qp.dense_qp``: the same problems
solved to the same answers within round-off (not bit for bit: the kernels solve with the Cholesky
factor by triangular substitution, the reference by LU), the same infeasible and indefinite cases
refused; and the rod's equilibria on the atrium and on a frictional compliant plane the same with
either QP."""

from __future__ import annotations

import numpy as np
import pytest

from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.optimization.active_set_qp import compiled_dense_qp, dense_qp
from ballchain.optimization.rod_statics import RodStatics
from ballchain.systems.rod_wall_friction import CompliantFrictionalRodStatics
from test_catheter_wall_friction import AXIS, Plane


def _problem(seed: int, n: int, m: int, n_eq: int):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, n))
    H = X @ X.T + 0.5 * n * np.eye(n)
    A, b = rng.normal(size=(m, n)), rng.normal(size=m)
    E, e = (rng.normal(size=(n_eq, n)), rng.normal(size=n_eq)) if n_eq else (None, None)
    return H, rng.normal(size=n), A, b, E, e


@pytest.mark.parametrize("seed, n, m, n_eq", [(0, 12, 7, 2), (1, 30, 0, 0), (2, 45, 9, 0), (3, 60, 14, 3),
                                              (4, 5, 5, 1)])
def test_the_compiled_qp_is_the_reference_within_round_off(seed, n, m, n_eq):
    H, g, A, b, E, e = _problem(seed, n, m, n_eq)
    ref = dense_qp(H, g, A, b, E, e)
    got = compiled_dense_qp(H, g, A, b, E, e)
    assert ref[0] is not None and got[0] is not None
    scale = np.abs(ref[0]).max()
    np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-11 * scale)
    for r, c in zip(ref[1:], got[1:]):
        assert r.shape == c.shape
        np.testing.assert_allclose(c, r, rtol=0, atol=1e-10 * max(1.0, np.abs(r).max(initial=0.0)))
    # The KKT conditions of the compiled answer itself (a mutated kernel fails here too).
    x, lam, mu = got
    residual = H @ x + g - A.T @ lam - (0.0 if E is None else E.T @ mu)
    assert np.abs(residual).max() < 1e-9 * max(1.0, np.abs(g).max())
    assert np.all(lam >= 0.0) and np.all(A @ x + b >= -1e-9)
    np.testing.assert_allclose(lam * (A @ x + b), 0.0, atol=1e-9)
    if E is not None:
        np.testing.assert_allclose(E @ x + e, 0.0, atol=1e-9)


def test_the_compiled_qp_refuses_what_the_reference_refuses():
    H, g, _, _, _, _ = _problem(5, 8, 0, 0)
    A = np.zeros((2, 8))
    A[0, 0], A[1, 0] = 1.0, -1.0  # x_0 >= 1 and x_0 <= -1
    b = np.array([-1.0, -1.0])
    assert dense_qp(H, g, A, b)[0] is None
    assert compiled_dense_qp(H, g, A, b) == (None, None, None)
    indefinite = H - 2.0 * np.abs(np.linalg.eigvalsh(H)).max() * np.eye(8)
    with pytest.raises(np.linalg.LinAlgError):
        dense_qp(indefinite, g, A[:1], b[:1])
    with pytest.raises(np.linalg.LinAlgError):
        compiled_dense_qp(indefinite, g, A[:1], b[:1])


class _ReferenceRod(RodStatics):
    qp = staticmethod(dense_qp)


def _same_equilibrium(ref, got):
    assert ref.converged and got.converged
    assert ref.iterations == got.iterations
    np.testing.assert_allclose(got.q, ref.q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.wall_forces, ref.wall_forces, rtol=0, atol=1e-7 * max(1e-3, ref.wall_forces.max()))
    assert got.base_torque == pytest.approx(ref.base_torque, rel=1e-6, abs=1e-12)


def test_the_rod_on_the_atrium_is_the_same_with_either_qp():
    """The rigid wall (every contact a QP row): the comparison's catheter at full knob through the
    septum, pushed and twisted into the atrium's wall; the equilibria agree within 1e-9 rad."""
    from sheath_world import sheath_world

    w = sheath_world()
    cat = SteerableCatheter().validate()
    axis = w["R_S"][:, 2]
    args = (cat, np.asarray(w["heart"].p_HE, float), axis, w["sdf"])
    fast, slow = RodStatics(*args), _ReferenceRod(*args)
    assert fast.qp is compiled_dense_qp and slow.qp is dense_qp
    touching = 0
    for length in (40e-3, 70e-3, 100e-3):
        q = None
        for phi in (0.0, 1.0, 2.0, 3.0):
            ref = slow.solve(length, phi, cat.curvature(1.0), q0=q)
            got = fast.solve(length, phi, cat.curvature(1.0), q0=q)
            _same_equilibrium(ref, got)
            touching += int(ref.wall_forces.any())
            q = ref.q
    assert touching >= 4  # the rows were there to be solved


def test_the_stuck_tip_s_equality_rows_are_the_same_with_either_qp():
    """The frictional compliant wall's stick rows (the QP's equality rows, with the stuck node's
    wall row): the tip pressed into a plane (its free tip 3 mm beyond it), then pushed along it
    below the cone."""
    cat = SteerableCatheter(wall_mu=0.2, wall_stiffness=140.0).validate()
    length, kappa = 40e-3, cat.curvature(0.5)
    free = RodStatics(cat, np.zeros(3), AXIS).solve(length, 0.0, kappa)
    tip = free.pose.tip_centre
    n = -np.array([tip[0], tip[1], 0.0]) / np.hypot(tip[0], tip[1])
    wall = Plane(n, -(n @ tip) - 3e-3 + cat.radius)

    class Reference(CompliantFrictionalRodStatics):
        qp = staticmethod(dense_qp)

    rods = CompliantFrictionalRodStatics(cat, np.zeros(3), AXIS, wall), Reference(cat, np.zeros(3), AXIS, wall)
    rests = [rod.solve(length, 0.0, kappa, q0=free.q) for rod in rods]
    _same_equilibrium(rests[1], rests[0])
    assert rests[1].indentation[-1] > 0.1e-3
    pushed = []
    for rod, rest in zip(rods, rests):
        rod.anchors, rod.last_nodes = rest.anchors, rest.last_nodes
        pushed.append(rod.solve(length, 0.0, kappa, q0=rest.q, force=0.3 * 0.2 * float(rest.wall_forces[-1]) * AXIS))
    _same_equilibrium(pushed[1], pushed[0])
    assert np.abs(pushed[1].friction[-1]).max() > 0.0  # the stick rows carried the push
