import pytest
"""Executes notebooks/actuation.ipynb (short settings) with nbclient in a temporary directory."""

import shutil
from pathlib import Path

import nbformat
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "actuation.ipynb"


def test_notebook_is_committed_without_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None


@pytest.mark.slow
def test_actuation_notebook_runs(tmp_path, monkeypatch):
    monkeypatch.setenv("BALLCHAIN_NOTEBOOK_LONG", "0")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    path = tmp_path / NOTEBOOK.name
    shutil.copy(NOTEBOOK, path)
    nb = nbformat.read(path, as_version=4)
    client = NotebookClient(nb, timeout=120, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    text = "\n".join(
        o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.get("output_type") == "stream"
    )
    # The short study converged on every run and the antiparallel start finished.
    assert "'converged': 3" in text
    assert "antiparallel: done at" in text
