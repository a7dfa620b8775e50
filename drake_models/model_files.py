"""Model files: the ``ballchain_models`` package, the cache of generated files, one parser helper.

Static model files live next to ``drake_models/package.xml`` (package ``ballchain_models``).
Generated files (heart meshes, SDFs) go to the cache directory, which is itself a package,
``ballchain_generated``, so every model is addressed as ``package://...``.

A cached file is a convenience, never a source of truth: one found damaged (truncated by a full
disk, edited, half-copied) is rebuilt, with one line on stderr (``report_rebuilt``), so that it
never turns every later run into a traceback. Generated meshes are checked against the SHA-1
list written beside them (``cached_files``).
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from pathlib import Path
from typing import Callable

PACKAGE_XML = Path(__file__).with_name("package.xml")
GENERATED_PACKAGE = "ballchain_generated"
CACHE_ENV = "BALLCHAIN_CACHE"  # the cache folder; default <tmp>/ballchain_cache
DIGESTS = "files.sha1"  # beside a set of generated files: "<sha1>  <name>" per file

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


def _cache_root() -> Path:
    return Path(os.environ.get(CACHE_ENV) or Path(tempfile.gettempdir()) / "ballchain_cache")


def check_cache_dir() -> Path:
    """The cache folder, checked without creating it: a UserInputError naming ``$BALLCHAIN_CACHE``
    when it is a file or cannot be written (the command line checks this before any work)."""
    from ballchain.drake_models.safe_files import check_output_dir

    what = f"${CACHE_ENV}" if os.environ.get(CACHE_ENV) else "the cache folder"
    return check_output_dir(_cache_root(), what)


def cache_dir() -> Path:
    """Directory of generated model files: $BALLCHAIN_CACHE, else <tmp>/ballchain_cache.

    It holds a ``package.xml`` of the ``ballchain_generated`` package (rewritten when damaged).

    Raises:
        UserInputError: the folder is a file or cannot be written.
    """
    root = _cache_root()
    xml = root / "package.xml"
    try:
        root.mkdir(parents=True, exist_ok=True)
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


def _sha1(path: Path) -> str:
    return hashlib.sha1(path.read_bytes()).hexdigest()


def cached_files(directory: Path, names: dict[str, str],
                 write: Callable[[dict[str, Path]], None]) -> dict[str, Path]:
    """A set of generated files in ``directory``, reused when intact, else (re)written.

    Intact means: every file is listed in ``files.sha1`` (written after them) with its SHA-1. A
    set with a damaged file or list (truncated, edited) is rebuilt with one line on stderr; a set
    never finished (no list) is rebuilt quietly. Each file is moved into place atomically, so
    parallel runs never read half a file.

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
        from ballchain.drake_models.errors import UserInputError

        raise UserInputError(f"cannot make the folder {str(directory)!r} for generated model files "
                             f"({err.strerror or err})") from None
    paths = {k: directory / n for k, n in names.items()}
    listing = directory / DIGESTS
    damaged = None
    if listing.exists():
        try:
            listed = dict(line.split("  ", 1)[::-1] for line in listing.read_text().splitlines())
            for path in paths.values():
                if listed.get(path.name) != _sha1(path):
                    damaged = path
                    break
        except (OSError, ValueError, UnicodeDecodeError):
            damaged = listing
        if damaged is None:
            return paths
    tag = f".{os.getpid()}.tmp"
    tmp = {k: p.with_name(p.name + tag) for k, p in paths.items()}
    write(tmp)
    digests = {p.name: _sha1(tmp[k]) for k, p in paths.items()}
    for k, p in paths.items():
        tmp[k].replace(p)
    tmp_listing = listing.with_name(listing.name + tag)
    tmp_listing.write_text("".join(f"{d}  {n}\n" for n, d in digests.items()))
    tmp_listing.replace(listing)
    if damaged is not None:
        report_rebuilt(damaged)
    return paths


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
