"""A run's Meshcat replay file: its size before the run (``replay_bytes``), a recording Meshcat
started without stop signals in its threads (``replay_meshcat``), and the page's caption
(``captioned_replay``). ``chain_simulation.run_station`` writes it; ``chain_simulation`` re-exports these.
"""

from __future__ import annotations

from html import escape as html_escape
from pathlib import Path

from ballchain.systems.chain_scenario import ChainScenario


# The size of a Meshcat replay (``StaticHtml``): the page with its meshes, plus one pose per
# body per published frame (measured: 2.35 MB at t = 0 and 77 kB per simulated second at 32
# frames/s for 16 balls, about 150 bytes per body and frame).
REPLAY_BASE_BYTES = 2.5e6
REPLAY_BYTES_PER_BODY_FRAME = 200.0


def replay_bytes(scenario: ChainScenario, duration: float) -> float:
    """About how big the replay of ``duration`` simulated seconds of ``scenario`` is [bytes]
    (for the free-space check before the run; an estimate on the high side)."""
    frames = duration / scenario.visualization.publish_period
    bodies = scenario.n_balls + 8  # the balls, the sheath, the magnets and the units' parts
    return REPLAY_BASE_BYTES + frames * bodies * REPLAY_BYTES_PER_BODY_FRAME


def replay_meshcat():
    """A Meshcat on localhost to record a replay file with (``html=``), without drake's "Meshcat
    listening for connections" line: in a batch run nobody is meant to connect, the file is the
    replay. Drake's logger is raised to WARNING while the server starts, then put back."""
    import logging

    from pydrake.geometry import Meshcat, MeshcatParams

    drake_logger = logging.getLogger("drake")
    level = drake_logger.level
    drake_logger.setLevel(max(logging.WARNING, drake_logger.getEffectiveLevel()))
    try:
        return without_stop_signals(lambda: Meshcat(MeshcatParams(host="localhost")))
    finally:
        drake_logger.setLevel(level)


STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")


def without_stop_signals(make):
    """``make()`` with the stop signals (SIGINT, SIGTERM, SIGHUP) blocked in this thread, so that
    the threads it starts (Meshcat's server) inherit the block: a stop signal then reaches the
    main thread only, where Python handles it (``cli.StopSignals``), never a server thread in
    the middle of a system call. Signals that arrive meanwhile wait, and come after."""
    import signal

    if not hasattr(signal, "pthread_sigmask"):
        return make()
    blocked = {getattr(signal, name) for name in STOP_SIGNALS if hasattr(signal, name)}
    before = signal.pthread_sigmask(signal.SIG_BLOCK, blocked)
    try:
        return make()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def replay_caption(scenario: ChainScenario) -> str | None:
    """What a replay names besides the scene: the anatomy file it ran on (None: the built-in atrium)."""
    return f"anatomy: {Path(scenario.anatomy).name}" if scenario.anatomy else None


def captioned_replay(page: str, caption: str | None) -> str:
    """The replay page with ``caption`` as its title and a line of text in its top-left corner."""
    if not caption:
        return page
    text = html_escape(caption)
    label = (f'<div id="ballchain-caption" style="position:fixed;top:6px;left:10px;z-index:10;'
             f'font:14px sans-serif;color:#222;background:rgba(255,255,255,0.7);padding:2px 6px">{text}</div>')
    page = page.replace("<head>", f"<head><title>{text}</title>", 1)
    at = page.rfind("</body>")
    return page + label if at < 0 else page[:at] + label + page[at:]
