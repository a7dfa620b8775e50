"""Where a Meshcat scene's camera starts: framing the atrium (or the free chain).

Meshcat's default camera stands metres away from the origin, where the 5 cm heart is a speck.
``frame_scene`` puts the camera target at the centre of the atrium's bounding box and the camera
along ``VIEW_DIRECTION_W``, just far enough for the whole box to be inside Meshcat's default
75 degree field of view. ``Meshcat.SetCameraPose`` stores the camera's position and
target in Meshcat's scene tree, so a page opened later and the self-contained HTML written by
``Meshcat.StaticHtml()`` (the replays) open on the same view; the person can orbit away from it.

The procedural atrium (``drake_models.heart``): frame H = world; the left veins leave the
chamber laterally (+x, a little posterior), the right veins posteriorly (-y, a little to the
right), and each target ring faces into the chamber around its veins. The default view looks
from anterior (+y), a little from the right (-x) and from above, through the semi-transparent
anterior wall: about 45 degrees from either ring's facing direction, so both rings show.
"""

from __future__ import annotations

import numpy as np

# From the scene's centre towards the camera (world frame, any length).
VIEW_DIRECTION_W = (-0.25, 1.0, 0.3)
MESHCAT_FOV_DEG = 75.0  # meshcat's default perspective camera (vertical field of view)
MARGIN = 1.1  # the camera stands this much farther than the tightest fit


SHEATH_IN_VIEW = 0.02  # [m] of a solid's sheath, back from its tip, kept in view

# The marker at each target's centre (a small sphere on the wall, in the scene's geometry: the
# quasi-static engine's and the plant's), poking through the target's disc: Okabe-Ito yellow
# #F0E442, apart from the disc's blue and vermillion for colour-blind readers too (a green dot
# on the vermillion disc of a touched target was the red-green pair), and 0.8 mm in radius (at
# 0.6 mm it showed as a dot of a few pixels).
TARGET_CENTRE_RGBA = (0.941, 0.894, 0.259, 1.0)
TARGET_CENTRE_RADIUS = 0.8e-3  # [m]


def atrium_box(heart) -> tuple[np.ndarray, np.ndarray]:
    """The axis-aligned bounding box (lower (3,), upper (3,)) [m] of an atrium's blood side;
    for a solid phantom part (``side == "solid"``: the chain works outside it) the box also holds
    the sheath's tip and its last ``SHEATH_IN_VIEW``, which stand in free space.

    Args:
        heart: an ``Atrium`` (its ``blood_surface``: the procedural atrium's endocardium with
            the vein tubes, a user's surface).
    """
    V = np.asarray(heart.blood_surface[0], float)
    if getattr(heart, "side", "lumen") == "solid":
        tip = np.asarray(heart.p_HE, float)
        V = np.vstack([V, tip, tip - SHEATH_IN_VIEW * np.asarray(heart.sheath_axis_H, float)])
    return V.min(axis=0), V.max(axis=0)


def camera_pose_for_box(lower, upper, direction_W=VIEW_DIRECTION_W, fov_deg: float = MESHCAT_FOV_DEG,
                        margin: float = MARGIN) -> tuple[np.ndarray, np.ndarray]:
    """Camera position and target that frame a box.

    The camera looks at the box's centre from along ``direction_W``, at the smallest distance
    from which each of the box's corners is inside the view's vertical field of view, both up and
    down and sideways (so in any window at least as wide as it is tall), times ``margin``.

    Args:
        lower, upper: (3,) the box's corners [m].
        direction_W: (3,) from the target towards the camera (any length, not vertical).
        fov_deg: the camera's vertical field of view [deg].
        margin: >= 1: how much farther than the tightest fit.

    Returns:
        (p_WC (3,) camera position, p_WT (3,) target: the box's centre) [m].
    """
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    u = np.asarray(direction_W, float)
    u = u / np.linalg.norm(u)
    centre = 0.5 * (lower + upper)
    # The camera's right and up axes (Meshcat keeps the camera's up towards +z).
    right = np.cross(-u, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, -u)
    half = 0.5 * (upper - lower)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    # A corner c is in view when max(|c.right|, |c.up|) <= tan(fov/2) (distance - c.u).
    tan_half = np.tan(0.5 * np.radians(fov_deg))
    lateral = np.maximum(np.abs(corners @ right), np.abs(corners @ up))
    distance = margin * float(np.max(corners @ u + lateral / tan_half))
    return centre + distance * u, centre


def frame_box(meshcat, lower, upper, direction_W=VIEW_DIRECTION_W, hide_grid: bool = True
              ) -> tuple[np.ndarray, np.ndarray]:
    """Point Meshcat's camera at a box's centre from where the whole box is in view.

    Args:
        meshcat: the Meshcat.
        lower, upper, direction_W: as ``camera_pose_for_box``.
        hide_grid: hide Meshcat's ground grid and world axes: both are sized for metres (grid
            lines 0.5 m apart), so at the scale of a heart the only parts in view are lines
            through the origin that cross the scene like stray force arrows.

    Returns:
        (p_WC, p_WT) as ``camera_pose_for_box``.
    """
    p_WC, p_WT = camera_pose_for_box(lower, upper, direction_W)
    meshcat.SetCameraPose(p_WC, p_WT)
    if hide_grid:
        meshcat.SetProperty("/Grid", "visible", False)
        meshcat.SetProperty("/Axes", "visible", False)
    return p_WC, p_WT


def box_with_points(lower, upper, points=None) -> tuple[np.ndarray, np.ndarray]:
    """The box (lower, upper) grown to hold ``points`` ((k, 3) [m], e.g. the magnets' centres; None
    or empty: the box as it is)."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    P = np.asarray([] if points is None else points, float).reshape(-1, 3)
    return (np.minimum(lower, P.min(axis=0)), np.maximum(upper, P.max(axis=0))) if len(P) else (lower, upper)


def frame_scene(meshcat, heart=None, chain_length: float | None = None, p_W_base=None, points=None):
    """Frame the atrium, or in free space the chain's reach, in Meshcat's camera.

    A replay page frames the atrium and the magnets once its scene has loaded
    (``replay_files.replay_overlay``, with this module's view direction, field of view and margin).

    Args:
        meshcat: the Meshcat.
        heart: the atrium (``LeftAtrium`` or ``UserAtrium``), or None (free space).
        chain_length: without a heart, the chain's length [m]: the view frames a cube of twice
            that side around ``p_W_base`` (everywhere the chain can swing to).
        p_W_base: (3,) without a heart, where the chain starts [m] (default: the origin).
        points: (k, 3) more points to keep in view [m] (e.g. the magnets' centres), or None.

    Returns:
        (p_WC, p_WT) [m], or None when there is nothing to frame (no heart, no chain length).
    """
    if heart is not None:
        return frame_box(meshcat, *box_with_points(*atrium_box(heart), points))
    if chain_length is None or not chain_length > 0:
        return None
    base = np.zeros(3) if p_W_base is None else np.asarray(p_W_base, float)
    return frame_box(meshcat, *box_with_points(base - chain_length, base + chain_length, points))
