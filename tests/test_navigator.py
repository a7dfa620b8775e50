"""The navigator's contact-force estimate (no force sensor) against the engine's true force, on
static cases: the magnet held where inverse statics says it presses a target; and its controls."""

import numpy as np
import pytest

from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.localisation import LocalisationParams
from ballchain.drake_models.params import BallChain, newtons_from_gram_force
from ballchain.systems.autonomous_navigator import NavigatorParams
from ballchain.systems.tip_force_estimator import TipForceEstimator

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


def test_the_dwell_looks_every_dwell_period():
    """``NavigatorParams.dwell_period``: in the dwell the navigator looks (asks the force model)
    once every dwell_period, each look counting that long of RF time; the dwell still ends
    ``dwell`` after the touch, and seeking looks every period. A period that is not a whole
    number of periods is refused."""
    from pydrake.systems.analysis import Simulator

    from ballchain.drake_models.params import BallChain
    from ballchain.systems.autonomous_navigator import AutonomousNavigator, TargetPlan

    command = newtons_from_gram_force(20.0)
    n_W = np.array([0.0, 0.0, 1.0])
    asked = []

    class Pressing:  # the force model: the commanded force on the target's normal, wherever the tip
        chain = BallChain()

        def reaction_W(self, p_W, dipoles_W, inserted_length, sheath_offset_W=None):
            asked.append(round(self.t, 6))
            return command * n_W

    plan = TargetPlan("t", np.zeros(3), n_W, np.array([[1.0, 0.0, 0.0]]), 0.03,
                      np.column_stack([-n_W, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
                      np.eye(3), np.zeros((3, 2)), command)
    centre = 0.5 * BallChain().ball_diameter * n_W

    def dwell_of(params):
        asked.clear()
        model = Pressing()
        nav = AutonomousNavigator(["u"], [plan], model, params)
        context = nav.CreateDefaultContext()
        nav.GetInputPort("m_W_u").FixValue(context, np.array([1.0, 0.0, 0.0]))
        nav.GetInputPort("inserted_length").FixValue(context, [0.03])
        nav.GetInputPort("p_WT_measured").FixValue(context, centre)
        simulator = Simulator(nav, context)
        k = 0
        while not nav.is_done(context) and k < 200:
            k += 1
            model.t = (k - 1) * params.period  # the time of the next update
            simulator.AdvanceTo(model.t + 0.5 * params.period)  # that update done
        assert nav.is_done(context)
        record = nav.records(context)[0]
        return record, [t for t in asked if t > record.t_touch + 1e-9]

    quick = NavigatorParams(start_time=0.0, dwell=1.0, dwell_period=0.05)
    record, dwell_looks = dwell_of(quick)
    assert record.reached and len(record.estimates) == len(dwell_looks) == 20
    assert record.t_end - record.t_touch == pytest.approx(1.0, abs=1e-9)
    slow = NavigatorParams(start_time=0.0, dwell=1.0, dwell_period=0.25)
    record, dwell_looks = dwell_of(slow)
    assert record.reached and record.dwell_time == pytest.approx(1.0)
    np.testing.assert_allclose([t for t, _ in record.estimates], record.t_touch + 0.25 * np.arange(1, 5), atol=1e-9)
    assert len(dwell_looks) == 4 and record.t_end - record.t_touch == pytest.approx(1.0, abs=1e-9)
    for bad in (0.07, 0.0, 0.02):
        with pytest.raises(UserInputError, match="dwell_period"):
            NavigatorParams(dwell_period=bad).validate()


def test_a_dipole_within_the_hold_band_is_left_where_it_is():
    """``NavigatorParams.hold_band``: no stick for a dipole within it of the desired one (half a
    wheel microstep's turn of the magnet by default, which the steppers cannot resolve), a stick
    towards the desired dipole beyond it; a band that is negative or a tenth of a radian is refused."""
    from ballchain.drake_models.params import BallChain
    from ballchain.systems.autonomous_navigator import AutonomousNavigator, TargetPlan

    params = NavigatorParams()
    assert np.degrees(2 * params.hold_band) == pytest.approx(0.124, abs=5e-4)  # 1.8 deg / 16 x rho_w / rho_a
    plan = TargetPlan("t", np.zeros(3), np.array([0.0, 0.0, 1.0]), np.array([[1.0, 0.0, 0.0]]), 0.03,
                      np.eye(3), np.eye(3), np.zeros((3, 2)), params.force_command)

    class Model:
        chain = BallChain()

    nav = AutonomousNavigator(["u"], [plan], Model(), params)
    m = np.array([[1.0, 0.0, 0.0]])
    for angle, moves in ((0.9 * params.hold_band, False), (1.1 * params.hold_band, True)):
        m_des = np.array([[np.cos(angle), np.sin(angle), 0.0]])
        stick = nav._sticks(m, m_des)[0]
        assert bool(np.any(stick)) == moves
        if moves:  # about +z: the magnet turns towards the desired dipole
            assert stick[2] > params.dead_band and abs(stick[0]) < 1e-12 and abs(stick[1]) < 1e-12
    for bad in (-1e-3, 0.1):
        with pytest.raises(UserInputError, match="hold_band"):
            NavigatorParams(hold_band=bad).validate()


def test_the_move_to_the_next_target_lifts_the_tip_off_the_wall():
    """``NavigatorParams.lift``: after the first target, the move draws the chain back by
    ``lift`` while the magnets turn (the feeder's command is a retraction), then, once the
    dipoles are aligned with the plan, feeds it to the plan's length; the first target and a
    lift of 0 feed straight to the plan's length."""
    from pydrake.systems.analysis import Simulator

    from ballchain.drake_models.params import BallChain
    from ballchain.systems.autonomous_navigator import AutonomousNavigator, TargetPlan

    command = newtons_from_gram_force(20.0)
    n_W, s_plan = np.array([0.0, 0.0, 1.0]), 0.03
    m_1, m_2 = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])

    class Pressing:
        chain = BallChain()

        def reaction_W(self, p_W, dipoles_W, inserted_length, sheath_offset_W=None):
            return command * n_W

    plans = [TargetPlan(name, np.zeros(3), n_W, m[None, :], s_plan, np.column_stack([-n_W, [1.0, 0, 0], [0, 1.0, 0]]),
                        np.eye(3), np.zeros((3, 2)), command) for name, m in (("a", m_1), ("b", m_2))]
    centre = 0.5 * BallChain().ball_diameter * n_W

    def feeds(params):
        nav = AutonomousNavigator(["u"], plans, Pressing(), params)
        context = nav.CreateDefaultContext()
        nav.GetInputPort("m_W_u").FixValue(context, m_1)
        nav.GetInputPort("inserted_length").FixValue(context, [s_plan])
        nav.GetInputPort("p_WT_measured").FixValue(context, centre)
        simulator = Simulator(nav, context)
        t = 0.0
        while not nav.records(context) or len(nav.records(context)) < 2:  # the first target pressed and held
            t += params.period
            simulator.AdvanceTo(t)
            assert t < 5.0
        turning = float(nav.GetOutputPort("v_insert_cmd").Eval(context)[0])
        nav.GetInputPort("m_W_u").FixValue(context, m_2)  # the magnets reach the next plan
        simulator.AdvanceTo(t + 2 * params.period)
        return turning, float(nav.GetOutputPort("v_insert_cmd").Eval(context)[0])

    params = NavigatorParams(start_time=0.0, dwell=0.1, dwell_period=0.05)
    turning, aligned = feeds(params)
    assert turning == pytest.approx(-params.feeder_gain * params.lift)  # drawn back while turning
    assert aligned == 0.0  # aligned at the plan's length: no feed (the lift is undone from s)
    turning, _ = feeds(NavigatorParams(start_time=0.0, dwell=0.1, dwell_period=0.05, lift=0.0))
    assert turning == 0.0
    for bad in (-1e-3, 0.1):
        with pytest.raises(UserInputError, match="lift"):
            NavigatorParams(lift=bad).validate()


