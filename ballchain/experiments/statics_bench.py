"""The statics benchmark: medians of repeated solves and a ratio against a baseline measured in the same run.

The equilibrium of an n-ball chain in a uniform field, solved by
``ChainStatics`` (Newton SQP in reduced coordinates, and its SNOPT reference) cold (from the
straight chain, no continuation) and warm (from the equilibrium at the field angle minus
``--warm-offset-deg``), against the naive SLSQP formulation of
``optimization.naive_statics`` from the straight chain, against the Python Newton solver on the
same kernels (``ChainStatics(compiled=False)``, the reference the compiled solve is held to:
"python" rows) and against that Python solver on the numpy reference implementation of the
chain's physics (``ReducedChain(backend="numpy")``, cold and warm): the compiled solve
(``optimization.compiled_newton``) is what the stack runs, the python and numpy rows say what
compiling the solve and the physics bought. Every solver must reach the same minimum (energy and
tip position against the Newton cold solve); the differences are printed.

The "contact" case times equilibria in contact: the 16-ball chain (``--balls`` is for the free
cases) pushed into the procedural left atrium by the left magnet of the heart scenarios,
inserted from 26.2 to 29 mm in 0.1 mm steps, each solve warm-started from the last (as the
quasi-static engine does), by the compiled solve and the Python reference alternately; the
median, p99 and maximum over every solve of every round.

``--compile-cost`` also times, in fresh processes, importing the kernels and running each once
with an empty numba cache (``NUMBA_CACHE_DIR`` pointed at a new temporary folder: what the first
run on a machine pays) and with the cache this run used.

Wall times are measured around each ``solve`` call (``time.perf_counter``), after one untimed
round, with the cases interleaved so that a burst of load from another process hits them all.
The problems are tiny (at most a few hundred unknowns), so multithreaded BLAS only adds
synchronisation: by default the loaded OpenBLAS libraries are limited to one thread for the run
(``--blas-threads``; 0 leaves them alone). ``--clock cpu`` times the process's CPU time instead
of wall time: steadier on a machine shared with other jobs. Benchmarks are scripts, not tests: the
tests check the fields' correctness, never the times.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
from dataclasses import dataclass

import numpy as np

from ballchain.infrastructure.errors import UserInputError, check_in
from ballchain.drake_models.field_sources import MAX_FIELD_T
from ballchain.experiments._result import Result, optional

# The agreement required of every solver with the Newton cold solve.
ENERGY_RTOL = 1e-9
TIP_ATOL_M = 1e-6

_CASES = ("newton_cold", "newton_warm", "python_cold", "python_warm", "numpy_cold", "numpy_warm", "snopt_cold",
          "snopt_warm", "baseline")
# Cases that --cases may leave out (the compiled Newton solves are always timed: the reference
# of every comparison). The naive SLSQP and SNOPT rows cannot run 1000 balls. "contact": the
# equilibria in contact in the heart (``contact_solves``).
_OPTIONAL = ("python", "numpy", "snopt", "baseline", "contact")


@contextlib.contextmanager
def blas_threads(n: int):
    """Limit the loaded BLAS libraries to ``n`` threads inside the block (``n = 0``: unchanged).

    Yields ``{library: threads in use}`` (what the solves ran with).
    """
    from threadpoolctl import ThreadpoolController

    controller = ThreadpoolController()
    with contextlib.ExitStack() as stack:
        if n > 0:
            stack.enter_context(controller.limit(limits=n, user_api="blas"))
        yield {info["filepath"].rsplit("/", 1)[-1]: info["num_threads"]
               for info in ThreadpoolController().info() if info["user_api"] == "blas"}


# --- statics ----------------------------------------------------------------------------------------


@dataclass(kw_only=True)
class StaticsBenchResult(Result):
    """What ``run_statics`` returns (times in ms, medians over the repeats; None: a case left out).

    Attributes:
        benchmark: "statics".
        n_balls, field_mT, angle_deg, warm_start_angle_deg, repeats, clock: the run's settings.
        cold_median_ms, warm_median_ms: the compiled Newton solve, cold and warm.
        python_cold_median_ms, python_warm_median_ms: the Python Newton solver on the kernels.
        numpy_cold_median_ms, numpy_warm_median_ms: the Python Newton solver on the numpy reference.
        snopt_cold_median_ms, snopt_warm_median_ms: SNOPT; baseline_median_ms: naive SLSQP.
        speedup_cold, speedup_warm: baseline / Newton; speedup_cold_vs_snopt: SNOPT / Newton;
        kernel_speedup_cold, kernel_speedup_warm: numpy reference / compiled (same-run ratios).
        compiled_speedup_cold, compiled_speedup_warm: Python solver / compiled solve.
        cold_back_to_back_median_ms, speedup_cold_back_to_back: the compiled cold solve repeated
            back to back (after the rounds), and baseline / it. In the rounds each solve follows
            another case (the Python solvers, SLSQP), which leaves the processor's caches cold:
            the two figures bracket a cold solve's cost.
        contact: the equilibria in contact (``contact_solves``; None: left out).
        same_minimum: each solver against the Newton cold solve (tolerances, differences, "ok").
        converged: per case (and the warm start); iterations: per case, and the baseline's
            energy evaluations.
        energy_J, tip_position_mm: the Newton cold minimum (tip shape (3,)).
        baseline: SLSQP's tolerance, message and largest constraint violation (None: not run).
        samples_ms, spread: every timed sample and (max - min) / median per case.
        blas_threads: {library: threads in use}; load_average_1min: before and after;
        cpu_count: the machine's.
        compile_cost: ``compile_cost()``'s dict (only when asked).
    """

    benchmark: str = "statics"
    n_balls: int
    field_mT: float
    angle_deg: float
    warm_start_angle_deg: float
    repeats: int
    clock: str
    cold_median_ms: float
    warm_median_ms: float
    python_cold_median_ms: float | None
    python_warm_median_ms: float | None
    numpy_cold_median_ms: float | None
    numpy_warm_median_ms: float | None
    snopt_cold_median_ms: float | None
    snopt_warm_median_ms: float | None
    baseline_median_ms: float | None
    speedup_cold: float | None
    speedup_warm: float | None
    speedup_cold_vs_snopt: float | None
    kernel_speedup_cold: float | None
    kernel_speedup_warm: float | None
    compiled_speedup_cold: float | None
    compiled_speedup_warm: float | None
    cold_back_to_back_median_ms: float
    speedup_cold_back_to_back: float | None
    kernel_note: str = ("python_*: the Newton solver in Python on the compiled kernels (the compiled solve's "
                        "reference); numpy_*: that solver on the numpy reference of the chain's physics")
    same_minimum: dict
    converged: dict
    iterations: dict
    iterations_note: str = "Newton: SQP iterations; SNOPT: energy evaluations; baseline: SLSQP iterations"
    energy_J: float
    tip_position_mm: np.ndarray
    baseline: dict | None
    samples_ms: dict
    spread: dict
    spread_note: str = "(max - min) / median of each case's samples"
    blas_threads: dict
    load_average_1min: dict
    cpu_count: int | None
    contact: dict | None = optional()
    compile_cost: dict | None = optional()


def _same_minimum(reference, other) -> dict:
    energy_diff = float(other.energy - reference.energy)
    tip_diff = float(np.linalg.norm(other.tip_position - reference.tip_position))
    return {
        "energy_diff_J": energy_diff,
        "energy_diff_rel": abs(energy_diff) / abs(reference.energy),
        "tip_diff_m": tip_diff,
        "max_position_diff_m": float(np.abs(other.positions - reference.positions).max()),
        "ok": bool(abs(energy_diff) <= ENERGY_RTOL * abs(reference.energy) and tip_diff <= TIP_ATOL_M),
    }


def _parse_cases(text: str) -> tuple[str, ...]:
    chosen = tuple(c.strip() for c in text.split(",") if c.strip())
    bad = [c for c in chosen if c not in _OPTIONAL]
    if bad:
        raise UserInputError(f"--cases: unknown case(s) {', '.join(bad)}; allowed: {', '.join(_OPTIONAL)}")
    return chosen


def compile_cost(timeout_s: float = 600.0) -> dict:
    """Wall time of importing the chain kernels and running each once, in fresh processes.

    Returns:
        ``{"empty_cache_s", "cached_s", "compile_s"}``: with ``NUMBA_CACHE_DIR`` on a new empty
        temporary folder (everything compiled), with the cache as configured for this run (loaded
        from disk), and their difference (what a machine's first run pays once).
    """
    import subprocess
    import tempfile

    code = (
        "import time; t0, c0 = time.perf_counter(), time.process_time(); "
        "from ballchain.optimization.warm_up import warm_up; warm_up(); "
        "print(time.perf_counter() - t0, time.process_time() - c0)"
    )

    def first_run(env) -> tuple[float, float]:
        proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                              timeout=timeout_s, check=True)
        wall, cpu = proc.stdout.strip().splitlines()[-1].split()
        return float(wall), float(cpu)

    with tempfile.TemporaryDirectory(prefix="ballchain-numba-cache-") as empty:
        empty_s, empty_cpu = first_run({**os.environ, "NUMBA_CACHE_DIR": empty})
    cached_s, cached_cpu = min(first_run(dict(os.environ)), first_run(dict(os.environ)))
    return {"empty_cache_s": empty_s, "cached_s": cached_s, "compile_s": empty_s - cached_s,
            "empty_cache_cpu_s": empty_cpu, "cached_cpu_s": cached_cpu, "compile_cpu_s": empty_cpu - cached_cpu,
            "note": "import + one call of every kernel in a fresh process (NUMBA_CACHE_DIR empty vs as "
                    "configured); *_s wall time, *_cpu_s the process's CPU time"}


CONTACT_PATH_MM = (26.2, 29.0, 0.1)  # the contact case's insertions: from, to, step [mm]


def contact_solves(repeats: int, now) -> dict:
    """Equilibria in contact, compiled against the Python reference (``ChainStatics(compiled=False)``)
    in the same run: the 16-ball chain pushed into the procedural left atrium by the heart
    scenarios' left magnet along ``CONTACT_PATH_MM``, each solve warm-started from the last (and
    its multipliers), one untimed pass then ``repeats`` timed ones of each solver, alternating.

    Returns:
        ``{"compiled", "python": {"median_ms", "p99_ms", "max_ms"}, "speedup_median",
        "solves", "in_contact", "max_position_diff_m", "iterations"}``.
    """
    from ballchain.drake_models.atrium_sdf import atrium_sdf
    from ballchain.drake_models.field_sources import MagnetSource
    from ballchain.drake_models.heart import LeftAtrium
    from ballchain.drake_models.params import BallChain, CylinderMagnet
    from ballchain.optimization.statics import ChainStatics
    from ballchain.optimization.wall_constraints import HeartConstraints, SheathGeometry, base_rotation, sheath_split

    heart = LeftAtrium()
    sdf = atrium_sdf(heart)
    chain = BallChain(n_balls=16)
    d = chain.ball_diameter
    magnet = MagnetSource.pointing(CylinderMagnet(), heart.p_HP + np.array([0.1651, 0.0, 0.0]), [0.0, -1.0, 0.0],
                                   "dipole")
    sheath = SheathGeometry(heart.p_HE, heart.sheath_axis_H, 1.8e-3, 0.3e-3)
    R_WB = base_rotation(heart.sheath_axis_H)
    start, stop, step = CONTACT_PATH_MM
    path = []
    for s in 1e-3 * np.arange(start, stop + 0.5 * step, step):
        k, a = sheath_split(chain.n_balls, s, d)
        path.append((k, HeartConstraints(heart.p_HE + a * heart.sheath_axis_H, R_WB, sdf, sheath, n_behind=k)))
    solvers = {name: {} for name in ("compiled", "python")}

    def one_pass(name: str, times: list | None) -> list:
        results, previous = [], None
        for k, c in path:
            n = chain.n_balls - k
            solver = solvers[name].get(n) or solvers[name].setdefault(
                n, ChainStatics(chain.with_balls(n), gravity=True, compiled=name == "compiled"))
            warm = previous if previous is not None and len(previous.positions) == n else None
            t0 = now()
            previous = solver.solve(magnet, warm, constraints=c)
            if times is not None:
                times.append(1e3 * (now() - t0))
            results.append(previous)
        return results

    times: dict[str, list] = {"compiled": [], "python": []}
    last = {name: one_pass(name, None) for name in times}
    for _ in range(repeats):
        for name in times:
            last[name] = one_pass(name, times[name])
    stats = {name: {"median_ms": float(np.median(t)), "p99_ms": float(np.percentile(t, 99)),
                    "max_ms": float(np.max(t))} for name, t in times.items()}
    return {**stats, "speedup_median": stats["python"]["median_ms"] / stats["compiled"]["median_ms"],
            "solves": len(times["compiled"]),
            "in_contact": sum(bool(r.wall_forces_W) for r in last["compiled"]),
            "converged": all(r.converged for name in last for r in last[name]),
            "max_position_diff_m": float(max(np.abs(a.positions - b.positions).max()
                                             for a, b in zip(last["compiled"], last["python"]))),
            "iterations": {name: [r.iterations for r in last[name]] for name in last}}


def _spread(samples_ms: list[float]) -> float:
    """(max - min) / median of a series: a rough noise figure."""
    return float((max(samples_ms) - min(samples_ms)) / np.median(samples_ms))


# The benchmarks' problem: the field's strength and angle, the warm start's offset (also ``bench
# scaling``'s); beyond them the solves time another problem (no equilibrium in 200 iterations).
FIELD_MT_RANGE = (1e-3, MAX_FIELD_T * 1e3)  # up to the API's bound (field_sources.MAX_FIELD_T)
ANGLE_DEG_RANGE = (-360.0, 360.0)
WARM_OFFSET_DEG_RANGE = (-45.0, 45.0)


def check_problem(field_mT, angle_deg, warm_offset_deg) -> None:
    """The field and warm start of a benchmark's problem, each in its range (UserInputError)."""
    check_in("--field-mT", field_mT, *FIELD_MT_RANGE, unit="mT")
    check_in("--angle-deg", angle_deg, *ANGLE_DEG_RANGE, unit="deg")
    check_in("--warm-offset-deg", warm_offset_deg, *WARM_OFFSET_DEG_RANGE, unit="deg")


