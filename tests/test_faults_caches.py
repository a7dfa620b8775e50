"""Caches that heal: a damaged cached file (generated wall mesh, atrium SDF, the generated
package's package.xml, numba's compiled kernels, a reproduce section record) is rebuilt with one
line on stderr and gives the same result as a fresh build; a bad ``BALLCHAIN_CACHE`` is one line.
A cache someone else controls: a folder of another user's or one that others may write is refused
in one line; a file planted with a rewritten digest list, or signed with another key, is rebuilt."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models import model_files
from ballchain.infrastructure.errors import UserInputError


@pytest.fixture(scope="module")
def user_atrium():
    from ballchain.drake_models.atrium_mesh import UserAtrium, validate_surface

    U, F = mt.icosphere(2)
    return UserAtrium(validate_surface(U * np.array([25e-3, 18e-3, 22e-3]), F, "m"), p_HP=[-25e-3, 0.0, 0.0])


def _one_rebuilt_line(err: str, path: Path) -> None:
    lines = [line for line in err.splitlines() if "was damaged" in line]
    assert len(lines) == 1, err
    assert lines[0].startswith("ballchain: ") and str(path) in lines[0] and "rebuilt" in lines[0]


# ------------------------------------------------------------------ generated wall meshes

def _damage(path: Path, how: str) -> None:
    data = path.read_bytes()
    if how == "truncated":
        path.write_bytes(data[: len(data) // 3])
    elif how == "edited":  # same size, one number changed
        i = data.index(b"\n", len(data) // 2) + 1
        path.write_bytes(data[:i] + (b"9" if data[i:i + 1] != b"9" else b"8") + data[i + 1:])
    elif how == "empty":
        path.write_bytes(b"")


@pytest.mark.parametrize("which, how", [("vtk", "truncated"), ("obj", "edited"), ("vtk", "empty")])
def test_a_damaged_generated_mesh_is_rebuilt_with_one_line(user_atrium, tmp_path, capsys, which, how):
    files = user_atrium.write_files(tmp_path)
    fresh = {k: p.read_bytes() for k, p in files.items()}
    capsys.readouterr()
    _damage(files[which], how)
    again = user_atrium.write_files(tmp_path)
    _one_rebuilt_line(capsys.readouterr().err, files[which])
    assert {k: p.read_bytes() for k, p in again.items()} == fresh
    user_atrium.write_files(tmp_path)  # intact now: reused, nothing said
    assert "damaged" not in capsys.readouterr().err


def test_a_damaged_digest_list_rebuilds_and_a_missing_one_rebuilds_quietly(user_atrium, tmp_path, capsys):
    files = user_atrium.write_files(tmp_path)
    fresh = files["vtk"].read_bytes()
    listing = tmp_path / model_files.SIGNATURES
    listing.write_bytes(b"\xff\xfe garbage without the two-space separator\n")
    files["vtk"].write_bytes(b"half a file")
    capsys.readouterr()
    user_atrium.write_files(tmp_path)
    _one_rebuilt_line(capsys.readouterr().err, listing)
    assert files["vtk"].read_bytes() == fresh
    # A set never finished (a run killed between the files and their list): rebuilt, nothing said.
    listing.unlink()
    files["obj"].write_bytes(b"v 0 0")
    user_atrium.write_files(tmp_path)
    assert "damaged" not in capsys.readouterr().err and listing.exists()
    assert files["obj"].read_bytes().startswith(b"# generated")


@pytest.mark.slow
def test_the_procedural_atriums_damaged_wall_is_rebuilt_and_drake_reads_it(tmp_path, capsys):
    from pydrake.geometry import ReadObjToTriangleSurfaceMesh

    from ballchain.drake_models.heart import HeartParams, LeftAtrium

    heart = LeftAtrium(HeartParams(subdivisions=2, visual_subdivisions=2))
    files = heart.write_files(tmp_path)
    n_faces = ReadObjToTriangleSurfaceMesh(str(files["obj"])).num_triangles()
    _damage(files["obj"], "truncated")
    capsys.readouterr()
    files = heart.write_files(tmp_path)
    _one_rebuilt_line(capsys.readouterr().err, files["obj"])
    assert ReadObjToTriangleSurfaceMesh(str(files["obj"])).num_triangles() == n_faces
    V, T = mt.read_vtk_tetrahedra(files["vtk"])
    np.testing.assert_allclose(V, heart.wall_tetrahedra[0], atol=1e-9)


def test_a_file_where_the_generated_files_go_is_one_line(user_atrium, tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("x")
    with pytest.raises(UserInputError, match="cannot make the folder .*afile"):
        user_atrium.write_files(afile / "wall")


# ------------------------------------------------------------------ the atrium SDF grid

@pytest.mark.parametrize("how", ["truncated", "text", "wrong arrays"])
def test_a_damaged_sdf_grid_is_rebuilt_with_one_line(user_atrium, tmp_path, capsys, how):
    from ballchain.drake_models.atrium_sdf import atrium_sdf

    grid = dict(spacing=2e-3, band=3e-3)
    fresh = atrium_sdf(user_atrium, directory=tmp_path, **grid)
    (path,) = tmp_path.glob("atrium_sdf_*.npz")
    if how == "truncated":  # numpy: zipfile.BadZipFile
        path.write_bytes(path.read_bytes()[:200])
    elif how == "text":
        path.write_text("not a zip file\n")
    else:  # a readable npz of the wrong shape
        np.savez(path, origin=np.zeros(2), spacing=2e-3, values=np.zeros(5), band=3e-3)
    capsys.readouterr()
    sdf = atrium_sdf(user_atrium, directory=tmp_path, **grid)
    _one_rebuilt_line(capsys.readouterr().err, path)
    np.testing.assert_array_equal(sdf.values, fresh.values)
    again = atrium_sdf(user_atrium, directory=tmp_path, **grid)  # the rebuilt file is read back
    assert "damaged" not in capsys.readouterr().err
    np.testing.assert_array_equal(again.values, sdf.values)


def test_a_grid_read_once_is_not_read_again_until_its_files_change(user_atrium, tmp_path, monkeypatch, capsys):
    """The process keeps the grids it has read and checked: a second call reads no file and gives
    a copy with the same node values; a file rewritten (a new modification time) or damaged after
    that is read again, and a damaged one rebuilt with its one line."""
    import os

    from ballchain.drake_models.atrium_sdf import atrium_sdf

    grid = dict(spacing=2e-3, band=3e-3)
    built = atrium_sdf(user_atrium, directory=tmp_path, **grid)
    (path,) = tmp_path.glob("atrium_sdf_*.npz")
    reads, real_load = [], np.load
    monkeypatch.setattr(np, "load", lambda *a, **k: (reads.append(a[0]), real_load(*a, **k))[1])
    first = atrium_sdf(user_atrium, directory=tmp_path, **grid)
    second = atrium_sdf(user_atrium, directory=tmp_path, **grid)
    assert reads == [path]  # the first call read the file, the second nothing
    assert second is not first and np.shares_memory(second.values, first.values)
    np.testing.assert_array_equal(second.values, built.values)
    p = first.origin + 5e-3
    assert second(p[None])[0] == first(p[None])[0]
    stat = path.stat()
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
    atrium_sdf(user_atrium, directory=tmp_path, **grid)
    assert reads == [path, path]  # rewritten: read again
    path.write_text("not a zip file\n")
    capsys.readouterr()
    rebuilt = atrium_sdf(user_atrium, directory=tmp_path, **grid)
    _one_rebuilt_line(capsys.readouterr().err, path)
    np.testing.assert_array_equal(rebuilt.values, built.values)


def test_the_process_keeps_only_the_last_grids_it_used(user_atrium, tmp_path, monkeypatch):
    """A sweep over anatomies reads a grid per anatomy: the process keeps the last ``KEEP_READ``
    used, the least recently used dropped (and read again when asked for)."""
    from ballchain.drake_models import atrium_sdf as module

    monkeypatch.setattr(module, "_READ", {})
    monkeypatch.setattr(module, "KEEP_READ", 2)
    grid = dict(spacing=2e-3, band=3e-3)
    folders = [tmp_path / name for name in "abc"]
    for folder in folders:  # built and written
        module.atrium_sdf(user_atrium, directory=folder, **grid)
    reads, real_load = [], np.load
    monkeypatch.setattr(np, "load", lambda *a, **k: (reads.append(a[0].parent.name), real_load(*a, **k))[1])
    for name in "aba":
        module.atrium_sdf(user_atrium, directory=tmp_path / name, **grid)
    assert reads == ["a", "b"] and len(module._READ) == 2
    module.atrium_sdf(user_atrium, directory=folders[2], **grid)  # c read: b, the least recently used, dropped
    assert len(module._READ) == 2
    module.atrium_sdf(user_atrium, directory=folders[0], **grid)
    module.atrium_sdf(user_atrium, directory=folders[1], **grid)
    assert reads == ["a", "b", "c", "b"]


# ------------------------------------------------------------------ the cache folder itself

def test_a_damaged_package_xml_is_rewritten_and_drake_reads_it(tmp_path, monkeypatch, capsys):
    from pydrake.multibody.parsing import PackageMap

    monkeypatch.setenv("BALLCHAIN_CACHE", str(tmp_path))
    model_files.cache_dir()
    xml = tmp_path / "package.xml"
    xml.write_text(xml.read_text()[:40])
    capsys.readouterr()
    model_files.cache_dir()
    _one_rebuilt_line(capsys.readouterr().err, xml)
    packages = PackageMap()
    packages.AddPackageXml(str(xml))
    assert packages.Contains(model_files.GENERATED_PACKAGE)


@pytest.mark.parametrize("where", ["a file", "under a file"])
def test_ballchain_cache_that_cannot_be_a_folder_is_one_line(tmp_path, monkeypatch, where):
    afile = tmp_path / "afile"
    afile.write_text("x")
    target = afile if where == "a file" else afile / "cache"
    monkeypatch.setenv("BALLCHAIN_CACHE", str(target))
    with pytest.raises(UserInputError, match=r"\$BALLCHAIN_CACHE .*afile"):
        model_files.cache_dir()


def test_ballchain_cache_a_file_stops_the_command_before_any_work(tmp_path, monkeypatch, capsys):
    from ballchain import cli

    afile = tmp_path / "afile"
    afile.write_text("x")
    monkeypatch.setenv("BALLCHAIN_CACHE", str(afile))
    assert cli.main(["wheels", "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    (line,) = captured.err.strip().splitlines()
    assert "$BALLCHAIN_CACHE" in line and "is a file" in line


# ------------------------------------------------------------------ a cache someone else controls

NOBODY = 65534  # the uid given to "another user's" folders


def _give_away(path: Path) -> None:
    """Make ``path`` another user's (uid 65534), as a second user of the machine would have made it."""
    if os.geteuid() != 0:
        pytest.skip("not root: only root can give a folder to another user (os.chown); these cases are not run")
    os.chown(path, NOBODY, NOBODY)


