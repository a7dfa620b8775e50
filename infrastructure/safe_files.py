"""Result files that are never half-written, and output paths checked before any work.

Every results writer (report, CSV, JSON, PNG, HTML) writes through ``atomic_path``: the data go
to a temporary file in the destination's folder, which replaces the destination with
``os.replace`` only once it is complete. A run killed part-way leaves either the old file or the
new one, never a truncated file that looks whole. ``check_output_file`` / ``check_output_dir``
are called by the commands before they compute, so an unwritable ``--out`` or ``--html`` is
refused at once instead of after the run.

Only regular files are ever replaced. A destination that is a named pipe (FIFO, e.g. ``--html
/dev/stdout`` in a pipeline or a shell's ``>(...)``) gets the finished data written into it; a
character or block device (``/dev/null``), a socket or a folder is refused, also behind a
symbolic link. A symbolic link to a file stays a link: its target gets the new content. Names
longer than the file system allows and a disk without room for the output are refused up
front; a write that fails anyway (the disk filled up during the run) raises ``OutputError``
naming the file and the reason, and the destination keeps its earlier content.

An output is never a file the run reads: the loaders register their files (``register_input``:
an anatomy file and the mesh and targets it names, the scenarios file, a scenario's
``atrium_file``, a sweep spec), and an output path that is one of them (links followed, hard
links included), or a folder holding one under a name the run writes, is refused by the checks
before any work, and by ``atomic_path`` at the latest.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import math
import os
import secrets
import shutil
import stat
import tempfile
from pathlib import Path

import numpy as np

from ballchain.infrastructure.errors import OutputError, UserInputError, short_repr, quote_path

TEMP_SUFFIX = ".partial"
_UMASK = os.umask(0o022)
os.umask(_UMASK)  # read once: temporary files are made 0600, results get the usual 0666 & ~umask

NAME_MAX = 255  # bytes per name, when the file system does not say (Linux, macOS)
PATH_MAX = 4096  # bytes per path, when the file system does not say (Linux)
TEMP_NAME_KEPT = 200  # characters of the destination's name in its temporary file's name (<= NAME_MAX - 18)
FOLDER_NAME_ROOM = 80  # bytes kept free in a folder's path for the names of the files written inside
MIN_FREE_BYTES = 1 << 20  # every output needs at least this much free space besides its own estimate

# OSError numbers of a write that failed because of where it goes (not a bug): one line, no traceback.
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.ENAMETOOLONG, errno.EROFS, errno.EACCES,
                          errno.EPERM, errno.EISDIR, errno.ENOTDIR, errno.EIO, errno.EPIPE})


def _kind(mode: int) -> str:
    """What a stat mode is, in words: "file", "fifo", "folder", "a character device", ..."""
    if stat.S_ISREG(mode):
        return "file"
    if stat.S_ISFIFO(mode):
        return "fifo"
    if stat.S_ISDIR(mode):
        return "folder"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def destination(path) -> tuple[Path, str]:
    """Where a write of ``path`` goes and what is there now.

    Returns:
        (the path to write, its kind): kind "absent", "file", "fifo", "folder" or a phrase
        ("a character device", "a block device", "a socket"). A symbolic link is followed: the
        path returned for a link to a file (or a dangling link) is its target, so that the link
        stays a link.
    """
    path = Path(path)
    try:
        mode = os.stat(path).st_mode  # follows links
    except FileNotFoundError:
        return (Path(os.path.realpath(path)) if path.is_symlink() else path), "absent"
    except NotADirectoryError:
        return path, "absent"  # a parent is a file: the folder checks say so
    kind = _kind(mode)
    if kind == "file" and path.is_symlink():
        return Path(os.path.realpath(path)), kind
    return path, kind


_ONLY_FILES = "only regular files are replaced, and a named pipe is written into"


def _phrase(kind: str) -> str:
    """A kind of ``destination`` as words for a message: "a folder", "a character device", ..."""
    return {"file": "a file", "fifo": "a named pipe", "folder": "a folder"}.get(kind, kind)


def output_error(path, err: OSError) -> OutputError:
    """``OutputError`` naming ``path`` and the reason of ``err`` (with the free space for a full disk)."""
    reason = err.strerror or str(err)
    if err.errno in (errno.ENOSPC, errno.EDQUOT):
        base = _existing_folder(Path(path).absolute().parent)
        with contextlib.suppress(OSError):
            reason += f" ({_megabytes(shutil.disk_usage(base).free)} free in {quote_path(base)})"
    elif err.errno == errno.EPIPE:
        reason += " (the reader of the pipe went away)"
    return OutputError(f"cannot write {quote_path(path)}: {reason}; nothing was replaced")


def _megabytes(n: float) -> str:
    return f"{n / 1e6:.1f} MB"


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path``; on success it replaces ``path`` atomically.

    The temporary file is removed when the block raises (also on KeyboardInterrupt), so nothing
    half-written is left behind. The folder is created when missing. A named pipe at ``path``
    is not replaced: the finished data are written into it (the write waits for a reader).

    Example:
        with atomic_path(out / "forces.png") as tmp:
            fig.savefig(tmp, format="png")

    Raises:
        OutputError: ``path`` is not a regular file nor a named pipe (a device, a socket, a
            folder), it is an input of this run (``register_input``), or the write failed for
            a reason of the place (full disk, read-only, name too long, ...: ``WRITE_ERRNOS``);
            ``path`` is unchanged.
    """
    target, kind = destination(path)
    if kind not in ("absent", "file", "fifo"):
        raise OutputError(f"cannot write {quote_path(path)}: it is {_phrase(kind)}, not a regular file "
                          f"({_ONLY_FILES})")
    found = input_at(path) if kind == "file" else None
    if found is not None:  # the last guard: the checks before the run should have said so
        raise OutputError(f"cannot write {quote_path(path)}: it is an input of this run "
                          f"({_input_phrase(path, found)}); nothing was replaced")
    # The temporary file's name is chosen before the file exists, and the clean-up below covers its
    # creation: a stop (Ctrl-C, SIGTERM or SIGHUP, raised as KeyboardInterrupt between two
    # bytecodes) landing right after the file was made cannot leave it behind. With
    # tempfile.mkstemp it could (its name is known only once mkstemp has returned): a SIGHUP in a
    # CI run of tests/test_faults.py once did.
    if kind == "fifo":  # the temporary file goes to the temporary folder (a pipe's folder may be /dev/fd)
        folder, prefix = Path(tempfile.gettempdir()), ".ballchain."
    else:
        folder, prefix = target.parent, f".{target.name[:TEMP_NAME_KEPT]}."
    tmp = None
    try:
        try:
            folder.mkdir(parents=True, exist_ok=True)
            tmp = folder / f"{prefix}{secrets.token_hex(4)}{TEMP_SUFFIX}"
            while not _created(tmp):  # taken (one chance in 4e9): another name
                tmp = folder / f"{prefix}{secrets.token_hex(4)}{TEMP_SUFFIX}"
        except OSError as err:
            if err.errno not in WRITE_ERRNOS:
                raise
            raise output_error(path, err) from None
        yield tmp
        if kind == "fifo":
            with open(tmp, "rb") as source, open(target, "wb") as pipe:
                shutil.copyfileobj(source, pipe)
            tmp.unlink()
        else:
            os.chmod(tmp, 0o666 & ~_UMASK)
            os.replace(tmp, target)
    except BaseException as err:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        if isinstance(err, OSError) and err.errno in WRITE_ERRNOS:
            raise output_error(path, err) from err
        raise


