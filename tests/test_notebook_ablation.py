"""Executes notebooks/ablation.ipynb (short settings) and checks what it prints."""

import re
from pathlib import Path

import pytest

from notebook_runner import run_notebook

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "ablation.ipynb"


@pytest.mark.slow
def test_ablation_notebook_runs(tmp_path, monkeypatch):
    text = run_notebook(NOTEBOOK, tmp_path, monkeypatch)
    error = float(re.search(r"error ([-+0-9.]+) %", text).group(1))
    assert abs(error) < 0.5  # the hemisphere's spreading resistance, as in tests/test_ablation.py
    assert text.count("Omega=1") == 2 and "magnet: the tip ball peaks at" in text
    assert (tmp_path / "ablation_fields.png").exists()