@pytest.fixture
def own_cache(tmp_path, monkeypatch):
    """The default cache folder moved under ``tmp_path`` (``$XDG_CACHE_HOME``), ``$BALLCHAIN_CACHE`` unset."""
    monkeypatch.delenv("BALLCHAIN_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    return tmp_path / "xdg" / "ballchain"


def _refusal(excinfo, folder: Path, *words) -> str:
    line = str(excinfo.value)
    assert "\n" not in line and str(folder) in line and "$BALLCHAIN_CACHE" in line, line
    for word in words:
        assert word in line, line
    return line


@pytest.mark.parametrize("named", ["$BALLCHAIN_CACHE", "the default"])
def test_a_cache_folder_of_another_user_is_refused_and_left_alone(tmp_path, monkeypatch, named):
    """The audit's case: a world-writable folder another user made where the cache goes."""
    if named == "$BALLCHAIN_CACHE":
        folder = tmp_path / "cache"
        monkeypatch.setenv("BALLCHAIN_CACHE", str(folder))
    else:  # no usable home: the shared temporary folder, under this user's uid
        monkeypatch.delenv("BALLCHAIN_CACHE", raising=False)
        monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
        monkeypatch.setenv("HOME", str(tmp_path / "no home"))
        monkeypatch.setattr("tempfile.tempdir", str(tmp_path))
        folder = tmp_path / f"ballchain_cache-{os.geteuid()}"
        assert model_files.default_cache_root() == folder
    folder.mkdir()
    folder.chmod(0o777)
    _give_away(folder)
    with pytest.raises(UserInputError) as excinfo:
        model_files.cache_dir()
    _refusal(excinfo, folder, f"uid {NOBODY}", "0777", "not to you")
    assert list(folder.iterdir()) == []  # nothing written into it
    with pytest.raises(UserInputError, match=f"uid {NOBODY}"):
        model_files.check_cache_dir()


def test_a_cache_folder_of_another_user_stops_the_command_before_any_work(tmp_path, monkeypatch, capsys):
    from ballchain import cli

    folder = tmp_path / "cache"
    folder.mkdir(mode=0o777)
    _give_away(folder)
    monkeypatch.setenv("BALLCHAIN_CACHE", str(folder))
    assert cli.main(["wheels", "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    (line,) = captured.err.strip().splitlines()
    assert "$BALLCHAIN_CACHE" in line and f"uid {NOBODY}" in line


@pytest.mark.parametrize("mode, who", [(0o770, "its group"), (0o757, "everyone"), (0o777, "everyone")])
@pytest.mark.parametrize("named", ["$BALLCHAIN_CACHE", "the default"])
def test_a_cache_folder_others_may_write_is_refused(tmp_path, monkeypatch, own_cache, mode, who, named):
    """Even the user's own folder, and even one the user named: its group or everyone could plant files."""
    folder = own_cache
    if named == "$BALLCHAIN_CACHE":
        folder = tmp_path / "named"
        monkeypatch.setenv("BALLCHAIN_CACHE", str(folder))
    folder.mkdir(parents=True)
    folder.chmod(mode)
    with pytest.raises(UserInputError) as excinfo:
        model_files.cache_dir()
    line = _refusal(excinfo, folder, f"writable by {who}", f"{mode:04o}", "chmod go-w")
    assert line.startswith("$BALLCHAIN_CACHE" if named == "$BALLCHAIN_CACHE" else "the cache folder")
    assert list(folder.iterdir()) == []


@pytest.mark.parametrize("mode, refused", [(0o777, True), (0o1777, False)])
def test_a_cache_under_a_folder_others_may_write_is_refused_unless_sticky(tmp_path, monkeypatch, mode, refused):
    """Whoever can write the folder above could rename the cache away and put theirs in its place;
    a sticky folder (as /tmp) lets no one rename another's entry."""
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(mode)
    monkeypatch.setenv("BALLCHAIN_CACHE", str(shared / "mine"))
    if refused:
        with pytest.raises(UserInputError) as excinfo:
            model_files.cache_dir()
        _refusal(excinfo, shared, "could swap the cache folder")
    else:
        assert model_files.cache_dir() == shared / "mine"


def test_a_cache_reached_through_another_users_link_is_refused(tmp_path, monkeypatch):
    """A link in a sticky shared folder that its owner (not you) can point elsewhere at any time."""
    mine = tmp_path / "mine"
    mine.mkdir(mode=0o700)
    link = tmp_path / "link"
    link.symlink_to(mine)
    if os.geteuid() != 0:
        pytest.skip("not root: only root can give a link to another user (os.lchown); this case is not run")
    os.lchown(link, NOBODY, NOBODY)
    monkeypatch.setenv("BALLCHAIN_CACHE", str(link))
    with pytest.raises(UserInputError) as excinfo:
        model_files.cache_dir()
    _refusal(excinfo, link, "the link", f"uid {NOBODY}")


@pytest.mark.parametrize("umask", [0o022, 0o000])
def test_the_default_cache_folder_is_made_private_under_a_per_user_name(own_cache, umask):
    old = os.umask(umask)
    try:
        assert model_files.cache_dir() == own_cache
        key = model_files.signing_key()
    finally:
        os.umask(old)
    assert own_cache.stat().st_mode & 0o777 == 0o700
    assert len(key) == 32 and (own_cache / model_files.KEY_FILE).stat().st_mode & 0o777 == 0o600
    assert model_files.signing_key() == key  # made once, then read


def test_without_a_usable_home_the_default_cache_is_the_uids_own_in_tmp(tmp_path, monkeypatch):
    monkeypatch.delenv("BALLCHAIN_CACHE", raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "absent"))
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))
    folder = model_files.cache_dir()
    assert folder == tmp_path / f"ballchain_cache-{os.geteuid()}"
    assert folder.stat().st_mode & 0o777 == 0o700