def _created(path: Path) -> bool:
    """Create ``path`` as a new empty file (mode 0600); False when the name is taken."""
    try:
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o600))
    except FileExistsError:
        return False
    return True


def atomic_write_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def _existing_folder(path: Path) -> Path:
    """The nearest folder among ``path`` and its parents that exists (never raises)."""
    p = path
    while True:
        try:
            os.stat(p)
            return p
        except OSError:
            if p.parent == p:
                return p
            p = p.parent


def _limit(folder: Path, name: str, default: int) -> int:
    try:
        return int(os.pathconf(folder, name))
    except (OSError, ValueError, TypeError):
        return default


def check_name_lengths(path, what: str, room: int = 0) -> None:
    """Each name in ``path`` fits the file system (NAME_MAX bytes), and so does the whole path
    (PATH_MAX bytes, with ``room`` bytes to spare for names added to it).

    Raises:
        UserInputError: naming the flag, the too long name (cut) and the limit.
    """
    absolute = Path(os.path.abspath(path))
    base = _existing_folder(absolute)
    name_max, path_max = _limit(base, "PC_NAME_MAX", NAME_MAX), _limit(base, "PC_PATH_MAX", PATH_MAX)
    for part in absolute.parts[1:]:
        size = len(os.fsencode(part))
        if size > name_max:
            raise UserInputError(f"{what} {quote_path(path)}: the name {short_repr(part)} is {size} bytes long; "
                                 f"the file system allows {name_max} bytes per name")
    size = len(os.fsencode(str(absolute)))
    if size + room >= path_max:
        raise UserInputError(f"{what} {quote_path(path)}: the path is {size} bytes long; the file system "
                             f"allows {path_max - 1 - room} here")


