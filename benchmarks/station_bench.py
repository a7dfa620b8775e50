"""Real-time factor of the station per engine and mode, and the per-piece profile of one
equilibrium in contact.

For every named heart scenario (``heart_scenarios``: those of the scenarios file inside the
atrium; or ``--scenarios``) the same simulated stretch is run with the
plant (the scenario's mode: quasi-static at 1 ms or dynamics at 0.1 ms) and with the
quasi-static engine (``engine: statics``), in one process, alternating, each ``--repeats``
times after an untimed warm-up of each (imports, the SDF's cache, the plant's first build).
Printed: median RTF on wall time and on process CPU time (the machine is shared, and wall time
counts the waits), and the engine's speed-up over the plant in the same run; at the end a table
of every scenario's engine and plant RTF (CPU time).

The profile: one warm equilibrium of 16 balls pressed on the atrium's roof (heart_wall_contact at
30 mm inserted, the field turned by 1 deg about x), timed piece by piece: the evaluations (the
chain's energy, gradient and Hessian in ReducedChain, plus the wall and sheath rows and gravity),
the constraint Hessians, the QP steps, the positive-definite checks, the rest (line search,
convergence tests, chart). Those pieces are the Python reference solver's (``compiled=False``):
the compiled solve is one kernel call (``benchmarks/statics_profile.py`` times its parts), timed
on the same equilibria beside it (``compiled_equilibrium_ms``).

The teleoperation task (``--teleop``): the simulated operator doing Task II (the 18 right-ring
targets, world mapping, seed 0) on each engine in the same run: the whole task on the quasi-static
engine (its wall time printed), and the plant (4 ms quasi-static steps, ``teleop.FAST``) on the first ``--plant-targets``
targets (the plant's whole task takes minutes: ``--plant-targets 0`` runs it whole). RTF on the
wall and CPU time of the simulation loop; the engine's speed-up is the ratio of the RTFs.

``--engine-only``: the quasi-static engine's runs alone (each scenario's engine RTF with every
run's, and Task II on the engine), for the engine's goals (issue 48: RTF >= 20 on every named heart
scenario, Task II <= 2 s of wall time). Everything runs with BLAS on one thread, as the command line
runs its commands. The JSON records the load average before and after.

    python benchmarks/station_bench.py --repeats 3 --json out.json
    python benchmarks/station_bench.py --scenarios --teleop --plant-targets 2
    python benchmarks/station_bench.py --engine-only --repeats 3 --teleop --teleop-repeats 3 --no-profile
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import dataclass

import numpy as np



def heart_scenarios() -> list[str]:
    """The named scenarios inside the atrium (``heart: true``), in the scenarios file's order."""
    from ballchain.systems.chain_scenario import load_scenario, scenario_names

    return [name for name in scenario_names() if load_scenario(name).heart]


@dataclass
class _Run:
    """One timed run: real-time factors on wall and process CPU time, the mode, the engine's solves."""

    rtf_wall: float
    rtf_cpu: float
    sim_s: float
    mode: str
    median_solve_ms: float | None = None
    solves: int | None = None


def _run_once(name: str, engine: str, duration: float | None, max_duration: float = np.inf) -> _Run:
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation, run_station

    overrides = "{engine: statics, mode: quasi-static}" if engine == "statics" else "{}"
    sc = load_scenario(name, overrides)
    cd = MakeStation(sc)
    T = min(sc.duration, max_duration) if duration is None else duration
    # The one run loop with its watchdog (ChainMonitor); its wall and CPU times are those of
    # Initialize + AdvanceTo, the build not counted.
    run = run_station(cd, duration=T)
    if run.failure is not None:
        raise RuntimeError(f"{name} ({engine}): {run.failure}")
    out = _Run(rtf_wall=T / run.wall_time, rtf_cpu=T / run.cpu_time, sim_s=T, mode=sc.mode)
    stats = cd.chain.solver_stats()
    if stats is not None:
        out.median_solve_ms = stats.median_solve_ms
        out.solves = stats.solves
    return out


