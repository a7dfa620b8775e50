"""Placing the prototype magnet so that it makes a wanted field at the chain's base.

The magnet sits in the chain's plane at ``p_WM = (0, -r, 0)`` (beside the insertion point) and
turns about z, its dipole at angle phi in the x-y plane. At the origin its point-dipole field is
``k |m| / r^3 (-cos phi, 2 sin phi, 0)``, so every field direction theta is reachable with
phi = atan2(sin(theta) / 2, -cos(theta)), and r sets the magnitude.
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.dipole import K_DIPOLE
from ballchain.drake_models.field_sources import FieldModel, MagnetSource, rotation_with_z_along
from ballchain.drake_models.params import CylinderMagnet


def magnet_angle_for_field_angle(theta_rad: float) -> float:
    """Dipole angle phi of a magnet at (0, -r, 0) whose field at the origin points at theta."""
    return float(np.arctan2(0.5 * np.sin(theta_rad), -np.cos(theta_rad)))


def field_angle_for_magnet_angle(phi_rad: float) -> float:
    """Inverse of ``magnet_angle_for_field_angle``."""
    return float(np.arctan2(2.0 * np.sin(phi_rad), -np.cos(phi_rad)))


def side_magnet(phi_rad: float, distance: float, magnet=CylinderMagnet(), model: FieldModel = "dipole") -> MagnetSource:
    """The magnet at (0, -distance, 0) with its dipole at phi in the x-y plane."""
    return MagnetSource(magnet, [0.0, -distance, 0.0],
                        rotation_with_z_along([np.cos(phi_rad), np.sin(phi_rad), 0.0]), model)


def side_magnet_for_field(theta_rad: float, field_T: float, magnet=CylinderMagnet(),
                          model: FieldModel = "dipole") -> MagnetSource:
    """The side magnet whose point-dipole field at the origin is ``field_T`` at angle theta."""
    phi = magnet_angle_for_field_angle(theta_rad)
    shape = np.hypot(np.cos(phi), 2.0 * np.sin(phi))
    distance = (K_DIPOLE * magnet.dipole_moment * shape / field_T) ** (1.0 / 3.0)
    return side_magnet(phi, distance, magnet, model)
