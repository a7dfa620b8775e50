"""Executes notebooks/actuation.ipynb (short settings) and checks what it prints."""

from pathlib import Path

import pytest

from notebook_runner import run_notebook

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "actuation.ipynb"


@pytest.mark.slow
def test_actuation_notebook_runs(tmp_path, monkeypatch):
    text = run_notebook(NOTEBOOK, tmp_path, monkeypatch)
    # The short study converged on every run and the antiparallel start finished.
    assert "'converged': 3" in text
    assert "antiparallel: done at" in text
