"""A small report document rendered both as Markdown and as self-contained HTML.

A report is a title and a list of sections; a section holds paragraphs, tables (header +
rows) and figures (PNG files, embedded in the HTML as base64 so the file travels alone).
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field
from pathlib import Path


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
                data = base64.b64encode(block.path.read_bytes()).decode()
                parts.append(f"<figure><img src='data:image/png;base64,{data}'>"
                             f"<figcaption>{esc(block.caption)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(title: str, sections: list[Section], out_dir: Path) -> tuple[Path, Path]:
    """Write ``report.md`` and ``report.html`` into out_dir; returns their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    md = out_dir / "report.md"
    md.write_text(to_markdown(title, sections, out_dir))
    page = out_dir / "report.html"
    page.write_text(to_html(title, sections))
    return md, page
