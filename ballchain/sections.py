"""Independent report sections run side by side on worker processes (``run_sections``), or one
after the other in this process: what ``reproduce`` and the procedure report share."""

from __future__ import annotations

import math
import sys
import time
import uuid
from pathlib import Path
from typing import Any, Callable, NamedTuple, Sequence

from threadpoolctl import threadpool_limits
from tqdm import tqdm

from ballchain.executor import Executor, _worker_name


class SectionRun(NamedTuple):
    """One report section's outcome: its name, what its function returned, seconds, where it ran."""

    name: str
    value: Any
    seconds: float
    worker: str


def _run_section(fn: Callable, out: str, quick: bool):
    start = time.perf_counter()
    with threadpool_limits(limits=1, user_api="blas"):
        value = fn(Path(out), quick)
    return value, time.perf_counter() - start, _worker_name()


def run_sections(sections: Sequence[tuple[str, Callable]], out: str | Path, quick: bool,
                 workers: int | None = None, client=None, progress: str | None = None) -> list[SectionRun]:
    """Run independent report sections ``fn(out, quick)`` in parallel; results in the given order.

    Args:
        sections: (name, fn) pairs; each fn(out: Path, quick: bool) returns what the serial loop
            would keep (for ``reproduce``: a (Section, data) pair). They must not depend on each
            other's files. fn must be importable by name (a module-level function).
        out: the report folder (shared: the workers are processes on this machine, or on
            machines that see the same folder).
        quick: passed to every fn.
        workers: LocalCluster worker processes (default: one per core); 0 or 1 runs them
            serially in this process (the reference).
        client: an existing ``distributed.Client`` instead of a new LocalCluster.
        progress: a progress bar on stderr with this description, one step per finished
            section (None: no bar).

    Returns:
        one SectionRun per section, in the order of ``sections``.

    Raises:
        the first (in section order) exception a section raised: serially at once (as the
        serial loop), on workers after the other sections finished.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    bar = tqdm(total=len(sections), desc=progress, unit="run", disable=progress is None, file=sys.stderr)
    if client is None and workers in (0, 1):
        runs = []
        with bar:
            for name, fn in sections:
                value, seconds, worker = _run_section(fn, str(out), quick)
                runs.append(SectionRun(name, value, seconds, worker))
                bar.update()
        return runs
    with Executor(workers=workers, client=client) as ex:
        # Longest first would balance better, but the caller knows the order; the scheduler
        # starts them in submission order as workers free up.
        run_id = uuid.uuid4().hex[:8]  # fresh keys: never an earlier run's result (see _run_on_client)
        futures = [ex.client.submit(_run_section, fn, str(out), quick, key=f"section-{k}-{run_id}", pure=False)
                   for k, (name, fn) in enumerate(sections)]
        from distributed import as_completed  # distributed only when sections run on workers

        with bar:
            for _ in as_completed(futures):
                bar.update()
        runs, first_error = [], None
        for (name, _), future in zip(sections, futures):
            if future.status == "error":
                first_error = first_error or future.exception()
                runs.append(SectionRun(name, None, math.nan, ""))
                continue
            value, seconds, worker = future.result()
            runs.append(SectionRun(name, value, seconds, worker))
    if first_error is not None:
        raise first_error
    return runs
