"""The chain's physics as compiled kernels (numba): the one implementation the stack runs.

One law per file, each the compiled form of a numpy reference that the tests hold it to
(``tests/test_chain_kernels.py``, ``tests/test_kernels_per_law.py``: 1e-12 of each array's
largest entry):

* ``pair``: the balls' mutual dipole energy, forces, torques and second derivatives
  (``dipole.py``);
* ``external``: point dipoles' field and gradient, and the balls' energy ``-m . B`` in an
  external field (``dipole.py``, ``chain_energy.field_energy``);
* ``sleeve``: the sleeve's bending ``(E I / d) theta tan(theta / 2)`` per bend
  (``chain_energy.sleeve_bending``);
* ``gravity``: gravity along -z (``chain_energy.field_energy``);
* ``wrenches``: those parts summed in Cartesian coordinates, and the balls' forces and torques
  (``chain_energy.chain_energy``; the wrench system runs this);
* ``charts``, ``constraints``, ``reduced``: the reduced coordinates (unit links and free dipoles
  in charts), the rigidity constraints and the energy with its exact gradient and Hessian in
  those coordinates (``optimization/reduced_chain.py``'s ``backend="numpy"``; statics runs this).

Field sources stay Python objects (``field_sources.FieldSource``): the caller evaluates the
external flux density ``B`` (n, 3) [T], its gradient ``G[k, a, b] = dB_a / dp_b`` (n, 3, 3)
[T/m] and, for Hessians, ``dG[k, a, b, c] = d2 B_a / dp_b dp_c`` (n, 3, 3, 3) at the ball
centres (``external_arrays``) and passes the arrays in; the kernels do the
energy/force/torque/Hessian arithmetic. Memory is O(n^2) for every entry point.

Kernels are compiled on first use and cached on disk (in ``__pycache__`` next to their files, or
in ``NUMBA_CACHE_DIR``), stamped with the whole package's sources (``_common.kernel``): a
machine pays the compilation once (``ballchain bench statics --compile-cost`` reports the cost),
and editing any kernel file recompiles them all.
"""

from ballchain.drake_models.kernels._common import (
    COINCIDENT,
    FOLDED,
    EnergyTerms,
    OK,
    TERM_BALLS,
    TERM_EXTERNAL,
    TERM_GRAVITY,
    TERM_SLEEVE,
    check_status,
)
from ballchain.drake_models.kernels.charts import (
    chain_configuration,
    chart_frames,
    chart_vectors,
    configuration_vectors,
)
from ballchain.drake_models.kernels.constraints import (
    constraint_rows,
    links_hessian,
    pair_index,
    pair_of_row,
    rigidity_gaps,
    rigidity_hessian,
)
from ballchain.drake_models.kernels.external import (
    add_external,
    dipole_field_and_gradient,
    external_arrays,
    external_hessian_blocks,
)
from ballchain.drake_models.kernels.gravity import add_gravity
from ballchain.drake_models.kernels.pair import pair_energy_gradient, pair_hessian
from ballchain.drake_models.kernels.reduced import reduced_energy, reduced_params
from ballchain.drake_models.kernels.sleeve import add_sleeve, sleeve_energy
from ballchain.drake_models.kernels.wrenches import (
    cartesian_energy,
    cartesian_wrenches,
    chain_energy,
    chain_wrenches,
)

__all__ = [
    "COINCIDENT", "EnergyTerms", "FOLDED", "OK", "TERM_BALLS", "TERM_EXTERNAL", "TERM_GRAVITY", "TERM_SLEEVE",
    "add_external", "add_gravity", "add_sleeve", "cartesian_energy", "cartesian_wrenches",
    "chain_configuration", "chain_energy", "chain_wrenches", "chart_frames", "chart_vectors",
    "check_status", "configuration_vectors", "constraint_rows", "dipole_field_and_gradient",
    "external_arrays", "external_hessian_blocks", "links_hessian", "pair_energy_gradient",
    "pair_hessian", "pair_index", "pair_of_row", "reduced_energy", "reduced_params",
    "rigidity_gaps", "rigidity_hessian", "sleeve_energy",
]