def _check_statics_inputs(n_balls, field_mT, angle_deg, warm_offset_deg, repeats, baseline_ftol, clock) -> None:
    """``run_statics``'s arguments checked before any work: a ``UserInputError`` naming the bad one."""
    if isinstance(n_balls, bool) or not isinstance(n_balls, int) or not 2 <= n_balls <= 64:
        # the SLSQP baseline's pairwise constraints grow as n^2: 64 balls already take minutes
        raise UserInputError(f"--balls must be an integer >= 2 and <= 64 (ball 1 is held), got {n_balls!r}")
    check_problem(field_mT, angle_deg, warm_offset_deg)
    if not isinstance(repeats, int) or not 1 <= repeats <= 1000:
        raise UserInputError(f"--repeats must be an integer in 1..1000, got {repeats!r}")
    if not (math.isfinite(baseline_ftol) and baseline_ftol > 0):
        raise UserInputError(f"--baseline-ftol must be a positive finite number, got {baseline_ftol}")
    if clock not in ("wall", "cpu"):
        raise UserInputError(f"--clock must be 'wall' or 'cpu', got {clock!r}")


def _statics_solves(chain, field_mT: float, angle_deg: float, warm_angle: float, baseline_ftol: float,
                    chosen) -> tuple:
    """The solvers of every case, built once: ``(warm_up, solves)``.

    ``warm_up()`` is the Newton solve at ``warm_angle`` (the warm cases' start); ``solves(warm_start)``
    maps each case's name to a call that runs one solve at ``angle_deg``.
    """
    from ballchain.drake_models.field_sources import UniformField
    from ballchain.optimization.naive_statics import NaiveStatics
    from ballchain.optimization.reduced_chain import ReducedChain
    from ballchain.optimization.statics import ChainStatics

    B = field_mT * 1e-3
    external = UniformField.in_plane(B, math.radians(angle_deg))
    external_warm = UniformField.in_plane(B, math.radians(warm_angle))
    newton = ChainStatics(chain, method="newton")
    python = ChainStatics(chain, method="newton", compiled=False)
    reference = ChainStatics(chain, method="newton", compiled=False)
    # The same solver on the numpy reference of the physics: ChainStatics builds its
    # ReducedChain on the first solve, unless one is there.
    reference._model = ReducedChain(chain, None, False, backend="numpy")
    snopt = ChainStatics(chain, method="snopt") if "snopt" in chosen else None

    def solves(warm_start) -> dict:
        return {
            "newton_cold": lambda: newton.solve(external),
            "newton_warm": lambda: newton.solve(external, warm_start),
            "python_cold": lambda: python.solve(external),
            "python_warm": lambda: python.solve(external, warm_start),
            "numpy_cold": lambda: reference.solve(external),
            "numpy_warm": lambda: reference.solve(external, warm_start),
            "snopt_cold": lambda: snopt.solve(external),
            "snopt_warm": lambda: snopt.solve(external, warm_start),
            "baseline": lambda: NaiveStatics(chain, external, ftol=baseline_ftol).solve(),
        }

    return (lambda: newton.solve(external_warm)), solves


