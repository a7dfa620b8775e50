"""The runs of ``reproduce``: the sections of the registry one after the other (the overall
progress bar weighted by their costs) or side by side on worker processes, the report rewritten
after each, and what an interruption leaves (``run``, the command's entry point).
"""

from __future__ import annotations

import functools
import json
import os
import statistics
import sys
import time
from pathlib import Path

from tqdm import tqdm

from ballchain.infrastructure.errors import UserInputError, caused_by_interrupt, short_repr
from ballchain.infrastructure.input_files import read_input_file
from ballchain.infrastructure.safe_files import TEMP_SUFFIX, check_output_dir
from ballchain.report import Section, section_from_dict, summary_lines, write_report
from ballchain.reproduce import registry
from ballchain.reproduce.cache import (CACHE, MAX_RECORD_BYTES, SECTION_DATA, _cached, _record_problem, _slug,
                                       check_same_folder, code_version, folder_identity, run_section, section_key)
from ballchain.reproduce.common import TITLE, _say
from ballchain.reproduce.registry import ReportSection
from ballchain.sections import run_sections
from ballchain.sweep import MAX_WORKERS_PER_CORE, max_workers  # the one cap on worker processes


def _section_job(name: str, key: str, folder, out: Path, quick: bool) -> tuple[Section, dict]:
    """One section with its cache step, as a task for a worker process (see ``run``)."""
    return run_section(Path(out), name, registry.find(name), quick, key, resume=False, folder=folder)


def _run_parallel(out: Path, chosen: list[ReportSection], quick: bool, code: str, resume: bool, workers: int,
                  folder=None) -> dict:
    """The sections on ``workers`` processes (``ballchain.sections.run_sections``); {name: (section, record)}.

    Each worker runs ``run_section`` (the cache step) for its section, so an interrupted parallel
    run resumes like a serial one. The files a section wrote are found by comparing the folder
    before and after it, so while sections run side by side a record may also list another
    section's files: that can only cause a needless rerun on ``--resume``, never a wrong reuse.
    """
    results, todo = {}, []
    for name in (s.name for s in chosen):
        key = section_key(name, quick, code)
        record = _cached(out, name, key) if resume else None
        if record is not None:
            results[name] = (section_from_dict(record["section"], out), {**record, "reused": True})
        else:
            todo.append((name, functools.partial(_section_job, name, key, folder)))
    _say(f"running {len(todo)} section(s) on {workers} worker processes: {', '.join(n for n, _ in todo)}")
    for run in run_sections(todo, out, quick, workers=workers):
        results[run.name] = run.value
    return results


def _timing_section(summary: dict, total: float, pending: list[str]) -> Section:
    timing = Section("Run time")
    timing.table(["experiment", "seconds", "reused from an earlier run"],
                 [[name, v["seconds"], "yes" if v["reused"] else "no"] for name, v in summary.items()]
                 + [["total (this run)", total, "-"]])
    if pending:
        timing.text(f"Not finished (the run was interrupted): {', '.join(pending)}. "
                    "`ballchain reproduce --resume` with the same --out finishes them.")
    return timing


def _previous_seconds(out: Path, names: list[str], quick: bool) -> dict[str, float]:
    """The sections' run times recorded by the previous run into ``out`` in the same mode (``quick``)."""
    found = {}
    for name in names:
        try:
            record = json.loads(read_input_file(out / CACHE / f"{_slug(name)}.json", "a section record",
                                                MAX_RECORD_BYTES).decode("utf-8", errors="replace"))
        except (OSError, ValueError, RecursionError):  # (UserInputError is a ValueError)
            continue
        if isinstance(record, dict) and record.get("quick") is bool(quick) and _record_problem(record) is None:
            found[name] = float(record["seconds"])
    return found


