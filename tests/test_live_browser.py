"""The live view in a real browser: headless Chromium (the system's, driven by Playwright) opens
the Meshcat page of ``run_live`` on localhost and presses keys on it, as a person would.

What is checked is what the person sees: the scene in the page (the tip ball's position, the
target discs' colour, read from the page's three.js scene tree), the page's pixels (the
readout panel), and the console lines. Screenshots go to the folder ``$LIVE_SHOTS`` names
(default: a new temporary directory). Every wait is for a condition, with a deadline.
"""

import os
import shutil
import tempfile
import threading
import time
import traceback
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
playwright_api = pytest.importorskip("playwright.sync_api", reason="playwright is in the test extras")
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(CHROMIUM is None, reason="needs the system's Chromium (apt-get install chromium)")]

VIEW = {"width": 960, "height": 540}  # small: the headless browser draws in software
DEADLINE = 30.0  # [s] wall time any one condition may take
# Meshcat frames at 10 Hz instead of 32 Hz: the headless browser draws in software (SwiftShader).
LIGHT = "{visualization: {publish_period: 0.1}}"

# The page's scene tree, in Drake's z-up world: three.js is y-up, (x, y, z)_three = (x, z, -y)_drake.
JS_BALL = """name => {
  let found = null;
  const walk = node => { for (const k in node.children) { if (found) return;
      if (k === name) { found = node.children[k]; return; } walk(node.children[k]); } };
  walk(viewer.scene_tree.find(["drake", "visualizer"]));
  if (!found) return null;
  const THREE_V = found.object.position.constructor;
  const p = new THREE_V(); found.object.getWorldPosition(p);
  return [p.x, -p.z, p.y];
}"""
# What the page holds, for a timeout's message: its websocket's state (1: open) and the number of
# the visualizer's nodes (one per ball and part; none while the scene is being redrawn).
JS_PAGE_STATE = """() => {
  const vis = viewer.scene_tree.find(["drake", "visualizer"]);
  return {socket: viewer.connection ? viewer.connection.readyState : null,
          visualizer_nodes: Object.keys(vis.children).length};
}"""
# The labels in the scene (meshcat_overlays.add_scene_labels): {group: names under /labels/<group>}.
JS_LABELS = """() => {
  const labels = viewer.scene_tree.find(["labels"]);
  const out = {};
  for (const g in labels.children) out[g] = Object.keys(labels.children[g].children);
  return out;
}"""
JS_TOUCHED = """() => {
  const targets = viewer.scene_tree.find(["drake", "overlays", "targets"]);
  return Object.keys(targets.children).filter(k => {
      const t = targets.children[k].children["touched"]; return t && t.object.visible; });
}"""


def _shots() -> Path:
    chosen = os.environ.get("LIVE_SHOTS")
    if chosen:
        try:
            Path(chosen).mkdir(parents=True, exist_ok=True)
            return Path(chosen)
        except OSError:
            pass
    return Path(tempfile.mkdtemp(prefix="live_shots_"))


def _wait(condition, what: str, deadline: float = DEADLINE, poll: float = 0.1, describe=None, ended=None):
    """``condition()`` once it is true; past the deadline an AssertionError naming ``what``, with
    ``describe()`` (what the test saw last) when given. ``ended()``, when given, says why the
    session behind the page can no longer make the condition true (None while it runs): then
    the AssertionError comes at once, with that reason, instead of at the deadline."""
    end = time.monotonic() + deadline
    while time.monotonic() < end:
        value = condition()
        if value:
            return value
        gone = None if ended is None else ended()
        if gone:
            raise AssertionError(f"waiting for {what}: {gone}")
        time.sleep(poll)
    seen = "" if describe is None else f"; {describe()}"
    raise AssertionError(f"timed out ({deadline:g} s) waiting for {what}{seen}")


