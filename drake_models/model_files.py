"""Model files: the ``ballchain_models`` package, the cache of generated files, one parser helper.

Static model files live next to ``drake_models/package.xml`` (package ``ballchain_models``).
Generated files (heart meshes, SDFs) go to the cache directory, which is itself a package,
``ballchain_generated``, so every model is addressed as ``package://...``.

A cached file is a convenience, never a source of truth: one found damaged (truncated by a full
disk, edited, half-copied) is rebuilt, with one line on stderr (``report_rebuilt``), so that it
never turns every later run into a traceback.

Only its owner can write the cache, and what it holds is checked by content. The folder has a
per-user name (``default_cache_root``), is made private (0700), and is refused in one line when
it belongs to someone else or its group or others may write it (``cache_dir``), for a
``$BALLCHAIN_CACHE`` too. Each set of generated files is signed with this user's secret key
(``signing.key`` in the cache, 0600): an HMAC-SHA256 of each file's content and its name, in
``files.hmac`` beside them (``cached_files``). A list of plain digests catches accidents only;
whoever can write the files can rewrite such a list to match (a planted heart did). A signature
needs the key, so a planted or altered file is rebuilt, with the same one line.
"""

from __future__ import annotations

import hashlib
import hmac
import io
import os
import re
import secrets
import shutil
import stat
import sys
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np

from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.infrastructure.safe_files import atomic_write_bytes, atomic_write_text, check_output_dir

PACKAGE_XML = Path(__file__).with_name("package.xml")
GENERATED_PACKAGE = "ballchain_generated"
CACHE_ENV = "BALLCHAIN_CACHE"  # the cache folder; default default_cache_root()
DIGESTS = "files.sha1"  # beside a set shipped in the package (lesion tables): "<sha1>  <name>" per file
SIGNATURES = "files.hmac"  # beside a set of cached files: "<HMAC-SHA256>  <name>" per file
KEY_FILE = "signing.key"  # in the cache folder: this user's secret key of the signatures (0600)

_GENERATED_XML = (
    '<?xml version="1.0"?>\n<package format="2">\n'
    f"  <name>{GENERATED_PACKAGE}</name>\n  <version>0.1.0</version>\n"
    "  <description>Generated ballchain model files (cache)</description>\n"
    '  <maintainer email="none@example.com">ballchain</maintainer>\n'
    "  <license>BSD-3-Clause</license>\n</package>\n"
)


def report_rebuilt(path, what: str = "cache file") -> None:
    """The one line on stderr saying that a damaged cached file was found and rebuilt."""
    print(f"ballchain: {what} {path} was damaged; rebuilt", file=sys.stderr)


def default_cache_root() -> Path:
    """The cache folder when ``$BALLCHAIN_CACHE`` is not set: a name of this user's own.

    ``$XDG_CACHE_HOME/ballchain`` (when that is an absolute path), else ``~/.cache/ballchain`` when
    the home folder is usable (it exists, is this user's and is writable), else
    ``<tmp>/ballchain_cache-<uid>``. The home comes first because no other user can make a folder
    inside it: a predictable name in the shared temporary folder can be made by anyone before its
    owner runs (to plant files in it, or only to block the owner's runs, which are then refused
    until ``$BALLCHAIN_CACHE`` names another folder). It is also where Linux tools keep caches
    (XDG) and it survives a reboot, so the meshes, grids and lesion tables are not built again
    after each one. The temporary folder, named by the uid, is the fallback for a machine or a
    container without a usable home (``HOME`` unset or read-only); a folder there that another
    user made is refused (``cache_dir``).
    """
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    if os.path.isabs(xdg):
        return Path(xdg) / "ballchain"
    try:
        home = Path.home()
        st = home.stat()
        usable = (stat.S_ISDIR(st.st_mode) and st.st_uid == os.geteuid()
                  and os.access(home, os.W_OK | os.X_OK))
    except (RuntimeError, OSError, KeyError):  # no HOME and no password entry, or not there
        usable = False
    if usable:
        return home / ".cache" / "ballchain"
    return Path(tempfile.gettempdir()) / f"ballchain_cache-{os.geteuid()}"


def _cache_root() -> Path:
    return Path(os.environ.get(CACHE_ENV) or default_cache_root())


