"""The compiled statics' model evaluation and solve, against an older commit in the same run.

Times ``compiled_newton.evaluate(q, order, chart, model)`` (orders 0, 1, 2) at the warm start of
free chains of 8/16/32/64 balls (23 mT at 90 deg, warm start from 87.5 deg) and of the 16-ball
chain pressed into the atrium (``statics_bench.contact_solves``' path, the solve in contact with
the most rows near contact), and the whole compiled Newton call (``compiled_newton.newton``) of
those solves and of the whole contact path; each against the same kernels of the commit ``--base``
(default: the commit the evaluation work started from), loaded from git into a scratch folder
(``/tmp/eval_profile_<commit>``: the kernel files and ``compiled_newton.py``, their imports of
each other redirected there; numba caches them there) and called with the same arguments,
interleaved. CPU time (``time.process_time``), medians of ``--repeats`` batches; ``evaluate`` is
called from a compiled loop (as the solve calls it: no dispatch from Python counted).
"""

from __future__ import annotations

import argparse
import importlib
import math
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BASE = "0740d27"
_KERNELS = ("charts", "constraints", "dense_qp", "external", "gravity", "heart_rows", "pair", "reduced", "sdf",
            "sleeve")


def load_base(commit: str):
    """The module ``compiled_newton`` of ``commit`` with that commit's kernels (``_common`` is shared)."""
    folder = Path(f"/tmp/eval_profile_{commit}")
    folder.mkdir(exist_ok=True)
    prefix = f"_evalbase_{commit}_"
    sources = {name: f"drake_models/kernels/{name}.py" for name in _KERNELS}
    sources["compiled_newton"] = "optimization/compiled_newton.py"
    for name, path in sources.items():
        text = subprocess.run(["git", "show", f"{commit}:{path}"], cwd=ROOT, check=True, capture_output=True,
                              text=True).stdout
        text = re.sub(r"from ballchain\.drake_models\.kernels\.(\w+) import",
                      lambda m: f"from {prefix}{m.group(1)} import" if m.group(1) in _KERNELS else m.group(0), text)
        target = folder / f"{prefix}{name}.py"
        if not target.exists() or target.read_text() != text:
            target.write_text(text)
    if str(folder) not in sys.path:
        sys.path.insert(0, str(folder))
    return importlib.import_module(f"{prefix}compiled_newton")


def _captured_calls(solve):
    """The arguments of every ``compiled_model.newton`` call ``solve()`` makes (chart copied)."""
    from ballchain.optimization import compiled_model as cm

    calls = []
    original = cm.newton

    def recording(chart, tup, rows0, weights0):
        calls.append((tuple(a.copy() for a in chart), tup, rows0.copy(), weights0.copy()))
        return original(chart, tup, rows0, weights0)

    cm.newton = recording
    try:
        solve()
    finally:
        cm.newton = original
    return calls


def free_case(n_balls: int):
    """The warm compiled solve of ``bench statics``: its newton call's arguments."""
    from ballchain.drake_models.field_sources import UniformField
    from ballchain.drake_models.params import BallChain
    from ballchain.optimization.statics import ChainStatics

    solver = ChainStatics(BallChain(n_balls=n_balls))
    B = 23e-3
    warm = solver.solve(UniformField.in_plane(B, math.radians(87.5)))
    field = UniformField.in_plane(B, math.radians(90.0))
    return _captured_calls(lambda: solver.solve(field, warm))[0]


