"""Model files: the ``ballchain_models`` package, the cache of generated files, one parser helper.

Static model files live next to ``drake_models/package.xml`` (package ``ballchain_models``).
Generated files (heart meshes, SDFs) go to the cache directory, which is itself a package,
``ballchain_generated``, so every model is addressed as ``package://...``.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

PACKAGE_XML = Path(__file__).with_name("package.xml")
GENERATED_PACKAGE = "ballchain_generated"


def cache_dir() -> Path:
    """Directory of generated model files: $BALLCHAIN_CACHE, else <tmp>/ballchain_cache.

    It holds a ``package.xml`` of the ``ballchain_generated`` package.
    """
    root = Path(os.environ.get("BALLCHAIN_CACHE", Path(tempfile.gettempdir()) / "ballchain_cache"))
    root.mkdir(parents=True, exist_ok=True)
    xml = root / "package.xml"
    if not xml.exists():
        tmp = root / f"package.xml.{os.getpid()}.tmp"
        tmp.write_text(
            '<?xml version="1.0"?>\n<package format="2">\n'
            f"  <name>{GENERATED_PACKAGE}</name>\n  <version>0.1.0</version>\n"
            "  <description>Generated ballchain model files (cache)</description>\n"
            '  <maintainer email="none@example.com">ballchain</maintainer>\n'
            "  <license>BSD-3-Clause</license>\n</package>\n"
        )
        tmp.replace(xml)
    return root


def source_hash(*modules) -> str:
    """A short hash of the source files of ``modules``: part of the key of a generated file, so
    that the cache (shared by every checkout on the machine) never hands a run a mesh made by
    other code."""
    import hashlib

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
