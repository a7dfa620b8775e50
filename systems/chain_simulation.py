"""Run the station of a scenario: the one run loop, its watchdog and metrics.

The diagram is built by ``systems/station.py`` (``MakeStation``: its steps, system names and
exported ports are described there). The run loop, the watchdog and the metrics read the device
through its model's interface (``Station.chain``, a ``device_model.DeviceModel``): the same code for
the ball chain on either engine, the steerable catheter and a user's device.
The watchdog (``ChainMonitor``, ``station_monitor``) lives in ``chain_monitor``, the replay
file's helpers in ``replay_files``; both re-exported here.

``run_station`` is the one Simulator loop (watchdog, progress, stop condition, a run's own
check, recording, Ctrl-C) of ``simulate``, teleoperation and the force pin, on a
``StationRunner`` (the Simulator with the scenario's simulator_config and the station monitor),
which the live view advances in chunks and starts over after a stop; ``run_simulation``
stops with ``SimulationFailure`` (saying when and which ball) on a NaN, a ball leaving the heart
or the chain breaking apart, and returns the typed ``SimulationMetrics`` otherwise.
"""

from __future__ import annotations

import gc
import math
import os
import resource
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator

from ballchain.infrastructure.arg_checks import require_bool, require_positive, require_type
from ballchain.drake_models.atrium import Atrium
from ballchain.infrastructure.errors import UserInputError, caused_by_interrupt, short_repr
from ballchain.infrastructure.safe_files import atomic_write_text, check_output_file, optional_field
from ballchain.systems.chain_model import SnapThrough, StaticsEngineStats
from ballchain.systems.chain_scenario import ChainScenario, check_steps
from ballchain.systems.chain_monitor import RIM_BAND, ChainMonitor, near_ostium_rim, station_monitor  # noqa: F401
from ballchain.systems.replay_files import (  # noqa: F401 (re-exported)
    REPLAY_BASE_BYTES,
    REPLAY_BYTES_PER_BODY_FRAME,
    STOP_SIGNALS,
    captioned_replay,
    replay_bytes,
    replay_caption,
    replay_meshcat,
    without_stop_signals,
)
from ballchain.systems.station import (  # re-exported (__all__)
    MakeStation,
    Station,
    StationPorts,
    atrium_for,
    chain_for,
    field_source_for,
)
from ballchain.systems.randomness import set_random_context


@dataclass
class SimulationMetrics:
    """What ``run_simulation`` measured (and ``SimulationFailure`` carries up to the failure).

    Serialised by ``safe_files.to_jsonable``: the fields in this order, ``statics``, ``html`` and
    ``p_W_mm`` left out while None (the JSON of ``ballchain simulate --json``).

    Attributes:
        realtime_factor: simulated time over wall_time_s (None for a zero wall time).
        sim_time_s: simulated time reached [s].
        tip_position_mm: the tip ball's centre at the end (3,) [mm] (None if not finite).
        min_wall_clearance_mm: smallest distance from a free ball's surface to the wall [mm]
            (negative: sunk into it; None without a heart).
        max_neighbor_gap_um: largest gap between neighbouring balls' surfaces [um] (negative:
            overlap).
        max_penetration_um: the larger of the two below [um].
        max_ball_overlap_um: largest overlap of two balls [um].
        max_wall_penetration_um: deepest a ball sank into the wall [um].
        monitor_checks: the watchdog's periodic checks.
        wall_time_s: wall time of the run loop (Initialize + AdvanceTo) [s]; build_time_s: of
            the station's build [s].
        time_step_s: the plant's step, or the quasi-static engine's period [s].
        mode: "quasi-static" or "dynamics"; engine: "plant" or "statics".
        n_steps: steps (or engine updates) in sim_time_s.
        targets_touched: names (e.g. "left_3") of the ablation targets the tip ball touched
            (``target_contact``; empty without any).
        tip_wall_force_N: the walls' contact force on the tip ball at the end (3,) [N], world frame.
        peak_memory_MB: the process's peak resident set size so far (``ru_maxrss``) [MiB] (the
            whole process, not this run alone).
        statics: the quasi-static engine's solves (None with the plant).
        html: the Meshcat replay written (None without one).
        p_W_mm: the ball centres at the end (n, 3) [mm] (None in ``SimulationFailure.metrics``).
    """

    realtime_factor: float | None
    sim_time_s: float
    tip_position_mm: list[float] | None
    min_wall_clearance_mm: float | None
    max_neighbor_gap_um: float | None
    max_penetration_um: float
    max_ball_overlap_um: float
    max_wall_penetration_um: float
    monitor_checks: int
    wall_time_s: float
    build_time_s: float
    time_step_s: float
    mode: str
    engine: str
    n_steps: int
    targets_touched: list[str]
    tip_wall_force_N: list[float]
    peak_memory_MB: float
    statics: StaticsEngineStats | None = optional_field()
    html: str | None = optional_field()
    p_W_mm: list[list[float]] | None = optional_field()


