"""Small anatomy files for the anatomy tests, written into a test's tmp_path."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models.atrium_mesh import write_stl_binary
from ballchain.drake_models.heart import LeftAtrium

SEMI_AXES_MM = np.array([27.0, 19.0, 24.0])  # the procedural atrium's endocardium, as a faceted ellipsoid


@functools.lru_cache
def _ellipsoid(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    U, F = mt.icosphere(subdivisions)
    return U * SEMI_AXES_MM, F


def ellipsoid_mesh(subdivisions: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """(V (nv, 3) [mm], F): an icosphere stretched to SEMI_AXES_MM, outward."""
    V, F = _ellipsoid(subdivisions)
    return V.copy(), F.copy()


@functools.lru_cache
def _procedural_points() -> tuple[np.ndarray, np.ndarray]:
    """(the procedural left ring's targets, its puncture) [mm]."""
    heart = LeftAtrium()
    return heart.rings["left"].p_HT * 1e3, heart.p_HP * 1e3


def lumen_anatomy(directory: Path, n_targets: int = 4, csv_text: str | None = None, **fields) -> Path:
    """A lumen anatomy in millimetres: a faceted ellipsoid (binary STL), targets at the mesh
    vertices nearest to every fifth target of the procedural left ring (a CSV with a header and
    names), the procedural atrium's puncture and sheath aim. ``fields`` replace YAML lines
    (a value of None drops the field)."""
    directory = Path(directory)
    V, F = ellipsoid_mesh()
    write_stl_binary(directory / "atrium.stl", V, F)
    ring, puncture = _procedural_points()
    ring = ring[:: 5][:n_targets]
    nearest = [V[int(np.argmin(np.linalg.norm(V - p, axis=1)))].tolist() for p in ring]
    if csv_text is None:
        csv_text = "name,x,y,z\n" + "".join(f"L{k + 1},{x!r},{y!r},{z!r}\n" for k, (x, y, z) in enumerate(nearest))
    (directory / "targets.csv").write_text(csv_text)
    p = puncture.tolist()
    lines = {"mesh": "atrium.stl", "length_unit": "mm", "side": "lumen", "targets": "targets.csv",
             "sheath": f"{{puncture: [{p[0]!r}, {p[1]!r}, {p[2]!r}], aim: [0, 0, 0]}}"}
    lines.update(fields)
    text = "".join(f"{k}: {v}\n" for k, v in lines.items() if v is not None)
    path = directory / "anatomy.yaml"
    path.write_text(text)
    return path


HOLES_MM = (-14.0, 14.0)  # x of the two vein openings through the phantom's plate


def solid_anatomy(directory: Path, per_hole: int = 4, **fields) -> Path:
    """A bench phantom built with another mesh library (trimesh, manifold3d booleans): a
    60 x 40 x 4 mm wall section with two 10 mm vein openings, its top face at z = 2 mm, in
    millimetres; ``per_hole`` targets on the top face 8 mm around each opening (the ring around
    the first, then the second), a sheath ending 20 mm above the plate, pointing down and in.
    ``fields`` replace YAML lines (None drops one)."""
    import trimesh

    directory = Path(directory)
    plate = trimesh.creation.box(extents=[60.0, 40.0, 4.0])
    holes = [trimesh.creation.cylinder(radius=5.0, height=10.0, transform=trimesh.transformations.translation_matrix(
        [x, 0.0, 0.0])) for x in HOLES_MM]
    phantom = plate.difference(trimesh.util.concatenate(holes))
    phantom.export(directory / "phantom.stl")
    angles = np.linspace(0.0, 2.0 * np.pi, per_hole, endpoint=False) + 0.5 * np.pi
    rows = [(f"{side}_{k + 1}", [x + 8.0 * float(np.cos(a)), 8.0 * float(np.sin(a)), 2.0])
            for side, x in zip(("left", "right"), HOLES_MM) for k, a in enumerate(angles)]
    (directory / "targets.csv").write_text("".join(f"{n} {x!r} {y!r} {z!r}\n" for n, (x, y, z) in rows))
    lines = {"mesh": "phantom.stl", "length_unit": "mm", "side": "solid", "targets": "targets.csv",
             "sheath": "{tip: [0, -22, 20], direction: [0, 0.6, -0.8]}"}
    lines.update(fields)
    path = directory / "phantom.yaml"
    path.write_text("".join(f"{k}: {v}\n" for k, v in lines.items() if v is not None))
    return path
