"""Stops and notes around the kernels' compilation and the optimisers (``infrastructure/kernel_compiler.py``,
``cli.StopSignals``, ``errors.caused_by_interrupt``), and ``NUMBA_DISABLE_JIT``.

A ``ballchain`` command has each kernel that numba's cache lacks compiled by a child process and
waits for it where a stop can be raised: a stop during a machine's first compilation ends the
command within moments (before, it was answered minutes later, after the compilation), one line
says what is compiled, and a second command on the same empty cache says whom it waits for.
The process tests wait for a line on stderr before they signal (never a fixed sleep); their time
bound (``ANSWERED_S``) is a liveness check, not a timing claim: before the change the command
ran on for minutes after the signal.
"""

from __future__ import annotations

import fcntl
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from ballchain.cli import main as cli_main
from ballchain.infrastructure import kernel_compiler
from ballchain.infrastructure.errors import StopRequest, caused_by_interrupt

ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONFAULTHANDLER": "1"}
ANSWERED_S = 15.0  # a stopped command has ended by then (it ran on for minutes before the change)
COMPILING = "ballchain: compiling the chain kernels once for this machine"


def _start(argv, cache: Path, log: Path, **popen):
    env = {**ENV, "NUMBA_CACHE_DIR": str(cache)}
    err = log.open("w")
    proc = subprocess.Popen([sys.executable, "-m", "ballchain", *argv], stdout=subprocess.PIPE, stderr=err,
                            text=True, env=env, **popen)
    return proc, err


def _wait_for_line(log: Path, proc, text: str, timeout: float = 600.0) -> str:
    end = time.monotonic() + timeout
    while text not in log.read_text():
        assert proc.poll() is None, log.read_text()[-3000:]
        assert time.monotonic() < end, f"no line {text!r}: {log.read_text()[-2000:]}"
        time.sleep(0.05)
    return log.read_text()


def _compilers_of(cache: Path) -> list[int]:
    """The compile children still running with this NUMBA_CACHE_DIR."""
    found = []
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            if (b"kernel_compiler" in (proc / "cmdline").read_bytes()
                    and f"NUMBA_CACHE_DIR={cache}".encode() in (proc / "environ").read_bytes().split(b"\0")):
                found.append(int(proc.name))
        except OSError:
            pass
    return found


def _ended_by(proc, log: Path, signum: int, cache: Path) -> str:
    try:
        proc.communicate(timeout=ANSWERED_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        pytest.fail(f"still running {ANSWERED_S:g} s after {signal.Signals(signum).name}: {log.read_text()[-2000:]}")
    text = log.read_text()
    assert proc.returncode == 128 + signum, text[-3000:]
    assert "Traceback" not in text, text[-3000:]
    end = time.monotonic() + 5.0
    while _compilers_of(cache) and time.monotonic() < end:  # SIGKILLed with the command: gone at once
        time.sleep(0.05)
    assert _compilers_of(cache) == []
    return text


# ------------------------------------------------------------------ the first compilation

@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="Linux /proc")
@pytest.mark.parametrize("signum, to", [(signal.SIGTERM, "command"), (signal.SIGINT, "group"),
                                        (signal.SIGTERM, "group")], ids=lambda v: getattr(v, "name", v))
