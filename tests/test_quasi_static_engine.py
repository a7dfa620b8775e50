"""The statics in the heart (wall and sheath rows, frictionless multipliers) and the quasi-static
engine against the MultibodyPlant."""

from pathlib import Path

import numpy as np
import pytest

from ballchain.drake_models.chain_energy import chain_energy
from ballchain.drake_models.field_sources import MagnetSource
from ballchain.drake_models.params import BallChain, CylinderMagnet
from ballchain.optimization.statics import ChainStatics, dense_qp
from ballchain.optimization.wall_constraints import (
    ConstrainedChain,
    HeartConstraints,
    SheathGeometry,
    base_rotation,
    sheath_split,
)


def _left_magnet(heart):
    u = np.array([1.0, 0.0, 0.0])
    return MagnetSource.pointing(CylinderMagnet(), heart.p_HP + 0.1651 * u, [0.0, -1.0, 0.0], "dipole")


def _constraints(heart, sdf, s, n=16, d=3.175e-3):
    k, a = sheath_split(n, s, d)
    sheath = SheathGeometry(heart.p_HE, heart.sheath_axis_H, 1.8e-3, 0.3e-3)
    return k, HeartConstraints(heart.p_HE + a * heart.sheath_axis_H, base_rotation(heart.sheath_axis_H), sdf,
                               sheath, n_behind=k, gravity=True)


def test_sheath_split_follows_the_feeder():
    d = 3.175e-3
    # At s = 0 the tip's centre is half a ball behind the exit: everything is held.
    assert sheath_split(16, 0.0, d) == (15, pytest.approx(-0.5 * d))
    k, a = sheath_split(16, 0.02, d)
    assert k == 9 and -d < a <= 0.0
    assert np.isclose(0.02 - (16 - 0.5 - k) * d, a)


def test_dense_qp_matches_the_kkt_conditions():
    rng = np.random.default_rng(0)
    n, m = 12, 7
    A0 = rng.normal(size=(n, n))
    H = A0 @ A0.T + n * np.eye(n)
    g = rng.normal(size=n)
    A = rng.normal(size=(m, n))
    b = rng.normal(size=m)
    E = rng.normal(size=(2, n))
    e = rng.normal(size=2)
    x, lam, mu = dense_qp(H, g, A, b, E, e)
    np.testing.assert_allclose(H @ x + g - A.T @ lam - E.T @ mu, 0.0, atol=1e-9)
    assert np.all(A @ x + b >= -1e-9) and np.all(lam >= 0)
    np.testing.assert_allclose(lam * (A @ x + b), 0.0, atol=1e-9)  # complementarity
    np.testing.assert_allclose(E @ x + e, 0.0, atol=1e-9)
    # Infeasible rows (x_0 >= 1 and x_0 <= -1) are reported, not hidden.
    A2 = np.zeros((2, n))
    A2[0, 0], A2[1, 0] = 1.0, -1.0
    assert dense_qp(H, g, A2, np.array([-1.0, -1.0]))[0] is None


def test_dense_qp_steps_along_a_soft_mode():
    """A step's QP the engine reported infeasible (the right ring with the navigator's
    ``average`` 8, seed 1, t = 173.6 s: the whole chain out, the tip on the wall; Python and
    compiled alike): one wall row (|A| = 3.06) and H nearly singular (eigenvalues 2.1e-6 to 7.5),
    so the dual's regularisation 1e-13 trace(M) = 1.5e-7 left the row at -3.8e-8, below the
    1e-8 tolerance. Feasible (one non-zero row always is): solved to the KKT conditions, by the
    reference and by the compiled kernel alike."""
    from ballchain.drake_models.kernels.dense_qp import cholesky
    from ballchain.drake_models.kernels.dense_qp import dense_qp as compiled_qp

    data = np.load(Path(__file__).parent / "data" / "qp_soft_mode.npz")
    H, g, A, b = data["H"], data["g"], data["A"], data["b"]
    x, lam, _ = dense_qp(H, g, A, b)
    assert x is not None
    np.testing.assert_allclose(H @ x + g - A.T @ lam, 0.0, atol=1e-9)
    assert np.all(A @ x + b >= -1e-9) and np.all(lam > 0)  # the row active, met
    ok, L = cholesky(H)
    assert ok
    ok, x_c, y_c = compiled_qp(L, g, A, b, 1, 200)
    assert ok
    # Different solves of H: round-off along the soft mode is about eps |g| / 2.1e-6 = 4e-11.
    np.testing.assert_allclose(x_c, x, rtol=0, atol=2e-10)
    np.testing.assert_allclose(y_c, lam, rtol=1e-9)