def round_order(active: tuple, round_: int) -> tuple:
    """The order of the cases in one round: a permutation drawn from the round's number, so that
    no case always runs first or always right after the same case (what runs before a solve
    decides what of it is still in the processor's caches: a compiled cold solve right after
    SLSQP took 0.46 ms, right after another compiled solve 0.29 ms). Round 0 keeps ``active``'s
    order. (Rotating the order, as this did before, kept every case's predecessor: the
    compiled cold solve always ran right after SLSQP, the warm one right after it.)"""
    if round_ == 0:
        return tuple(active)
    return tuple(active[i] for i in np.random.default_rng(round_).permutation(len(active)))


def _timed_rounds(solves, active: tuple, repeats: int, now, bar, warm_start) -> tuple[dict, dict]:
    """One untimed round, then ``repeats`` timed ones of every active case: ``(samples_ms, last result)``."""
    calls = solves(warm_start)
    samples: dict[str, list[float]] = {case: [] for case in active}
    last = {}
    for round_ in range(repeats + 1):  # round 0 is untimed (first-call costs)
        for case in round_order(active, round_):
            t0 = now()
            result = calls[case]()
            elapsed = now() - t0
            if round_ > 0:
                samples[case].append(1e3 * elapsed)
            last[case] = result
            bar.update()
    return samples, last