def run(*, scenarios=None, repeats: int = 3, duration: float | None = None,
        max_duration: float = np.inf, profile_repeats: int = 20, profile: bool = True,
        engine_only: bool = False) -> dict:
    """RTF per scenario and engine (medians; ``scenarios`` None: ``heart_scenarios()``) and the
    profile of one equilibrium in contact. ``engine_only``: the quasi-static engine's runs alone
    (no plant column)."""
    results = {}
    engines = ("statics",) if engine_only else ("plant", "statics")
    for name in heart_scenarios() if scenarios is None else scenarios:
        if not engine_only:
            _run_once(name, "plant", min(duration or 0.02, 0.02))  # warm-up (untimed)
        _run_once(name, "statics", duration, max_duration)
        samples = {engine: [] for engine in engines}
        for _ in range(repeats):
            for engine in engines:
                samples[engine].append(_run_once(name, engine, duration, max_duration))
        row = {}
        for engine, runs in samples.items():
            row[engine] = {
                "mode": runs[0].mode,
                "rtf_wall": round(float(np.median([r.rtf_wall for r in runs])), 3),
                "rtf_cpu": round(float(np.median([r.rtf_cpu for r in runs])), 3),
            }
            if engine == "statics":
                row[engine]["median_solve_ms"] = round(float(np.median([r.median_solve_ms for r in runs])), 2)
                row[engine]["solves"] = runs[0].solves
                row[engine]["rtf_cpu_runs"] = [round(r.rtf_cpu, 3) for r in runs]
        if not engine_only:
            row["speedup_wall"] = round(row["statics"]["rtf_wall"] / row["plant"]["rtf_wall"], 2)
            row["speedup_cpu"] = round(row["statics"]["rtf_cpu"] / row["plant"]["rtf_cpu"], 2)
        results[name] = row
        print(name, json.dumps(row), flush=True)
    print(rtf_table(results), flush=True)
    return {"scenarios": results, "profile": profile_equilibrium(profile_repeats) if profile else None}


def rtf_table(results: dict) -> str:
    """Markdown: every scenario's engine and plant RTF (CPU time), the engine's median solve and
    its speed-up over the plant (same run)."""
    if any("plant" not in row for row in results.values()):  # engine_only
        lines = ["| scenario | engine RTF (CPU) | runs | median solve [ms] |", "|---|---:|---|---:|"]
        for name, row in results.items():
            e = row["statics"]
            lines.append(f"| {name} | {e['rtf_cpu']:.2f} | {', '.join(f'{v:.1f}' for v in e['rtf_cpu_runs'])} | "
                         f"{e['median_solve_ms']:.2f} |")
        return "\n".join(lines)
    lines = ["| scenario | engine RTF (CPU) | median solve [ms] | plant mode | plant RTF (CPU) | engine / plant |",
             "|---|---:|---:|---|---:|---:|"]
    for name, row in results.items():
        e, p = row["statics"], row["plant"]
        lines.append(f"| {name} | {e['rtf_cpu']:.2f} | {e['median_solve_ms']:.2f} | {p['mode']} | {p['rtf_cpu']:.2f} | "
                     f"{row['speedup_cpu']:.1f}x |")
    return "\n".join(lines)