def _same_twice(read, apart: float = 0.2):
    """``read()`` when two reads ``apart`` seconds apart agree (and are not None), else None."""
    first = read()
    time.sleep(apart)
    return first if first is not None and read() == first else None


def _session_ended(thread: threading.Thread, result: dict) -> str | None:
    """Why the live session's thread is no longer running (its exception with the traceback, or
    how it ended), or None while it runs."""
    if thread.is_alive():
        return None
    error = result.get("error")
    if error is not None:
        return "the live session raised " + "".join(traceback.format_exception(error))
    live = result.get("live")
    return f"the live session ended ({None if live is None else live.ended}, stops {getattr(live, 'stops', None)})"


def _panel_colour(page) -> np.ndarray:
    """The readout panel's background colour on the screen (RGB), from a screenshot's pixels a
    few pixels inside its top-left corner (``teleop.LIVE_STATUS_ANCHOR``, in screen heights)."""
    from io import BytesIO

    from PIL import Image

    from ballchain.experiments.teleop import LIVE_STATUS_ANCHOR

    image = Image.open(BytesIO(page.screenshot())).convert("RGB")
    h = VIEW["height"]
    x, y = int(VIEW["width"] / 2 + LIVE_STATUS_ANCHOR[0] * h) + 3, int(h / 2 - LIVE_STATUS_ANCHOR[1] * h) + 3
    return np.asarray(image.crop((x, y, x + 6, y + 4))).reshape(-1, 3).mean(axis=0)


