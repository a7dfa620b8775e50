"""The compiled Newton solve (``optimization.compiled_newton``, ``ChainStatics(compiled=True)``)
against the Python solver it replaces (``compiled=False``, the reference): the same equilibria to
1e-9 m, the same multipliers to 1e-6 relative, the same iterations and the same failures, in free
space, with a tip target, a plane wall, in the heart and along a recorded teleoperation path."""

import numpy as np
import pytest

from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.field_sources import FieldSources, MagnetSource, UniformField
from ballchain.drake_models.params import BallChain, CylinderMagnet, Sleeve
from ballchain.optimization.statics import ChainStatics, rotation_path
from ballchain.optimization.wall_constraints import HeartConstraints, SheathGeometry, base_rotation, sheath_split

B23 = 0.023


def field(deg, magnitude=B23):
    return UniformField.in_plane(magnitude, np.radians(deg))


def assert_same(compiled, reference, positions_atol=1e-9, iterations=True):
    """The compiled result is the reference's: converged or not for the same reason, the same
    configuration (1e-9 m) and multipliers (1e-6 relative to the largest).

    A failure is compared by its verdict and reason only: where a failing solve stops is not an
    answer, and the two solvers' rounding can end it elsewhere (on one machine the engine's
    warm start after a sub-chain change in heart_wall_contact fails with an infeasible QP step in
    both, after 8 iterations in one and 7 in the other, 4 mm apart)."""
    assert (compiled.converged, compiled.reason) == (reference.converged, reference.reason)
    if not reference.converged:
        return
    if iterations:
        assert compiled.iterations == reference.iterations
    np.testing.assert_allclose(compiled.positions, reference.positions, rtol=0, atol=positions_atol)
    np.testing.assert_allclose(compiled.dipoles, reference.dipoles, rtol=0, atol=positions_atol / 3.175e-3)
    np.testing.assert_allclose(compiled.energy, reference.energy, rtol=1e-9, atol=1e-15)
    active = {k for k, v in reference.multipliers.items() if v > 1e-9}
    assert active == {k for k, v in compiled.multipliers.items() if v > 1e-9}
    scale = max([1e-12] + [abs(v) for v in reference.multipliers.values()])
    for k in active:
        assert abs(compiled.multipliers[k] - reference.multipliers[k]) <= 1e-6 * scale, k
    for name in ("pair_forces", "wall_forces"):
        a, b = getattr(compiled, name), getattr(reference, name)
        assert set(a) == set(b), name
        for k in b:
            assert abs(a[k] - b[k]) <= 1e-6 * max(1e-12, max(abs(x) for x in b.values())), (name, k)
    np.testing.assert_allclose(compiled.tip_reaction, reference.tip_reaction, rtol=1e-6,
                               atol=1e-6 * max(1e-12, np.abs(reference.tip_reaction).max()))
    for name in ("wall_forces_W", "sheath_forces_W"):
        a, b = getattr(compiled, name), getattr(reference, name)
        assert set(a) == set(b), name
        for k in b:
            np.testing.assert_allclose(a[k], b[k], rtol=0, atol=1e-6 * np.linalg.norm(b[k]))


def both(chain, **kw):
    return ChainStatics(chain, compiled=True, **kw), ChainStatics(chain, compiled=False, **kw)


@pytest.mark.parametrize("sleeve,gravity", [(False, False), (True, True)])
def test_free_space_continuation_matches_the_reference(sleeve, gravity):
    """A 90-degree turn of a uniform field in 22.5-degree steps, each solve warm-started from
    the last (cold for the first), with and without sleeve and gravity."""
    chain = BallChain(n_balls=10, sleeve=Sleeve() if sleeve else None)
    fast, slow = both(chain, gravity=gravity)
    a = b = None
    for angle in rotation_path(0.0, 90.0, 22.5):
        a, b = fast.solve(field(angle), a), slow.solve(field(angle), b)
        assert b.converged
        assert_same(a, b)


def test_magnets_and_their_sum_match_the_reference():
    """Point-dipole magnets (the kernels evaluate their field and its derivative) and a sum
    with a uniform field, from the straight chain."""
    chain = BallChain(n_balls=12)
    magnet = MagnetSource.pointing(CylinderMagnet(), [0.02, 0.08, 0.0], [0.0, -1.0, 0.0], "dipole")
    fast, slow = both(chain)
    for source in (magnet, FieldSources([magnet, field(45.0, 0.005)])):
        a, b = fast.solve(source), slow.solve(source)
        assert b.converged
        assert_same(a, b)


