"""The ablation electrode's touch of a target: one rule for the ball chain's tip ball and the
manual catheter's distal electrode (issue 45).

A target is a circle of radius R_T on the wall around p_T (unit normal n_T into the chamber).
An electrode is a capsule: the points within its radius r of the axis segment from a (its
proximal end on the axis) to b (the centre of its distal dome). It touches the target when some
point of its surface within ``tolerance`` of the wall's tangent plane lies over the target's
circle: some axis point x(s) = a + s (b - a), s in [0, 1], with height |h(s)| <= r + tolerance
above the plane (h = (x - p_T) . n_T: the surface point below it within the tolerance of the
wall, or in it) and lateral distance |x(s) - p_T - h(s) n_T| <= R_T (the contact point below it
on the circle). h is linear in s, the lateral distance's square quadratic: the s where the
height holds form one interval, and the least lateral distance over it is the clamped
projection. The wall's curvature is ignored over the electrode (as over the target:
``systems.target_contact``).

* The ball chain's tip ball: a = b (a sphere), the rule of the robotic arm unchanged (its exact
  expressions: ``touches`` with a zero-length axis).
* The manual catheter's distal electrode: a cylinder of the catheter's radius closed by a
  hemispherical dome, ``CATHETER_ELECTRODE_LENGTH`` = 3.5 mm long, its proximal edge taken as
  the axis's end (its flat proximal face, against the shaft, cannot touch alone). Sources: the
  TactiCath SE contact-force ablation catheter (Abbott, the maker of the paper's TactiFlex) has a
  3.5 mm distal electrode (Calzolari et al., in vitro lesions with a 3.5 mm open-irrigated
  CF-sensing tip; a comparison of catheter contact angles listing the distal tips of IntellaNav
  MiFi OI 4.5 mm, IntellaNav StablePoint 4.0 mm and TactiCath SE 3.5 mm); the standard
  non-irrigated tip is 4 mm on a 7 Fr catheter (a 7 Fr / 4 mm tip against 8 mm tips, surface
  areas 29 and 59 mm^2, J. Interv. Card. Electrophysiol. 2(3):279-284, 1998). The electrode's
  diameter is taken as the catheter's 8 Fr (the paper's).
"""

from __future__ import annotations

import numpy as np

CATHETER_ELECTRODE_LENGTH = 3.5e-3  # [m] the distal electrode, dome included (module docstring)


def axis_start(centre, direction, radius: float, length: float) -> np.ndarray:
    """The proximal end of the electrode's axis: ``length - radius`` behind the dome's centre
    ``centre`` along the unit tip ``direction`` (the dome's centre itself for a ball)."""
    return np.asarray(centre, float) - max(float(length) - float(radius), 0.0) * np.asarray(direction, float)


def touches(b, p_WT: np.ndarray, n_W: np.ndarray, radius: float, target_radius: float, tolerance: float,
            a=None) -> np.ndarray:
    """Which targets the electrode touches (module docstring).

    Args:
        b: (3,) the distal dome's centre (a ball's centre) [m].
        p_WT: (n, 3) target centres on the wall [m]; n_W: (n, 3) unit wall normals into the chamber.
        radius: the electrode's radius [m]; target_radius: [m]; tolerance: [m].
        a: (3,) the axis's proximal end [m] (None: a ball at ``b``).

    Returns:
        (n,) bool.
    """
    rel_b = np.asarray(b, float) - p_WT
    h_b = (rel_b * n_W).sum(axis=1)
    reach = radius + tolerance
    if a is None or not np.any(np.asarray(a, float) != np.asarray(b, float)):
        lateral2 = (rel_b * rel_b).sum(axis=1) - h_b * h_b  # |rel|^2 = h^2 + lateral^2
        return (np.abs(h_b) <= reach) & (lateral2 <= target_radius**2)
    rel_a = np.asarray(a, float) - p_WT
    h_a = (rel_a * n_W).sum(axis=1)
    dh = h_b - h_a
    # The s in [0, 1] where |h_a + s dh| <= reach.
    flat = np.abs(dh) < 1e-15
    with np.errstate(divide="ignore", invalid="ignore"):
        s_lo = np.where(flat, 0.0, np.minimum((-reach - h_a) / dh, (reach - h_a) / dh))
        s_hi = np.where(flat, 1.0, np.maximum((-reach - h_a) / dh, (reach - h_a) / dh))
    s_lo = np.where(flat & (np.abs(h_a) > reach), 2.0, np.maximum(s_lo, 0.0))
    s_hi = np.minimum(s_hi, 1.0)
    some = s_lo <= s_hi
    # The lateral vectors at both ends and the least lateral distance over [s_lo, s_hi].
    la = rel_a - h_a[:, None] * n_W
    lb = rel_b - h_b[:, None] * n_W
    d = lb - la
    dd = (d * d).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_star = np.where(dd > 0, -(la * d).sum(axis=1) / dd, 0.0)
    s_star = np.clip(s_star, s_lo, np.maximum(s_hi, s_lo))
    closest = la + s_star[:, None] * d
    return some & ((closest * closest).sum(axis=1) <= target_radius**2)
