"""The one check of every file a user gives the project to read, before a byte of it is read.

Anatomy files, meshes, targets CSVs, scenario files, sweep specs and resume records are all read
through ``read_input_file`` (or checked ahead with ``check_input_file`` where the read comes
later). It refuses, as one ``UserInputError`` line that starts with the caller's ``where`` (the
field or flag and the name as the user gave it):

- a name longer than the file system allows (a 300-character name was an ``OSError: File name
  too long`` traceback), a path that does not exist, a loop of symbolic links, a path through a
  file, a file that cannot be read;
- anything that is not a regular file, also behind a symbolic link: a folder, a named pipe
  (reading it would wait for a writer), a device (``/dev/urandom`` never ends), a socket;
- a file larger than the limit of its kind (``MAX_MESH_BYTES``, ``MAX_TABLE_TEXT_BYTES``, the
  YAML loader's ``safe_yaml.MAX_BYTES``), from its size before it is read (an 8 GB sparse mesh
  was read whole: a ``MemoryError`` traceback), and again while it is read (a file whose size
  says 0, as those of ``/proc``, or that grows meanwhile, is read only up to the limit).

The messages name the file and the kind of problem, never the file's contents: a file that is not
what the user meant (``/proc/self/environ``, a credentials file) must not end up quoted in a log.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from ballchain.infrastructure.errors import UserInputError, short_repr

MAX_MESH_BYTES = 512_000_000  # a mesh file (OBJ, STL, PLY, VTK): MAX_TRIANGLES as binary STL is 100 MB
MAX_TABLE_TEXT_BYTES = 1_000_000  # a targets CSV (tens of rows; 1 MB is over 10,000)
NAME_MAX = 255  # bytes per name, when the file system does not say (Linux, macOS)
PATH_MAX = 4096  # bytes per path, when the file system does not say (Linux)

_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a named pipe"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _size(n: int) -> str:
    """A size in words: "600 bytes", "1.0 MB (1000000 bytes)", "8590 MB (8589934592 bytes)"."""
    if n < 1_000_000:
        return f"{n} bytes"
    return f"{n / 1e6:.1f} MB ({n} bytes)" if n < 10_000_000 else f"{n / 1e6:.0f} MB ({n} bytes)"


def _too_long(path: Path) -> str:
    """Which name of ``path`` is longer than its file system allows (ENAMETOOLONG), in words."""
    absolute = Path(os.path.abspath(path))
    parent = absolute.parent
    while not os.path.isdir(parent) and parent != parent.parent:
        parent = parent.parent
    limits = []
    for name, default in (("PC_NAME_MAX", NAME_MAX), ("PC_PATH_MAX", PATH_MAX)):
        try:
            limits.append(int(os.pathconf(parent, name)))
        except (OSError, ValueError):
            limits.append(default)
    name_max, path_max = limits
    longest = max(absolute.parts[1:] or [""], key=lambda part: len(os.fsencode(part)))
    if len(os.fsencode(longest)) > name_max:
        return (f"the name {short_repr(longest)} is {len(os.fsencode(longest))} bytes long, longer than the file "
                f"system allows ({name_max} bytes per name)")
    return (f"the path is {len(os.fsencode(str(absolute)))} bytes long, longer than the file system allows "
            f"({path_max - 1} bytes)")


def _refusal(path: Path, where: str, err: OSError) -> UserInputError:
    if err.errno == errno.ENOENT:
        reason = "no such file"
    elif err.errno == errno.ENOTDIR:
        reason = "no such file (a name on its path is a file, not a folder)"
    elif err.errno == errno.ELOOP:
        reason = "a loop of symbolic links, not a file"
    elif err.errno == errno.ENAMETOOLONG:
        reason = _too_long(path)
    else:
        reason = f"cannot read it ({err.strerror or type(err).__name__})"
    return UserInputError(f"{where}: {reason}")


def _check_stat(st: os.stat_result, where: str, limit: int | None, noun: str) -> None:
    for test, kind in _KINDS:
        if test(st.st_mode):
            raise UserInputError(f"{where}: is {kind}, not {noun}")
    if not stat.S_ISREG(st.st_mode):
        raise UserInputError(f"{where}: is not a regular file; give {noun}")
    if limit is not None and st.st_size > limit:
        raise UserInputError(f"{where}: the file is {_size(st.st_size)}, more than the {_size(limit)} allowed "
                             f"for {noun}")


def check_input_file(path, where: str, limit: int | None = None, noun: str = "a file") -> Path:
    """Check that ``path`` names a regular file (links followed) of at most ``limit`` bytes,
    without reading it; for a check before the work whose read comes later (that read goes
    through ``read_input_file``).

    Args:
        path: the file (str or Path).
        where: the start of every message: the field or flag and the name as the user gave it
            ("anatomy file 'a.yaml'", "scenario atrium_file 'la.stl'").
        limit: the most bytes the file may hold (None: any size).
        noun: what the file should be, for the messages ("a mesh file (.obj, .stl, .ply or .vtk)").

    Returns:
        ``path`` as a Path.

    Raises:
        UserInputError: one line, ``where`` and the problem: no such file, a name too long, a loop
            of links, a folder, a pipe, a device, a socket, larger than ``limit``, unreadable.
    """
    path = Path(path)
    try:
        st = os.stat(path)
    except (OSError, ValueError) as err:  # ValueError: a NUL byte in the name
        if isinstance(err, ValueError):
            raise UserInputError(f"{where}: a file name cannot hold a NUL character") from None
        raise _refusal(path, where, err) from None
    _check_stat(st, where, limit, noun)
    return path


def read_input_file(path, where: str, limit: int, noun: str = "a file") -> bytes:
    """The bytes of the file ``path``, checked as ``check_input_file`` checks it, and read no
    further than ``limit`` bytes whatever its size said (``/proc`` files say 0).

    The file is opened without waiting (a named pipe put in its place after the check is refused,
    not waited on) and checked again on the open file.

    Raises:
        UserInputError: as ``check_input_file``, or more than ``limit`` bytes read.
    """
    path = check_input_file(path, where, limit, noun)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as err:
        raise _refusal(path, where, err) from None
    try:
        _check_stat(os.fstat(fd), where, limit, noun)
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, min(1 << 24, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as err:
        raise _refusal(path, where, err) from None
    finally:
        os.close(fd)
    if size > limit:
        raise UserInputError(f"{where}: the file holds more than the {_size(limit)} allowed for {noun} (its size "
                             "grew while it was read, or its file system does not say it)")
    return b"".join(chunks)
