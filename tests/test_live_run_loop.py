"""The live view on the station's run loop (``chain_simulation.StationRunner``): advanced in chunks
as ``run_station`` advances in one go, started over after a stop, the scenario's
simulator_config applied, ``gc.freeze`` only when asked for; and the flags of ``teleop --live``."""

import gc

import numpy as np
import pytest

from ballchain.cli import main as cli_main
from ballchain.systems.chain_scenario import load_scenario
from ballchain.systems.chain_simulation import StationRunner, MakeStation, run_station

FREE = "free_space_uniform_90deg"


def _positions(cd, root):
    return cd.chain.ball_positions(cd.chain.system.GetMyContextFromRoot(root)).copy()


def test_chunked_advances_reach_the_state_of_one_advance():
    """Five 20 ms advances of a StationRunner and one 100 ms run_station: the same ball centres
    (bit for bit: the same steps and events)."""
    scenario = load_scenario(FREE, "{n_balls: 4}")
    cd_one = MakeStation(scenario)
    one = run_station(cd_one, duration=0.1)
    cd = MakeStation(scenario)
    runner = StationRunner(cd)
    for k in range(1, 6):
        assert runner.advance_to(0.02 * k) is None and not runner.stopped
    np.testing.assert_array_equal(_positions(cd, runner.context), _positions(cd_one, one.context))
    assert np.linalg.norm(_positions(cd, runner.context) - _positions(cd, cd.diagram.CreateDefaultContext())) > 1e-4


def test_a_stopped_run_starts_over_and_stops_again_the_same_way():
    """A chain that breaks (too little damping): the watchdog's message; after ``restart`` the
    time is 0, the state the initial one, no failure, and the run breaks again at the same time."""
    cd = MakeStation(load_scenario(FREE, "{translational_damping: 0.1}"))
    runner = StationRunner(cd, restartable=True)
    first = runner.advance_to(0.05)
    assert first is not None and "the chain broke between balls" in first and runner.failure == first
    t_first = runner.context.get_time()
    runner.restart()
    assert runner.context.get_time() == 0.0 and runner.failure is None and runner.monitor.failure is None
    np.testing.assert_array_equal(_positions(cd, runner.context), _positions(cd, cd.diagram.CreateDefaultContext()))
    assert runner.advance_to(0.05) == first and runner.context.get_time() == t_first
    with pytest.raises(RuntimeError, match="restartable"):
        StationRunner(cd).restart()


def test_gc_freeze_only_when_asked_for():
    """``run_station`` freezes the objects alive (``gc.freeze``) during the run only with
    ``freeze_gc=True``, and unfreezes them after."""
    scenario = load_scenario(FREE, "{n_balls: 3}")
    seen = []

    def look(root):
        seen.append(gc.get_freeze_count())
        return False

    assert gc.get_freeze_count() == 0
    run_station(MakeStation(scenario), duration=0.005, stop=look)
    assert max(seen) == 0
    seen.clear()
    run_station(MakeStation(scenario), duration=0.005, stop=look, freeze_gc=True)
    assert min(seen) > 0 and gc.get_freeze_count() == 0


@pytest.mark.parametrize("argv, flag", [
    (["--task", "right"], "--task"), (["--targets", "3"], "--targets"), (["--seed", "0"], "--seed"),
    (["--time-limit", "5"], "--time-limit"), (["--html", "x.html"], "--html"), (["--no-progress"], "--no-progress"),
])
def test_live_refuses_the_simulated_operators_flags(argv, flag, capsys):
    """Each flag of the simulated operator's task, even at its default value, is refused with --live:
    one line, exit 2, before any build."""
    assert cli_main(["teleop", "--live", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{flag} does not apply to --live" in err


@pytest.mark.parametrize("argv, flag", [
    (["--units", "two"], "--units"), (["--duration", "1"], "--duration"), (["--realtime-rate", "2"], "--realtime-rate"),
    (["--no-wait"], "--no-wait"),
])
def test_the_live_flags_are_refused_without_live(argv, flag, capsys):
    assert cli_main(["teleop", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{flag} does not apply without --live" in err


@pytest.mark.slow
def test_the_live_view_applies_the_scenarios_simulator_config():
    """build_live's Simulator has the scenario's simulator_config (the live realtime rate aside)."""
    from pydrake.systems.analysis import ExtractSimulatorConfig

    from ballchain.experiments import teleop

    session = teleop.build_live(n_balls=8, realtime_rate=0.0,
                                overrides="{simulator_config: {publish_every_time_step: true, accuracy: 0.003}}")
    applied = ExtractSimulatorConfig(session.simulator)
    assert applied.publish_every_time_step and applied.accuracy == 0.003 and applied.target_realtime_rate == 0.0
    assert session.advance_to(0.1) is None
