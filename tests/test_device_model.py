"""The device-model seam (systems/device_model.py): one interface and one registry for every
device; the ball chain, the steerable catheter and a toy third device (tests/toy_device.py,
registered with one call) all through ``MakeStation``, ``run_station`` and the operator."""

import numpy as np
import pytest

import ballchain as bc
from ballchain.experiments import teleop
from ballchain.systems import device_model
from ballchain.systems.catheter_model import CatheterModel
from ballchain.systems.chain_model import ChainModel
from ballchain.systems.chain_scenario import DEVICES, ENGINES, load_scenario
from ballchain.systems.chain_simulation import ChainMonitor, after_updates, run_station
from ballchain.systems.station import CHAIN_MODELS, MakeStation, Station

from toy_device import MagnetOnRod  # noqa: E402  (registers "magnet_on_rod")


def test_one_registry_gives_the_vocabulary_and_the_models():
    assert DEVICES[:2] == ("ball_chain", "steerable_catheter") and "magnet_on_rod" in DEVICES
    assert ENGINES == ("plant", "statics")  # the toy's engine is one of them
    assert bc.DeviceModel is device_model.DeviceModel
    models = {key: device_model.device_model_class(*key) for key in list(device_model.DEVICE_MODELS)}
    assert all(issubclass(m, device_model.DeviceModel) and (m.device, m.engine) == key for key, m in models.items())
    assert models[("steerable_catheter", "statics")] is CatheterModel
    assert models[("magnet_on_rod", "statics")] is MagnetOnRod
    assert CHAIN_MODELS == {e: models[("ball_chain", e)] for e in ("plant", "statics")}
    assert all(issubclass(m, ChainModel) for m in CHAIN_MODELS.values())
    with pytest.raises(bc.UserInputError, match="no model of device 'steerable_catheter'.*'statics'"):
        device_model.device_model_class("steerable_catheter", "plant")
    with pytest.raises(bc.UserInputError, match="device must be one of"):
        device_model.device_model_class("guidewire", "statics")
    with pytest.raises(ValueError, match="already"):
        bc.register_device_model("steerable_catheter", "statics", MagnetOnRod)


def test_a_scenario_s_device_and_engine_must_be_a_registered_pair():
    with pytest.raises(bc.UserInputError, match="engine 'plant' has no model of device 'steerable_catheter'"):
        load_scenario("teleop_right_unit", "{device: steerable_catheter, units: [], engine: plant}")
    assert load_scenario("teleop_right_unit", "{device: magnet_on_rod, engine: statics}").device == "magnet_on_rod"


def test_every_device_is_a_station_with_the_same_interface():
    """The chain on either engine and the catheter: a Station, the interface's ports (the tip's
    wall force, no anatomy offsets on a still wall), the tip body's pose the tip position."""
    scenarios = {"plant": load_scenario("teleop_right_unit"),
                 "statics": load_scenario("teleop_right_unit", "{engine: statics}"),
                 "catheter": load_scenario("teleop_right_unit", "{device: steerable_catheter, units: [], "
                                                                "engine: statics}")}
    for name, scenario in scenarios.items():
        station = MakeStation(scenario)
        device = station.device
        assert isinstance(station, Station) and isinstance(device, device_model.DeviceModel), name
        assert device.get_tip_wall_force_output_port().size() == 6
        assert device.get_anatomy_offsets_output_port() is None
        assert device.electrode.radius == device.tip_radius > 0
        root = station.diagram.CreateDefaultContext()
        station.diagram.ExecuteInitializationEvents(root)
        poses = device.get_body_poses_output_port().Eval(device.system.GetMyContextFromRoot(root))
        np.testing.assert_array_equal(poses[device.tip_body_index].translation(), station.tip_position(root))
        assert device.is_finite(device.system.GetMyContextFromRoot(root)) and device.failure is None
    assert set(CatheterModel(station.device.system, station.device.hand).actuation_input_ports()) == {"handle"}


def test_the_statics_engine_gives_its_anatomy_offsets_as_a_port():
    scenario = load_scenario("teleop_right_unit", "{engine: statics, wall_motion: {enabled: true}}")
    station = MakeStation(scenario)
    port = station.device.get_anatomy_offsets_output_port()
    assert port is not None and port.size() == 6
    assert station.target_touches.get_anatomy_offsets_input_port() is not None


def _toy_scenario():
    scenario = load_scenario("teleop_right_unit", "{device: magnet_on_rod, engine: statics}")
    return teleop.hand_over(scenario, "world", None, {})


def test_the_toy_device_runs_through_make_station_run_station_and_the_monitor():
    """The unit's stick turned (an exported ``right_unit.joystick``, held at full about z): the
    unit's field turns the magnet on its rod; the watchdog watches it; ``feeder.v_insert_cmd``
    (the toy's own slide) pushes it out."""
    station = MakeStation(_toy_scenario())
    assert isinstance(station.device, MagnetOnRod)
    context = station.diagram.CreateDefaultContext()
    station.diagram.GetInputPort("right_unit.joystick").FixValue(context, [0.0, 0.0, 1.0])
    station.diagram.GetInputPort("feeder.v_insert_cmd").FixValue(context, [0.005])
    start = station.tip_position(context)
    monitor = ChainMonitor(station)
    run = run_station(station, duration=1.0, context=context, monitor=monitor)
    assert run.failure is None and monitor.checks > 0 and monitor.min_clearance > 0
    metrics = station.device.metrics(run.context)
    assert metrics["length_mm"] == pytest.approx(20.0, abs=0.3) and metrics["bend_deg"] > 0.5
    assert np.linalg.norm(run.tip_position - start) > 1e-3


@pytest.mark.slow
def test_the_simulated_operator_drives_the_toy_device_in_the_teleoperation_task():
    """``teleop.run`` with ``--set '{device: magnet_on_rod}'``: the simulated operator steers the
    magnet on its rod through the station's unit and the toy's own feeder, the same code as for
    the chain: the run ends without a failure, with a row per target."""
    result = teleop.run(task="right", targets=2, overrides="{device: magnet_on_rod}", progress=False,
                        time_limit=10.0)
    assert [row["target"] for row in result.rows] == ["right_1", "right_2"]
    assert result.summary.failure is None and result.summary.sim_time_s > 1.0