def test_tip_target_matches_the_reference():
    """The tip held on a target off its free position: the null-space step, the QP with the
    tip's equality rows and its second-order correction; the reaction is the same."""
    chain = BallChain(n_balls=10)
    fast, slow = both(chain)
    free = slow.solve(field(90.0), slow.solve(field(45.0)))
    for offset_mm in ((1.0, 0.0, 0.0), (-3.0, 2.0, 0.0), (0.0, -2.0, 1.5)):
        target = free.tip_position + 1e-3 * np.array(offset_mm)
        a, b = fast.solve(field(90.0), free, tip_target=target), slow.solve(field(90.0), free, tip_target=target)
        assert b.converged and np.linalg.norm(b.tip_reaction) > 1e-3
        assert_same(a, b)


def test_plane_wall_matches_the_reference():
    """The chain turned onto a plane wall: the wall rows' multipliers are the same pushes."""
    chain = BallChain(n_balls=8)
    wall = (np.array([0.0, 0.012, 0.0]), np.array([0.0, -1.0, 0.0]))
    fast, slow = both(chain)
    a = b = None
    for angle in rotation_path(0.0, 90.0, 22.5):
        a, b = fast.solve(field(angle), a, wall=wall), slow.solve(field(angle), b, wall=wall)
        assert_same(a, b)
    assert b.wall_forces and b.converged


def test_failures_are_the_same_failures():
    """The iteration limit, an unreachable tip target (the QP infeasible), a non-finite field
    and a field the kernels do not evaluate (the Python solver takes it) are reported alike."""
    chain = BallChain(n_balls=10)
    fast, slow = both(chain, max_iterations=1)
    a, b = fast.solve(field(90.0)), slow.solve(field(90.0))
    assert not a.converged and "iteration limit (1)" in a.reason
    assert_same(a, b)
    fast, slow = both(chain)
    far = np.array([0.1, 0.0, 0.0])  # three times the chain's length away
    a, b = fast.solve(field(90.0), tip_target=far), slow.solve(field(90.0), tip_target=far)
    assert not a.converged and a.reason == b.reason
    np.testing.assert_allclose(a.positions, b.positions, atol=1e-9)

    class NaNField:
        def field_and_gradient(self, p):
            return np.full((len(p), 3), np.nan), np.zeros((len(p), 3, 3))

    a, b = fast.solve(NaNField()), slow.solve(NaNField())
    assert not a.converged and a.reason == b.reason and "not finite" in a.reason

    class Python:  # a field source the kernels cannot evaluate: the same answer, from Python
        def field_and_gradient(self, p):
            B, G = field(60.0).field_and_gradient(p)
            return B, G

    assert_same(fast.solve(Python()), slow.solve(Python()))


def test_cold_solves_start_from_the_straight_chain_every_time():
    """The cold start and its chart are built once per solver (``ChainStatics._straight_chain``,
    ``compiled_model.run``'s ``chart0``) while the kernel re-centres its chart in place: after a
    solve that re-centres (8 balls, 5 mT antiparallel to the chain), the next cold solve is the
    same solve, as a new solver's and the Python reference's."""
    chain = BallChain(n_balls=8)
    external = field(180.0, 5e-3)
    fast = ChainStatics(chain)
    first, second, third = fast.solve(external), fast.solve(external), fast.solve(external)
    assert first.converged and first.iterations > 10
    assert first.positions.flags.writeable and first.dipoles.flags.writeable  # the caller's, not the cached start
    for other in (second, third, ChainStatics(chain).solve(external)):
        np.testing.assert_array_equal(other.positions, first.positions)
        assert other.iterations == first.iterations
    assert_same(first, ChainStatics(chain, compiled=False).solve(external))


def test_a_solvers_settings_changed_between_cold_solves_apply():
    """The free chain's kernel inputs are remembered per solver and settings: a setting changed
    after a solve applies to the next one."""
    chain = BallChain(n_balls=10)
    statics = ChainStatics(chain)
    assert statics.solve(field(90.0)).converged
    statics.max_iterations = 2
    limited = statics.solve(field(90.0))
    assert not limited.converged and "iteration limit (2)" in limited.reason
    statics.max_iterations = 200
    statics.tolerance = 1e-3  # a loose tolerance stops earlier
    loose = statics.solve(field(90.0))
    statics.tolerance = 1e-8
    tight = statics.solve(field(90.0))
    assert loose.converged and tight.converged and loose.iterations < tight.iterations


