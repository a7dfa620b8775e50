"""The station's models from a scenario, before any diagram: its atrium (``atrium_for``), the
scenario placed on a loaded anatomy (``apply_anatomy``), its fixed external field
(``field_source_for``). ``station.MakeStation``'s first steps use them; ``station`` re-exports them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ballchain.drake_models.atrium import Atrium
from ballchain.infrastructure.errors import UserInputError, short_repr, quote_path
from ballchain.drake_models.field_sources import FieldSource, FieldSources, MagnetSource, UniformField
from ballchain.drake_models.heart import HeartParams, LeftAtrium
from ballchain.drake_models.params import CylinderMagnet, SphereMagnet
from ballchain.systems.chain_scenario import ChainScenario
from ballchain.drake_models.anatomy import load_anatomy
from ballchain.drake_models.atrium_mesh import UserAtrium, load_atrium_surface
from ballchain.drake_models.model_files import resolve_uri



def atrium_for(scenario: ChainScenario) -> Atrium:
    """The scenario's atrium: its anatomy file's (``anatomy``), the user's surface when
    ``atrium_file`` is set, else procedural."""
    if scenario.anatomy:

        return load_anatomy(scenario.anatomy).atrium()
    if not scenario.atrium_file:
        return LeftAtrium(HeartParams(scale=scenario.heart_scale, subdivisions=scenario.heart_subdivisions))

    path = scenario.atrium_file
    path = resolve_uri(path) if path.startswith("package://") else Path(path)
    try:
        surface = load_atrium_surface(path, scenario.atrium_units)
    except UserInputError as err:  # name the scenario field the user typed
        raise UserInputError(f"scenario atrium_file: {err}") from None
    return UserAtrium(surface, scenario.puncture, scenario.sheath_aim or None)


def apply_anatomy(scenario: ChainScenario, anatomy, units=None) -> ChainScenario:
    """The scenario on a loaded anatomy (``drake_models.anatomy.Anatomy``): ``anatomy`` names its
    file, and the units (default: all), in order, stand at its magnets (``p_WM``).

    Raises:
        UserInputError: fewer magnets in the file than units to place (naming the file).
    """
    from dataclasses import replace

    units = scenario.units if units is None else units
    if len(anatomy.magnets) < len(units):
        raise UserInputError(f"anatomy file {quote_path(anatomy.path)}: magnets gives {len(anatomy.magnets)} "
                             f"unit position(s), the station has {len(units)} unit(s): give one per unit")
    scenario.anatomy = str(anatomy.path)
    fresh = type(units[0])() if units else None
    for unit, p_WM in zip(units, anatomy.magnets):
        placed = replace(unit, p_WM=[float(v) for v in p_WM], anchor=fresh.anchor, distance=fresh.distance,
                         direction_W=list(fresh.direction_W))
        scenario.units[next(k for k, u in enumerate(scenario.units) if u is unit)] = placed
    return scenario.validate()


def field_source_for(scenario: ChainScenario, p_WP: np.ndarray) -> FieldSource | None:
    """The scenario's fixed external field (a FieldSource or None); p_WP is the puncture [m]."""
    sources = []
    if np.any(np.asarray(scenario.uniform_field) != 0.0):
        sources.append(UniformField(np.asarray(scenario.uniform_field, float)))
    for m in scenario.magnets:
        magnet = CylinderMagnet() if m.shape == "cylinder" else SphereMagnet()
        if m.p_WM:
            p_WM = np.asarray(m.p_WM, float)
        else:
            u = np.asarray(m.direction_W, float)
            p_WM = p_WP + m.distance_from_puncture * u / np.linalg.norm(u)
        sources.append(MagnetSource.pointing(magnet, p_WM, m.m_hat_W, m.model))
    if not sources:
        return None
    return sources[0] if len(sources) == 1 else FieldSources(sources)
