"""The statics' answer: ``StaticsResult`` (an equilibrium, or a failed solve's last iterate),
``StaticsError``, the straight chain (the cold start) and the tip's angle to a field.
``optimization.statics`` re-exports them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ballchain.drake_models.chain_energy import EnergyTerms
from ballchain.drake_models.params import BallChain
from ballchain.drake_models.vectors import angle_between
from ballchain.infrastructure.arg_checks import as_vector, require_type
from ballchain.optimization.reduced_chain import X_AXIS

Method = Literal["newton", "snopt"]


class StaticsError(RuntimeError):
    """A statics solve that did not converge, with the reason."""


@dataclass
class StaticsResult:
    """An equilibrium of the chain (or the last iterate of a failed solve).

    Attributes:
        positions: (n, 3) ball centres [m], ball 1 at the origin.
        dipoles: (n, 3) unit dipole directions, ball 1 along +x.
        energy: total potential energy [J].
        terms: the energy's parts.
        converged: whether the solver certified a (local) minimum.
        reason: the solver's message (why it stopped).
        solver: solver name.
        iterations: Newton iterations, or energy evaluations for SNOPT.
        solve_time: wall time of the solve [s].
        max_violation: largest rigidity-constraint violation, ``|p_i - p_j| < d``, [m] (0 if none).
        pair_forces: ``{(i, j): force [N]}`` between non-adjacent balls i, j (0-based) that touch
            at the equilibrium: the rigidity constraints' multipliers.
        tip_reaction: (3,) force [N] that a tip target exerts on the tip ball (the tip
            constraint's multiplier); zero without a target. The chain presses on the target
            with minus this.
        wall_forces: ``{i: force [N]}`` the wall pushes on ball i (0-based) along its normal.
        wall_forces_W: with ``HeartConstraints``: ``{i: f_W (3,) [N]}`` the atrium's wall
            pushes on ball i of the sub-chain (frictionless: along the wall's normal).
        sheath_forces_W: likewise the sheath's lip and bore.
        positions_W, dipoles_W: with ``HeartConstraints``: the configuration in world.
        multipliers: ``{row: multiplier}`` of the rows near contact at the solution (scaled
            units); a warm start carrying them starts the next solve's model with them.
    """

    positions: np.ndarray
    dipoles: np.ndarray
    energy: float
    terms: EnergyTerms
    converged: bool
    reason: str
    solver: str
    iterations: int
    solve_time: float
    max_violation: float = 0.0
    pair_forces: dict = field(default_factory=dict)
    tip_reaction: np.ndarray = field(default_factory=lambda: np.zeros(3))
    wall_forces: dict = field(default_factory=dict)
    wall_forces_W: dict = field(default_factory=dict)
    sheath_forces_W: dict = field(default_factory=dict)
    positions_W: np.ndarray | None = None
    dipoles_W: np.ndarray | None = None
    multipliers: dict = field(default_factory=dict)

    @property
    def tip_position(self) -> np.ndarray:
        return self.positions[-1]

    @property
    def tip_dipole(self) -> np.ndarray:
        return self.dipoles[-1]

    def link_directions(self) -> np.ndarray:
        """(n-1, 3) unit vectors from each ball to the next."""
        links = np.diff(self.positions, axis=0)
        return links / np.linalg.norm(links, axis=1)[:, None]


def straight_chain(chain: BallChain, direction=X_AXIS) -> tuple[np.ndarray, np.ndarray]:
    """The straight chain along ``direction`` from the origin, all dipoles along it."""
    direction = np.asarray(direction, dtype=float)
    direction = direction / np.linalg.norm(direction)
    n = chain.n_balls
    positions = np.arange(n)[:, None] * chain.ball_diameter * direction
    return positions, np.tile(direction, (n, 1))


def tip_angle_deg(result: StaticsResult, field_direction) -> float:
    """Angle between the tip ball's dipole and a field direction [deg]."""
    require_type(result, StaticsResult, "result", "a StaticsResult")
    as_vector(field_direction, "field_direction", nonzero=True)
    f = np.asarray(field_direction, dtype=float)
    return float(np.degrees(angle_between(result.tip_dipole, f / np.linalg.norm(f))))
