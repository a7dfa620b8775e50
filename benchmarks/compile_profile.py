"""Per-kernel compilation cost of the compiled stack's first run, with an empty numba cache.

Runs a workload (``warm_up``: every kernel the stack runs, the compiled Newton solve among them;
``simulate``: what a first ``ballchain simulate`` compiles, a short run of ``heart_wall_contact``
on the plant and on the quasi-static engine; ``both``) in a fresh
process whose ``NUMBA_CACHE_DIR`` is a new empty folder, and records numba's compile events
(``numba.core.event``, kind ``numba:compile``): one per specialisation compiled. A kernel's
compilation includes the compilation of the kernels it calls for the first time (numba types
and compiles a callee inside its caller's compile), so each row gives its inclusive CPU time and
its exclusive time (less the nested compile events): the exclusive time is what the kernel's own
typing, lowering and LLVM optimisation cost, the callees' code linked into it included.

Prints a table (exclusive CPU seconds, largest first) or JSON with ``--json``. A benchmark, not a
test: times are the process's CPU time (``time.process_time``) and depend on the machine's load.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

_CHILD = r"""
import json, sys, time
from numba.core import event

records, stack = [], []

class Listener(event.Listener):
    def on_start(self, ev):
        stack.append([time.process_time(), 0.0])

    def on_end(self, ev):
        t0, nested = stack.pop()
        total = time.process_time() - t0
        if stack:
            stack[-1][1] += total
        disp = ev.data["dispatcher"]
        records.append({"kernel": f"{disp.py_func.__module__.rsplit('.', 1)[-1]}.{disp.py_func.__qualname__}",
                        "signature": str(ev.data["args"]), "inclusive_s": total, "exclusive_s": total - nested})

event.register("numba:compile", Listener())
c0 = time.process_time()
workload = sys.argv[1]
if workload in ("warm_up", "both"):
    from ballchain.optimization.warm_up import warm_up
    warm_up()
if workload in ("simulate", "both"):
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import run_simulation
    run_simulation(scenario=load_scenario("heart_wall_contact", "{duration: 0.02}"))
    run_simulation(scenario=load_scenario("heart_wall_contact", "{engine: statics, duration: 0.05}"))
print(json.dumps({"total_cpu_s": time.process_time() - c0, "records": records}))
"""


def profile(workload: str, cache_dir: str | None = None) -> dict:
    """The compile events of ``workload`` in a fresh process (an empty cache unless ``cache_dir``)."""
    with tempfile.TemporaryDirectory(prefix="ballchain-numba-cache-") as empty:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache_dir or empty}
        proc = subprocess.run([sys.executable, "-c", _CHILD, workload], env=env, capture_output=True, text=True,
                              check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def table(result: dict) -> str:
    rows = sorted(result["records"], key=lambda r: -r["exclusive_s"])
    lines = [f"{'kernel':<46s} {'excl. CPU s':>11s} {'incl. CPU s':>11s}  signature"]
    for r in rows:
        sig = r["signature"] if len(r["signature"]) < 70 else r["signature"][:67] + "..."
        lines.append(f"{r['kernel']:<46s} {r['exclusive_s']:11.2f} {r['inclusive_s']:11.2f}  {sig}")
    compiled = sum(r["exclusive_s"] for r in rows)
    lines.append(f"{len(rows)} specialisations compiled, {compiled:.1f} CPU-s in compile events; "
                 f"the whole workload {result['total_cpu_s']:.1f} CPU-s")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workload", choices=("warm_up", "simulate", "both"), default="warm_up")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    result = profile(args.workload)
    print(json.dumps(result, indent=1) if args.json else table(result))


if __name__ == "__main__":
    main()