class SimulationFailure(RuntimeError):
    """The simulation stopped: NaN, a ball out of the heart, or the chain broken.

    Attributes:
        metrics: the ``SimulationMetrics`` up to the failure (``p_W_mm`` None), or None when
            the run did not get that far.
    """

    def __init__(self, message: str, metrics: SimulationMetrics | None = None):
        super().__init__(message)
        self.metrics = metrics


__all__ = [
    "ChainMonitor", "MakeStation", "RunOutcome", "SimulationFailure", "SimulationMetrics", "SnapThrough",
    "StaticsEngineStats", "Station", "StationPorts", "StationRunner",
    "after_updates", "atrium_for", "chain_for", "field_source_for", "frozen_gc", "replay_bytes", "run_simulation",
    "run_station", "station_monitor",
]


def _targets_touched(cd: Station, root_context) -> list[str]:
    tracker = cd.target_touches
    return [] if tracker is None else tracker.touched_names(tracker.GetMyContextFromRoot(root_context))


def _tip_wall_force(cd: Station, root_context) -> list[float]:
    """The walls' contact force on the tip ball at the end of the run [N] (world frame)."""
    port = cd.chain.get_tip_wall_force_output_port()
    f = port.Eval(port.get_system().GetMyContextFromRoot(root_context))[:3]
    return [round(float(v), 6) for v in f]


@dataclass
class RunOutcome:
    """What ``run_station`` ran: its times, its failure, the final context and the chain's state in it.

    The chain's state at the end: ``tip_position`` (3,) [m], ``ball_positions`` (n, 3) [m]
    (``Station``'s readings of ``context``).

    Attributes:
        sim_time: simulated time reached [s].
        wall_time: wall time of Simulator Initialize + AdvanceTo [s] (the build is not counted).
        cpu_time: the process's CPU time over the same span [s].
        failure: the failure message of ``check`` or of the watchdog (or the solver's error, with
            the time), or None.
        stopped: True when ``stop`` ended the run before ``duration``.
        monitor: the ChainMonitor that watched the run (its metrics, tolerated sinkings).
        context: the Simulator's root context at the end.
        simulator: the Simulator.
        station: the Station that ran.

    It pickles (``pickle.dumps``, a process pool, a Dask worker) as plain data: the times, the
    failure, the chain's end state (``ball_positions``, ``tip_position``) and the monitor's
    numbers. The live pydrake objects cannot be pickled: ``context``, ``simulator`` and
    ``station`` are None in the unpickled copy (and its ``monitor`` has no station to check).
    """

    sim_time: float
    wall_time: float
    cpu_time: float
    failure: str | None
    stopped: bool
    monitor: ChainMonitor
    context: object
    simulator: Simulator
    station: Station | None = None

    def _station(self) -> Station:
        if self.station is None:
            raise ValueError("this RunOutcome has no station: read the state with Station.ball_positions(context)")
        return self.station

    @property
    def ball_positions(self) -> np.ndarray:
        """The ball centres (n, 3) [m] at the end of the run, ball 1 first, the tip ball last."""
        kept = self.__dict__.get("_ball_positions")  # an unpickled copy's
        if self.station is None and kept is not None:
            return kept.copy()
        return self._station().ball_positions(self.context)

    @property
    def tip_position(self) -> np.ndarray:
        """The tip ball's centre (3,) [m] at the end of the run."""
        if self.station is None and self.__dict__.get("_ball_positions") is not None:
            return self.ball_positions[-1]
        return self._station().tip_position(self.context)

    def __getstate__(self) -> dict:
        """Plain data (see the class docstring): the live pydrake objects are left out."""
        state = dict(self.__dict__)
        has_state = self.station is not None or self.__dict__.get("_ball_positions") is not None
        state["_ball_positions"] = np.array(self.ball_positions, dtype=float) if has_state else None
        state.update(context=None, simulator=None, station=None)
        return state

    def __copy__(self) -> "RunOutcome":
        copy = object.__new__(RunOutcome)  # a shallow copy keeps the live objects (pickling leaves them out)
        copy.__dict__.update(self.__dict__)
        return copy


