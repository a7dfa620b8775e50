"""The chain plant and MagneticWrenchSystem: ports, wrenches vs chain_energy, Newton's third law,
a short simulation in the heart, and free-space statics agreement."""

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from ballchain.drake_models.chain_energy import chain_energy
from ballchain.drake_models.field_sources import MagnetSource, UniformField, rotation_with_z_along
from ballchain.drake_models.heart import HeartParams, LeftAtrium
from ballchain.drake_models.params import BallChain, CylinderMagnet, Sleeve
from ballchain.systems.chain_plant import ChainPlantConfig, add_chain_plant
from ballchain.systems.chain_scenario import load_scenario
from ballchain.systems.chain_simulation import MakeStation, run_simulation
from ballchain.systems.magnetic_wrench import MagneticWrenchSystem

RNG = np.random.default_rng(3)


def _random_chain_poses(n, d):
    """A wiggly chain of touching balls with random dipole directions (body x axes)."""
    p = np.zeros((n, 3))
    for i in range(1, n):
        u = np.array([1.0, 0.0, 0.0]) + 0.4 * RNG.normal(size=3)
        p[i] = p[i - 1] + d * u / np.linalg.norm(u)
    R = []
    for _ in range(n):
        x = RNG.normal(size=3)
        Rz = rotation_with_z_along(x)  # column 2 = x direction
        R.append(Rz[:, [2, 0, 1]])  # body x = that direction
    return p, R


def _wrench_context(chain, field_source=None, port_magnets=(), magnet_states=None):
    """A MagneticWrenchSystem for bodies 1..n with fixed poses; returns (system, context, p, m_hat)."""
    n = chain.n_balls
    system = MagneticWrenchSystem(chain, list(range(1, n + 1)), field_source=field_source,
                                  port_magnets=port_magnets, base_direction_W=[1, 0, 0])
    context = system.CreateDefaultContext()
    p, R = _random_chain_poses(n, chain.ball_diameter)
    poses = [RigidTransform()] + [RigidTransform(RotationMatrix(r), x) for r, x in zip(R, p)]
    system.get_body_poses_input_port().FixValue(context, AbstractValue.Make(poses))
    if magnet_states is not None:
        system.get_magnet_states_input_port().FixValue(context, magnet_states)
    m_hat = np.array([r[:, 0] for r in R])
    return system, context, p, m_hat


def _output_wrenches(system, context):
    forces = system.get_spatial_forces_output_port().Eval(context)
    F = np.array([f.F_Bq_W.translational() for f in forces])
    tau = np.array([f.F_Bq_W.rotational() for f in forces])
    return forces, F, tau


def test_wrench_system_ports():
    chain = BallChain(n_balls=5)
    system = MagneticWrenchSystem(chain, [1, 2, 3, 4, 5])
    assert system.num_input_ports() == 1 and system.num_output_ports() == 1
    assert system.get_input_port(0).get_name() == "body_poses"
    assert system.get_output_port(0).get_name() == "spatial_forces"
    with_port = MagneticWrenchSystem(chain, [1, 2, 3, 4, 5], port_magnets=[CylinderMagnet()] * 2)
    assert with_port.num_input_ports() == 2
    assert with_port.get_magnet_states_input_port().get_name() == "magnet_states"
    assert with_port.get_magnet_states_input_port().size() == 12
    with pytest.raises(ValueError, match="body indices"):
        MagneticWrenchSystem(chain, [1, 2, 3])


@pytest.mark.parametrize("sleeve", [None, Sleeve()])
def test_wrenches_equal_chain_energy_gradient(sleeve):
    """Output = (-dU/dp, m_hat x -dU/dm_hat) of chain_energy, to 1e-12 relative (same arithmetic)."""
    chain = BallChain(n_balls=8, sleeve=sleeve)
    magnet = MagnetSource.pointing(CylinderMagnet(), [0.0, 0.12, 0.05], [0.3, -1.0, 0.2])
    system, context, p, m_hat = _wrench_context(chain, field_source=magnet)
    forces, F, tau = _output_wrenches(system, context)
    _, dU_dp, dU_dm, _ = chain_energy(chain, p, m_hat, magnet, gravity=False, base_direction=[1, 0, 0])
    scale = np.abs(dU_dp).max()
    np.testing.assert_allclose(F, -dU_dp, rtol=1e-12, atol=1e-12 * scale)
    np.testing.assert_allclose(tau, np.cross(m_hat, -dU_dm), rtol=1e-12, atol=1e-12 * np.abs(tau).max())
    assert [int(f.body_index) for f in forces] == list(range(1, 9))
    np.testing.assert_array_equal(np.array([f.p_BoBq_B for f in forces]), 0.0)