def check_free_space(folder, what: str, expected_bytes: float = 0, shown=None) -> None:
    """The disk holding ``folder`` (or its nearest existing parent) has room for an output of
    about ``expected_bytes`` (plus ``MIN_FREE_BYTES``).

    Raises:
        UserInputError: naming the flag, the free space and the estimate.
    """
    base = _existing_folder(Path(folder).absolute())
    try:
        free = shutil.disk_usage(base).free
    except OSError:
        return  # no answer from the file system: the write will tell
    if free < MIN_FREE_BYTES + expected_bytes:
        need = f"about {_megabytes(expected_bytes)}" if expected_bytes else f"at least {_megabytes(MIN_FREE_BYTES)}"
        raise UserInputError(f"{what} {quote_path(shown if shown is not None else folder)}: only "
                             f"{_megabytes(free)} free on the disk holding {quote_path(base)}; this run writes "
                             f"{need}")


# --- this run's inputs: an output never replaces one ----------------------------------------------

_INPUTS: dict[str, str] = {}
"""The files this process has read as inputs: resolved path -> what it is ("anatomy mesh", "sweep
spec", ...). The loaders add to it (``register_input``); the output checks and ``atomic_path`` read
it, so that a result is never written over a file the run reads."""
# No lock: each use below is one dict operation, which the interpreter makes atomic; a lock held
# when a stop (a KeyboardInterrupt from the signal handler) lands inside it would never be released.


def register_input(path, what: str) -> None:
    """Record ``path`` as a file this run reads (``what`` names it in messages: "anatomy mesh").

    From then on an output that is that file (the same path once links are followed, or a hard
    link to it) is refused by ``check_output_file`` / ``check_output_dir`` before any work, and
    by ``atomic_path`` at the latest. Called by the loaders (anatomy files and what they name,
    the scenarios file and a scenario's ``atrium_file``, sweep specs); never raises.
    """
    try:
        real = os.path.realpath(os.fspath(path))
    except (TypeError, ValueError, OSError):
        return
    _INPUTS.setdefault(real, str(what))


def forget_inputs() -> None:
    """Forget every registered input (a long-lived session that starts an unrelated run)."""
    _INPUTS.clear()


