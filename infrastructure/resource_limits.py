"""The machine's limits on a run: open files, processes and threads, memory.

A run that meets one of them ends with one line naming the limit, its value
(``resource.getrlimit``) and what to do, and exit status 1 (``ResourceLimitError``; the command
line turns the errors below into it too, ``limit_message``). Status 1, not 2: the command and
its input are valid, and the same command runs where the limit is higher; the limit was set by
the shell (``ulimit``), a batch scheduler or the administrator, not by the command's
arguments. So a script can tell "fix the command" (2) from "the run failed here" (1), as for a
full disk.

What is checked before the work, where it is cheap: an address-space limit under 1 GiB, where
the libraries cannot load (``address_space_refusal``); a ``LocalCluster`` of n worker processes
(``sweep --workers n``, ``reproduce --workers n``) needs open files in this process for the
scheduler's and each nanny's connections and pipes (``check_open_files``). Measured on the
``statics`` sweep (Linux, Dask 2026.8): the least ``ulimit -n`` that runs is 32 for 1 worker, 44
for 2, 64 for 4 and 104 for 8, about 24 + 10 per worker; below it Dask's nannies fail to start
(``EMFILE``, five chained tracebacks), and with a limit of 16 its accept loop spun at full CPU
writing the same traceback to stderr (2 GB in five minutes). The soft limit is raised up to the
hard one when that is enough (any process may do so); otherwise the run is refused before the
cluster starts.
"""

from __future__ import annotations

import errno
import resource

from ballchain.infrastructure.errors import ResourceLimitError

MIN_ADDRESS_SPACE = 2**30  # [bytes] below it the libraries fail to load, or OpenBLAS waits forever
FDS_BASE = 32  # open files of the command and the scheduler (24 measured, plus room)
FDS_PER_WORKER = 12  # open files per LocalCluster worker in this process (10 measured, plus room)


def _soft(which: int) -> int | None:
    """The soft limit ``which`` (resource.RLIMIT_*), None when unlimited."""
    soft, _ = resource.getrlimit(which)
    return None if soft == resource.RLIM_INFINITY else soft


def _size(n_bytes: int) -> str:
    return f"{n_bytes / 2**30:.1f} GiB" if n_bytes >= 2**30 else f"{n_bytes / 2**20:.0f} MiB"


def open_files_needed(workers: int) -> int:
    """About how many open files a command with a LocalCluster of ``workers`` processes needs."""
    return FDS_BASE + FDS_PER_WORKER * workers


def check_open_files(workers: int, flag: str = "--workers") -> None:
    """Make sure this process may open the files a LocalCluster of ``workers`` processes needs:
    the soft limit is raised (up to the hard limit) when it is lower.

    Raises:
        ResourceLimitError: the hard limit is lower too; the message names ``ulimit -n``, its
            value, what is needed and how many workers the limit allows.
    """
    need = open_files_needed(workers)
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY or soft >= need:
        return
    if hard == resource.RLIM_INFINITY or hard >= need:
        resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))
        return
    fit = max(0, (hard - FDS_BASE) // FDS_PER_WORKER)
    then = f"{flag} {fit} or fewer" if fit >= 1 else f"{flag} 0 (serial, in this process)"
    raise ResourceLimitError(f"{flag} {workers} needs about {need} open files (Dask's scheduler and "
                             f"{FDS_PER_WORKER} per worker process), and this process may open {hard} "
                             f"(ulimit -n); raise it (ulimit -n {max(need, 1024)}) or give {then}")


def address_space_refusal() -> str | None:
    """The one line refusing to start under an address-space limit (``ulimit -v``, ``ulimit -d``)
    lower than ``MIN_ADDRESS_SPACE``, else None. Measured: the commands map 0.5-0.75 GiB as
    pydrake, numba's LLVM, scipy and OpenBLAS load; under 0.55 GiB the import fails ("failed to
    map segment"), and at 0.6-0.7 GiB OpenBLAS's start-up loops on a failing malloc for ever, at
    full CPU and deaf to SIGTERM (its C code never returns to Python)."""
    for name, which in (("ulimit -v", resource.RLIMIT_AS), ("ulimit -d", resource.RLIMIT_DATA)):
        value = _soft(which)
        if value is not None and value < MIN_ADDRESS_SPACE:
            return (f"this process may use {_size(value)} of memory ({name} {value // 1024}), and ballchain needs "
                    f"at least {_size(MIN_ADDRESS_SPACE)} to load its libraries; raise the limit ({name} "
                    f"{4 * MIN_ADDRESS_SPACE // 1024} or unlimited)")
    return None


def _processes_message() -> str:
    limit = _soft(resource.RLIMIT_NPROC)
    shown = f"this user may run {limit} processes and threads" if limit is not None else \
        "the system has no more processes or threads to give (no per-user limit is set)"
    return (f"cannot start another process or thread: {shown} (ulimit -u); raise the limit, or start fewer "
            "worker processes (--workers)")


def _memory_message() -> str:
    limits = [(name, _soft(which)) for name, which in (("ulimit -v", resource.RLIMIT_AS),
                                                       ("ulimit -d", resource.RLIMIT_DATA))]
    limits = [(name, value) for name, value in limits if value is not None]
    if limits:
        name, value = min(limits, key=lambda item: item[1])
        return (f"out of memory: this process may use {_size(value)} ({name} {value // 1024}); raise the limit "
                f"({name} unlimited) or make the run smaller")
    return ("out of memory: the machine (or its memory cgroup) had no more to give, with no per-process limit "
            "set (ulimit -v unlimited); free memory or make the run smaller")


_STARTS = {"_launch", "spawnv_passfds", "_execute_child", "_fork_exec", "fork", "start", "_start_new_thread"}


def _started_something(err: BaseException) -> bool:
    """Whether ``err`` was raised while starting a process or a thread (its traceback's frames)."""
    tb = err.__traceback__
    while tb is not None:
        if tb.tb_frame.f_code.co_name in _STARTS:
            return True
        tb = tb.tb_next
    return False


def _one(err: BaseException) -> str | None:
    if isinstance(err, ResourceLimitError):
        return str(err)
    if isinstance(err, MemoryError):
        return _memory_message()
    if isinstance(err, OSError):
        if err.errno == errno.EMFILE:
            limit = _soft(resource.RLIMIT_NOFILE)
            return (f"too many open files: this process may open {limit} (ulimit -n); raise the limit (ulimit -n "
                    f"{max(4 * (limit or 0), 1024)}), or start fewer worker processes (--workers)")
        if err.errno == errno.ENFILE:
            return ("too many open files on this machine: the system's table is full (ENFILE, "
                    "/proc/sys/fs/file-max); close other programs or raise it")
        if err.errno == errno.ENOMEM:
            return _memory_message()
        if err.errno == errno.EAGAIN and _started_something(err):
            return _processes_message()
    if isinstance(err, RuntimeError) and "can't start new thread" in str(err):
        return _processes_message()
    return None


def limit_message(err: BaseException) -> str | None:
    """The one line for an error caused by a resource limit (``err`` or an error it was raised
    from or while handling: Dask wraps a nanny's ``EMFILE`` in "Nanny failed to start"), else
    None."""
    seen = set()
    while err is not None and id(err) not in seen:
        message = _one(err)
        if message is not None:
            return message
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return None
