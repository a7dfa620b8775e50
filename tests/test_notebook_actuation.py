"""Executes notebooks/actuation.ipynb (short settings) and checks what it prints; the experiments'
``run`` it uses (Hall inversion, reconfiguration traces), quickly."""

import re
from pathlib import Path

import numpy as np
import pytest

from notebook_runner import run_notebook

from ballchain.drake_models.dipole_inversion import paper_formula_angle_error
from ballchain.experiments import hall_inversion, reconfiguration
from ballchain.infrastructure.errors import UserInputError

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "actuation.ipynb"


@pytest.mark.slow
def test_actuation_notebook_runs(tmp_path, monkeypatch):
    text = run_notebook(NOTEBOOK, tmp_path, monkeypatch)
    # The short study converged on every run and the antiparallel start finished.
    assert "'converged': 3" in text
    assert "antiparallel: done at" in text
    # The paper's formula's largest error over the 2.5 deg grid is its closed form's (36.85 deg).
    printed = float(re.search(r"max error, paper formula: ([0-9.]+) deg", text).group(1))
    closed = np.rad2deg(paper_formula_angle_error(np.deg2rad(np.arange(0.0, 180.01, 2.5)))).max()
    assert printed == pytest.approx(closed, abs=0.006)
    # The unit reconfigured to neutral (-x) before the stick, and a dead-band stick moved nothing.
    dipole = [float(v) for v in re.search(r"neutral after [0-9.]+ s: dipole \[([^\]]+)\]", text).group(1).split()]
    assert dipole[0] < -0.999
    assert float(re.search(r"under the dead-band stick: ([-+0-9.e]+) mT", text).group(1)) < 1e-6


def test_hall_inversion_run_is_the_comparison_at_each_distance():
    result = hall_inversion.run(distances_mm=(60, 100), theta_step_deg=15.0)
    np.testing.assert_array_equal(result.theta_deg, np.arange(0.0, 181.0, 15.0))
    closed = np.rad2deg(paper_formula_angle_error(np.deg2rad(result.theta_deg)))
    for c, worst in zip(result.comparisons, result.paper_formula_max_error_deg):
        np.testing.assert_allclose(c.paper_formula_dipole, closed, atol=1e-9)  # depends on the angle only
        assert worst == pytest.approx(closed.max(), abs=1e-9)
        assert c.correct_inverse_dipole.max() < 1e-6
    # The dipole assumption costs more near the magnet; the field falls with distance (about 1/D^3).
    near, far = result.correct_inverse_exact_max_error_deg
    assert near > far > 1.0
    assert result.B_max_mT[0] / result.B_max_mT[1] == pytest.approx((100 / 60) ** 3, rel=0.25)
    assert "comparisons" in result.to_dict()


@pytest.mark.parametrize("bad, match", [({"distances_mm": (10,)}, "distances_mm"), ({"distances_mm": []}, "distances_mm"),
                                        ({"theta_step_deg": 7.0}, "theta_step_deg"),
                                        ({"theta_step_deg": True}, "theta_step_deg"), ({"refine": 1}, "refine")])
def test_hall_inversion_run_refuses_bad_input(bad, match):
    with pytest.raises(UserInputError, match=match):
        hall_inversion.run(**bad)


def test_reconfiguration_study_keeps_each_run_s_trace_out_of_the_json():
    study = reconfiguration.run(runs=1, progress=False)
    (trace,) = study.traces
    assert trace.time_s == study.time_s[0] and trace.final_error_deg == study.final_error_deg[0]
    # Run 0 starts antiparallel: the true angle starts at 180 deg and ends under the tolerance.
    assert trace.error_deg[0] == pytest.approx(180.0, abs=1e-6) and trace.error_deg[-1] < 1.0
    assert len(trace.t) == len(trace.error_deg) == len(trace.measured_error_deg) > 10
    assert "traces" not in study.to_dict()
