"""How this machine's BLAS sums a short dot product, so that a kernel can sum it the same way.

The Python systems that the actuation kernels mirror bit for bit (``rotating_magnet_unit._norm``,
the Hall estimator, the reconfiguration controller) take 1-D ``@``/``.dot``/``norm`` through
numpy's BLAS ``ddot``. For the few terms they sum, OpenBLAS goes left to right, but its kernel
depends on the CPU it detects: on a Haswell-class kernel each step is a product then a sum
(``s + a_i b_i``, two roundings); on a SkylakeX-class kernel it is a fused multiply-add
(``fma(a_i, b_i, s)``, one rounding). The two differ in the last bit for about a third of random
vectors. ``DDOT_FMA`` says which this process's numpy uses, probed once at import on vectors
where the two orders give different floats; ``fma`` is the fused multiply-add a kernel calls
(LLVM's ``llvm.fma.f64``; exact in Python when numba's JIT is off).

Kernel caches are stamped with ``ORDER`` (``_common``): a process whose BLAS sums the other way
(``OPENBLAS_CORETYPE``, another machine) never loads a kernel compiled for the first.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
from numba import config, types
from numba.extending import intrinsic


def _exact_fma(a: float, b: float, c: float) -> float:
    """``a * b + c`` rounded once (the reference the probe and the JIT-off kernels use)."""
    return float(Fraction(a) * Fraction(b) + Fraction(c))


def _probe() -> str:
    """"fma", "plain" or "other": which left-to-right sum numpy's ``ddot`` matches here."""
    rng = np.random.default_rng(20261207)
    fused = plain = True
    for _ in range(64):
        a, b = rng.normal(size=4), rng.normal(size=4)
        blas = float(a.dot(b))
        s_plain, s_fused = float(a[0] * b[0]), float(a[0] * b[0])
        for i in range(1, 4):
            s_plain = s_plain + float(a[i] * b[i])
            s_fused = _exact_fma(float(a[i]), float(b[i]), s_fused)
        plain &= blas == s_plain
        fused &= blas == s_fused
    return "fma" if fused and not plain else "plain" if plain and not fused else "other"


ORDER = _probe()
"""How numpy's ``ddot`` sums here: "fma", "plain", or "other" (neither: the kernels sum plainly and
their last bits may differ from the Python systems')."""

DDOT_FMA = ORDER == "fma"


if config.DISABLE_JIT:
    fma = _exact_fma
else:
    @intrinsic
    def fma(typingctx, a, b, c):
        """``a * b + c`` with one rounding (LLVM's ``llvm.fma.f64``), for float64 arguments."""
        signature = types.float64(types.float64, types.float64, types.float64)

        def codegen(context, builder, sig, args):
            return builder.fma(*args)

        return signature, codegen
