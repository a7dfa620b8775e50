"""The cache step of ``reproduce``: each finished section's record, its key, and ``--resume``.

As each section finishes its data go to ``OUT/sections/<name>.json``, its report part and the
hashes of the files it wrote to ``OUT/.reproduce/<name>.json``. ``--resume`` reuses a finished
section when its key (a hash of its name, ``--quick`` and the code: every source file of the
package) matches and its files are unchanged. The run stops when its results folder is no longer
the one it started in (``check_same_folder``).
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import math
import os
import stat
import time
from pathlib import Path

from ballchain.infrastructure.errors import OutputError, UserInputError, short_repr, quote_path
from ballchain.infrastructure.input_files import read_input_file
from ballchain.infrastructure.safe_files import TEMP_SUFFIX, atomic_write_text, to_jsonable, write_json
from ballchain.report import Section, section_from_dict, section_to_dict
from ballchain.reproduce.common import _say

CACHE = ".reproduce"  # OUT/.reproduce/<section>.json: finished sections, for --resume
MAX_RECORD_BYTES = 10_000_000  # a section record is a few kB (its report part and its files' hashes)
SECTION_DATA = "sections"  # OUT/sections/<section>.json: each section's data


SOURCE_PACKAGES = ("ballchain", "ballchain.drake_models", "ballchain.optimization", "ballchain.systems",
                   "ballchain.infrastructure")  # each a top-level folder (pyproject's package-dir)


def code_version() -> str:
    """A hash of every source file of the package (and its YAML), sub-packages included (the
    kernels, the reproduce and sweep packages, the infrastructure): the code's version.

    A content hash, not a commit id, so that uncommitted edits count as another version.
    """
    digest = hashlib.sha256()
    for name in SOURCE_PACKAGES:
        (root,) = importlib.util.find_spec(name).submodule_search_locations  # found, not imported
        root = Path(root)
        for path in sorted([*root.rglob("*.py"), *root.rglob("*.yaml")]):
            digest.update(f"{name}/{path.relative_to(root).as_posix()}".encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def section_key(name: str, quick: bool, code: str) -> str:
    """The cache key of a section: its name, its inputs (``quick``) and the code version."""
    return hashlib.sha256(json.dumps({"section": name, "quick": quick, "code": code}).encode()).hexdigest()[:16]


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name)


def _file_hash(path: Path) -> str:
    with open(path, "rb") as f:  # streamed: a result file of any size costs no memory
        return hashlib.file_digest(f, "sha256").hexdigest()


def _snapshot(out: Path) -> dict[str, tuple[int, int]]:
    """{relative path: (mtime_ns, size)} of the files under ``out`` (cache folder excluded)."""
    files = {}
    for path in out.rglob("*"):
        if path.is_file() and CACHE not in path.relative_to(out).parts and not path.name.endswith(TEMP_SUFFIX):
            st = path.stat()
            files[path.relative_to(out).as_posix()] = (st.st_mtime_ns, st.st_size)
    return files


def _record_problem(record) -> str | None:
    """What is wrong with the shape of a stored section record (parsed JSON), or None."""
    if not isinstance(record, dict):
        return f"a JSON {type(record).__name__}, not an object"
    missing = [k for k in ("key", "seconds", "files", "section") if k not in record]
    if missing:
        return f"no {', '.join(repr(k) for k in missing)}"
    seconds, files, section = record["seconds"], record["files"], record["section"]
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not math.isfinite(seconds):
        return "'seconds' is not a finite number"
    if not isinstance(files, dict) or not all(isinstance(v, str) for v in files.values()):
        return "'files' is not an object of file hashes"
    if not isinstance(section, dict) or not isinstance(section.get("title"), str) \
            or not isinstance(section.get("blocks"), list):
        return "'section' has no title or blocks"
    for block in section["blocks"]:
        ok = isinstance(block, dict) and (
            isinstance(block.get("text"), str)
            or (isinstance(block.get("table"), dict) and isinstance(block["table"].get("header"), list)
                and isinstance(block["table"].get("rows"), list)
                and all(isinstance(r, list) for r in block["table"]["rows"]))
            or (isinstance(block.get("figure"), dict) and isinstance(block["figure"].get("path"), str)))
        if not ok:
            return "a block of 'section' is not a text, a table or a figure"
        resolution = (block["table"].get("resolution") or {}) if isinstance(block.get("table"), dict) else {}
        if not isinstance(resolution, dict) or not all(
                k.isdigit() and isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0
                for k, v in resolution.items()):
            return "a table's resolution is not a mapping of column numbers to positive numbers"
    headlines = section.get("headlines", [])
    if not isinstance(headlines, list) or not all(
            isinstance(h, dict) and isinstance(h.get("result"), str) and isinstance(h.get("why", ""), str)
            and h.get("agrees") in (True, False, None)
            for h in headlines):
        return "'headlines' is not a list of {result, why, agrees}"
    return None


def _cached(out: Path, name: str, key: str) -> dict | None:
    """The stored record of a finished section when its key and files still match, else None.

    A record that is not JSON or not of the record's shape (edited, or written by other code)
    is not an error: the section runs again, and a line says so.
    """
    path = out / CACHE / f"{_slug(name)}.json"
    if not os.path.lexists(path):
        return None
    try:  # a regular file of at most MAX_RECORD_BYTES (input_files)
        text = read_input_file(path, f"the record of the finished section {name!r}", MAX_RECORD_BYTES,
                               "a section record").decode("utf-8", errors="replace")
    except UserInputError as err:
        _say(f"{err}; running the section again")
        return None
    try:
        record = json.loads(text)
        problem = _record_problem(record)
    except (ValueError, RecursionError):
        problem = "not JSON"
    if problem is not None:
        _say(f"the record of the finished section {name!r} ({path}) is damaged ({problem}); "
             "running the section again")
        return None
    if record.get("key") != key:
        return None
    for rel, digest in record.get("files", {}).items():
        f = out / rel
        try:
            if not f.is_file() or _file_hash(f) != digest:
                return None
        except (OSError, ValueError):  # a name no file can have (a NUL byte, too long)
            return None
    for block in record["section"]["blocks"]:
        figure = Path(block["figure"]["path"]) if "figure" in block else None
        if figure is not None and not (figure if figure.is_absolute() else out / figure).is_file():
            _say(f"the record of the finished section {name!r} ({path}) names a missing figure {str(figure)!r}; "
                 "running the section again")
            return None
    return record


def run_section(out: Path, name: str, experiment, quick: bool, key: str, resume: bool,
                folder: tuple[int, int] | None = None) -> tuple[Section, dict]:
    """One section with its cache step: reuse it (``resume`` and a matching record) or run it and
    store its data, its report part and the hashes of the files it wrote.

    ``folder``: the results folder's ``folder_identity`` at the start of the run; the section
    neither starts nor stores its data when ``out`` is no longer that folder (``check_same_folder``).

    Returns:
        (the section, its record: {"key", "seconds", "files", "reused"}).
    """
    if resume:
        record = _cached(out, name, key)
        if record is not None:
            return section_from_dict(record["section"], out), {**record, "reused": True}
    check_same_folder(out, folder, f"section {name!r}")
    before = _snapshot(out)
    t0 = time.perf_counter()
    section, data = experiment(out, quick)
    seconds = time.perf_counter() - t0
    check_same_folder(out, folder, f"the data of section {name!r} were stored")
    write_json(out / SECTION_DATA / f"{_slug(name)}.json", data)
    section.text(f"All of this section's data: `{SECTION_DATA}/{_slug(name)}.json`.")  # a link in the report
    after = _snapshot(out)
    changed = sorted(rel for rel, stamp in after.items() if before.get(rel) != stamp)
    record = {"key": key, "name": name, "seconds": seconds, "quick": quick,
              "files": {rel: _file_hash(out / rel) for rel in changed},
              "section": section_to_dict(section, out)}
    atomic_write_text(out / CACHE / f"{_slug(name)}.json", json.dumps(to_jsonable(record), indent=1))
    return section, {**record, "reused": False}


def folder_identity(out: Path) -> tuple[int, int] | None:
    """(device, inode) of the folder ``out``; None when there is no folder there now."""
    try:
        st = os.stat(out)
    except OSError:
        return None
    return (st.st_dev, st.st_ino) if stat.S_ISDIR(st.st_mode) else None


def check_same_folder(out: Path, folder: tuple[int, int] | None, before: str) -> None:
    """Stop when the results folder is not the one the run started in (``folder``, its
    ``folder_identity``): deleted, or deleted and made again (a later write recreates it empty),
    or another folder moved to its name. Writing on would give a report citing files that are
    gone; nothing is checked when ``folder`` is None.

    Raises:
        OutputError: one line (exit status 1) naming the folder and where the run stopped.
    """
    if folder is None:
        return
    now = folder_identity(out)
    if now != folder:
        how = "was deleted" if now is None else "was deleted or replaced (it is not the folder the run started in)"
        raise OutputError(f"--out {quote_path(out)} {how} during the run: stopped before {before}; "
                          "nothing more was written")


