"""The steerable catheter's shaft braid in torsion: the netting formula against the stretch of
the helical wires computed from their geometry, and the stated construction's numbers by hand."""

from __future__ import annotations

import numpy as np
import pytest

from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.steerable_catheter import SteerableCatheter


def _braid_GJ_from_geometry(cat: SteerableCatheter, twist_rate: float = 1e-3) -> float:
    """GJ from the wires' strain energy: a unit length of shaft twisted by ``twist_rate``; each
    wire a helix on the braid's cylinder whose unrolled length is sqrt(L^2 + s^2), s its
    circumferential travel (L tan(alpha), plus or minus R_b times the twist)."""
    L, R, a = 1.0, cat.braid_radius, cat.braid_angle
    area = np.pi * cat.braid_wire_diameter**2 / 4.0
    energy = 0.0
    for sign in (+1.0, -1.0):  # the two sets of wires, N/2 each way
        s0 = sign * L * np.tan(a)
        length0 = np.hypot(L, s0)
        length1 = np.hypot(L, s0 + R * twist_rate * L)
        strain = length1 / length0 - 1.0
        energy += 0.5 * cat.braid_wires * cat.braid_modulus * area * strain**2 * length0 / 2.0
    return 2.0 * energy / (twist_rate**2 * L)


@pytest.mark.parametrize("angle_deg", [30.0, 45.0, 60.0])
def test_netting_formula_matches_the_wires_stretch(angle_deg):
    cat = SteerableCatheter(braid_angle=np.radians(angle_deg)).validate()
    assert cat.braid_GJ == pytest.approx(_braid_GJ_from_geometry(cat), rel=1e-3)


def test_stated_construction_by_hand():
    """16 wires of 0.002 in at 60 degrees on a 1.1 mm radius, 193 GPa: by hand
    16 * 193e9 * (pi / 4) (50.8e-6)^2 * (1.1e-3)^2 * (3 / 4) * (1 / 2) = 2.840e-3 N m^2; the plain
    Pebax tube's GJ 500e6 * pi (d_o^4 - d_i^4) / 64 / 1.45 with d_o = 8/3 mm, d_i = 1.5 mm."""
    cat = SteerableCatheter().validate()
    by_hand = 16 * 193e9 * (np.pi / 4) * 50.8e-6**2 * 1.1e-3**2 * 0.75 * 0.5
    assert cat.braid_GJ == pytest.approx(by_hand, rel=1e-12)
    plain = 500e6 * np.pi * ((8e-3 / 3) ** 4 - 1.5e-3**4) / 64 / 1.45
    assert cat.plain_GJ == pytest.approx(plain, rel=1e-12)
    assert cat.shaft_GJ == pytest.approx(plain + by_hand, rel=1e-12)
    assert SteerableCatheter(braid_wires=0).validate().shaft_GJ == pytest.approx(plain, rel=1e-12)


@pytest.mark.parametrize("field, value", [("braid_wires", 15), ("braid_wires", -2), ("braid_angle", np.pi / 2),
                                          ("braid_radius", 2e-3), ("braid_wire_diameter", 0.0)])
def test_bad_braid_is_refused(field, value):
    with pytest.raises(UserInputError, match=field):
        SteerableCatheter(**{field: value}).validate()