def _export_recording(cd: Station, meshcat, html: Path) -> None:
    cd.visualizer.StopRecording()
    cd.visualizer.PublishRecording()
    atomic_write_text(html, captioned_replay(meshcat.StaticHtml(), replay_caption(cd.scenario)))


def _keep_replay(cd: Station, meshcat, html: Path, progress: str | None, root) -> None:
    """After Ctrl-C (or a stop signal): the replay recorded so far written (from the start: an
    export the interrupt cut short left no file, the write being atomic), and the line saying so."""
    _export_recording(cd, meshcat, html)
    print(f"{progress or 'run'}: interrupted at t = {root.get_time():.4f} s; replay so far written "
          f"to {html}", file=sys.stderr)


def after_updates(condition, period: float):
    """``condition(root_context) -> bool`` asked only where its answer can have changed: a
    condition on one system's state that only its periodic updates (``period`` [s], offset 0)
    change, e.g. ``SimulatedOperator.is_done``. As a ``stop`` of ``station_monitor``.

    Drake applies the updates at time t in the step that starts at t: the monitor sees them at
    that step's end. The condition is asked at the first monitor call after each update time
    (and at the first call of a run, or of a run started over at an earlier time); in between,
    its last answer is returned. The same steps end the run as asking at every step, without
    the context lookups at the other steps (the steps of the faster units, the feeder's).
    """
    if not (isinstance(period, (int, float)) and math.isfinite(period) and period > 0):
        raise ValueError(f"after_updates: period must be a positive number of seconds, got {period!r}")
    tolerance = 1e-9 * period  # far below any step, far above the event times' round-off
    seen = {"next": -math.inf, "last": -math.inf, "answer": False}

    def ask(root_context):
        t = root_context.get_time()
        if t < seen["last"]:  # the run started over
            seen["next"] = -math.inf
        seen["last"] = t
        if t <= seen["next"] + tolerance:  # no update applied since the last answer
            return seen["answer"]
        seen["answer"] = bool(condition(root_context))
        seen["next"] = math.ceil(t / period - 1e-9) * period  # the first update at or after t
        return seen["answer"]

    return ask