def test_a_person_steers_the_chain_in_the_browser_into_a_vein_and_starts_over_after_a_stop():
    """Keys pressed on the page reach the station: the chain moves, a target turns vermillion; the tip
    goes down a vein (the left inferior) and the session goes on there; a stop of the watchdog
    (forced: nothing counts as inside, a stand-in for a real escape) pauses the session
    with the reason on the page (red panel), R starts over (the chain back at the start) and
    Escape ends it."""
    from ballchain.drake_models.heart import LeftAtrium
    from ballchain.experiments import teleop
    from ballchain.systems.meshcat_joystick import KEY_MAP
    from ballchain.systems.target_contact import heart_targets

    heart = LeftAtrium()
    n = 16
    lines, result = [], {}

    def live():  # Meshcat's buttons must be added from the thread that made the Meshcat: this one
        try:
            result["live"] = teleop.run_live(heart=heart, echo=lines.append, status_period=0.5, overrides=LIGHT)
        except BaseException as err:  # noqa: BLE001 - reported by the test
            result["error"] = err

    thread = threading.Thread(target=live, daemon=True)
    thread.start()

    def wait(condition, what: str, **kw):
        """``_wait``, ending at once when the session has died; on a timeout the last lines too."""
        kw.setdefault("describe", lambda: f"the last lines: {lines[-4:]}")
        return _wait(condition, what, ended=lambda: _session_ended(thread, result), **kw)

    shots = _shots()
    with playwright_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM,
                                     args=["--use-gl=swiftshader", "--enable-unsafe-swiftshader"])
        try:
            page = browser.new_page(viewport=VIEW)
            url = wait(lambda: next((ln.split()[1] for ln in lines if ln.startswith("Meshcat: ")), None),
                       "the URL", deadline=120)
            wait(lambda: any(ln.startswith("waiting for a browser") for ln in lines), "the wait for a browser")
            assert not any(ln.startswith("t = ") for ln in lines), "the clock started before the page connected"
            page.goto(url)
            tip = lambda: page.evaluate(JS_BALL, f"ball_{n}")  # noqa: E731
            wait(tip, "the chain on the page")
            wait(lambda: any(ln.startswith("t = ") for ln in lines), "the clock to start")
            # Where the chain rests at the start, read twice 0.2 s apart: the page draws a redrawn
            # scene message by message, each ball at the origin until its pose arrives, and the
            # chain sits still until the first key.
            p0 = np.array(wait(lambda: _same_twice(tip), "the chain at rest on the page"))
            # The page binds a key once it has the button's control: wait for all of them.
            wait(lambda: page.evaluate("() => Object.keys(viewer.keydown_callbacks).length") >= len(KEY_MAP),
                 "the page to bind the keys")
            page.mouse.click(5, VIEW["height"] - 5)  # focus on the page (a click, no drag: the view stays)
            # The scene names what it shows: every vein, every target (before it is touched: its
            # short name, "R5" for right_5), and the world's axes x, y, z.
            labels = wait(lambda: (lambda d: d if len(d.get("targets", [])) == len(heart_targets(heart)[0]) else None)(
                page.evaluate(JS_LABELS)), "the labels in the scene")
            assert sorted(labels["veins"]) == sorted(o.name for o in heart.ostia) == ["LIPV", "LSPV", "RIPV", "RSPV"]
            assert sorted(labels["triad"]) == ["x", "y", "z"]
            page.screenshot(path=shots / "01_start.png")
            # The readouts and the key map are text in the page (Meshcat's controls), not only pictures.
            for text in ("feed (ArrowUp)", "retract (ArrowDown)", "world mapping: stick axes 0, 1, 2",
                         "tip force on the wall"):
                wait(lambda: page.get_by_text(text).count(), f"{text!r} as page text")
            # Retract at the start: the feeder sits at its retraction stop (the start's length), the
            # command is dropped and the page says why; the chain stays (no watchdog stop).
            for _ in range(4):
                page.keyboard.press("ArrowDown")
            wait(lambda: page.get_by_text("retraction stop").count(), "the retraction stop in the page's text")
            assert "(command +0.0)" in [ln for ln in lines if ln.startswith("t = ")][-1]
            assert np.linalg.norm(np.array(tip()) - p0) < 1e-3
            page.screenshot(path=shots / "01b_retraction_stop.png")

            # Feed at full speed (4 presses of ArrowUp): the chain moves and touches a target.
            for _ in range(4):
                page.keyboard.press("ArrowUp")
            wait(lambda: np.linalg.norm(np.array(tip()) - p0) > 10e-3, "the tip to move 10 mm")
            touched = wait(lambda: page.evaluate(JS_TOUCHED), "a target to turn vermillion")
            page.screenshot(path=shots / "02_target_green.png")
            assert touched
            # The chain all out: ball 1 stops, the command against the stop is dropped (no wind-up:
            # it read +20 mm/s while the chain did not move) and the readout says why.
            wait(lambda: any("feeder: ball 1 +0.0 mm/s (command +0.0); the whole chain is out" in ln for ln in lines),
                 "ball 1 to stop at full insertion, the command dropped and said why")
            wait(lambda: page.get_by_text("the whole chain is out").count(), "the insertion stop in the page's text")
            page.screenshot(path=shots / "02b_whole_chain_out.png")

            # Turn the magnet about world y (W, full stick) until the tip is down a vein.
            # A person sees the stop on the readout before steering: Meshcat keeps no order between
            # the clicks read in one period, and a Space read with the W presses centres the stick
            # (the stop wins), which a lagging simulation in CI made happen. The feeder's command
            # already reads zero (dropped at the stop), so that readout cannot show the Space was
            # read: the session's clock a second on can (it reads the keys every period; one run in
            # about eight pressed W before the Space was read, and the stick stayed centred).
            page.keyboard.press("Space")
            t_space = _last_time(lines)
            wait(lambda: _last_time(lines) >= t_space + 1.0 and "(command +0.0)" in lines[-1],
                 "the session to read the Space (its clock 1 s on) with the feeder's command zero")
            for _ in range(4):
                page.keyboard.press("KeyW")
            wait(lambda: heart.in_veins(np.array(tip()))[0], "the tip to go down a vein",
                 describe=lambda: f"the tip on the page at {np.round(np.array(tip()) * 1e3, 1).tolist()} mm, "
                                  f"the last status lines: {lines[-3:]}")
            page.keyboard.press("Space")
            # The session goes on after the tip entered the vein (the watchdog's old rule stopped it
            # there). With the stick released the tip may slide back out within those 2 s of
            # real-time steering, so the check is the entry above and no stop after it.
            t_vein = float(_last_time(lines))
            wait(lambda: _last_time(lines) >= t_vein + 2.0, "2 s more of simulated time after the tip entered the vein")
            assert thread.is_alive() and not any(ln.startswith("stopped at") for ln in lines), "\n".join(lines)
            page.screenshot(path=shots / "03_tip_in_vein.png")
            calm = _panel_colour(page)

            # A stop of the watchdog: nothing counts as inside the heart any more, so every ball out
            # of the sheath has escaped (the ellipsoid without the veins was a stand-in that
            # depended on how far down the vein the real-time steering had taken the tip).
            heart.contains = lambda p: np.zeros(len(np.atleast_2d(p)), dtype=bool)
            wait(lambda: any(ln.startswith("paused") for ln in lines), "the pause")
            stop = next(ln for ln in lines if ln.startswith("stopped at"))
            assert "escaped the heart" in stop, stop
            red = wait(lambda: (lambda c: c.tolist() if c[0] > 2 * c[1] + 20 else None)(_panel_colour(page)),
                       "the red pause panel on the page")
            page.screenshot(path=shots / "04_paused.png")
            wait(lambda: page.get_by_text("PAUSED: the watchdog stopped the run").count(), "the pause as page text")
            assert thread.is_alive()
            assert calm[0] < 2 * calm[1] + 20 < red[0]  # grey while running, red when paused
            del heart.contains  # the real rule again

            # R starts over: the chain back where it started, the panel grey again.
            page.keyboard.press("KeyR")
            wait(lambda: "started over" in lines, "the restart")
            # (The page redraws the chain after the restart: the tip is missing for a moment.)
            wait(lambda: (lambda p: p is not None and np.linalg.norm(np.array(p) - p0) < 1e-3)(tip()),
                 "the chain back at the start",
                 describe=lambda: f"the tip on the page at {tip()}, p0 {p0.tolist()}, the page {page.evaluate(JS_PAGE_STATE)}, "
                                  f"the last status lines: {lines[-4:]}")
            wait(lambda: (lambda c: c.tolist() if c[0] < 2 * c[1] + 20 else None)(_panel_colour(page)),
                 "the grey readout panel again")
            page.screenshot(path=shots / "05_started_over.png")

            # The controls opened (the readouts and the keys as text), for the picture; in this small
            # window the open panel is taller than the page, which arrow keys and Space would scroll.
            page.get_by_text("Open Controls").click()
            wait(lambda: page.get_by_text("tip force on the wall").first.is_visible(), "the readout in the open controls")
            # (The readout's buttons are replaced as it changes: scroll the page, not to an element.)
            page.evaluate("() => window.scrollTo(0, document.body.scrollHeight)")
            page.screenshot(path=shots / "06_controls_as_text.png")
            page.evaluate("() => window.scrollTo(0, 0)")

            page.keyboard.press("Escape")
            thread.join(DEADLINE)
            assert not thread.is_alive()
        finally:
            if thread.is_alive():  # a failed check: end the session (Escape quits, also when paused)
                page.keyboard.press("Escape")
                thread.join(DEADLINE)
            browser.close()
    assert "error" not in result, result.get("error")
    live = result["live"]
    assert live.ended == "quit" and live.restarts == 1 and len(live.stops) == 1
    assert "escaped the heart" in live.stops[0]["reason"]
    assert live.wait_s > 0  # the clock waited for the page


def _last_time(lines) -> float:
    """The simulated time of the last console status line ("t = ... s ...")."""
    for ln in reversed(lines):
        if ln.startswith("t = "):
            return float(ln.split()[2])
    return -1.0
