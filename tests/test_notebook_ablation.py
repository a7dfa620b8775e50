"""Executes notebooks/ablation.ipynb (short settings) with nbclient in a temporary directory."""

import re
import shutil
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "ablation.ipynb"


def test_notebook_is_committed_without_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None


@pytest.mark.slow
def test_ablation_notebook_runs(tmp_path, monkeypatch):
    monkeypatch.setenv("BALLCHAIN_NOTEBOOK_LONG", "0")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    path = tmp_path / NOTEBOOK.name
    shutil.copy(NOTEBOOK, path)
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    text = "\n".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs
                     if o.get("output_type") == "stream")
    error = float(re.search(r"error ([-+0-9.]+) %", text).group(1))
    assert abs(error) < 0.5  # the hemisphere's spreading resistance, as in tests/test_ablation.py
    assert text.count("Omega=1") == 2 and "magnet: the tip ball peaks at" in text
    assert (tmp_path / "ablation_fields.png").exists()
