"""The chain-model seam (systems/chain_model.py): both engines behind one interface."""

import numpy as np
import pytest
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator

from ballchain.systems.chain_model import ChainModel
from ballchain.systems.chain_scenario import ENGINES, load_scenario
from ballchain.systems.station import CHAIN_MODELS, MakeStation
from ballchain.systems.target_contact import wall_force_on, wall_geometries

# A free chain with one unit: every port of the interface is there (magnet_states too).
UNIT_IN_FREE_SPACE = ("{heart: false, units: [{anchor: puncture, distance: 0.15, direction_W: [0.0, -1.0, 0.0]}], "
                      "insertion: {feeder: false}")


def _station(engine: str):
    return MakeStation(load_scenario("teleop_right_unit", UNIT_IN_FREE_SPACE + f", engine: {engine}}}"))


def test_every_engine_of_the_scenario_has_a_chain_model():
    assert set(CHAIN_MODELS) == set(ENGINES)
    assert all(issubclass(model, ChainModel) and model.engine == name for name, model in CHAIN_MODELS.items())


@pytest.fixture(scope="module")
def stations():
    return {engine: _station(engine) for engine in ENGINES}


def test_both_engines_have_the_same_ports_and_geometry(stations):
    plant, statics = stations["plant"].chain, stations["statics"].chain
    n = plant.n_balls
    sizes = {}
    for engine, chain in (("plant", plant), ("statics", statics)):
        sizes[engine] = (chain.get_magnet_states_input_port().size(), chain.get_feeder_state_input_port().size(),
                         chain.get_ball_positions_output_port().size(), chain.get_tip_wall_force_output_port().size(),
                         chain.get_snap_throughs_output_port().size())
    assert sizes["plant"] == sizes["statics"] == (6, 2, 3 * n, 6, 1)
    assert [int(i) for i in plant.ball_body_indices] == [int(i) for i in statics.ball_body_indices] == list(
        range(1, n + 1))
    np.testing.assert_array_equal(plant.p_WE, statics.p_WE)
    np.testing.assert_array_equal(plant.sheath_axis_W, statics.sheath_axis_W)
    np.testing.assert_array_equal(plant.X_WF.GetAsMatrix34(), statics.X_WF.GetAsMatrix34())


def test_ball_positions_port_body_poses_and_state_agree(stations):
    for station in stations.values():
        chain = station.chain
        root = station.diagram.CreateDefaultContext()
        station.diagram.ExecuteInitializationEvents(root)  # the engine's first equilibrium
        context = chain.system.GetMyContextFromRoot(root)
        p = chain.ball_positions(context)
        port = chain.get_ball_positions_output_port()
        np.testing.assert_array_equal(port.Eval(port.get_system().GetMyContextFromRoot(root)).reshape(-1, 3), p)
        poses = chain.get_body_poses_output_port().Eval(context)
        np.testing.assert_array_equal(np.array([poses[int(i)].translation() for i in chain.ball_body_indices]), p)
        assert chain.is_finite(context) and chain.failure is None


def test_plant_tip_wall_force_is_the_walls_push_along_their_normal():
    """The tip pressed 0.2 mm into the flat wall (y = 12 mm, outward normal -y): the output is the
    contact results' wall force on the tip, pushing it out along -y, acting within the ball (one
    step: the plant's contact results are sampled, the step's from that state)."""
    station = MakeStation(load_scenario("free_space_wall"))
    chain = station.chain
    simulator = Simulator(station.diagram)
    root = simulator.get_mutable_context()
    plant_context = chain.plant.GetMyMutableContextFromRoot(root)
    r = 0.5 * chain.config.chain.ball_diameter
    p_tip = np.array([chain.ball_positions(plant_context)[-1][0], 0.012 - r + 0.2e-3, 0.0])
    chain.plant.SetFreeBodyPose(plant_context, chain.ball_bodies[-1], RigidTransform(p_tip))
    simulator.AdvanceTo(chain.time_step)
    port = chain.get_tip_wall_force_output_port()
    out = port.Eval(port.get_system().GetMyContextFromRoot(root))
    f, p_WC = out[:3], out[3:]
    # Within 10 deg of the normal (measured 4 deg, frictionless: the rigid ball's mesh facets, 1 mm
    # resolution, tilt the hydroelastic contact surface).
    assert f[1] < -0.01 and np.hypot(f[0], f[2]) < np.tan(np.radians(10.0)) * abs(f[1])
    assert np.linalg.norm(p_WC - p_tip) < r
    tip = set(chain.plant.GetCollisionGeometriesForBody(chain.ball_bodies[-1]))
    walls = wall_geometries(chain.plant, chain.scene_graph.model_inspector())
    expected, _ = wall_force_on(chain.plant.get_contact_results_output_port().Eval(plant_context), tip, walls)
    np.testing.assert_array_equal(f, expected)


def test_only_the_plant_holds_a_pin(stations):
    with pytest.raises(TypeError, match="pin"):
        stations["statics"].chain.add_pin(None, np.zeros(3), 1.0)