def contact_cases():
    """The newton calls of one warm pass along the contact path of ``bench statics``."""
    from ballchain.experiments import statics_bench as sb
    from ballchain.optimization import compiled_model as cm

    recorded = []
    original_newton = cm.newton

    def recording(chart, tup, rows0, weights0):
        recorded.append((tuple(a.copy() for a in chart), tup, rows0.copy(), weights0.copy()))
        return original_newton(chart, tup, rows0, weights0)

    cm.newton = recording
    try:
        sb.contact_solves(1, time.process_time)
    finally:
        cm.newton = original_newton
    return recorded[:len(recorded) // 2]  # the untimed compiled pass (then the timed one)


def looped(evaluate):
    """A compiled loop of ``count`` calls of ``evaluate`` (no dispatch from Python per call)."""
    from numba import njit

    @njit
    def loop(q, order, chart, model, count):
        total = 0.0
        for _ in range(count):
            total += evaluate(q, order, chart, model)[1]
        return total

    return loop


def _time(fn, inner: int) -> float:
    t0 = time.process_time()
    for _ in range(inner):
        fn()
    return (time.process_time() - t0) / inner


def compare(label: str, new, old, repeats: int, inner: int, per: int = 1) -> tuple[float, float]:
    """Median per-call CPU time of new and old (interleaved batches of ``inner`` calls, each
    call ``per`` of the timed thing) [us]; prints a line."""
    new(), old()
    tn, to = [], []
    for _ in range(repeats):
        tn.append(_time(new, inner) / per)
        to.append(_time(old, inner) / per)
    a, b = 1e6 * float(np.median(tn)), 1e6 * float(np.median(to))
    print(f"  {label:<42s} new {a:9.1f} us   base {b:9.1f} us   {b / a:5.2f}x", flush=True)
    return a, b


def check_same(cn, base, call) -> float:
    """The largest difference between the new and base evaluations of order 2 at q = 0."""
    chart, tup = call[0], call[1]
    K = chart[0].shape[0]
    q = np.zeros(2 * K)
    a = cn.evaluate(q, 2, tuple(c.copy() for c in chart), tup)
    b = base.evaluate(q, 2, tuple(c.copy() for c in chart), tup)
    worst = 0.0
    for i in (1, 4, 5):
        x, y = np.asarray(a[i]), np.asarray(b[i])
        scale = max(1.0, float(np.abs(y).max()))
        worst = max(worst, float(np.abs(x - y).max()) / scale)
    return worst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--base", default=BASE, help=f"the commit to compare against (default {BASE})")
    parser.add_argument("--sizes", default="8,16,32,64", help="free chains' ball counts")
    parser.add_argument("--repeats", type=int, default=21, help="timed batches per case (medians)")
    parser.add_argument("--no-contact", action="store_true", help="leave out the atrium cases")
    args = parser.parse_args()
    from threadpoolctl import threadpool_limits

    from ballchain.optimization import compiled_newton as cn

    base = load_base(args.base)
    loop_new, loop_base = looped(cn.evaluate), looped(base.evaluate)
    with threadpool_limits(limits=1, user_api="blas"):
        for n in (int(s) for s in args.sizes.split(",")):
            call = free_case(n)
            chart, tup, rows0, weights0 = call
            K = chart[0].shape[0]
            q = np.zeros(2 * K)
            inner = max(4, 8000 // (n * n))
            print(f"free chain of {n} balls (uniform 23 mT), evaluate at the warm start "
                  f"(relative difference new - base {check_same(cn, base, call):.1e}):", flush=True)
            for order in (0, 1, 2):
                compare(f"evaluate order {order}", lambda: loop_new(q, order, chart, tup, inner),
                        lambda: loop_base(q, order, chart, tup, inner), args.repeats, 1, inner)
            compare("newton (warm solve)", lambda: cn.newton(tuple(c.copy() for c in chart), tup, rows0, weights0),
                    lambda: base.newton(tuple(c.copy() for c in chart), tup, rows0, weights0), args.repeats,
                    max(1, inner // 8))
        if args.no_contact:
            return
        calls = contact_cases()
        busiest = max(calls, key=lambda c: c[2].size)
        chart, tup = busiest[0], busiest[1]
        q = np.zeros(2 * chart[0].shape[0])
        print(f"16 balls in the atrium ({len(calls)} solves of the contact path; evaluate at the solve with the "
              f"most warm rows, {busiest[2].size}, relative difference {check_same(cn, base, busiest):.1e}):",
              flush=True)
        for order in (0, 1, 2):
            compare(f"evaluate order {order}", lambda: loop_new(q, order, chart, tup, 50),
                    lambda: loop_base(q, order, chart, tup, 50), args.repeats, 1, 50)

        def path(module):
            for ch, tp, r0, w0 in calls:
                module.newton(tuple(c.copy() for c in ch), tp, r0, w0)

        compare("newton, whole contact path (sum)", lambda: path(cn), lambda: path(base), max(5, args.repeats // 3), 1)
        per_new, per_old = [], []
        for _ in range(max(5, args.repeats // 3)):
            for ch, tp, r0, w0 in calls:
                for module, out in ((cn, per_new), (base, per_old)):
                    t0 = time.process_time()
                    module.newton(tuple(c.copy() for c in ch), tp, r0, w0)
                    out.append(1e3 * (time.process_time() - t0))
        for name, t in (("new", per_new), ("base", per_old)):
            print(f"  per solve ({name}): median {np.median(t):.3f} ms, p99 {np.percentile(t, 99):.3f} ms, "
                  f"max {np.max(t):.3f} ms (CPU, newton call only)")


if __name__ == "__main__":
    main()
