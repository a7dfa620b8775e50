"""The machine's limits (open files, processes, memory) met by a command: one line naming the
limit (its value from ``resource.getrlimit``) and what to do, exit status 1, no traceback.

The commands run in a subprocess whose limits ``preexec_fn`` sets, as ``ulimit`` would. Two
cases cannot be met for real here and are provoked instead, through the same code path: the
tests run as root, which the kernel exempts from the process limit (``ulimit -u``), so the
worker's start fails as fork does at that limit (EAGAIN); and a run that needs more memory than
``ulimit -v`` allows is a command that asks for 16 GiB at once (a real run near the limit may
also die in a C library: see ``resource_limits``).
"""

from __future__ import annotations

import errno
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from ballchain.infrastructure import resource_limits
from ballchain.infrastructure.resource_limits import limit_message

SPEC = """
experiment: statics
grid:
  n_balls: [4, 5]
  field_angle_deg: [90]
"""


def _limited(**limits):
    """A preexec_fn setting resource limits (name: (soft, hard)) in the child, as ulimit does."""
    def apply():
        for name, value in limits.items():
            resource.setrlimit(getattr(resource, name), value)
    return apply


def _ballchain(args, cwd: Path, preexec_fn=None, script: str | None = None,
               timeout: float = 600) -> subprocess.CompletedProcess:
    """The command line in a child (or ``script``, a stand-in for it, given ``args``). ``timeout``
    only guards against a hang (before the change, a low address-space limit hung OpenBLAS)."""
    command = [sys.executable, "-c", script, *args] if script else [sys.executable, "-m", "ballchain", *args]
    return subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=timeout, preexec_fn=preexec_fn)


def _one_error_line(result: subprocess.CompletedProcess, *words) -> str:
    assert result.returncode == 1, result.stderr[-3000:]
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    lines = [line for line in result.stderr.splitlines() if "error" in line.lower()]
    assert len(lines) == 1, result.stderr[-3000:]
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def spec(tmp_path):
    path = tmp_path / "spec.yaml"
    path.write_text(SPEC)
    return path


# ------------------------------------------------------------------ open files (ulimit -n)

@pytest.mark.slow
def test_an_open_file_limit_too_low_for_the_workers_is_one_line_before_they_start(spec, tmp_path):
    """The audit's case: ulimit -n 24 and --workers 2 gave five chained tracebacks (EMFILE,
    "Nanny failed to start")."""
    result = _ballchain(["sweep", str(spec), "--out", "out", "--workers", "2", "--no-progress"], tmp_path,
                        _limited(RLIMIT_NOFILE=(24, 24)))
    line = _one_error_line(result, "ulimit -n", "24", "--workers 2", f"{resource_limits.open_files_needed(2)}")
    assert line.startswith("ballchain sweep: error:")
    assert not (tmp_path / "out" / "table.csv").exists()  # refused before any point ran


@pytest.mark.slow
def test_a_low_soft_open_file_limit_is_raised_up_to_the_hard_one(spec, tmp_path):
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < resource_limits.open_files_needed(2):
        pytest.skip(f"the hard open-file limit here ({hard}) is below what two workers need")
    result = _ballchain(["sweep", str(spec), "--out", "out", "--workers", "2", "--no-progress", "--no-figure"],
                        tmp_path, _limited(RLIMIT_NOFILE=(24, hard)))
    assert result.returncode == 0, result.stderr[-3000:]
    assert "Traceback" not in result.stderr and (tmp_path / "out" / "table.csv").exists()


def test_open_files_needed_grows_with_the_workers_and_the_refusal_says_how_many_fit(monkeypatch):
    monkeypatch.setattr(resource, "getrlimit", lambda which: (100, 100))
    with pytest.raises(resource_limits.ResourceLimitError) as excinfo:
        resource_limits.check_open_files(8)
    fit = (100 - resource_limits.FDS_BASE) // resource_limits.FDS_PER_WORKER
    assert f"--workers {fit} or fewer" in str(excinfo.value) and "ulimit -n" in str(excinfo.value)
    resource_limits.check_open_files(fit)  # fits: nothing said