def profile_equilibrium(repeats: int = 20) -> dict:
    """Median time of each piece of one warm equilibrium in contact [ms]."""
    from ballchain.optimization import statics as st
    from ballchain.optimization.reduced_chain import ReducedChain
    from ballchain.optimization.wall_constraints import ConstrainedChain
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation

    sc = load_scenario("heart_wall_contact", "{engine: statics, insertion: {initial: 0.03, final: 0.03}}")
    cd = MakeStation(sc)
    compiled = cd.chain.engine_system
    # The pieces are the Python solver's functions (the compiled solve is one kernel call:
    # benchmarks/statics_profile.py times its parts); the compiled solve of the same equilibria
    # is timed beside it.
    engine = compiled.replica(compiled=False)
    s = 0.03
    p, m, result, k = engine.equilibrium(s, None)
    B = np.array(cd.field_source.B_W, float)
    pieces = {"evaluation": ConstrainedChain.evaluate, "chain_energy": ReducedChain.evaluate,
              "constraint_hessian": ConstrainedChain.constraint_hessian, "qp": st.dense_qp,
              "positive_definite": st._positive_definite}
    clock = {key: 0.0 for key in pieces}

    def timed(key, fn):
        def wrapper(*a, **kw):
            t = time.perf_counter()
            try:
                return fn(*a, **kw)
            finally:
                clock[key] += time.perf_counter() - t
        return wrapper

    originals = {"evaluation": (ConstrainedChain, "evaluate"), "chain_energy": (ReducedChain, "evaluate"),
                 "constraint_hessian": (ConstrainedChain, "constraint_hessian"), "qp": (st, "dense_qp"),
                 "positive_definite": (st, "_positive_definite")}
    totals, per_piece, iterations, compiled_totals = [], {key: [] for key in pieces}, [], []
    from ballchain.drake_models.field_sources import UniformField

    from ballchain.systems.quasi_static_engine import _one_blas_thread

    blas = _one_blas_thread()  # as the engine solves
    blas.__enter__()
    for j in range(repeats):
        angle = np.radians(1.0) * (1 if j % 2 == 0 else -1)
        c, s_ = np.cos(angle), np.sin(angle)
        field = UniformField(np.array([B[0], c * B[1] - s_ * B[2], s_ * B[1] + c * B[2]]))  # about x
        engine._field_source = field
        for key, (owner, attr) in originals.items():
            setattr(owner, attr, timed(key, pieces[key]))
        for key in clock:
            clock[key] = 0.0
        t = time.perf_counter()
        try:
            _, _, res, _ = engine.equilibrium(s, None, p, m)
        finally:
            for key, (owner, attr) in originals.items():
                setattr(owner, attr, pieces[key])
        totals.append(time.perf_counter() - t)
        iterations.append(res.iterations)
        compiled._field_source = field
        t = time.perf_counter()
        compiled.equilibrium(s, None, p, m)
        compiled_totals.append(time.perf_counter() - t)
        for key in clock:
            per_piece[key].append(clock[key])
    out = {"compiled_equilibrium_ms": round(1e3 * float(np.median(compiled_totals)), 3),
           "equilibrium_ms": round(1e3 * float(np.median(totals)), 3),
           "newton_iterations": float(np.median(iterations)),
           "wall_contacts": len(res.wall_forces_W)}
    for key, values in per_piece.items():
        out[f"{key}_ms"] = round(1e3 * float(np.median(values)), 3)
    # evaluation = chain_energy (the chain's energy, gradient, Hessian: ReducedChain) + the wall
    # and sheath rows, gravity and bookkeeping (ConstrainedChain).
    out["rows_gravity_ms"] = round(out["evaluation_ms"] - out["chain_energy_ms"], 3)
    out["rest_ms"] = round(out["equilibrium_ms"] - sum(out[f"{k}_ms"] for k in pieces if k != "chain_energy"), 3)
    out.update(qp_comparison(engine, s, p, m))
    blas.__exit__(None, None, None)
    print("profile", json.dumps(out), flush=True)
    return out


def qp_comparison(engine, s, p, m, repeats: int = 30) -> dict:
    """One QP step of the equilibrium in contact, solved by the dense active set and by Clarabel
    through a MathematicalProgram built for it (the statics' previous way): median ms, and the
    largest difference of the steps."""
    from ballchain.optimization.statics import ChainStatics

    captured = []
    original = ChainStatics._qp_step

    def capture(self, *args):
        captured.append(args)
        return original(self, *args)

    ChainStatics._qp_step = capture
    try:
        engine.equilibrium(s + 0.5e-3, None, p, m)
    finally:
        ChainStatics._qp_step = original
    args = captured[0]
    out = {"qp_rows": int(len(args[2]))}
    steps = {}
    for qp in ("dense", "clarabel"):
        solver = ChainStatics(engine.chain, qp=qp)
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            steps[qp] = solver._qp_step(*args)[0]
            times.append(time.perf_counter() - t)
        out[f"qp_{qp}_ms"] = round(1e3 * float(np.median(times)), 3)
    out["qp_step_difference"] = float(np.abs(steps["dense"] - steps["clarabel"]).max())
    return out


