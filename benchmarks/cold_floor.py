"""The cold solve's floor: what a 16-ball cold solve costs against SLSQP's, split into the compiled
kernel and the Python around it, right after another solver and back to back, per step limit.

``ballchain bench statics`` times the compiled cold solve (the canonical problem, 23 mT at 90
deg, from the straight chain) among the other solvers, so its caches are cold. This script splits
that time: the whole call and its kernel (``compiled_model.newton``) alone, each right after the
Python solver's solve of the same problem (cold, as in the bench) and repeated back to back
(warm caches), for ``max_step`` values (0.5 rad is the solver's default; another value changes
the iterates and, in some problems, which minimum a cold solve reaches: docs/performance.md
sections 21 and 22). Each figure is printed with its ratio to SLSQP's cold solve in the same run.
CPU time (``time.process_time``), BLAS limited to one thread as in ``bench statics``.

    python benchmarks/cold_floor.py
    python benchmarks/cold_floor.py --repeats 25 --max-steps 0.5,1.0 --json floor.json
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np


def run(repeats: int = 15, max_steps=(0.5, 0.75, 1.0), baseline_repeats: int = 5) -> dict:
    """The table of the module's docstring: SLSQP's cold solve [ms] and, per step limit, the
    iterations and the median cold and back-to-back times [ms] of the call and of its kernel."""
    from ballchain.drake_models.field_sources import UniformField
    from ballchain.drake_models.params import BallChain
    from ballchain.experiments.statics_bench import blas_threads
    from ballchain.optimization import compiled_model
    from ballchain.optimization.naive_statics import NaiveStatics
    from ballchain.optimization.statics import ChainStatics

    chain = BallChain(n_balls=16)
    field = UniformField.in_plane(23e-3, math.radians(90))
    clock = time.process_time
    kernel = compiled_model.newton
    kernel_times: list[float] = []

    def timed_kernel(*args):
        t0 = clock()
        try:
            return kernel(*args)
        finally:
            kernel_times.append(clock() - t0)

    out = {"clock": "cpu", "repeats": repeats, "max_steps": {}}
    with blas_threads(1):
        NaiveStatics(chain, field).solve()  # imports and first calls, untimed
        baseline = []
        for _ in range(baseline_repeats):
            t0 = clock()
            NaiveStatics(chain, field).solve()
            baseline.append(clock() - t0)
        out["slsqp_cold_ms"] = slsqp = 1e3 * float(np.median(baseline))
        compiled_model.newton = timed_kernel
        try:
            for max_step in max_steps:
                statics = ChainStatics(chain, method="newton")
                statics.max_step = float(max_step)
                first = statics.solve(field)
                times = {"cold": [], "cold_kernel": [], "back_to_back": [], "back_to_back_kernel": []}
                for _ in range(repeats):
                    NaiveStatics(chain, field).solve()
                    t0 = clock()
                    statics.solve(field)
                    times["cold"].append(clock() - t0)
                    times["cold_kernel"].append(kernel_times[-1])
                    for _ in range(3):
                        t0 = clock()
                        statics.solve(field)
                        times["back_to_back"].append(clock() - t0)
                        times["back_to_back_kernel"].append(kernel_times[-1])
                row = {k: 1e3 * float(np.median(v)) for k, v in times.items()}
                row["iterations"] = int(first.iterations)
                row["tip_m"] = [float(x) for x in first.positions[-1]]
                row["speedup"] = {k: slsqp / row[k] for k in times}
                out["max_steps"][f"{max_step:g}"] = row
        finally:
            compiled_model.newton = kernel
    out["ms_for_700x"] = slsqp / 700.0
    return out


def _max_steps(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--max-steps must be numbers separated by commas, got {text!r}") from None
    if not values or not all(math.isfinite(v) and v > 0.0 for v in values):
        raise argparse.ArgumentTypeError(f"--max-steps must be positive finite step limits [rad], got {text!r}")
    return values


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=15, help="cold solves per step limit (default 15)")
    parser.add_argument("--max-steps", type=_max_steps, default=(0.5, 0.75, 1.0),
                        help="step limits [rad], comma-separated (default 0.5,0.75,1.0; 0.5 is the solver's)")
    parser.add_argument("--json", default=None, help="write the results to this file")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    if args.json:  # before the runs: a path that cannot be written must not cost them
        from ballchain.infrastructure.errors import UserInputError
        from ballchain.infrastructure.safe_files import check_output_file

        try:
            check_output_file(args.json, "--json")
        except UserInputError as err:
            parser.error(str(err))
    out = run(repeats=args.repeats, max_steps=args.max_steps)
    slsqp = out["slsqp_cold_ms"]
    print(f"SLSQP cold {slsqp:.1f} ms (CPU); 700x needs {out['ms_for_700x']:.3f} ms")
    print("max_step  its   cold: call (kernel + Python)     kernel alone    back to back (kernel)")
    for name, r in out["max_steps"].items():
        s = r["speedup"]
        print(f"{name:>8} {r['iterations']:4d}   {r['cold']:.3f} ({r['cold_kernel']:.3f} + {r['cold'] - r['cold_kernel']:.3f}) "
              f"{s['cold']:5.0f}x   {r['cold_kernel']:.3f} {s['cold_kernel']:5.0f}x   "
              f"{r['back_to_back']:.3f} ({r['back_to_back_kernel']:.3f}) {s['back_to_back']:5.0f}x")
    if args.json:
        from ballchain.infrastructure.safe_files import write_json

        write_json(args.json, out)


if __name__ == "__main__":
    main()
