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

A sampled system draws sample k's numbers from ``numpy.random.default_rng((seed, k))``: a
function of the seed and the sample's index alone. ``SampleGenerators`` gives that very generator
for a fraction of its cost (a Hall sensor samples a hundred times a second), and its normal
draws (``normal``, ``standard_normal``) in one compiled call: numpy's PCG64 and ziggurat on the
same words, the same floats (``tests/test_per_update_python.py``).
"""

import numbers

import numpy as np
from numba.np.random import _constants as _zig
from pydrake.common import RandomGenerator
from pydrake.systems.framework import BasicVector, Diagram, LeafSystem

from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.drake_models.kernels._common import kernel

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


# numpy's SeedSequence (NEP 19 keeps its algorithm and PCG64's seeding stable across versions):
# the hash constants of its entropy pool (pool size 4, 32-bit words) and PCG64's 128-bit LCG
# multiplier. ``tests/test_randomness.py`` holds the generator to numpy's, stream and all.
_M32 = np.uint64(0xFFFFFFFF)
_INIT_A, _MULT_A = np.uint64(0x43B0D7E5), np.uint64(0x931E8875)
_INIT_B, _MULT_B = np.uint64(0x8B51F9DD), np.uint64(0x58F38DED)
_MIX_L, _MIX_R = np.uint64(0xCA01F9DD), np.uint64(0x4973F715)
_SHIFT = np.uint64(16)
_PCG_MULTIPLIER = (2549297995355413924 << 64) | 4865540595714422341
_M128 = (1 << 128) - 1


@kernel
def _seed_sequence_words(a, b):
    """``SeedSequence((a, b)).generate_state(4, numpy.uint64)`` for integers 0 <= a, b < 2**63:
    (4,) uint64. The entropy is each integer's 32-bit words, least significant first (one word
    for 0)."""
    entropy = np.zeros(4, np.uint64)
    n = 0
    for value in (np.uint64(a), np.uint64(b)):
        entropy[n] = value & _M32
        n += 1
        if value >> np.uint64(32):
            entropy[n] = value >> np.uint64(32)
            n += 1
    h = _INIT_A
    pool = np.zeros(4, np.uint64)
    for i in range(4):  # hashmix of each word (0 past the entropy) into the pool
        v = (entropy[i] if i < n else np.uint64(0)) ^ h
        h = (h * _MULT_A) & _M32
        v = (v * h) & _M32
        pool[i] = v ^ (v >> _SHIFT)
    for i_src in range(4):  # every word mixed into every other (the entropy fits the pool)
        for i_dst in range(4):
            if i_src != i_dst:
                v = pool[i_src] ^ h
                h = (h * _MULT_A) & _M32
                v = (v * h) & _M32
                v ^= v >> _SHIFT
                r = (_MIX_L * pool[i_dst] - _MIX_R * v) & _M32
                pool[i_dst] = r ^ (r >> _SHIFT)
    h = _INIT_B
    out = np.zeros(4, np.uint64)
    for i in range(8):  # generate_state: 8 32-bit words, read as 4 little-endian uint64
        v = pool[i % 4] ^ h
        h = (h * _MULT_B) & _M32
        v = (v * h) & _M32
        v ^= v >> _SHIFT
        out[i // 2] |= v << np.uint64(32 * (i % 2))
    return out


_ONE, _BITS_32, _BITS_63 = np.uint64(1), np.uint64(32), np.uint64(63)
_MULT_HI, _MULT_LO = np.uint64(_PCG_MULTIPLIER >> 64), np.uint64(_PCG_MULTIPLIER & 0xFFFFFFFFFFFFFFFF)
# numpy's ziggurat for the standard normal (``random_standard_normal`` of its distributions.c),
# its tables as numba's port of that code holds them (the same numbers as numpy's).
_KI, _WI, _FI = (np.ascontiguousarray(a) for a in (_zig.ki_double, _zig.wi_double, _zig.fi_double))
_ZIG_R, _ZIG_INV_R = float(_zig.ziggurat_nor_r), float(_zig.ziggurat_nor_inv_r)
_TO_DOUBLE = 1.0 / 9007199254740992.0  # numpy's next_double: the top 53 bits times 2**-53


@kernel
def _mul_64(a, b):
    """(high, low) uint64 words of the 128-bit product a b of two uint64 words."""
    a_lo, a_hi = a & _M32, a >> _BITS_32
    b_lo, b_hi = b & _M32, b >> _BITS_32
    lo_lo, hi_lo, lo_hi, hi_hi = a_lo * b_lo, a_hi * b_lo, a_lo * b_hi, a_hi * b_hi
    middle = (lo_lo >> _BITS_32) + (hi_lo & _M32) + lo_hi
    return hi_hi + (hi_lo >> _BITS_32) + (middle >> _BITS_32), (middle << _BITS_32) | (lo_lo & _M32)


@kernel
def _lcg_128(hi, lo, inc_hi, inc_lo):
    """(hi, lo) of PCG64's step ``state * multiplier + increment`` modulo 2**128."""
    p_hi, p_lo = _mul_64(lo, _MULT_LO)
    p_hi = p_hi + hi * _MULT_LO + lo * _MULT_HI  # modulo 2**64: the words above 128 bits drop
    lo_new = p_lo + inc_lo
    carry = _ONE if lo_new < p_lo else np.uint64(0)
    return p_hi + inc_hi + carry, lo_new


