"""Drake's conventions for randomness, for the station's stochastic Python systems.

In Drake a run's randomness lives in its context: ``system.SetRandomContext(context,
generator)`` (a ``pydrake.common.RandomGenerator(seed)``) hands one generator to every leaf
system's ``SetRandomState`` and ``SetRandomParameters``, and the default context is one fixed
draw, so a run is a function of its context alone. pydrake does not let a Python LeafSystem
override those two (they are C++ virtuals without a Python trampoline: ``SetRandomContext``
leaves a Python system's context at its defaults), so the station's stochastic Python systems
(the Hall sensors' noise, the simulated operator's tremor) follow the convention themselves:

* each is a ``SeededLeafSystem``: its randomness is one seed, a numeric parameter whose default
  is the seed it was built with (so the default context is the run it always was), and its
  ``SetRandomParameters(context, parameters, generator)`` (Drake's signature) draws a fresh seed
  from the generator;
* ``set_random_context(system, context, generator)`` is ``system.SetRandomContext(context,
  generator)`` followed by each seeded leaf's ``SetRandomParameters`` with the same generator, in
  the diagram's order: the same generator seed gives the same run, another seed another run.

A scenario's ``random_seed`` (``chain_scenario.ChainScenario``) is that generator's seed in
``chain_simulation.run_station``.
"""

import numbers

from pydrake.common import RandomGenerator
from pydrake.systems.framework import BasicVector, Diagram, LeafSystem

from ballchain.drake_models.errors import UserInputError, short_repr

MAX_SEED = 2**32 - 1  # RandomGenerator's seeds (and the seeds it draws) are 32-bit


def check_random_seed(seed, what: str = "random_seed") -> int:
    """A seed of a RandomGenerator: an integer in 0..MAX_SEED (not a bool).

    Raises:
        UserInputError: naming ``what``, the value and the range.
    """
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or not 0 <= seed <= MAX_SEED:
        raise UserInputError(f"{what} must be an integer in 0..{MAX_SEED}, got {short_repr(seed)}")
    return int(seed)


class SeededLeafSystem(LeafSystem):
    """A LeafSystem whose randomness is one seed, kept as a numeric parameter (module docstring).

    A subclass calls ``DeclareSeedParameter(seed)`` once and draws its random numbers from
    ``seed(context)`` only (e.g. ``numpy.random.default_rng((seed, sample_index))``), so that its
    outputs are a function of the context.
    """

    def DeclareSeedParameter(self, seed: int) -> None:
        """Declare the seed parameter (1), its default ``seed`` (an integer in 0..MAX_SEED)."""
        seed = check_random_seed(seed, f"{self.get_name() or type(self).__name__} seed")
        self._seed_index = self.DeclareNumericParameter(BasicVector([float(seed)]))

    def seed(self, context) -> int:
        """The seed in this (the system's own) context."""
        return int(context.get_numeric_parameter(self._seed_index).GetAtIndex(0))

    def set_seed(self, context, seed: int) -> None:
        """Set the seed in this (the system's own) context."""
        seed = check_random_seed(seed, f"{self.get_name()} seed")
        context.get_mutable_numeric_parameter(self._seed_index).SetAtIndex(0, float(seed))

    def SetRandomParameters(self, context, parameters, generator: RandomGenerator) -> None:
        """Drake's SetRandomParameters: a fresh seed, the generator's next number."""
        parameters.get_mutable_numeric_parameter(self._seed_index).SetAtIndex(0, float(generator()))


def seeded_systems(system) -> list[SeededLeafSystem]:
    """The SeededLeafSystems of a diagram (depth first, in the order they were added)."""
    if isinstance(system, SeededLeafSystem):
        return [system]
    if isinstance(system, Diagram):
        return [leaf for sub in system.GetSystems() for leaf in seeded_systems(sub)]
    return []


def set_random_context(system, context, generator: RandomGenerator) -> None:
    """Drake's ``system.SetRandomContext(context, generator)``, then every seeded Python leaf
    system's ``SetRandomParameters`` with the same generator.

    Args:
        system: a system (a diagram: the root of ``context``).
        context: its root context (state and parameters are overwritten, as by SetRandomContext).
        generator: e.g. ``RandomGenerator(seed)``.
    """
    system.SetRandomContext(context, generator)
    for leaf in seeded_systems(system):
        leaf_context = leaf.GetMyMutableContextFromRoot(context)
        leaf.SetRandomParameters(leaf_context, leaf_context.get_mutable_parameters(), generator)
