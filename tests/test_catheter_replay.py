"""The manual catheter's Meshcat replay (``ballchain teleop --device steerable_catheter --html``)."""

from __future__ import annotations

import base64
import re

import msgpack
import numpy as np
import pytest

from ballchain.experiments import manual_catheter as mc
from ballchain.experiments.teleop import REPLAY_PERIOD


def _commands(page: str) -> list[dict]:
    """The Meshcat commands a StaticHtml page replays (base64 msgpack)."""
    blobs = re.findall(r'data:application/octet-binary;base64,([A-Za-z0-9+/=]+)"', page)
    return [msgpack.unpackb(base64.b64decode(b), raw=False, strict_map_key=False) for b in blobs]


@pytest.mark.slow
def test_catheter_replay_records_the_rod(tmp_path):
    """One second of the right task: the page draws the atrium and the targets and animates every
    rod node, a frame per replay period; the tip node's recorded path moves (the operator's
    probing turns the handle) and ends where the run left the tip."""
    html = tmp_path / "replay.html"
    result = mc.run(task="right", targets=1, time_limit=1.0, html=html)
    assert result.html == str(html)
    commands = _commands(html.read_text())
    paths = {c.get("path") for c in commands}
    assert "/drake/catheter_view/atrium" in paths and "/drake/catheter_view/targets/right_1" in paths
    (animation,) = [c for c in commands if c["type"] == "set_animation"]
    tracks = {a["path"]: a["clip"] for a in animation["animations"]}
    cat = mc.comparison_catheter()
    n_nodes = int(round(cat.model_length / cat.segment_length)) + 1
    assert {f"/drake/catheter_view/rod/{i}" for i in range(n_nodes)} <= set(tracks)
    tip = tracks[f"/drake/catheter_view/rod/{n_nodes - 1}"]
    assert tip["fps"] == pytest.approx(1.0 / REPLAY_PERIOD)
    keys = [k for t in tip["tracks"] if t["name"] == ".position" for k in t["keys"]]
    assert len(keys) >= round(1.0 / REPLAY_PERIOD)
    path = np.array([k["value"] for k in keys])
    assert np.ptp(path, axis=0).max() > 1e-4  # it moved by more than 0.1 mm
    end = np.asarray(result.settings["path"]["tip"][-1])  # the tip's end, a tip radius beyond the node
    assert np.linalg.norm(path[-1] - end) == pytest.approx(cat.radius, abs=1e-6)


def test_catheter_replay_bad_path_refused_before_the_run(tmp_path, capsys):
    """A replay path that is a folder is one line, exit status 2, before the run."""
    from ballchain.cli import main

    code = main(["teleop", "--device", "steerable_catheter", "--targets", "1", "--html", str(tmp_path)])
    err = capsys.readouterr()
    assert code == 2 and "--html" in err.err and "folder" in err.err
    assert "\n" not in err.err.strip() and err.out == ""
