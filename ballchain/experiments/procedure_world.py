"""The procedure in a world the navigator does not know (issue 43): the run's ``world`` argument
turned into the scenario's ``world:`` block (``systems.world_scenario``; the perturbations,
their laws and sources in ``drake_models.world``).
"""

from __future__ import annotations

import json

from ballchain.drake_models.world import NAMES, PRESETS
from ballchain.infrastructure.errors import UserInputError, short_repr

WORLDS = tuple(PRESETS)


def world_block(world, seed: int) -> dict | None:
    """The scenario's ``world:`` block for a run's ``world``: a preset name ("none": None, the
    perfect world) or a mapping {preset, only, scale, seed} (the seed defaulting to the run's).

    Raises:
        UserInputError: another name, or a mapping with other keys.
    """
    if isinstance(world, str):
        if world not in PRESETS:
            raise UserInputError(f"world must be one of {', '.join(WORLDS)} (or a mapping: preset, only, scale, "
                                 f"seed), got {short_repr(world)}")
        world = {"preset": world}
    if not isinstance(world, dict) or not set(world) <= {"preset", "only", "scale", "seed"}:
        raise UserInputError(f"world must be a preset name ({', '.join(WORLDS)}) or a mapping of preset, only, scale, "
                             f"seed, got {short_repr(world)}")
    if world.get("preset", "none") not in PRESETS:
        raise UserInputError(f"world preset must be one of {', '.join(WORLDS)}, got {short_repr(world.get('preset'))}")
    only = world.get("only", [])
    if isinstance(only, str):
        only = [only]
    if not isinstance(only, (list, tuple)) or any(name not in NAMES for name in only):
        raise UserInputError(f"world only must name perturbations among {', '.join(NAMES)}, got {short_repr(only)}")
    block = {"preset": world.get("preset", "none"), "only": list(only), "scale": world.get("scale", 1.0),
             "seed": world.get("seed", seed)}
    if block["preset"] == "none" or block["scale"] == 0:
        return None
    return block


def with_world(overrides: str | None, world, seed: int) -> str | None:
    """The scenario overrides with the run's world added (``world_block``); ``overrides`` itself
    for the perfect world.

    Raises:
        UserInputError: a bad world, or overrides that set ``world`` too.
    """
    from ballchain.systems.chain_scenario import parse_overrides

    block = world_block(world, seed)
    if block is None:
        return overrides
    changes = parse_overrides(overrides)
    if "world" in changes:
        raise UserInputError(f"--world {short_repr(world)} and --set world: {short_repr(changes['world'])} both set "
                             "the world; give only one of them")
    return json.dumps({**changes, "world": block})