def input_at(path) -> tuple[str, str] | None:
    """(the input's path, what it is) when ``path`` is a registered input of this run (by its
    resolved path, links followed, or by its device and inode: a hard link), else None."""
    inputs = _INPUTS.copy().items()  # a copy in one step: another thread may register meanwhile
    if not inputs:
        return None
    try:
        real = os.path.realpath(os.fspath(path))
    except (TypeError, ValueError, OSError):
        return None
    for known, what in inputs:
        if known == real:
            return known, what
    try:
        st = os.stat(real)
    except (OSError, ValueError):
        return None  # absent: no input (the registered ones exist under their own names)
    if not stat.S_ISREG(st.st_mode):
        return None
    for known, what in inputs:
        try:
            other = os.stat(known)
        except (OSError, ValueError):
            continue
        if (other.st_dev, other.st_ino) == (st.st_dev, st.st_ino):
            return known, what
    return None


def _input_phrase(path, found: tuple[str, str]) -> str:
    """"anatomy mesh" or "anatomy mesh a/atrium.stl" (when ``path`` reaches it through a link)."""
    known, what = found
    same = os.path.abspath(os.fspath(path)) == known
    return what if same else f"{what} {short_repr(known)}"


def check_output_dir(path, what: str, *, expected_bytes: float = 0, names=()) -> Path:
    """Check that ``path`` is (or can be created as) a writable folder, without creating it.

    Args:
        path: the folder.
        what: the flag or field named in the message (e.g. "--out").
        expected_bytes: about how much the run writes there (checked against the free space).
        names: the files the run writes in the folder: any that exists must be a regular file
            (or a named pipe), not a folder or a device, and not an input of this run
            (``register_input``).

    Raises:
        UserInputError: it is a file, or it (or its nearest existing parent) is not writable, a
            name is too long, the disk is (nearly) full, or one of ``names`` is not a file or is
            an input of this run.
    """
    path = Path(path)
    shown = quote_path(path)
    check_name_lengths(path, what, room=FOLDER_NAME_ROOM)
    target, kind = destination(path)
    if kind not in ("absent", "folder"):
        raise UserInputError(f"{what} {shown} is {_phrase(kind)}, not a folder")
    base = _existing_folder(path.absolute())
    if not base.is_dir():
        raise UserInputError(f"{what} {shown}: {quote_path(base)} is a file, so the folder cannot be created")
    if not os.access(base, os.W_OK | os.X_OK):
        raise UserInputError(f"{what} {shown}: folder {quote_path(base)} is not writable")
    try:  # os.access says yes to root even on a read-only file system: try it
        with tempfile.TemporaryFile(dir=base, prefix=".ballchain_probe"):
            pass
    except OSError as err:
        raise UserInputError(f"{what} {shown}: cannot write in {quote_path(base)} ({err.strerror})") from None
    check_free_space(base, what, expected_bytes, shown=path)
    for name in names:
        _, kind = destination(path / name)
        if kind not in ("absent", "file", "fifo"):
            raise UserInputError(f"{what} {shown}: {short_repr(name)} in it is {_phrase(kind)}, and this run writes "
                                 "a file of that name; move it away or give another folder")
        found = input_at(path / name)
        if found is not None:
            raise UserInputError(f"{what} {shown}: {short_repr(name)} in it is an input of this run "
                                 f"({_input_phrase(path / name, found)}), and this run writes a file of that name "
                                 "there: choose another folder")
    return path


def check_output_file(path, what: str, *, expected_bytes: float = 0) -> Path:
    """Check that the file ``path`` can be written (its folder exists or can be created).

    A named pipe is accepted (it is written into); a device, a socket or a folder is refused,
    also behind a symbolic link.

    Args:
        path: the file.
        what: the flag or field named in the message (e.g. "--html").
        expected_bytes: about how big the file will be (checked against the free space).

    Raises:
        UserInputError: it is a folder, a device, a read-only file, an input of this run
            (``register_input``: by its resolved path or as a hard link), in an unwritable place,
            its name is too long, or the disk is (nearly) full.
    """
    path = Path(path)
    shown = quote_path(path)
    check_name_lengths(path, what)
    target, kind = destination(path)
    if kind == "folder":
        raise UserInputError(f"{what} {shown} is a folder; give a file name")
    if kind not in ("absent", "file", "fifo"):
        raise UserInputError(f"{what} {shown} is {kind}, not a regular file; give a file name ({_ONLY_FILES})")
    if kind != "absent" and not os.access(target, os.W_OK):
        raise UserInputError(f"{what} {shown} exists and is not writable")
    found = input_at(path) if kind == "file" else None
    if found is not None:
        raise UserInputError(f"{what} {shown} is an input of this run ({_input_phrase(path, found)}): choose "
                             "another name")
    if kind == "fifo":
        return path
    try:
        check_output_dir(target.parent, what, expected_bytes=expected_bytes)
    except UserInputError:
        base = _existing_folder(target.absolute().parent)
        if base.exists() and not base.is_dir():
            raise UserInputError(f"{what} {shown}: {quote_path(base)} is a file, so the folder cannot "
                                 "be created") from None
        raise
    return path