def _cache_what() -> str:
    return f"${CACHE_ENV}" if os.environ.get(CACHE_ENV) else "the cache folder"


def _user(uid: int) -> str:
    try:
        import pwd  # lazy: POSIX only, and only for a refusal's message

        return f"{pwd.getpwuid(uid).pw_name} (uid {uid})"
    except (ImportError, KeyError):
        return f"uid {uid}"


def check_private(root, what: str | None = None) -> None:
    """Refuse a cache folder that someone other than this user could write (nothing when it is
    absent or not a folder: making it says why it cannot be one).

    The folder must belong to this user and not be writable by its group or others; a
    ``$BALLCHAIN_CACHE`` that the user named is held to the same rule, since anyone in the group
    could plant files in every run, and each member's runs would rebuild the others' files (the
    signatures are per user). Each folder above it (and each link on the way) must be this
    user's or root's, and not writable by others unless it is sticky (as ``/tmp``: there no one
    can rename another's entry), or the cache folder could be swapped for another.

    Raises:
        UserInputError: one line naming the folder, its owner and mode, and what to do.
    """
    what = what or _cache_what()
    me = os.geteuid()
    root = Path(root)
    shown = short_repr(str(root), 4100)  # whole (a path is at most 4096 bytes): what to look at
    fix = f"set ${CACHE_ENV} to a folder of your own that only you can write"
    try:
        st = os.stat(root)
    except OSError:
        return
    if not stat.S_ISDIR(st.st_mode):
        return
    mode = f"mode {stat.S_IMODE(st.st_mode):04o}"
    if st.st_uid != me:
        raise UserInputError(f"{what} {shown} belongs to {_user(st.st_uid)} ({mode}), not to you: its owner could "
                             f"plant model files in your runs; remove it or {fix}")
    if st.st_mode & 0o022:
        who = "everyone" if st.st_mode & 0o002 else "its group"
        raise UserInputError(f"{what} {shown} is writable by {who} ({mode}, owner {_user(st.st_uid)}): they could "
                             f"plant model files in your runs; chmod go-w it or {fix}")
    given, real = Path(os.path.abspath(root)), Path(os.path.realpath(root))
    for path in sorted({given, *given.parents, *real.parents}, key=lambda p: len(p.parts)):  # links as given
        try:
            st = os.lstat(path)
        except OSError:
            continue
        open_to_others = (stat.S_ISDIR(st.st_mode) and st.st_mode & 0o022
                          and not st.st_mode & stat.S_ISVTX)
        if st.st_uid not in (me, 0) or open_to_others:
            kind = "the link" if stat.S_ISLNK(st.st_mode) else "the folder"
            why = (f"belongs to {_user(st.st_uid)}" if st.st_uid not in (me, 0)
                   else f"is writable by {'everyone' if st.st_mode & 0o002 else 'its group'} and not sticky")
            raise UserInputError(f"{what} {shown}: {kind} {short_repr(str(path), 4100)} on its way {why} (mode "
                                 f"{stat.S_IMODE(st.st_mode):04o}), so others could swap the cache folder for one "
                                 f"of theirs; {fix}")


def check_cache_dir() -> Path:
    """The cache folder, checked without creating it: a UserInputError naming ``$BALLCHAIN_CACHE``
    when it is a file, cannot be written, or someone else could write it (``check_private``; the
    command line checks this before any work)."""
    check_private(_cache_root())
    return check_output_dir(_cache_root(), _cache_what())


def cache_dir() -> Path:
    """Directory of generated model files: $BALLCHAIN_CACHE, else ``default_cache_root()``.

    Made private (0700) when missing, then checked (``check_private``). It holds a
    ``package.xml`` of the ``ballchain_generated`` package (rewritten when damaged) and this
    user's signing key (``KEY_FILE``).

    Raises:
        UserInputError: the folder is a file, cannot be written, or someone else could write it.
    """
    root = _cache_root()
    xml = root / "package.xml"
    try:
        for folder in reversed([p for p in (root, *root.parents) if not p.exists()]):
            folder.mkdir(mode=0o700, exist_ok=True)  # private, the folders above it made too
        check_private(root)  # after making it: one made by someone else meanwhile is refused too
        try:
            intact = xml.read_text() == _GENERATED_XML
        except FileNotFoundError:
            intact = None
        except (OSError, UnicodeDecodeError):
            intact = False
        if not intact:
            tmp = root / f"package.xml.{os.getpid()}.tmp"
            tmp.write_text(_GENERATED_XML)
            tmp.replace(xml)
            if intact is False:
                report_rebuilt(xml)
    except OSError:
        check_cache_dir()  # a file, or not writable: the one-line message
        raise  # anything else is not the user's setting
    return root


