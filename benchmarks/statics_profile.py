"""Per-piece profile of one warm equilibrium: where a ChainStatics solve spends its time.

The 16-ball chain at 23 mT and 90 deg, warm-started from its equilibrium at 87.5 deg (the
``ballchain bench statics`` warm case), solved many times by the Python Newton solver
(``ChainStatics(compiled=False)``) on the compiled kernels and on the numpy reference of the
physics, in one run with the cases interleaved, and by the compiled solve (one call per
equilibrium: its pieces are the call, the Python around it and single kernel calls for scale). The pieces are timed by wrapping the functions the solve calls (exclusive times:
a piece's time excludes the wrapped pieces it calls), per solve; "Newton loop, rest" is the
solve's wall time less the pieces. The wrappers add about a microsecond a call: the unwrapped
median of the same solves is printed beside them. Prints a table, or JSON with ``--json``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import time

import numpy as np


class _PieceTimer:
    """Exclusive time per named piece, through wrappers installed on functions."""

    def __init__(self, clock=time.perf_counter):
        self.clock = clock
        self.totals: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self._stack: list[float] = []  # time of wrapped children of each open piece

    def wrap(self, name, fn, name_of=None):
        def wrapper(*args, **kwargs):
            self._stack.append(0.0)
            t0 = self.clock()
            try:
                return fn(*args, **kwargs)
            finally:
                elapsed = self.clock() - t0
                children = self._stack.pop()
                if self._stack:
                    self._stack[-1] += elapsed
                key = name_of(args, kwargs) if name_of else name
                self.totals[key] = self.totals.get(key, 0.0) + elapsed - children
                self.calls[key] = self.calls.get(key, 0) + 1
        return wrapper


@contextlib.contextmanager
def _instrumented(timer: _PieceTimer):
    from ballchain.drake_models import kernels as ck
    from ballchain.optimization import reduced_chain as rc
    from ballchain.optimization import statics as st

    def order_of(prefix):
        return lambda args, kwargs: f"{prefix} order {args[2] if len(args) > 2 else kwargs['order']}"

    patches = [
        (rc.ReducedChain, "_evaluate_kernel", "evaluate", order_of("kernel evaluate: Python wrapper,")),
        (rc.ReducedChain, "_evaluate_numpy", "evaluate", order_of("numpy evaluate: chart/chain-rule bookkeeping,")),
        (rc, "field_energy", "numpy evaluate: pair + field energy/Hessian (field_energy)", None),
        (rc, "sleeve_bending", "numpy evaluate: sleeve (sleeve_bending)", None),
        (ck, "reduced_energy", "kernel evaluate: reduced_energy (energy, gradient, Hessian, chain rule)", None),
        (ck, "chart_vectors", "kernel evaluate: chart_vectors, chain_configuration, rigidity_gaps", None),
        (ck, "chain_configuration", "kernel evaluate: chart_vectors, chain_configuration, rigidity_gaps", None),
        (ck, "rigidity_gaps", "kernel evaluate: chart_vectors, chain_configuration, rigidity_gaps", None),
        (ck, "external_arrays", "kernel evaluate: field arrays (external_arrays)", None),
        (rc.ReducedChain, "constraint_hessian", "constraint and tip Hessians", None),
        (rc.ReducedChain, "tip_hessian", "constraint and tip Hessians", None),
        (rc.ReducedChain, "chart_from_configuration", "chart set-up (chart_from_configuration)", None),
        (rc.ReducedChain, "configuration", "configuration at the solution", None),
        (st, "_positive_definite", "positive-definite test (_positive_definite, less Cholesky)", None),
        (st, "_null_space", "null space (SVD)", None),
        (st.ChainStatics, "_qp_step", "QP step (MathematicalProgram + Clarabel)", None),
        (np.linalg, "cholesky", "Cholesky (np.linalg.cholesky)", None),
        (np.linalg, "solve", "linear solve (np.linalg.solve)", None),
        (np.linalg, "eigh", "eigendecomposition (np.linalg.eigh)", None),
    ]
    saved = []
    try:
        for owner, attr, name, name_of in patches:
            original = getattr(owner, attr)
            saved.append((owner, attr, original))
            setattr(owner, attr, timer.wrap(name, original, name_of))
        yield
    finally:
        for owner, attr, original in reversed(saved):
            setattr(owner, attr, original)


def run(*, n_balls: int = 16, solves: int = 200, field_mT: float = 23.0, angle_deg: float = 90.0,
        warm_offset_deg: float = 2.5, clock: str = "wall") -> dict:
    """Profile ``solves`` warm solves of the Python Newton solver per backend of the physics
    ("kernel", "numpy"), and of the compiled solve ("compiled", ``_compiled_pieces``).

    ``clock``: "wall" (``time.perf_counter``) or "cpu" (``time.process_time``: this process's
    CPU time, steadier on a machine shared with other jobs).

    Returns:
        ``{backend: {"median_ms" (unwrapped), "instrumented_ms" (mean, wrapped), "iterations",
        "pieces_ms": {piece: ms per solve}, "calls": {piece: calls per solve}}}``.
    """
    from threadpoolctl import threadpool_limits

    from ballchain.drake_models.field_sources import UniformField
    from ballchain.drake_models.params import BallChain
    from ballchain.optimization.reduced_chain import ReducedChain
    from ballchain.optimization.statics import ChainStatics

    now = time.process_time if clock == "cpu" else time.perf_counter
    chain = BallChain(n_balls=n_balls)
    B = field_mT * 1e-3
    external = UniformField.in_plane(B, math.radians(angle_deg))
    warm_field = UniformField.in_plane(B, math.radians(angle_deg - warm_offset_deg))
    solvers = {"kernel": ChainStatics(chain, compiled=False), "numpy": ChainStatics(chain, compiled=False)}
    solvers["numpy"]._model = ReducedChain(chain, None, False, backend="numpy")
    out = {}
    with threadpool_limits(limits=1, user_api="blas"):
        warm = solvers["kernel"].solve(warm_field)
        plain = {name: [] for name in solvers}
        for _ in range(solves):  # unwrapped, interleaved
            for name, solver in solvers.items():
                t0 = now()
                result = solver.solve(external, warm)
                plain[name].append(now() - t0)
        for name, solver in solvers.items():
            timer = _PieceTimer(now)
            with _instrumented(timer):
                t0 = now()
                for _ in range(solves):
                    result = solver.solve(external, warm)
                wrapped = (now() - t0) / solves
            pieces = {k: 1e3 * v / solves for k, v in sorted(timer.totals.items(), key=lambda kv: -kv[1])}
            pieces["Newton loop, rest (ChainStatics.solve and _newton)"] = 1e3 * wrapped - sum(pieces.values())
            out[name] = {
                "median_ms": 1e3 * float(np.median(plain[name])),
                "instrumented_ms": 1e3 * wrapped,
                "iterations": result.iterations,
                "converged": bool(result.converged),
                "energy_J": result.energy,
                "pieces_ms": pieces,
                "calls": {k: v / solves for k, v in timer.calls.items()},
            }
        out["compiled"] = _compiled_pieces(ChainStatics(chain), external, warm, solves, now)
    return out


def _compiled_pieces(solver, external, warm, solves: int, now) -> dict:
    """The compiled solve (``optimization.compiled_newton``) in pieces: the whole warm solve, the
    one compiled call (the Newton loop and every evaluation), the Python around it (argument
    checks, the field check, the model's arrays, the result), and single calls of the physics
    kernel (``reduced_energy``, order 2 and 0) at the warm start for scale. Medians per solve."""
    from ballchain.drake_models import kernels as ck
    from ballchain.optimization import compiled_model as cm
    from ballchain.optimization import compiled_newton as cn

    result = solver.solve(external, warm)
    model = solver._model
    arrays = cm.model_tuple(solver, model, external, None)
    p0, m0 = np.ascontiguousarray(warm.positions), np.ascontiguousarray(warm.dipoles)
    rows, weights = np.zeros(0, np.int64), np.zeros(0)
    chart = ck.chart_frames(ck.configuration_vectors(p0, m0))
    q = np.zeros(model.nq)
    V = ck.chart_vectors(q, *chart)
    p, m_hat = ck.chain_configuration(V[0], model.n_links, model.d)
    _, B, G, dG = ck.external_arrays(external, p, hessian=True)

    def median_ms(call) -> float:
        samples = []
        for _ in range(solves):
            t0 = now()
            call()
            samples.append(now() - t0)
        return 1e3 * float(np.median(samples))

    whole = median_ms(lambda: solver.solve(external, warm))
    kernel = median_ms(lambda: cn.newton(ck.chart_frames(ck.configuration_vectors(p0, m0)), arrays, rows, weights))
    pieces = {
        "compiled call (Newton loop, evaluations, QP, line search)": kernel,
        "model arrays (model_tuple)": median_ms(lambda: cm.model_tuple(solver, model, external, None)),
        "one energy/gradient/Hessian evaluation (reduced_energy, order 2), for scale": median_ms(
            lambda: ck.reduced_energy(V, p, m_hat, B, G, dG, model._params, True, 2)),
        "one energy evaluation (reduced_energy, order 0), for scale": median_ms(
            lambda: ck.reduced_energy(V, p, m_hat, B, G, dG, model._params, True, 0)),
    }
    pieces["Python around the call (checks, field check, result)"] = whole - kernel - pieces["model arrays (model_tuple)"]
    return {"median_ms": whole, "instrumented_ms": whole, "iterations": result.iterations,
            "converged": bool(result.converged), "energy_J": result.energy, "pieces_ms": pieces, "calls": {}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--balls", type=int, default=16, help="number of balls (default 16)")
    parser.add_argument("--solves", type=int, default=200, help="warm solves per backend (default 200)")
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                        help="wall time or this process's CPU time (steadier under load)")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args()
    out = run(n_balls=args.balls, solves=args.solves, clock=args.clock)
    if args.json:
        print(json.dumps(out, indent=1))
        return
    for name, r in out.items():
        print(f"{name}: median {r['median_ms']:.3f} ms ({args.clock}) per warm solve unwrapped, {r['instrumented_ms']:.3f} ms "
              f"instrumented, {r['iterations']} iterations")
        for piece, ms in r["pieces_ms"].items():
            calls = r["calls"].get(piece)
            print(f"  {ms:8.3f} ms  {'' if calls is None else f'{calls:5.1f} calls'}  {piece}")


if __name__ == "__main__":
    main()