def _plant(files: dict, listing_dir: Path) -> None:
    """What a second user did: the wall meshes scaled by 0.7, and every list beside them rewritten
    with the planted files' plain digests (the SHA-1 list, and a list of the same name as the
    signatures; without the key, a plain digest is all they can write)."""
    import hashlib

    V, T = mt.read_vtk_tetrahedra(files["vtk"])
    mt.write_vtk_tetrahedra(files["vtk"], 0.7 * V, T)
    obj = files["obj"].read_text().splitlines()
    files["obj"].write_text("\n".join(
        "v " + " ".join(f"{0.7 * float(x):.9g}" for x in line.split()[1:]) if line.startswith("v ") else line
        for line in obj) + "\n")
    for name, algorithm in (("files.sha1", "sha1"), (model_files.SIGNATURES, "sha256")):
        (listing_dir / name).write_text("".join(f"{hashlib.new(algorithm, p.read_bytes()).hexdigest()}  {p.name}\n"
                                                for p in files.values()))


@pytest.mark.parametrize("where", ["in the cache", "in a folder given"])
def test_a_planted_mesh_with_its_digest_list_rewritten_is_rebuilt_with_one_line(user_atrium, tmp_path, monkeypatch,
                                                                              capsys, where):
    monkeypatch.setenv("BALLCHAIN_CACHE", str(tmp_path / "cache"))
    directory = None if where == "in the cache" else tmp_path / "wall"
    files = user_atrium.write_files(directory)
    fresh = {k: p.read_bytes() for k, p in files.items()}
    _plant(files, files["vtk"].parent)
    capsys.readouterr()
    again = user_atrium.write_files(directory)
    _one_rebuilt_line(capsys.readouterr().err, files["vtk"])
    assert {k: p.read_bytes() for k, p in again.items()} == fresh
    user_atrium.write_files(directory)  # signed again: reused, nothing said
    assert "damaged" not in capsys.readouterr().err


