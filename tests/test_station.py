"""The station builder (systems/station.py): Drake's config structs reach the systems, the pin and
the units go through the builder's steps, and the actuation-only diagram is wired as the station."""

from __future__ import annotations

import numpy as np
import pytest

from ballchain.infrastructure.errors import UserInputError
from ballchain.systems.chain_scenario import load_scenario
from ballchain.systems.station import MakeStation

SMALL = "free_space_uniform_90deg"  # no heart: builds in a fraction of a second


def test_the_default_plant_config_is_the_chain_plants_and_the_step_has_one_home():
    """The scenario's default MultibodyPlantConfig is the chain's (SAP, hydroelastic with
    fallback, near-rigid threshold 0), and the plant's step is the scenario's ``time_step``."""
    from pydrake.multibody.plant import DiscreteContactApproximation

    for mode, step in (("quasi-static", 1e-3), ("dynamics", 1e-4)):
        st = MakeStation(load_scenario(SMALL, f"{{n_balls: 3, mode: {mode}}}"))
        plant = st.chain.plant
        assert plant.time_step() == step
        assert plant.get_discrete_contact_approximation() == DiscreteContactApproximation.kSap
        assert plant.get_contact_model().name == "kHydroelasticWithFallback"
        assert plant.get_sap_near_rigid_threshold() == 0.0
    st = MakeStation(load_scenario(SMALL, "{n_balls: 3, time_step: 2.0e-3}"))
    assert st.chain.plant.time_step() == 2e-3


def test_plant_config_fields_reach_the_plant():
    from pydrake.multibody.plant import DiscreteContactApproximation

    st = MakeStation(load_scenario(SMALL, "{n_balls: 3, plant_config: {sap_near_rigid_threshold: 1.0, "
                                          "discrete_contact_approximation: lagged, contact_model: point}}"))
    plant = st.chain.plant
    assert plant.get_sap_near_rigid_threshold() == 1.0
    assert plant.get_discrete_contact_approximation() == DiscreteContactApproximation.kLagged
    assert plant.get_contact_model().name == "kPoint"
    assert plant.time_step() == 1e-3  # the other fields of the struct kept their values


def test_unknown_keys_inside_a_drake_config_struct_are_refused_by_the_schema_check():
    from ballchain.systems.chain_scenario import ChainScenario, check_yaml_schema

    check_yaml_schema({"plant_config": {"contact_model": "point"}, "simulator_config": {"accuracy": 1e-3},
                       "visualization": {"publish_period": 0.1}}, ChainScenario, "test")
    for data, name in (({"plant_config": {"contact_modle": "point"}}, "contact_modle"),
                       ({"simulator_config": {"max_step": 0.1}}, "max_step"),
                       ({"visualization": {"period": 0.1}}, "period"),
                       ({"plant_config": {"time_step": "fast"}}, "plant_config.time_step")):
        with pytest.raises(UserInputError, match=name):
            check_yaml_schema(data, ChainScenario, "test")


def test_simulator_config_is_applied_by_the_run_loop_and_realtime_rate_overrides_it():
    from pydrake.systems.analysis import ExtractSimulatorConfig

    from ballchain.systems.chain_simulation import run_station

    scenario = load_scenario(SMALL, "{n_balls: 3, simulator_config: {target_realtime_rate: 50.0, "
                                    "publish_every_time_step: true, accuracy: 0.003}}")
    run = run_station(MakeStation(scenario), duration=0.002)
    assert run.failure is None
    applied = ExtractSimulatorConfig(run.simulator)
    assert applied.target_realtime_rate == 50.0 and applied.publish_every_time_step and applied.accuracy == 0.003
    run = run_station(MakeStation(scenario), duration=0.002, realtime_rate=100.0)
    assert run.simulator.get_target_realtime_rate() == 100.0
    default = run_station(MakeStation(load_scenario(SMALL, "{n_balls: 3}")), duration=0.002)
    assert default.simulator.get_target_realtime_rate() == 0.0


def test_visualization_config_reaches_the_visualiser_the_overlays_and_the_markers(monkeypatch):
    """``visualization.publish_period`` (and the colour, the alpha slider) reach the
    MeshcatVisualizer's params; the same period drives the overlays and the unit markers."""
    import pydrake.geometry
    from pydrake.geometry import Meshcat, MeshcatParams

    from ballchain.systems import station

    seen = {}
    add_to_builder = pydrake.geometry.MeshcatVisualizer.AddToBuilder

    def spy_visualizer(builder, scene_graph, meshcat, params):
        seen["params"] = params
        return add_to_builder(builder, scene_graph, meshcat, params)

    def spy(cls, name):
        def make(*args, **kwargs):
            seen[name] = args[2]  # their ``period`` argument
            return cls(*args, **kwargs)
        return make

    monkeypatch.setattr(pydrake.geometry.MeshcatVisualizer, "AddToBuilder", staticmethod(spy_visualizer))
    monkeypatch.setattr(station, "MeshcatOverlays", spy(station.MeshcatOverlays, "overlays"))
    monkeypatch.setattr(station, "UnitMeshcatMarkers", spy(station.UnitMeshcatMarkers, "markers"))
    meshcat = Meshcat(MeshcatParams(host="localhost"))
    scenario = load_scenario("teleop_right_unit", "{heart: false, units: [{anchor: puncture, distance: 0.15, "
                                                  "direction_W: [0.0, -1.0, 0.0]}], insertion: {feeder: false}, "
                                                  "visualization: {publish_period: 0.25, enable_alpha_sliders: true, "
                                                  "default_illustration_color: {rgba: [0.1, 0.2, 0.3, 1.0]}}}")
    MakeStation(scenario, meshcat)
    params = seen["params"]
    assert params.publish_period == 0.25 and params.enable_alpha_slider
    assert (params.default_color.r(), params.default_color.g(), params.default_color.b()) == (0.1, 0.2, 0.3)
    assert seen["overlays"] == 0.25 and seen["markers"] == 0.25


