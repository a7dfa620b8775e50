"""The README is a front door: short, with the two set-up commands, and a Python example that runs."""

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
MAX_README_BYTES = 10_000
SETUP_COMMANDS = (  # the two commands a new user copies: they stay byte for byte
    'python3 -m venv .venv && . .venv/bin/activate && pip install -e ".[test]" && ballchain reproduce --out results',
    'python3 -m venv .venv && . .venv/bin/activate && pip install -e ".[test]" && python -m pytest -q',
)
FLOAT = r"[-+]?\d+\.?\d*(?:[eE][-+]?\d+)?"


def python_blocks(text: str) -> list[str]:
    """The README's ```python code blocks, in order."""
    return re.findall(r"^```python\n(.*?)^```$", text, flags=re.S | re.M)


def printed_vectors(output: str) -> list[list[float]]:
    """Every printed numpy vector (``[a b c]``) in ``output``, as floats."""
    return [[float(x) for x in re.findall(FLOAT, inside)] for inside in re.findall(r"\[([^\]]*)\]", output)]


def test_readme_is_short_and_keeps_the_setup_commands():
    text = README.read_text()
    assert len(text.encode()) <= MAX_README_BYTES
    lines = text.splitlines()
    for command in SETUP_COMMANDS:
        assert command in lines
    blocks = python_blocks(text)
    assert len(blocks) == 1 and len(blocks[0].strip().splitlines()) <= 10


def test_readme_links_point_at_files_that_exist():
    text = README.read_text()
    targets = re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", text)
    assert targets
    for target in targets:
        assert (README.parent / target).exists(), target


@pytest.mark.slow
def test_readme_python_example_runs(tmp_path):
    (code,) = python_blocks(README.read_text())
    run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                         timeout=900, env={**os.environ, "MPLBACKEND": "Agg"})
    assert run.returncode == 0, run.stderr[-2000:]
    station_tip, statics_tip = printed_vectors(run.stdout)
    assert len(station_tip) == 3 and all(math.isfinite(x) for x in station_tip)
    # 16 touching balls of 3.175 mm from ball 1 at the origin: the tip is at most 15 diameters away,
    # and a field along +y bends it towards +y.
    assert len(statics_tip) == 3
    assert 0.0 < math.hypot(*statics_tip) <= 15 * 3.175e-3 + 1e-9
    assert statics_tip[1] > 0.0
