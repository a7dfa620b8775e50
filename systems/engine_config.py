"""The scenario's engine and device as typed configs (``ChainScenario.engine``, ``.device``).

Each engine and each device has a config class; the scenario holds one of each, a tagged union
in the manner of drake's ``yaml_load_typed`` unions and manipulation's ``model_drivers``. The
YAML gives either the plain name or the tagged form (the tag is the name in CamelCase)::

    engine: statics                 # the plain name (every scenario file so far)
    engine: !Statics {}             # the same engine, tagged
    device: !SteerableCatheter {}   # device: steerable_catheter

==========================  ====================  ==============================================
config                      name (tag)            what it says about the scenario
==========================  ====================  ==============================================
``PlantEngine``             plant (!Plant)        the MultibodyPlant: both modes, stepped at the
                                                  ``time_step``; reads ``plant_config``, the
                                                  slide gains and the joints' damping; holds a pin
``StaticsEngine``           statics (!Statics)    the quasi-static engine: quasi-static only,
                                                  stepped at ``statics_period``; moves the wall
``BallChainDevice``         ball_chain            the magnetic chain: takes the moving wall
                            (!BallChain)
``SteerableCatheterDevice`` steerable_catheter    the manual catheter: no units, quasi-static,
                            (!SteerableCatheter)  in an atrium
==========================  ====================  ==============================================

A config validates the scenario for itself (``check``, run by ``scenario_checks.check_fields``)
and answers the questions the checks and the experiments used to ask of the name
(``has_plant``, ``moves_wall``, ``holds_pin``, ``update``, ``own_period``, ``takes_wall_motion``).
The configs hold no settings of their own yet: the statics engine's period stays the scenario's
``statics_period`` (a hand-over switches the engine after the overrides, which may set it).

A config is a ``str`` whose text is its name, so the name reads as it always did wherever code
reads it (``scenario.engine == "statics"``, the device models' ``(device, engine)`` registry,
JSON results, messages), and a plain name set on a scenario is converted (``engine_config``,
``device_config``). A device or engine registered without a config class of its own
(``device_model.register_device_model``) gets the base class's (``DeviceConfig(name)``).

A new engine is a subclass here with its answers, in ``ENGINE_CONFIGS``; a new device needs a
config class only to check something of its own (``DEVICE_CONFIGS``).
"""

from typing import ClassVar

from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.systems.chain_plant import ChainPlantConfig, chain_multibody_plant_config


def tag_of(name: str) -> str:
    """The YAML tag of a registered name: its CamelCase ("steerable_catheter" -> "!SteerableCatheter")."""
    return "!" + "".join(part[:1].upper() + part[1:] for part in str(name).split("_"))


class ScenarioChoice(str):
    """A typed config that is its name: the base of ``EngineConfig`` and ``DeviceConfig``.

    ``Class()`` is the class's own ``name``; ``Class(name)`` (the base classes) any registered one.
    """

    __slots__ = ()
    kind: ClassVar[str] = ""  # the scenario's field: "engine" or "device"
    NAME: ClassVar[str] = ""  # a subclass's own name ("" on the base classes: any name)

    def __new__(cls, name: str | None = None):
        own = cls.__dict__.get("NAME", "")
        if name is None:
            name = own
        if not isinstance(name, str) or not name or (own and name != own):
            raise ValueError(f"{cls.__name__}: the {cls.kind} name must be {own!r}, got {name!r}"
                             if own else f"{cls.__name__}: the {cls.kind} needs a name, got {name!r}")
        return str.__new__(cls, name)

    @property
    def name(self) -> str:
        """The name, as a plain ``str``."""
        return str.__str__(self)

    @property
    def tag(self) -> str:
        """The YAML tag of this config (``!Statics``)."""
        return tag_of(self)

    def check(self, s) -> None:
        """Refuse a scenario ``s`` this choice cannot run (UserInputError naming the field)."""


class EngineConfig(ScenarioChoice):
    """An engine: how the device's state is advanced. The class attributes are its answers.

    Attributes:
        modes: the scenario modes it runs.
        why_modes: why only those (for the message).
        has_plant: it builds the MultibodyPlant and reads its settings (``plant_config``, the
            slide gains, the quasi-static joints' damping).
        moves_wall: it places a moving wall at each update (``wall_motion``).
        holds_pin: it can hold a force-sensor pin on the tip (``pin``).
    """

    __slots__ = ()
    kind = "engine"
    modes: ClassVar[tuple[str, ...]] = ("quasi-static",)
    why_modes: ClassVar[str] = "the engine solves equilibria"
    has_plant: ClassVar[bool] = False
    moves_wall: ClassVar[bool] = False
    holds_pin: ClassVar[bool] = False

    def update(self, s) -> tuple[str, float]:
        """(field, period [s]) of the engine's updates in scenario ``s``."""
        return "statics_period", s.statics_period

    def own_period(self, s) -> float | None:
        """The engine's own update period [s] (``statics_period``); None when the plant's time
        step sets the pace."""
        field, period = self.update(s)
        return period if field == "statics_period" else None

    def check(self, s) -> None:
        if s.mode not in self.modes:
            raise UserInputError(f"scenario engine: {self} needs mode: {' or '.join(self.modes)} ({self.why_modes}), "
                                 f"got {s.mode!r}")
        if not self.has_plant:  # a plant setting would be silently ignored
            if repr(s.plant_config) != repr(chain_multibody_plant_config()):
                raise UserInputError(f"scenario plant_config configures the MultibodyPlant: engine: {self} does not "
                                     "read it (leave plant_config out, or use engine: plant)")
            if list(s.insertion.slide_gains) != list(ChainPlantConfig.feeder_gains):
                raise UserInputError(f"scenario insertion.slide_gains are the plant's slide actuator: engine: {self} "
                                     "does not read them (leave them out, or use engine: plant)")


