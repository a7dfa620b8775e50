"""The sensorless force estimate under mismatch as a report section (issue 43; beyond the paper).

The sensitivity table (``experiments/world_sensitivity.py``: the autonomous navigator in a world it
does not know, each perturbation alone at its published magnitude and all together) costs far more
than the rest of the report (tens of CPU minutes), so ``reproduce`` does not run it: the section
reads the JSON that ``ballchain sensitivity --out OUT/sensitivity`` wrote under the report's folder
(``SENSITIVITY_FILE``) and lays it out, or says in one line how to make it. Its cost in the report
is that of reading a file.

``--resume`` reuses this section as it was when the code is unchanged: after a new
``ballchain sensitivity`` run, rerun the report without ``--resume`` (or give
``--sections "world sensitivity"``).
"""

from __future__ import annotations

import json
from pathlib import Path

from ballchain.infrastructure.errors import UserInputError
from ballchain.infrastructure.input_files import read_input_file
from ballchain.report import Section

SENSITIVITY_FILE = Path("sensitivity") / "sensitivity.json"  # under the report's folder
MAX_BYTES = 50_000_000  # a sensitivity JSON with every run's dwells: a few MB at most
HEADER = ["ring", "condition", "magnitude", "reached", "mean abs error [gf]", "mean error [gf]", "worst [gf]",
          "dwell in window", "dwells worse than TactiCath", "runs stopped"]
ROW_KEYS = ("ring", "condition", "reached", "targets", "estimate_mean_abs_error_gf")
TITLE = "The sensorless force estimate under mismatch (beyond the paper; issue 43)"


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.0f}%"


def _num(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def read_sensitivity(path: Path) -> dict:
    """The sensitivity result at ``path`` (``SensitivityResult.to_dict``), checked for what the
    table needs: ``rows`` (each with ``ROW_KEYS``) and ``settings``.

    Raises:
        UserInputError: the file cannot be read or is not a sensitivity result.
    """
    raw = read_input_file(path, "the report's sensitivity file", MAX_BYTES, "a sensitivity JSON")
    try:
        data = json.loads(raw)
    except (ValueError, UnicodeDecodeError) as err:
        raise UserInputError(f"the report's sensitivity file {path} is not JSON ({err})") from None
    rows = data.get("rows") if isinstance(data, dict) else None
    if not isinstance(rows, list) or not isinstance(data.get("settings"), dict) \
            or not all(isinstance(r, dict) and all(k in r for k in ROW_KEYS) for r in rows):
        raise UserInputError(f"the report's sensitivity file {path} is not the JSON of `ballchain sensitivity`: it "
                             f"needs 'rows' (each with {', '.join(ROW_KEYS)}) and 'settings'")
    return data


def sensitivity_section(out: Path, quick: bool) -> tuple[Section, dict]:
    """The sensitivity table of ``OUT/sensitivity/sensitivity.json`` when there is one, else the
    one line that says how to make it (``quick`` changes nothing: nothing is run)."""
    section = Section(TITLE)
    path = Path(out) / SENSITIVITY_FILE
    make = (f"`ballchain sensitivity --ring both --seeds 3 --targets 6 --dwell 5 --out {path.parent}` "
            "(about half an hour of CPU time) writes it, and the next `ballchain reproduce` into this folder shows it "
            "(docs/guide/world.md).")
    if not path.exists():
        section.text(f"Not run by `reproduce` (its cost): {make}")
        return section, {"source": None, "rows": [], "settings": {}}
    try:
        data = read_sensitivity(path)
    except UserInputError as err:
        section.text(f"Could not read {SENSITIVITY_FILE.as_posix()}: {err}. {make}")
        return section, {"source": None, "rows": [], "settings": {}, "problem": str(err)}
    s = data["settings"]
    section.text(
        f"Read from `{SENSITIVITY_FILE.as_posix()}` (`ballchain sensitivity`, not rerun here): the procedure's autonomous "
        "navigator in a world it does not know (docs/guide/world.md: the perturbations, their published magnitudes "
        f"and sources), seeds {s.get('seeds', '?')}, the first {s.get('targets', '?')} targets of each ring, "
        f"{s.get('dwell_s', '?')} s dwells; {s.get('cpu_time_s', '?')} CPU s. Each row pools its seeds' dwells; "
        "TactiCath's mean absolute error is 1.29 gf (Kueffer et al., Europace 2022).")
    section.table(HEADER, [[r["ring"], r["condition"], r.get("magnitude") or "", f"{r['reached']}/{r['targets']}",
                            _num(r["estimate_mean_abs_error_gf"]), _num(r.get("estimate_mean_error_gf")),
                            _num(r.get("estimate_worst_error_gf")), _pct(r.get("in_window_fraction")),
                            _pct(r.get("worse_than_tacticath")), r.get("failures", "-")] for r in data["rows"]])
    return section, {"source": SENSITIVITY_FILE.as_posix(), "rows": data["rows"], "settings": s}


def sensitivity_headlines(section: Section, data: dict) -> None:
    """Per ring (no paper value): the perfect world's error and reach against all perturbations
    together, and the single perturbation that reaches the fewest targets."""
    rows = data.get("rows") or []
    for ring in dict.fromkeys(r["ring"] for r in rows):
        by = {r["condition"]: r for r in rows if r["ring"] == ring}
        alone = [r for c, r in by.items() if c not in ("none", "all") and not c.startswith("all x")]
        parts = [f"{c}: {by[c]['reached']}/{by[c]['targets']} reached, {_num(by[c]['estimate_mean_abs_error_gf'])} gf"
                 for c in ("none", "all") if c in by]
        worst = min(alone, key=lambda r: r["reached"] / max(r["targets"], 1), default=None)
        why = "" if worst is None else (f"alone, {worst['condition']} reaches the fewest targets "
                                        f"({worst['reached']}/{worst['targets']})")
        section.headline(f"{ring} ring: the sensorless force estimate in a world it does not know "
                         "(mean abs error over the dwells)", None, "; ".join(parts) or "-", None, why)
