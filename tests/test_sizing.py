"""Clinical magnet sizing (paper Section V-A): the paper's numbers, the typo, the magnet-magnet force."""

import json
import math

import numpy as np
import pytest

from ballchain.cli import main as cli_main
from ballchain.drake_models.dipole import K_DIPOLE, MU0, chain_interactions
from ballchain.drake_models.params import GRAVITY, CylinderMagnet, gram_force
from ballchain.optimization.sizing import (
    SizingInputs,
    aligned_force_prefactors,
    force_between_magnets,
    size_clinical_magnet,
    solve_typo_equation,
)

GF = GRAVITY * 1e-3  # one gram-force [N]


def test_prototype_volume_by_hand():
    # pi (3.81 cm)^3 = pi * 55.306 cm^3 = 173.750 cm^3
    assert CylinderMagnet().volume == pytest.approx(math.pi * 0.0381**3, rel=1e-12)
    assert CylinderMagnet().volume * 1e6 == pytest.approx(173.750, abs=1e-3)


def test_sizing_reproduces_paper_diameter_and_mass():
    result = size_clinical_magnet(SizingInputs())
    print(f"clinical sphere: {result.diameter * 1e3:.3f} mm, {result.mass:.4f} kg")
    # The paper prints 119 mm and "about 6.6 kg": its rounding is the tolerance.
    assert result.diameter * 1e3 == pytest.approx(119.0, abs=0.5)
    assert result.mass == pytest.approx(6.6, abs=0.05)
    # Hand-checked figure: 119.165 mm, 6.645 kg (density 7500 kg/m^3).
    assert result.diameter * 1e3 == pytest.approx(119.165, abs=1e-3)
    assert result.mass == pytest.approx(7500 * math.pi / 6 * result.diameter**3, rel=1e-12)
    assert result.distance == pytest.approx(0.2965 + result.diameter / 2, rel=1e-12)


def test_sizing_roots_match_polynomial_roots():
    # Independent path: the residual is a quartic in r; numpy's companion-matrix roots.
    s = SizingInputs()
    a = s.alpha * s.measured_force * s.measured_distance**4 * 4.0 / 3.0 * math.pi
    b = s.desired_force * s.prototype_volume
    c = s.heart_to_surface
    # b (c + r)^4 - a r^3 = 0
    poly = b * np.array([1.0, 4 * c, 6 * c**2, 4 * c**3, c**4]) - np.array([0.0, a, 0.0, 0.0, 0.0])
    roots = np.roots(poly)
    real_pos = np.sort(roots[(np.abs(roots.imag) < 1e-9 * np.abs(roots)) & (roots.real > 0)].real)
    assert len(real_pos) == 2
    result = size_clinical_magnet(s)
    assert result.diameter == pytest.approx(2 * real_pos[0], rel=1e-9)
    assert result.second_root_diameter == pytest.approx(2 * real_pos[1], rel=1e-9)
    assert result.second_root_diameter > 100.0  # the other root is a 150 m sphere: non-physical


def test_sizing_ratio_invariances():
    base = size_clinical_magnet(SizingInputs()).diameter
    # Only alpha f_m / f_d matters: doubling both alpha and f_d changes nothing.
    same = size_clinical_magnet(SizingInputs(alpha=0.64, desired_force=20.0 * GF)).diameter
    assert same == pytest.approx(base, rel=1e-10)
    # The remanence cancels in the sizing (it only sets the clinical moment).
    assert size_clinical_magnet(SizingInputs(remanence=1.2)).diameter == pytest.approx(base, rel=1e-12)
    # A larger desired force needs a larger magnet.
    assert size_clinical_magnet(SizingInputs(desired_force=20.0 * GF)).diameter > base * 1.2


def test_no_root_is_reported():
    with pytest.raises(ValueError, match="no spherical magnet of any diameter"):
        size_clinical_magnet(SizingInputs(desired_force=1000.0 * GF))


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_inputs_are_validated(bad):
    with pytest.raises(ValueError, match="measured_distance must be a positive finite number"):
        SizingInputs(measured_distance=bad)