class PlantEngine(EngineConfig):
    """``engine: plant`` (``!Plant``): the MultibodyPlant, the reference and the only one for dynamics."""

    __slots__ = ()
    NAME = "plant"
    modes = ("quasi-static", "dynamics")
    has_plant = True
    holds_pin = True

    def update(self, s) -> tuple[str, float]:
        return "time_step", s.effective_time_step


class StaticsEngine(EngineConfig):
    """``engine: statics`` (``!Statics``): the equilibrium solved every ``statics_period``
    (``systems/quasi_static_engine.py``), quasi-static mode only."""

    __slots__ = ()
    NAME = "statics"
    moves_wall = True


class DeviceConfig(ScenarioChoice):
    """A device. The class attributes are its answers.

    Attributes:
        takes_wall_motion: the moving wall (``wall_motion``) is modelled for it.
    """

    __slots__ = ()
    kind = "device"
    takes_wall_motion: ClassVar[bool] = False


class BallChainDevice(DeviceConfig):
    """``device: ball_chain`` (``!BallChain``): the magnetic chain, the default."""

    __slots__ = ()
    NAME = "ball_chain"
    takes_wall_motion = True


class SteerableCatheterDevice(DeviceConfig):
    """``device: steerable_catheter`` (``!SteerableCatheter``): the paper's manual comparison arm,
    an 8 Fr steerable catheter in the same atrium and sheath (``systems/catheter_station.py``)."""

    __slots__ = ()
    NAME = "steerable_catheter"

    def check(self, s) -> None:
        if s.units or s.mode != "quasi-static" or not (s.heart or s.atrium_file):
            raise UserInputError("scenario device: steerable_catheter is a manual catheter in the atrium: it needs "
                                 "no units (units: []), mode: quasi-static and an atrium")


ENGINE_CONFIGS: dict[str, type[EngineConfig]] = {c.NAME: c for c in (PlantEngine, StaticsEngine)}
DEVICE_CONFIGS: dict[str, type[DeviceConfig]] = {c.NAME: c for c in (BallChainDevice, SteerableCatheterDevice)}
CHOICES = {"engine": (EngineConfig, ENGINE_CONFIGS), "device": (DeviceConfig, DEVICE_CONFIGS)}


def choice_config(kind: str, value) -> ScenarioChoice:
    """The config of scenario field ``kind`` ("engine" or "device") for ``value``: a config as it
    is, a name as its class's config (a name without a class of its own: the base class's, which
    the checks then refuse unless a device model registers it)."""
    base, classes = CHOICES[kind]
    if isinstance(value, base):
        return value
    return classes[value]() if value in classes else base(value)


def engine_config(value) -> EngineConfig:
    """``choice_config("engine", value)``: ``engine_config("statics") == StaticsEngine()``."""
    return choice_config("engine", value)


def device_config(value) -> DeviceConfig:
    """``choice_config("device", value)``."""
    return choice_config("device", value)


def choice_name(kind: str, value, names, where: str) -> str:
    """The name a YAML value of field ``kind`` gives: a plain name as it is (an unknown one is
    refused by the checks, naming the allowed ones), or a tagged config (``!Statics {}``, read by
    ``safe_yaml.load_yaml`` as ``{"_tag": "!Statics"}``) as its name.

    Args:
        names: the registered names (``device_model.ENGINES`` or ``DEVICES``).
        where: what the YAML came from ("--set", "scenario 'heart_left'").

    Raises:
        UserInputError: "{where}: {kind} must be ...", naming the allowed names and tags.
    """
    tags = {tag_of(n): n for n in names}
    allowed = f"one of {', '.join(map(repr, names))} or a tagged config ({', '.join(f'{t} {{}}' for t in tags)})"
    if isinstance(value, str):
        return str(value)
    if isinstance(value, dict) and "_tag" in value:
        tag = value["_tag"]
        if tag not in tags:
            raise UserInputError(f"{where}: {kind} tag {short_repr(tag)} is not a {kind}; {kind} must be {allowed}")
        extra = [k for k in value if k != "_tag"]
        if extra:
            raise UserInputError(f"{where}: {kind} {tag} takes no settings, got {short_repr(extra[0])} "
                                 f"(give {tag} {{}})")
        return tags[tag]
    raise UserInputError(f"{where}: {kind} must be {allowed}, got {short_repr(value)}")


def choice_tags(names_by_kind) -> tuple[str, ...]:
    """The YAML tags of every registered name (``safe_yaml.load_yaml``'s ``tags``)."""
    return tuple(tag_of(n) for names in names_by_kind for n in names)


def choices_with(kind: str, names, answer: str) -> str:
    """The names among ``names`` whose config answers ``answer`` (an attribute) true, as
    "a or b" for a message: ``choices_with("engine", ENGINES, "holds_pin") == "plant"``."""
    return " or ".join(n for n in names if getattr(choice_config(kind, n), answer))