def test_a_set_signed_with_another_key_is_rebuilt(user_atrium, tmp_path, monkeypatch, capsys):
    """A whole set copied from another cache (another user's, or another key): its signatures are not this key's."""
    monkeypatch.setenv("BALLCHAIN_CACHE", str(tmp_path / "theirs"))
    theirs = user_atrium.write_files(tmp_path / "wall")
    monkeypatch.setenv("BALLCHAIN_CACHE", str(tmp_path / "mine"))
    capsys.readouterr()
    user_atrium.write_files(tmp_path / "wall")
    _one_rebuilt_line(capsys.readouterr().err, theirs["vtk"])


@pytest.mark.parametrize("how", ["readable by others", "another owner", "a link", "not a key"])
def test_a_signing_key_that_is_not_the_users_private_one_is_replaced(user_atrium, tmp_path, monkeypatch, capsys, how):
    monkeypatch.setenv("BALLCHAIN_CACHE", str(tmp_path / "cache"))
    files = user_atrium.write_files()
    key = tmp_path / "cache" / model_files.KEY_FILE
    if how == "readable by others":
        key.chmod(0o644)
    elif how == "another owner":
        _give_away(key)
    elif how == "a link":
        (tmp_path / "planted.key").write_text("0" * 64)
        key.unlink()
        key.symlink_to(tmp_path / "planted.key")
    else:
        key.write_text("0" * 64 + "\n")
    capsys.readouterr()
    again = user_atrium.write_files()
    err = capsys.readouterr().err
    assert f"cache key {key} was damaged; rebuilt" in err  # and the set signed with the old key:
    _one_rebuilt_line("\n".join(line for line in err.splitlines() if "cache key" not in line), files["vtk"])
    assert not key.is_symlink() and key.stat().st_mode & 0o777 == 0o600 and key.stat().st_uid == os.geteuid()
    assert again == files