def test_typo_equation_gives_something_else_and_depends_on_units():
    s = SizingInputs()
    # Closed form: (d_d/2) K^(1/4) = d_c + d_d/2 with K = alpha (4/3) pi f_m d_m^4 / (f_d V_m), SI.
    K = (s.alpha * 4 / 3 * math.pi * s.measured_force * s.measured_distance**4) / (
        s.desired_force * s.prototype_volume
    )
    expected = 2 * s.heart_to_surface / (K**0.25 - 1)
    typo_m = solve_typo_equation(s)
    physics_mm = size_clinical_magnet(s).diameter * 1e3
    print(f"typo equation: {typo_m * 1e3:.2f} mm (SI), physics: {physics_mm:.2f} mm")
    assert typo_m == pytest.approx(expected, rel=1e-10)
    assert typo_m * 1e3 == pytest.approx(303.69, abs=0.01)
    # Dimensionally inconsistent: in cm it gives another diameter (71.13 mm).
    assert solve_typo_equation(s, 1e-2) * 1e3 == pytest.approx(71.13, abs=0.01)
    # Neither is the paper's 119 mm.
    for unit in (1.0, 1e-2, 1e-3):
        assert abs(solve_typo_equation(s, unit) * 1e3 - 119.0) > 40.0
    # No positive root when the left side's coefficient is the smaller one.
    assert solve_typo_equation(SizingInputs(alpha=1e-6)) is None


def test_force_between_magnets_matches_hand_formulae_and_chain_interactions():
    m, s = 1000.0, 0.7
    forces = force_between_magnets(m, s)
    unit = MU0 * m**2 / (4 * math.pi * s**4)
    assert forces["coaxial_head_to_tail"]["force_N"] == pytest.approx(6 * unit, rel=1e-12)
    assert forces["coaxial_head_to_head"]["force_N"] == pytest.approx(6 * unit, rel=1e-12)
    assert forces["side_by_side_parallel"]["force_N"] == pytest.approx(3 * unit, rel=1e-12)
    assert forces["side_by_side_antiparallel"]["force_N"] == pytest.approx(3 * unit, rel=1e-12)
    assert forces["coaxial_head_to_tail"]["attractive"] == 1.0
    assert forces["coaxial_head_to_head"]["attractive"] == 0.0
    assert forces["side_by_side_parallel"]["attractive"] == 0.0
    assert forces["side_by_side_antiparallel"]["attractive"] == 1.0
    # Same number from the all-pairs path (which also gives Newton's third law).
    p = np.array([[0.0, 0.0, 0.0], [s, 0.0, 0.0]])
    _, F, _ = chain_interactions(p, np.array([[m, 0, 0], [m, 0, 0]]))
    np.testing.assert_allclose(F[1], [-6 * unit, 0, 0], rtol=1e-12)
    np.testing.assert_allclose(F[0], -F[1], rtol=1e-12)


def test_force_between_clinical_magnets_versus_paper():
    result = size_clinical_magnet(SizingInputs())
    # Hand check: |m| = Br (pi/6) D^3 / mu0, coaxial 6 k m^2 / (2d)^4.
    m = 1.44 * math.pi / 6 * result.diameter**3 / MU0
    assert result.dipole_moment == pytest.approx(m, rel=1e-12)
    s = 2 * result.distance
    forces = force_between_magnets(m, s)
    coaxial_gf = gram_force(forces["coaxial_head_to_tail"]["force_N"])
    side_gf = gram_force(forces["side_by_side_antiparallel"]["force_N"])
    print(f"clinical magnets {s * 100:.2f} cm apart: coaxial {coaxial_gf:.1f} gf, side {side_gf:.1f} gf")
    assert coaxial_gf == pytest.approx(gram_force(6 * K_DIPOLE * m**2 / s**4), rel=1e-12)
    assert coaxial_gf == pytest.approx(245.2, abs=0.1)
    assert side_gf == pytest.approx(122.6, abs=0.1)
    # The paper's "about 500 gf" is about twice the physical maximum at separation 2 d.
    assert 1.9 < 500.0 / coaxial_gf < 2.2
    # It is what the coaxial force gives at separation 2 d_c (centres at the arm surfaces):
    at_2dc = gram_force(force_between_magnets(m, 2 * 0.2965)["coaxial_head_to_tail"]["force_N"])
    assert at_2dc == pytest.approx(500.0, rel=0.05)


