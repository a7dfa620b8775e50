"""Meshcat overlays of a chain simulation.

``meshcat_overlays`` (MeshcatOverlays, only with a Meshcat): the 5 mm targets as discs on the
wall (blue, vermillion with a white rim once touched), the total external field at the tip ball as a blue arrow and
the wall's contact force on the tip ball as an orange arrow. Everything is also stored in the
Meshcat recording, so the HTML replay shows it. Which targets are touched comes from
``systems/target_contact.py``, the wall force from the chain model's ``tip_wall_force``.
"""

from __future__ import annotations

import hashlib
import io
import textwrap
from typing import Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont
from pydrake.common import MemoryFile
from pydrake.common.value import AbstractValue
from pydrake.geometry import Cylinder, InMemoryMesh, Mesh, MeshcatCone, Rgba
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import EventStatus, LeafSystem

from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.drake_models.params import CylinderMagnet, SphereMagnet
from ballchain.systems.magnetic_wrench import external_field_source
from ballchain.systems.meshcat_view import MESHCAT_FOV_DEG, VIEW_DIRECTION_W, atrium_box

FIELD_ARROW_SCALE = 1.0  # [m/T]: 1 mm per mT
FORCE_ARROW_SCALE = 0.1  # [m/N]: 10 mm per 0.1 N
FIELD_ARROW_RGBA = Rgba(0.1, 0.35, 0.95, 1.0)  # blue
FORCE_ARROW_RGBA = Rgba(1.0, 0.55, 0.0, 1.0)  # orange
# The target discs are opaque: three.js draws opaque objects first, then blends the
# semi-transparent heart over them; a semi-transparent disc is drawn after the heart and its
# depth test fails wherever the heart's near wall is in front of it (every disc on the near side
# of the chamber vanished in the replays).
# Okabe-Ito colours, told apart by colour-blind readers: blue #0072B2 not touched yet,
# vermillion #D55E00 touched; a touched disc also has a white rim (a wider white disc under it).
TARGET_RGBA = Rgba(0.0, 0.447, 0.698, 1.0)  # blue: not touched yet
TOUCHED_RGBA = Rgba(0.835, 0.369, 0.0, 1.0)  # vermillion: touched
TARGET_OUTLINE_RGBA = Rgba(1.0, 1.0, 1.0, 1.0)  # white: the touched disc's rim
TARGET_OUTLINE_SCALE = 1.3  # the rim's radius over the disc's


def _arrow_pose(p_W: np.ndarray, v_W: np.ndarray) -> RigidTransform:
    """An arrow frame at p_W with its z axis along v_W (any non-zero length)."""
    return RigidTransform(RotationMatrix(rotation_with_z_along(v_W)), p_W)