def test_a_planted_sdf_grid_is_rebuilt_with_one_line(user_atrium, tmp_path, monkeypatch, capsys):
    from ballchain.drake_models.atrium_sdf import atrium_sdf

    monkeypatch.setenv("BALLCHAIN_CACHE", str(tmp_path / "cache"))
    grid = dict(spacing=2e-3, band=3e-3)
    fresh = atrium_sdf(user_atrium, directory=tmp_path, **grid)
    (path,) = tmp_path.glob("atrium_sdf_*.npz")
    import hashlib

    planted = (fresh.values + 1e-3).astype(np.float32)  # a wall 1 mm away everywhere: a well-formed grid
    np.savez_compressed(path, origin=fresh.origin, spacing=fresh.spacing, values=planted, band=fresh.band)
    for listing in tmp_path.glob("atrium_sdf_*.hmac"):
        listing.write_text(f"{hashlib.sha256(path.read_bytes()).hexdigest()}  {path.name}\n")
    capsys.readouterr()
    sdf = atrium_sdf(user_atrium, directory=tmp_path, **grid)
    _one_rebuilt_line(capsys.readouterr().err, path)
    np.testing.assert_array_equal(sdf.values, fresh.values)


# ------------------------------------------------------------------ numba's compiled kernels

_KERNEL_CALL = """
import numpy as np
from ballchain.drake_models.kernels import pair as ck
r, x, y = np.array([1e-3, 2e-3, 0.5e-3]), np.array([0.0, 0.0, 1.0]), np.array([0.6, 0.0, 0.8])
g = [np.zeros(3) for _ in range(3)]
print(repr(float(ck._pair_first(r, x, y, 1.0, *g))))
"""