@kernel
def _pcg64_output(hi, lo):
    """PCG64's output of a state: XSL-RR (the two words xored, rotated right by the top 6 bits)."""
    x = hi ^ lo
    rot = hi >> np.uint64(58)
    return (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))


@kernel
def _standard_normals(seed, k, n, scale):
    """``numpy.random.default_rng((seed, k)).standard_normal(n)`` (n,) for integers
    0 <= seed, k < 2**63: PCG64 seeded as numpy seeds it from ``SeedSequence((seed, k))``, each
    number numpy's ziggurat on its 64-bit outputs (``SampleGenerators.standard_normal``); with a
    ``scale`` (not NaN), ``normal(scale=scale, size=n)``: numpy's ``0.0 + scale * z`` each."""
    w = _seed_sequence_words(seed, k)
    # PCG64's srandom: increment (w2 w3) << 1 | 1, the state (w0 w1) added after one step from 0.
    inc_hi, inc_lo = (w[2] << _ONE) | (w[3] >> _BITS_63), (w[3] << _ONE) | _ONE
    lo = inc_lo + w[1]
    hi = inc_hi + w[0] + (_ONE if lo < inc_lo else np.uint64(0))
    hi, lo = _lcg_128(hi, lo, inc_hi, inc_lo)
    out = np.empty(n)
    for i in range(n):
        while True:  # numpy's random_standard_normal
            hi, lo = _lcg_128(hi, lo, inc_hi, inc_lo)
            r = _pcg64_output(hi, lo)
            idx = np.intp(r & np.uint64(0xFF))
            r >>= np.uint64(8)
            rabs = (r >> _ONE) & np.uint64(0x000FFFFFFFFFFFFF)
            x = float(rabs) * _WI[idx]
            if r & _ONE:
                x = -x
            if rabs < _KI[idx]:
                break
            if idx == 0:
                while True:
                    hi, lo = _lcg_128(hi, lo, inc_hi, inc_lo)
                    xx = -_ZIG_INV_R * np.log1p(-(float(_pcg64_output(hi, lo) >> np.uint64(11)) * _TO_DOUBLE))
                    hi, lo = _lcg_128(hi, lo, inc_hi, inc_lo)
                    yy = -np.log1p(-(float(_pcg64_output(hi, lo) >> np.uint64(11)) * _TO_DOUBLE))
                    if yy + yy > xx * xx:
                        x = -(_ZIG_R + xx) if (rabs >> np.uint64(8)) & _ONE else _ZIG_R + xx
                        break
                break
            hi, lo = _lcg_128(hi, lo, inc_hi, inc_lo)
            u = float(_pcg64_output(hi, lo) >> np.uint64(11)) * _TO_DOUBLE
            if (_FI[idx - 1] - _FI[idx]) * u + _FI[idx] < np.exp(-0.5 * x * x):
                break
        out[i] = x if np.isnan(scale) else 0.0 + scale * x
    return out


class SampleGenerators:
    """``numpy.random.default_rng((seed, k))``, the same generator (the same numbers from every
    method), built in a few microseconds instead of tens: one PCG64 of this object's, its state
    set to the one ``default_rng`` would start from. A sampled system keeps one and asks it for
    sample k's generator (valid until the next ``generator`` call of this object).
    """

    def __init__(self) -> None:
        self._bit_generator = np.random.PCG64(0)
        self._generator = np.random.Generator(self._bit_generator)

    def generator(self, seed: int, k: int) -> np.random.Generator:
        """Sample k's generator: ``default_rng((seed, k))``'s stream, for integers
        0 <= seed, k < 2**63 (other values: numpy's own ``default_rng``)."""
        if not (0 <= seed < 2**63 and 0 <= k < 2**63):
            return np.random.default_rng((seed, k))
        w = _seed_sequence_words(seed, k).tolist()
        # PCG64's seeding from those words (its srandom: two steps of the LCG).
        increment = ((((w[2] << 64) | w[3]) << 1) | 1) & _M128
        state = ((increment + ((w[0] << 64) | w[1])) * _PCG_MULTIPLIER + increment) & _M128
        self._bit_generator.state = {"bit_generator": "PCG64", "state": {"state": state, "inc": increment},
                                     "has_uint32": 0, "uinteger": 0}
        return self._generator

    def standard_normal(self, seed: int, k: int, n: int) -> np.ndarray:
        """Sample k's ``default_rng((seed, k)).standard_normal(n)`` (n,), the same floats, drawn by
        one compiled call (no generator's state set from Python: a few microseconds less a sample)."""
        if not (0 <= seed < 2**63 and 0 <= k < 2**63):
            return np.random.default_rng((seed, k)).standard_normal(n)
        return _standard_normals(seed, k, n, np.nan)

    def normal(self, seed: int, k: int, scale: float, n: int) -> np.ndarray:
        """Sample k's ``default_rng((seed, k)).normal(scale=scale, size=n)`` (n,) for a scale
        >= 0: numpy's ``loc + scale * z`` with loc 0, the same floats."""
        if not (0 <= seed < 2**63 and 0 <= k < 2**63 and scale >= 0):
            return np.random.default_rng((seed, k)).normal(scale=scale, size=n)
        return _standard_normals(seed, k, n, float(scale))