def test_a_stop_during_the_first_compilation_ends_the_command_within_seconds(tmp_path, signum, to):
    """An empty numba cache: the command says what it compiles, and a SIGTERM (``kill``, a batch
    scheduler: the command alone or its whole process group) or Ctrl-C (the terminal's process
    group, the compiling child included) ends it at once, with the one line and 128 + the signal."""
    cache, log = tmp_path / "numba", tmp_path / "stderr.txt"
    proc, err = _start(["statics", "--balls", "4"], cache, log, start_new_session=True)
    with err:
        text = _wait_for_line(log, proc, COMPILING)
        assert text.count(COMPILING) == 1 and f"later runs load them from {cache}" in text
        assert _compilers_of(cache), "no compiling child"
        if to == "group":
            os.killpg(proc.pid, signum)
        else:
            proc.send_signal(signum)
        text = _ended_by(proc, log, signum, cache)
    name = "interrupted" if signum == signal.SIGINT else f"interrupted by {signal.Signals(signum).name}"
    assert f"ballchain statics: {name} (files already written are complete)" in text
    assert len(text.strip().splitlines()) == 2, text  # the compiling note and the stop's line


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="Linux /proc")
def test_a_command_waiting_for_another_process_compilation_says_so_and_stops_at_once(tmp_path):
    """Another process compiles into the same cache (it holds the lock, its pid in the file): the
    command says whom it waits for, and a SIGTERM still ends it at once."""
    cache, log = tmp_path / "numba", tmp_path / "stderr.txt"
    cache.mkdir()
    with open(cache / kernel_compiler.LOCK_NAME, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        lock.write(f"{os.getpid()}\n")
        lock.flush()
        proc, err = _start(["statics", "--balls", "4"], cache, log)
        with err:
            text = _wait_for_line(log, proc, f"process {os.getpid()} is compiling the chain kernels into {cache}")
            assert COMPILING not in text  # it compiles nothing while the other one does
            proc.send_signal(signal.SIGTERM)
            text = _ended_by(proc, log, signal.SIGTERM, cache)
    assert "ballchain statics: interrupted by SIGTERM" in text


_KERNEL_CALL = textwrap.dedent("""
    import sys
    import numpy as np
    from ballchain.infrastructure import kernel_compiler
    from ballchain.drake_models.kernels import pair as ck
    r, x, y = np.array([1e-3, 2e-3, 0.5e-3]), np.array([0.0, 0.0, 1.0]), np.array([0.6, 0.0, 0.8])
    g = [np.zeros(3) for _ in range(3)]
    with kernel_compiler.in_a_child():
        value = ck._pair_first(r, x, y, 1.0, *g)
    stats = ck._pair_first.stats
    print(repr(float(value)), sum(stats.cache_hits.values()), sum(stats.cache_misses.values()))
""")


def _kernel_run(cache: Path, code: str = _KERNEL_CALL, *args) -> tuple[list[str], str]:
    proc = subprocess.run([sys.executable, "-c", code, *args], env={**ENV, "NUMBA_CACHE_DIR": str(cache)},
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.split(), proc.stderr


@pytest.mark.slow
def test_a_kernel_compiled_by_the_child_is_loaded_from_the_cache(tmp_path):
    """The child compiles into the cache and the command loads it (a cache hit, no compilation
    of its own), with the one line; the next process loads it and says nothing."""
    from ballchain.drake_models.kernels import pair as ck

    r, x, y = np.array([1e-3, 2e-3, 0.5e-3]), np.array([0.0, 0.0, 1.0]), np.array([0.6, 0.0, 0.8])
    expected = repr(float(ck._pair_first(r, x, y, 1.0, *[np.zeros(3) for _ in range(3)])))
    (value, hits, misses), err = _kernel_run(tmp_path)
    assert (value, hits, misses) == (expected, "1", "0"), err
    assert err.count(COMPILING) == 1 and len(err.strip().splitlines()) == 1, err
    assert (tmp_path / kernel_compiler.LOCK_NAME).exists()
    (value, hits, misses), err = _kernel_run(tmp_path)
    assert (value, hits, misses) == (expected, "1", "0") and err == ""


def test_the_note_names_the_cache_as_a_user_finds_it(monkeypatch):
    import numba

    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    in_tree = kernel_compiler._where("/src/drake_models/kernels/__pycache__")
    assert in_tree == "the __pycache__ folders beside their sources"
    assert kernel_compiler._where("/home/u/.cache/numba/kernels_0a1b") == "/home/u/.cache/numba"
    monkeypatch.setattr(numba.config, "CACHE_DIR", "/scratch/numba")
    assert kernel_compiler._where("/scratch/numba/kernels_0a1b") == "/scratch/numba"


_ELSEWHERE = """
from ballchain.drake_models.kernels._common import kernel


@kernel
def offset(x):
    return x + 1.5
"""

_CALL_ELSEWHERE = textwrap.dedent("""
    import sys
    sys.path.insert(0, sys.argv[1])  # a module only this process can import
    import elsewhere
    from ballchain.infrastructure import kernel_compiler
    with kernel_compiler.in_a_child():
        value = elsewhere.offset(1.0)
    stats = elsewhere.offset.stats
    print(value, sum(stats.cache_hits.values()), sum(stats.cache_misses.values()))
""")


@pytest.mark.slow
def test_a_kernel_the_child_cannot_find_is_compiled_in_the_command(tmp_path):
    """A kernel the child cannot import (a module on a path set at run time) is compiled in the
    command's process, as before: the right value, no hang, the one line all the same."""
    folder = tmp_path / "module"
    folder.mkdir()
    (folder / "elsewhere.py").write_text(_ELSEWHERE)
    out, err = _kernel_run(tmp_path / "numba", _CALL_ELSEWHERE, str(folder))
    assert out == ["2.5", "0", "1"] and err.count(COMPILING) == 1 and len(err.strip().splitlines()) == 1, err


# ------------------------------------------------------------------ NUMBA_DISABLE_JIT

_TIP = re.compile(r"tip at \(([-0-9., ]+)\) mm, tip angle ([-0-9.]+) deg, energy ([-0-9.e+]+) J")


@pytest.mark.slow
def test_numba_disable_jit_runs_the_commands_as_python():
    """NUMBA_DISABLE_JIT=1 (a debugging switch) ran into an AttributeError at import: the kernels
    now run as Python, with the compiled kernels' answer."""
    runs = {}
    for switch in ("0", "1"):
        proc = subprocess.run([sys.executable, "-m", "ballchain", "statics", "--balls", "4"], capture_output=True,
                              text=True, timeout=600, env={**ENV, "NUMBA_DISABLE_JIT": switch})
        assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
        runs[switch] = _TIP.search(proc.stdout).groups()
    assert runs["1"] == runs["0"]
    api = textwrap.dedent("""
        import numpy as np
        import ballchain
        from ballchain.drake_models.kernels import pair
        assert not hasattr(pair.pair_hessian, "signatures")  # a Python function, not a dispatcher
        r = ballchain.ChainStatics(ballchain.BallChain(n_balls=3)).solve(ballchain.UniformField([0.0, 0.02, 0.0]))
        print(r.converged, np.round(r.tip_position, 6).tolist())
    """)
    proc = subprocess.run([sys.executable, "-c", api], capture_output=True, text=True, timeout=600,
                          env={**ENV, "NUMBA_DISABLE_JIT": "1"})
    assert proc.returncode == 0 and proc.stdout.startswith("True"), proc.stderr[-3000:]


# ------------------------------------------------------------------ a stop inside an optimiser

def _snopt_stopped_by(exc: BaseException):
    """Solve a small program whose cost raises ``exc`` at its third evaluation; what comes out."""
    from pydrake.solvers import MathematicalProgram, SnoptSolver

    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(2)
    calls = []

    def cost(v):
        calls.append(1)
        if len(calls) == 3:
            raise exc
        return (v[0] - 1.0) ** 2 + (v[1] - 2.0) ** 2

    prog.AddCost(cost, vars=x)
    with pytest.raises(BaseException) as caught:
        SnoptSolver().Solve(prog, np.zeros(2))
    return caught.value


@pytest.mark.parametrize("exc", [StopRequest(signal.SIGTERM), KeyboardInterrupt()], ids=["StopRequest", "Ctrl-C"])
def test_a_stop_inside_snopt_is_a_stop(exc):
    """Drake's SNOPT keeps only the text of what a cost raised (a RuntimeError, no context): a stop
    there is still recognised as one."""
    err = _snopt_stopped_by(exc)
    assert type(err) is RuntimeError and err.__context__ is None and caused_by_interrupt(err)


def test_an_error_inside_snopt_stays_an_error():
    err = _snopt_stopped_by(ValueError("StopRequest: a bug's message"))
    assert type(err) is RuntimeError and not caused_by_interrupt(err)


@pytest.mark.parametrize("solver", ["ipopt", "slsqp"])
def test_a_stop_inside_ipopt_and_slsqp_comes_out_as_the_stop(solver):
    calls = []

    def f(v):
        calls.append(1)
        if len(calls) == 3:
            raise StopRequest(signal.SIGTERM)
        return (v[0] - 1.0) ** 2 + (v[1] - 2.0) ** 2

    with pytest.raises(BaseException) as caught:
        if solver == "slsqp":
            from scipy.optimize import minimize

            minimize(f, np.zeros(2), method="SLSQP")
        else:
            from pydrake.solvers import IpoptSolver, MathematicalProgram

            prog = MathematicalProgram()
            x = prog.NewContinuousVariables(2)
            prog.AddCost(f, vars=x)
            IpoptSolver().Solve(prog, np.zeros(2))
    assert caused_by_interrupt(caught.value)


def test_plan_stopped_inside_snopt_is_one_line_and_130(monkeypatch, capsys):
    """Ctrl-C while SNOPT evaluates the held tip's force (its only caller): one line, status 130,
    no traceback (it was SNOPT's RuntimeError, a traceback and status 1)."""
    from ballchain.optimization import inverse_statics

    original, calls = inverse_statics.HeldTip.value_and_jacobian, []

    def interrupted(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            signal.raise_signal(signal.SIGINT)  # the handler raises at the next line: inside SNOPT's callback
        return original(self, *args, **kwargs)

    monkeypatch.setattr(inverse_statics.HeldTip, "value_and_jacobian", interrupted)
    code = cli_main(["plan", "--targets", "1", "--balls", "16", "--min-force", "5"])  # 5 gf: SNOPT runs
    err = capsys.readouterr().err
    assert calls and code == 130, err[-3000:]
    assert "ballchain plan: interrupted (files already written are complete)" in err and "Traceback" not in err


@pytest.mark.slow
def test_a_stopped_plan_is_one_line_and_130(tmp_path):
    """Ctrl-C once the plan runs (at 5 gf most of its time is SNOPT's): status 130, one line, no
    traceback."""
    log = tmp_path / "stderr.txt"
    err = log.open("w")
    proc = subprocess.Popen([sys.executable, "-m", "ballchain", "plan", "--min-force", "5"], stdout=subprocess.PIPE,
                            stderr=err, text=True, env=ENV)
    with err:
        end = time.monotonic() + 900
        while not re.search(r"plan left: .*\b[1-9]\d*/20 \[", log.read_text()):
            assert proc.poll() is None and time.monotonic() < end, log.read_text()[-3000:]
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=300)
    text = log.read_text()
    assert proc.returncode == 130 and "Traceback" not in text, text[-3000:]
    assert "ballchain plan: interrupted" in text