def test_a_tip_beyond_the_wall_is_drawn_back():
    """``NavigatorParams.captured``: a measured tip more than ``captured`` beyond the target's
    wall for ``settle`` looks (in a vein) makes the navigator draw the chain back (the feeder's
    full speed backwards) until the tip is inside the wall; a target never pressed is then given
    up, one pressed before (the tip slipped off it into the vein) is sought again. Just inside
    that depth the navigator keeps seeking and feeding."""
    from pydrake.systems.analysis import Simulator

    from ballchain.drake_models.params import BallChain
    from ballchain.systems.autonomous_navigator import AutonomousNavigator, TargetPlan

    n_W = np.array([0.0, 0.0, 1.0])  # into the chamber
    command = newtons_from_gram_force(20.0)

    class Model:
        chain, pressing = BallChain(), False

        def reaction_W(self, p_W, dipoles_W, inserted_length, sheath_offset_W=None):
            return command * n_W if self.pressing else np.zeros(3)

    plan = TargetPlan("t", np.zeros(3), n_W, np.array([[1.0, 0.0, 0.0]]), 0.03,
                      np.column_stack([-n_W, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
                      np.eye(3), np.zeros((3, 2)), command)
    params = NavigatorParams(start_time=0.0)
    centre = 0.5 * BallChain().ball_diameter * n_W

    def start(tip, pressing=False):
        model = Model()
        model.pressing = pressing
        nav = AutonomousNavigator(["u"], [plan], model, params)
        context = nav.CreateDefaultContext()
        nav.GetInputPort("p_WT_measured").FixValue(context, tip)
        nav.GetInputPort("m_W_u").FixValue(context, np.array([1.0, 0.0, 0.0]))
        nav.GetInputPort("inserted_length").FixValue(context, [0.029])  # 1 mm short of the plan
        return nav, context, Simulator(nav, context)

    def advance(simulator, periods):
        simulator.AdvanceTo(simulator.get_context().get_time() + periods * params.period)

    def drawn_back(nav, context, simulator):
        assert nav.GetOutputPort("v_insert_cmd").Eval(context)[0] == pytest.approx(-params.feeder_speed)
        advance(simulator, 4)
        assert nav.GetOutputPort("v_insert_cmd").Eval(context)[0] == pytest.approx(-params.feeder_speed)
        nav.GetInputPort("p_WT_measured").FixValue(context, centre + 1e-4 * n_W)  # back inside
        advance(simulator, 2)

    # Never pressed: in the vein on the way in, drawn back, given up.
    nav, context, simulator = start(centre - 1.01 * params.captured * n_W)
    advance(simulator, params.settle + 1.5)
    drawn_back(nav, context, simulator)
    (record,) = nav.records(context)
    assert record.captures == 1 and not record.reached and nav.is_done(context)
    # Pressed, then slipped off into the vein: drawn back, sought again.
    nav, context, simulator = start(centre, pressing=True)
    nav.GetInputPort("inserted_length").FixValue(context, [0.03])
    advance(simulator, params.settle + 3.5)
    assert nav.records(context)[0].reached
    nav.GetInputPort("p_WT_measured").FixValue(context, centre + [4e-3, 0, 0] - 1.01 * params.captured * n_W)
    nav.GetInputPort("inserted_length").FixValue(context, [0.029])
    advance(simulator, round(params.dwell_period / params.period) + params.settle + 1)  # the slip, then the looks
    drawn_back(nav, context, simulator)
    (record,) = nav.records(context)
    assert record.captures == 1 and record.slips == 1 and not nav.is_done(context)
    assert nav.GetOutputPort("v_insert_cmd").Eval(context)[0] > 0.0  # seeking at the plan's length again
    # Just inside the depth: seeking and feeding on.
    nav, context, simulator = start(centre - 0.99 * params.captured * n_W)
    advance(simulator, params.settle + 1.5)
    (record,) = nav.records(context)
    assert record.captures == 0 and nav.GetOutputPort("v_insert_cmd").Eval(context)[0] > 0.0
    with pytest.raises(UserInputError, match="captured"):
        NavigatorParams(captured=-1e-3).validate()


def test_the_dwell_row_counts_every_sample_between_the_looks():
    """``procedure_runs._dwell_row``: with a look every ``look_period`` the dwell's figures are
    taken over every logged sample in the dwell (each look standing for the samples since the one
    before, the estimate held between the looks), not over the looks alone; a slip's interval (no
    look recorded) is left out; with a look every period only the looks' samples count."""
    from ballchain.experiments.procedure_runs import _dwell_row
    from ballchain.systems.autonomous_navigator import DwellRecord, TargetPlan

    period, lo, hi = 0.05, newtons_from_gram_force(10.0), newtons_from_gram_force(40.0)
    t = np.round(np.arange(0, 61) * period, 10)  # 0 .. 3 s
    n_W = np.array([0.0, 0.0, 1.0])
    true = np.where(t < 1.0, newtons_from_gram_force(20.0), newtons_from_gram_force(5.0))  # drops out of the window

    class Log:
        def __init__(self, data):
            self._data = np.atleast_2d(data)

        def FindLog(self, context):
            return self

        def sample_times(self):
            return t

        def data(self):
            return self._data

    force = Log(np.vstack([np.zeros((2, t.size)), true]))
    balls = Log(np.zeros((3, t.size)))
    estimate = Log(np.full(t.size, newtons_from_gram_force(20.0)))
    plan = TargetPlan("t", np.zeros(3), n_W, np.array([[1.0, 0.0, 0.0]]), 0.03, np.eye(3), np.eye(3),
                      np.zeros((3, 2)), newtons_from_gram_force(20.0))
    record = DwellRecord("t", 0.0, t_touch=0.25, t_end=2.5, reached=True, dwell_time=2.0)
    # Looks every 0.25 s from 0.5 to 1.5 s, a slip, then again from 2.0 to 2.25 s.
    looks = [0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 2.25]
    record.estimates = [(x, newtons_from_gram_force(20.0)) for x in looks]
    row = _dwell_row(record, [force, balls, estimate, balls], None, plan, (lo, hi), 0.0, 0.25)
    counted = [x for x in t if any(0 <= L - x < 0.25 - 1e-9 for L in looks)]
    inside = sum(1 for x in counted if x < 1.0)
    assert len(counted) == 7 * 5
    assert row["in_window_fraction"] == pytest.approx(round(inside / len(counted), 4))
    assert row["force_true_min_gf"] == pytest.approx(5.0)
    # Looks every period: the looks' own samples only (the code before the dwell's look period).
    row = _dwell_row(record, [force, balls, estimate, balls], None, plan, (lo, hi), 0.0, period)
    assert row["in_window_fraction"] == pytest.approx(round(sum(1 for x in looks if x < 1.0) / len(looks), 4))
