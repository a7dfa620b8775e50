"""The scenario's ``world:`` block (``chain_scenario.ChainScenario.world``): which world the
station's physics plays, unknown to the planner, the navigator's force model and the simulated
operator (``drake_models.world``; applied by ``systems.world_apply``).

No ``from __future__ import annotations``: pydrake's ``yaml_load_typed`` reads the dataclass's
field types as objects.
"""

import numbers
import typing
from dataclasses import dataclass, field

from ballchain.drake_models.world import NAMES, PRESETS, WorldMagnitudes, preset
from ballchain.infrastructure.errors import UserInputError, short_repr


@dataclass
class WorldScenario:
    """The world the station plays (``drake_models.world``: the perturbations, their laws and
    sources).

    Attributes:
        preset: "none" (the perfect world: the model's own numbers, the default) or
            "literature" (every perturbation at its published magnitude).
        only: the perturbations kept (the others 0), e.g. ``[magnet_position]``; empty: all of
            the preset's.
        scale: every magnitude times this (1: the preset's).
        seed: the world's draw; absent: the scenario's ``random_seed`` (0 when that is absent
            too). The procedure sets it to its seed.
    """

    preset: str = "none"
    only: typing.List[str] = field(default_factory=list)
    scale: float = 1.0
    seed: typing.Optional[int] = None

    def magnitudes(self) -> WorldMagnitudes:
        """The magnitudes this block asks for (a checked block)."""
        m = preset(self.preset)
        if self.only:
            m = m.only(self.only)
        if self.scale != 1.0:
            m = WorldMagnitudes(**{k: v * self.scale for k, v in m.to_dict().items()})
        return m

    @property
    def perturbed(self) -> bool:
        return any(v != 0.0 for v in self.magnitudes().to_dict().values())


def check_world(s) -> None:
    """The scenario's ``world`` block: a known preset, known perturbations, a scale in 0..10, a
    seed in 0..2**32-1; a perturbed world needs the ball chain on the quasi-static engine (the
    world applies where that engine is built).

    Raises:
        UserInputError: naming the field, the value and what is allowed.
    """
    w = s.world
    if not isinstance(w, WorldScenario):
        raise UserInputError(f"scenario world must be a mapping (preset, only, scale, seed), got {short_repr(w)}")
    if w.preset not in PRESETS:
        raise UserInputError(f"scenario world.preset must be one of {', '.join(PRESETS)}, got {short_repr(w.preset)}")
    if not isinstance(w.only, list) or any(name not in NAMES for name in w.only):
        raise UserInputError(f"scenario world.only must be a list of {', '.join(NAMES)}, got {short_repr(w.only)}")
    if isinstance(w.scale, bool) or not isinstance(w.scale, numbers.Real) or not 0.0 <= w.scale <= 10.0:
        raise UserInputError(f"scenario world.scale must be a number in 0..10, got {short_repr(w.scale)}")
    if w.seed is not None and (isinstance(w.seed, bool) or not isinstance(w.seed, numbers.Integral)
                               or not 0 <= w.seed <= 2**32 - 1):
        raise UserInputError(f"scenario world.seed must be absent or an integer in 0..{2**32 - 1}, "
                             f"got {short_repr(w.seed)}")
    w.magnitudes()  # each magnitude in its range
    if w.perturbed and (s.device != "ball_chain" or s.engine != "statics"):
        raise UserInputError(f"scenario world.preset {w.preset!r} perturbs the quasi-static engine's world: it needs "
                             f"device ball_chain and engine statics, got device {s.device!r}, engine {s.engine!r}")


def world_seed(s) -> int:
    """The world's seed: ``world.seed``, else the scenario's ``random_seed``, else 0."""
    if s.world.seed is not None:
        return int(s.world.seed)
    return 0 if s.random_seed is None else int(s.random_seed)