@contextmanager
def frozen_gc(enabled: bool = True):
    """Freeze the Python objects alive now (``gc.freeze``) for the ``with`` block, unfreeze after.

    The libraries and a built station keep ~170k Python objects alive; a full (generation 2)
    collection scans them all (~65 ms on this machine) and lands in a run wherever the
    allocation count says. Frozen they are not scanned (garbage made in the block is still
    collected); unfrozen afterwards, so any garbage among them is collected later. A process-wide
    switch: only a program that owns its process (the command line) asks for it, after the build
    (``run_station(freeze_gc=True)``, the live view).
    """
    if not enabled:
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def check_run_arguments(cd, what: str, *, monitor=None, stop=None, check=None, on_time=None, context=None,
                        realtime_rate=None, html=None) -> None:
    """The arguments of a run (``run_station``, ``StationRunner``) that Drake or a hook would
    otherwise refuse deep inside the run (a pybind11 "incompatible function arguments", "'dict'
    object is not callable" at the first step): each of its kind, before anything is built.

    Raises:
        UserInputError: "{what} {argument} must be ..., got ...".
    """
    if not isinstance(cd, Station):
        raise UserInputError(f"{what}'s cd must be a Station (MakeStation(scenario)), got {type(cd).__name__}")
    if monitor is not None:
        require_type(monitor, ChainMonitor, f"{what} monitor", "a ChainMonitor (ChainMonitor(station)) or None")
    for name, hook in (("stop", stop), ("check", check), ("on_time", on_time)):
        if hook is not None and not callable(hook):
            raise UserInputError(f"{what} {name} must be a function of the root context or None, "
                                 f"got {type(hook).__name__} {short_repr(hook)}")
    if context is not None:
        from pydrake.systems.framework import Context

        try:
            ok = isinstance(context, Context) and cd.diagram.ValidateContext(context) is None
        except RuntimeError:  # a context of another system
            ok = False
        if not ok:
            raise UserInputError(f"{what} context must be a root context of the station's diagram "
                                 f"(station.diagram.CreateDefaultContext()) or None, got {type(context).__name__}")
    if realtime_rate is not None:
        require_positive(realtime_rate, f"{what} realtime_rate", allow_zero=True)
    if html is not None and (isinstance(html, bool) or not isinstance(html, (str, os.PathLike))):
        raise UserInputError(f"{what} html must be a file name (str or Path) or None, got {short_repr(html)}")


