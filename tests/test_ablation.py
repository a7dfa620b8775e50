"""The RF lesion model: analytic limits, conservation, the generator law, mesh convergence, the CLI."""

import json
import math

import numpy as np
import pytest

from ballchain.cli import main as cli_main
from ballchain.drake_models import lesion_fem as fem
from ballchain.drake_models import tissue as laws
from ballchain.infrastructure.errors import UserInputError
from ballchain.experiments import ablation


# ----------------------------------------------------------------------------- electric checks

@pytest.mark.parametrize("electrode", [fem.ball_chain_tip(indentation=3.175e-3 / 2),
                                       fem.catheter_8fr(indentation=4.0e-3 / 3)], ids=["ball", "catheter_dome"])
def test_hemisphere_spreading_resistance(electrode):
    """Half-immersed sphere (dome) in a half space, insulated surface: R = (1/a - 1/b) / (2 pi sigma).

    The ground arc at b = 30 mm is concentric with the hemisphere, so the formula is exact; the
    FE value converges from below (0.13 % at h = 0.1 mm, the polygonal arcs). Tolerance 0.5 %.
    The half-space value 1/(2 pi sigma a) is 5.3 % (a/b) higher than the truncated one.
    """
    sigma = 0.54
    am = fem.build_mesh(electrode, h=0.1e-3)
    r_fem = fem.electrode_resistance(am, sigma, saline_sigma=0.0)
    r_exact = laws.spreading_resistance_hemisphere(sigma, electrode.radius, am.outer_radius)
    assert abs(r_fem / r_exact - 1) < 5e-3
    r_half_space = laws.spreading_resistance_hemisphere(sigma, electrode.radius)
    assert r_half_space == pytest.approx(1 / (2 * math.pi * sigma * electrode.radius))
    assert r_half_space / r_exact - 1 == pytest.approx(electrode.radius / (am.outer_radius - electrode.radius))


def test_shallow_cap_approaches_disc_resistance():
    """A cap 0.05 mm deep is nearly a flat disc: R within 10 % below 1/(4 sigma a) (the cap bulges)."""
    sigma = 0.54
    electrode = fem.ball_chain_tip(indentation=0.05e-3)
    am = fem.build_mesh(electrode, h=0.03e-3, fine_radius=2e-3)
    r_fem = fem.electrode_resistance(am, sigma, saline_sigma=0.0)
    r_disc = laws.spreading_resistance_disc(sigma, electrode.contact_radius)
    truncation = 1 / (2 * math.pi * sigma * am.outer_radius)  # the far arc's share
    assert 0.90 < (r_fem + truncation) / r_disc < 1.0


def test_active_surfaces_ball_in_tissue_only_catheter_everywhere():
    """The ball conducts only on its cap in tissue (shrink wrap above); the catheter into saline too.

    So a conducting bath lowers the catheter's resistance much more than the ball's, whose
    current reaches the saline only through the tissue at the contact's edge.
    """
    ratios = {}
    for electrode in (fem.catheter_8fr(), fem.ball_chain_tip()):
        am = fem.build_mesh(electrode, h=0.15e-3)
        p = am.mesh.p[:, am.active_nodes]
        dist = np.hypot(p[0], p[1] - electrode.centre_height)
        if electrode.kind == "ball":
            assert np.all(p[1] <= 1e-12) and np.allclose(dist, electrode.radius, rtol=1e-9)
        else:
            assert np.any(p[1] > electrode.top_height / 2)
        ratios[electrode.kind] = (fem.electrode_resistance(am, 0.54, saline_sigma=1.6)
                                  / fem.electrode_resistance(am, 0.54, saline_sigma=0.54))
    assert ratios["catheter"] < 0.5 < ratios["ball"] < 1.0


# ----------------------------------------------------------------------------- laws

def test_arrhenius_constant_temperature_by_hand():
    """60 C held for 10 s: Omega = A exp(-Ea / (R T)) t.

    By hand: Ea / (R T) = 2.596e5 / (8.314462618 x 333.15) = 93.71966; exp(-93.71966) x 2.94e39
    = 0.0584007 1/s; x 10 s = 0.584007 (Omega = 1 after 17.12 s).
    """
    times = np.linspace(0.0, 10.0, 11)
    temps = np.full((11, 3), 60.0)
    omega = laws.ARRHENIUS_MYOCARDIUM.damage(temps, times)
    np.testing.assert_allclose(omega, 0.584006819705115, rtol=1e-9)
    assert laws.ARRHENIUS_MYOCARDIUM.rate(60.0) * 17.123 == pytest.approx(1.0, abs=1e-4)


