"""The statics' quasi-Newton reference (``ChainStatics(method="snopt")``): the whole problem as one
MathematicalProgram (energy cost with analytic gradient, rigidity as a vector constraint)
solved by SNOPT.
"""

from __future__ import annotations

import numpy as np
from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue, InitializeAutoDiff
from pydrake.solvers import MathematicalProgram

from ballchain.optimization.reduced_chain import ReducedChain

_SNOPT_MESSAGES = {
    1: "optimality conditions satisfied",
    3: "requested accuracy could not be achieved",
    13: "nonlinear infeasibilities minimized",
    31: "iteration limit reached",
    32: "major iteration limit reached",
    41: "current point cannot be improved",
    42: "singular basis",
}


def snopt_solve(snopt, options, model: ReducedChain):
    """The SNOPT solve of ``model`` from q = 0 with the solver ``snopt`` and its ``options``;
    returns (q, converged, reason, energy evaluations, pair multipliers)."""
    prog = MathematicalProgram()
    q = prog.NewContinuousVariables(model.nq, "q")
    cache: dict = {}
    counter = [0]

    def evaluate(x):
        value = ExtractValue(x).reshape(-1)
        key = value.tobytes()
        if cache.get("key") != key:
            cache["key"], cache["ev"] = key, model.evaluate(value, 1)
            counter[0] += 1
        return value, cache["ev"]

    def cost(x):
        _, ev = evaluate(x)
        if x.dtype == float:
            return ev.energy
        return AutoDiffXd(ev.energy, ev.gradient @ ExtractGradient(x))

    def rigidity(x):
        _, ev = evaluate(x)
        if x.dtype == float:
            return ev.gaps
        return InitializeAutoDiff(ev.gaps, ev.jacobian @ ExtractGradient(x)).reshape(-1)

    prog.AddCost(cost, q, description="energy")
    n_pairs = len(model.pair_i)
    binding = None
    if n_pairs:
        binding = prog.AddConstraint(rigidity, np.zeros(n_pairs), np.full(n_pairs, np.inf), q,
                                     description="rigidity")
    prog.AddBoundingBoxConstraint(-1.5, 1.5, q[model.n_vectors :])
    result = snopt.Solve(prog, np.zeros(model.nq), options)
    info = result.get_solver_details().info
    lam = {}
    if binding is not None:
        duals = result.GetDualSolution(binding)
        lam = {k: float(v) for k, v in enumerate(duals) if v > 0}
    return (result.GetSolution(q), info == 1, _SNOPT_MESSAGES.get(info, f"SNOPT info {info}"),
            counter[0], lam)
