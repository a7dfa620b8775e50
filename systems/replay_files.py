"""A run's Meshcat replay file: its size before the run (``replay_bytes``), a recording Meshcat
started without stop signals in its threads (``replay_meshcat``), and what the page says over the
scene (``captioned_replay``: what the run is, the simulated time, a legend; the camera then
frames the atrium and the magnets). ``chain_simulation.run_station`` writes it; ``chain_simulation`` re-exports these.
"""

from __future__ import annotations

import json
from html import escape as html_escape
from pathlib import Path

from ballchain.systems.chain_scenario import ChainScenario
from ballchain.systems.meshcat_overlays import (FIELD_ARROW_RGBA, FORCE_ARROW_RGBA, TARGET_OUTLINE_RGBA, TARGET_RGBA,
                                                 TOUCHED_RGBA)
from ballchain.systems.meshcat_view import MARGIN, MESHCAT_FOV_DEG, TARGET_CENTRE_RGBA, VIEW_DIRECTION_W


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


def replay_caption(scenario: ChainScenario) -> str:
    """What the replay page says the run is: the scenario's description, the device, the
    engine (and mode), the random seed and the anatomy file it ran on (the built-in atrium
    when none)."""
    parts = [scenario.description.strip() or "ball-chain run",
             f"device: {scenario.device}",
             f"{scenario.mode}, {scenario.engine} engine",
             f"seed: {'none' if scenario.random_seed is None else scenario.random_seed}",
             f"anatomy: {Path(scenario.anatomy).name}" if scenario.anatomy else "anatomy: the built-in atrium"]
    return " | ".join(parts)


# The legend's rows: (swatch CSS, label, the Meshcat path (under /drake) whose presence shows the
# row, or "" for always). Colours as drawn: meshcat_overlays' targets and arrows, the chain's balls
# (engine_geometry), the magnets (station, station_units).
def _hex(rgba) -> str:
    return "#" + "".join(f"{round(255 * c):02x}" for c in (rgba.r(), rgba.g(), rgba.b()))


def _hex_tuple(rgba) -> str:
    return "#" + "".join(f"{round(255 * c):02x}" for c in rgba[:3])


def _legend_rows() -> list[tuple[str, str, str]]:
    disc = "display:inline-block;width:12px;height:12px;border-radius:50%;vertical-align:middle"
    bar = "display:inline-block;width:16px;height:4px;vertical-align:middle"
    return [
        (f"{disc};background:linear-gradient(90deg,#bfbfc7 50%,#73737f 50%)", "the chain (balls; red: north)",
         "visualizer"),
        (f"{disc};background:{_hex(TARGET_RGBA)}", "target, not touched yet", "overlays/targets"),
        (f"{disc};background:{_hex(TOUCHED_RGBA)};box-shadow:0 0 0 2px {_hex(TARGET_OUTLINE_RGBA)},0 0 0 3px #555",
         "target touched (white rim)", "overlays/targets"),
        (f"{disc};width:6px;height:6px;margin:3px;background:{_hex_tuple(TARGET_CENTRE_RGBA)};box-shadow:0 0 0 1px #555",
         "target centre", "overlays/targets"),
        (f"{disc};border-radius:3px;background:#999aa6;border-top:3px solid #d91a1a", "magnet (red: north)",
         "units|magnets"),
        (f"{bar};background:{_hex(FIELD_ARROW_RGBA)}", "field at the tip (1 mm per mT)", "overlays/tip_field"),
        (f"{bar};background:{_hex(FORCE_ARROW_RGBA)}", "wall force on the tip (10 mm per 0.1 N)",
         "overlays/tip_contact_force"),
    ]


