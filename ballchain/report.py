"""A small report document rendered both as Markdown and as self-contained HTML.

A report is a title and a list of sections; a section holds paragraphs, tables (header +
rows) and figures (PNG files, embedded in the HTML as base64 so the file travels alone). Both
files are written atomically (a killed run leaves the previous report or the new one, never half
of one). A section round-trips through JSON (``section_to_dict`` / ``section_from_dict``), so a
finished section can be stored and reused by ``ballchain reproduce --resume``.
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field
from pathlib import Path

from ballchain.drake_models.safe_files import atomic_write_text


@dataclass
class Table:
    header: list[str]
    rows: list[list]
    caption: str = ""


@dataclass
class Figure:
    path: Path
    caption: str = ""


@dataclass
class Section:
    title: str
    blocks: list = field(default_factory=list)  # str (paragraph) | Table | Figure

    def text(self, paragraph: str) -> "Section":
        self.blocks.append(paragraph)
        return self

    def table(self, header, rows, caption: str = "") -> "Section":
        self.blocks.append(Table(list(header), [list(r) for r in rows], caption))
        return self

    def figure(self, path, caption: str = "") -> "Section":
        self.blocks.append(Figure(Path(path), caption))
        return self


def _cell(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def to_markdown(title: str, sections: list[Section], out_dir: Path) -> str:
    lines = [f"# {title}", ""]
    for section in sections:
        lines += [f"## {section.title}", ""]
        for block in section.blocks:
            if isinstance(block, str):
                lines += [block, ""]
            elif isinstance(block, Table):
                if block.caption:
                    lines += [f"*{block.caption}*", ""]
                lines.append("| " + " | ".join(block.header) + " |")
                lines.append("|" + "---|" * len(block.header))
                lines += ["| " + " | ".join(_cell(v) for v in row) + " |" for row in block.rows]
                lines.append("")
            elif isinstance(block, Figure):
                rel = block.path.relative_to(out_dir) if block.path.is_relative_to(out_dir) else block.path
                lines += [f"![{block.caption}]({rel})", ""]
                if block.caption:
                    lines += [f"*{block.caption}*", ""]
    return "\n".join(lines)


def to_html(title: str, sections: list[Section]) -> str:
    esc = html.escape
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>{esc(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:60em;margin:2em auto;line-height:1.4}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:.2em .5em;"
        "text-align:right}th{background:#eee}img{max-width:100%}figcaption,caption{color:#555}</style>",
        f"</head><body><h1>{esc(title)}</h1>",
    ]
    for section in sections:
        parts.append(f"<h2>{esc(section.title)}</h2>")
        for block in section.blocks:
            if isinstance(block, str):
                parts.append(f"<p>{esc(block)}</p>")
            elif isinstance(block, Table):
                parts.append("<table>")
                if block.caption:
                    parts.append(f"<caption>{esc(block.caption)}</caption>")
                parts.append("<tr>" + "".join(f"<th>{esc(h)}</th>" for h in block.header) + "</tr>")
                for row in block.rows:
                    parts.append("<tr>" + "".join(f"<td>{esc(_cell(v))}</td>" for v in row) + "</tr>")
                parts.append("</table>")
            elif isinstance(block, Figure):
                if not block.path.exists():  # say so instead of failing the whole report
                    parts.append(f"<p><em>figure missing: {esc(str(block.path))}</em></p>")
                    continue
                data = base64.b64encode(block.path.read_bytes()).decode()
                parts.append(f"<figure><img src='data:image/png;base64,{data}'>"
                             f"<figcaption>{esc(block.caption)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(title: str, sections: list[Section], out_dir: Path) -> tuple[Path, Path]:
    """Write ``report.md`` and ``report.html`` into out_dir atomically; returns their paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    md = atomic_write_text(out_dir / "report.md", to_markdown(title, sections, out_dir))
    page = atomic_write_text(out_dir / "report.html", to_html(title, sections))
    return md, page


def _plain(value):
    """A table cell as plain JSON (numpy scalars to Python; NaN and inf to None)."""
    import math

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
                                     "caption": block.caption}})
        elif isinstance(block, Figure):
            path = block.path
            rel = path.relative_to(out_dir) if path.is_relative_to(out_dir) else path
            blocks.append({"figure": {"path": rel.as_posix(), "caption": block.caption}})
    return {"title": section.title, "blocks": blocks}


def section_from_dict(data: dict, out_dir: Path) -> Section:
    """The inverse of ``section_to_dict`` (relative figure paths resolved against ``out_dir``)."""
    section = Section(data["title"])
    for block in data["blocks"]:
        if "text" in block:
            section.text(block["text"])
        elif "table" in block:
            t = block["table"]
            section.table(t["header"], t["rows"], t.get("caption", ""))
        elif "figure" in block:
            f = block["figure"]
            path = Path(f["path"])
            section.figure(path if path.is_absolute() else Path(out_dir) / path, f.get("caption", ""))
    return section
