"""Executes notebooks/ablation.ipynb (short settings) and checks what it prints; the FEM hand
check it shows (``lesion_fem_check.run``), quickly."""

import math
import re
from pathlib import Path

import pytest

from notebook_runner import run_notebook

from ballchain.experiments import lesion_fem_check
from ballchain.infrastructure.errors import UserInputError

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "ablation.ipynb"
BALL_RADIUS_M = 3.175e-3 / 2  # the paper's 1/8 inch balls
GROUND_RADIUS_M = 30e-3


def hemisphere_ohm(sigma):
    """(1/a - 1/b) / (2 pi sigma): a hemisphere in a half space, ground at b."""
    return (1 / BALL_RADIUS_M - 1 / GROUND_RADIUS_M) / (2 * math.pi * sigma)


@pytest.mark.slow
def test_ablation_notebook_runs(tmp_path, monkeypatch):
    text = run_notebook(NOTEBOOK, tmp_path, monkeypatch)
    error = float(re.search(r"error ([-+0-9.]+) %", text).group(1))
    assert abs(error) < 0.5  # the hemisphere's spreading resistance, as in tests/test_ablation.py
    exact = float(re.search(r"exact ([0-9.]+) Ohm", text).group(1))
    assert exact == pytest.approx(hemisphere_ohm(0.54), abs=0.006)
    assert text.count("Omega=1") == 2 and "magnet: the tip ball peaks at" in text
    assert "ablation_fields.png" in text and (tmp_path / "ablation_fields.png").exists()


def test_lesion_fem_check_is_the_exact_hemisphere_up_to_the_mesh():
    check = lesion_fem_check.run(h_mm=0.2, conductivity_S_per_m=2.0)
    assert check.ball_radius_mm == pytest.approx(BALL_RADIUS_M * 1e3)
    assert check.exact_ohm == pytest.approx(hemisphere_ohm(2.0), rel=1e-12)
    assert abs(check.error_pct) < 0.5
    assert check.error_pct == pytest.approx(100 * (check.fem_ohm / check.exact_ohm - 1), rel=1e-12)


@pytest.mark.parametrize("bad, match", [({"h_mm": 0.0}, "h_mm"), ({"conductivity_S_per_m": float("nan")}, "conductivity"),
                                        ({"conductivity_S_per_m": 0.0}, "conductivity")])
def test_lesion_fem_check_refuses_bad_input(bad, match):
    with pytest.raises(UserInputError, match=match):
        lesion_fem_check.run(**bad)
