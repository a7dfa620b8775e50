"""The naive baseline of chain statics: a fmincon-style formulation solved by SLSQP.

This is what a competent user would write first, and what ``ChainStatics`` is measured against
(``ballchain bench statics``). It solves the canonical problem of ``optimization.statics``
(docs/design.md, 2.3): ball 1 held at the origin with its dipole along +x, balls 2..n free.

Formulation, in full (maximal) coordinates:

* variables ``x = (p_2 .. p_n, m_2 .. m_n)``: 6 (n - 1) numbers, positions in units of the
  ball diameter d (so the constraints are O(1)) and raw dipole vectors;
* objective: ``chain_energy`` (the one source of truth) divided by E0 = 2 k |m|^2 / d^3, the
  energy of two touching coaxial balls, at the normalised directions ``m_hat = m / |m|``. Its
  gradient is the analytic one of ``chain_energy`` through the chain rule,
  ``dU/dm = (I - m_hat m_hat^T) dU/dm_hat / |m|``. Normalising (rather than evaluating the
  energy at the raw vectors) keeps the objective exactly the energy of a physical configuration
  at every iterate, whatever the constraint violation, so the line search compares energies,
  not artefacts of |m| != 1;
* equality constraints: ``|m_i|^2 - 1 = 0`` (i = 2..n; they only fix the otherwise free scale
  of m_i, their multipliers are zero) and ``|p_{i+1} - p_i|^2 / d^2 - 1 = 0`` (adjacent balls
  touch);
* inequality constraints: ``|p_j - p_i|^2 / d^2 - 1 >= 0`` for every non-adjacent pair
  (j >= i + 2, ball 1 included);
* every constraint vectorised, with its analytic (dense) Jacobian;
* start: the straight chain along +x (or a given configuration), no continuation.

SLSQP (scipy) builds a BFGS approximation of the Lagrangian's Hessian, so it needs many
iterations where the reduced-coordinate Newton method with the exact Hessian needs a few.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from ballchain.drake_models.chain_energy import chain_energy
from ballchain.drake_models.dipole import K_DIPOLE
from ballchain.drake_models.field_sources import FieldSource
from ballchain.drake_models.params import BallChain
from ballchain.infrastructure.errors import UserInputError

_X_AXIS = np.array([1.0, 0.0, 0.0])


@dataclass
class NaiveStaticsResult:
    """The SLSQP baseline's answer.

    Attributes:
        positions: (n, 3) ball centres [m], ball 1 at the origin.
        dipoles: (n, 3) unit dipole directions (normalised), ball 1 along +x.
        energy: total potential energy at (positions, dipoles) [J].
        success: scipy's success flag (SLSQP exit mode 0).
        message: scipy's message.
        iterations: SLSQP major iterations.
        evaluations: objective (and gradient) evaluations.
        solve_time: wall time of the solve [s].
        max_violation: largest violation of any constraint, in units of d^2 (dimensionless).
    """

    positions: np.ndarray
    dipoles: np.ndarray
    energy: float
    success: bool
    message: str
    iterations: int
    evaluations: int
    solve_time: float
    max_violation: float

    @property
    def tip_position(self) -> np.ndarray:
        return self.positions[-1]

    @property
    def tip_dipole(self) -> np.ndarray:
        return self.dipoles[-1]


class NaiveStatics:
    """The fmincon-style problem of one chain in one field (see the module docstring).

    Args:
        chain: the chain (the sleeve's bending energy is included when ``chain.sleeve``).
        external: the external field source, or None.
        gravity: include gravity along -z.
        ftol: SLSQP's tolerance on the (scaled, O(1)) objective.
        max_iterations: SLSQP iteration limit.
    """

    def __init__(
        self,
        chain: BallChain,
        external: FieldSource | None,
        gravity: bool = False,
        ftol: float = 1e-12,
        max_iterations: int = 1000,
    ):
        if chain.n_balls < 2:
            raise UserInputError("the naive statics needs at least 2 balls (ball 1 is held)")
        self.chain = chain
        self.external = external
        self.gravity = gravity
        self.ftol = ftol
        self.max_iterations = max_iterations
        n = chain.n_balls
        self.n = n
        self.nf = n - 1  # free balls
        self.nx = 6 * self.nf
        self.d = chain.ball_diameter
        self.energy_scale = 2.0 * K_DIPOLE * chain.dipole_moment**2 / self.d**3
        self.pair_i, self.pair_j = np.triu_indices(n, k=2)  # 0-based ball indices
        self._rows_pair = np.arange(len(self.pair_i))
        self._rows_link = np.arange(n - 1)
        self._rows_m = np.arange(self.nf)
        self.evaluations = 0

    # --- variables -------------------------------------------------------------------------
    def pack(self, positions: np.ndarray, dipoles: np.ndarray) -> np.ndarray:
        """x from positions (n, 3) [m] and dipoles (n, 3) (ball 1's are ignored)."""
        return np.concatenate([(positions[1:] / self.d).ravel(), np.asarray(dipoles[1:], float).ravel()])

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(positions (n, 3) in units of d with ball 1 at 0, raw dipoles (n, 3) with m_1 = +x)."""
        h = 3 * self.nf
        P = np.vstack([np.zeros(3), x[:h].reshape(self.nf, 3)])
        M = np.vstack([_X_AXIS, x[h:].reshape(self.nf, 3)])
        return P, M

    def configuration(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(positions (n, 3) [m], unit dipoles (n, 3)) at x."""
        P, M = self.unpack(x)
        return P * self.d, M / np.linalg.norm(M, axis=1)[:, None]

    # --- objective -------------------------------------------------------------------------
    def objective(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """(U / E0, its gradient (nx,)) with the dipoles normalised."""
        self.evaluations += 1
        P, M = self.unpack(x)
        norms = np.linalg.norm(M, axis=1)
        m_hat = M / norms[:, None]
        U, dU_dp, dU_dmhat, _ = chain_energy(self.chain, P * self.d, m_hat, self.external, self.gravity)
        # Through m_hat = m / |m|: dU/dm = (I - m_hat m_hat^T) dU/dm_hat / |m|.
        radial = np.einsum("ij,ij->i", m_hat, dU_dmhat)
        dU_dm = (dU_dmhat - radial[:, None] * m_hat) / norms[:, None]
        grad = np.concatenate([(dU_dp[1:] * self.d).ravel(), dU_dm[1:].ravel()]) / self.energy_scale
        return U / self.energy_scale, grad

    # --- constraints (dimensionless, vectorised) -----------------------------------------------
    def equalities(self, x: np.ndarray) -> np.ndarray:
        """(|m_i|^2 - 1 for i = 2..n, |p_{i+1} - p_i|^2 / d^2 - 1 for i = 1..n-1)."""
        P, M = self.unpack(x)
        links = np.diff(P, axis=0)
        return np.concatenate([np.einsum("ij,ij->i", M[1:], M[1:]) - 1.0, np.einsum("ij,ij->i", links, links) - 1.0])

    def equality_jacobian(self, x: np.ndarray) -> np.ndarray:
        """(2 (n - 1), nx) Jacobian of ``equalities``."""
        P, M = self.unpack(x)
        nf, h = self.nf, 3 * self.nf
        J = np.zeros((2 * nf, self.nx))
        rows, k3 = self._rows_m, np.arange(3)
        # |m_i|^2: 2 m_i in m_i's columns (free ball f = i - 1 -> columns h + 3 f + k).
        J[rows[:, None], h + 3 * rows[:, None] + k3] = 2.0 * M[1:]
        # Link l between balls l and l+1 (0-based): +2 r on ball l+1 (free index l), -2 r on
        # ball l (free index l - 1, absent for the held ball 1).
        links = np.diff(P, axis=0)
        L = self._rows_link
        J[nf + L[:, None], 3 * L[:, None] + k3] = 2.0 * links
        J[nf + L[1:, None], 3 * (L[1:, None] - 1) + k3] = -2.0 * links[1:]
        return J

    def inequalities(self, x: np.ndarray) -> np.ndarray:
        """|p_j - p_i|^2 / d^2 - 1 >= 0 for every non-adjacent pair (j >= i + 2)."""
        P, _ = self.unpack(x)
        S = P[self.pair_j] - P[self.pair_i]
        return np.einsum("ij,ij->i", S, S) - 1.0

    def inequality_jacobian(self, x: np.ndarray) -> np.ndarray:
        """(pairs, nx) Jacobian of ``inequalities``."""
        P, _ = self.unpack(x)
        S = P[self.pair_j] - P[self.pair_i]
        J = np.zeros((len(S), self.nx))
        rows, k3 = self._rows_pair[:, None], np.arange(3)
        J[rows, 3 * (self.pair_j[:, None] - 1) + k3] = 2.0 * S  # pair_j >= 2: always free
        free_i = self.pair_i >= 1
        J[rows[free_i], 3 * (self.pair_i[free_i, None] - 1) + k3] = -2.0 * S[free_i]
        return J

    # --- solve -----------------------------------------------------------------------------
    def solve(self, positions: np.ndarray | None = None, dipoles: np.ndarray | None = None) -> NaiveStaticsResult:
        """Minimise from (positions, dipoles), the straight chain along +x if None.

        Args:
            positions: (n, 3) initial ball centres [m] (ball 1's is ignored: it is held at 0).
            dipoles: (n, 3) initial dipole directions.

        Returns:
            The result; check ``success``.
        """
        start = time.perf_counter()
        if (positions is None) != (dipoles is None):
            raise UserInputError("give both positions and dipoles for the initial guess, or neither")
        if positions is None:
            positions = np.arange(self.n)[:, None] * self.d * _X_AXIS
            dipoles = np.tile(_X_AXIS, (self.n, 1))
        x0 = self.pack(np.asarray(positions, float), np.asarray(dipoles, float))
        self.evaluations = 0
        constraints = [
            {"type": "eq", "fun": self.equalities, "jac": self.equality_jacobian},
        ]
        if len(self.pair_i):
            constraints.append({"type": "ineq", "fun": self.inequalities, "jac": self.inequality_jacobian})
        res = minimize(
            self.objective,
            x0,
            jac=True,
            method="SLSQP",
            constraints=constraints,
            options={"ftol": self.ftol, "maxiter": self.max_iterations},
        )
        positions, dipoles = self.configuration(res.x)
        U = chain_energy(self.chain, positions, dipoles, self.external, self.gravity)[0]
        violation = float(np.abs(self.equalities(res.x)).max())
        if len(self.pair_i):
            violation = max(violation, float(np.maximum(0.0, -self.inequalities(res.x)).max()))
        return NaiveStaticsResult(
            positions=positions,
            dipoles=dipoles,
            energy=float(U),
            success=bool(res.success),
            message=str(res.message),
            iterations=int(res.nit),
            evaluations=self.evaluations,
            solve_time=time.perf_counter() - start,
            max_violation=violation,
        )


def solve_naive_statics(
    chain: BallChain,
    external: FieldSource | None,
    gravity: bool = False,
    positions: np.ndarray | None = None,
    dipoles: np.ndarray | None = None,
    ftol: float = 1e-12,
    max_iterations: int = 1000,
) -> NaiveStaticsResult:
    """The SLSQP baseline's equilibrium of ``chain`` in ``external`` from the straight chain
    (or from ``positions``/``dipoles``); see ``NaiveStatics``."""
    return NaiveStatics(chain, external, gravity, ftol, max_iterations).solve(positions, dipoles)
