"""Live steering (``ballchain teleop --live``): a person drives the teleoperation station in Meshcat.

``run_live`` opens Meshcat, waits for a browser, and advances the station (``build_live``: the
station of ``live_scenario_for`` with ``MeshcatJoystick`` on every unit's stick and the feeder) in
real time, chunk by chunk, with the readouts between chunks and a pause on a watchdog stop.
``teleop`` re-exports every public name.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from ballchain.experiments._result import Result
from ballchain.experiments.teleop_station import MAPPINGS, SCENARIO, hand_over, load_for_hand_over


@dataclass
@dataclass
class LiveResult(Result):
    """What ``run_live`` returns.

    Attributes:
        url: the Meshcat URL.
        ended: "quit", "duration" or "failure" (the watchdog stopped it with nobody watching); a
            live view a person watches pauses on a failure instead (see ``stops``).
        failure: the last watchdog message (None: none).
        stops: every watchdog message, in order, with the simulated time it came at
            [{t_s, reason}]; restarts: how often the person started over after one.
        sim_time_s, wall_time_s: simulated time since the last start and the wall time since the
            clock started (the first browser connected) [s]; realtime_factor: simulated time over
            wall time in the advances (pauses not counted); target_realtime_rate: the one asked for.
        wait_s: wall time spent waiting for a browser [s].
        targets_touched: the targets' names; n_targets: how many the station has.
        tip_wall_force_N: the wall's force on the tip ball at the end (3,) [N].
        settings: {mapping, units, n_balls, time_step_s, overrides}.
    """

    url: str
    ended: str
    failure: str | None
    stops: list
    restarts: int
    sim_time_s: float
    wall_time_s: float
    realtime_factor: float | None
    target_realtime_rate: float
    wait_s: float
    targets_touched: list
    n_targets: int
    tip_wall_force_N: list
    settings: dict


LIVE_SCENARIOS = {"one": SCENARIO, "two": "teleop_two_units"}  # --units: the right unit, or both
LIVE_CHUNK = 0.05  # [s] simulated time per advance: quit, Ctrl-C and the readouts between chunks
LIVE_STATUS_PERIOD = 2.0  # [s] wall time between console status lines
# [s] wall time between updates of the page's readout panel: each is a new picture the page
# decodes (a software-drawing browser under load took over 0.5 s to; at 1.5 s the pictures show).
LIVE_PANEL_PERIOD = 1.5
LIVE_POLL = 0.05  # [s] wall time between looks at Meshcat while waiting (a browser, a reset)
# Where the page's panels go (``TextPanel``: top-left corners, screen heights from the centre):
# the readouts top left, the key map bottom left, the heart in the middle of the screen.
LIVE_STATUS_ANCHOR, LIVE_KEYS_ANCHOR = (-0.7, 0.44), (-0.7, -0.34)


MAX_LIVE_RATE = 100.0  # a person steering at more than 100 times real time sees nothing of it


def check_live_inputs(mapping: str, units: str, n_balls: int | None, duration: float | None,
                      realtime_rate: float) -> None:
    """Raises UserInputError naming the flag on bad input for ``run_live``."""
    from ballchain.infrastructure.errors import UserInputError, short_repr
    from ballchain.systems.chain_scenario import MAX_DURATION

    if mapping not in MAPPINGS:
        raise UserInputError(f"--mapping must be one of {tuple(MAPPINGS)}, got {short_repr(mapping)}")
    if units not in LIVE_SCENARIOS:
        raise UserInputError(f"--units must be one of {tuple(LIVE_SCENARIOS)} (the right unit, or both), "
                             f"got {short_repr(units)}")
    if n_balls is not None and n_balls < 3:
        raise UserInputError(f"--balls must be >= 3 (ball 1 stays in the sheath), got {n_balls}")
    if duration is not None and not (np.isfinite(duration) and 0 < duration <= MAX_DURATION):
        raise UserInputError(f"--duration must be in (0, {MAX_DURATION:g}] s of simulated time, got {duration}")
    if not (np.isfinite(realtime_rate) and 0 <= realtime_rate <= MAX_LIVE_RATE):
        raise UserInputError(f"--realtime-rate must be in [0, {MAX_LIVE_RATE:g}] (0: as fast as possible), "
                             f"got {realtime_rate}")


def live_scenario_for(mapping: str, units: str = "one", n_balls: int | None = None, overrides: str | None = None,
                      anatomy=None):
    """The teleoperation station with every unit's stick and the feeder left to a person.

    Args:
        mapping: "world" or "catheter" (every unit).
        units: "one" (``teleop_right_unit``) or "two" (``teleop_two_units``: both sides).
        n_balls: chain length (default: the scenario's 16).
        overrides: inline YAML overrides of the scenario (``--set``), applied first. The engine is
            ``DEFAULT_ENGINE`` (the quasi-static engine: real time for 16 balls; the plant runs at
            about a fifth of it) unless they name one, e.g. ``{engine: plant}``.
        anatomy: a loaded ``Anatomy``: the station on it, the units at its magnets (in order).
    """
    from ballchain.infrastructure.errors import UserInputError
    from ballchain.systems.chain_scenario import parse_overrides

    try:
        scenario = load_for_hand_over(LIVE_SCENARIOS[units], overrides)
    except UserInputError:
        raise
    except ValueError as err:
        raise UserInputError(f"--set: {err}") from None
    if anatomy is not None:
        from ballchain.systems.station import apply_anatomy

        apply_anatomy(scenario, anatomy)
    return hand_over(scenario, mapping, n_balls, parse_overrides(overrides))


class LiveSession:
    """A station driven by ``MeshcatJoystick``, ready to be advanced (``build_live``).

    The run loop is the station's (``chain_simulation.StationRunner``, as ``run_station``'s): the
    scenario's simulator_config, the watchdog, the quit button as the stop condition, advanced
    in chunks, and started over after a stop (``restart``).

    Attributes:
        cd: the Station; ``cd.added["meshcat_joystick"]`` is the joystick system.
        runner: the StationRunner; simulator: its Simulator; root: its root context.
        meshcat: the Meshcat (localhost).
        joystick: the MeshcatJoystick.
        chain_monitor: the ChainMonitor (watchdog).
        status: the page's readout panel (``TextPanel``, set by ``run_live``), or None.
    """

    def __init__(self, cd, runner, meshcat, joystick):
        self.cd, self.runner, self.meshcat, self.joystick = cd, runner, meshcat, joystick
        self.status = None
        self.simulator, self.root, self.chain_monitor = runner.simulator, runner.context, runner.monitor

    def advance_to(self, t: float) -> str | None:
        """Advance the simulation to time t [s].

        Returns:
            None (reached t), "quit" (the person asked to quit) or the watchdog's failure message.
        """
        failure = self.runner.advance_to(t)
        if failure is None and self.runner.stopped:
            return "quit"
        return failure

    def restart(self) -> None:
        """Start over from the initial state (after the watchdog stopped the run)."""
        self.runner.restart()

    def touched(self) -> list[str]:
        tracker = self.cd.target_touches
        return [] if tracker is None else tracker.touched_names(tracker.GetMyContextFromRoot(self.root))

    def tip_force_N(self) -> np.ndarray:
        """The wall's force on the tip ball now [N] (as the overlay's orange arrow)."""
        overlays = self.cd.meshcat_overlays
        if overlays is None:
            return np.zeros(3)
        return overlays.tip_contact_force(overlays.GetMyContextFromRoot(self.root))[0]

    def ball_1_along_sheath(self) -> float:
        """Ball 1's centre along the sheath axis from the sheath exit [m]: the chain's actual
        insertion (the feeder's speed is its rate of change)."""
        chain = self.cd.chain
        p = chain.ball_positions(chain.system.GetMyContextFromRoot(self.root))
        return float((p[0] - chain.p_WE) @ chain.sheath_axis_W)

    def joystick_state(self) -> tuple[str, np.ndarray, float]:
        """(selected unit, stick axes (3,), feeder command [m/s]) as sent now."""
        j = self.joystick
        ctx = j.GetMyContextFromRoot(self.root)
        unit = j.selected_unit(ctx)
        return unit, j.get_joystick_output_port(unit).Eval(ctx), float(j.GetOutputPort("v_insert_cmd").Eval(ctx)[0])

    def feeder_end_stop(self) -> int:
        """-1 at the feeder's retraction stop, +1 with the whole chain out, 0 between (or no feeder)."""
        from ballchain.systems.meshcat_joystick import end_stop

        feeder = self.cd.feeder
        if feeder is None:
            return 0
        length = feeder.GetOutputPort("inserted_length").Eval(feeder.GetMyContextFromRoot(self.root))[0]
        return end_stop(length, *feeder.end_stops())

    def feeder_note(self, v_cmd: float, v_ball_1: float) -> str | None:
        """What the readout says when the chain does not follow the feeder's command (at an end
        stop, where the command is dropped, or ball 1 slower than a quarter of it), else None."""
        stop, feeder = self.feeder_end_stop(), self.cd.feeder
        if stop > 0:
            return f"the whole chain is out ({self.cd.scenario.n_balls} balls): feed adds nothing"
        if stop < 0:
            return (f"retraction stop ({feeder.min_length * 1e3:.0f} mm out, where the run started): "
                    "retract adds nothing")
        if abs(v_cmd) > 1e-3 and abs(v_ball_1) < 0.25 * abs(v_cmd):
            return "the chain does not follow the command"
        return None

    def clicks(self, action: str) -> float:
        """Clicks so far of the key bound to ``action`` (Meshcat's count; read while paused)."""
        return sum(self.meshcat.GetButtonClicks(k.label) for k in self.joystick.keys if k.action == action)


def build_live(*, mapping: str = "world", units: str = "one", n_balls: int | None = None,
               overrides: str | None = None, meshcat=None, heart=None, realtime_rate: float = 1.0,
               joystick_period: float = 0.02, anatomy=None) -> LiveSession:
    """Build the station with ``MeshcatJoystick`` driving every unit's stick and the feeder.

    Args:
        mapping, units, n_balls, overrides: as ``live_scenario_for``.
        meshcat: a Meshcat to use (default: a new one on localhost).
        heart: a prebuilt atrium to reuse.
        realtime_rate: the simulator's target real-time rate (0: as fast as possible); the
            scenario's simulator_config applies otherwise.
        joystick_period: how often the joystick reads Meshcat [s] (simulated time).
        anatomy: an anatomy file or a loaded ``Anatomy`` (its surface, targets, sheath, units at
            its magnets) instead of the procedural atrium.
    """
    from pydrake.geometry import Meshcat, MeshcatParams

    from ballchain.systems.chain_simulation import (ChainMonitor, MakeStation, StationRunner, atrium_for,
                                                    near_ostium_rim, without_stop_signals)
    from ballchain.systems.meshcat_joystick import MeshcatJoystick
    from ballchain.systems.meshcat_overlays import add_scene_labels

    check_live_inputs(mapping, units, n_balls, None, realtime_rate)
    if anatomy is not None:
        from ballchain.drake_models.anatomy import Anatomy, load_anatomy

        anatomy = anatomy if isinstance(anatomy, Anatomy) else load_anatomy(anatomy)
        heart = anatomy.atrium()
    scenario = live_scenario_for(mapping, units, n_balls, overrides, anatomy)
    meshcat = meshcat if meshcat is not None else without_stop_signals(
        lambda: Meshcat(MeshcatParams(host="localhost")))
    heart = heart or atrium_for(scenario)

    def add_joystick(builder, ports):
        # The stepper feeder's end stops reach the joystick (a command against one is dropped).
        feeder = builder.GetSubsystemByName("feeder") if builder.HasSubsystemNamed("feeder") else None
        if feeder is not None:
            # Retraction stops at the start's length: holding retract leaves the chain's first
            # balls out in the heart (pulled back into the sheath, the watchdog stopped the run).
            feeder.set_min_length(scenario.insertion.initial)
        j = builder.AddSystem(MeshcatJoystick(meshcat, list(ports.joystick_inputs), period=joystick_period,
                                              end_stops=None if feeder is None else feeder.end_stops()))
        for name, port in ports.joystick_inputs.items():
            builder.Connect(j.get_joystick_output_port(name), port)
        builder.Connect(j.GetOutputPort("v_insert_cmd"), ports.feeder_command_input)
        if feeder is not None:
            builder.Connect(feeder.GetOutputPort("inserted_length"), j.GetInputPort("feeder_inserted_length"))
        add_scene_labels(meshcat, ports.heart, ports.targets)
        return {"meshcat_joystick": j}

    cd = MakeStation(scenario, meshcat=meshcat, heart=heart, add_systems=add_joystick)
    joystick = cd.added["meshcat_joystick"]
    chain_monitor = ChainMonitor(cd, tolerate_sinking=lambda p: near_ostium_rim(heart, p))
    # The quit button ends an advance (a termination).
    runner = StationRunner(cd, monitor=chain_monitor, realtime_rate=realtime_rate, restartable=True,
                           stop=lambda context: joystick.quit_requested(joystick.GetMyContextFromRoot(context)))
    return LiveSession(cd, runner, meshcat, joystick)


def _panel_lines(session, mapping: str, omega: float) -> list[str]:
    """The page's key-map panel: the mapping and every binding, in a few lines."""
    from ballchain.systems.meshcat_joystick import key_map_compact

    head = (f"world mapping: stick axes 0, 1, 2 turn the magnet about world x, y, z (up to {omega:g} rad/s)"
            if mapping == "world" else
            f"catheter mapping: axes 0, 1 swing the tip's field about its z, -y (up to {omega:g} rad/s)")
    return [head] + key_map_compact(session.joystick.keys)


def run_live(*, mapping: str = "world", units: str = "one", n_balls: int | None = None,
             overrides: str | None = None, duration: float | None = None, realtime_rate: float = 1.0,
             meshcat=None, heart=None, echo=print, status_period: float = LIVE_STATUS_PERIOD,
             wait_for_browser: bool = True, freeze_gc: bool = False, anatomy=None) -> LiveResult:
    """Let a person steer the chain live in Meshcat with a gamepad or the keyboard.

    Opens Meshcat on localhost (or uses ``meshcat``), prints its URL and the key map, waits for a
    browser to open the page (the simulated clock starts then), and runs the station in real
    time (``realtime_rate``) until the person quits (Escape, Start), Ctrl-C, or ``duration``
    simulated seconds have passed. When the station is slower than real time it runs as fast as
    it can. The page shows the key map and a readout panel (time, the real-time rate achieved,
    targets touched, the wall's force on the tip, the feeder's actual speed: ball 1's along the
    sheath, and why the chain does not follow the command when it does not), both also as text
    in the page (Meshcat's controls); the scene names the veins and the targets and shows the
    world's axes (``meshcat_overlays.add_scene_labels``). Retraction stops at the start's
    length (the feeder's ``min_length``). When the watchdog stops the run (a ball out of the heart, the chain broken, a
    failed solve) while a browser is connected, the view pauses with the reason on the page
    until the person starts over (R) or quits; with nobody connected the run ends as a failure.

    Args:
        mapping: "world" or "catheter".
        units: "one" (the right unit) or "two" (both; N or RB switches the stick between them).
        n_balls: chain length (default 16).
        overrides: inline YAML overrides of the scenario (``--set``), e.g. the engine.
        duration: simulated-time limit [s] (None: until the person quits).
        realtime_rate: target real-time rate (1: real time; 0: as fast as possible).
        meshcat: a Meshcat to use (default: a new one on localhost).
        heart: a prebuilt atrium to reuse.
        echo: where the URL, the key map and the status lines go (``print``).
        status_period: wall time between status lines [s].
        wait_for_browser: start the clock when the first browser connects (False: at once).
        freeze_gc: freeze the objects alive after the build for the session
            (``chain_simulation.frozen_gc``; the command line asks for it).
        anatomy: an anatomy file or a loaded ``Anatomy`` instead of the procedural atrium
            (``build_live``).

    Returns:
        A ``LiveResult``.

    Raises:
        KeyboardInterrupt: Ctrl-C (after the summary line and removing the buttons).
    """
    from ballchain.systems.chain_simulation import frozen_gc

    check_live_inputs(mapping, units, n_balls, duration, realtime_rate)
    session = build_live(mapping=mapping, units=units, n_balls=n_balls, overrides=overrides, meshcat=meshcat,
                         heart=heart, realtime_rate=realtime_rate, anatomy=anatomy)
    scenario = session.cd.scenario
    meshcat = session.meshcat
    tracker = session.cd.target_touches
    n_targets = 0 if tracker is None else len(tracker.names)
    unit_names = session.joystick.unit_names
    status = _announce_live(session, mapping, realtime_rate, duration, echo)

    ended, stops, restarts = "duration", [], 0
    limit = np.inf if duration is None else float(duration)
    waited = time.perf_counter()
    advancing, simulated = 0.0, 0.0  # wall and simulated time in the advances [s] (pauses not counted)
    start = time.perf_counter()
    try:
        if wait_for_browser and meshcat.GetNumActiveConnections() == 0:
            _wait_for_browser(meshcat, status, echo)
        waited = time.perf_counter() - waited
        start = time.perf_counter()
        readout = _LiveReadout(session, status, echo, n_targets, status_period, start)
        with frozen_gc(freeze_gc):
            while session.root.get_time() < limit - 1e-12:
                t0, sim0 = time.perf_counter(), session.root.get_time()
                reason = session.advance_to(min(sim0 + LIVE_CHUNK, limit))
                advancing += time.perf_counter() - t0
                simulated += session.root.get_time() - sim0
                if reason == "quit":
                    ended = "quit"
                    break
                if reason is not None:
                    t_stop = session.root.get_time()
                    stops.append({"t_s": round(t_stop, 4), "reason": reason})
                    echo(f"stopped at t = {t_stop:.2f} s: {reason}")
                    if meshcat.GetNumActiveConnections() == 0:
                        ended = "failure"
                        break
                    if _pause_until_choice(session, status, reason, echo) == "quit":
                        ended = "quit"
                        break
                    session.restart()
                    restarts += 1
                    echo("started over")
                    readout.start_over(time.perf_counter())
                    continue
                readout.maybe_show(time.perf_counter())
    except KeyboardInterrupt:
        _end_live(session, echo, "interrupted", stops, time.perf_counter() - start, n_targets)
        raise
    wall = time.perf_counter() - start
    touched = _end_live(session, echo, ended, stops, wall, n_targets)
    sim_time = session.root.get_time()
    rate = round(simulated / advancing, 4) if advancing > 0 else None
    return LiveResult(url=meshcat.web_url(), ended=ended, failure=stops[-1]["reason"] if stops else None,
                      stops=stops, restarts=restarts, sim_time_s=round(sim_time, 4), wall_time_s=round(wall, 3),
                      realtime_factor=rate, target_realtime_rate=realtime_rate, wait_s=round(waited, 3),
                      targets_touched=touched, n_targets=n_targets,
                      tip_wall_force_N=[round(float(v), 6) for v in session.tip_force_N()],
                      settings={"mapping": mapping, "units": unit_names, "n_balls": scenario.n_balls,
                                "time_step_s": scenario.effective_time_step, "overrides": overrides,
                                "anatomy": scenario.anatomy or None})


def _announce_live(session, mapping: str, realtime_rate: float, duration: float | None, echo):
    """The URL, the settings and the key map on the terminal; the key-map panel on the page.

    Returns the page's status panel (also kept as ``session.status``).
    """
    from ballchain.systems.meshcat_joystick import key_map_text
    from ballchain.systems.meshcat_overlays import PageText, TextPanel

    scenario, meshcat = session.cd.scenario, session.meshcat
    omega = scenario.units[0].teleop_omega_max
    echo(f"Meshcat: {meshcat.web_url()}  (open it in a browser on this machine)")
    echo(f"steering {', '.join(session.joystick.unit_names)} with the {mapping} mapping, {scenario.n_balls} balls, "
         f"time step {scenario.effective_time_step * 1e3:g} ms, target real-time rate {realtime_rate:g}"
         + (f", for {duration:g} s" if duration is not None else ", until you quit (Escape, Start or Ctrl-C)"))
    echo(_panel_lines(session, mapping, omega)[0])
    echo(key_map_text(session.joystick.keys))
    echo("the targets turn from blue to vermillion when the tip touches them; the orange arrow is the wall's force on the tip")
    echo("the page's controls (Open Controls) hold the key map and the readouts as text")
    keys = TextPanel(meshcat, "keys", anchor=LIVE_KEYS_ANCHOR, width_px=1150)
    keys.show(_panel_lines(session, mapping, omega))
    keys.flush()
    # The same as page text (the key bindings are the joystick's buttons, above these lines).
    PageText(meshcat, "").show([_panel_lines(session, mapping, omega)[0]])
    status = session.status = TextPanel(meshcat, "status", anchor=LIVE_STATUS_ANCHOR, width_px=1150)
    status.page = PageText(meshcat, "")  # the readouts as page text too (_status_panel)
    return status


def _status_panel(status, lines: list[str], paused: bool = False) -> None:
    """The status panel's lines: white on dark grey, or yellow on red while paused."""
    status.show(lines, colour=(255, 235, 120) if paused else (255, 255, 255),
                background=(150, 20, 20) if paused else (20, 20, 20))
    page = getattr(status, "page", None)
    if page is not None:
        page.show(lines)


def _wait_for_browser(meshcat, status, echo) -> None:
    """Wait until a browser has the page open (the simulated clock starts then)."""
    echo("waiting for a browser to open the page (the clock starts then)")
    _status_panel(status, ["waiting for the page to connect"])
    status.flush()
    while meshcat.GetNumActiveConnections() == 0:
        time.sleep(LIVE_POLL)


def _pause_until_choice(session, status, reason: str, echo) -> str:
    """The watchdog's reason on the page until the person starts over or quits: "restart" or "quit"."""
    echo("paused: press R (or 'start over' in Meshcat's controls) to start over, Escape to quit")
    _status_panel(status, ["PAUSED: the watchdog stopped the run", *_wrap(reason, 80),
                           "R: start over from the beginning    Escape: quit"], paused=True)
    reset0, quit0 = session.clicks("reset"), session.clicks("quit")
    paused = time.perf_counter()
    while session.clicks("reset") == reset0 and session.clicks("quit") == quit0:
        if time.perf_counter() - paused > LIVE_PANEL_PERIOD:
            status.flush()  # the page has decoded the pause panel by now
            status.redraw()
            paused = time.perf_counter()
        time.sleep(LIVE_POLL)
    return "quit" if session.clicks("quit") != quit0 else "restart"


class _LiveReadout:
    """The live readout: the page's status panel every ``LIVE_PANEL_PERIOD`` and a status line every
    ``status_period`` of wall time, with rates measured since the last readout."""

    def __init__(self, session, status, echo, n_targets: int, status_period: float, now: float):
        self.session, self.status, self.echo = session, status, echo
        self.n_targets, self.status_period = n_targets, status_period
        self.start_over(now)

    def start_over(self, now: float) -> None:
        """Measure from ``now`` and the chain's start (at the session's start and after a restart)."""
        self.last_wall = self.last_panel = self.last_line = now
        self.last_sim, self.last_ball_1 = 0.0, self.session.ball_1_along_sheath()

    def maybe_show(self, now: float) -> None:
        """The panel and the status line, each when due."""
        from ballchain.drake_models.params import gram_force

        session, n_targets = self.session, self.n_targets
        panel_due = now - self.last_panel >= LIVE_PANEL_PERIOD
        line_due = now - self.last_line >= self.status_period
        if not (panel_due or line_due):
            return
        t = session.root.get_time()
        unit, stick, v_cmd = session.joystick_state()
        ball_1 = session.ball_1_along_sheath()
        # Measured since the last readout: the chain's actual insertion, not the command.
        v_ball_1 = (ball_1 - self.last_ball_1) / (t - self.last_sim) if t > self.last_sim else 0.0
        rate = (t - self.last_sim) / (now - self.last_wall)
        f_gf = gram_force(float(np.linalg.norm(session.tip_force_N())))
        touched = session.touched()
        follow = session.feeder_note(v_cmd, v_ball_1)
        if panel_due:
            _status_panel(self.status, [
                f"t = {t:.1f} s   real-time rate {rate:.2f}   {unit}",
                f"targets touched {len(touched)}/{n_targets}" + (f": {', '.join(touched[-4:])}" if touched else ""),
                f"tip force on the wall {f_gf:.1f} gf",
                f"feeder: ball 1 moves {v_ball_1 * 1e3:+.1f} mm/s (command {v_cmd * 1e3:+.1f} mm/s)"]
                + ([follow] if follow else []))
            session.meshcat.SetRealtimeRate(rate)
            self.last_panel = now
        if line_due:
            self.echo(f"t = {t:7.2f} s  real-time rate {rate:5.2f}  targets {len(touched)}/{n_targets}  "
                      f"tip force {f_gf:5.1f} gf  {unit} stick {np.round(stick, 2).tolist()}  "
                      f"feeder: ball 1 {v_ball_1 * 1e3:+.1f} mm/s (command {v_cmd * 1e3:+.1f})"
                      + (f"; {follow}" if follow else ""))
            self.last_line = now
        self.last_wall, self.last_sim, self.last_ball_1 = now, t, ball_1


def _wrap(text: str, width: int) -> list[str]:
    import textwrap

    return textwrap.wrap(text, width) or [""]


def _end_live(session, echo, ended: str, stops: list, wall: float, n_targets: int) -> list[str]:
    """The summary line; the buttons removed from the page and the panel says the session ended."""
    sim_time = session.root.get_time()
    touched = session.touched()
    failure = stops[-1]["reason"] if ended == "failure" else None
    echo(f"ended ({ended}{': ' + failure if failure else ''}) at t = {sim_time:.2f} s after {wall:.1f} s, "
         f"{len(touched)}/{n_targets} targets touched" + (f" ({', '.join(touched)})" if touched else "")
         + (f", {len(stops)} stop(s)" if stops else ""))
    session.joystick.remove_buttons()
    session.status.show([f"the session ended ({ended}) at t = {sim_time:.1f} s"])
    session.status.flush()
    return touched