@pytest.mark.slow  # the atrium's SDF: about 30 s to build when it is not cached yet
def test_row_derivatives_match_finite_differences(heart, sdf):
    chain = BallChain(n_balls=16)
    k, c = _constraints(heart, sdf, 0.024)
    model = ConstrainedChain(chain.with_balls(16 - k))
    model.set_constraints(c)
    model.external = c.external_in_base(_left_magnet(heart), chain)
    rng = np.random.default_rng(3)
    p0 = np.arange(16 - k)[:, None] * chain.ball_diameter * np.array([1.0, 0.0, 0.0])
    model.chart_from_configuration(p0, np.tile([1.0, 0.0, 0.0], (16 - k, 1)))
    q = 0.05 * rng.normal(size=model.nq)
    ev = model.evaluate(q, 2)
    h = 1e-6
    rows = np.arange(model.n_pairs, len(ev.gaps))
    for j in rng.choice(model.nq, 8, replace=False):
        e = np.zeros(model.nq)
        e[j] = h
        plus, minus = model.evaluate(q + e, 1), model.evaluate(q - e, 1)
        np.testing.assert_allclose(ev.gradient[j], (plus.energy - minus.energy) / (2 * h), rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(ev.jacobian[rows, j], (plus.gaps[rows] - minus.gaps[rows]) / (2 * h),
                                   rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(ev.hessian[:, j], (plus.gradient - minus.gradient) / (2 * h), rtol=1e-5, atol=1e-5)
        weights = rng.uniform(0.1, 1.0, len(rows))
        Hc = model.constraint_hessian(q, rows, weights)
        fd = (plus.jacobian[rows].T @ weights - minus.jacobian[rows].T @ weights) / (2 * h)
        np.testing.assert_allclose(Hc[:, j], fd, rtol=1e-4, atol=1e-4)


@pytest.mark.slow
def test_heart_statics_multipliers_balance_every_sub_chain(heart, sdf):
    """In contact with the wall, the frictionless wall and sheath pushes (the multipliers) with
    the magnetic forces and gravity leave every sub-chain beyond a held or free ball in moment
    balance about that ball's centre, and every free dipole without torque; the free balls stay
    a radius inside the lumen."""
    chain = BallChain(n_balls=16)
    d = chain.ball_diameter
    source = _left_magnet(heart)
    k, c = _constraints(heart, sdf, 0.027)
    result = ChainStatics(chain.with_balls(16 - k), gravity=True).solve_or_raise(source, constraints=c)
    assert result.wall_forces_W, "the chain should touch the wall"
    p, m = c.full_configuration(result.positions, result.dipoles, d)
    _, dU_dp, dU_dm, _ = chain_energy(chain, p, m, source, gravity=True, base_direction=heart.sheath_axis_H)
    F, tau = -dU_dp, np.cross(m, -dU_dm)
    for b, f in list(result.wall_forces_W.items()) + list(result.sheath_forces_W.items()):
        F[k + b] += f
    # The wall pushes along the inward normal (frictionless).
    for b, f in result.wall_forces_W.items():
        n = sdf(p[k + b][None])[1][0]
        np.testing.assert_allclose(f / np.linalg.norm(f), n / np.linalg.norm(n), atol=1e-9)
    assert np.all(sdf(p[k + 1:], gradient=False) >= 0.5 * d - 1e-7 * d)
    scale = np.abs(F[k:]).max() * d
    np.testing.assert_allclose(tau[k + 1:], 0.0, atol=1e-6 * scale)
    for j in range(k, 15):
        moment = np.sum(np.cross(p[j + 1:] - p[j], F[j + 1:]) + tau[j + 1:], axis=0)
        np.testing.assert_allclose(moment, 0.0, atol=1e-6 * scale)


def test_engine_solves_the_tip_on_the_wall_along_a_soft_mode(heart, sdf):
    """The failing solve of ``test_dense_qp_steps_along_a_soft_mode`` in its engine: the right
    ring (navigator ``average`` 8, seed 1) stopped at t = 173.6 s, s = 49.21 mm, on "QP step
    infeasible" from the prediction, the last equilibrium and the straight chain, compiled and
    Python alike. Now both reach the same local minimum, the tip on the wall."""
    from ballchain.systems.quasi_static_engine import QuasiStaticEngine

    data = np.load(Path(__file__).parent / "data" / "engine_soft_mode.npz")
    sheath = SheathGeometry(heart.p_HE, heart.sheath_axis_H, 1.8e-3, 0.3e-3)
    answers = []
    for compiled in (True, False):
        engine = QuasiStaticEngine(BallChain(n_balls=16), range(1, 17), heart.p_HE, heart.sheath_axis_H, sdf=sdf,
                                   sheath=sheath, port_magnets=[CylinderMagnet()], period=0.05,
                                   initial_inserted_length=0.02, compiled=compiled)
        p, m, result, k = engine.equilibrium(float(data["s"]), data["magnets"], data["p_W"], data["m_W"],
                                             (data["predicted_p"], data["predicted_m"]))
        assert k == 0 and result.converged and result.reason.startswith("local minimum")
        assert result.positions.shape[0] - 1 in result.wall_forces_W  # the tip on the wall
        answers.append(p)
    np.testing.assert_allclose(answers[0], answers[1], rtol=0, atol=1e-9)


# --- the engine as a system -----------------------------------------------------------------------
def _engine_diagram(name, overrides):
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation

    return MakeStation(load_scenario(name, "{engine: statics, " + overrides.strip()[1:-1] + "}"))


@pytest.mark.slow
def test_engine_ports_outputs_and_a_short_run():
    """Ports and sizes; the published poses are the chain's state (dipoles along body x, the
    plant's BodyIndex values); the chain is in equilibrium at initialisation and, pushed by the
    feeder, moves by the inserted length at the sheath and stays a radius inside the lumen."""
    cd = _engine_diagram("heart_left_quasi_static", "{duration: 0.2}")
    engine = cd.chain.engine_system
    assert [engine.get_input_port(i).get_name() for i in range(engine.num_input_ports())] == ["feeder_desired_state"]
    assert engine.get_feeder_state_input_port().size() == 2
    assert [engine.get_output_port(i).get_name() for i in range(engine.num_output_ports())] == [
        "body_poses", "tip_wall_force", "ball_positions", "snap_throughs"]
    from pydrake.systems.analysis import Simulator

    sim = Simulator(cd.diagram)
    sim.Initialize()
    ctx = engine.GetMyContextFromRoot(sim.get_context())
    p0 = engine.ball_positions(ctx).copy()
    poses = engine.get_body_poses_output_port().Eval(ctx)
    for i, index in enumerate(cd.chain.ball_body_indices):
        np.testing.assert_allclose(poses[int(index)].translation(), p0[i], atol=1e-15)
    d = cd.chain.config.chain.ball_diameter
    np.testing.assert_allclose(np.linalg.norm(np.diff(p0, axis=0), axis=1), d, rtol=1e-9)  # touching
    m0 = np.array([poses[int(i)].rotation().matrix()[:, 0] for i in cd.chain.ball_body_indices])
    sim.AdvanceTo(0.201)  # past the update at 0.2 s: the feeder moved 3 mm (from 0.05 s at 20 mm/s)
    p1 = engine.ball_positions(ctx)
    s0, s1 = 0.02, 0.02 + 0.02 * 0.15
    # The balls still in the sheath move along its axis by exactly the feeder's travel.
    np.testing.assert_allclose(p1[0] - p0[0], (s1 - s0) * cd.chain.sheath_axis_W, atol=1e-12)
    assert np.linalg.norm(p1[-1] - p0[-1]) > 1e-3  # the tip moved
    free = ~cd.chain.in_sheath(p1)
    assert np.all(cd.chain.engine_system._sdf(p1[free], gradient=False) >= 0.5 * d - 1e-6 * d)
    assert np.all(cd.heart.contains(p1) | cd.chain.in_sheath(p1))
    assert np.allclose(np.linalg.norm(m0, axis=1), 1.0)


def _settled_plant_from(cd_engine, scenario_name, overrides, duration, from_engine: bool):
    """The plant of the same scenario, started at the engine's equilibrium (``from_engine``) or
    straight out of the sheath (its default), run for ``duration``: (ball centres (n, 3),
    largest ball speed at the end [m/s], the plant's tip wall force (3,) [N], the engine's ball
    centres (n, 3), the engine's tip wall force (3,))."""
    from pydrake.math import RigidTransform, RotationMatrix
    from pydrake.systems.analysis import Simulator

    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation, _tip_wall_force
    from ballchain.systems.quasi_static_engine import rotations_with_x_along

    sim_e = Simulator(cd_engine.diagram)
    sim_e.Initialize()
    ctx_e = cd_engine.chain.engine_system.GetMyContextFromRoot(sim_e.get_context())
    x = cd_engine.chain.engine_system.state_vector(ctx_e)
    n = cd_engine.chain.n_balls
    p_e, m_e = x[: 3 * n].reshape(n, 3), x[3 * n: 6 * n].reshape(n, 3)
    cd = MakeStation(load_scenario(scenario_name, overrides))
    sim = Simulator(cd.diagram)
    plant = cd.chain.plant
    ctx = plant.GetMyMutableContextFromRoot(sim.get_mutable_context())
    R = rotations_with_x_along(m_e)
    # Neighbours 4 um into each other, as chain_plant starts them: SAP's contact constraint
    # needs the pair in contact (exactly touching, 2 N of attraction slams them together).
    d = cd.chain.config.chain.ball_diameter
    links = np.diff(p_e, axis=0) * (1.0 - 4e-6 / d)
    p_start = p_e[0] + np.vstack([np.zeros(3), np.cumsum(links, axis=0)])
    for i, body in enumerate(cd.chain.ball_bodies[1:], start=1):
        if from_engine:
            plant.SetFreeBodyPose(ctx, body, RigidTransform(RotationMatrix(R[i]), p_start[i]))
    sim.Initialize()
    sim.AdvanceTo(duration)
    speeds = [np.linalg.norm(plant.EvalBodySpatialVelocityInWorld(ctx, b).translational())
              for b in cd.chain.ball_bodies]
    f_e = x[6 * n: 6 * n + 3]
    return cd.chain.ball_positions(ctx), float(max(speeds)), np.array(_tip_wall_force(cd, sim.get_context())), p_e, f_e


@pytest.mark.slow
@pytest.mark.parametrize("name, overrides, contact, from_engine, duration", [
    # 15 mm inserted, the magnet on the left: no ball touches the wall. The plant settles slowly
    # here (weak field, heavy damping: ~2 s from straight), so it starts at the engine's shape.
    ("heart_left_quasi_static", "{insertion: {initial: 0.015, final: 0.015}, contact: {friction: 0.0}}", False,
     True, 1.0),
    # 30 mm inserted, 30 mT upwards: the tip presses on the roof. From the engine's shape the
    # plant's first steps blow up (the chain bends over the sheath's lip, which the plant models
    # as six rods: a ball set on the statics' smooth lip falls between two), so it starts
    # straight, as the scenario does, and settles for 2.5 s.
    ("heart_wall_contact", "{insertion: {initial: 0.03, final: 0.03}, contact: {friction: 0.0}}", True,
     False, 2.5),
])
def test_engines_agree_after_settling(name, overrides, contact, from_engine, duration):
    """The plant (frictionless contact here: the statics' model) run until it has settled ends
    within 0.5 mm (free) / 1 mm (in contact) of the engine's equilibrium at the tip, with the
    wall's push on the tip within 15 %. Measured: 0.43 mm free; in contact 0.6 mm (the compliant
    wall lets the tip sink where the statics' wall is rigid), 0.079 N (engine) vs 0.077 N."""
    cd_e = _engine_diagram(name, overrides)
    p_plant, speed, f_plant, p_engine, f_engine = _settled_plant_from(cd_e, name, overrides, duration, from_engine)
    assert speed < 2e-3, f"the plant has not settled: a ball still moves at {speed * 1e3:.2f} mm/s"
    tip = np.linalg.norm(p_plant[-1] - p_engine[-1])
    assert tip < (1e-3 if contact else 0.5e-3), tip
    if contact:
        assert np.linalg.norm(f_engine) > 0.02 and np.linalg.norm(f_plant) > 0.02
        assert abs(np.linalg.norm(f_engine) - np.linalg.norm(f_plant)) < 0.15 * np.linalg.norm(f_plant)
    else:
        assert not np.any(f_engine) and np.linalg.norm(f_plant) < 1e-3


def test_engine_field_is_checked():
    from ballchain.infrastructure.errors import UserInputError
    from ballchain.systems.chain_scenario import load_scenario

    assert load_scenario("heart_left_quasi_static").engine == "plant"  # nothing changes by default
    with pytest.raises(UserInputError, match="engine must be one of"):
        load_scenario("heart_left_quasi_static", "{engine: magic}")
    with pytest.raises(UserInputError, match="needs mode: quasi-static"):
        load_scenario("heart_right_dynamics", "{engine: statics}")
    with pytest.raises(UserInputError, match="statics_period"):
        load_scenario("heart_left_quasi_static", "{engine: statics, statics_period: 0.0}")


HEART_SCENARIOS = ["heart_left_quasi_static", "heart_sleeve_quasi_static", "heart_no_field", "heart_wall_contact",
                   "teleop_right_unit", "teleop_two_units"]


@pytest.mark.slow
@pytest.mark.parametrize("name", HEART_SCENARIOS + ["free_space_wall", "free_space_uniform_90deg"])
def test_every_named_scenario_runs_on_the_statics_engine(name):
    """A short run of each named quasi-static scenario with ``engine: statics``: the watchdog
    (escape, breaks) passes, the chain stays a radius inside the wall, no solve fails."""
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import run_simulation

    m = run_simulation(scenario=load_scenario(name, "{engine: statics, duration: 0.2}"))
    assert m.engine == "statics" and m.realtime_factor > 0
    assert m.statics.failures == [] and m.statics.solves >= 1
    if m.min_wall_clearance_mm is not None:
        assert m.min_wall_clearance_mm > -1e-3  # the SDF grid's error, not a penetration
