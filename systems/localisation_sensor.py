"""A simulated tip localisation sensor (electromagnetic tracking: ``drake_models.localisation``).

``LocalisationSensor`` samples the tip ball's true centre every ``1/rate`` seconds, adds
isotropic Gaussian noise, and outputs each sample ``latency`` seconds later (a whole number of
samples): what a clinical navigator reads. Until the first delayed sample exists the output is
the first noisy sample (the tracker reports from the start).

Randomness follows the station's convention (``randomness.SeededLeafSystem``): one seed
parameter; sample k's noise is drawn from ``numpy.random.default_rng((seed, k))`` (built by
``randomness.SampleGenerators``), so the output is a function of the context.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, EventStatus

from ballchain.drake_models.localisation import LocalisationParams
from ballchain.infrastructure.arg_checks import require_type
from ballchain.systems.randomness import SampleGenerators, SeededLeafSystem


class LocalisationSensor(SeededLeafSystem):
    """The tracked tip position.

    Input ports:
        ball_positions: (3 n,) the chain's ball centres [m] (the chain model's
            ``ball_positions``); the last three are the tip ball's.

    Output ports:
        p_WT_measured: (3,) the measured tip position [m].

    State (discrete, updated every ``params.period``): the delay line, (d + 1) samples of 3
    (newest last; d = ``params.delay_samples``), then the sample count.

    Args:
        n_balls: the chain's number of balls.
        params: LocalisationParams.
        seed: the default of the seed parameter (0..2**32-1).
    """

    def __init__(self, n_balls: int, params: LocalisationParams | None = None, seed: int = 0,
                 name: str = "localisation") -> None:
        super().__init__()
        self.params = p = params or LocalisationParams()
        require_type(p, LocalisationParams, "LocalisationSensor params", "a LocalisationParams")
        self.set_name(name)
        self._n = int(n_balls)
        self._d = p.delay_samples
        self.DeclareSeedParameter(seed)
        self._generators = SampleGenerators()
        self._in = self.DeclareVectorInputPort("ball_positions", 3 * self._n)
        self._state = self.DeclareDiscreteState(BasicVector(np.zeros(3 * (self._d + 1) + 1)))
        self.DeclareVectorOutputPort("p_WT_measured", 3, self._calc, prerequisites_of_calc={self.xd_ticket()})
        self.DeclarePeriodicDiscreteUpdateEvent(p.period, 0.0, self._update)

    def get_ball_positions_input_port(self):
        return self._in

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._state).get_value()
        k = int(x[-1])
        tip = np.asarray(self._in.Eval(context))[-3:]
        # default_rng((seed, k)).standard_normal(3), the same floats, drawn compiled.
        sample = tip + self.params.noise_std * self._generators.standard_normal(self.seed(context), k, 3)
        new = np.empty_like(x)  # the line shifted by one sample, the new one last, then the count
        if k == 0:  # the first sample fills the line: the reading exists from the start
            new[:-1] = np.tile(sample, self._d + 1)
        else:
            new[:-4], new[-4:-1] = x[3:-1], sample
        new[-1] = k + 1.0
        discrete_state.get_mutable_vector(self._state).SetFromVector(new)
        return EventStatus.Succeeded()

    def _calc(self, context, output):
        # The oldest sample of the line: taken d samples ago.
        output.SetFromVector(context.get_discrete_state(self._state).get_value()[:3])