def test_the_pin_step_reads_the_spring_on_the_tip():
    """``pin`` in a scenario: ``force_sensor_pin`` on the tip ball, its reading exported as
    ``pin_reading``: k (p_tip - p_pin) at the start (the straight chain), i.e. the force the tip
    presses on the pin; and the tip feels the opposite force."""
    point = [0.025, 0.001, 0.0]
    st = MakeStation(load_scenario(SMALL, f"{{n_balls: 4, uniform_field: [0, 0, 0], pin: {{point: {point}, "
                                          "stiffness: 400.0}}"))
    assert st.pin is not None and st.diagram.HasOutputPort("pin_reading")
    context = st.diagram.CreateDefaultContext()
    plant_context = st.chain.plant.GetMyContextFromRoot(context)
    tip = st.chain.ball_positions(plant_context)[-1]
    reading = st.diagram.GetOutputPort("pin_reading").Eval(context)
    np.testing.assert_allclose(reading, 400.0 * (tip - np.asarray(point)), rtol=1e-12, atol=1e-15)
    generalized = st.chain.plant.get_applied_generalized_force_input_port().Eval(plant_context)
    assert generalized[-3:] == pytest.approx(-reading, rel=1e-12)  # the tip ball's translational forces


def test_a_prebuilt_field_source_replaces_the_scenarios_field_and_not_both():
    from ballchain.drake_models.field_sources import UniformField

    source = UniformField(np.array([0.0, 0.023, 0.0]))
    st = MakeStation(load_scenario(SMALL, "{n_balls: 3, uniform_field: [0, 0, 0]}"), field_source=source)
    assert st.field_source is source and st.chain.wrench is not None
    with pytest.raises(UserInputError, match="field_source"):
        MakeStation(load_scenario(SMALL, "{n_balls: 3}"), field_source=source)


def _unit_wiring(diagram, names) -> set:
    """The connections between the units' own systems: {(source, output, destination, input)}."""
    parts = (".magnet", ".drive", ".hall_sensor", ".estimator", ".controller", ".teleoperation", ".mode_switch",
             ".unit")
    ours = {f"{n}{p}" for n in names for p in parts}
    edges = set()
    for (dst, i), (src, o) in diagram.connection_map().items():
        if dst.get_name() in ours and src.get_name() in ours:
            edges.add((src.get_name(), src.get_output_port(o).get_name(), dst.get_name(),
                       dst.get_input_port(i).get_name()))
    return edges


@pytest.mark.parametrize("unit_systems", ["compiled", "python"])
def test_the_actuation_only_diagram_wires_the_units_as_the_station_does(unit_systems):
    """One unit step (``actuation_station.add_unit_systems``): the units of the full station and
    those of the actuation-only diagram built from the same unit configs have the same wiring
    (each loop closed, each Hall sensor seeing and each estimator subtracting the other unit:
    the composed systems through the other magnet's pose, one ``ActuationUnit`` through its
    quaternion)."""
    from ballchain.systems.actuation_station import StationOptions, make_actuation_station

    st = MakeStation(load_scenario("teleop_two_units", f"{{unit_systems: {unit_systems}}}"))
    names = list(st.units)
    configs = [st.units[n].config for n in names]
    hardware = make_actuation_station(configs, StationOptions(compiled_units=unit_systems == "compiled"))
    station_edges, hardware_edges = _unit_wiring(st.diagram, names), _unit_wiring(hardware, names)
    assert station_edges == hardware_edges
    cross = {e for e in station_edges if e[0].split(".")[0] != e[2].split(".")[0]}
    if unit_systems == "compiled":
        assert {(e[2].split(".")[1], e[3]) for e in cross} == {("unit", "q_WM_left_unit"), ("unit", "q_WM_right_unit")}
        assert ("right_unit.teleoperation", "omega_desired_W", "right_unit.unit", "omega_teleop_W") in station_edges
        return
    assert {(e[2].split(".")[1], e[3]) for e in cross} == {
        ("hall_sensor", "X_WM_left_unit"), ("estimator", "X_WM_left_unit"),
        ("hall_sensor", "X_WM_right_unit"), ("estimator", "X_WM_right_unit")}
