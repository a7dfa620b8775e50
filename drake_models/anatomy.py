"""An anatomy file: a surface the chain works against, its ablation targets, the sheath and the magnets.

A segmented left atrium (CT, MRI) or a printed bench phantom becomes usable by every
target-reaching experiment through one YAML file (read with ``safe_yaml``, typed by
``AnatomySpec``; relative paths are relative to the file)::

    mesh: la_segmentation.stl        # .stl / .obj, or "procedural" (the built-in atrium, heart.py)
    length_unit: mm                  # m | mm (required: the mesh, targets, sheath and magnets use it)
    transform: {translation: [0, 0, 0], rpy_deg: [0, 0, 0]}   # optional, places all of the above
    side: lumen                      # lumen: the chain works inside the closed surface;
                                     # solid: outside it (a printed phantom part)
    targets: targets.csv             # or an inline list: [[x, y, z], {name: LSPV_1, position: [x, y, z]}]
    touch_radius: 2.5                # optional; default the paper's 5 mm circle (HeartParams.target_diameter)
    sheath: {puncture: [x, y, z], aim: [x, y, z]}   # lumen (aim optional: the chamber's centroid)
    # sheath: {tip: [x, y, z], direction: [dx, dy, dz]}   # solid: a sheath end in free space
    magnets: [[x, y, z]]             # optional (see ``default_magnet``)

The targets CSV has x, y, z per row (comma, semicolon or whitespace separated, in the file's
``length_unit``), an optional header line naming the columns (x, y, z and name) and an optional
names column (first or last). A target farther than ``MAX_TARGET_GAP`` (1 mm) from the surface is
refused, naming its row and its distance; a puncture within ``MAX_PUNCTURE_DISTANCE`` (5 mm) of the
surface is snapped onto it (the nearest vertex, as ``UserAtrium`` does), one farther is refused.

Every field is checked before any work (``load_anatomy``): a bad one is a ``UserInputError``
naming the field and the file. The built-in procedural atrium is one such file,
``anatomies/procedural_left_atrium.yaml`` (its targets, the rings of ``LeftAtrium``, as CSV).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ballchain.drake_models import mesh_tools as mt
from ballchain.drake_models.atrium_mesh import (MAX_PUNCTURE_DISTANCE, MESH_NOUN, AtriumSurface, UserAtrium,
                                                load_atrium_surface)
from ballchain.drake_models.heart import HeartParams, LeftAtrium
from ballchain.drake_models.params import CylinderMagnet
from ballchain.infrastructure.errors import UserInputError, short_repr, quote_path
from ballchain.infrastructure.input_files import (MAX_MESH_BYTES, MAX_TABLE_TEXT_BYTES, check_input_file,
                                                  read_input_file)
from ballchain.infrastructure.safe_files import register_input
from ballchain.infrastructure.safe_yaml import MAX_BYTES, check_value, check_yaml_schema, load_yaml_file, yaml_kind

ANATOMIES_DIR = Path(__file__).resolve().parent / "anatomies"
PROCEDURAL_FILE = ANATOMIES_DIR / "procedural_left_atrium.yaml"
PROCEDURAL = "procedural"  # the ``mesh`` entry of the built-in atrium
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}
SIDES = ("lumen", "solid")
MAX_TARGET_GAP = 1e-3  # [m] a target may lie this far from the surface
DEFAULT_TOUCH_RADIUS = 0.5 * HeartParams.target_diameter  # [m] the paper's 5 mm target circle
MAX_TOUCH_RADIUS = 20e-3  # [m]
DEFAULT_MAGNET_DISTANCE = 0.10  # [m] the paper's teleoperation unit stands 10 cm from the targets' wall
MAX_COORDINATE = 1.0  # [m] every point of an anatomy lies within 1 m of its origin
NORMAL_BAND = 0.5e-3  # [m] faces this much farther than the nearest one still shape a target's normal


@dataclass
class TransformSpec:
    """A rigid placement of everything in the file: p_world = R(rpy_deg) p_file + translation.

    Attributes:
        translation: (3,) in the file's ``length_unit``.
        rpy_deg: (3,) roll, pitch, yaw [deg] (Drake's RollPitchYaw: R = Rz(yaw) Ry(pitch) Rx(roll)).
    """

    translation: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    rpy_deg: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])


@dataclass
class SheathSpec:
    """Where the sheath's end stands (in ``length_unit``).

    Attributes:
        puncture: (3,) the septal puncture on a lumen surface (snapped onto it within 5 mm).
        aim: (3,) the point the sheath points to from the puncture (default: the chamber's centroid).
        tip: (3,) the sheath's end in free space (solid side).
        direction: (3,) the sheath's axis at its end, towards where the chain goes (solid side).
    """

    puncture: list[float] = field(default_factory=list)
    aim: list[float] = field(default_factory=list)
    tip: list[float] = field(default_factory=list)
    direction: list[float] = field(default_factory=list)


@dataclass
class AnatomySpec:
    """The schema of an anatomy file (see the module docstring); ``targets`` is checked apart
    (a CSV path or an inline list)."""

    description: str = ""
    mesh: str = ""
    length_unit: str = ""
    transform: TransformSpec = field(default_factory=TransformSpec)
    side: str = "lumen"
    touch_radius: float = 0.0  # 0: DEFAULT_TOUCH_RADIUS
    sheath: SheathSpec = field(default_factory=SheathSpec)
    magnets: list[list[float]] = field(default_factory=list)


@dataclass
class Anatomy:
    """A loaded, validated anatomy (SI units, the station's frame).

    Attributes:
        path: the anatomy file; name: its stem; description: its one line.
        mesh: the mesh file (None for the procedural atrium); side: "lumen" or "solid".
        surface: the transformed surface (None for the procedural atrium).
        target_names: in file order; p_WT: (n, 3) target centres [m]; n_W: (n, 3) unit surface
            normals at the targets, pointing to the chain's side; gaps: (n,) distances to the surface [m].
        touch_radius: [m]; puncture, aim, tip, direction: the sheath ((3,) or None; the puncture
            snapped onto the surface); magnets: (k, 3) unit centres [m]; magnets_default: whether
            ``magnets`` is ``default_magnet``'s.
    """

    path: Path
    name: str
    description: str
    mesh: Path | None
    side: str
    surface: AtriumSurface | None
    target_names: list[str]
    p_WT: np.ndarray
    n_W: np.ndarray
    gaps: np.ndarray
    touch_radius: float
    puncture: np.ndarray | None
    aim: np.ndarray | None
    tip: np.ndarray | None
    direction: np.ndarray | None
    magnets: np.ndarray
    magnets_default: bool
    _atrium: object = field(default=None, repr=False)

    @property
    def procedural(self) -> bool:
        return self.mesh is None

    def atrium(self):
        """The atrium the station and the experiments use (built once): the procedural
        ``LeftAtrium`` (its rings are this file's targets), or a ``UserAtrium`` carrying the
        targets as its one ring, "anatomy" (``AnatomyTargets``)."""
        if self._atrium is None:
            if self.procedural:
                self._atrium = LeftAtrium()
            else:
                self._atrium = self._user_atrium()
        return self._atrium

    def _user_atrium(self):
        try:
            if self.side == "lumen":
                atrium = UserAtrium(self.surface, self.puncture, self.aim, side="lumen")
            else:  # the sheath's end in free space, pointing along its direction
                atrium = UserAtrium(self.surface, self.tip, self.tip + 0.01 * self.direction, side="solid")
        except UserInputError as err:  # names the mesh or the sheath's field
            raise UserInputError(f"{_where(self.path)}: {' '.join(str(err).split())}") from None
        atrium.rings = {"anatomy": AnatomyTargets(self.target_names, self.p_WT, self.n_W, self.touch_radius)}
        return atrium

    def indices(self, prefix: str | None = None) -> list[int]:
        """The targets named ``{prefix}_...`` (all when None), in file order."""
        return [k for k, n in enumerate(self.target_names) if prefix is None or n.startswith(f"{prefix}_")]

    def describe(self) -> dict:
        """What reports and replays show: the file, the side, the sheath's exit and axis, the
        targets and the magnets (mm)."""
        mm = lambda p: [round(1e3 * float(v), 3) + 0.0 for v in p]  # noqa: E731 (+ 0.0: no -0.0)
        atrium = self.atrium()
        return {"file": str(self.path), "name": self.name, "description": self.description,
                "mesh": PROCEDURAL if self.mesh is None else str(self.mesh), "side": self.side,
                "sheath_exit_mm": mm(atrium.p_HE), "sheath_axis": [float(v) for v in atrium.sheath_axis_H],
                "touch_radius_mm": round(1e3 * self.touch_radius, 4),
                "targets": [{"name": n, "position_mm": mm(p), "gap_mm": round(1e3 * float(g), 4)}
                            for n, p, g in zip(self.target_names, self.p_WT, self.gaps)],
                "magnets_mm": [mm(p) for p in self.magnets], "magnets_default": self.magnets_default}


@dataclass
class AnatomyTargets:
    """A user anatomy's targets as the station reads an atrium's ring (``rings["anatomy"]``).

    Attributes:
        names: the file's target names; p_HT: (n, 3) centres [m]; n_HT: (n, 3) unit normals to
            the chain's side; radius: the touch radius [m].
    """

    names: list[str]
    p_HT: np.ndarray
    n_HT: np.ndarray
    radius: float

    @property
    def polygon_length(self) -> float:
        """The path through the targets in file order [m]."""
        return float(np.linalg.norm(np.diff(self.p_HT, axis=0), axis=1).sum())

    curve_length = polygon_length


# ------------------------------------------------------------------------------------------------ loading


def _where(path: Path) -> str:
    """The file as messages name it: its path, or .../its name when the path is long."""
    text = str(path)
    return f"anatomy file {short_repr(text if len(text) <= 72 else f'.../{Path(text).name}')}"


def _bad(path: Path, field_name: str, message: str) -> UserInputError:
    return UserInputError(f"{_where(path)}: {field_name} {message}")


def load_anatomy(path: str | Path) -> Anatomy:
    """Read and check an anatomy file, load its mesh and place its targets, sheath and magnets.

    Raises:
        UserInputError: one line naming the field and the file, before any simulation work.

    Example:
        The shipped example anatomy (the procedural atrium written as a file)::

            >>> import ballchain as bc; from importlib.resources import files
            >>> anatomy = bc.load_anatomy(files("ballchain.drake_models") / "anatomies" / "procedural_left_atrium.yaml")
            >>> anatomy.side, len(anatomy.target_names)
            ('lumen', 38)
    """
    if not isinstance(path, (str, Path)) or not str(path):
        raise UserInputError(f"anatomy file must be a file name, got {short_repr(path)}")
    path = Path(path)
    check_input_file(path, _where(path), MAX_BYTES, "an anatomy file (YAML)")
    register_input(path, "anatomy file")  # an output of the run may not replace it (nor the files it names)
    data = load_yaml_file(path, _where(path))
    if not isinstance(data, dict):
        raise UserInputError(f"{_where(path)}: must be a mapping of anatomy fields (mesh, length_unit, targets, "
                             f"...), got {yaml_kind(data)}")
    data = dict(data)
    raw_targets = data.pop("targets", None)
    check_yaml_schema(data, AnatomySpec, _where(path))
    spec = _spec(path, data)
    scale = LENGTH_UNITS[spec.length_unit]
    R, t = _transform(path, spec, scale)
    names, points, rows = _targets(path, raw_targets, spec.length_unit)
    place = lambda p: (np.asarray(p, float) * scale) @ R.T + t  # noqa: E731
    touch = DEFAULT_TOUCH_RADIUS if spec.touch_radius == 0.0 else spec.touch_radius * scale
    mesh, surface = _mesh(path, spec, R, t)
    p_WT = place(points)
    procedural = LeftAtrium() if surface is None else None
    gaps, n_W = _surface_at(surface or procedural, p_WT, spec.side)
    far = np.flatnonzero(gaps > MAX_TARGET_GAP)
    if len(far):
        k = int(far[0])
        raise _bad(path, "targets", f"{rows[k]} ({names[k]}) is {gaps[k] * 1e3:.2f} mm from the surface; a target "
                                    f"must lie within {MAX_TARGET_GAP * 1e3:g} mm of it (coordinates in "
                                    f"{spec.length_unit}, before the transform)")
    sheath = _sheath(path, spec, surface, place, R)
    magnets = [place(m) for m in spec.magnets]
    default = not magnets
    if default:
        magnets = [default_magnet(p_WT, n_W)]
    else:
        _check_magnet_clearance(path, spec, surface or procedural, np.array(magnets))
    anatomy = Anatomy(path=path, name=path.stem, description=spec.description, mesh=mesh, side=spec.side,
                      surface=surface, target_names=names, p_WT=p_WT, n_W=n_W, gaps=gaps, touch_radius=touch,
                      magnets=np.array(magnets), magnets_default=default, _atrium=procedural, **sheath)
    anatomy.atrium()  # the surface's and the sheath's checks that need the wall (one chamber, a free tip)
    return anatomy


def _check_magnet_clearance(path: Path, spec: AnatomySpec, surface, magnets_W: np.ndarray) -> None:
    """Each magnet at least a prototype magnet's bounding radius from the surface: closer (or
    inside the chamber) the chain could reach into the magnet, and the station would stop at
    its start with the field point inside the magnet's bounding sphere."""
    clearance = CylinderMagnet().bounding_radius
    gaps, _ = _surface_at(surface, magnets_W, spec.side)
    near = np.flatnonzero(gaps < clearance)
    if len(near):
        k = int(near[0])
        raise _bad(path, f"magnets[{k}]", f"{short_repr(spec.magnets[k])} is {gaps[k] * 1e3:.1f} mm from the surface; "
                                          f"a magnet unit stands outside the chamber, at least "
                                          f"{clearance * 1e3:.1f} mm (the prototype magnet's bounding radius) "
                                          f"from it (coordinates in {spec.length_unit}, before the transform)")


def default_magnet(p_WT: np.ndarray, n_W: np.ndarray, distance: float = DEFAULT_MAGNET_DISTANCE) -> np.ndarray:
    """One unit ``distance`` (10 cm) from the targets' centroid along the mean surface normal at
    the targets pointing away from the chain's side (out of a lumen, into a solid): behind the
    wall the chain presses, as the paper's unit stands behind the atrial wall."""
    away = -np.mean(n_W, axis=0)
    norm = np.linalg.norm(away)
    if norm < 1e-6:
        raise UserInputError("anatomy magnets: the targets' normals cancel out (targets all round the surface), "
                             "so there is no default place for the magnet unit: give magnets: [[x, y, z]]")
    return np.mean(p_WT, axis=0) + distance * away / norm


def _spec(path: Path, data: dict) -> AnatomySpec:
    """The typed fields, each checked: required, one of the choices, sized, in range."""
    for name in ("mesh", "length_unit"):
        if name not in data:
            raise _bad(path, name, "is required" + (" (m or mm: no guessing for a user file)"
                                                    if name == "length_unit" else
                                                    " (a .stl/.obj file, or 'procedural')"))
    spec = AnatomySpec(**{k: v for k, v in data.items() if k not in ("transform", "sheath")})
    spec.transform = TransformSpec(**data.get("transform", {}))
    spec.sheath = SheathSpec(**data.get("sheath", {}))
    if spec.length_unit not in LENGTH_UNITS:
        raise _bad(path, "length_unit", f"must be 'm' or 'mm', got {short_repr(spec.length_unit)}")
    if spec.side not in SIDES:
        raise _bad(path, "side", f"must be 'lumen' (inside the surface) or 'solid' (outside it), got "
                                 f"{short_repr(spec.side)}")
    if not spec.mesh:
        raise _bad(path, "mesh", "must name a .stl or .obj file (relative to the anatomy file) or 'procedural'")
    if not 0.0 <= spec.touch_radius * LENGTH_UNITS[spec.length_unit] <= MAX_TOUCH_RADIUS:
        raise _bad(path, "touch_radius", f"must be > 0 and at most {MAX_TOUCH_RADIUS * 1e3:g} mm in "
                                         f"{spec.length_unit}, got {spec.touch_radius:g}")
    if "touch_radius" in data and spec.touch_radius == 0.0:
        raise _bad(path, "touch_radius", "must be > 0 (leave it out for the paper's 5 mm circle)")
    for name in ("translation", "rpy_deg"):
        _vector(path, f"transform.{name}", getattr(spec.transform, name), spec.length_unit, empty_ok=False)
    for name in ("puncture", "aim", "tip", "direction"):
        _vector(path, f"sheath.{name}", getattr(spec.sheath, name), spec.length_unit)
    for k, m in enumerate(spec.magnets):
        _vector(path, f"magnets[{k}]", m, spec.length_unit, empty_ok=False)
    _check_sheath_fields(path, spec, data)
    return spec


def _vector(path: Path, name: str, v: list, unit: str, empty_ok: bool = True) -> None:
    if empty_ok and not v:
        return
    if len(v) != 3:
        raise _bad(path, name, f"must be 3 numbers [x, y, z] in {unit}, got {short_repr(v)}")
    if name.endswith("rpy_deg"):
        return
    if name.endswith("direction") and not any(v):
        raise _bad(path, name, f"must not be all zero, got {short_repr(v)}")
    if np.linalg.norm(v) * LENGTH_UNITS[unit] > MAX_COORDINATE and not name.endswith("direction"):
        raise _bad(path, name, f"is {np.linalg.norm(v) * LENGTH_UNITS[unit]:.3g} m from the origin, more than "
                               f"{MAX_COORDINATE:g} m: wrong length_unit ({unit})? got {short_repr(v)}")


def _check_sheath_fields(path: Path, spec: AnatomySpec, data: dict) -> None:
    """Which sheath fields each side and mesh takes: lumen puncture (+ aim), solid tip + direction,
    none for the procedural atrium (it has its own puncture and sheath axis)."""
    s = spec.sheath
    given = [n for n in ("puncture", "aim", "tip", "direction") if getattr(s, n)]
    if spec.mesh == PROCEDURAL:
        for name in ("transform", "sheath"):
            if name in data:
                raise _bad(path, name, "is not read with mesh: procedural (the built-in atrium has its own frame, "
                                       "puncture and sheath axis): leave it out")
        if spec.side != "lumen":
            raise _bad(path, "side", "must be lumen with mesh: procedural (the chain works inside the built-in atrium)")
        if spec.length_unit != "m":
            raise _bad(path, "length_unit", "must be m with mesh: procedural (the built-in atrium is in metres)")
        return
    wanted = ("puncture", "aim") if spec.side == "lumen" else ("tip", "direction")
    wrong = [n for n in given if n not in wanted]
    if wrong:
        raise _bad(path, f"sheath.{wrong[0]}", f"is not read on the {spec.side} side (it takes sheath "
                                               f"{' and '.join(wanted)}): leave it out")
    needed = ("puncture",) if spec.side == "lumen" else ("tip", "direction")
    missing = [n for n in needed if n not in given]
    if missing:
        raise _bad(path, f"sheath.{missing[0]}", f"is required on the {spec.side} side ("
                   + ("the septal puncture on the surface, [x, y, z]" if spec.side == "lumen" else
                      "the sheath's end in free space and its axis, [x, y, z] each") + ")")


def _transform(path: Path, spec: AnatomySpec, scale: float) -> tuple[np.ndarray, np.ndarray]:
    from pydrake.math import RollPitchYaw, RotationMatrix

    R = RotationMatrix(RollPitchYaw(np.radians(spec.transform.rpy_deg))).matrix()
    return R, np.asarray(spec.transform.translation, float) * scale


def _mesh(path: Path, spec: AnatomySpec, R: np.ndarray, t: np.ndarray) -> tuple[Path | None, AtriumSurface | None]:
    if spec.mesh == PROCEDURAL:
        return None, None
    mesh = _named_file(path, "mesh", spec.mesh, MAX_MESH_BYTES, MESH_NOUN)
    register_input(mesh, "anatomy mesh")
    try:
        surface = load_atrium_surface(mesh, spec.length_unit)
    except UserInputError as err:
        raise _bad(path, "mesh", f"{short_repr(spec.mesh)}: {' '.join(str(err).split())}") from None
    return mesh, replace(surface, V=surface.V @ R.T + t)  # a rigid motion: the orientation and volume stay


def _named_file(path: Path, field_name: str, raw: str, limit: int, noun: str) -> Path:
    """The file an anatomy field names (relative to the anatomy file), checked before it is read
    (``input_files.check_input_file``: a regular file of at most ``limit`` bytes)."""
    named = path.parent / raw if not Path(raw).is_absolute() else Path(raw)
    try:
        return check_input_file(named, f"{_where(path)}: {field_name} {short_repr(raw)}", limit, noun)
    except UserInputError as err:
        if str(err).endswith("no such file"):
            raise UserInputError(f"{err} (looked for {quote_path(named)})") from None
        raise


def _surface_at(surface, p: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
    """Distances (n,) [m] from the points to the surface (an AtriumSurface, or the procedural
    LeftAtrium) and the unit normals there (n, 3), pointing to the chain's side."""
    if isinstance(surface, LeftAtrium):  # the procedural atrium: its targets lie on the endocardial ellipsoid
        atrium = surface
        gaps = np.asarray(atrium.wall_distance(p), float)
        return gaps, np.array([ellipsoid_inward_normal(q, atrium.semi_axes) for q in p]).reshape(-1, 3)
    tri = surface.V[surface.F]
    n_face = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # outward, area-weighted
    gaps, n_out = np.zeros(len(p)), np.zeros((len(p), 3))
    for k, q in enumerate(p):  # exact over every triangle (a plate's faces are large: no centroid search)
        d = mt.point_triangle_distances(q[None], tri[None])[0]
        gaps[k] = d.min()
        n_out[k] = n_face[d <= gaps[k] + NORMAL_BAND].sum(axis=0)
    n_out /= np.linalg.norm(n_out, axis=1, keepdims=True)
    return gaps, (-n_out if side == "lumen" else n_out)


def ellipsoid_inward_normal(p_HT: np.ndarray, semi_axes: np.ndarray) -> np.ndarray:
    """The procedural endocardium's unit normal at a point on it, into the chamber: its outward
    normal is along p / a^2."""
    n_out = p_HT / semi_axes**2
    return -n_out / np.linalg.norm(n_out)


def _sheath(path: Path, spec: AnatomySpec, surface: AtriumSurface | None, place, R: np.ndarray) -> dict:
    """The sheath's points in the world frame [m]; a puncture snapped onto the surface's nearest
    vertex when within MAX_PUNCTURE_DISTANCE of it, else refused."""
    s = spec.sheath
    out = {"puncture": None, "aim": None, "tip": None, "direction": None}
    if surface is None:
        return out
    if s.puncture:
        p = place(s.puncture)
        gap = float(mt.point_triangle_distances(p[None], surface.V[surface.F][None]).min())
        if gap > MAX_PUNCTURE_DISTANCE:
            raise _bad(path, "sheath.puncture", f"is {gap * 1e3:.1f} mm from the surface; it must lie within "
                                                f"{MAX_PUNCTURE_DISTANCE * 1e3:g} mm of it (it is snapped onto it), "
                                                f"got {short_repr(s.puncture)} {spec.length_unit}")
        out["puncture"] = surface.V[int(np.argmin(np.linalg.norm(surface.V - p, axis=1)))].copy()
    if s.aim:
        out["aim"] = place(s.aim)
        if np.linalg.norm(out["aim"] - place(s.puncture)) < 1e-6 or np.linalg.norm(out["aim"] - out["puncture"]) < 1e-6:
            raise _bad(path, "sheath.aim", "coincides with the puncture: give a point the sheath points to")
    if s.tip:
        out["tip"] = place(s.tip)
        direction = R @ np.asarray(s.direction, float)
        out["direction"] = direction / np.linalg.norm(direction)
    return out


# ------------------------------------------------------------------------------------------------ targets

_HEADER_NAMES = {"x": "x", "y": "y", "z": "z", "name": "name", "label": "name", "id": "name", "target": "name"}


def _targets(path: Path, raw, unit: str) -> tuple[list[str], np.ndarray, list[str]]:
    """(names, points (n, 3) in the file's unit, row labels for messages) of the ``targets`` field."""
    if raw is None:
        raise _bad(path, "targets", "is required: a CSV file (x, y, z per row) or an inline list of [x, y, z]")
    if isinstance(raw, str):
        csv = _named_file(path, "targets", raw, MAX_TABLE_TEXT_BYTES, "a targets CSV (x, y, z per row)")
        register_input(csv, "anatomy targets CSV")
        label = f"targets {short_repr(raw)}"
        names, points, rows = read_targets_csv(csv, f"{_where(path)}: {label}")
        rows = [f"{short_repr(raw)} {row}" for row in rows]
    elif isinstance(raw, list):
        names, points, rows = _inline_targets(path, raw, unit)
    else:
        raise _bad(path, "targets", f"must be a CSV file name or a list of [x, y, z], got {short_repr(raw)}")
    if not points:
        raise _bad(path, "targets", "has no targets: give at least one")
    seen = set()
    for name, row in zip(names, rows):
        if name in seen:
            raise _bad(path, "targets", f"{row}: the name {short_repr(name)} is used twice; give each target its own")
        seen.add(name)
    return names, np.array(points, float), rows


def _inline_targets(path: Path, raw: list, unit: str):
    names, points, rows = [], [], []
    for k, item in enumerate(raw):
        where = f"targets[{k}]"
        if isinstance(item, dict):
            unknown = set(item) - {"name", "position"}
            if unknown or "position" not in item:
                raise _bad(path, where, f"must be [x, y, z] or {{name: ..., position: [x, y, z]}}, got "
                                        f"{short_repr(item)}")
            check_value(item.get("name", ""), str, f"{where}.name", _where(path))
            name, xyz = item.get("name") or f"target_{k + 1}", item["position"]
        else:
            name, xyz = f"target_{k + 1}", item
        check_value(xyz, list[float], where, _where(path))
        if len(xyz) != 3:
            raise _bad(path, where, f"must be 3 numbers [x, y, z] in {unit}, got {short_repr(xyz)}")
        names.append(str(name))
        points.append([float(v) for v in xyz])
        rows.append(where)
    return names, points, rows


def _split(line: str) -> list[str]:
    if "," in line:
        return [c.strip() for c in line.split(",")]
    if ";" in line:
        return [c.strip() for c in line.split(";")]
    return line.split()


def _number(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if np.isfinite(value) else None


def read_targets_csv(csv: Path, where: str) -> tuple[list[str], list[list[float]], list[str]]:
    """Targets of a CSV file: x, y, z per row (comma, semicolon or whitespace separated), an
    optional header naming the columns (x, y, z, name), an optional names column (first or last
    without a header); blank lines and lines starting with '#' are skipped.

    Returns:
        (names, [[x, y, z], ...] in the file's units, ["row 3", ...] naming each target's line).

    Raises:
        UserInputError: ``where`` and the row: a field that is not a number, a row with the wrong
            number of fields; not a regular file, or larger than ``MAX_TABLE_TEXT_BYTES``. The
            messages name the row and the column, never quote the file (it may not be a targets
            file at all: a credentials file, ``/proc/self/environ``).
    """
    text = read_input_file(csv, where, MAX_TABLE_TEXT_BYTES, "a targets CSV (x, y, z per row)").decode(
        "utf-8-sig", errors="replace")
    lines = [(k, line) for k, line in enumerate(text.splitlines(), start=1)
             if line.strip() and not line.lstrip().startswith("#")]
    columns = None
    if lines and all(_number(c) is None for c in _split(lines[0][1])):
        header = [re.sub(r"\W", "", c.lower()) for c in _split(lines[0][1])]
        columns = [_HEADER_NAMES.get(c) for c in header]
        named = [c for c in columns if c is not None]
        if sorted(c for c in named if c in "xyz") != ["x", "y", "z"] or len(set(named)) != len(named):
            raise UserInputError(f"{where}: row {lines[0][0]}: a header (a row without numbers) must name the "
                                 "columns x, y, z once each (and optionally name)")
        lines = lines[1:]
    names, points, rows = [], [], []
    for lineno, line in lines:
        cells = _split(line)
        row = f"row {lineno}"
        cols = columns or _guess_columns(cells)
        if cols is None or len(cells) != len(cols):
            expected = len(columns) if columns else "3 (x, y, z) or 4 (with a name first or last)"
            raise UserInputError(f"{where}: {row}: {len(cells)} fields, expected {expected}")
        values = dict(zip(cols, cells))
        xyz = [_number(values[c]) for c in "xyz"]
        if any(v is None for v in xyz):
            bad = next(c for c, v in zip("xyz", xyz) if v is None)
            raise UserInputError(f"{where}: {row}: its {bad} is not a finite number (x, y, z are numbers in the "
                                 f"anatomy's length_unit)")
        names.append(values.get("name") or f"target_{len(points) + 1}")
        points.append(xyz)
        rows.append(row)
    return names, points, rows


def _guess_columns(cells: list[str]) -> list[str] | None:
    """Columns of a headerless row: x, y, z, or a name first or last."""
    numeric = [_number(c) is not None for c in cells]
    if len(cells) == 3:
        return ["x", "y", "z"]
    if len(cells) == 4 and not numeric[0] and all(numeric[1:]):
        return ["name", "x", "y", "z"]
    if len(cells) == 4 and all(numeric[:3]) and not numeric[3]:
        return ["x", "y", "z", "name"]
    return None


def procedural_anatomy_text() -> tuple[str, str]:
    """(the YAML, the targets CSV) of the built-in atrium's anatomy file: ``LeftAtrium``'s rings
    in order (left_1..left_20, right_1..right_18) and the paper's teleoperation unit, 10 cm beyond
    the right carina on the line from the atrium's centre, every number written exactly."""
    atrium = LeftAtrium()
    names = [f"{side}_{k + 1}" for side, ring in atrium.rings.items() for k in range(len(ring.p_HT))]
    points = np.concatenate([ring.p_HT for ring in atrium.rings.values()])
    csv = "name,x,y,z\n" + "".join(f"{n},{x!r},{y!r},{z!r}\n" for n, (x, y, z) in zip(names, points.tolist()))
    carina = atrium.carinas["right"]
    p_HM = (carina + DEFAULT_MAGNET_DISTANCE * carina / np.linalg.norm(carina)).tolist()
    yaml = ("# The built-in procedural left atrium (drake_models/heart.py) as an anatomy file: generated by\n"
            "# drake_models.anatomy.procedural_anatomy_text(); the targets are LeftAtrium's two rings.\n"
            "description: the procedural left atrium, its two rings of ablation targets (Task I left, Task II "
            "right) and the paper's teleoperation unit 10 cm beyond the right carina\n"
            f"mesh: {PROCEDURAL}\nlength_unit: m\nside: lumen\ntargets: {PROCEDURAL_FILE.stem}.csv\n"
            f"magnets: [[{p_HM[0]!r}, {p_HM[1]!r}, {p_HM[2]!r}]]\n")
    return yaml, csv