def _kernel_run(cache: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    return subprocess.run([sys.executable, "-c", _KERNEL_CALL], env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.slow
@pytest.mark.parametrize("which, how", [("nbi", "truncated"), ("nbc", "garbage")])
def test_a_damaged_numba_cache_file_is_recompiled_with_one_line(tmp_path, which, how):
    first = _kernel_run(tmp_path)
    assert first.returncode == 0 and "damaged" not in first.stderr, first.stderr
    files = {p.suffix[1:]: p for p in tmp_path.rglob("pair._pair_first-*")}
    assert set(files) == {"nbi", "nbc"}, files
    data = files[which].read_bytes()
    files[which].write_bytes(data[:20] if how == "truncated" else bytes(range(256)) * 8)
    second = _kernel_run(tmp_path)
    assert second.returncode == 0, second.stderr
    _one_line = [line for line in second.stderr.splitlines() if "was damaged" in line]
    assert len(_one_line) == 1 and str(files[which]) in _one_line[0] and "recompiled" in _one_line[0]
    assert second.stdout == first.stdout  # the same number, from a fresh compilation
    third = _kernel_run(tmp_path)  # numba wrote the files again: read back, nothing said
    assert third.returncode == 0 and "damaged" not in third.stderr and third.stdout == first.stdout
    assert files[which].exists()


# ------------------------------------------------------------------ reproduce --resume records

def _experiments(calls: dict):
    from ballchain.infrastructure.safe_files import atomic_write_text
    from ballchain.report import Section

    def make(name):
        def section(out: Path, quick: bool):
            calls[name] = calls.get(name, 0) + 1
            atomic_write_text(out / f"{name}.txt", f"{name}\n")
            return Section(f"Section {name}").text(f"{name} done"), {"n": name}
        return section

    from ballchain.reproduce import ReportSection

    return [ReportSection(name, make(name)) for name in ("one", "two")]


def _edit_record(record: dict, how: str):
    if how == "a JSON list":
        return [record]
    if how == "no key":
        return {k: v for k, v in record.items() if k != "key"}
    if how == "no section":
        return {k: v for k, v in record.items() if k != "section"}
    if how == "seconds a string":
        return {**record, "seconds": "fast"}
    if how == "files a list":
        return {**record, "files": list(record["files"])}
    if how == "blocks not a list":
        return {**record, "section": {"title": "x", "blocks": "text"}}
    if how == "a block of numbers":
        return {**record, "section": {"title": "x", "blocks": [{"table": {"header": 1, "rows": 2}}]}}
    if how == "a missing figure":
        return {**record, "section": {"title": "x", "blocks": [{"figure": {"path": "gone.png"}}]}}
    raise AssertionError(how)


@pytest.mark.parametrize("how", ["a JSON list", "no key", "no section", "seconds a string", "files a list",
                                 "blocks not a list", "a block of numbers", "a missing figure", "not JSON"])
def test_a_resume_record_of_the_wrong_shape_reruns_its_section_with_one_line(tmp_path, monkeypatch, capsys, how):
    from ballchain import reproduce

    calls: dict = {}
    monkeypatch.setattr(reproduce.registry, "SECTIONS", _experiments(calls))
    reproduce.run(out=tmp_path, quick=True)
    path = tmp_path / reproduce.CACHE / "one.json"
    if how == "not JSON":
        path.write_text(path.read_text()[:30])
    else:
        path.write_text(json.dumps(_edit_record(json.loads(path.read_text()), how)))
    capsys.readouterr()
    data = reproduce.run(out=tmp_path, quick=True, resume=True)
    assert data["reused"] == ["two"] and calls == {"one": 2, "two": 1}
    lines = [line for line in capsys.readouterr().err.splitlines() if "running the section again" in line]
    assert len(lines) == 1 and "'one'" in lines[0]
    assert "Section one" in (tmp_path / "report.md").read_text()
    # The rerun wrote a good record: the next resume reuses both.
    assert reproduce.run(out=tmp_path, quick=True, resume=True)["reused"] == ["one", "two"]