class StationRunner:
    """The Simulator of a built station with its watchdog, advanced in chunks (and restartable).

    The run loop of ``run_station`` (one advance to the end) and of the live view (chunks
    between a person's inputs, and a restart).

    The Simulator gets the scenario's ``simulator_config`` (its defaults are the Simulator's
    own; an explicit ``realtime_rate`` overrides its target_realtime_rate) and the monitor
    ``station_monitor(cd, monitor, stop, on_time, check)``. Neither ``check`` nor ``stop`` nor
    the watchdog changes the trajectory (they only read the state).

    Args:
        cd: the built diagram.
        monitor: the watchdog (default: ``ChainMonitor(cd)``).
        stop, check, on_time: as ``station_monitor``.
        context: None (the diagram's default context), or a root context to start from.
        realtime_rate: the target real-time rate (None: the scenario's).
        restartable: keep a copy of the initial context for ``restart``.

    Attributes:
        simulator, context (its root context), monitor; stopped: ``stop`` ended the last advance;
        failure: the failure message that ended the last advance, or None.

    Example:
        Advance a station in chunks (as the live view does between a person's inputs)::

            >>> import ballchain as bc
            >>> runner = bc.StationRunner(bc.MakeStation(bc.load_scenario("free_space_uniform_90deg", "{n_balls: 6}")))
            >>> runner.advance_to(0.02), runner.advance_to(0.05)  # None: no failure
            (None, None)
            >>> [round(1e3 * float(v), 1) for v in runner.cd.tip_position(runner.context)[:2]]  # [mm]
            [14.9, 3.9]
    """

    def __init__(self, cd: Station, *, monitor: ChainMonitor | None = None, stop=None, check=None,
                 on_time=None, context=None, realtime_rate: float | None = None, restartable: bool = False):
        check_run_arguments(cd, "StationRunner", monitor=monitor, stop=stop, check=check, on_time=on_time,
                            context=context, realtime_rate=realtime_rate)
        self.cd = cd
        if context is None and cd.scenario.random_seed is not None:
            from pydrake.common import RandomGenerator

            context = cd.diagram.CreateDefaultContext()
            set_random_context(cd.diagram, context, RandomGenerator(cd.scenario.random_seed))
        self.simulator = Simulator(cd.diagram) if context is None else Simulator(cd.diagram, context)
        ApplySimulatorConfig(cd.scenario.simulator_config, self.simulator)
        if realtime_rate is not None:
            self.simulator.set_target_realtime_rate(realtime_rate)
        self.monitor = ChainMonitor(cd) if monitor is None else monitor
        self._checked = []  # the message of ``check``, when it ended the run

        def run_check(root_context):
            message = check(root_context)
            if message:
                self._checked.append(message)
            return message

        self.simulator.set_monitor(station_monitor(cd, self.monitor, stop=stop, on_time=on_time,
                                                   check=None if check is None else run_check))
        self.context = self.simulator.get_mutable_context()
        self._initial = self.context.Clone() if restartable else None
        self._initialized = False
        self.stopped = False
        self.failure: str | None = None

    def advance_to(self, t: float) -> str | None:
        """Advance to simulated time t [s] (Initialize first, at the first call).

        Returns:
            None (t reached, or ``stop`` ended the advance: ``stopped``), or the failure message
            of ``check`` or of the watchdog, or the solver's error with the time (no exception).

        Raises:
            KeyboardInterrupt: Ctrl-C, also when a compiled call wrapped it in another error.
        """
        from pydrake.systems.analysis import SimulatorStatus

        require_positive(t, "advance_to t", allow_zero=True)
        if t < self.context.get_time():  # Drake's AdvanceTo would end the process (a failed assertion)
            raise UserInputError(f"advance_to t must not be before the simulation's time {self.context.get_time():g} s, "
                                 f"got {t:g}")
        try:
            if not self._initialized:
                self._initialized = True
                self.simulator.Initialize()
            status = self.simulator.AdvanceTo(t)
        except BaseException as err:
            if caused_by_interrupt(err):
                if isinstance(err, KeyboardInterrupt):
                    raise
                raise KeyboardInterrupt from err
            if not isinstance(err, (RuntimeError, ValueError)):
                raise
            self.failure = ((self._checked[0] if self._checked else self.monitor.failure)
                            or f"at t = {self.context.get_time():.4f} s: {' '.join(str(err).split())}")
            return self.failure
        self.stopped = status.reason() == SimulatorStatus.ReturnReason.kReachedTerminationCondition
        return None

    def restart(self) -> None:
        """Start over from the initial context (time, state, parameters; needs ``restartable``):
        the watchdog's schedule and failure and the quasi-static engine's failure are cleared and
        the next advance initialises the Simulator again (its real-time pacing too)."""
        if self._initial is None:
            raise RuntimeError("StationRunner.restart needs restartable=True")
        self.context.SetTimeStateAndParametersFrom(self._initial)
        self.monitor.restart()
        self.cd.chain.clear_failure()
        self._checked.clear()
        self._initialized, self.stopped, self.failure = False, False, None


