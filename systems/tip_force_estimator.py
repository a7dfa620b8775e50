"""The navigator's contact force without a force sensor: the chain's statics with the tip held at
the measured point (``TipForceEstimator``; ``systems/autonomous_navigator.py`` uses it every look).
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.field_sources import FieldSources, MagnetSource, rotation_with_z_along
from ballchain.drake_models.params import BallChain
from ballchain.optimization.compiled_held_tip import HeldTip, HeldTipStatics
from ballchain.optimization.statics import ChainStatics


class TipForceEstimator:
    """The contact force estimated from the model, without a force sensor.

    The statics of the chain beyond the sheath (``ChainStatics``, the planner's model: the
    first free ball at the sheath exit) under the measured magnets, with the tip ball's centre
    held at the measured point: the reaction that holds it there is what the wall supplies;
    its component on the wall's outward normal is the estimated contact force.

    Args:
        chain: the ball chain (its ball diameter; the number of free balls follows the insertion).
        p_WE, R_WS: the sheath exit [m] and the statics frame's rotation (x along the sheath).
        magnets: [(magnet, p_WM (3,))] the units' magnets (``params`` shapes) and centres.
        model: the field model of the magnets ("dipole", ...).
        n_max: the most free balls.
    """

    def __init__(self, chain: BallChain, p_WE, R_WS, magnets: list, model: str, n_max: int) -> None:
        self.chain, self.model, self.n_max = chain, model, int(n_max)
        self.p_WE, self.R_WS = np.asarray(p_WE, float), np.asarray(R_WS, float)
        self.magnets = [(mag, self.R_WS.T @ (np.asarray(p, float) - self.p_WE)) for mag, p in magnets]
        self._solvers: dict[int, HeldTipStatics] = {}
        self._last: dict[int, HeldTip] = {}

    def free_balls(self, inserted_length: float) -> int:
        """Balls beyond the sheath exit at an inserted length (ball 1 included, at least 2)."""
        # (n - 1/2) diameters put ball 1's centre at the exit with n balls out (the plans' rule);
        # rounded, so that a feeder within half a diameter of the plan's length counts n.
        return min(max(round(inserted_length / self.chain.ball_diameter + 0.5), 2), self.n_max)  # (np.clip's cost)

    def field_S(self, dipoles_W: np.ndarray, sheath_offset_W: np.ndarray | None = None) -> FieldSources:
        m_S = (self.R_WS.T @ np.asarray(dipoles_W, float).reshape(-1, 3).T).T
        magnets = self.magnets if sheath_offset_W is None else [  # the magnets stay; the sheath moved
            (mag, p - self.R_WS.T @ np.asarray(sheath_offset_W, float)) for mag, p in self.magnets]
        return FieldSources([MagnetSource(mag, p, rotation_with_z_along(m), self.model)
                             for (mag, p), m in zip(magnets, m_S)])

    def reaction_W(self, p_W: np.ndarray, dipoles_W: np.ndarray, inserted_length: float,
                   sheath_offset_W: np.ndarray | None = None) -> np.ndarray | None:
        """The reaction (3,) [N] holding the tip ball's centre at p_W (None: no held equilibrium),
        with the sheath's exit at ``p_WE`` moved by ``sheath_offset_W`` (3,) [m] (None: at rest).

        The statics (``ChainStatics``) on the compiled path with the magnets' arrays
        (``optimization.compiled_held_tip``: the same solve as with ``field_S``'s sources)."""
        n = self.free_balls(inserted_length)
        solver = self._solvers.get(n)
        if solver is None:
            solver = self._solvers[n] = HeldTipStatics(ChainStatics(self.chain.with_balls(n), max_iterations=25),
                                                       self.magnets, self.model)
        p_WE = self.p_WE if sheath_offset_W is None else self.p_WE + np.asarray(sheath_offset_W, float)
        target = self.R_WS.T @ (np.asarray(p_W, float) - p_WE)
        m_S = (self.R_WS.T @ np.asarray(dipoles_W, float).reshape(-1, 3).T).T
        shift = None if sheath_offset_W is None else self.R_WS.T @ np.asarray(sheath_offset_W, float)
        for start in (self._last.get(n), None):
            result = solver.reaction(m_S, target, start, shift)
            if result.converged:
                self._last[n] = result
                return self.R_WS @ result.tip_reaction
        return None

    def force(self, p_W, dipoles_W, inserted_length, n_out_W, sheath_offset_W=None) -> tuple[float, np.ndarray]:
        """(F, r_W): the estimated contact force [N] (the reaction on the outward normal
        ``n_out_W``, at least 0) and the whole reaction (zeros without an equilibrium)."""
        r = self.reaction_W(p_W, dipoles_W, inserted_length, sheath_offset_W)
        if r is None:
            return 0.0, np.zeros(3)
        return max(float(r @ np.asarray(n_out_W, float)), 0.0), r
