"""Compile (or load from numba's on-disk cache) every kernel the stack runs, once, up front.

It lives here, not beside the kernels (``drake_models/kernels``), because it runs them through
``ReducedChain``: the reduced-coordinate kernels are warmed with exactly the argument types
statics passes them.
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models import kernels
from ballchain.drake_models.field_sources import UniformField
from ballchain.drake_models.kernels import actuation
from ballchain.drake_models.params import BallChain, Sleeve
from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.optimization.reduced_chain import ReducedChain
from ballchain.optimization.rod_statics import RodStatics
from ballchain.optimization.statics import ChainStatics


def warm_up() -> None:
    """Compile (or load from the cache) every kernel the stack runs, on a 4-ball chain."""
    chain = BallChain(n_balls=4, sleeve=Sleeve())
    d = chain.ball_diameter
    p = d * np.array([[0.0, 0, 0], [1, 0, 0], [1.8, 0.6, 0], [2.2, 1.5, 0.1]])
    m = np.tile([1.0, 0.0, 0.0], (4, 1))
    kernels.chain_energy(chain, p, m, UniformField([0.0, 0.02, 0.0]), gravity=True)
    kernels.chain_wrenches(chain, p, m, UniformField([0.0, 0.02, 0.0]))
    kernels.pair_hessian(p, m, chain.dipole_moment)
    kernels.dipole_field_and_gradient(p, np.array([[0.0, 0.2, 0.0]]), np.array([[0.0, 1.0, 0.0]]), np.zeros(1))
    model = ReducedChain(chain, UniformField([0.0, 0.02, 0.0]), gravity=True)
    model.chart_from_configuration(p, m)
    q = np.zeros(model.nq)
    ev = model.evaluate(q, 2)
    ev.jacobian[np.arange(len(ev.gaps))]
    model.constraint_hessian(q, np.array([0]), np.array([1.0]))
    model.tip_hessian(q, np.ones(3))
    ChainStatics(chain, gravity=True).solve(UniformField([0.0, 0.02, 0.0]))  # the compiled Newton solve
    actuation.warm_up()  # the actuation units' update
    rod = RodStatics(SteerableCatheter(), np.zeros(3), np.array([0.0, 0.0, 1.0]), None)
    rod.pose(np.zeros(3 * (rod.n_joints - rod.first_free(0.01))), 0.01, 0.0)  # the catheter rod's pose
