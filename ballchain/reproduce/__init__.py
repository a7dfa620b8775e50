"""Reproduce the paper's checks and write a report beside the paper's numbers (the main job).

The command ``ballchain reproduce`` (``commands/reproduce.py``) is a thin adapter of ``run``; each
section calls its experiments (``ballchain/experiments/``) and lays out their results.

Runs every experiment available in this version, with progress bars (the overall one weighted by
the sections' measured costs), and writes ``OUT/report.md``,
``OUT/report.html`` (self-contained), the figures and the CSV/JSON data. Each section names its
headlines: rows of its own paper-vs-model tables with a verdict (``AGREES_WITHIN``) and why; the
report opens with them as a summary table, and ``run`` returns them as one line each for the
console. ``--quick`` shortens every experiment (for tests and smoke runs).

Nothing is lost on an interruption: every file is written atomically; as each section finishes
its data go to ``OUT/sections/<name>.json``, its report part and the hashes of the files it
wrote to ``OUT/.reproduce/<name>.json``, and the report is rewritten with the sections done so
far. ``--resume`` reuses a finished section when its key (a hash of its name, ``--quick`` and
the code: every source file of the package) matches and its files are unchanged, and runs the
rest. ``--sections`` runs some sections only.

The package: ``registry.py`` (the one table of sections: name, function, cost, headline builder),
the sections by theme (``paper_checks.py``, ``forces.py``, ``navigation.py``, ``lesions.py``),
``cache.py`` (records, keys, ``--resume``), ``runner.py`` (the serial and parallel runs, ``run``)
and ``common.py`` (the title, the verdict rule). The names of the single module it was are
re-exported here.
"""

from __future__ import annotations

from ballchain.reproduce import cache, registry, runner
from ballchain.reproduce.cache import (CACHE, MAX_RECORD_BYTES, SECTION_DATA, check_same_folder, code_version,
                                       folder_identity, run_section, section_key)
from ballchain.reproduce.common import AGREES_WITHIN, TITLE
from ballchain.reproduce.registry import SECTIONS, ReportSection, find
from ballchain.reproduce.runner import run, section_weights

# Private names the tests reach (their homes: cache, navigation, runner).
from ballchain.reproduce.cache import _cached, _record_problem  # noqa: F401, E402
from ballchain.reproduce.navigation import _manual_headlines  # noqa: F401, E402
from ballchain.reproduce.runner import _previous_seconds  # noqa: F401, E402

# The names of the single module this package was. Each ``*_section`` is the registry's entry: called
# as ``(out, quick)`` it runs the whole section, its headlines included, as the function of that name did.
alignment_section = find("alignment")
sizing_section = find("sizing")
field_models_section = find("field models")
workspace_section = find("workspace")
validation_section = find("model validation")
forces_section = find("tip forces")
clinical_section = find("Table I effects and clinical design")
plan_section = find("model-based steering")
teleop_section = find("teleoperation")
manual_section = find("robotic vs manual")
ablation_section = find("ablation")
procedure_section = find("ablation procedure")
EXPERIMENTS = [(s.name, s) for s in SECTIONS]
"""(name, section) of every section, in report order: a view of ``SECTIONS`` (``run`` reads the registry)."""
SECTION_COST_S = {s.name: s.cost_s for s in SECTIONS if s.cost_s is not None}
"""{name: (full, quick) seconds}: a view of ``SECTIONS``' costs (``ReportSection.cost_s``)."""

__all__ = [
    "AGREES_WITHIN", "CACHE", "EXPERIMENTS", "MAX_RECORD_BYTES", "ReportSection", "SECTIONS", "SECTION_COST_S",
    "SECTION_DATA", "TITLE", "ablation_section", "alignment_section", "cache", "check_same_folder", "clinical_section",
    "code_version", "field_models_section", "find", "folder_identity", "forces_section", "manual_section",
    "plan_section", "procedure_section", "registry", "run", "run_section", "runner", "section_key", "section_weights",
    "sizing_section", "teleop_section", "validation_section", "workspace_section",
]
