"""The watchdog does not query the mesh again for a state it already passed (issue 48, session
50): an engine holding its equilibrium (a dwell) shows the same positions at every check, and
every test and metric of ``ChainMonitor.check`` is a function of them; a moved state, a moving
wall and a tolerated sinking are checked afresh."""

import numpy as np
import pytest

from ballchain.systems.chain_scenario import load_scenario
from ballchain.systems.chain_simulation import ChainMonitor, run_station
from ballchain.systems.station import MakeStation


@pytest.fixture(scope="module")
def ran():
    station = MakeStation(load_scenario("teleop_right_unit", "{engine: statics}"))
    context = station.diagram.CreateDefaultContext()
    monitor = ChainMonitor(station)
    run = run_station(station, duration=1.0, context=context, monitor=monitor)
    assert run.failure is None
    return station, run.context


def _counting(heart, monkeypatch):
    calls = []
    for name in ("contains", "wall_distance"):
        original = getattr(heart, name)
        monkeypatch.setattr(heart, name, lambda p, original=original, name=name: (calls.append(name), original(p))[1])
    return calls


def _metrics(monitor):
    return (monitor.min_clearance, monitor.max_gap, monitor.max_penetration, monitor.max_ball_overlap,
            monitor.max_wall_penetration)


def test_an_unchanged_state_is_not_queried_again_and_a_moved_one_is(ran, monkeypatch):
    station, root = ran
    chain = station.chain
    plant_context = chain.system.GetMyContextFromRoot(root)
    monitor = ChainMonitor(station)
    calls = _counting(station.heart, monkeypatch)
    assert monitor.check(plant_context, wall=True) is None
    first, queried = _metrics(monitor), len(calls)
    assert queried == 2 and np.isfinite(monitor.min_clearance)
    assert monitor.check(plant_context, wall=False) is None and monitor.check(plant_context, wall=True) is None
    assert len(calls) == queried and _metrics(monitor) == first and monitor.checks == 3  # counted, not queried
    # The same check by a fresh monitor on the same state: the same metrics (nothing skipped that counts).
    fresh = ChainMonitor(station)
    assert fresh.check(plant_context, wall=True) is None and _metrics(fresh) == first
    queried = len(calls)
    # A state one ball moved by 1 um: queried again.
    state = plant_context.get_mutable_discrete_state(0).get_mutable_value()
    sl = chain.engine_system._slices["p"]
    state[sl.start] += 1e-6
    assert monitor.check(plant_context, wall=True) is None and len(calls) == queried + 2
    monitor.restart()  # forgets what it saw
    assert monitor.check(plant_context, wall=True) is None and len(calls) == queried + 4


def test_a_tolerated_sinking_is_recorded_again_not_remembered(ran, monkeypatch):
    station, root = ran
    plant_context = station.chain.system.GetMyContextFromRoot(root)
    deep = 0.5 * station.heart.params.wall_thickness + 1e-3
    monkeypatch.setattr(station.heart, "wall_distance", lambda p: np.full(len(p), -deep))
    monitor = ChainMonitor(station, tolerate_sinking=lambda p: True)
    assert monitor.check(plant_context, wall=True) is None
    assert monitor._gaps_seen is None and monitor._wall_seen is None and len(monitor.tolerated_sinkings) == 1
