"""A small report document rendered both as Markdown and as self-contained HTML.

A report is a title and a list of sections; a section holds paragraphs, tables (header +
rows) and figures (PNG files, embedded in the HTML as base64 so the file travels alone), and
its headlines: the rows that compare the paper with the model in one line each. The report opens
with a summary table of every section's headlines and a table of contents; a results file a
paragraph or a cell names (``replays/x.html``, ``teleop_seeds/teleop_seeds.csv``, a ``.json``)
becomes a relative link when it exists, so the links work in the Markdown and in the HTML beside
it. Both files are written atomically (a killed run leaves the previous report or the new one,
never half of one). A section round-trips through JSON (``section_to_dict`` /
``section_from_dict``), so a finished section can be stored and reused by
``ballchain reproduce --resume``.

Numbers are printed with 4 significant digits, except that a value below 1e-9 of the largest
in its table column (or below 1e-12 absolute) is floating-point round-off and prints as 0 (an
angle error of 1e-14 deg is an exact zero computed in floating point), and that a table may give
a column's resolution (the quantity's precision), to which its values are rounded.
"""

from __future__ import annotations

import base64
import html
import math
import numbers
import re
from dataclasses import dataclass, field
from pathlib import Path

from ballchain.infrastructure.safe_files import atomic_write_text

NOISE_RELATIVE = 1e-9
"""A value below this fraction of its column's largest magnitude is round-off: printed as 0."""
NOISE_ABSOLUTE = 1e-12
"""A value below this magnitude (in the column's unit) is round-off: printed as 0."""
SIGNIFICANT_DIGITS = 4


@dataclass
class Table:
    header: list[str]
    rows: list[list]
    caption: str = ""
    resolution: dict[int, float] = field(default_factory=dict)  # column index -> the quantity's precision


@dataclass
class Figure:
    path: Path
    caption: str = ""


@dataclass
class Headline:
    """One paper-vs-model row of a section, for the report's summary and the console.

    ``paper`` and ``model`` are the values of a row of one of the section's tables; ``agrees``
    is the section's verdict (None: nothing of the paper's to compare with); ``why`` says in a
    clause why they agree or differ.
    """

    result: str
    paper: object
    model: object
    agrees: bool | None
    why: str = ""

    def difference(self) -> str:
        """The model's relative difference from the paper, as text ("" when not two numbers)."""
        p, m = self.paper, self.model
        if isinstance(p, bool) or isinstance(m, bool) or not isinstance(p, (int, float)) \
                or not isinstance(m, (int, float)) or p == 0 or not math.isfinite(p) or not math.isfinite(m):
            return ""
        return f"{100.0 * (m - p) / p:+.2g} %"

    def verdict(self) -> str:
        return {True: "agrees", False: "disagrees", None: "-"}[self.agrees]


@dataclass
class Section:
    title: str
    blocks: list = field(default_factory=list)  # str (paragraph) | Table | Figure
    headlines: list[Headline] = field(default_factory=list)

    def text(self, paragraph: str) -> "Section":
        self.blocks.append(paragraph)
        return self

    def table(self, header, rows, caption: str = "", resolution: dict[int, float] | None = None) -> "Section":
        self.blocks.append(Table(list(header), [list(r) for r in rows], caption, dict(resolution or {})))
        return self

    def figure(self, path, caption: str = "") -> "Section":
        self.blocks.append(Figure(Path(path), caption))
        return self

    def headline(self, result: str, paper, model, agrees: bool | None, why: str = "") -> "Section":
        """Add a paper-vs-model row (values taken from one of the section's tables) to the summary."""
        self.headlines.append(Headline(result, paper, model, agrees, why))
        return self


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def column_scales(rows: list[list]) -> list[float]:
    """The largest finite magnitude of each column's numbers (0 for a column without any)."""
    scales: list[float] = []
    for row in rows:
        scales += [0.0] * (len(row) - len(scales))
        for i, value in enumerate(row):
            if _is_number(value) and math.isfinite(value):
                scales[i] = max(scales[i], abs(float(value)))
    return scales


