"""Every notebook in notebooks/ runs top to bottom (quick mode: their FULL flags are off).

A notebook with a dedicated test (tests/test_notebook_<name>.py, which also checks what it
prints) is left to that test.
"""

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

HERE = Path(__file__).resolve().parent
NOTEBOOKS = [
    path
    for path in sorted((HERE.parent / "notebooks").glob("*.ipynb"))
    if not (HERE / f"test_notebook_{path.stem}.py").exists()
]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
@pytest.mark.slow
def test_notebook_runs_and_is_stored_without_outputs(path, tmp_path, monkeypatch):
    nb = nbformat.read(path, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert not cell.outputs, f"{path.name} is committed with outputs"
    monkeypatch.setenv("MPLBACKEND", "Agg")
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
