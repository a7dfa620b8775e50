"""The Dask executor that sweeps and report sections share: a new LocalCluster, a job-queue
cluster, an existing scheduler (asked who it is first) or this process, and the caps on workers."""

from __future__ import annotations

import os

from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.infrastructure.resource_limits import ResourceLimitError, check_open_files, limit_message

MAX_WORKERS_PER_CORE = 4  # LocalCluster processes per core: more only share the cores (and the memory)
MAX_JOBS = 256  # job-queue jobs one sweep may ask for
CONNECT_TIMEOUT = 15.0  # [s] for a scheduler to accept the connection and answer


def default_workers() -> int:
    """One worker process per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def max_workers() -> int:
    """The most LocalCluster worker processes: ``MAX_WORKERS_PER_CORE`` per core."""
    return MAX_WORKERS_PER_CORE * default_workers()


def _check_executor(scheduler: str | None, workers: int | None, jobqueue: str | None) -> None:
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
        raise UserInputError(f"--workers must be an integer >= 0 (0: serial, in this process), got {short_repr(workers)}")
    for name, value in (("--scheduler", scheduler), ("--jobqueue", jobqueue)):
        if value is not None and not isinstance(value, str):
            raise UserInputError(f"{name} must be a string (or None), got {short_repr(value)}")
    if scheduler is not None and jobqueue is not None:
        raise UserInputError("--scheduler and --jobqueue exclude each other: give one")
    if scheduler is not None and workers == 0:
        raise UserInputError("--workers 0 (serial) and --scheduler exclude each other")
    if scheduler is not None:
        _check_address(scheduler)
    if jobqueue is None and scheduler is None and workers is not None and workers > max_workers():
        raise UserInputError(f"--workers must be at most {max_workers()} ({MAX_WORKERS_PER_CORE} per core; this "
                             f"process may use {default_workers()}), got {workers}")
    if jobqueue is not None and workers is not None and workers > MAX_JOBS:
        raise UserInputError(f"--workers (jobs of --jobqueue) must be at most {MAX_JOBS}, got {workers}")
    if jobqueue is not None:
        if jobqueue not in JOBQUEUE_CLUSTERS:
            raise UserInputError(f"--jobqueue must be one of {sorted(JOBQUEUE_CLUSTERS)}, got {short_repr(jobqueue)}")
        try:
            import dask_jobqueue  # noqa: F401
        except ImportError:
            raise UserInputError("--jobqueue needs dask-jobqueue (pip install dask-jobqueue); it is an "
                                 "optional dependency") from None


def _check_address(address) -> None:
    """A scheduler address: a scheme Dask speaks (tcp:// when none is given), a host and a port."""
    from distributed.comm.addressing import parse_host_port
    from distributed.comm.registry import backends

    if not isinstance(address, str):
        raise UserInputError(f"--scheduler must be an address like tcp://host:8786, got {short_repr(address)}")
    scheme, sep, location = address.partition("://")
    if not sep:
        scheme, location = "tcp", address
    schemes = sorted(set(backends) - {"inproc"})  # inproc: only within one process
    if scheme not in schemes:
        raise UserInputError(f"--scheduler {short_repr(address)}: unknown scheme {short_repr(scheme)}; Dask "
                             f"speaks {', '.join(schemes)} (e.g. tcp://host:8786)")
    try:
        host, port = parse_host_port(location)
    except ValueError:
        host, port = "", 0
    if not host or not 0 < port < 65536:
        raise UserInputError(f"--scheduler must be an address like tcp://host:8786 (a host and a port in "
                             f"1..65535), got {short_repr(address)}")


def _probe_scheduler(address: str, timeout: float) -> None:
    """Ask what listens at ``address`` who it is (Dask's ``identity``) within ``timeout`` seconds.

    ``distributed.Client`` waits for a silent peer past its own timeout (the handshake has none),
    so the question runs first, bounded as a whole, on a loop of its own (in a thread: the caller
    may be inside a running event loop, e.g. a notebook).

    Raises:
        UserInputError: nothing answered in time, or what answered is not a Dask scheduler.
    """
    import asyncio
    from concurrent.futures import ThreadPoolExecutor

    from distributed.comm import connect

    async def identity():
        comm = await connect(address, timeout=timeout)
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            comm.abort()

    def ask():
        return asyncio.run(asyncio.wait_for(identity(), timeout))

    with ThreadPoolExecutor(max_workers=1) as pool:
        try:
            reply = pool.submit(ask).result()
        except (asyncio.TimeoutError, TimeoutError):
            raise UserInputError(f"--scheduler {short_repr(address)}: no Dask scheduler answered within {timeout:g} s "
                                 "(something else listens there, or it is busy)") from None
        except OSError as err:
            raise UserInputError(f"--scheduler {short_repr(address)}: cannot connect: {' '.join(str(err).split())[:200]}") from None
        except Exception as err:  # noqa: BLE001 - whatever a foreign service sends back
            raise UserInputError(f"--scheduler {short_repr(address)}: what listens there does not speak Dask's protocol "
                                 f"({type(err).__name__})") from None
    kind = reply.get("type") if isinstance(reply, dict) else None
    if kind != "Scheduler":
        raise UserInputError(f"--scheduler {short_repr(address)}: a Dask {kind or 'peer'} answers there, not a scheduler")


JOBQUEUE_CLUSTERS = {"slurm": "SLURMCluster", "pbs": "PBSCluster", "sge": "SGECluster", "lsf": "LSFCluster",
                     "htcondor": "HTCondorCluster", "moab": "MoabCluster", "oar": "OARCluster"}


class Executor:
    """A Dask client on a new LocalCluster, a job-queue cluster or an existing scheduler.

    Use as a context manager; ``client`` is None for the serial (in-process) executor.
    """

    def __init__(self, *, scheduler: str | None = None, workers: int | None = None, jobqueue: str | None = None,
                 client=None, connect_timeout: float = CONNECT_TIMEOUT):
        _check_executor(scheduler, workers, jobqueue)
        self.scheduler, self.workers, self.jobqueue = scheduler, workers, jobqueue
        self.connect_timeout = connect_timeout
        self.client, self._own_client, self.cluster = client, client is None, None
        self.description = "client given by the caller" if client is not None else ""

    def __enter__(self) -> "Executor":
        if self.client is not None or self.workers == 0:
            self.description = self.description or "serial (this process)"
            return self
        from distributed import Client

        if self.scheduler is not None:
            _probe_scheduler(self.scheduler, self.connect_timeout)
            try:
                self.client = Client(self.scheduler, timeout=f"{self.connect_timeout:g}s")
            except (OSError, TimeoutError) as err:
                raise UserInputError(f"--scheduler {short_repr(self.scheduler)}: cannot connect: {err}") from None
            self.description = f"scheduler {self.scheduler}"
        elif self.jobqueue is not None:
            import dask_jobqueue

            # Queue, cores, memory, walltime... come from the dask-jobqueue configuration
            # (~/.config/dask/jobqueue.yaml); --workers sets how many jobs to start.
            self.cluster = getattr(dask_jobqueue, JOBQUEUE_CLUSTERS[self.jobqueue])()
            self.cluster.scale(jobs=self.workers or 1)
            self.client = Client(self.cluster)
            self.description = f"{self.jobqueue} job queue, {self.workers or 1} job(s)"
        else:
            import logging
            import warnings

            from distributed import LocalCluster

            n = self.workers or default_workers()
            check_open_files(n)  # too low a ulimit -n: one line now (Dask's nannies fail in tracebacks)
            # Processes with one thread each: the points are GIL-bound Python and numpy. The
            # scheduler's HTTP server (health routes) moves to a free port when another cluster on
            # the machine holds 8787: not worth a warning.
            nanny_log = logging.getLogger("distributed.nanny")
            level = nanny_log.level
            nanny_log.setLevel(logging.CRITICAL)  # its "Failed to start process" traceback: the error below holds it
            try:
                with warnings.catch_warnings():
                    warnings.filterwarnings("ignore", message=r"Port \d+ is already in use")
                    # The workers' own logs at CRITICAL only: a point's failure reaches the client as its
                    # exception and a dead worker as KilledWorker (both reported by the caller), while at
                    # shutdown a worker whose heartbeat meets the closed scheduler logs a traceback
                    # ("Failed to communicate with scheduler during heartbeat") after a clean run.
                    self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                                dashboard_address=None, silence_logs=logging.CRITICAL)
            except Exception as err:  # a limit met as the workers start (processes, memory): one line
                message = limit_message(err)
                if message is None:
                    raise
                raise ResourceLimitError(message) from err
            finally:
                nanny_log.setLevel(level)
            self.client = Client(self.cluster)
            self.description = f"LocalCluster, {n} worker process(es)"
        return self

    def __exit__(self, *exc) -> None:
        try:
            if self._own_client and self.client is not None:
                self.client.close()
                self.client = None
        finally:  # a stop while the client closes still closes the cluster (its worker processes)
            if self.cluster is not None:
                self.cluster.close()
                self.cluster = None


def _infrastructure_error(exc) -> bool:
    """Whether a task's failure is the cluster's (its worker died), not the point's."""
    from distributed.scheduler import KilledWorker

    try:
        from distributed.comm.core import CommClosedError
    except ImportError:  # pragma: no cover
        CommClosedError = OSError  # noqa: N806
    return isinstance(exc, (KilledWorker, CommClosedError, OSError, TimeoutError))


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return "serial"