def _read_key(path: Path) -> bytes | bool:
    """The key in ``path``; False when it is missing, None when it is not one of this user's
    private key files (a link, another owner, readable by others, not 64 hex digits)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    except FileNotFoundError:
        return False
    except OSError:  # a link (ELOOP), or unreadable
        return None
    try:
        st = os.fstat(fd)
        text = os.read(fd, 129)
    finally:
        os.close(fd)
    if (not stat.S_ISREG(st.st_mode) or st.st_uid != os.geteuid() or st.st_mode & 0o077
            or not re.fullmatch(rb"[0-9a-f]{64}", text)):
        return None
    return bytes.fromhex(text.decode())


def signing_key() -> bytes:
    """This user's secret key of the cache's signatures: ``KEY_FILE`` in ``cache_dir()``, 32 random
    bytes made on first use (0600). A key file that is not this user's private one is replaced,
    with one line (every set signed with it is then rebuilt)."""
    path = cache_dir() / KEY_FILE
    key = _read_key(path)
    if isinstance(key, bytes):
        return key
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o600)
    try:
        os.fchmod(fd, 0o600)
        os.write(fd, secrets.token_hex(32).encode())
    finally:
        os.close(fd)
    try:
        if key is None:
            os.replace(tmp, path)
            report_rebuilt(path, "cache key")
        else:
            os.link(tmp, path)  # never replaces: a process that made it first wins, both read theirs
    except FileExistsError:
        pass
    finally:
        tmp.unlink(missing_ok=True)
    key = _read_key(path)
    if not isinstance(key, bytes):
        raise OSError(f"the cache key {path} could not be made")
    return key


def _signature(key: bytes, path: Path, name: str) -> str:
    """HMAC-SHA256 of the file ``path``'s content, as the file ``name`` (its folder's and its own
    name: a file moved to another set's folder does not pass)."""
    mac = hmac.new(key, name.encode() + b"\0", "sha256")
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            mac.update(chunk)
    return mac.hexdigest()


def _signed_name(path: Path) -> str:
    return f"{path.parent.name}/{path.name}"


def unsigned(listing: Path, paths) -> Path | None:
    """The first of ``paths`` whose content does not carry its signature in ``listing`` (or
    ``listing`` itself when it is missing or unreadable); None when every file does."""
    key = signing_key()
    try:
        listed = dict(line.split("  ", 1)[::-1] for line in listing.read_text().splitlines())
    except (OSError, ValueError, UnicodeDecodeError):
        return listing
    for path in paths:
        try:
            signed = hmac.compare_digest(listed.get(path.name, ""), _signature(key, path, _signed_name(path)))
        except (OSError, TypeError):  # missing, unreadable; a signature that is not ASCII
            signed = False
        if not signed:
            return path
    return None


def install_signed(listing: Path, files: dict[Path, Path]) -> None:
    """Move each temporary file into place (``files``: final path -> temporary file) and sign
    them in ``listing``, written last and atomically (a run killed before it leaves a set that
    is not signed, rebuilt quietly). The signatures are of the temporary files: of what this run
    wrote."""
    key = signing_key()
    signed = {final.name: _signature(key, tmp, _signed_name(final)) for final, tmp in files.items()}
    for final, tmp in files.items():
        os.replace(tmp, final)
    tmp_listing = listing.with_name(f"{listing.name}.{os.getpid()}.tmp")
    tmp_listing.write_text("".join(f"{d}  {n}\n" for n, d in signed.items()))
    tmp_listing.replace(listing)


