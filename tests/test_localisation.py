"""The simulated localisation sensor against its parameters: noise, rate, latency; bad figures."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.localisation import LocalisationParams
from ballchain.systems.localisation_sensor import LocalisationSensor


def _run(params, velocity, duration, seed=0):
    """Two balls, the tip moving at ``velocity`` from (1, 2, 3) mm; the output logged at every sample."""
    builder = DiagramBuilder()
    t = [0.0, duration + 1.0]
    start = np.array([0.0, 0.0, 0.0, 1e-3, 2e-3, 3e-3])
    end = start + np.concatenate([np.zeros(3), np.asarray(velocity) * t[1]])
    source = builder.AddSystem(TrajectorySource(PiecewisePolynomial.FirstOrderHold(t, np.column_stack([start, end]))))
    sensor = builder.AddSystem(LocalisationSensor(2, params, seed))
    builder.Connect(source.get_output_port(), sensor.get_ball_positions_input_port())
    logger = LogVectorOutput(sensor.GetOutputPort("p_WT_measured"), builder, params.period)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(duration)
    log = logger.FindLog(simulator.get_context())
    return log.sample_times(), log.data().T


def test_noise_std_matches_its_parameter():
    params = LocalisationParams(noise_std=0.4e-3, rate=40.0, latency=0.05)
    _, data = _run(params, np.zeros(3), 20.0)
    errors = data[5:] - np.array([1e-3, 2e-3, 3e-3])
    # 800 samples per axis: the sample std's own spread is sigma / sqrt(2 * 800) = 2.5 %; 10 % is 4 spreads.
    assert np.allclose(errors.std(axis=0), 0.4e-3, rtol=0.10)
    assert np.allclose(errors.mean(axis=0), 0.0, atol=4 * 0.4e-3 / np.sqrt(len(errors)))


def test_rate_and_latency():
    """Noise-free on a ramp: one new value per sample period, the true tip a latency earlier."""
    v = np.array([1e-3, 0.0, 0.0])  # 1 mm/s
    params = LocalisationParams(noise_std=0.0, rate=40.0, latency=0.075)
    t, data = _run(params, v, 2.0)
    changes = np.count_nonzero(np.abs(np.diff(data[:, 0])) > 1e-12)
    # The first reading stands until the first delayed sample arrives (delay_samples periods).
    assert changes == pytest.approx(2.0 * params.rate - params.delay_samples, abs=1)
    # A log at t_k reads the value held over (t_(k-1), t_k] (it publishes before the update at
    # t_k): the sample taken a latency before t_(k-1).
    late = t > params.latency + params.period + 0.01
    expected = 1e-3 + v[0] * (t[late] - params.period - params.latency)
    assert np.allclose(data[late, 0], expected, atol=1e-9)


def test_sample_k_is_the_tip_plus_default_rngs_draw():
    """Without latency, the reading after sample k is the tip plus
    ``noise_std * default_rng((seed, k)).standard_normal(3)`` (the documented stream)."""
    params = LocalisationParams(noise_std=0.4e-3, rate=40.0, latency=0.0)
    t, data = _run(params, np.zeros(3), 0.5, seed=7)
    tip = np.array([1e-3, 2e-3, 3e-3])
    for k in range(1, 15):  # the log at t_k reads sample k - 1 (it publishes before the update at t_k)
        row = int(np.argmin(np.abs(t - k * params.period)))
        expected = tip + params.noise_std * np.random.default_rng((7, k - 1)).standard_normal(3)
        assert np.array_equal(data[row], expected), k


def test_same_seed_same_noise_other_seed_other():
    params = LocalisationParams()
    a = _run(params, np.zeros(3), 1.0, seed=3)[1]
    b = _run(params, np.zeros(3), 1.0, seed=3)[1]
    c = _run(params, np.zeros(3), 1.0, seed=4)[1]
    assert np.array_equal(a, b) and not np.allclose(a, c)


@pytest.mark.parametrize("field, value", [("noise_std", -1e-3), ("noise_std", float("nan")), ("rate", 0.0),
                                          ("latency", 2.0), ("latency", 0.03), ("rate", True)])
def test_bad_figures_name_the_field(field, value):
    with pytest.raises(UserInputError, match=field):
        LocalisationParams(**{field: value})