def test_conductivity_law():
    """+1.5 %/C in tissue, +2 %/C in saline (from 25 C), two decades down between 100 and 105 C."""
    assert laws.electrical_conductivity(laws.MYOCARDIUM, 47.0) == pytest.approx(0.54 * 1.15)
    assert laws.electrical_conductivity(laws.SALINE, 37.0) == pytest.approx(1.6 * 1.24)
    at_100 = laws.electrical_conductivity(laws.MYOCARDIUM, 100.0)
    assert laws.electrical_conductivity(laws.MYOCARDIUM, 105.0) == pytest.approx(at_100 * 1e-2)
    assert laws.electrical_conductivity(laws.MYOCARDIUM, 102.5) == pytest.approx(at_100 * 1e-1)


def test_temperature_limited_generator_law():
    t0 = np.array([50.0, 90.0])
    rise = np.array([0.01, 0.02])
    assert laws.temperature_limited_voltage_squared(100.0, t0, rise, None) == 100.0
    assert laws.temperature_limited_voltage_squared(100.0, t0, rise, 100.0) == 100.0  # 92 C: no cut
    v2 = laws.temperature_limited_voltage_squared(1000.0, t0, rise, 100.0)
    assert v2 == pytest.approx(500.0)  # the 90 C point reaches exactly 100 C
    assert laws.temperature_limited_voltage_squared(1000.0, np.array([101.0]), np.array([1.0]), 100.0) == 0.0


# ----------------------------------------------------------------------------- the time loop

def test_constant_power_holds_each_step():
    """Without the cut-off, V^2 / Z and the Joule integral equal the set power at every step."""
    sim = fem.simulate(fem.ball_chain_tip(), power_W=5.0, duration_s=3.0, h=0.2e-3, limit_C=None,
                       output_every_s=1.0)
    np.testing.assert_allclose(sim.power, 5.0, rtol=1e-9)  # the Joule heat's integral
    np.testing.assert_allclose(sim.voltage**2 / sim.impedance, 5.0, rtol=1e-9)  # u^T A u route
    assert sim.impedance[-1] < sim.impedance[0]  # sigma rises with temperature


def test_cut_off_caps_temperature_and_otherwise_delivers_the_set_power():
    sim = fem.simulate(fem.ball_chain_tip(), power_W=15.0, duration_s=5.0, h=0.2e-3, output_every_s=1.0)
    assert sim.limited.any() and not sim.limited[0]
    np.testing.assert_allclose(sim.power[~sim.limited], 15.0, rtol=1e-9)
    assert np.all(sim.power[sim.limited] < 15.0)
    assert sim.max_tissue_C.max() <= laws.VAPORISATION_ONSET_C + 1e-6


def test_energy_balance():
    """Electric energy in = heat stored + heat into the far boundary; no undershoot below T0.

    Implicit Euler with a lumped heat capacity conserves energy exactly in the discrete sense
    (tolerance 1e-9). The boundary's share is the Joule heat next to the dispersive electrode:
    for a hemisphere of radius a the power dissipated beyond rho is (1/rho - 1/b) / (1/a - 1/b)
    of the total, about 0.5 % for the outermost 3 mm element layer here; conduction cannot reach
    the arc (30 mm) in 10 s.
    """
    electrode = fem.catheter_8fr()
    sim = fem.simulate(electrode, power_W=30.0, duration_s=10.0, h=0.2e-3, output_every_s=5.0)
    assert sim.energy_delivered_J > 10.0
    assert sim.energy_stored_J + sim.energy_boundary_J == pytest.approx(sim.energy_delivered_J, rel=1e-9)
    a, b = electrode.radius, sim.mesh.outer_radius
    shell = (1 / (b - 3e-3) - 1 / b) / (1 / a - 1 / b)
    assert 0.5 * shell < sim.energy_boundary_J / sim.energy_delivered_J < 2 * shell
    assert sim.final_temperature.min() >= 22.0 - 1e-9


def test_lesion_extent_of_a_known_field():
    """A field 1 - |p|^2 / c^2 is >= 0 on a disc of radius c: width 2c, depth c (to P1 accuracy)."""
    am = fem.build_mesh(fem.ball_chain_tip(), h=0.1e-3)
    c = 3.0e-3
    p = am.mesh.p
    ext = fem.lesion_extent(am, 1 - (p[0] ** 2 + p[1] ** 2) / c**2, 0.0)
    assert ext["width_mm"] == pytest.approx(6.0, abs=0.01)
    assert ext["depth_mm"] == pytest.approx(3.0, abs=0.01)
    assert ext["surface_diameter_mm"] == pytest.approx(6.0, abs=0.01)


def test_bad_electrode_and_settings_are_user_errors():
    with pytest.raises(UserInputError, match="indentation"):
        fem.ball_chain_tip(indentation=2e-3)
    with pytest.raises(UserInputError, match="tissue"):
        laws.tissue("bone")
    with pytest.raises(UserInputError, match="ball_power_W"):
        ablation.run(ball_power_W=-1.0)


# ----------------------------------------------------------------------------- convergence

