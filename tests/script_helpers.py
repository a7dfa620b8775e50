"""What the tests of the scripts in ``benchmarks/`` share: loading one as a module."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def load_benchmark(name: str, monkeypatch=None):
    """``benchmarks/<name>.py`` as a module named ``name``; with ``monkeypatch`` it is also put in
    ``sys.modules`` for the test (a script whose dataclasses look their module up)."""
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    if monkeypatch is not None:
        monkeypatch.setitem(sys.modules, name, module)
    spec.loader.exec_module(module)
    return module
