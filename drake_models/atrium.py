"""What every atrium offers the rest of the stack: the procedural ``LeftAtrium``
(``drake_models/heart.py``) and a user's segmented ``UserAtrium`` (``drake_models/atrium_mesh.py``).

The plant, the quasi-static engine, the watchdog, the target tracker, the operator and Meshcat
use an atrium only through these members (frame H: the heart's, the world's in the station).
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Atrium(Protocol):
    """An atrium as the station sees it: the members below, and nothing else.

    A new atrium (another mesh, an analytic chamber) is any object with these members; it need
    not inherit from this class (a structural protocol: ``isinstance(obj, Atrium)`` checks the
    members' names). ``MakeStation(scenario, heart=my_atrium)`` and ``run_station`` take it.

    Attributes:
        p_HP: (3,) septal puncture [m].
        p_HE: (3,) the sheath's exit [m].
        sheath_axis_H: (3,) unit sheath axis, into the chamber.
        params: wall thickness (``params.wall_thickness`` [m]) and meshing parameters.
        rings: ablation target rings by side ("left", "right"); empty for a user's atrium (a
            segmentation carries no ostia labels).
        ostia: the vein ostia (``heart.Ostium``); empty for a user's atrium.
        carinas: side -> (3,) carina point [m] (unit placement anchors); empty for a user's atrium.
        wall_distance: ``wall_distance(p (k, 3)) -> (k,)`` distance to the blood-side surface [m].
        lumen_key: what the lumen test depends on besides ``blood_surface``'s triangles (part
            of the SDF cache key).
        side: "lumen" (the chain works inside the surface: an atrium) or "solid" (it works
            outside: a printed phantom part; the signed distance, the wall, ``contains`` and the
            camera framing are mirrored, see ``atrium_mesh.UserAtrium``).
    """

    p_HP: np.ndarray
    p_HE: np.ndarray
    sheath_axis_H: np.ndarray
    params: object
    rings: dict
    ostia: list
    carinas: dict
    lumen_key: str
    side: str

    def contains(self, p_H: np.ndarray) -> np.ndarray:
        """(k,) bool: the points (k, 3) lie where the chain may be (inside the chamber; for a
        solid, outside it and within the working box)."""

    def write_files(self, directory: Path | None = None) -> dict[str, Path]:
        """The wall's model files, written to ``directory`` (default: the cache, reused when
        intact): ``{"vtk": the wall's tetrahedra (hydroelastic contact), "obj": its surface (the
        visual)}``; the plant and the quasi-static engine load them."""

    @property
    def wall_tetrahedra(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (v, 3) [m], tetrahedra (t, 4)) of the wall shell, for hydroelastic contact."""

    @property
    def blood_surface(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (v, 3) [m], triangles (f, 3)): the blood-side surface ``wall_distance``
        measures to (the procedural atrium's includes the vein tubes' inner walls)."""

    def lumen_grid_contains(self, origin: np.ndarray, spacing: float, shape: tuple[int, int, int]) -> np.ndarray:
        """(nx, ny, nz) bool: the nodes of a grid (origin (3,) [m], spacing [m]) lie in the blood
        pool, with the sign changing exactly on ``blood_surface``'s triangles (the SDF's sign)."""
