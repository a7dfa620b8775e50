"""The clinical system: field against magpylib, the image-dipole law, the sizing search."""

import math

import numpy as np
import pytest

from ballchain.drake_models.dipole import MU0, dipole_field
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.image_dipole import (
    image_dipole,
    image_energy,
    image_factor,
    image_force,
    normal_attraction,
)
from ballchain.drake_models.params import BallChain, SphereMagnet, gram_force
from ballchain.experiments import clinical
from ballchain.experiments import table1_effects as effects

# --- the clinical field -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def stand():
    return clinical.clinical_stand(clinical.todays_chain())


def test_clinical_field_at_the_atrium_matches_magpylib_spheres(stand):
    """Both 119 mm spheres (any directions) against magpylib's uniformly magnetised sphere,
    at points around the atrium; exact for a sphere, so the tolerance is round-off."""
    from magpylib.func import sphere_field

    magnet = SphereMagnet(diameter=0.119)
    field_for = clinical.ClinicalField(stand, magnet)
    rng = np.random.default_rng(3)
    m = rng.normal(size=(2, 3))
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    points = np.vstack([np.zeros(3), rng.uniform(-0.04, 0.04, size=(6, 3))])
    B, _ = field_for(m).field_and_gradient(points)
    expected = np.zeros_like(points)
    for c, u in zip(stand.magnets.values(), m):
        expected += np.asarray(sphere_field("B", observers=points - c, diameters=magnet.diameter,
                                            polarizations=magnet.remanence * u, squeeze=False)).reshape(points.shape)
    np.testing.assert_allclose(B, expected, rtol=1e-9, atol=1e-15)
    # The placement: each centre d_c + D/2 from the atrium's centre, on the patient's left and right.
    for c in stand.magnets.values():
        p_H = stand.p_HE + stand.R_HS @ c
        np.testing.assert_allclose(np.linalg.norm(p_H), 0.2965 + 0.0595, rtol=1e-12)
        np.testing.assert_allclose(p_H[1:], 0.0, atol=1e-12)


def test_aiming_points_both_fields_along_the_asked_direction(stand):
    field_for = clinical.ClinicalField(stand, SphereMagnet())
    for b in clinical.seed_directions():
        m = field_for.aiming(b)
        for c, u in zip(field_for.centres, m):
            B = dipole_field(-c, u)
            np.testing.assert_allclose(B / np.linalg.norm(B), b / np.linalg.norm(b), atol=1e-9)


def test_eight_french_chain_is_the_papers():
    chain = clinical.eight_french_chain()
    today = clinical.todays_chain()
    assert chain.ball_volume / today.ball_volume == pytest.approx(0.32, abs=0.005)  # 2.17^3 / 3.175^3 = 0.319
    assert chain.length >= today.length > (chain.n_balls - 1) * chain.ball_diameter
    assert chain.sleeve.outer_diameter == pytest.approx(2.67e-3)
    assert chain.sleeve.outer_diameter - chain.sleeve.inner_diameter == pytest.approx(0.5e-3)


def test_bad_input_is_refused_before_any_solve():
    with pytest.raises(UserInputError, match="chains"):
        clinical.run(chains=("10Fr",))
    with pytest.raises(UserInputError, match="--ring-step"):
        clinical.run(ring_step=-1)
    with pytest.raises(UserInputError, match="reference"):
        clinical.run(reference="skin")
    with pytest.raises(UserInputError, match="--max-diameter-mm"):
        clinical.run(max_diameter_mm=50.0)


# --- the image-dipole law -----------------------------------------------------------------------