def run_station(cd: Station, *, duration: float, monitor: ChainMonitor | None = None, stop=None,
                check=None, context=None, progress: str | None = None, progress_step: float | None = None,
                html: Path | None = None, meshcat=None, realtime_rate: float | None = None,
                freeze_gc: bool = False) -> RunOutcome:
    """Run a built station for ``duration`` simulated seconds and return its ``RunOutcome``.

    The one Simulator loop of the scenario runs, the teleoperation tasks and the force pin
    (``StationRunner``, advanced once to ``duration``).

    The Simulator's monitor runs after Initialize and after every step: ``check`` first, then
    the watchdog (``monitor``), then the progress bar, then ``stop``. A failure of ``check`` or
    of the watchdog, or a RuntimeError / ValueError of the solver, ends the run with its message
    in ``RunOutcome.failure`` (no exception). On Ctrl-C the replay recorded so far is written to
    ``html`` before the KeyboardInterrupt goes on (also when it comes just after the run, while
    the replay is being written). Neither ``check`` nor ``stop`` nor the
    watchdog changes the trajectory (they only read the state).

    Args:
        cd: the built station (``MakeStation``).
        duration: simulated-time limit [s].
        monitor: the watchdog (default: ``ChainMonitor(cd)``).
        stop: None, or ``stop(root_context) -> bool``: end the run (a termination) when True.
        check: None, or ``check(root_context) -> str | None``: the run's own failure test, called
            before the watchdog; a message ends the run with it as ``RunOutcome.failure``.
        context: None (the diagram's default context; with the scenario's ``random_seed``, a
            context randomised with ``RandomGenerator(random_seed)``:
            ``randomness.set_random_context``), or a root context of ``cd.diagram`` to start from
            (an initial state set by the caller, used as it is); the Simulator runs in it.
        progress: None (no bar), or the label of a tqdm bar of the simulated time on stderr.
        progress_step: update the bar every this many simulated seconds (default duration/200).
        html: record the run in Meshcat and write the replay (self-contained HTML) here; the
            diagram must have been built with ``meshcat`` (the path is checked by the caller).
        meshcat: the Meshcat the diagram was built with (needed with ``html``).
        realtime_rate: the Simulator's target real-time rate (None: the scenario's
            ``simulator_config.target_realtime_rate``, 0 by default: as fast as possible).
        freeze_gc: freeze the objects alive at the start for the run (``frozen_gc``: a
            process-wide switch, for a program that owns its process).

    Returns:
        RunOutcome.

    Raises:
        UserInputError: before the run, for a ``cd`` that is not a Station, a ``duration`` that is
            not a finite time > 0, ``html`` without a Meshcat in the station, and a ``progress``,
            ``progress_step`` or ``realtime_rate`` of the wrong kind.

    Example:
        Run a station for 50 ms of simulated time and read the tip::

            >>> import ballchain as bc
            >>> station = bc.MakeStation(bc.load_scenario("free_space_uniform_90deg", "{n_balls: 6}"))
            >>> outcome = bc.run_station(station, duration=0.05)
            >>> outcome.failure, outcome.stopped, [round(1e3 * float(v), 1) for v in outcome.tip_position[:2]]
            (None, False, [14.9, 3.9])
    """
    check_run_arguments(cd, "run_station", monitor=monitor, stop=stop, check=check, context=context, html=html)
    require_positive(duration, "run_station duration")
    if progress is not None and not isinstance(progress, str):
        raise UserInputError(f"run_station progress must be a label (str) or None, got {short_repr(progress)}")
    if progress_step is not None:
        require_positive(progress_step, "run_station progress_step")
    if realtime_rate is not None:
        require_positive(realtime_rate, "run_station realtime_rate", allow_zero=True)
    if html is not None and cd.visualizer is None:
        raise UserInputError("run_station html needs a station built with a Meshcat (MakeStation(scenario, "
                             "meshcat=...)): this one has none to record")
    bar = None
    if progress is not None:
        from tqdm import tqdm

        bar = tqdm(total=duration, desc=progress, unit="sim s", file=sys.stderr,
                   bar_format="{l_bar}{bar}| {n:.3g}/{total:.3g} sim s [{elapsed}<{remaining}]")
    step = duration / 200 if progress_step is None else progress_step
    shown = [0.0]

    def show(t):
        if t - shown[0] >= step:
            bar.update(t - shown[0])
            shown[0] = t

    runner = StationRunner(cd, monitor=monitor, stop=stop, check=check, on_time=None if bar is None else show,
                           context=context, realtime_rate=realtime_rate)
    root = runner.context
    record = cd.visualizer is not None and html is not None
    if record:
        cd.visualizer.StartRecording()
    try:
        with frozen_gc(freeze_gc):
            start, cpu = time.perf_counter(), time.process_time()
            failure = runner.advance_to(duration)
        if bar is not None:  # the bar shows where the run ended; a task that ended early ends at 100 %
            end = root.get_time()
            if runner.stopped and failure is None:
                bar.total = end
            bar.update(end - shown[0])
    except KeyboardInterrupt:  # Ctrl-C: keep the replay, stop
        if record:
            _keep_replay(cd, meshcat, html, progress, root)
        raise
    finally:
        if bar is not None:
            bar.close()
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    if record:
        try:
            _export_recording(cd, meshcat, html)
        except KeyboardInterrupt:  # Ctrl-C just after the run ended, while its replay was written
            _keep_replay(cd, meshcat, html, progress, root)
            raise
    return RunOutcome(root.get_time(), wall, cpu, failure, runner.stopped, runner.monitor, root, runner.simulator, cd)