def test_paper_force_law_prefactor_is_the_equatorial_one():
    c = aligned_force_prefactors((0.0, 45.0, 90.0))
    assert c[0.0] == pytest.approx(6.0, rel=1e-12)
    # c(theta)^2 = 9 (1 + 3 cos^2) + 9 cos^2 sin^2 / (1 + 3 cos^2): 23.4 at 45 deg.
    assert c[45.0] == pytest.approx(math.sqrt(23.4), rel=1e-12)
    assert c[90.0] == pytest.approx(3.0, rel=1e-12)  # the paper's 3


# ----------------------------------------------------------------------------------------- CLI


def _run_json(capsys, *flags):
    rc = cli_main(["sizing", "--json", *flags])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    return json.loads(captured.out)


def test_cli_json_defaults(capsys):
    out = _run_json(capsys)
    keys = ("diameter_mm", "mass_kg", "force_between_magnets_gf", "typo_equation_diameter_mm", "paper", "assumptions")
    for key in keys:
        assert key in out
    assert out["diameter_mm"] == pytest.approx(119.165, abs=1e-3)
    assert out["mass_kg"] == pytest.approx(6.645, abs=1e-3)
    assert out["typo_equation_diameter_mm"] == pytest.approx(303.69, abs=0.01)
    assert out["force_between_magnets_gf"] == pytest.approx(245.2, abs=0.1)
    assert out["paper"]["diameter_mm"] == 119.0
    assert out["paper"]["force_between_magnets_gf"] == 500.0
    assert out["force_between_magnets_by_orientation"]["side_by_side_parallel"]["attractive"] is False
    assert out["inputs"]["measured_force_gf"] == pytest.approx(132.6, rel=1e-12)
    assert out["alpha_from_ball_diameters_2_17_over_3_175_cubed"] == pytest.approx(0.32, abs=0.005)


def test_cli_overrides_change_the_answer(capsys):
    base = _run_json(capsys)["diameter_mm"]
    farther = _run_json(capsys, "--heart-to-surface-distance-cm", "35")["diameter_mm"]
    weaker = _run_json(capsys, "--measured-force-gf", "66.3")["diameter_mm"]
    assert farther > base and weaker > base
    # Halving f_m is the same as doubling f_d (only alpha f_m / f_d enters).
    doubled = _run_json(capsys, "--desired-force-gf", "20")["diameter_mm"]
    assert weaker == pytest.approx(doubled, rel=1e-10)


def test_cli_text_output(capsys):
    assert cli_main(["sizing"]) == 0
    text = capsys.readouterr().out
    assert "119.17 mm" in text and "coaxial_head_to_tail" in text


@pytest.mark.parametrize(
    "flag, value",
    [
        ("--alpha", "0"),
        ("--measured-force-gf", "-132.6"),
        ("--desired-force-gf", "nan"),
        ("--measured-distance-cm", "inf"),
        ("--heart-to-surface-distance-cm", "0"),
        ("--prototype-diameter-mm", "-1"),
        ("--prototype-length-mm", "nan"),
        ("--remanence-T", "0"),
        ("--density-kg-m3", "-7500"),
    ],
)
def test_cli_bad_values_exit_2_with_one_line(capsys, flag, value):
    rc = cli_main(["sizing", "--json", flag, value])
    captured = capsys.readouterr()
    assert rc == 2
    assert captured.out == ""
    assert "Traceback" not in captured.err
    assert captured.err.count("\n") == 1
    assert flag in captured.err and "positive finite" in captured.err


def test_cli_unreachable_force_exits_2(capsys):
    rc = cli_main(["sizing", "--desired-force-gf", "1000"])
    captured = capsys.readouterr()
    assert rc == 2
    assert "no spherical magnet" in captured.err and "Traceback" not in captured.err