def format_number(value, scale: float = 0.0, resolution: float | None = None) -> str:
    """A table cell as text: round-off as 0, floats to their resolution or 4 significant digits.

    Args:
        value: the cell (None prints as "-", booleans as yes/no; text and integers as they are).
        scale: the largest magnitude in the value's column: what round-off is relative to.
        resolution: the quantity's precision, in its unit (e.g. 0.01 for a percentage known to
            a hundredth); None: 4 significant digits.
    """
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if not isinstance(value, float) or not math.isfinite(value):
        return str(value)
    if abs(value) < max(NOISE_ABSOLUTE, NOISE_RELATIVE * scale):
        return "0"
    if resolution:
        decimals = max(0, -math.floor(math.log10(resolution) + 1e-9))
        text = f"{round(value / resolution) * resolution:.{decimals}f}"
        return "0" if float(text) == 0.0 else text
    if abs(value) >= 10 ** SIGNIFICANT_DIGITS:
        return f"{value:.0f}"  # no exponent for a whole number of this size
    return f"{value:.{SIGNIFICANT_DIGITS}g}"


def _formatted_rows(table: Table) -> list[list[str]]:
    scales = column_scales(table.rows)
    return [[format_number(v, scales[i] if i < len(scales) else 0.0, table.resolution.get(i))
             for i, v in enumerate(row)] for row in table.rows]


# A code span, or a results file named bare (a relative path ending in .html, .csv or .json).
_INLINE = re.compile(r"`([^`]+)`|(?<![\w./-])((?:[\w-][\w.-]*/)*[\w-][\w.-]*\.(?:html|csv|json))(?![\w/])")
_RESULTS_FILE = re.compile(r"(?:[\w-][\w.-]*/)*[\w-][\w.-]*\.(?:html|csv|json)")


def _linkable(path: str, out_dir: Path | None) -> bool:
    """Whether ``path`` names a results file in ``out_dir`` (then the report links it, relatively)."""
    return (out_dir is not None and _RESULTS_FILE.fullmatch(path) is not None and ".." not in path.split("/")
            and (Path(out_dir) / path).is_file())


def _inline(text: str, out_dir: Path | None, markdown: bool) -> str:
    """A paragraph or a cell with its results files linked (and its code spans as <code> in HTML)."""
    plain = (lambda s: s) if markdown else html.escape
    pieces, pos = [], 0
    for match in _INLINE.finditer(text):
        code, path = match.group(1), match.group(2)
        target = code if code is not None else path
        if markdown:
            shown = match.group(0)
            piece = f"[{shown}]({target})" if _linkable(target, out_dir) else shown
        else:
            shown = f"<code>{html.escape(target)}</code>" if code is not None else html.escape(target)
            piece = f'<a href="{html.escape(target)}">{shown}</a>' if _linkable(target, out_dir) else shown
        pieces += [plain(text[pos:match.start()]), piece]
        pos = match.end()
    pieces.append(plain(text[pos:]))
    return "".join(pieces)


def anchors(sections: list[Section]) -> list[str]:
    """Each section's anchor: its title as GitHub slugs a heading (so Markdown viewers find it too)."""
    seen: dict[str, int] = {}
    out = []
    for section in sections:
        slug = re.sub(r"[^\w\- ]", "", section.title.lower()).replace(" ", "-")
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        out.append(slug if count == 0 else f"{slug}-{count}")
    return out


def _summary_rows(sections: list[Section], names: list[str]) -> list[list[str]]:
    """The summary table's rows (text): one per headline; ``names`` are the sections' anchors."""
    rows = []
    for section, anchor in zip(sections, names):
        for i, h in enumerate(section.headlines):
            diff = h.difference()
            model = format_number(h.model) + (f" ({diff})" if diff else "")
            link = f"[{section.title}](#{anchor})" if i == 0 else ""  # the section once, on its first row
            rows.append([link, h.result, format_number(h.paper), model, h.verdict(), h.why])
    return rows


SUMMARY_HEADER = ["section", "headline result", "paper", "model (vs paper)", "agrees?", "why"]