def _back_to_back(call, repeats: int, now, bar) -> list[float]:
    """One untimed call, then ``repeats`` timed ones in a row [ms]."""
    call()
    bar.update()
    samples = []
    for _ in range(repeats):
        t0 = now()
        call()
        samples.append(1e3 * (now() - t0))
        bar.update()
    return samples


def _statics_result(samples: dict, last: dict, active: tuple, warm_start) -> dict:
    """The result's medians, ratios, agreement, convergence and iteration counts (``StaticsBenchResult``
    fields), from the timed samples and each case's last solve."""
    reference = last["newton_cold"]
    medians = {case: float(np.median(samples[case])) if case in active else None for case in _CASES}
    same = {case: _same_minimum(reference, last[case]) for case in active if case != "newton_cold"}
    converged = {case: bool(last[case].converged) for case in active if case != "baseline"}
    if "baseline" in active:
        converged["baseline"] = bool(last["baseline"].success)
    converged["warm_start"] = bool(warm_start.converged)
    baseline = last.get("baseline")

    def ratio(a, b):
        return None if medians[a] is None or medians[b] is None else medians[a] / medians[b]

    def iterations(case):
        return last[case].iterations if case in last else None

    return dict(
        cold_median_ms=medians["newton_cold"],
        warm_median_ms=medians["newton_warm"],
        python_cold_median_ms=medians["python_cold"],
        python_warm_median_ms=medians["python_warm"],
        numpy_cold_median_ms=medians["numpy_cold"],
        numpy_warm_median_ms=medians["numpy_warm"],
        snopt_cold_median_ms=medians["snopt_cold"],
        snopt_warm_median_ms=medians["snopt_warm"],
        baseline_median_ms=medians["baseline"],
        speedup_cold=ratio("baseline", "newton_cold"),
        speedup_warm=ratio("baseline", "newton_warm"),
        speedup_cold_vs_snopt=ratio("snopt_cold", "newton_cold"),
        kernel_speedup_cold=ratio("numpy_cold", "newton_cold"),
        kernel_speedup_warm=ratio("numpy_warm", "newton_warm"),
        compiled_speedup_cold=ratio("python_cold", "newton_cold"),
        compiled_speedup_warm=ratio("python_warm", "newton_warm"),
        same_minimum={
            "reference": "newton_cold",
            "tolerance": {"energy_rel": ENERGY_RTOL, "tip_m": TIP_ATOL_M},
            **same,
            "ok": all(v["ok"] for v in same.values()),
        },
        converged=converged,
        iterations={
            **{case: iterations(case) for case in _CASES},
            "baseline_evaluations": None if baseline is None else baseline.evaluations,
        },
        energy_J=reference.energy,
        tip_position_mm=1e3 * reference.tip_position,
        samples_ms=samples,
        spread={case: _spread(samples[case]) for case in active},
    )