def test_image_law_makes_the_field_normal_to_a_soft_iron_surface():
    """mu_r -> inf: H tangential vanishes on the surface (the boundary condition the image is for)."""
    rng = np.random.default_rng(0)
    n = np.array([0.3, -0.2, 0.93])
    n /= np.linalg.norm(n)
    p0 = np.array([0.01, 0.02, -0.01])
    p = p0 + 0.004 * n + np.array([0.001, -0.002, 0.0005])
    m = rng.normal(size=3)
    p_img, m_img = image_dipole(p, m, p0, n)
    # The mirror point: the midpoint on the surface, the separation along the normal.
    assert abs(((p + p_img) / 2 - p0) @ n) < 1e-15
    np.testing.assert_allclose(np.cross(p - p_img, n), 0.0, atol=1e-15)
    t1 = np.cross(n, [1.0, 0.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    for a, b in rng.uniform(-0.01, 0.01, size=(5, 2)):
        q = p0 + a * t1 + b * t2
        B = dipole_field(q - p, m) + dipole_field(q - p_img, m_img)
        tangential = np.linalg.norm(B - (B @ n) * n)
        assert tangential < 1e-12 * np.linalg.norm(B), (tangential, np.linalg.norm(B))
    # The normal component is kept, the tangential one flipped.
    np.testing.assert_allclose(m_img @ n, m @ n, rtol=1e-12)
    np.testing.assert_allclose(m_img - (m_img @ n) * n, -(m - (m @ n) * n), atol=1e-15)


def test_image_force_is_minus_the_gradient_of_the_induced_energy():
    rng = np.random.default_rng(1)
    n = np.array([0.0, 0.0, 1.0])
    p = np.array([0.001, -0.002, 0.003])
    m = 0.0192 * rng.normal(size=3)
    F = image_force(p, m, np.zeros(3), n)
    h = 1e-8
    grad = np.array([(image_energy(p + h * e, m, np.zeros(3), n) - image_energy(p - h * e, m, np.zeros(3), n)) / (2 * h)
                     for e in np.eye(3)])
    np.testing.assert_allclose(F, -grad, rtol=1e-6, atol=1e-9 * np.linalg.norm(F))
    assert np.linalg.norm(F[:2]) < 1e-12 * abs(F[2])  # a plane pulls along its normal only


def test_normal_dipole_pull_is_the_coaxial_image_limit():
    """A dipole normal to soft iron at height h: 3 mu0 m^2 / (32 pi h^4); parallel: half of it."""
    M, h = BallChain().dipole_moment, 1.5875e-3
    expected = 3 * MU0 * M**2 / (32 * math.pi * h**4)
    assert normal_attraction(M, h) == pytest.approx(expected, rel=1e-12)
    assert normal_attraction(M, h, math.pi / 2) == pytest.approx(expected / 2, rel=1e-12)
    assert gram_force(normal_attraction(M, h)) == pytest.approx(222.0, abs=0.5)  # a touching ball: 222 gf
    # A finite permeability scales the image by (mu_r - 1) / (mu_r + 1); air (mu_r = 1) none.
    assert normal_attraction(M, h, mu_r=1000.0) == pytest.approx(expected * 999 / 1001, rel=1e-12)
    assert image_factor(1.0) == 0.0
    with pytest.raises(ValueError):
        image_dipole(np.array([0.0, 0.0, -1e-3]), np.ones(3), np.zeros(3), [0, 0, 1])


def test_sensor_resolution_every_table_i_value_is_a_whole_step():
    r = effects.sensor_resolution()
    assert r.step_gf == pytest.approx(5.0986, abs=1e-4)
    assert r.largest_distance_from_a_whole_step < 0.01


# --- the sizing search --------------------------------------------------------------------------


class _PowerLaw:
    """A stand-in for TargetSolver: the best force F = F0 (D / D0)^p, counting its solves."""

    def __init__(self, f0, d0, p):
        self.f0, self.d0, self.p, self.calls = f0, d0, p, 0

    def force(self, D):
        return self.f0 * (D / self.d0) ** self.p

    def solve(self, D):
        self.calls += 1
        return clinical.TargetForce("x", self.force(D), True, 0.0, 0.0, self.force(D), None, 0, "")


@pytest.mark.parametrize("f0, p", [(1.8, 2.4), (4.85, 1.7), (14.0, 2.0)])
def test_threshold_search_finds_the_power_law_crossing(f0, p):
    fake = _PowerLaw(f0, 0.119, p)
    found = clinical.threshold_diameter(fake, fake.solve(0.119), 0.119)
    exact = 0.119 * (10.0 / f0) ** (1 / p)
    assert found["diameter_m"] == pytest.approx(exact, rel=1e-6)  # log-log interpolation is exact here
    lo, hi = found["bracket_m"]
    assert fake.force(lo) < 10.0 <= fake.force(hi) and hi - lo <= 0.02 * hi
    assert found["steps"] == fake.calls - 1 <= 6


class _FailsOnce(_PowerLaw):
    """Finds nothing inside the cone at its second solve unless restarted from the seeds."""

    def __init__(self, *args):
        super().__init__(*args)
        self.restarts = 0

    def restart(self):
        self.restarts += 1

    def solve(self, D):
        out = super().solve(D)
        if self.calls == 2 and not self.restarts:
            return clinical.TargetForce("x", 0.0, False, None, None, None, None, 0, "nothing inside the cone")
        return out


def test_threshold_search_retries_a_failed_search_from_the_seeds():
    fake = _FailsOnce(1.8, 0.119, 2.0)
    found = clinical.threshold_diameter(fake, fake.solve(0.119), 0.119)
    assert fake.restarts == 1
    assert found["diameter_m"] == pytest.approx(0.119 * (10.0 / 1.8) ** 0.5, rel=1e-6)
    assert all(f > 0 for _, f in found["history"])


class _FailsAt(_PowerLaw):
    """Finds nothing inside the cone at one size, restarted or not (an isolated search failure)."""

    def __init__(self, *args, bad):
        super().__init__(*args)
        self.bad = bad

    def restart(self):
        pass

    def solve(self, D):
        if abs(D - self.bad) < 1e-12:
            self.calls += 1
            return clinical.TargetForce("x", 0.0, False, None, None, None, None, 0, "nothing inside the cone")
        return super().solve(D)


def test_threshold_search_steps_over_an_isolated_failure():
    probe = _PowerLaw(1.8, 0.119, 2.0)
    first_step = clinical.threshold_diameter(probe, probe.solve(0.119), 0.119)["history"][1][0]
    fake = _FailsAt(1.8, 0.119, 2.0, bad=first_step)
    found = clinical.threshold_diameter(fake, fake.solve(0.119), 0.119)
    assert (first_step, 0.0) in found["history"]
    assert found["diameter_m"] == pytest.approx(0.119 * (10.0 / 1.8) ** 0.5, rel=1e-6)


def test_threshold_search_says_when_the_limit_is_too_small():
    fake = _PowerLaw(0.5, 0.119, 1.0)
    found = clinical.threshold_diameter(fake, fake.solve(0.119), 0.119, max_diameter=0.5)
    assert found["diameter_m"] is None


def test_quantile_diameter_counts_targets():
    d = [100.0, 150.0, None, 120.0, 130.0, 140.0, 110.0, 160.0, 170.0, 180.0]
    assert clinical._quantile_diameter(d, 0.9) == 180.0  # 9 of 10 reach 10 gf by 180 mm
    assert clinical._quantile_diameter(d, 1.0) is None  # one target never does
    assert clinical._quantile_diameter(d[:2] + d[3:], 1.0) == 180.0
    assert clinical._quantile_diameter(d[:2] + d[3:], 0.8) == 170.0  # 8 of 9


@pytest.mark.slow
def test_right_vein_force_grows_with_the_spheres_and_crosses_10_gf():
    """Today's chain on the RSPV: the best force inside the cone rises with D; 10 gf between
    119 mm and 2.5 times that; the tip force is almost all push (the gradient pull < 5 %)."""
    import ballchain.drake_models.heart as heart

    solver = clinical.TargetSolver(clinical.todays_chain(), "RSPV", 0.1, 0.0, 0.2965, "surface", heart.LeftAtrium())
    forces = []
    for D in (0.119, 0.15, 0.19):
        r = solver.solve(D)
        assert r.feasible and r.friction_needed <= 0.1 * (1 + 2e-3)
        assert abs(r.gradient_pull_gf) < 0.05 * r.force_gf
        np.testing.assert_allclose(r.gradient_pull_gf + r.sheath_push_gf, r.force_gf, rtol=1e-9)
        forces.append(r.force_gf)
    assert forces[0] < forces[1] < forces[2]
    assert forces[0] < 10.0 < forces[2]
    found = clinical.threshold_diameter(solver, solver.solve(0.119), 0.119)
    assert 0.15 < found["diameter_m"] < 0.19
    assert found["steps"] <= 6


# --- helpers of the effects models --------------------------------------------------------------


def test_frame_field_is_the_same_field_in_rotated_coordinates():
    from ballchain.drake_models.field_sources import MagnetSource

    source = MagnetSource(SphereMagnet(), [0.2, -0.1, 0.05], effects.frame_along([0.3, 0.4, -0.2]))
    R = effects.frame_along([-0.2, 0.9, 0.1])
    t = np.array([0.01, 0.02, -0.03])
    p_C = np.array([[0.001, 0.002, 0.003], [-0.01, 0.0, 0.02]])
    B_C, G_C = effects.FrameField(source, R, t).field_and_gradient(p_C)
    B_S, G_S = source.field_and_gradient(p_C @ R.T + t)
    np.testing.assert_allclose(B_C @ R.T, B_S, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(np.einsum("ia,kab,jb->kij", R, G_C, R), G_S, rtol=1e-10, atol=1e-15)


def test_frozen_field_keeps_each_balls_field_and_drops_the_gradient():
    from ballchain.drake_models.field_sources import MagnetSource, field_gradient_derivative

    source = MagnetSource(SphereMagnet(), [0.0, -0.2, 0.0])
    p = np.array([[0.0, 0.0, 0.0], [0.003, 0.0, 0.0], [0.006, 0.001, 0.0]])
    frozen = effects.FrozenField(source, p)
    B, G = frozen.field_and_gradient(p + 1e-3)  # moved balls keep their fields
    np.testing.assert_array_equal(B, source.field_and_gradient(p)[0])
    assert not G.any() and not field_gradient_derivative(frozen, p).any()
    with pytest.raises(ValueError, match="3 balls"):
        frozen.field_and_gradient(p[:2])


def test_cli_refuses_bad_flags(capsys):
    from ballchain.cli import main

    assert main(["clinical", "--chains", "12Fr"]) == 2
    assert "chains" in capsys.readouterr().err
    assert main(["clinical", "--max-diameter-mm", "80"]) == 2


def test_slerp_turns_rows_along_the_great_circle():
    a = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    b = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    half = clinical._slerp(a, b, 0.5)
    np.testing.assert_allclose(half[0], [math.sqrt(0.5), math.sqrt(0.5), 0.0], atol=1e-12)
    assert abs(half[1] @ a[1]) < 1e-12 and np.linalg.norm(half[1]) == pytest.approx(1.0)  # opposite: 90 deg
    np.testing.assert_allclose(half[2], a[2])
    np.testing.assert_allclose(clinical._slerp(a, b, 1.0), b, atol=1e-12)


def test_the_push_curve_without_a_field_ends_instead_of_raising():
    """With no field the pushed chain's held-tip Newton system can turn singular in floating point
    near the straight chain: the solve reports non-convergence (the curve ends there) instead of
    raising LinAlgError (which stopped ``reproduce``). The push is the chain's buckling load, about
    2.1 gf."""
    from ballchain.experiments import table1_effects

    (row,) = table1_effects.push_curve(fields_mT=(0.0,), steps=24)
    assert row.curve_mm_gf and 1.5 < row.plateau_gf < 3.0