def write_csv(path, rows: list[dict], fieldnames=None) -> Path:
    """Write dict rows as CSV to ``path`` atomically (extra keys ignored); returns the path."""
    import csv
    import io

    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=list(fieldnames or (rows[0] if rows else [])),
                            extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    return atomic_write_text(path, buffer.getvalue())


def agg_pyplot():
    """``matplotlib.pyplot`` on the Agg backend: figures for files, no display needed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path, **kwargs) -> Path:
    """``fig.savefig`` to ``path`` atomically (the format from the path's suffix), then close the
    figure (a results writer has no further use for it); returns the path."""
    import matplotlib.pyplot as plt

    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format=path.suffix.lstrip(".") or "png", **kwargs)
    finally:
        plt.close(fig)
    return path


def note_replacements(out, names, command: str) -> list[str]:
    """Say on stderr which of the files ``names`` in folder ``out`` already exist and are about
    to be replaced (one line); returns them."""
    import sys

    out = Path(out)
    existing = [n for n in names if (out / n).exists()]
    if existing:
        print(f"ballchain {command}: replacing {', '.join(existing)} in {out}", file=sys.stderr)
    return existing


OMIT_IF_NONE = "omit_if_none"
"""Dataclass field metadata key: a field marked ``{OMIT_IF_NONE: True}`` is left out of the JSON
while its value is None (an optional part of a result, e.g. the files written only with ``out``)."""

NOT_IN_JSON = "not_in_json"
"""Dataclass field metadata key: a field marked ``{NOT_IN_JSON: True}`` is never in the JSON (a
working object a result keeps for its figures, e.g. the simulated fields)."""


def optional_field(**kwargs):
    """A dataclass field that defaults to None and is left out of the JSON (``to_jsonable``)
    while None (``OMIT_IF_NONE``): for the parts of a result that exist only in some runs, so that
    the JSON keeps the keys it had when results were dicts."""
    return dataclasses.field(default=None, metadata={OMIT_IF_NONE: True}, **kwargs)


def to_jsonable(value):
    """numpy arrays and scalars to plain Python, recursively; NaN and inf become None (null), so
    the JSON is valid (the JSON standard has no NaN). A dataclass becomes the dict of its fields
    in their order (fields marked ``OMIT_IF_NONE`` left out while None, ``NOT_IN_JSON`` always)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, np.generic):
        return to_jsonable(value.item())
    if isinstance(value, Path):
        return str(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return to_jsonable({f.name: getattr(value, f.name) for f in dataclasses.fields(value)
                            if not (f.metadata.get(NOT_IN_JSON)
                                    or (f.metadata.get(OMIT_IF_NONE) and getattr(value, f.name) is None))})
    if value is None or isinstance(value, (bool, int, str)):
        return value
    return str(value)  # anything else (a Drake object, ...): its text, so the JSON is always valid


def json_text(data) -> str:
    """The JSON text of ``data`` (``to_jsonable``: numpy to Python, non-finite numbers to null)."""
    return json.dumps(to_jsonable(data), indent=1, allow_nan=False)


def write_json(path, data) -> Path:
    """Write ``data`` as JSON to ``path`` atomically (see ``json_text``); returns the path."""
    return atomic_write_text(path, json_text(data) + "\n")
