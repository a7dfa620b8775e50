"""Run a notebook the way every notebook test does (imported by the notebook tests)."""

from pathlib import Path

import nbformat
from nbclient import NotebookClient

CELL_TIMEOUT_S = 1800  # a hang guard: the slowest cell needs well under a minute on an idle core
STARTUP_TIMEOUT_S = 300


def run_notebook(path: Path, tmp_path: Path, monkeypatch) -> str:
    """Check that ``path`` is stored without outputs, run it in ``tmp_path`` (quick mode, Agg
    backend, one BLAS thread, a fixed hash seed: the same conditions in every run, as the
    ``ballchain`` command) and return what its cells printed."""
    nb = nbformat.read(path, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert not cell.outputs and cell.execution_count is None, f"{path.name} is committed with outputs"
    monkeypatch.setenv("BALLCHAIN_NOTEBOOK_LONG", "0")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.setenv(var, "1")
    monkeypatch.setenv("PYTHONHASHSEED", "0")
    NotebookClient(nb, timeout=CELL_TIMEOUT_S, startup_timeout=STARTUP_TIMEOUT_S, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()
    return "\n".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs
                     if o.get("output_type") == "stream")
