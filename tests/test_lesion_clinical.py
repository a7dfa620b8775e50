"""The lesion FEM in clinical conditions (issue 44): the still path unchanged, the Newton condition
against a slab's exact steady state, energy balance, the generator's limits, blood-flow cooling."""

import numpy as np
import pytest
from skfem import BilinearForm, ElementTriP1, CellBasis, MeshTri, asm, condense, solve
from skfem.helpers import dot, grad
from types import SimpleNamespace

from ballchain.drake_models import lesion_boundary as lb
from ballchain.drake_models import lesion_clinical as lc
from ballchain.drake_models import lesion_fem as fem
from ballchain.drake_models.rf_generator import Generator
from ballchain.infrastructure.errors import UserInputError

H = 0.3e-3  # coarse mesh: these are checks of the equations, not of the lesion's size


@pytest.fixture(scope="module")
def catheter_mesh():
    return fem.build_mesh(fem.catheter_8fr(1e-3), h=H)


@pytest.fixture(scope="module")
def ball_mesh():
    return fem.build_mesh(fem.ball_chain_tip(1e-3), h=H)


def test_still_bath_is_the_bench_fem_step_for_step(catheter_mesh):
    """Still saline, no irrigation, power control: the same temperatures and damage as
    ``lesion_fem.simulate`` (the paper's bench) to 1e-9."""
    el = catheter_mesh.electrode
    a = fem.simulate(el, power_W=30, duration_s=6, initial_temperature_C=37, mesh=catheter_mesh, output_every_s=3)
    b = lc.simulate_clinical(el, generator=Generator(power_W=30), duration_s=6, initial_temperature_C=37,
                             mesh=catheter_mesh, output_every_s=3)
    assert np.abs(a.final_temperature - b.final_temperature).max() < 1e-9
    assert np.abs(a.damage - b.damage).max() < 1e-9
    assert np.allclose(a.power, b.power, rtol=1e-12)


@BilinearForm
def _k(u, v, w):
    return w.k * dot(grad(u), grad(v)) * w.x[0]


def test_newton_condition_matches_a_slab_steady_state():
    """Conduction across a slab 0 < z < L (k), T = T1 at z = 0, -k dT/dz = h (T - Tinf) at z = L:
    T(L) = (k T1 / L + h Tinf) / (k / L + h), linear in z. The r-weighting cancels (no r flux)."""
    k, h, L, t1, tinf = 0.56, 610.0, 2e-3, 90.0, 37.0
    mesh = MeshTri.init_tensor(np.linspace(0.0, 1e-3, 6), np.linspace(0.0, L, 21))
    top = mesh.facets_satisfying(lambda x: np.isclose(x[1], L))
    fake = SimpleNamespace(mesh=mesh, n_nodes=mesh.p.shape[1])
    R, r = lb.robin_operator(fake, top, h, tinf)
    K = asm(_k, CellBasis(mesh, ElementTriP1()), k=k)
    bottom = np.flatnonzero(np.isclose(mesh.p[1], 0.0))
    x = np.zeros(mesh.p.shape[1])
    x[bottom] = t1
    T = solve(*condense(K + R, r, x=x, D=bottom))
    t_l = (k * t1 / L + h * tinf) / (k / L + h)
    exact = t1 + (t_l - t1) * mesh.p[1] / L
    assert np.abs(T - exact).max() < 1e-9
    # The boundary's heat loss is h (T(L) - Tinf) over the face (r-weighted: area / 2 pi = R^2 / 2).
    loss = float(np.sum(R @ T - r))
    assert loss == pytest.approx(h * (t_l - tinf) * (1e-3) ** 2 / 2, rel=1e-9)


@pytest.mark.parametrize("flow,irrigation", [("low", "none"), ("high", "open"), ("none", "open")])
def test_energy_balance(catheter_mesh, flow, irrigation):
    """Delivered = stored + held nodes (far arc, blood, irrigated tip) + convection + blood's Joule heat."""
    s = lc.simulate_clinical(catheter_mesh.electrode, generator=Generator(power_W=20), duration_s=6,
                             conditions=lb.conditions(flow, irrigation), mesh=catheter_mesh, output_every_s=3)
    i = s.info
    out = s.energy_stored_J + i["energy_held_J"] + i["energy_convection_J"] + i["energy_blood_joule_J"]
    assert out == pytest.approx(s.energy_delivered_J, rel=1e-9)
    # (negative with the irrigated tip at 30 C below the 37 C blood: the blood warms the tip)
    assert (i["energy_convection_J"] != 0) == (flow != "none")


def test_zero_coefficients_make_adiabatic_interfaces(ball_mesh):
    """h -> 0 with flowing blood: no convective loss, the wetted surfaces insulated; low and high
    flow cool the ball in turn (at the same delivered power, 1 W, below every limit)."""
    el = ball_mesh.electrode
    peaks = {}
    for name, cond in (("h0", lb.ThermalConditions(blood_flow="low")), ("low", lb.conditions("low")), ("high", lb.conditions("high"))):
        s = lc.simulate_clinical(el, generator=Generator(power_W=1.0), duration_s=8, conditions=cond,
                                 mesh=ball_mesh, output_every_s=4)
        assert s.info["limit_share"]["power"] == pytest.approx(1.0)
        peaks[name] = s.max_electrode_C.max()
        if name == "h0":
            assert s.info["energy_convection_J"] == 0.0
    assert peaks["h0"] > peaks["low"] > peaks["high"] > 37.0


def test_temperature_control_holds_the_set_point(catheter_mesh):
    """Temperature control at 60 C with a 50 W cap: once the electrode reaches 60 C it stays
    there (within 0.1 C: with no power at all the hot tissue beside it still warms it by a few
    hundredths of a degree in a step, which no generator can undo); the delivered power then
    falls below the cap."""
    s = lc.simulate_clinical(catheter_mesh.electrode, generator=Generator(mode="temperature", power_W=50, target_C=60),
                             duration_s=15, mesh=catheter_mesh, output_every_s=5)
    assert s.max_electrode_C.max() <= 60.1
    held = s.times > 5.0
    assert np.all(np.abs(s.max_electrode_C[held] - 60.0) < 0.1)
    assert s.power[held].max() < 50.0
    assert s.info["limit_share"]["electrode"] > 0.5


def test_magnet_limit_holds_the_ball_below_it(ball_mesh):
    """The magnet's limit in power mode: the tip ball's hottest point never passes it."""
    s = lc.simulate_clinical(ball_mesh.electrode, generator=Generator(power_W=15, electrode_limit_C=75.0),
                             duration_s=10, mesh=ball_mesh, output_every_s=5)
    assert s.max_electrode_C.max() <= 75.0 + 1e-6
    assert s.max_electrode_C.max() > 74.9
    assert s.info["mean_power_W"] < 15.0


def test_bad_settings_are_refused():
    with pytest.raises(UserInputError, match="blood_flow"):
        lb.conditions("fast")
    with pytest.raises(UserInputError, match="irrigation"):
        lb.conditions("low", "closed")
    with pytest.raises(UserInputError, match="target_C"):
        Generator(mode="temperature", target_C=120.0)
    with pytest.raises(UserInputError, match="mode"):
        Generator(mode="impedance")