class MeshcatOverlays(LeafSystem):
    """Draws the ablation targets, the field at the tip and the wall's push on the tip in Meshcat.

    Meshcat paths (all under ``overlays/``):
        ``targets/<name>/open`` and ``targets/<name>/touched``: a 5 mm disc (the target's
            diameter, 0.3 mm thick) on the wall at each target, blue until the tip touches it
            (``touched`` input), then vermillion with a white rim (``touched/rim``) for the rest of the run.
        ``tip_field``: the total external field B_W at the tip ball's centre (fixed sources and
            port magnets, not the chain's own dipoles), blue, 1 mm per mT.
        ``tip_contact_force``: the wall's contact force on the tip ball (the sum over its
            hydroelastic and point contacts with ``heart_wall`` / ``wall_plane``), orange, 10 mm
            per 0.1 N, from the contact centroid; hidden when the tip does not touch the wall.

    Input ports:
        body_poses: abstract list[RigidTransform] indexed by BodyIndex (the chain's ``body_poses``).
        tip_wall_force: (6) the walls' force on the tip ball f_W [N], then where it acts [m] (the
            chain model's ``tip_wall_force``).
        touched: (n_targets,) only when there are targets (TargetTouchTracker's ``touched``).
        magnet_states: (6 k,) only with port magnets: as MagneticWrenchSystem's ``magnet_states``
            (per magnet p_WM [m] then its dipole direction).
        anatomy_offsets: (6,) only with ``moving_wall``: the quasi-static engine's (the heart's
            and the wall's offsets [m], ``drake_models.wall_motion``); ``overlays/targets`` is
            moved by the wall's offset, so that the discs ride on the moving wall.

    Publishes every ``period`` seconds and at initialisation, and a target's change at the step
    it happens (a per-step publish: the last touch of a run that ends there is in the replay's
    last frame); each drawing carries the context's time, so that it is stored in the Meshcat
    recording when one is running.

    Args:
        meshcat: the Meshcat.
        tip_body_index: the tip ball's BodyIndex.
        period: publishing period [s].
        targets: ``heart_targets(heart)``, or None for no targets.
        field_source: the fixed external FieldSource, or None.
        port_magnets: the magnets whose states come from ``magnet_states``.
        model: "dipole" or "exact", the port magnets' field model (as the wrench system's).
        moving_wall: the targets ride on a moving wall (input ``anatomy_offsets``).
    """

    def __init__(self, meshcat, tip_body_index, period: float, targets=None, field_source=None,
                 port_magnets: Sequence[CylinderMagnet | SphereMagnet] = (), model: str = "dipole",
                 moving_wall: bool = False) -> None:
        super().__init__()
        self.set_name("meshcat_overlays")
        self._meshcat = meshcat
        self._tip = int(tip_body_index)
        self._field_source = field_source
        self._port_magnets = list(port_magnets)
        self._model = model
        self._port_moments = np.array([m.dipole_moment for m in self._port_magnets])
        self._port_radii = np.array([m.bounding_radius for m in self._port_magnets])
        names, p_WT, n_W, radius = targets if targets is not None else ([], np.zeros((0, 3)), None, 0.0)
        self.target_names = list(names)
        self._body_poses_port = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        self._tip_force_port = self.DeclareVectorInputPort("tip_wall_force", 6)
        self._touched_port = self.DeclareVectorInputPort("touched", len(names)) if names else None
        self._magnet_port = (self.DeclareVectorInputPort("magnet_states", 6 * len(self._port_magnets))
                             if self._port_magnets else None)
        self._anatomy_port = self.DeclareVectorInputPort("anatomy_offsets", 6) if moving_wall else None
        # Targets: the discs sit 0.1 mm off the wall so that the semi-transparent wall does not hide them.
        self._target_paths = [f"overlays/targets/{n}" for n in names]
        for path, p, n in zip(self._target_paths, p_WT, n_W if names else []):
            meshcat.SetTransform(path, _arrow_pose(p + 1e-4 * n, n))
            meshcat.SetObject(f"{path}/open", Cylinder(radius, 0.3e-3), TARGET_RGBA)
            meshcat.SetObject(f"{path}/touched", Cylinder(radius, 0.3e-3), TOUCHED_RGBA)
            meshcat.SetObject(f"{path}/touched/rim", Cylinder(TARGET_OUTLINE_SCALE * radius, 0.2e-3), TARGET_OUTLINE_RGBA)
            meshcat.SetTransform(f"{path}/touched/rim", RigidTransform([0.0, 0.0, -0.1e-3]))
            meshcat.SetProperty(f"{path}/touched", "visible", False)
        for path, rgba in (("overlays/tip_field", FIELD_ARROW_RGBA), ("overlays/tip_contact_force", FORCE_ARROW_RGBA)):
            # A unit-length shaft along z (scaled to the arrow's length) and a 2 mm head at its end.
            meshcat.SetObject(f"{path}/shaft", Cylinder(0.25e-3, 1.0), rgba)
            meshcat.SetObject(f"{path}/head", MeshcatCone(2e-3, 0.7e-3, 0.7e-3), rgba)
            meshcat.SetProperty(path, "visible", False)
        self._drawn_touched = np.zeros(len(names), bool)
        self.DeclarePeriodicPublishEvent(period, 0.0, self._publish)
        self.DeclareInitializationPublishEvent(self._publish_all)
        if names:
            # A touch is drawn at the step it happens, not at the next period: a run that ends at
            # its last touch (the operator's task done) ended before that period, and the
            # replay's last frame missed the last target (Task II's right_18, issue 46).
            self.DeclarePerStepPublishEvent(self._publish_touches)

    def get_body_poses_input_port(self):
        return self._body_poses_port

    def get_tip_wall_force_input_port(self):
        return self._tip_force_port

    def get_touched_input_port(self):
        return self._touched_port

    def get_magnet_states_input_port(self):
        return self._magnet_port

    def get_anatomy_offsets_input_port(self):
        return self._anatomy_port

    # ------------------------------------------------------------------------ quantities drawn
    def tip_field(self, context) -> np.ndarray:
        """B_W (3,) [T]: the total external field at the tip ball's centre (no chain dipoles)."""
        p = self._body_poses_port.Eval(context)[self._tip].translation()
        states = None if self._magnet_port is None else self._magnet_port.Eval(context)
        source = external_field_source(self._field_source, self._port_magnets, self._port_moments,
                                       self._port_radii, states, self._model)
        return np.zeros(3) if source is None else source.field_and_gradient(p[None])[0][0]

    def tip_contact_force(self, context) -> tuple[np.ndarray, np.ndarray | None]:
        """(f_W (3,) [N], p_WC (3,) [m] or None): the walls' contact force on the tip ball, and
        where it acts (None without contact)."""
        v = self._tip_force_port.Eval(context)
        f = np.array(v[:3])
        return f, (np.array(v[3:]) if np.linalg.norm(f) > 0 else None)

    # ------------------------------------------------------------------------------- drawing
    def _set_arrow(self, path: str, p_W: np.ndarray | None, v_W: np.ndarray, t: float) -> None:
        length = float(np.linalg.norm(v_W))
        if p_W is None or length < 1e-5:
            self._meshcat.SetProperty(path, "visible", False, t)
            return
        self._meshcat.SetProperty(path, "visible", True, t)
        self._meshcat.SetTransform(path, _arrow_pose(p_W, v_W), t)
        self._meshcat.SetTransform(f"{path}/shaft", RigidTransform([0.0, 0.0, 0.5 * length]), t)
        self._meshcat.SetProperty(f"{path}/shaft", "scale", [1.0, 1.0, length], t)
        # The cone's apex is at its origin, opening along +z: turned over, it points along the arrow.
        self._meshcat.SetTransform(f"{path}/head", RigidTransform(RotationMatrix.MakeXRotation(np.pi),
                                                                   [0.0, 0.0, length]), t)

    def _draw_targets(self, context, changed_only: bool) -> None:
        if self._touched_port is None:
            return
        touched = self._touched_port.Eval(context) > 0.5
        t = context.get_time()
        if self._anatomy_port is not None:
            self._meshcat.SetTransform("overlays/targets", RigidTransform(self._anatomy_port.Eval(context)[3:]), t)
        for k in np.flatnonzero(touched != self._drawn_touched) if changed_only else range(len(touched)):
            self._meshcat.SetProperty(f"{self._target_paths[k]}/touched", "visible", bool(touched[k]), t)
            self._meshcat.SetProperty(f"{self._target_paths[k]}/open", "visible", not touched[k], t)
        # A visualisation cache (as MeshcatVisualizer keeps one): only changes are sent.
        self._drawn_touched = touched.copy()

    def _draw_arrows(self, context) -> None:
        t = context.get_time()
        p_tip = self._body_poses_port.Eval(context)[self._tip].translation()
        self._set_arrow("overlays/tip_field", p_tip, FIELD_ARROW_SCALE * self.tip_field(context), t)
        f, p_WC = self.tip_contact_force(context)
        self._set_arrow("overlays/tip_contact_force", p_WC, FORCE_ARROW_SCALE * f, t)

    def _publish(self, context):
        self._draw_targets(context, changed_only=True)
        self._draw_arrows(context)
        return EventStatus.Succeeded()

    def _publish_touches(self, context):
        self._draw_targets(context, changed_only=True)
        return EventStatus.Succeeded()

    def _publish_all(self, context):
        # Every target's state at the start (also a recording's first keyframe: before its first
        # keyframe, a replay holds that keyframe's value).
        self._draw_targets(context, changed_only=False)
        self._draw_arrows(context)
        return EventStatus.Succeeded()