# The page's script: the clock (the Meshcat animation's current time: ``viewer.animator``, the
# time the Animations folder's slider shows), the legend's rows for what the scene holds, the
# targets touched by now, and once the scene has loaded the camera on the atrium and the magnets.
_SCRIPT = """
(function () {
  const FRAMING = %(framing)s;
  const $ = id => document.getElementById(id);
  const node = path => { let n = viewer.scene_tree;
    for (const k of path) { if (!n.children || !(k in n.children)) return null; n = n.children[k]; } return n; };
  const drake = p => node(["drake"].concat(p.split("/")));
  const visible = n => { for (let o = n && n.object; o; o = o.parent) if (!o.visible) return false; return !!n; };
  let framed = false, started = performance.now();
  function frameMagnets() {
    // The box (three.js world, y up) of the heart's wall and the magnets, then the camera as
    // meshcat_view.camera_pose_for_box places it.
    const parts = [];
    for (const p of ["visualizer/heart_wall"]) { const n = drake(p); if (n) parts.push(n.object); }
    for (const p of ["units", "magnets"]) { const n = drake(p); if (n) parts.push(n.object); }
    if (parts.length < 2) return false;
    let lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (const root of parts) {
      root.updateMatrixWorld(true);
      root.traverse(o => { if (!o.geometry || !o.visible) return;
        if (!o.geometry.boundingBox) o.geometry.computeBoundingBox();
        const b = o.geometry.boundingBox.clone().applyMatrix4(o.matrixWorld);
        [b.min.x, b.min.y, b.min.z].forEach((v, i) => lo[i] = Math.min(lo[i], v));
        [b.max.x, b.max.y, b.max.z].forEach((v, i) => hi[i] = Math.max(hi[i], v)); });
    }
    if (!(lo[0] < hi[0])) return false;
    const d = FRAMING.direction, u = [d[0], d[2], -d[1]], nu = Math.hypot(...u);
    for (let i = 0; i < 3; i++) u[i] /= nu;
    const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let right = cross(u.map(v => -v), [0, 1, 0]); const nr = Math.hypot(...right); right = right.map(v => v / nr);
    const up = cross(right, u.map(v => -v));
    const centre = lo.map((v, i) => 0.5 * (v + hi[i])), half = lo.map((v, i) => 0.5 * (hi[i] - v));
    const tanHalf = Math.tan(0.5 * FRAMING.fov * Math.PI / 180);
    let dist = 0;
    for (const sx of [-1, 1]) for (const sy of [-1, 1]) for (const sz of [-1, 1]) {
      const c = [sx * half[0], sy * half[1], sz * half[2]];
      dist = Math.max(dist, dot(c, u) + Math.max(Math.abs(dot(c, right)), Math.abs(dot(c, up))) / tanHalf);
    }
    dist *= FRAMING.margin;
    viewer.handle_command({type: "set_target", value: centre});
    viewer.handle_command({type: "set_property", path: "/Cameras/default/rotated/<object>", property: "position",
                           value: centre.map((v, i) => v + dist * u[i])});
    return true;
  }
  function tick() {
    const a = viewer.animator;
    if (a) {
      const t = Number(a.time) || 0;  // what the Animations folder's time shows (its slider sets it too)
      $("ballchain-time").textContent = "t = " + t.toFixed(2) + " s" + (a.duration > 0 ? " of " + a.duration.toFixed(2) + " s" : "");
    }
    for (const row of document.querySelectorAll("#ballchain-legend [data-path]")) {
      const shown = row.dataset.path.split("|").some(p => drake(p));
      row.style.display = shown ? "" : "none";
    }
    const targets = drake("overlays/targets");
    if (targets) {
      const names = Object.keys(targets.children).filter(k => visible(targets.children[k].children["touched"]))
        .sort((a, b) => a.localeCompare(b, undefined, {numeric: true}));  // right_2 before right_10
      $("ballchain-touched").textContent = "touched by now: " + (names.length ? names.join(", ") : "none");
    }
    if (!framed && FRAMING.magnets && ((a && a.duration > 0) || performance.now() - started > 3000)) framed = frameMagnets();
    requestAnimationFrame(tick);
  }
  requestAnimationFrame(tick);
})();
"""


def replay_overlay(caption: str) -> str:
    """The HTML put over a replay page: the ``caption`` (``id="ballchain-caption"``), the
    simulated time (``ballchain-time``), the targets touched by the time shown, the legend
    (``ballchain-legend``), and the script that keeps them (and frames the magnets)."""
    box = ("position:fixed;z-index:10;font:13px sans-serif;color:#111;background:rgba(255,255,255,0.82);"
           "padding:4px 8px;border-radius:4px;pointer-events:none")
    rows = "".join(f'<div data-path="{html_escape(path)}"><span style="{html_escape(swatch)}"></span> '
                   f'{html_escape(label)}</div>' for swatch, label, path in _legend_rows())
    framing = {"direction": list(VIEW_DIRECTION_W), "fov": MESHCAT_FOV_DEG, "margin": MARGIN, "magnets": True}
    return (f'<div style="{box};top:6px;left:10px;max-width:60vw">'
            f'<div id="ballchain-caption">{html_escape(caption)}</div>'
            f'<div id="ballchain-time" style="font:bold 18px monospace;margin-top:2px">t = 0.00 s</div>'
            f'<div id="ballchain-touched"></div></div>'
            f'<div id="ballchain-legend" style="{box};bottom:10px;left:10px;line-height:20px">{rows}</div>'
            f'<script id="ballchain-replay-script">{_SCRIPT % {"framing": json.dumps(framing)}}</script>')


def captioned_replay(page: str, caption: str | None) -> str:
    """The replay page with ``caption`` as its title and, over the scene, the caption in its
    top-left corner, the simulated time below it and the legend at the bottom left
    (``replay_overlay``); the page as it is without a caption."""
    if not caption:
        return page
    text = html_escape(caption)
    page = page.replace("<head>", f"<head><title>{text}</title>", 1)
    label = replay_overlay(caption)
    at = page.rfind("</body>")
    return page + label if at < 0 else page[:at] + label + page[at:]