def teleop_task(plant_targets: int | None = 2, repeats: int = 1, engine_only: bool = False) -> dict:
    """Task II (right ring, world mapping, seed 0) per engine: the engine whole, the plant on the
    first ``plant_targets`` (None: whole; ``engine_only``: no plant). Medians over ``repeats``
    alternating runs after an untimed warm-up of each (one target)."""
    from ballchain.experiments import teleop
    from ballchain.systems.chain_simulation import atrium_for

    heart = atrium_for(teleop.scenario_for("world"))
    engines = {"statics": (None, None)}
    if not engine_only:
        engines["plant"] = (teleop.FAST, plant_targets)
    for overrides, _ in engines.values():  # warm-up: numba kernels, the SDF, the plant's first build
        teleop.run(task="right", mapping="world", targets=1, progress=False, heart=heart, overrides=overrides)
    samples = {k: [] for k in engines}
    for _ in range(repeats):
        for engine, (overrides, targets) in engines.items():
            samples[engine].append(teleop.run(task="right", mapping="world", targets=targets, progress=False,
                                              heart=heart, overrides=overrides).summary)
    out = {}
    for engine, runs in samples.items():
        out[engine] = {"targets": runs[0].targets, "touched": runs[0].touched,
                       "sim_s": runs[0].sim_time_s,
                       "wall_s": round(float(np.median([r.wall_time_s for r in runs])), 2),
                       "wall_s_runs": [round(r.wall_time_s, 3) for r in runs],
                       "rtf_wall": round(float(np.median([r.realtime_factor for r in runs])), 3),
                       "rtf_cpu": round(float(np.median([r.realtime_factor_cpu for r in runs])), 3),
                       "failure": runs[0].failure, "missed_reasons": runs[0].missed_reasons}
    if not engine_only:
        out["speedup_wall"] = round(out["statics"]["rtf_wall"] / out["plant"]["rtf_wall"], 2)
        out["speedup_cpu"] = round(out["statics"]["rtf_cpu"] / out["plant"]["rtf_cpu"], 2)
    print("teleop_right_world", json.dumps(out), flush=True)
    e = out["statics"]
    print(f"Task II (right ring, world mapping) with the engine: {e['touched']}/{e['targets']} targets, "
          f"{e['sim_s']:.1f} s simulated in {e['wall_s']:.2f} s wall (RTF {e['rtf_wall']:.1f} wall, "
          f"{e['rtf_cpu']:.1f} CPU)", flush=True)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", nargs="*", default=None,
                        help="named scenarios (default: every named heart scenario)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per scenario and engine")
    parser.add_argument("--duration", type=float, default=None, help="simulated time per run [s] (default: the scenario's)")
    parser.add_argument("--max-duration", type=float, default=np.inf,
                        help="cap on the scenario's duration when --duration is not given [s]")
    parser.add_argument("--profile-repeats", type=int, default=20, help="warm equilibria in the profile")
    parser.add_argument("--no-profile", action="store_true", help="skip the equilibrium's profile")
    parser.add_argument("--teleop", action="store_true",
                        help="also the teleoperation task (Task II, world mapping) per engine")
    parser.add_argument("--plant-targets", type=int, default=2,
                        help="with --teleop: the plant's run covers the first N targets (0: the whole task, minutes)")
    parser.add_argument("--teleop-repeats", type=int, default=1, help="with --teleop: timed runs per engine")
    parser.add_argument("--engine-only", action="store_true",
                        help="only the quasi-static engine's runs (no plant column, no plant Task II)")
    parser.add_argument("--json", default=None, help="write the results to this file")
    args = parser.parse_args()
    if args.plant_targets < 0 or args.teleop_repeats < 1:
        parser.error("--plant-targets must be >= 0 and --teleop-repeats >= 1")
    if args.json:  # before the runs: a path that cannot be written must not cost them
        from ballchain.infrastructure.errors import UserInputError
        from ballchain.infrastructure.safe_files import check_output_file

        try:
            check_output_file(args.json, "--json")
        except UserInputError as err:
            parser.error(str(err))
    from threadpoolctl import threadpool_limits

    out = {}
    load_before = os.getloadavg()[0]
    # BLAS on one thread for the whole run, as the command line runs every command (``cli``): the
    # engine's per-update limit (``one_blas_thread``) is then a no-op, as in ``ballchain
    # simulate``, instead of two thread-count changes per update (about 20 us).
    with threadpool_limits(limits=1, user_api="blas"):
        if args.scenarios is None or args.scenarios:
            out = run(scenarios=args.scenarios, repeats=args.repeats, duration=args.duration,
                      max_duration=args.max_duration, profile_repeats=args.profile_repeats,
                      profile=not args.no_profile, engine_only=args.engine_only)
        if args.teleop:
            out["teleop_right_world"] = teleop_task(args.plant_targets or None, args.teleop_repeats,
                                                    engine_only=args.engine_only)
    out["load_average_1min"] = {"before": load_before, "after": os.getloadavg()[0]}
    out["cpu_count"] = os.cpu_count()
    if args.json:
        from ballchain.infrastructure.safe_files import write_json

        write_json(args.json, out)


if __name__ == "__main__":
    main()