def section_weights(names: list[str], quick: bool, previous: dict[str, float]) -> dict[str, float]:
    """Each section's expected cost in seconds: the previous run's time, else the registry's
    measured cost (``ReportSection.cost_s``) scaled to this machine by the sections both know (the
    median ratio), else the median cost."""
    costs = {s.name: s.cost_s for s in registry.SECTIONS if s.cost_s is not None}
    table = {n: costs[n][1 if quick else 0] for n in names if n in costs}
    ratios = [previous[n] / table[n] for n in previous if table.get(n, 0.0) > 0]
    scale = statistics.median(ratios) if ratios else 1.0
    weights = {n: previous[n] if n in previous else table[n] * scale if n in table else None for n in names}
    known = [w for w in weights.values() if w is not None]
    fill = statistics.median(known) if known else 1.0
    return {n: max(fill if w is None else w, 1e-3) for n, w in weights.items()}


def _progress_bar(weights: dict[str, float]) -> tqdm:
    """The overall bar: it advances by each section's weight, so its rate (averaged over the whole
    run) and its estimate of the time left are in the sections' measured costs, not their count."""
    return tqdm(total=sum(weights.values()), desc="reproduce", file=sys.stderr, smoothing=0,
                bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed} so far, about {remaining} left{postfix}]")


def _run_serial(out: Path, chosen: list[ReportSection], quick: bool, code: str, resume: bool, weights: dict,
                progress: dict) -> None:
    """The sections one after the other (``run_section``); after each the report is rewritten.

    ``progress`` holds the run's state for ``run``: "done" (sections), "summary" ({name: seconds,
    reused}), "start" and "current" (the section running).
    """
    done, summary = progress["done"], progress["summary"]
    bar = _progress_bar(weights)
    try:
        for experiment in chosen:
            name = experiment.name
            progress["current"] = name
            bar.set_postfix_str(f"now: {name}")
            section, record = run_section(out, name, experiment, quick, section_key(name, quick, code), resume,
                                          folder=progress.get("folder"))
            if record["reused"]:
                _say(f"reused the finished section {name!r} ({record['seconds']:.1f} s in the earlier run)")
                bar.total -= weights[name]  # costs nothing now: out of the estimate
                bar.refresh()
            else:
                bar.update(weights[name])
            done.append(section)
            summary[name] = {"seconds": record["seconds"], "reused": record["reused"]}
            pending = [s.name for s in chosen if s.name not in summary]
            check_same_folder(out, progress.get("folder"), "the report was written")
            write_report(TITLE, done + [_timing_section(summary, time.perf_counter() - progress["start"], pending)],
                         out)
        progress["current"] = None
        bar.set_postfix_str("")
    finally:
        bar.close()