def run_statics(
    *,
    n_balls: int = 16,
    field_mT: float = 23.0,
    angle_deg: float = 90.0,
    warm_offset_deg: float = 2.5,
    repeats: int = 5,
    baseline_ftol: float = 1e-12,
    blas_threads_limit: int = 1,
    progress: bool = True,
    cases: str | tuple[str, ...] = _OPTIONAL,
    measure_compile_cost: bool = False,
    clock: str = "wall",
) -> StaticsBenchResult:
    """Time ``ChainStatics`` (newton on the kernels and on the numpy reference, snopt; cold, warm)
    against the SLSQP baseline.

    Args:
        n_balls: chain length (>= 2).
        field_mT: uniform field magnitude [mT] (> 0).
        angle_deg: field angle from +x towards +y [deg].
        warm_offset_deg: warm solves start from the (Newton, cold) equilibrium at
            ``angle_deg - warm_offset_deg`` [deg].
        repeats: timed solves per case (>= 1), after one untimed round.
        baseline_ftol: SLSQP's tolerance on the scaled energy.
        blas_threads_limit: OpenBLAS threads during the run (0: unchanged).
        progress: show a tqdm bar on stderr.
        cases: the baselines to time besides the Newton solves on the kernels (any of "numpy",
            "snopt", "baseline"; a comma-separated string or a tuple).
        measure_compile_cost: also run ``compile_cost`` (fresh processes).
        clock: "wall" (``time.perf_counter``) or "cpu" (``time.process_time``).

    Returns:
        A ``StaticsBenchResult``: medians [ms] (``cold_median_ms``, ``warm_median_ms`` for Newton,
        ``numpy_*`` for Newton on the numpy reference, ``snopt_*``, ``baseline_median_ms``; None
        for a case left out), ``speedup_cold`` (baseline / Newton cold), ``kernel_speedup_*``
        (numpy reference / kernels), ``compile_cost`` when asked, every sample, ``iterations``
        per case, ``converged`` per case, ``same_minimum`` (each solver against the Newton cold
        solve), and the run's conditions; ``to_json()`` is what ``bench statics --json`` prints.

    Raises:
        UserInputError: bad arguments.
    """
    _check_statics_inputs(n_balls, field_mT, angle_deg, warm_offset_deg, repeats, baseline_ftol, clock)
    now = time.process_time if clock == "cpu" else time.perf_counter
    chosen = _parse_cases(cases) if isinstance(cases, str) else _parse_cases(",".join(cases))
    active = tuple(c for c in _CASES if c.startswith("newton") or c.split("_")[0] in chosen)
    contact = None

    from tqdm import tqdm

    from ballchain.drake_models.params import BallChain

    chain = BallChain(n_balls=n_balls)
    warm_angle = angle_deg - warm_offset_deg
    warm_up, solves = _statics_solves(chain, field_mT, angle_deg, warm_angle, baseline_ftol, chosen)

    load_before = os.getloadavg()
    bar = tqdm(total=1 + (repeats + 1) * (len(active) + 1), desc=f"bench statics ({n_balls} balls)", unit="solve",
               file=sys.stderr, disable=not progress, leave=False)
    with blas_threads(blas_threads_limit) as threads_in_use:
        warm_start = warm_up()
        bar.update()
        samples, last = _timed_rounds(solves, active, repeats, now, bar, warm_start)
        back_to_back = float(np.median(_back_to_back(solves(warm_start)["newton_cold"], repeats, now, bar)))
        if "contact" in chosen:
            contact = contact_solves(repeats, now)
    bar.close()
    load_after = os.getloadavg()

    result = _statics_result(samples, last, active, warm_start)
    return StaticsBenchResult(
        n_balls=n_balls,
        field_mT=field_mT,
        angle_deg=angle_deg,
        warm_start_angle_deg=warm_angle,
        repeats=repeats,
        clock=clock,
        **result,
        cold_back_to_back_median_ms=back_to_back,
        speedup_cold_back_to_back=(None if result["baseline_median_ms"] is None
                                   else result["baseline_median_ms"] / back_to_back),
        baseline=None if "baseline" not in last else {"ftol": baseline_ftol, "message": last["baseline"].message,
                                                      "max_violation": last["baseline"].max_violation},
        blas_threads=threads_in_use,
        load_average_1min={"before": load_before[0], "after": load_after[0]},
        cpu_count=os.cpu_count(),
        contact=contact,
        compile_cost=compile_cost() if measure_compile_cost else None,
    )


run = run_statics  # the experiment's entry point, as every module of ballchain/experiments has