# --------------------------------------------------------------------------- text on the screen
# Meshcat draws no text of its own: a panel is a picture of the text (PIL) on a flat square
# (an OBJ with its texture) that is a child of Meshcat's camera, so it stays put on the screen
# while the person turns the view. three.js keeps the vertical field of view (MESHCAT_FOV_DEG) and
# widens the horizontal one with the window, so a panel is placed by its height on the screen.
CAMERA_PATH = "/Cameras/default/rotated/<object>"
TEXT_DEPTH = 0.015  # [m] in front of the camera (Meshcat's near plane is at 0.01 m)
TEXT_PX_PER_VIEW = 1400  # texture pixels per screen height (sharp on screens up to about 1400 px)
TEXT_FONT_PX = 26  # font height in texture pixels (13 px on a 700 px high view)


def _text_png(lines: Sequence[str], width_px: int | None, colour, background, font_px: int,
              stroke_px: int = 0) -> bytes:
    """A picture (PNG) of ``lines``; ``width_px`` None: as wide as the longest line; ``stroke_px``
    thickens the letters (a label shrunk on the screen keeps its contrast)."""
    font = ImageFont.load_default(size=font_px)
    line_px = int(round(1.25 * font_px))
    height_px = line_px * max(1, len(lines)) + font_px // 2
    if width_px is None:
        width_px = int(max([font.getlength(line) for line in lines] + [1])) + font_px
    image = Image.new("RGB", (int(width_px), height_px), background)
    draw = ImageDraw.Draw(image)
    for k, line in enumerate(lines):
        draw.text((font_px // 2, font_px // 4 + k * line_px), line, font=font, fill=colour,
                  stroke_width=stroke_px, stroke_fill=colour)
    png = io.BytesIO()
    image.save(png, format="PNG")
    return png.getvalue()


def _quad_mesh(png: bytes, w: float, h: float, two_sided: bool = False):
    """A flat w x h [m] rectangle centred on its origin, facing +z, showing the picture ``png``
    (a Drake Mesh in memory: OBJ, MTL and PNG); ``two_sided``: its back shows the picture too,
    read the right way round from behind."""
    # Files named by their content: the page keeps a texture by its file name, so a new text under
    # a name seen before would never be loaded.
    name = "panel_" + hashlib.sha1(png).hexdigest()[:12]
    obj = (f"mtllib {name}.mtl\nv {-w / 2} {-h / 2} 0\nv {w / 2} {-h / 2} 0\nv {w / 2} {h / 2} 0\n"
           f"v {-w / 2} {h / 2} 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\nusemtl {name}\n"
           "f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n")
    if two_sided:  # the back: the other winding, the picture mirrored so that it reads from behind
        obj += "vn 0 0 -1\nf 2/1/2 1/2/2 4/3/2\nf 2/1/2 4/3/2 3/4/2\n"
    # Emissive only (no diffuse): the panel shows its picture's colours whatever the lights.
    mtl = f"newmtl {name}\nKa 0 0 0\nKd 0 0 0\nKs 0 0 0\nKe 1 1 1\nmap_Ke {name}.png\n"
    mesh = InMemoryMesh(mesh_file=MemoryFile(obj, ".obj", f"{name}.obj"),
                        supporting_files={f"{name}.mtl": MemoryFile(mtl, ".mtl", f"{name}.mtl"),
                                          f"{name}.png": MemoryFile(png, ".png", f"{name}.png")})
    return Mesh(mesh)


def text_panel_mesh(lines: Sequence[str], width_px: int, colour=(255, 255, 255), background=(20, 20, 20),
                    font_px: int = TEXT_FONT_PX):
    """A flat rectangle showing ``lines`` as a Drake Mesh (in memory: OBJ, MTL and PNG), its
    height in metres at ``TEXT_DEPTH`` in front of the camera (from ``TEXT_PX_PER_VIEW``).

    Returns:
        (Mesh, (width, height) [m]): the rectangle is centred on its origin, facing +z.
    """
    png = _text_png(lines, width_px, colour, background, font_px)
    width_px, height_px = Image.open(io.BytesIO(png)).size
    view_height = 2.0 * TEXT_DEPTH * np.tan(np.radians(0.5 * MESHCAT_FOV_DEG))
    w, h = view_height * width_px / TEXT_PX_PER_VIEW, view_height * height_px / TEXT_PX_PER_VIEW
    return _quad_mesh(png, w, h), (w, h)


def label_mesh(text: str, height: float, colour=(255, 255, 255), background=(20, 20, 20), font_px: int = 32):
    """A label in the scene: ``text`` on a two-sided rectangle ``height`` [m] high (as wide as the
    text), centred on its origin, facing +z.

    Returns:
        (Mesh, (width, height) [m]).
    """
    png = _text_png([text], None, colour, background, font_px, stroke_px=max(1, font_px // 16))
    width_px, height_px = Image.open(io.BytesIO(png)).size
    w = height * width_px / height_px
    return _quad_mesh(png, w, height, two_sided=True), (w, height)


# --------------------------------------------------------------------------- labels in the scene
LABELS_PATH = "/labels"  # outside /drake: the station's restart redraws /drake, not the labels
VEIN_LABEL_HEIGHT = 4.0e-3  # [m]
TARGET_LABEL_HEIGHT = 2.2e-3  # [m]
TRIAD_LABEL_HEIGHT = 3.0e-3  # [m]
TRIAD_LENGTH = 12e-3  # [m]
# The triad in the colours of Drake's (AddFrameTriadIllustration: x red, y green, z blue), each
# axis also named by its letter (the colours alone are not enough for colour-blind readers).
TRIAD_RGBA = {"x": Rgba(0.9, 0.1, 0.1, 1.0), "y": Rgba(0.1, 0.7, 0.1, 1.0), "z": Rgba(0.1, 0.2, 0.9, 1.0)}


def show_on_top(meshcat, path: str) -> None:
    """Draw the object at ``path`` over everything (the semi-transparent heart wall tinted the
    labels behind it pink and faint): no depth test, among the transparent objects, drawn last
    (three.js material and render order, set through Meshcat's property paths)."""
    meshcat.SetProperty(f"{path}/<object>", "material.depthTest", False)
    meshcat.SetProperty(f"{path}/<object>", "material.transparent", True)
    meshcat.SetProperty(f"{path}/<object>", "renderOrder", 10.0)


def _facing(direction_W) -> RotationMatrix:
    """A label's rotation: its face (+z) towards ``direction_W`` (towards the camera), its
    text's up (+y) as near the world's up (+z) as it goes."""
    z = np.asarray(direction_W, float) / np.linalg.norm(direction_W)
    x = np.cross([0.0, 0.0, 1.0], z)
    x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-9 else np.array([1.0, 0.0, 0.0])
    return RotationMatrix(np.column_stack([x, np.cross(z, x), z]))


def add_scene_labels(meshcat, heart=None, targets=None, direction_W=None) -> dict[str, str]:
    """Names in the scene: each vein's at its ostium, each target's short name beside its disc
    ("R5": ``right_5``), and an axes triad of the world frame (x, y, z: the world mapping's stick
    axes turn the magnet about them), all under ``LABELS_PATH``; the labels face
    ``direction_W`` (the default view's, ``meshcat_view.VIEW_DIRECTION_W``) and read from
    behind too.

    Args:
        meshcat: the Meshcat.
        heart: the atrium (its ``ostia``: none for a user's atrium), or None.
        targets: ``heart_targets(heart)`` (names, p_WT, n_W, radius), or None.
        direction_W: towards the camera (default ``VIEW_DIRECTION_W``).

    Returns:
        {Meshcat path: the label's text}.
    """
    R = _facing(VIEW_DIRECTION_W if direction_W is None else direction_W)
    shown: dict[str, str] = {}

    def label(path: str, text: str, p_W, height: float, colour=(255, 255, 255), background=(20, 20, 20)):
        mesh, _ = label_mesh(text, height, colour, background)
        meshcat.SetObject(f"{LABELS_PATH}/{path}", mesh)
        show_on_top(meshcat, f"{LABELS_PATH}/{path}")
        meshcat.SetTransform(f"{LABELS_PATH}/{path}", RigidTransform(R, np.asarray(p_W, float)))
        shown[f"{LABELS_PATH}/{path}"] = text

    for ostium in getattr(heart, "ostia", None) or []:
        # In the lumen, a vein's radius in from its ostium's centre (the wall does not hide it).
        p = np.asarray(ostium.p_HO) - 0.5 * ostium.diameter * np.asarray(ostium.axis_H)
        # The acronym alone (the full names overlapped where two ostia line up in the view).
        label(f"veins/{ostium.name}", ostium.name, p,
              VEIN_LABEL_HEIGHT, colour=(20, 20, 20), background=(255, 255, 255))
    if targets is not None:
        names, p_WT, n_W, radius = targets
        p_WT, n_W = np.asarray(p_WT, float), np.asarray(n_W, float)
        rings: dict[str, list[int]] = {}
        for k, name in enumerate(names):
            rings.setdefault(name.rpartition("_")[0], []).append(k)
        for ring, ks in rings.items():
            centre = p_WT[ks].mean(axis=0)
            for k in ks:
                # Beside the disc on the ring's outer side (clear of the disc, whose colour says
                # whether it is touched, and of the vein labels inside the ring), a little into the
                # chamber: "R5" is right_5, shown before it is touched.
                out = p_WT[k] - centre
                out -= (out @ n_W[k]) * n_W[k]
                out /= max(np.linalg.norm(out), 1e-12)
                number = names[k].rpartition("_")[2]
                text = f"{ring[:1].upper()}{number}" if ring and number.isdigit() else names[k]
                label(f"targets/{names[k]}", text, p_WT[k] + 2.0 * radius * out + 0.5e-3 * n_W[k],
                      TARGET_LABEL_HEIGHT, colour=(255, 255, 255), background=(0, 114, 178))
    if heart is not None:
        # At the atrium's lower front corner on the side away from the sheath (in the default
        # view, in front of the wall at the lower left for the procedural atrium, whose sheath
        # comes in from the lower right).
        lower, upper = atrium_box(heart)
        sheath = np.asarray(getattr(heart, "p_HE", 0.5 * (lower + upper)), float)
        x = lower[0] if sheath[0] - lower[0] > upper[0] - sheath[0] else upper[0]
        add_triad(meshcat, [x, upper[1], lower[2] + TRIAD_LENGTH], shown, R)
    return shown


def add_triad(meshcat, p_W, shown: dict | None = None, label_rotation: RotationMatrix | None = None) -> None:
    """The world frame's axes at ``p_W`` (``LABELS_PATH``/triad): ``TRIAD_LENGTH`` long, x red,
    y green, z blue, each named by its letter at its end."""
    shown = {} if shown is None else shown
    R_label = label_rotation or RotationMatrix()
    base = f"{LABELS_PATH}/triad"
    meshcat.SetTransform(base, RigidTransform(np.asarray(p_W, float)))
    for k, (axis, rgba) in enumerate(TRIAD_RGBA.items()):
        e = np.zeros(3)
        e[k] = 1.0
        R = RotationMatrix(rotation_with_z_along(e))
        meshcat.SetObject(f"{base}/{axis}/shaft", Cylinder(0.35e-3, TRIAD_LENGTH), rgba)
        meshcat.SetTransform(f"{base}/{axis}/shaft", RigidTransform(R, 0.5 * TRIAD_LENGTH * e))
        meshcat.SetObject(f"{base}/{axis}/head", MeshcatCone(2e-3, 1e-3, 1e-3), rgba)
        meshcat.SetTransform(f"{base}/{axis}/head", RigidTransform(R.multiply(RotationMatrix.MakeXRotation(np.pi)),
                                                                    (TRIAD_LENGTH + 2e-3) * e))
        colour = tuple(round(255 * c) for c in (rgba.r(), rgba.g(), rgba.b()))
        mesh, _ = label_mesh(f"{axis} (world)", TRIAD_LABEL_HEIGHT, (255, 255, 255), colour)
        meshcat.SetObject(f"{base}/{axis}/label", mesh)
        show_on_top(meshcat, f"{base}/{axis}/label")
        meshcat.SetTransform(f"{base}/{axis}/label", RigidTransform(R_label, (TRIAD_LENGTH + 5.5e-3) * e))
        shown[f"{base}/{axis}/label"] = f"{axis} (world)"


PAGE_TEXT_WIDTH = 40  # characters a line of page text holds (Meshcat's control panel, 245 px)


class PageText:
    """Lines of text in the page itself (HTML, not a picture): each line the label of a Meshcat
    button in the page's control panel (``Meshcat.AddButton``; clicking one does nothing), so a
    screen reader reads it, a person copies it and a browser test finds it
    (``page.get_by_text``). A new text replaces the lines that changed.

    Args:
        meshcat: the Meshcat (buttons are added from the thread that made it).
        prefix: put before every line (names the group in the panel, keeps the labels apart
            from other buttons').
        width: lines longer than this many characters are wrapped (the panel shows about 42 of
            a button's label; the rest is cut off on the screen, though a screen reader has it).
    """

    def __init__(self, meshcat, prefix: str, width: int = PAGE_TEXT_WIDTH):
        self._meshcat, self._prefix, self._width = meshcat, prefix, int(width)
        self.labels: list[str] = []

    def show(self, lines: Sequence[str]) -> None:
        labels = []
        wrapped = [part for line in lines for part in (textwrap.wrap(f"{self._prefix}{line}", self._width) or [""])]
        for k, label in enumerate(wrapped):
            labels.append(label if label not in labels else f"{label} ({k + 1})")  # names are unique
        if labels == self.labels:
            return
        self.clear()
        for label in labels:
            self._meshcat.AddButton(label)
        self.labels = labels

    def clear(self) -> None:
        for label in self.labels:
            self._meshcat.DeleteButton(label, strict=False)
        self.labels = []


class TextPanel:
    """Lines of text fixed on the screen: a child of Meshcat's camera, so it stays put while the
    person turns the view.

    A new text is a new picture that the browser decodes before it can draw it (drawn before,
    its square is black). So each text goes into one of two slots, hidden, and is shown (the
    other slot hidden) at the next ``show`` or ``flush``: what the page shows lags one update.

    Args:
        meshcat: the Meshcat.
        name: the panel's name (``<camera>/text/<name>``).
        anchor: where the panel's top-left corner goes, in screen heights from the screen's
            centre (x to the right, y up: (-0.5, 0.5) is the top edge, half a screen height left
            of the centre, the left edge of a square window).
        width_px: the panel's width in texture pixels (``TEXT_PX_PER_VIEW`` per screen height).
    """

    def __init__(self, meshcat, name: str, anchor: tuple[float, float], width_px: int = 700):
        self._meshcat, self._anchor, self._width = meshcat, anchor, int(width_px)
        self.path = f"{CAMERA_PATH}/text/{name}"
        self._shown: int | None = None  # the slot on the screen
        self._pending: int | None = None  # the slot written last, not shown yet
        self.lines: list[str] | None = None  # the text written last

    def show(self, lines: Sequence[str], colour=(255, 255, 255), background=(20, 20, 20)) -> None:
        """Write ``lines`` (one string a line) in the colours given (RGB); the text written before
        goes on the screen now, this one at the next ``show`` or ``flush``."""
        from pydrake.math import RigidTransform

        self.flush()
        slot = 0 if self._shown != 0 else 1
        path = f"{self.path}/{slot}"
        mesh, (w, h) = text_panel_mesh(lines, self._width, colour, background)
        view_height = 2.0 * TEXT_DEPTH * np.tan(np.radians(0.5 * MESHCAT_FOV_DEG))
        x, y = self._anchor[0] * view_height + 0.5 * w, self._anchor[1] * view_height - 0.5 * h
        # Off the screen until ``flush`` (the page loads the picture of a visible object only).
        self._meshcat.SetTransform(path, RigidTransform([x + 10.0 * view_height, y, -TEXT_DEPTH]))
        self._meshcat.SetObject(path, mesh)
        self._meshcat.SetProperty(path, "visible", True)
        self._meshcat.SetProperty(self.path, "visible", True)
        self._pending, self._pending_xy, self.lines = slot, (x, y), list(lines)

    def flush(self) -> None:
        """Put the text written last on the screen (the other slot hidden)."""
        from pydrake.math import RigidTransform

        if self._pending is None:
            return
        self._meshcat.SetTransform(f"{self.path}/{self._pending}", RigidTransform([*self._pending_xy, -TEXT_DEPTH]))
        if self._shown is not None and self._shown != self._pending:
            self._meshcat.SetProperty(f"{self.path}/{self._shown}", "visible", False)
        self._shown, self._shown_xy, self._pending = self._pending, self._pending_xy, None

    def redraw(self) -> None:
        """Make the page draw the panel again (its pose sent again): the page draws only when
        told something changed, not when it has decoded a picture, so a still scene (a paused
        run) shows a new panel only after this."""
        from pydrake.math import RigidTransform

        if self._shown is not None:
            self._meshcat.SetTransform(f"{self.path}/{self._shown}", RigidTransform([*self._shown_xy, -TEXT_DEPTH]))

    def hide(self) -> None:
        self._meshcat.SetProperty(self.path, "visible", False)