def test_newtons_third_law_without_external_field():
    """Internal dipole forces sum to zero and conserve angular momentum (about any point)."""
    chain = BallChain(n_balls=10)
    system, context, p, _ = _wrench_context(chain)
    _, F, tau = _output_wrenches(system, context)
    f_scale = np.abs(F).max()
    np.testing.assert_allclose(F.sum(axis=0), 0.0, atol=1e-12 * f_scale)
    total_moment = (np.cross(p, F) + tau).sum(axis=0)
    np.testing.assert_allclose(total_moment, 0.0, atol=1e-12 * f_scale * chain.ball_diameter)


def test_uniform_field_adds_torque_only():
    chain = BallChain(n_balls=4)
    B = np.array([0.0, 0.023, 0.0])
    sys0, ctx0, p, m_hat = _wrench_context(chain)
    _, F0, tau0 = _output_wrenches(sys0, ctx0)
    sys1 = MagneticWrenchSystem(chain, [1, 2, 3, 4], field_source=UniformField(B))
    ctx1 = sys1.CreateDefaultContext()
    sys1.get_body_poses_input_port().FixValue(ctx1, sys0.get_body_poses_input_port().Eval(ctx0))
    _, F1, tau1 = _output_wrenches(sys1, ctx1)
    np.testing.assert_allclose(F1, F0, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(tau1 - tau0, np.cross(chain.dipole_moment * m_hat, B), rtol=1e-9, atol=1e-15)


def test_magnet_states_port_matches_a_fixed_magnet():
    chain = BallChain(n_balls=6)
    p_WM, m_hat_W = np.array([0.02, -0.15, 0.03]), np.array([0.0, 1.0, 0.0])
    fixed = MagnetSource.pointing(CylinderMagnet(), p_WM, m_hat_W)
    sys_f, ctx_f, _, _ = _wrench_context(chain, field_source=fixed)
    sys_p = MagneticWrenchSystem(chain, list(range(1, 7)), port_magnets=[CylinderMagnet()])
    ctx_p = sys_p.CreateDefaultContext()
    sys_p.get_body_poses_input_port().FixValue(ctx_p, sys_f.get_body_poses_input_port().Eval(ctx_f))
    sys_p.get_magnet_states_input_port().FixValue(ctx_p, np.concatenate([p_WM, m_hat_W]))
    _, F_f, tau_f = _output_wrenches(sys_f, ctx_f)
    _, F_p, tau_p = _output_wrenches(sys_p, ctx_p)
    np.testing.assert_allclose(F_p, F_f, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(tau_p, tau_f, rtol=1e-12, atol=1e-15)



def test_two_port_magnets_match_their_magnet_sources_and_refuse_overlap():
    """PortDipoles (all port magnets at once) against a sum of MagnetSources, a cylinder and a
    sphere, one dipole direction given unnormalised; a magnet on the chain is refused."""
    from ballchain.drake_models.field_sources import FieldSources
    from ballchain.drake_models.params import SphereMagnet

    chain = BallChain(n_balls=6)
    magnets = [CylinderMagnet(), SphereMagnet()]
    p_WM = np.array([[0.02, -0.15, 0.03], [-0.1, 0.12, -0.02]])
    m_W = np.array([[0.0, 2.0, 0.0], [0.3, -0.2, 0.9]])
    fixed = FieldSources([MagnetSource.pointing(m, p, d) for m, p, d in zip(magnets, p_WM, m_W)])
    sys_f, ctx_f, _, _ = _wrench_context(chain, field_source=fixed)
    sys_p = MagneticWrenchSystem(chain, list(range(1, 7)), port_magnets=magnets)
    ctx_p = sys_p.CreateDefaultContext()
    sys_p.get_body_poses_input_port().FixValue(ctx_p, sys_f.get_body_poses_input_port().Eval(ctx_f))
    sys_p.get_magnet_states_input_port().FixValue(ctx_p, np.hstack([p_WM, m_W]).reshape(-1))
    _, F_f, tau_f = _output_wrenches(sys_f, ctx_f)
    _, F_p, tau_p = _output_wrenches(sys_p, ctx_p)
    np.testing.assert_allclose(F_p, F_f, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(tau_p, tau_f, rtol=1e-12, atol=1e-15)
    sys_p.get_magnet_states_input_port().FixValue(ctx_p, np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0] * 2))
    with pytest.raises(ValueError, match="bounding sphere"):
        sys_p.get_spatial_forces_output_port().Eval(ctx_p)

@pytest.fixture(scope="module")
def coarse_heart():
    return LeftAtrium(HeartParams(subdivisions=3))


def test_plant_structure_and_modes(coarse_heart):
    for translational, angular in ((1.0, 1e-5), (0.0, 0.0)):
        builder = DiagramBuilder()
        cp = add_chain_plant(builder, ChainPlantConfig(
            time_step=1e-3, translational_damping=translational, angular_damping=angular,
            heart=coarse_heart, initial_inserted_length=0.02))
        plant = cp.plant
        assert plant.get_contact_model().name == "kHydroelasticWithFallback"
        assert plant.time_step() == 1e-3
        assert cp.n_balls == 16
        assert plant.num_positions() == 1 + 7 * 15  # feeder slide + 15 quaternion floating joints
        joint = plant.GetJointByName("ball_2_floating")
        assert joint.default_translational_damping() == translational
        assert joint.default_angular_damping() == angular
        np.testing.assert_allclose(plant.GetBodyByName("ball_5").default_mass(), BallChain().ball_mass)
        # Ball 1 sits in the sheath; the chain starts straight along the sheath axis, touching.
        context = plant.CreateDefaultContext()
        p = cp.ball_positions(context)
        gaps = np.linalg.norm(np.diff(p, axis=0), axis=1) - BallChain().ball_diameter
        np.testing.assert_allclose(gaps, -4e-6, atol=1e-9)
        assert cp.in_sheath(p[:1])[0]
        assert np.linalg.norm(np.cross(p[-1] - p[0], cp.sheath_axis_W)) < 1e-9


def test_short_quasi_static_run_in_the_heart_keeps_the_chain_intact(coarse_heart):
    """Insert 5 mm in 0.1 s with no field: the tip advances ~5 mm along the sheath, chain intact."""
    scenario = load_scenario("heart_no_field", "{heart_subdivisions: 3, gravity: false, "
                             "insertion: {initial: 0.02, final: 0.025, start_time: 0.0, speed: 0.05}}")
    cd = MakeStation(scenario, heart=coarse_heart)
    simulator = Simulator(cd.diagram)
    plant_context = cd.chain.plant.GetMyContextFromRoot(simulator.get_mutable_context())
    p0 = cd.chain.ball_positions(plant_context)
    simulator.AdvanceTo(0.15)
    p1 = cd.chain.ball_positions(plant_context)
    d = cd.chain.config.chain.ball_diameter
    gaps = np.linalg.norm(np.diff(p1, axis=0), axis=1) - d
    assert np.all(np.abs(gaps) < 20e-6)  # touching, < 20 um of overlap or gap
    assert np.all(coarse_heart.contains(p1) | cd.chain.in_sheath(p1))
    advance = (p1 - p0) @ cd.chain.sheath_axis_W
    np.testing.assert_allclose(advance, 5e-3, atol=0.3e-3)  # straight chain, pushed 5 mm
    assert np.linalg.norm(np.cross(p1[-1] - p1[0], cd.chain.sheath_axis_W)) < 0.2e-3


# A 2.5 s settling run: the quick tier compares the plant with the statics in
# test_simulate (a unit steering 8 balls) and test_forces (the pinned tip's force).
@pytest.mark.slow
def test_free_space_quasi_static_settles_on_the_statics_solution():
    """Ball 1 clamped, 23 mT at 90 deg, 8 balls: the tip within 0.5 mm of solve_statics."""
    from ballchain.optimization.statics import solve_statics

    n = 8
    B = np.array([0.0, 0.023, 0.0])
    statics = solve_statics(BallChain(n_balls=n), UniformField(B))
    assert statics.converged
    scenario = load_scenario("free_space_uniform_90deg", f"{{n_balls: {n}}}")
    result = run_simulation(scenario=scenario, duration=2.5)
    p = np.array(result.p_W_mm) * 1e-3
    np.testing.assert_allclose(p[0], 0.0, atol=1e-9)  # ball 1 clamped at the origin
    tip_error = np.linalg.norm(p[-1] - statics.positions[-1])
    print(f"tip: simulation {p[-1] * 1e3} mm, statics {statics.positions[-1] * 1e3} mm, "
          f"error {tip_error * 1e3:.3f} mm")
    assert tip_error < 0.5e-3
    assert np.abs(p - statics.positions).max() < 0.5e-3


@pytest.mark.slow
def test_compliant_wall_holds_the_chain_from_inside():
    """Bent up against the roof by 30 mT: hydroelastic contact holds the tip inside the chamber,
    sunk less than half the wall (0 < sinking < 1.25 mm), the chain intact."""
    from ballchain.systems.chain_simulation import ChainMonitor

    scenario = load_scenario("heart_wall_contact")
    cd = MakeStation(scenario)
    simulator = Simulator(cd.diagram)
    monitor = ChainMonitor(cd)
    simulator.set_monitor(monitor)
    simulator.AdvanceTo(0.8)
    plant = cd.chain.plant
    plant_context = plant.GetMyContextFromRoot(simulator.get_context())
    contacts = plant.get_contact_results_output_port().Eval(plant_context)
    assert contacts.num_hydroelastic_contacts() >= 1
    p = cd.chain.ball_positions(plant_context)
    heart = cd.heart
    assert p[-1, 2] > 0.8 * heart.semi_axes[2]  # the tip is up at the roof
    half_wall = 0.5 * heart.params.wall_thickness
    assert -half_wall < monitor.min_clearance < 0.0
    assert monitor.max_gap < 20e-6
    assert np.all(heart.contains(p) | cd.chain.in_sheath(p))


@pytest.mark.slow
def test_chain_pressed_against_a_wall_settles_on_the_statics_solution():
    """8 balls, 23 mT at 90 deg, a flat wall at y = 12 mm: the simulated chain (stiff compliant
    half-space) settles within 0.5 mm of the statics with a rigid frictionless wall; what is left
    is the tip's indentation into the compliant wall, along its normal."""
    from ballchain.optimization.statics import ChainStatics, rotation_path

    scenario = load_scenario("free_space_wall")
    point, normal = np.array(scenario.wall_plane[:3]), np.array(scenario.wall_plane[3:])
    solver = ChainStatics(BallChain(n_balls=scenario.n_balls))
    statics = None
    for angle in rotation_path(0.0, 90.0, 22.5):
        statics = solver.solve_or_raise(UniformField.in_plane(0.023, np.radians(angle)), statics,
                                        wall=(point, normal))
    assert set(statics.wall_forces) == {scenario.n_balls - 1}  # only the tip touches
    result = run_simulation(scenario=scenario, duration=2.5)
    p = np.array(result.p_W_mm) * 1e-3
    error = p - statics.positions
    print(f"tip: simulation {p[-1] * 1e3} mm, statics {statics.positions[-1] * 1e3} mm, "
          f"wall force (statics) {statics.wall_forces[scenario.n_balls - 1]:.3f} N")
    assert np.abs(error).max() < 0.5e-3
    indentation = -(error[-1] @ normal)
    assert 0.0 < indentation < 0.3e-3  # into the wall, a fraction of a millimetre
    # The wall's push on the tip: the simulation's contact force against the statics multiplier
    # (0.01 % apart when measured; 2 % allows for the settling that is left after 2.5 s).
    f_sim = np.array(result.tip_wall_force_N)
    f_statics = statics.wall_forces[scenario.n_balls - 1] * normal
    np.testing.assert_allclose(f_sim, f_statics, rtol=0, atol=0.02 * np.linalg.norm(f_statics))
