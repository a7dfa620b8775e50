"""CLI: `ballchain wheels` and `ballchain reconfigure` (JSON out, bad input exits 2)."""

import json

import numpy as np
import pytest

from ballchain.cli import main
from ballchain.drake_models.omniwheel import PAPER_A


def test_wheels_json(capsys):
    assert main(["wheels", "--json", "--samples", "50"]) == 0
    data = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(data["A_paper"], PAPER_A)
    np.testing.assert_allclose(data["A_derived_rows_minus_a"], PAPER_A, atol=0.005)
    res = data["rolling_residual_relative"]
    assert res["derived: omega_a = (rho_w/rho_a) A^-1 omega_w"] < 1e-14
    assert res["paper: omega_a = (rho_a/rho_w) A omega_w"] > 0.3
    fwd = np.asarray(data["forward_map_sphere_from_wheels"])
    inv = np.asarray(data["inverse_map_wheels_from_sphere"])
    np.testing.assert_allclose(fwd @ inv, np.eye(3), atol=1e-12)


def test_wheels_text(capsys):
    assert main(["wheels"]) == 0
    assert "rolling-contact residual" in capsys.readouterr().out


def test_reconfigure_json(capsys):
    code = main(["reconfigure", "--runs", "2", "--json", "--no-progress", "--field-model", "dipole"])
    out = capsys.readouterr().out
    data = json.loads(out)
    assert set(data) == {"runs", "converged", "max_final_error_deg", "median_time_s", "max_time_s"}
    assert data["runs"] == 2 and data["converged"] == 2 and code == 0
    assert data["max_final_error_deg"] < 1.0


@pytest.mark.parametrize(
    "argv",
    [
        ["reconfigure", "--runs", "0"],
        ["reconfigure", "--slip", "1.5"],
        ["reconfigure", "--field-model", "quadrupole"],
        ["wheels", "--samples", "many"],
    ],
)
def test_bad_arguments_exit_2_without_traceback(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "error" in err and "Traceback" not in err
