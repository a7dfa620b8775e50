"""Table I from statics: the stand's geometry and one short optimisation of the tip force."""

import numpy as np

from ballchain.drake_models.heart import LeftAtrium
from ballchain.drake_models.params import BallChain
from ballchain.experiments import forces


def test_stand_geometry():
    atrium = LeftAtrium()
    stand = forces.build_stand(atrium)
    # The statics frame: sheath axis along +x, rotation proper.
    np.testing.assert_allclose(stand.R_HS @ [1.0, 0, 0], atrium.sheath_axis_H, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(stand.R_HS), 1.0, atol=1e-12)
    for config, p_SM in stand.magnets.items():
        p_HM = stand.p_HE + stand.R_HS @ p_SM
        np.testing.assert_allclose(np.linalg.norm(p_HM - atrium.p_HP), forces.DISTANCE, rtol=1e-12)
    reach = 15 * BallChain().ball_diameter
    for vein, (target, axis) in stand.targets.items():
        assert np.linalg.norm(target) < reach, vein
        np.testing.assert_allclose(np.linalg.norm(axis), 1.0, atol=1e-12)


def test_short_optimisation_finds_a_pressing_force():
    stand = forces.build_stand()
    out = forces.max_normal_force(BallChain(n_balls=16), stand, "RSPV", ("1",), grid=4, refine_evaluations=5)
    assert out["force_N"] is not None
    result = out["result"]
    target, axis = stand.targets["RSPV"]
    np.testing.assert_allclose(result.tip_position, target, atol=1e-12)
    # Pressing into the vein, and of the size a 76 mm magnet 16 cm away can give (grams, not
    # the paper's tens of grams; see the report).
    assert 0.0 < out["force_N"] == -result.tip_reaction @ axis
    assert out["force_gf"] < 30.0