@pytest.mark.slow
@pytest.mark.parametrize("device", ["ball_chain", "catheter"])
def test_mesh_convergence(device):
    """Two refinements (0.14 -> 0.1 -> 0.07 mm): width and depth, both criteria, change < 0.1 mm."""
    rows = ablation.mesh_convergence(device, h_mm=(0.14, 0.1, 0.07), progress=False)
    keys = ("width_mm", "depth_mm", "iso50_width_mm", "iso50_depth_mm")
    dims = [np.array([r[k] for k in keys]) for r in rows]
    assert rows[0]["nodes"] < rows[1]["nodes"] < rows[2]["nodes"]
    assert np.all(np.abs(dims[1] - dims[0]) < 0.1), dims
    assert np.all(np.abs(dims[2] - dims[1]) < 0.1), dims


@pytest.mark.slow
def test_time_step_convergence():
    """Halving the largest step (1 s -> 0.5 s) moves the lesion by less than 0.05 mm."""
    electrode = fem.ball_chain_tip()
    mesh = fem.build_mesh(electrode, h=0.15e-3)
    ends = [fem.simulate(electrode, power_W=15.0, duration_s=90.0, dt_max=dt, mesh=mesh, output_every_s=90.0)
            .growth[-1] for dt in (1.0, 0.5)]
    for key in ("omega_width_mm", "omega_depth_mm"):
        assert abs(ends[0][key] - ends[1][key]) < 0.05


# ----------------------------------------------------------------------------- experiment and CLI

@pytest.mark.slow
def test_cli_json_both_devices(tmp_path, capsys):
    code = cli_main(["ablation", "--json", "--mesh-mm", "0.2", "--duration-s", "20", "--out", str(tmp_path)])
    assert code == 0
    data = json.loads(capsys.readouterr().out)
    names = [d["device"] for d in data["devices"]]
    assert names == ["ball_chain", "catheter"]
    for d in data["devices"]:
        assert d["omega_depth_mm"] > 0 and d["iso50_width_mm"] >= d["omega_width_mm"]
        assert d["paper"]["width_mm"] in (5.7, 5.4)
        assert d["peak_tissue_C"] <= 100.0 + 1e-6
    for name in ("ablation.json", "ablation_growth.csv", "ablation_fields.png", "ablation_growth.png"):
        assert (tmp_path / name).stat().st_size > 0


@pytest.mark.parametrize("flag,value", [("--ball-power-W", "0"), ("--duration-s", "-5"), ("--indentation-mm", "3"),
                                        ("--tissue", "bone"), ("--mesh-mm", "2")])
def test_cli_bad_flags_exit_2_naming_the_flag(flag, value, capsys):
    assert cli_main(["ablation", flag, value, "--no-files"]) == 2
    err = capsys.readouterr().err
    assert flag in err and err.count("\n") == 1


@pytest.mark.slow
def test_power_duration_map_reads_every_duration_from_one_run():
    data = ablation.power_duration_map(powers_W=(10.0,), durations_s=(20.0, 40.0), h_mm=0.2, dt_max_s=2.0,
                                       progress=False)
    rows = data["rows"]
    assert [r["duration_s"] for r in rows] == [20.0, 40.0]
    assert rows[1]["depth_mm"] >= rows[0]["depth_mm"] and rows[1]["energy_J"] > rows[0]["energy_J"]
    assert "transmural" in data["headline"]


@pytest.mark.slow
def test_reproduce_section_quick(tmp_path):
    from ballchain import reproduce

    section, data = reproduce.ablation_section(tmp_path, quick=True)
    assert [d["device"] for d in data["devices"]] == ["ball_chain", "catheter"]
    for name in ("ablation.json", "ablation_growth.csv", "ablation_map.csv", "ablation_fields.png",
                 "ablation_growth.png", "ablation_map.png"):
        assert (tmp_path / "ablation" / name).stat().st_size > 0
    saved = json.loads((tmp_path / "ablation" / "ablation.json").read_text())
    assert saved["devices"][0]["paper"] == {"power_W": 15.0, "duration_s": 90.0, "width_mm": 5.7, "depth_mm": 3.1}
    assert len(saved["power_duration_map"]["rows"]) == 4
    # Beyond the paper: the catheter against the published lesions (issue 44).
    assert data["validation"]["summary"]["points"] == 10
    assert (tmp_path / "ablation" / "lesion_validation.json").stat().st_size > 0


def test_joule_share_catheter_heats_mostly_saline():
    """The catheter's bare electrode puts most of its power into the saline; the ball about half."""
    cath = fem.joule_share(fem.build_mesh(fem.catheter_8fr(), h=0.2e-3))
    ball = fem.joule_share(fem.build_mesh(fem.ball_chain_tip(), h=0.2e-3))
    for share in (cath, ball):
        assert share["tissue"] + share["saline"] == pytest.approx(1.0, abs=1e-12)
    assert cath["saline"] > 0.75 and 0.3 < ball["saline"] < 0.7