def run(*, out: Path, quick: bool = False, resume: bool = False, sections=None, workers: int = 1) -> dict:
    """Run every experiment (or ``sections``), write the report; returns a summary.

    Each section is an entry of the registry (``registry.SECTIONS``: its name, its function
    ``(out, quick) -> (Section, data)``, its cost, its headlines); the loop runs them one after the
    other through ``run_section`` (its cache step), and after each rewrites the report with the
    sections finished so far.

    Args:
        out: the results folder (checked writable before any work).
        quick: short versions of every experiment.
        resume: reuse the finished sections of an earlier (interrupted) run in ``out``.
        sections: names of the sections to run (default: all).
        workers: 1 runs the sections one after the other in this process; more runs them side by
            side on a Dask LocalCluster of that many processes (same results; the report is written
            once all are done, in the same order).

    Returns:
        {"report_md", "report_html", "experiments" ({name: seconds, reused}), "total_seconds",
        "quick", "code_version", "replaced", "reused", "headlines" (the summary's lines: each
        section's paper-vs-model rows, one line each)}.

    Raises:
        UserInputError: an unwritable ``out`` or an unknown section name.
    """
    out = Path(out)
    # The files the run writes at fixed names (besides its figures' folders): none may be a file this
    # run reads (``safe_files.register_input``).
    check_output_dir(out, "--out", names=("report.md", "report.html", "sizing.json", "field_models.json",
                                          "table1_effects.json",
                                          *(f"{SECTION_DATA}/{_slug(s.name)}.json" for s in registry.SECTIONS)))
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= max_workers():
        raise UserInputError(f"--workers must be an integer in 1..{max_workers()} ({MAX_WORKERS_PER_CORE} per "
                             f"core), got {short_repr(workers)}")
    names = [s.name for s in registry.SECTIONS]
    if sections is not None:
        unknown = [s for s in sections if s not in names]
        if unknown:
            raise UserInputError(f"--sections: unknown section(s) {unknown}; the sections are {', '.join(names)}")
    chosen = [s for s in registry.SECTIONS if sections is None or s.name in sections]
    replaced = _prepare_out(out, resume)
    # Read before a fresh run forgets the previous records: the progress bar's weights.
    chosen_names = [s.name for s in chosen]
    weights = section_weights(chosen_names, quick, _previous_seconds(out, chosen_names, quick))
    if not resume:  # a fresh run: only its own sections may be resumed later
        for name in chosen_names:
            (out / CACHE / f"{_slug(name)}.json").unlink(missing_ok=True)
    code = code_version()
    # The folder this run writes in: it stops when the folder goes (check_same_folder). Held open for
    # the run, so that its inode number cannot be given to a folder made after it was deleted (tmpfs
    # and ext4 hand a freed number out again at once: the new folder would pass for the old one).
    held = os.open(out, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        folder = folder_identity(out)
        progress = {"done": [], "summary": {}, "start": time.perf_counter(), "current": None, "folder": folder}
        done, summary, start = progress["done"], progress["summary"], progress["start"]
        try:
            if workers > 1:
                results = _run_parallel(out, chosen, quick, code, resume, workers, folder)
                for name in chosen_names:
                    section, record = results[name]
                    done.append(section)
                    summary[name] = {"seconds": record["seconds"], "reused": record["reused"]}
                check_same_folder(out, folder, "the report was written")
                write_report(TITLE, done + [_timing_section(summary, time.perf_counter() - start, [])], out)
            else:
                _run_serial(out, chosen, quick, code, resume, weights, progress)
        except BaseException as err:
            if not caused_by_interrupt(err):
                raise
            pending = [n for n in chosen_names if n not in summary]
            if folder_identity(out) != folder:  # gone: a report written now would cite files that are not there
                _say(f"interrupted, and {out} is not the folder the run started in (deleted or replaced): no report "
                     "written")
            else:
                write_report(TITLE, done + [_timing_section(summary, time.perf_counter() - start, pending)], out)
                _say(f"interrupted in {progress['current']!r}; {len(summary)} of {len(chosen)} sections finished and "
                     f"kept; `ballchain reproduce --out {out}{' --quick' if quick else ''} --resume` finishes the rest")
            if isinstance(err, KeyboardInterrupt):
                raise
            raise KeyboardInterrupt from err
    finally:
        os.close(held)
    md, page = out / "report.md", out / "report.html"
    return {"report_md": md, "report_html": page, "experiments": summary,
            "total_seconds": time.perf_counter() - start, "quick": quick, "code_version": code,
            "replaced": replaced if not resume else [],
            "reused": [n for n, v in summary.items() if v["reused"]],
            "headlines": summary_lines(list(zip(summary, done)))}


def _prepare_out(out: Path, resume: bool) -> list[str]:
    """Create ``out``, remove a killed run's temporary files, say what a fresh run replaces; returns
    the names of the files and folders already there."""
    replaced = sorted(p.name + ("/" if p.is_dir() else "") for p in out.iterdir()
                      if p.name != CACHE) if out.is_dir() else []
    out.mkdir(parents=True, exist_ok=True)
    for stale in out.rglob(f"*{TEMP_SUFFIX}"):  # temporary files of a killed run: never results
        stale.unlink(missing_ok=True)
    replaced = [name for name in replaced if not name.endswith(TEMP_SUFFIX)]
    if replaced and not resume:
        shown = ", ".join(replaced[:12]) + (f" and {len(replaced) - 12} more" if len(replaced) > 12 else "")
        _say(f"{out} is not empty ({shown}): the report, the data and the figures this run writes replace "
             "those of the same names; other files are left alone")
    return replaced
