"""A replay explains itself: the page a run writes (``html=``) carries over its scene what the run
is (scenario, device, seed), the simulated time and a legend (``systems/replay_files.py``), and in
a real browser (the system's Chromium, driven by Playwright) the clock runs with the animation and
the legend shows. Screenshots go to the folder ``$REPLAY_SHOTS`` names (default: a temporary one).
"""

import os
import shutil
import time
from pathlib import Path

import pytest

from ballchain.systems.meshcat_overlays import TARGET_RGBA, TOUCHED_RGBA
from ballchain.systems.meshcat_view import TARGET_CENTRE_RGBA
from ballchain.systems.replay_files import captioned_replay, replay_overlay

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or "/usr/bin/chromium"


@pytest.fixture(scope="module")
def replay(tmp_path_factory) -> Path:
    """A short teleoperation run's replay (the right ring, one target)."""
    from ballchain.experiments import teleop

    html = tmp_path_factory.mktemp("replay") / "replay.html"
    result = teleop.run(task="right", targets=1, html=html, progress=False)
    assert result.html == str(html) and html.exists()
    # The targets the run touched, beside the page (the browser test reads them at the last frame).
    (html.parent / "touched.txt").write_text("\n".join(r["target"] for r in result.rows if r["touched"]))
    return html


def test_the_overlay_names_the_run_and_escapes_it():
    page = "<html><head><meta></head><body><div>scene</div></body></html>"
    assert captioned_replay(page, None) == page
    out = captioned_replay(page, "demo <1> | device: ball_chain | seed: 3")
    assert out.startswith("<html><head><title>demo &lt;1&gt; | device: ball_chain | seed: 3</title>")
    assert "<1>" not in out and out.endswith("</body></html>")
    for element in ('id="ballchain-caption"', 'id="ballchain-time"', 'id="ballchain-legend"',
                    'id="ballchain-touched"', 'id="ballchain-replay-script"'):
        assert out.index(element) < out.index("</body>")
    assert replay_overlay("demo <1> | device: ball_chain | seed: 3") in out


def test_the_written_replay_has_the_caption_legend_and_clock(replay):
    page = replay.read_text(encoding="utf-8")
    caption = page[page.index("<title>") + 7:page.index("</title>")]
    for part in ("device: ball_chain", "seed: ", "statics engine", "anatomy: the built-in atrium"):
        assert part in caption
    assert f'id="ballchain-caption">{caption}</div>' in page
    for label in ("the chain", "target, not touched yet", "target touched", "magnet", "field at the tip",
                  "wall force on the tip"):
        assert label in page
    # The legend's swatches are the colours the targets are drawn in (Okabe-Ito blue, vermillion).
    assert (TARGET_RGBA.r(), TARGET_RGBA.g(), TARGET_RGBA.b()) == (0.0, 0.447, 0.698) and "#0072b2" in page
    assert (TOUCHED_RGBA.r(), TOUCHED_RGBA.g(), TOUCHED_RGBA.b()) == (0.835, 0.369, 0.0) and "#d55e00" in page
    # The centre markers: Okabe-Ito yellow (#F0E442; they were green, the red-green pair on a
    # touched disc), in the legend too.
    assert TARGET_CENTRE_RGBA[:3] == (0.941, 0.894, 0.259) and "#f0e442" in page and "target centre" in page
    assert 'id="ballchain-time"' in page and "viewer.animator" in page and "requestAnimationFrame" in page


@pytest.mark.slow
def test_in_a_browser_the_clock_runs_and_the_legend_shows(replay):
    playwright_api = pytest.importorskip("playwright.sync_api", reason="playwright is in the test extras")
    if not Path(CHROMIUM).exists():
        pytest.skip("needs the system's Chromium (apt-get install chromium)")
    shots = Path(os.environ.get("REPLAY_SHOTS") or replay.parent)
    shots.mkdir(parents=True, exist_ok=True)
    clock = "() => document.getElementById('ballchain-time').textContent"

    def seconds(text: str) -> float:
        assert text.startswith("t = "), text
        return float(text.split()[2])

    def wait(condition, what: str, deadline: float = 10.0):
        end = time.monotonic() + deadline
        while time.monotonic() < end:
            value = condition()
            if value:
                return value
            time.sleep(0.1)
        raise AssertionError(f"timed out waiting for {what}")

    with playwright_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM,
                                     args=["--use-gl=swiftshader", "--enable-unsafe-swiftshader"])
        try:
            page = browser.new_page(viewport={"width": 960, "height": 540})
            errors = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(replay.as_uri())
            # The animation loads, then plays: the clock names its length, and advances.
            wait(lambda: " of " in page.evaluate(clock), "the animation to load")
            t0 = seconds(page.evaluate(clock))
            t1 = wait(lambda: (lambda t: t if t > t0 + 0.2 else None)(seconds(page.evaluate(clock))),
                      "the clock to advance")
            assert t1 > t0
            assert page.locator("#ballchain-legend").is_visible()
            assert page.locator("#ballchain-caption").is_visible()
            for label in ("the chain", "target, not touched yet", "target touched", "magnet"):
                assert page.get_by_text(label).first.is_visible(), label
            page.screenshot(path=shots / "replay_view.png")
            # The last frame shows the last touch: the run ends at its last target's touch, which
            # the overlays draw at that step (they drew it only at the next period, never reached).
            touched = sorted((replay.parent / "touched.txt").read_text().split())
            assert touched, "the one-target run touched nothing"
            page.evaluate("() => { const a = viewer.animator; a.pause(); a.seek(a.duration); }")
            shown = "() => document.getElementById('ballchain-touched').textContent"
            text = wait(lambda: (lambda t: t if t.startswith("touched by now: ") else None)(page.evaluate(shown)),
                        "the touched targets' line")
            wait(lambda: sorted(page.evaluate(shown).removeprefix("touched by now: ").split(", ")) == touched,
                 f"the last frame to show {touched} touched (the page: {text!r})")
            page.screenshot(path=shots / "replay_last_frame.png")
            assert not errors, errors
        finally:
            browser.close()


def test_the_framed_box_holds_the_extra_points():
    import numpy as np

    from ballchain.systems.meshcat_view import box_with_points

    lo, hi = box_with_points([-1, -1, -1], [1, 1, 1], None)
    assert lo.tolist() == [-1, -1, -1] and hi.tolist() == [1, 1, 1]
    lo, hi = box_with_points([-1, -1, -1], [1, 1, 1], np.array([[-0.5, 3.0, 0.0], [-4.0, 0.0, 0.5]]))
    assert lo.tolist() == [-4, -1, -1] and hi.tolist() == [1, 3, 1]
