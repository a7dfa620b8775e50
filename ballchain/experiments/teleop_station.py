"""The teleoperation station handed over to an operator or a person (``teleop.run``, ``run_live``).

The named scenario with the ``--set`` overrides applied, checked with the engine the hand-over
gives it (``load_for_hand_over``), then the handed units' scripted sticks removed, the mapping
set, the feeder left to the operator and the engine ``DEFAULT_ENGINE`` unless the overrides name
one (``hand_over``). ``teleop`` re-exports every name.
"""

from __future__ import annotations

from ballchain.infrastructure.errors import UserInputError
from ballchain.systems.engine_config import StaticsEngine

MAPPINGS = {"world": "world", "catheter": "tip"}  # user-facing name -> TeleoperationMapper frame
SCENARIO = "teleop_right_unit"
# The station's engine unless the overrides say otherwise: the quasi-static engine
# (``systems/quasi_static_engine.py``: the chain's equilibrium with the atrium's wall every 50 ms),
# whole tasks in seconds. ``--set '{engine: plant}'`` runs the MultibodyPlant (minutes per task).
DEFAULT_ENGINE = StaticsEngine()


def handed_over_engine(mode: str, overrides: dict) -> str | None:
    """The engine ``hand_over`` gives a scenario of ``mode``: ``DEFAULT_ENGINE`` unless
    ``overrides`` (the parsed ``--set`` mapping) name one or it does not run the mode (the
    quasi-static engine runs only the quasi-static mode; None: the scenario keeps its own)."""
    return DEFAULT_ENGINE if "engine" not in overrides and mode in DEFAULT_ENGINE.modes else None


def load_for_hand_over(name: str, overrides: str | None):
    """The named scenario with ``overrides`` applied, checked with the engine the hand-over will
    give it (``handed_over_engine``) rather than the file's: a field that needs the quasi-static
    engine (``wall_motion``) needs no ``engine: statics`` of its own, and one the run's engine
    would ignore is refused before the build.

    Raises:
        UserInputError: as ``chain_scenario.load_scenario``; overrides that leave no magnet unit
            (``units: []``: the operator steers one).
    """
    from ballchain.systems.chain_scenario import apply_overrides, load_scenario, parse_overrides

    changes = parse_overrides(overrides)
    scenario = load_scenario(name)
    engine = handed_over_engine(changes.get("mode", scenario.mode), changes)
    changes = changes if engine is None else {**changes, "engine": engine}
    scenario = apply_overrides(scenario, changes).validate() if changes else scenario
    if not scenario.units:
        raise UserInputError("--set: units is [], which leaves the station no magnet unit to steer; keep the "
                             "scenario's units (a list of mappings updates them: '{units: [{teleop_omega_max: "
                             "1.0}]}')")
    return scenario


def hand_over(scenario, mapping: str, n_balls: int | None, overrides: dict, units=None):
    """The station with the sticks of ``units`` (default: all) and the feeder left to an operator
    or a person: their scripted joysticks removed, the mapping set, the engine ``DEFAULT_ENGINE``
    unless ``overrides`` (the parsed ``--set`` mapping) name one or the mode is not quasi-static."""
    if n_balls is not None and "n_balls" in overrides:
        raise UserInputError(f"--balls {n_balls} and --set n_balls {overrides['n_balls']!r} both give the chain's "
                             "length: give one of them")
    refuse_replaced(scenario, overrides, mapping, scenario.units if units is None else units)
    engine = handed_over_engine(scenario.mode, overrides)
    if engine is not None:
        scenario.engine = engine
    if n_balls is not None:
        scenario.n_balls = n_balls
    for unit in scenario.units if units is None else units:
        unit.joystick = []
        unit.joystick_source = "external"
        unit.teleop_frame = MAPPINGS[mapping]
    ins = scenario.insertion
    ins.feeder, ins.feeder_command = True, "external"
    ins.final = ins.initial
    return scenario.validate()


def refuse_replaced(scenario, overrides: dict, mapping: str, handed) -> None:
    """Refuse the overrides that ``hand_over`` would replace without a word: a handed unit's
    scripted stick (``joystick_source``, ``joystick``: the operator cannot drive a script), its
    mapping (``teleop_frame``: ``--mapping``'s) and the feeder's own motion (``insertion``'s
    ``feeder``, ``feeder_command``, ``final``: the operator feeds the chain). ``scenario`` has the
    overrides applied (its ``units[i]`` is the override's ``units[i]``).

    Raises:
        UserInputError: naming the field, the value and what the run does instead.
    """
    from ballchain.infrastructure.errors import short_repr

    other = "catheter" if mapping == "world" else "world"
    for i, entry in enumerate(overrides.get("units") or []):
        if not isinstance(entry, dict) or i >= len(scenario.units) or not any(scenario.units[i] is u for u in handed):
            continue
        name = scenario.units[i].name
        stick = (f"the stick of unit {name!r} is the operator's (joystick_source: external), who cannot drive a "
                 "script (a scripted stick runs with `ballchain simulate`)")
        allowed = {"joystick_source": ("external", stick), "joystick": ([], stick),
                   "teleop_frame": (MAPPINGS[mapping], f"the mapping of unit {name!r} is --mapping {mapping}'s "
                                                       f"({MAPPINGS[mapping]!r}; --mapping {other} gives "
                                                       f"{MAPPINGS[other]!r})")}
        for key, (kept, why) in allowed.items():
            if key in entry and entry[key] != kept:
                raise UserInputError(f"--set units[{i}].{key}: {short_repr(entry[key])} would be ignored: {why}; "
                                     f"leave {key} out")
    insertion = overrides.get("insertion")
    if isinstance(insertion, dict):
        kept = {"feeder": True, "feeder_command": "external", "final": scenario.insertion.initial}
        for key, value in kept.items():
            if key in insertion and insertion[key] != value:
                raise UserInputError(f"--set insertion.{key}: {short_repr(insertion[key])} would be ignored: the "
                                     f"operator feeds the chain (feeder: true, feeder_command: external, the "
                                     f"insertion starting at insertion.initial); leave {key} out")