def run_simulation(*, scenario: ChainScenario, duration: float | None = None, html: Path | None = None,
                   meshcat=None, heart: Atrium | None = None, progress: bool = False) -> SimulationMetrics:
    """Simulate a scenario and return its metrics.

    Args:
        scenario: the (validated) scenario.
        duration: simulated time [s] (default: the scenario's).
        html: write a self-contained Meshcat recording to this file.
        meshcat: a Meshcat to use (a localhost one is started when ``html`` is given).
        heart: a prebuilt atrium to reuse.
        progress: show a progress bar of the simulated time on stderr.

    Returns:
        The run's ``SimulationMetrics`` (with the ball centres ``p_W_mm``).

    Raises:
        SimulationFailure: NaN, escape or break (message says when and which ball); its
            ``metrics`` are the run's up to the failure (no ``p_W_mm``).
    """
    require_type(scenario, ChainScenario, "run_simulation scenario", "a ChainScenario (load_scenario(name))")
    require_bool(progress, "run_simulation progress")
    if html is not None and (isinstance(html, bool) or not isinstance(html, (str, os.PathLike))):
        raise UserInputError(f"run_simulation html must be a file name (str or Path) or None, got {short_repr(html)}")
    duration = scenario.duration if duration is None else duration
    check_steps(scenario, duration, "duration")
    if html is not None:
        check_output_file(html, "html", expected_bytes=replay_bytes(scenario, duration))
    if html is not None and meshcat is None:
        meshcat = replay_meshcat()
    cd = MakeStation(scenario, meshcat=meshcat, heart=heart)
    run = run_station(cd, duration=duration, progress="simulate" if progress else None, html=html, meshcat=meshcat)
    monitor, root, error = run.monitor, run.context, run.failure
    chain = cd.chain
    plant_context = chain.system.GetMyContextFromRoot(root)
    wall, sim_time = run.wall_time, run.sim_time
    step = chain.time_step
    metrics = SimulationMetrics(
        realtime_factor=round(sim_time / wall, 4) if wall > 0 else None,
        sim_time_s=round(sim_time, 6),
        **monitor.metrics(plant_context),
        wall_time_s=round(wall, 3),
        build_time_s=round(cd.build_time_s, 3),
        time_step_s=step,
        mode=scenario.mode,
        engine=scenario.engine,
        n_steps=int(round(sim_time / step)),
        targets_touched=_targets_touched(cd, root),
        tip_wall_force_N=_tip_wall_force(cd, root),
        # ru_maxrss is in KiB on Linux: the process's peak resident set size so far (the whole
        # process, not this run alone).
        peak_memory_MB=round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
        statics=chain.solver_stats(),
        html=str(html) if cd.visualizer is not None and html is not None else None,
    )
    if error is not None:
        raise SimulationFailure(f"simulation stopped: {error}", metrics)
    metrics.p_W_mm = (chain.body_positions(plant_context) * 1e3).round(4).tolist()
    return metrics