def test_compiled_is_checked():
    with pytest.raises(UserInputError, match="compiled"):
        ChainStatics(BallChain(n_balls=4), compiled="yes")


# --- in the heart ----------------------------------------------------------------------------------
def _constraints(heart, sdf, s, n=16, d=3.175e-3):
    k, a = sheath_split(n, s, d)
    sheath = SheathGeometry(heart.p_HE, heart.sheath_axis_H, 1.8e-3, 0.3e-3)
    return k, HeartConstraints(heart.p_HE + a * heart.sheath_axis_H, base_rotation(heart.sheath_axis_H), sdf,
                               sheath, n_behind=k, gravity=True)


def test_heart_insertion_matches_the_reference(heart, sdf):
    """The chain pushed into the atrium against its wall by a magnet, insertion by insertion,
    warm-started with the last solution's multipliers (as the engine does): the same
    equilibria, wall and sheath pushes."""
    chain = BallChain(n_balls=16)
    u = np.array([1.0, 0.0, 0.0])
    magnet = MagnetSource.pointing(CylinderMagnet(), heart.p_HP + 0.1651 * u, [0.0, -1.0, 0.0], "dipole")
    a = b = None
    touched = False
    for s in (0.021, 0.024, 0.027):
        k, c = _constraints(heart, sdf, s)
        fast, slow = both(chain.with_balls(16 - k), gravity=True)
        warm = None if b is None or len(b.positions) != 16 - k else b
        a, b = fast.solve(magnet, warm, constraints=c), slow.solve(magnet, warm, constraints=c)
        assert b.converged
        assert_same(a, b)
        np.testing.assert_allclose(a.positions_W, b.positions_W, atol=1e-9)
        touched |= bool(b.wall_forces_W)
    assert touched, "the chain should touch the wall"