def summary_lines(named_sections) -> list[str]:
    """The console's summary: one line per headline, ``(name, section)`` pairs in report order."""
    lines = []
    for name, section in named_sections:
        for h in section.headlines:
            diff = h.difference()
            values = f"paper {format_number(h.paper)}, model {format_number(h.model)}" + (f" ({diff})" if diff else "")
            lines.append(f"{h.verdict():<9}  {name}: {h.result}: {values}" + (f"; {h.why}" if h.why else ""))
    return lines


def _table_md(header: list[str], rows: list[list[str]]) -> list[str]:
    return (["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
            + ["| " + " | ".join(row) + " |" for row in rows] + [""])


def to_markdown(title: str, sections: list[Section], out_dir: Path) -> str:
    """The report as Markdown: title, summary, contents, then the sections."""
    names = anchors(sections)
    lines = [f"# {title}", ""]
    summary = _summary_rows(sections, names)
    if summary:
        lines += ["## Summary", ""] + _table_md(SUMMARY_HEADER, summary)
    lines += ["## Contents", ""] + [f"- [{s.title}](#{a})" for s, a in zip(sections, names)] + [""]
    for section in sections:
        lines += [f"## {section.title}", ""]
        for block in section.blocks:
            if isinstance(block, str):
                lines += [_inline(block, out_dir, True), ""]
            elif isinstance(block, Table):
                if block.caption:
                    lines += [f"*{block.caption}*", ""]
                lines += _table_md(block.header, [[_inline(c, out_dir, True) for c in row]
                                                  for row in _formatted_rows(block)])
            elif isinstance(block, Figure):
                rel = block.path.relative_to(out_dir) if block.path.is_relative_to(out_dir) else block.path
                lines += [f"![{block.caption}]({rel.as_posix()})", ""]
                if block.caption:
                    lines += [f"*{block.caption}*", ""]
    return "\n".join(lines)


_STYLE = ("<style>body{font-family:sans-serif;max-width:60em;margin:2em auto;line-height:1.4}"
          "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:.2em .5em;"
          "text-align:right}th{background:#eee}img{max-width:100%}figcaption,caption{color:#555}"
          ".text,table.summary td,table.summary th{text-align:left}"
          "table.summary td:nth-child(3),table.summary td:nth-child(4),"
          "table.summary td:nth-child(5){white-space:nowrap}"
          "td.agrees{background:#e3f4e1}td.disagrees{background:#fbe3e0}"
          "code{background:#f3f3f3;padding:0 .2em}</style>")


def _md_link_to_html(cell: str) -> str:
    """A summary cell "[title](#anchor)" as an HTML link."""
    match = re.fullmatch(r"\[(.*)\]\((#[\w-]*)\)", cell)
    return f'<a href="{match.group(2)}">{html.escape(match.group(1))}</a>' if match else html.escape(cell)


def _summary_html(sections: list[Section], names: list[str]) -> list[str]:
    summary = _summary_rows(sections, names)
    if not summary:
        return []
    parts = ["<h2 id='summary'>Summary</h2><table class='summary'>",
             "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in SUMMARY_HEADER) + "</tr>"]
    for row in summary:
        cells = [_md_link_to_html(row[0])] + [html.escape(c) for c in row[1:]]
        verdict = row[4] if row[4] in ("agrees", "disagrees") else ""
        parts.append("<tr>" + "".join(f"<td class='{verdict}'>{c}</td>" if i == 4 else f"<td>{c}</td>"
                                      for i, c in enumerate(cells)) + "</tr>")
    return parts + ["</table>"]


def _block_html(block, out_dir: Path | None) -> str:
    esc = html.escape
    if isinstance(block, str):
        return f"<p>{_inline(block, out_dir, False)}</p>"
    if isinstance(block, Table):
        parts = ["<table>"] + ([f"<caption>{esc(block.caption)}</caption>"] if block.caption else [])
        numeric = [any(_is_number(r[i]) for r in block.rows if i < len(r)) for i in range(len(block.header))]
        parts.append("<tr>" + "".join(f"<th>{esc(h)}</th>" if numeric[i] else f"<th class='text'>{esc(h)}</th>"
                                      for i, h in enumerate(block.header)) + "</tr>")
        for values, row in zip(block.rows, _formatted_rows(block)):  # numbers to the right, text to the left
            right = [_is_number(v) or (v in (None, "-") and i < len(numeric) and numeric[i])  # "-": as its column
                     for i, v in enumerate(values)]
            parts.append("<tr>" + "".join(f"<td>{_inline(c, out_dir, False)}</td>" if r
                                          else f"<td class='text'>{_inline(c, out_dir, False)}</td>"
                                          for r, c in zip(right, row)) + "</tr>")
        return "\n".join(parts + ["</table>"])
    path = block.path if block.path.is_absolute() or out_dir is None else Path(out_dir) / block.path
    if not path.exists():  # say so instead of failing the whole report
        return f"<p><em>figure missing: {esc(str(block.path))}</em></p>"
    data = base64.b64encode(path.read_bytes()).decode()
    return (f"<figure><img src='data:image/png;base64,{data}'>"
            f"<figcaption>{esc(block.caption)}</figcaption></figure>")


def to_html(title: str, sections: list[Section], out_dir: Path | None = None) -> str:
    """The report as one HTML page (figures embedded); files are linked relative to ``out_dir``."""
    esc = html.escape
    names = anchors(sections)
    parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'>", f"<title>{esc(title)}</title>", _STYLE,
             f"</head><body><h1>{esc(title)}</h1>"]
    parts += _summary_html(sections, names)
    parts.append("<h2 id='contents'>Contents</h2><ul>"
                 + "".join(f"<li><a href='#{a}'>{esc(s.title)}</a></li>" for s, a in zip(sections, names)) + "</ul>")
    for section, anchor in zip(sections, names):
        parts.append(f"<h2 id='{anchor}'>{esc(section.title)}</h2>")
        parts += [_block_html(block, out_dir) for block in section.blocks]
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(title: str, sections: list[Section], out_dir: Path) -> tuple[Path, Path]:
    """Write ``report.md`` and ``report.html`` into out_dir atomically; returns their paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    md = atomic_write_text(out_dir / "report.md", to_markdown(title, sections, out_dir))
    page = atomic_write_text(out_dir / "report.html", to_html(title, sections, out_dir))
    return md, page


def _plain(value):
    """A table cell as plain JSON (numpy scalars to Python; NaN and inf to None)."""
    if hasattr(value, "item") and not isinstance(value, (list, tuple, dict)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value if value is None or isinstance(value, (bool, int, float, str)) else str(value)


def section_to_dict(section: Section, out_dir: Path) -> dict:
    """A JSON-ready form of a section; figure paths are stored relative to ``out_dir``."""
    blocks = []
    for block in section.blocks:
        if isinstance(block, str):
            blocks.append({"text": block})
        elif isinstance(block, Table):
            blocks.append({"table": {"header": [str(h) for h in block.header],
                                     "rows": [[_plain(v) for v in row] for row in block.rows],
                                     "caption": block.caption,
                                     "resolution": {str(i): r for i, r in block.resolution.items()}}})
        elif isinstance(block, Figure):
            path = block.path
            rel = path.relative_to(out_dir) if path.is_relative_to(out_dir) else path
            blocks.append({"figure": {"path": rel.as_posix(), "caption": block.caption}})
    headlines = [{"result": h.result, "paper": _plain(h.paper), "model": _plain(h.model), "agrees": h.agrees,
                  "why": h.why} for h in section.headlines]
    return {"title": section.title, "blocks": blocks, "headlines": headlines}


def section_from_dict(data: dict, out_dir: Path) -> Section:
    """The inverse of ``section_to_dict`` (relative figure paths resolved against ``out_dir``)."""
    section = Section(data["title"])
    for block in data["blocks"]:
        if "text" in block:
            section.text(block["text"])
        elif "table" in block:
            t = block["table"]
            section.table(t["header"], t["rows"], t.get("caption", ""),
                          {int(i): float(r) for i, r in (t.get("resolution") or {}).items()})
        elif "figure" in block:
            f = block["figure"]
            path = Path(f["path"])
            section.figure(path if path.is_absolute() else Path(out_dir) / path, f.get("caption", ""))
    for h in data.get("headlines") or []:
        section.headline(h["result"], h.get("paper"), h.get("model"), h.get("agrees"), h.get("why", ""))
    return section
