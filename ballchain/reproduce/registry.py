"""The report's sections, in report order: the one table ``reproduce`` runs from.

Each entry names a section, the function that runs its experiments and lays out its results
(``(out, quick) -> (Section, data)``), its measured cost (the overall progress bar's weight) and
its headline builder (``(section, data)``: the section's paper-vs-model rows for the summary). A
new section is a function and a headline builder in the module of its theme, and one entry here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ballchain.report import Section
from ballchain.reproduce.forces import clinical_headlines, clinical_section, forces_headlines, forces_section
from ballchain.reproduce.lesions import ablation_headlines, ablation_section, procedure_headlines, procedure_section
from ballchain.reproduce.navigation import (manual_headlines, manual_section, plan_headlines, plan_section,
                                            teleop_headlines, teleop_section)
from ballchain.reproduce.paper_checks import (alignment_headlines, alignment_section, field_models_headlines,
                                              field_models_section, sizing_headlines, sizing_section,
                                              validation_headlines, validation_section, workspace_headlines,
                                              workspace_section)
from ballchain.reproduce.sensitivity import sensitivity_headlines, sensitivity_section


@dataclass(frozen=True)
class ReportSection:
    """One section of the report.

    Attributes:
        name: the section's name (``--sections``, the cache's file names).
        function: ``(out: Path, quick: bool) -> (Section, data)``: runs the section's experiments,
            writes its files under ``out`` and lays out its results.
        cost_s: (wall seconds of a full run, of a --quick run), measured once (see ``SECTIONS``);
            None: unknown (the progress bar weighs it as the median section).
        headlines: ``(section, data) -> None``: adds the section's paper-vs-model rows to the
            summary (``Section.headline``); None: none.

    Calling the entry runs the function, then the headline builder: the whole section.
    """

    name: str
    function: Callable[[Path, bool], tuple[Section, Any]]
    cost_s: tuple[float, float] | None = None
    headlines: Callable[[Section, Any], None] | None = None

    def __call__(self, out: Path, quick: bool) -> tuple[Section, Any]:
        section, data = self.function(out, quick)
        if self.headlines is not None:
            self.headlines(section, data)
        return section, data


SECTIONS: tuple[ReportSection, ...] = (
    ReportSection("alignment", alignment_section, (80.0, 15.5), alignment_headlines),
    ReportSection("sizing", sizing_section, (1.2, 2.8), sizing_headlines),
    ReportSection("field models", field_models_section, (3.8, 0.3), field_models_headlines),
    ReportSection("workspace", workspace_section, (7.0, 6.7), workspace_headlines),
    ReportSection("model validation", validation_section, (17.3, 14.2), validation_headlines),
    ReportSection("tip forces", forces_section, (219.0, 41.8), forces_headlines),
    ReportSection("Table I effects and clinical design", clinical_section, (64.3, 57.9), clinical_headlines),
    ReportSection("model-based steering", plan_section, (171.0, 59.0), plan_headlines),
    ReportSection("teleoperation", teleop_section, (655.0, 148.1), teleop_headlines),
    # The comparison alone, CPU seconds (measured separately).
    ReportSection("robotic vs manual", manual_section, (133.0, 8.8), manual_headlines),
    ReportSection("ablation", ablation_section, (76.6, 56.5), ablation_headlines),
    # Alone, 2 worker processes (load 2; quick: load 7-9, before issue 22).
    ReportSection("ablation procedure", procedure_section, (370.0, 290.6), procedure_headlines),
    # Reads OUT/sensitivity/sensitivity.json (``ballchain sensitivity --out``) if any: runs nothing.
    ReportSection("world sensitivity", sensitivity_section, (0.1, 0.1), sensitivity_headlines),
)
"""The sections in report order. Their costs were measured once: the wall time of a full run
(21.6 min) and of a --quick run (6.7 min), each ``ballchain reproduce`` in a new process (the first
section pays for the imports and the compiled kernels) on a 2-core machine under load. Only the
ratios matter: they weight the overall progress bar, so that its estimate of the time left counts
a teleoperation section as about eight alignment sections rather than one. The times of the
previous run into the same folder, when its records say them, replace these (scaled to this
machine)."""


def find(name: str) -> ReportSection:
    """The entry of ``SECTIONS`` named ``name`` (a KeyError when there is none: the caller checked)."""
    for entry in SECTIONS:
        if entry.name == name:
            return entry
    raise KeyError(name)