def test_a_ball_curled_back_beside_the_sheath_has_its_wall_row(heart, sdf):
    """A free ball behind the sheath's exit plane is in the bore (no wall row: the sheath holds
    it) only within r_c of the axis; curled back beside the sheath (a chain looping towards the
    septum) it keeps its wall row, so the wall stops it. Before, any ball behind the exit plane
    lost its row, and Task II's seed 9 (the touching-rows convexification) put the tip 1.66 mm
    into the septum, 10.6 mm off the axis and 1.5 mm behind the exit plane. The reference and
    the compiled rows agree."""
    from ballchain.drake_models.kernels.heart_rows import heart_rows
    from ballchain.optimization.compiled_model import _sdf_arrays
    from ballchain.optimization.wall_constraints import ConstrainedChain, RHO_SMOOTHING

    k, c = _constraints(heart, sdf, 0.027)
    chain = BallChain(n_balls=4)
    model = ConstrainedChain(chain)
    model.set_constraints(c)
    a_E = float((c.sheath.p_WE - c.p_WB) @ c.R_WB[:, 0])
    r_c = c.sheath.bore_radius + c.sheath.lip_radius
    # Free balls 1..3: in the bore behind the exit; beside the sheath 1.5 mm behind the exit and
    # 10.6 mm off the axis, on the side where the septum is nearest (the wall row violated
    # there); past the exit on the axis.
    angles = np.radians(np.arange(0.0, 360.0, 10.0))
    ring = np.column_stack([np.full(angles.size, a_E - 1.5e-3), 10.6e-3 * np.cos(angles), 10.6e-3 * np.sin(angles)])
    beside = ring[np.argmin(sdf(c.p_WB + ring @ c.R_WB.T, gradient=False))]
    p_B = np.array([[a_E - 1e-3, 0.1e-3, 0.0], beside, [a_E + 3e-3, 0.0, 0.0]])
    values, v, _ = model._rows(p_B, hessian=False)
    L = 3
    s_W = sdf(c.p_WB + p_B @ c.R_WB.T, gradient=False)
    assert values[0] == 10.0  # in the bore: no wall row
    np.testing.assert_allclose(values[1:L], (s_W[1:] - model.r) / model.d, rtol=1e-12)
    assert np.hypot(*p_B[1, 1:]) > r_c and values[1] < 0.0  # beside the sheath, in the wall: violated
    grid, frame = _sdf_arrays(sdf)
    sheath = np.array([1.0, a_E, r_c, model.r + c.sheath.lip_radius, RHO_SMOOTHING])
    kv, kg, _ = heart_rows(np.ascontiguousarray(p_B), np.ascontiguousarray(c.p_WB, float),
                           np.ascontiguousarray(c.R_WB, float), grid, frame, sheath, model.r, model.d, False)
    np.testing.assert_allclose(kv, values, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(kg, v, rtol=1e-12, atol=1e-12)


# --- along the engine's paths (recorded solves, replayed) ----------------------------------------
HEART_SCENARIOS = ["heart_left_quasi_static", "heart_sleeve_quasi_static", "heart_no_field", "heart_wall_contact",
                   "teleop_right_unit", "teleop_two_units"]


@pytest.mark.slow
@pytest.mark.parametrize("name", HEART_SCENARIOS)
def test_engine_paths_match_the_reference(name, monkeypatch):
    """Every equilibrium the quasi-static engine solves in a short run of each named heart
    scenario (the teleoperation ones: the magnets moved by the recorded joystick path; the
    insertion; warm-started from the last equilibrium with its multipliers), solved again by the
    compiled solve and by the Python reference with the engine's settings: the same answers."""
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import run_simulation

    from ballchain.optimization.compiled_model import HeartSolve
    from ballchain.optimization.statics import StaticsResult

    calls = []
    original, short = ChainStatics.solve, HeartSolve.solve

    def recording(self, external, warm_start=None, tip_target=None, wall=None, constraints=None):
        calls.append((self.chain, self.gravity, self.tolerance, self.feasibility_tolerance, external, warm_start,
                      constraints))
        return original(self, external, warm_start, tip_target, wall, constraints)

    def recording_short(self, field_W, constraints, p0_B, m0_B, lam0):
        # The engine's short path (HeartSolve: ChainStatics.solve's kernel call): the same problem
        # as ChainStatics.solve from this warm start (a cold start's straight chain with no
        # multipliers is the warm start None).
        s = self.statics
        warm = StaticsResult(p0_B, m0_B, 0.0, None, True, "warm start", "", 0, 0.0, multipliers=lam0 or {})
        calls.append((s.chain, s.gravity, s.tolerance, s.feasibility_tolerance, field_W, warm, constraints))
        return short(self, field_W, constraints, p0_B, m0_B, lam0)

    monkeypatch.setattr(ChainStatics, "solve", recording)
    monkeypatch.setattr(HeartSolve, "solve", recording_short)
    # 0.3 s: at least five solves after the start-up (which reuses the warm-up's equilibrium).
    run_simulation(scenario=load_scenario(name, "{engine: statics, duration: 0.3}"))
    monkeypatch.setattr(ChainStatics, "solve", original)
    monkeypatch.setattr(HeartSolve, "solve", short)
    assert len(calls) >= 5
    for chain, gravity, tolerance, feasibility, external, warm, constraints in calls:
        fast, slow = both(chain, gravity=gravity, tolerance=tolerance)
        fast.feasibility_tolerance = slow.feasibility_tolerance = feasibility
        a, b = fast.solve(external, warm, constraints=constraints), slow.solve(external, warm, constraints=constraints)
        assert_same(a, b)


def _tangent_basis(N):
    """Orthonormal basis of the null space of the rows N."""
    _, s, Vt = np.linalg.svd(N)
    return Vt[int(np.sum(s > 1e-10 * s.max())):].T


@pytest.mark.parametrize("seed", range(4))
def test_the_qp_curvature_is_the_lagrangians_along_the_rows_and_definite(seed):
    """An indefinite Lagrangian's Hessian whose negative curvature lies across the step's rows
    (as a chain pressed on the wall's, docs/performance.md 11): the QP's curvature is positive
    definite, equal to H on the rows' tangent space (the step there is the exact Newton step),
    with no eigendecomposition; the compiled and the reference functions agree."""
    from ballchain.optimization.compiled_newton import CONVEXIFY, qp_curvature
    from ballchain.optimization.statics import _qp_curvature

    rng = np.random.default_rng(seed)
    n, m = 20, 3
    A = rng.normal(size=(n, n))
    N = rng.normal(size=(m, n))
    H = A @ A.T / n + 0.1 * np.eye(n) - 5.0 * N.T @ N  # negative across the rows only
    assert np.linalg.eigvalsh(H)[0] < -1.0
    Z = _tangent_basis(N)
    assert np.linalg.eigvalsh(Z.T @ H @ Z)[0] > 0.0
    ok, Hm, Lc, definite = qp_curvature(H, N, N)  # every row touches
    assert ok and not definite
    np.testing.assert_allclose(Lc @ Lc.T, Hm, rtol=0, atol=1e-12 * np.abs(Hm).max())
    assert np.linalg.eigvalsh(Hm)[0] > 0.0
    np.testing.assert_allclose(Z.T @ Hm @ Z, Z.T @ H @ Z, rtol=0, atol=1e-12 * np.abs(H).max())
    # Hm is H + rho s N'N for one of the listed rho (s = max(1, max|H_ii|)).
    s = max(1.0, np.abs(np.diag(H)).max())
    rho = np.linalg.lstsq((N.T @ N).reshape(-1, 1) * s, (Hm - H).reshape(-1), rcond=None)[0][0]
    assert min(abs(rho / r - 1.0) for r in CONVEXIFY) < 1e-9
    np.testing.assert_allclose(_qp_curvature(H, N, N), Hm, rtol=0, atol=1e-13 * np.abs(Hm).max())


def test_the_qp_curvature_keeps_a_definite_hessian_and_flips_curvature_along_the_rows():
    """H positive definite: H itself. Negative curvature on the rows' tangent space too (no
    convexification across the rows helps): the eigenvalues' flip, as ``positive_definite``;
    the compiled and the reference functions agree."""
    from ballchain.optimization.compiled_newton import positive_definite, qp_curvature
    from ballchain.optimization.statics import _positive_definite, _qp_curvature

    rng = np.random.default_rng(7)
    n = 16
    A = rng.normal(size=(n, n))
    N = rng.normal(size=(2, n))
    H = A @ A.T / n + 0.1 * np.eye(n)
    ok, Hm, _, definite = qp_curvature(H, N[:1], N)
    assert ok and definite
    np.testing.assert_array_equal(Hm, H)
    np.testing.assert_array_equal(_qp_curvature(H, N[:1], N), H)
    Z = _tangent_basis(N)
    H = H - 3.0 * (Z[:, :1] @ Z[:, :1].T)  # negative along a tangent direction
    assert np.linalg.eigvalsh(Z.T @ H @ Z)[0] < 0.0
    ok, Hm, Lc, definite = qp_curvature(H, N[:1], N)
    assert ok and not definite
    np.testing.assert_allclose(Hm, positive_definite(H)[1], rtol=0, atol=0)
    w, V = np.linalg.eigh(H)
    np.testing.assert_allclose(Hm, (V * np.abs(w)) @ V.T, rtol=0, atol=1e-12 * np.abs(H).max())
    np.testing.assert_allclose(_qp_curvature(H, N[:1], N), _positive_definite(H), rtol=0, atol=0)
    np.testing.assert_allclose(_qp_curvature(H, N[:1], N), Hm, rtol=0, atol=1e-12 * np.abs(H).max())


def _convexified_by(H, Hm, R):
    """The rho of Hm = H + rho s R'R (s = max(1, max|H_ii|)), and how far Hm is from that."""
    s = max(1.0, np.abs(np.diag(H)).max())
    C = (R.T @ R) * s
    rho = float(np.vdot(C, Hm - H) / np.vdot(C, C))
    return rho, float(np.abs(Hm - H - rho * C).max())


@pytest.mark.parametrize("seed", range(3))
def test_the_touching_rows_convexify_first_then_every_near_row(seed):
    """The rows that touch (Nt) convexify first: negative curvature across them is removed by
    H + rho s Nt'Nt, leaving H's curvature along every other near row (which may open); negative
    curvature across a near row that does not touch needs H + rho s N'N. The compiled and the
    reference functions agree."""
    from ballchain.optimization.compiled_newton import CONVEXIFY, qp_curvature
    from ballchain.optimization.statics import _qp_curvature

    rng = np.random.default_rng(10 + seed)
    n = 18
    A = rng.normal(size=(n, n))
    N = rng.normal(size=(3, n))
    Nt = N[:2]  # rows 0 and 1 touch, row 2 is near
    base = A @ A.T / n + 0.1 * np.eye(n)
    for H, R in ((base - 5.0 * Nt.T @ Nt, Nt), (base - 5.0 * N[2:].T @ N[2:], N)):
        assert np.linalg.eigvalsh(H)[0] < 0.0
        ok, Hm, Lc, definite = qp_curvature(H, Nt, N)
        assert ok and not definite
        assert np.linalg.eigvalsh(Hm)[0] > 0.0
        np.testing.assert_allclose(Lc @ Lc.T, Hm, rtol=0, atol=1e-12 * np.abs(Hm).max())
        rho, off = _convexified_by(H, Hm, R)
        assert off < 1e-12 * np.abs(H).max()
        assert min(abs(rho / r - 1.0) for r in CONVEXIFY) < 1e-9
        np.testing.assert_allclose(_qp_curvature(H, Nt, N), Hm, rtol=0, atol=1e-13 * np.abs(Hm).max())
    # The first case keeps H's own curvature along the near row that does not touch.
    H = base - 5.0 * Nt.T @ Nt
    Hm = qp_curvature(H, Nt, N)[1]
    Zt = _tangent_basis(Nt)
    np.testing.assert_allclose(Zt.T @ Hm @ Zt, Zt.T @ H @ Zt, rtol=0, atol=1e-12 * np.abs(H).max())


def _null_space_step(H, g, J, c):
    """The pinned tip's null-space step (the solver's before section 33 of docs/performance.md),
    written out here: (dq, lam, dq' Hm dq)."""
    Z = _tangent_basis(J)
    dq_n = -np.linalg.pinv(J) @ c
    Hz = Z.T @ H @ Z
    dq = dq_n - Z @ np.linalg.solve(Hz, Z.T @ (g + H @ dq_n))
    lam = np.linalg.lstsq(J.T, g + H @ dq, rcond=None)[0]
    return dq, lam, float(dq @ (Z @ Hz @ Z.T) @ dq)


@pytest.mark.parametrize("seed", range(4))
def test_the_pinned_step_is_the_null_space_step(seed):
    """A pinned tip's Lagrangian's Hessian, indefinite in the whole space (a chain pressed by the
    magnets would buckle without its pin) and definite along the pin's tangent space: the Schur
    step of H + rho s J'J (compiled and reference) is the null-space step, its multipliers the
    KKT system's and its curvature the null-space model's, within round-off."""
    from ballchain.optimization.compiled_newton import pinned_step
    from ballchain.optimization.statics import _pinned_step

    rng = np.random.default_rng(seed)
    n, m = 40, 3
    A = rng.normal(size=(n, n))
    J = rng.normal(size=(m, n))
    H = A @ A.T / n + 0.1 * np.eye(n) - 5.0 * J.T @ J  # negative across the pin's rows only
    assert np.linalg.eigvalsh(H)[0] < -1.0
    g, c = rng.normal(size=n), 0.5 * rng.normal(size=m)
    dq0, lam0, curv0 = _null_space_step(H, g, J, c)
    ok, dq, lam, curv = pinned_step(H, g, J, c)
    assert ok
    reference = _pinned_step(H, g, J, c)
    assert reference is not None
    for dq1, lam1, curv1 in ((dq, lam, curv), reference):
        np.testing.assert_allclose(dq1, dq0, rtol=0, atol=1e-10 * np.abs(dq0).max())
        np.testing.assert_allclose(lam1, lam0, rtol=0, atol=1e-10 * np.abs(lam0).max())
        assert abs(curv1 - curv0) <= 1e-10 * abs(curv0)
        np.testing.assert_allclose(J @ dq1 + c, 0.0, atol=1e-12)  # the linearised pin
        np.testing.assert_allclose(g + H @ dq1 - J.T @ lam1, 0.0, atol=1e-9 * np.abs(g).max())  # stationary
    # The curvature is the tangent part's, not dq's own (the pin's rows carry H's negative part).
    assert abs(curv - float(dq @ H @ dq)) > 1e-6 * abs(curv)


def test_the_pinned_step_declines_a_tangent_space_that_is_not_definite():
    """Negative curvature along the pin's tangent space: no rho makes H + rho s J'J definite, so
    the Schur step declines (the solver then flips the tangent curvature, ``positive_definite``)."""
    from ballchain.optimization.compiled_newton import pinned_step
    from ballchain.optimization.statics import _pinned_step

    rng = np.random.default_rng(7)
    n, m = 30, 3
    A = rng.normal(size=(n, n))
    J = rng.normal(size=(m, n))
    Z = _tangent_basis(J)
    H = A @ A.T / n - 3.0 * np.outer(Z[:, 0], Z[:, 0])
    assert np.linalg.eigvalsh(Z.T @ H @ Z)[0] < -1.0
    g, c = rng.normal(size=n), rng.normal(size=m)
    assert not pinned_step(H, g, J, c)[0]
    assert _pinned_step(H, g, J, c) is None