def cached_files(directory: Path, names: dict[str, str],
                 write: Callable[[dict[str, Path]], None]) -> dict[str, Path]:
    """A set of generated files in ``directory``, reused when intact, else (re)written.

    Intact means: every file is signed in ``files.hmac`` (written after them) with this user's
    key (``unsigned``): its content is what this user's ballchain wrote under that name. A set
    with a damaged, altered or planted file, or a damaged list, is rebuilt with one line on
    stderr; a set never finished (no list) is rebuilt quietly. Each file is moved into place
    atomically, so parallel runs never read half a file.

    Args:
        directory: the folder (created when missing).
        names: key -> file name.
        write: writes every file, given key -> temporary path.

    Returns:
        key -> path.
    """
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UserInputError(f"cannot make the folder {str(directory)!r} for generated model files "
                             f"({err.strerror or err})") from None
    paths = {k: directory / n for k, n in names.items()}
    listing = directory / SIGNATURES
    damaged = None
    if listing.exists():
        damaged = unsigned(listing, paths.values())
        if damaged is None:
            return paths
    tag = f".{os.getpid()}.tmp"
    tmp = {k: p.with_name(p.name + tag) for k, p in paths.items()}
    write(tmp)
    install_signed(listing, {p: tmp[k] for k, p in paths.items()})
    if damaged is not None:
        report_rebuilt(damaged)
    return paths


def shipped_arrays(path: Path) -> dict | None:
    """The arrays of a table shipped in the package (``ship_arrays``): None when it is missing or
    its content does not match its line in the ``DIGESTS`` list beside it (then the caller builds
    the table into the cache instead)."""
    try:
        listed = (path.parent / DIGESTS).read_text().split()
        data = path.read_bytes()
    except OSError:
        return None
    if listed[:2] != [hashlib.sha1(data).hexdigest(), path.name]:
        return None
    with np.load(io.BytesIO(data)) as table:
        return {k: np.array(table[k]) for k in table.files}


def ship_arrays(root: Path, tables: dict, name: str) -> list[Path]:
    """Write tables into the package: each ``{key: arrays}`` as ``root/<key>/<name>`` (an .npz)
    with its ``DIGESTS`` list, atomically, and remove the folders of ``root`` of any other key
    (a stale key's table would never be read again). Returns the tables written."""
    written = []
    for key, arrays in tables.items():
        path = Path(root) / key / name
        path.parent.mkdir(parents=True, exist_ok=True)
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        data = buffer.getvalue()
        atomic_write_bytes(path, data)
        atomic_write_text(path.parent / DIGESTS, f"{hashlib.sha1(data).hexdigest()}  {path.name}\n")
        written.append(path)
    for old in Path(root).iterdir():
        if old.is_dir() and old.name not in tables:
            shutil.rmtree(old)
    return written


def source_hash(*modules) -> str:
    """A short hash of the source files of ``modules``: part of the key of a generated file, so
    that the cache (shared by every checkout on the machine) never hands a run a mesh made by
    other code."""
    digest = hashlib.sha1()
    for module in modules:
        digest.update(Path(module.__file__).read_bytes())
    return digest.hexdigest()[:8]


def generated_uri(path: Path) -> str:
    """The package:// URI of a file inside ``cache_dir()``."""
    rel = Path(path).resolve().relative_to(cache_dir().resolve())
    return f"package://{GENERATED_PACKAGE}/{rel.as_posix()}"


def make_parser(plant, scene_graph=None):
    """A pydrake Parser for ``plant`` that knows the ``ballchain_models`` and generated packages."""
    from pydrake.multibody.parsing import Parser

    parser = Parser(plant, scene_graph) if scene_graph is not None else Parser(plant)
    packages = parser.package_map()
    if not packages.Contains("ballchain_models"):
        packages.AddPackageXml(str(PACKAGE_XML))
    if not packages.Contains(GENERATED_PACKAGE):
        packages.AddPackageXml(str(cache_dir() / "package.xml"))
    return parser


def resolve_uri(uri: str) -> Path:
    """The file behind a package:// URI (through the same package map as ``make_parser``)."""
    from pydrake.multibody.parsing import PackageMap

    packages = PackageMap()
    packages.AddPackageXml(str(PACKAGE_XML))
    packages.AddPackageXml(str(cache_dir() / "package.xml"))
    return Path(packages.ResolveUrl(uri))
