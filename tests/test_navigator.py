"""The navigator's contact-force estimate (no force sensor) against the engine's true force, on
static cases: the magnet held where inverse statics says it presses a target; and its controls."""

import numpy as np
import pytest

from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.localisation import LocalisationParams
from ballchain.drake_models.params import BallChain, newtons_from_gram_force
from ballchain.systems.autonomous_navigator import NavigatorParams, TipForceEstimator

# Dipole directions (world) that inverse statics (``procedure.target_plans``) found to press the
# right ring's first target with the whole chain out: inputs of the static case, not answers.
RIGHT_1_DIPOLE = np.array([-0.0874, -0.106, 0.9905])


@pytest.fixture(scope="module")
def pressed():
    """The station's chain at equilibrium (quasi-static engine) with the magnet at RIGHT_1_DIPOLE."""
    from ballchain.drake_models.field_sources import rotation_with_z_along
    from ballchain.experiments.teleop import scenario_for
    from ballchain.systems.chain_simulation import MakeStation, run_station
    from ballchain.systems.target_contact import heart_targets

    scenario = scenario_for("world")
    s = (scenario.n_balls - 1) * BallChain().ball_diameter
    scenario.insertion.initial = scenario.insertion.final = s
    cd = MakeStation(scenario)
    context = cd.diagram.CreateDefaultContext()
    cd.diagram.GetInputPort("right_unit.joystick").FixValue(context, np.zeros(3))
    cd.diagram.GetInputPort("feeder.v_insert_cmd").FixValue(context, np.zeros(1))
    magnet = cd.units["right_unit"].magnet
    magnet.set_orientation(magnet.GetMyMutableContextFromRoot(context), rotation_with_z_along(RIGHT_1_DIPOLE))
    out = run_station(cd, duration=0.5, context=context)
    assert out.failure is None
    heart = cd.heart
    R_WS = rotation_with_z_along(heart.sheath_axis_H)[:, [2, 0, 1]]
    unit = cd.units["right_unit"].config
    estimator = TipForceEstimator(BallChain(), heart.p_HE, R_WS, [(unit.magnet, np.asarray(unit.p_WM))], unit.model,
                                  scenario.n_balls)
    names, p_WT, n_W, _ = heart_targets(heart)
    m_W = cd.units["right_unit"].magnet.GetOutputPort("m_W").Eval(magnet.GetMyContextFromRoot(out.context))
    return {"tip": cd.tip_position(out.context), "f_W": cd.tip_wall_force(out.context), "s": s,
            "m": np.asarray(m_W) / np.linalg.norm(m_W), "estimator": estimator, "n_W": n_W[names.index("right_1")]}


def test_the_case_presses_the_wall(pressed):
    assert pressed["f_W"] @ pressed["n_W"] > newtons_from_gram_force(5.0)


def test_estimate_at_the_true_tip(pressed):
    """Without sensor noise the estimate differs from the truth by the model's simplification
    only (the free chain beyond the sheath exit, against the engine's chain with the sheath and
    the wall along its length): within 10 % of the force."""
    e = pressed["estimator"]
    f_true = float(pressed["f_W"] @ pressed["n_W"])
    f_est, r = e.force(pressed["tip"], pressed["m"], pressed["s"], pressed["n_W"])
    assert f_est == pytest.approx(f_true, rel=0.10)
    # The reaction's direction is the wall's push: along the wall's normal.
    assert r @ pressed["f_W"] / (np.linalg.norm(r) * np.linalg.norm(pressed["f_W"])) > np.cos(np.radians(15.0))


def test_estimate_noise_follows_the_sensor_noise_and_the_stiffness(pressed):
    """With the sensor's noise sigma on the tip, the estimate's spread is sigma times the
    gradient of the estimate with the held point (the chain's stiffness at the tip), to first
    order; its mean stays within the model's 10 % plus three standard errors."""
    e = pressed["estimator"]
    tip, m, s, n = pressed["tip"], pressed["m"], pressed["s"], pressed["n_W"]
    sigma = LocalisationParams().noise_std
    h = 0.05e-3
    grad = np.array([(e.force(tip + h * d, m, s, n)[0] - e.force(tip - h * d, m, s, n)[0]) / (2 * h)
                     for d in np.eye(3)])
    spread = sigma * np.linalg.norm(grad)
    rng = np.random.default_rng(0)
    samples = np.array([e.force(tip + sigma * rng.standard_normal(3), m, s, n)[0] for _ in range(200)])
    # 200 samples: the sample std's own spread is 5 %; the noise is not small against the
    # stiffness's change over 0.4 mm, hence the factor-of-1.5 band of a first-order prediction.
    assert spread / 1.5 < samples.std() < 1.5 * spread
    f_true = float(pressed["f_W"] @ n)
    assert abs(samples.mean() - f_true) < 0.10 * f_true + 3 * samples.std() / np.sqrt(len(samples))


def test_navigator_params_are_checked():
    with pytest.raises(UserInputError, match="window"):
        NavigatorParams(force_command=newtons_from_gram_force(50.0)).validate()
    with pytest.raises(UserInputError, match="dwell"):
        NavigatorParams(dwell=-1.0).validate()


def test_the_force_model_holds_the_mean_of_the_last_looks():
    """``NavigatorParams.average``: the force model is asked for the tip at the mean of the last
    ``average`` measured tips on this target, the newest included; 0 or a fraction is refused."""
    from pydrake.systems.analysis import Simulator

    from ballchain.drake_models.params import BallChain
    from ballchain.systems.autonomous_navigator import AutonomousNavigator, TargetPlan

    asked = []

    class Recorder:
        chain = BallChain()

        def reaction_W(self, p_W, dipoles_W, inserted_length, sheath_offset_W=None):
            asked.append(np.array(p_W, float))
            return np.zeros(3)

    n_W = np.array([0.0, 0.0, 1.0])
    plan = TargetPlan("t", np.zeros(3), n_W, np.array([[1.0, 0.0, 0.0]]), 0.03,
                      np.column_stack([-n_W, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
                      np.eye(3), np.zeros((3, 2)), newtons_from_gram_force(20.0))
    tips = [np.array([0.0, 0.0, 1e-3 * k]) for k in range(6)]

    def looks_of(params):
        asked.clear()
        nav = AutonomousNavigator(["u"], [plan], Recorder(), params)
        context = nav.CreateDefaultContext()
        nav.GetInputPort("m_W_u").FixValue(context, np.array([1.0, 0.0, 0.0]))
        nav.GetInputPort("inserted_length").FixValue(context, [0.03])
        simulator = Simulator(nav, context)
        for k, tip in enumerate(tips):
            nav.GetInputPort("p_WT_measured").FixValue(context, tip)
            simulator.AdvanceTo(params.period * (k + 1) + 1e-6)
        assert len(asked) >= 4  # the move ended at the first look (aligned, at length): seeking since
        return list(asked), tips[len(tips) - len(asked):]  # the tips the seek looked at, in order

    asked_3, seen = looks_of(NavigatorParams(start_time=0.0, average=3))
    for j in range(len(asked_3)):
        np.testing.assert_allclose(asked_3[j], np.mean(seen[max(0, j - 2):j + 1], axis=0), atol=1e-15)
    asked_1, seen = looks_of(NavigatorParams(start_time=0.0))  # the default: each look alone, exactly
    assert all(np.array_equal(a, b) for a, b in zip(asked_1, seen, strict=True))
    for bad in (0, 2.5, True):
        with pytest.raises(UserInputError, match="average"):
            NavigatorParams(average=bad).validate()