# ------------------------------------------------------------------ processes and threads (ulimit -u)

_FORK_REFUSED = """
import errno, multiprocessing.util, sys

def refused(*args, **kwargs):  # what fork does at the user's process limit
    raise BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")

multiprocessing.util.spawnv_passfds = refused
from ballchain.cli import main

if __name__ == "__main__":
    sys.exit(main())
"""


@pytest.mark.slow
def test_a_worker_process_that_cannot_be_started_is_one_line_naming_ulimit_u(spec, tmp_path):
    result = _ballchain(["sweep", str(spec), "--out", "out", "--workers", "2", "--no-progress"], tmp_path,
                        _limited(RLIMIT_NPROC=(4000, resource.getrlimit(resource.RLIMIT_NPROC)[1])),
                        script=_FORK_REFUSED)
    _one_error_line(result, "ulimit -u", "4000", "--workers")


# ------------------------------------------------------------------ memory (ulimit -v)

_ASKS_16_GIB = """
import sys
import numpy as np
import ballchain.commands.wheels as wheels
from ballchain.cli import main

wheels.main = lambda args: np.ones(2**31)  # 16 GiB at once
if __name__ == "__main__":
    sys.exit(main())
"""


def test_a_run_that_needs_more_memory_than_ulimit_v_is_one_line(tmp_path):
    result = _ballchain(["wheels", "--json"], tmp_path, _limited(RLIMIT_AS=(4 * 2**30, resource.RLIM_INFINITY)),
                        script=_ASKS_16_GIB)
    _one_error_line(result, "out of memory", "ulimit -v 4194304", "4.0 GiB")


def test_an_address_space_too_small_to_load_the_libraries_is_refused_before_they_load(tmp_path):
    """Under about 0.55 GiB the import failed in a traceback ("failed to map segment"); at 0.6-0.7
    GiB OpenBLAS's start-up looped for ever, deaf to SIGTERM."""
    result = _ballchain(["statics", "--json"], tmp_path, _limited(RLIMIT_AS=(512 * 2**20, resource.RLIM_INFINITY)),
                        timeout=120)
    line = _one_error_line(result, "ulimit -v 524288", "512 MiB", "1.0 GiB")
    assert line.startswith("ballchain statics: error:") and result.stdout == ""


# ------------------------------------------------------------------ which errors are a limit's

def _raised(make):
    try:
        make()
    except BaseException as err:  # noqa: BLE001
        return err
    raise AssertionError("nothing raised")


def _nanny_failed():
    """Dask's chain when a nanny cannot start: EMFILE, then the nanny's own error, then its start's."""
    try:
        try:
            raise OSError(errno.EMFILE, "Too many open files")
        except OSError:
            raise AssertionError("Status.init")
    except AssertionError as err:
        raise RuntimeError("Nanny failed to start.") from err


def test_a_limit_is_found_anywhere_in_the_chain_and_other_errors_stay_bugs():
    assert "ulimit -n" in limit_message(_raised(_nanny_failed))
    assert "ulimit -u" in limit_message(RuntimeError("can't start new thread"))
    assert "too many open files on this machine" in limit_message(OSError(errno.ENFILE, "File table overflow"))
    assert "out of memory" in limit_message(MemoryError())
    assert "out of memory" in limit_message(OSError(errno.ENOMEM, "Cannot allocate memory"))
    # EAGAIN from anything but starting a process or thread (a non-blocking socket) is not a limit's
    assert limit_message(BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")) is None
    for bug in (RuntimeError("Nanny failed to start."), ValueError("x"), OSError(errno.EINVAL, "Invalid argument")):
        assert limit_message(bug) is None


def test_without_a_memory_limit_the_line_says_the_machine_ran_out(monkeypatch):
    monkeypatch.setattr(resource, "getrlimit", lambda which: (resource.RLIM_INFINITY, resource.RLIM_INFINITY))
    message = limit_message(MemoryError())
    assert "no per-process limit" in message and "make the run smaller" in message
