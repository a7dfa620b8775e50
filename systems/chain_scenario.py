"""Scenario schema of the chain-in-a-heart simulation, and loading of named scenarios.

A scenario is data: the dataclass ``ChainScenario`` is the schema, named scenarios live in
``drake_models/station.scenarios.yaml`` (loaded with pydrake's ``yaml_load_typed``), and any
field can be overridden with inline YAML (``load_scenario("heart_left", "{duration: 0.01}")``).
All quantities are SI: m, s, T, N, kg. Drake's own config structs are fields of the scenario
(``plant_config: MultibodyPlantConfig``, ``simulator_config: SimulatorConfig``,
``visualization: VisualizationConfig``); the time step has one home, ``time_step``. The station
builder (``systems/station.py``) turns a scenario into a diagram.

The scenario's parts live in ``scenario_schema.py``, its checks (``validate``) in
``scenario_checks.py``; this module keeps ``ChainScenario`` and the loading, and re-exports
every name of both. No ``from __future__ import annotations``: pydrake's ``yaml_load_typed``
reads the dataclasses' field types as objects.
"""


import dataclasses
import typing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.multibody.plant import MultibodyPlantConfig
from pydrake.systems.analysis import SimulatorConfig
from pydrake.visualization import VisualizationConfig

from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.infrastructure.safe_files import register_input
from ballchain.infrastructure.safe_yaml import check_value  # noqa: F401 (the sweep's check imports it from here)
from ballchain.infrastructure.safe_yaml import (check_yaml_schema, load_typed, load_yaml, load_yaml_file,
                                             schema_fields as _schema_fields, yaml_kind)
from ballchain.systems.chain_plant import ContactConfig, chain_multibody_plant_config
# ENGINES, DEVICES: live views of the one registry of device models (``device_model.DEVICE_MODELS``):
# the ball chain on "plant" or "statics", the paper's manual comparison arm, and any registered.
from ballchain.systems.device_model import DEVICE_MODELS, DEVICES, ENGINES, engines  # noqa: F401
# The engine and the device as typed configs (a plain name is converted: ``choice_config``).
from ballchain.systems.engine_config import (CHOICES, BallChainDevice, DeviceConfig, EngineConfig,  # noqa: F401
                                             PlantEngine, StaticsEngine, choice_config, choice_name, choice_tags)
from ballchain.systems.unit_config import MagnetUnitConfig
from ballchain.systems.world_scenario import WorldScenario
# The parts and the checks, re-exported (their homes: scenario_schema.py, scenario_checks.py).
from ballchain.systems.scenario_schema import (ANCHORS, CONTACT_MODELS, CONTACT_SURFACE_REPRESENTATIONS,  # noqa: F401
                                               DEFAULT_TIME_STEP, DISCRETE_CONTACT_APPROXIMATIONS,
                                               FEEDER_COMMANDS, JOYSTICK_SOURCES, MODES, TELEOP_FRAMES,
                                               UNIT_SYSTEMS, VISUALIZATION_FIELDS_USED, InsertionScenario,
                                               LocalisationScenario, MagnetScenario, OscillationScenario,
                                               PinScenario, WallMotionScenario, _oscillation,
                                               station_visualization_config)
from ballchain.systems.scenario_checks import (CONTACT_BOUNDS, MAX_BALLS, MAX_DISTANCE,  # noqa: F401
                                               MAX_DURATION, MAX_DYNAMICS_STEP, MAX_SLIDE_KP, MAX_STEPS,
                                               MAX_TIME_STEP, MAX_UNIFORM_FIELD, MIN_SAMPLES_PER_CYCLE,
                                               MIN_TIME_STEP, PLANT_CONFIG_BOUNDS, _a, _check_kind,
                                               _check_unit_numbers, _direction, _finite_fields,
                                               _list_item_schema, _one_of, _plain, _point, _require,
                                               _whole_steps, check_anatomy_field, check_atrium,
                                               check_atrium_file, check_contact, check_drake_configs,
                                               check_field_sources, check_fields, check_insertion,
                                               check_kinds, check_pin, check_steps, check_timing,
                                               check_units, check_wall_motion, update_periods)

SCENARIOS_FILE = Path(__file__).resolve().parents[1] / "drake_models" / "station.scenarios.yaml"
if not SCENARIOS_FILE.exists():  # installed (non-editable) layout
    from ballchain import drake_models as _dm

    SCENARIOS_FILE = Path(_dm.__file__).with_name("station.scenarios.yaml")


@dataclass
class ChainScenario:
    """One simulation scenario: the chain, the atrium, the fields, the units, the insertion, the engine.

    Load a named one with ``load_scenario``; the module docstring describes the schema.

    Attributes:
        description: one line.
        n_balls: chain length (ball 1 is the feeder ball in the sheath).
        sleeve: include the sleeve's bending forces (from chain_energy).
        heart: simulate inside the procedural left atrium (else free space).
        heart_scale: scales every length of the atrium.
        heart_subdivisions: icosphere subdivisions of the atrium's collision wall (3: ~3 mm).
        atrium_file: a user's endocardial surface (.obj/.stl path or package:// URI) to use
            instead of the procedural atrium (see ``drake_models.atrium_mesh``).
        atrium_units: "auto", "m" or "mm" for ``atrium_file``.
        puncture: (3,) septal puncture in the user atrium's frame [m] (required with
            ``atrium_file``; moved to the nearest surface vertex).
        sheath_aim: (3,) point the sheath points to [m] (default: the chamber's centroid).
        anatomy: an anatomy file (``drake_models.anatomy``: a surface, its targets, sheath and
            magnet units) to use instead of the procedural atrium or ``atrium_file``; the units
            stand at its magnets (``station.apply_anatomy``).
        sheath: the transseptal sheath's collision cage (else ball 1 alone is held).
        mode: "quasi-static" (damped floating joints, ~1e-3 s steps) or "dynamics" (no damping).
        time_step: the plant's discrete step [s]; 0 means the mode's default (1e-3 or 1e-4).
            The time step's one home: ``plant_config.time_step`` is refused.
        plant_config: Drake's MultibodyPlantConfig of the chain plant (contact model, discrete
            contact approximation, SAP near-rigid threshold, ...; defaults:
            ``chain_plant.chain_multibody_plant_config()``); its ``time_step`` must stay 0 (the
            step is ``time_step`` above). Not read by ``engine: statics``.
        simulator_config: Drake's SimulatorConfig, applied by ``run_station``
            (``ApplySimulatorConfig``; ``target_realtime_rate`` 0: as fast as possible, a run's
            ``realtime_rate`` argument overrides it; ``start_time`` must be 0).
        visualization: Drake's VisualizationConfig of the Meshcat view (when a Meshcat is
            given): ``publish_period`` [s] (Meshcat publishing and replay frames; also the
            overlays' and unit markers' period), ``default_illustration_color``,
            ``delete_on_initialization_event``, ``enable_alpha_sliders``; the other fields must
            keep ``station_visualization_config()``'s values.
        translational_damping: quasi-static damping on each free ball [N s/m].
        angular_damping: quasi-static damping on each free ball [N m s].
        gravity: gravity along -z.
        uniform_field: a uniform external field B_W [T] (zeros: none).
        magnets: fixed external magnets.
        units: rotating actuation units driven by scripted joysticks (``unit_config.MagnetUnitConfig``,
            systems/station_units.py).
        insertion: the feeder's motion.
        contact: contact parameters.
        wall_plane: () or (x, y, z, nx, ny, nz): a flat compliant wall in free space (point on
            its surface, outward normal) [m].
        duration: default simulated time [s].
        break_gap: a gap between neighbours larger than this means the chain broke [m].
        check_period: how often the monitor checks escape, breaks and clearance [s].
        engine: the engine's typed config (``engine_config``): ``PlantEngine`` (``plant`` or
            ``!Plant {}``: the MultibodyPlant, the reference, and the only one for dynamics) or
            ``StaticsEngine`` (``statics`` or ``!Statics {}``: ``systems/quasi_static_engine.py``,
            the equilibrium solved every ``statics_period``, quasi-static mode only). A config is
            its name (a ``str``); a name set here is converted.
        statics_period: the statics engine's update period [s] (50 ms: the teleoperated magnet
            turns at most 1.5 deg and the feeder moves 1 mm in one period; larger moves are
            split by the engine's continuation).
        unit_systems: "compiled" (the default: each unit one ``actuation_unit.ActuationUnit``,
            its update compiled) or "python" (the composed Python systems, its reference: the
            same numbers, bit for bit, several times the cost).
        pin: a force-sensor pin on the tip ball (off by default; plant engine only).
        device: the device's typed config (``engine_config``): ``BallChainDevice`` (``ball_chain``
            or ``!BallChain {}``: the magnetic chain, the default) or ``SteerableCatheterDevice``
            (``steerable_catheter`` or ``!SteerableCatheter {}``: the paper's manual comparison
            arm, an 8 Fr steerable catheter in the same atrium and sheath,
            ``systems/catheter_station.py``; no magnet units, quasi-static), or any registered
            device's name (``device_model.register_device_model``). A name set here is converted.
        wall_motion: the anatomy's periodic motion, respiration and heart beat
            (``WallMotionScenario``; off by default; ``engine: statics`` only).
        random_seed: absent (null): every stochastic system (the Hall sensors' noise, a simulated
            operator's tremor) keeps its default seed, the run it always was; an integer in
            0..2**32 - 1: ``run_station`` draws their seeds from ``RandomGenerator(random_seed)``
            (``randomness.set_random_context``, Drake's SetRandomContext).
        localisation: the tip tracker's noise, rate and latency (``LocalisationScenario``), read
            by the simulated procedure's navigator.
        world: the world the engine plays, unknown to the planner, the navigator and the operator
            (``world_scenario.WorldScenario``: ``preset: none``, the model's own numbers, by default).
    """

    description: str = ""
    n_balls: int = 16
    sleeve: bool = False
    heart: bool = True
    heart_scale: float = 1.0
    heart_subdivisions: int = 3
    atrium_file: str = ""
    atrium_units: str = "auto"
    puncture: list[float] = field(default_factory=list)
    sheath_aim: list[float] = field(default_factory=list)
    anatomy: str = ""
    sheath: bool = True
    mode: str = "quasi-static"
    time_step: float = 0.0
    plant_config: MultibodyPlantConfig = field(default_factory=chain_multibody_plant_config)
    simulator_config: SimulatorConfig = field(default_factory=SimulatorConfig)
    visualization: VisualizationConfig = field(default_factory=station_visualization_config)
    translational_damping: float = 1.0
    angular_damping: float = 1e-5
    gravity: bool = True
    uniform_field: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    magnets: list[MagnetScenario] = field(default_factory=list)
    units: list[MagnetUnitConfig] = field(default_factory=list)
    insertion: InsertionScenario = field(default_factory=InsertionScenario)
    contact: ContactConfig = field(default_factory=ContactConfig)
    wall_plane: list[float] = field(default_factory=list)
    duration: float = 0.1
    break_gap: float = 1e-3
    check_period: float = 5e-3
    engine: EngineConfig = PlantEngine()
    statics_period: float = 0.05
    unit_systems: str = "compiled"
    pin: PinScenario = field(default_factory=PinScenario)
    random_seed: typing.Optional[int] = None
    device: DeviceConfig = BallChainDevice()
    wall_motion: WallMotionScenario = field(default_factory=WallMotionScenario)
    localisation: LocalisationScenario = field(default_factory=LocalisationScenario)
    world: WorldScenario = field(default_factory=WorldScenario)

    def __setattr__(self, name, value) -> None:
        if name in CHOICES and isinstance(value, str):  # engine, device: a name is its config
            value = choice_config(name, value)
        super().__setattr__(name, value)

    @property
    def effective_time_step(self) -> float:
        return self.time_step if self.time_step > 0 else DEFAULT_TIME_STEP[self.mode]

    def validate(self) -> "ChainScenario":
        """Check every field in one pass (``check_fields``); raises UserInputError naming the
        first bad field. Returns self."""
        check_fields(self)
        return self


def _scenarios_data(filename: Path) -> dict:
    """The scenarios file as a mapping (read with the one user-YAML loader)."""
    if not isinstance(filename, (str, Path)) or not str(filename).strip():
        raise UserInputError(f"the scenarios file must be a file name, got {short_repr(filename)}")
    where = f"scenarios file {short_repr(Path(filename).name)}"
    register_input(filename, "scenarios file")  # an output of the run may not replace it
    data = load_yaml_file(filename, where, _tags())
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise UserInputError(f"{where} must be a mapping of scenario names to scenarios, got {yaml_kind(data)}")
    return data


def scenario_names(filename: Path = SCENARIOS_FILE) -> list[str]:
    """Names of the scenarios in a scenarios file (keys not starting with an underscore)."""
    return [k for k in _scenarios_data(filename) if not str(k).startswith("_")]


def scenario_descriptions(filename: Path = SCENARIOS_FILE) -> dict[str, str]:
    """Each scenario's one-line description, by name (in the file's order; "" when it has none)."""
    data = _scenarios_data(filename)
    return {str(k): str(v.get("description", "")) if isinstance(v, dict) else "" for k, v in data.items()
            if not str(k).startswith("_")}


def load_scenario(name: str, overrides: str | None = None, filename: Path = SCENARIOS_FILE) -> ChainScenario:
    """Load a named scenario, apply inline-YAML overrides, validate it.

    Both YAML documents are read by ``safe_yaml.load_yaml`` (bounded, no duplicate keys, YAML
    1.2 numbers), checked against the schema, then typed with pydrake's ``yaml_load_typed``.

    Args:
        name: a scenario name in ``filename``.
        overrides: inline YAML mapping (e.g. "{mode: dynamics, duration: 0.01}"), or None; see
            ``apply_overrides`` for how lists merge.
        filename: the scenarios file.

    Raises:
        UserInputError: unknown name, YAML that does not parse, a field that does not exist, a
            value of the wrong type, or a bad value (the message names the field).

    Example:
        A named scenario with one field changed (``--set`` on the command line)::

            >>> import ballchain as bc
            >>> scenario = bc.load_scenario("free_space_uniform_90deg", "{n_balls: 6}")
            >>> scenario.n_balls, scenario.engine, scenario.uniform_field  # field [T]
            (6, 'plant', [0.0, 0.023, 0.0])
    """
    data = _scenarios_data(filename)
    names = [k for k in data if not str(k).startswith("_")]
    if name not in names:
        raise UserInputError(f"unknown scenario {short_repr(name)}; known scenarios: {', '.join(map(str, names))}")
    where = f"scenario {name!r}"
    entry, choices = _split_choices(data[name], where)
    check_yaml_schema(entry, ChainScenario, where)
    scenario = load_typed(entry, ChainScenario, where, defaults=ChainScenario())
    for key, value in choices.items():
        setattr(scenario, key, value)
    changes = parse_overrides(overrides)
    if changes:
        scenario = apply_overrides(scenario, changes)
    return scenario.validate()


def parse_overrides(overrides: str | dict | None) -> dict:
    """The ``--set`` inline YAML as a mapping checked against the schema ({} for None/empty).
    From Python the overrides may also be a mapping (``plain_overrides``: numpy values welcome).

    Raises:
        UserInputError: it does not parse (or is too large, an alias bomb, has a duplicate key),
            is not a mapping, names an unknown field or gives a value of the wrong shape.
    """
    if isinstance(overrides, dict):
        return _checked(plain_overrides(overrides), "--set")
    if overrides is not None and not isinstance(overrides, str):
        raise UserInputError(f"--set (overrides) must be inline YAML text or a mapping of scenario fields, "
                             f"got {type(overrides).__name__}")
    if overrides is None or not overrides.strip():
        return {}
    data = load_yaml(overrides, "--set", _tags())
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise UserInputError(f"--set must be a YAML mapping of scenario fields such as "
                             f"'{{n_balls: 10}}', got {short_repr(overrides)}")
    return _checked(data, "--set")


def _tags() -> tuple[str, ...]:
    """The YAML tags of the engines' and devices' typed configs (``!Statics``, ``!BallChain``, ...)."""
    return choice_tags((ENGINES, DEVICES))


def _split_choices(data, where: str) -> tuple[dict, dict]:
    """``data`` without its ``engine`` and ``device``, and those as names (a plain name, or a
    tagged config's: ``engine_config.choice_name``); data that is not a mapping as it is."""
    if not isinstance(data, dict):
        return data, {}
    names = {"engine": ENGINES, "device": DEVICES}
    choices = {key: choice_name(key, data[key], names[key], where) for key in CHOICES if key in data}
    return {k: v for k, v in data.items() if k not in choices}, choices


def _checked(data, where: str):
    """Override data checked against the schema, the engine and device as names."""
    rest, choices = _split_choices(data, where)
    check_yaml_schema(rest, ChainScenario, where)
    return {**data, **choices}


def plain_overrides(data: dict, where: str = "--set", path: str = ""):
    """Overrides given in Python as the plain data YAML reads: numpy scalars as Python numbers,
    numpy arrays and tuples as lists, mappings with text keys.

    Raises:
        UserInputError: naming the field, for a key that is not text or a value that is not a
            number, text, boolean, None, list or mapping.
    """
    if isinstance(data, dict):
        out = {}
        for key, value in data.items():
            if not isinstance(key, str):
                raise UserInputError(f"{where}: field names must be text, got {short_repr(key)}"
                                     f"{f' in {path}' if path else ''}")
            out[key] = plain_overrides(value, where, f"{path}.{key}" if path else key)
        return out
    if isinstance(data, (list, tuple, np.ndarray)):
        return [plain_overrides(v, where, f"{path}[{i}]") for i, v in enumerate(data)]
    if isinstance(data, np.generic):
        data = data.item()
    if data is None or isinstance(data, (bool, int, float, str)):
        return data
    raise UserInputError(f"{where}: {path or 'the overrides'} must be plain data (numbers, text, true/false, "
                         f"lists, mappings), got {type(data).__name__}")


def apply_overrides(scenario: ChainScenario, data: dict, where: str = "--set") -> ChainScenario:
    """A copy of ``scenario`` with the checked override mapping ``data`` applied.

    A mapping updates only the fields it names (``{insertion: {speed: 0.02}}`` keeps the other
    insertion fields). A list of numbers replaces the list. A list of mappings (``units``,
    ``magnets``, a unit's ``joystick``) is the new list, each entry updating the scenario's entry
    it names: a unit entry with the ``name`` of one of the scenario's units updates that unit;
    an entry without a name updates the entry at the same position; an entry past the end (or a
    unit with a new name) starts from the defaults. So ``{units: [{teleop_omega_max: 1.0}]}``
    changes the first unit's speed and keeps its anchor, distance, direction and joystick, and
    ``{units: []}`` removes every unit.

    Raises:
        UserInputError: ``scenario`` is not a ChainScenario, or ``data`` not a mapping of
            scenario fields (``plain_overrides``, ``check_yaml_schema``).
    """
    if not isinstance(scenario, ChainScenario):
        raise UserInputError(f"apply_overrides scenario must be a ChainScenario, got {type(scenario).__name__}")
    if not isinstance(data, dict):
        raise UserInputError(f"apply_overrides data must be a mapping of scenario fields (parse_overrides' "
                             f"answer), got {type(data).__name__}")
    rest, choices = _split_choices(_checked(plain_overrides(data, where), where), where)
    scenario = load_typed(_complete_entries(rest, scenario, ChainScenario), ChainScenario, where, defaults=scenario)
    for key, value in choices.items():
        setattr(scenario, key, value)
    return scenario


def _complete_entries(data: dict, base, schema) -> dict:
    """``data`` with each entry of a list of mappings written out in full from ``base``'s entry
    it updates (see ``apply_overrides``), so that the typed load keeps what it does not name."""
    hints = _schema_fields(schema)
    out = dict(data)
    for key, value in data.items():
        item = _list_item_schema(hints[key])
        if item is not None and isinstance(value, list):
            old = list(getattr(base, key))
            out[key] = [_full_entry(entry, _updated_entry(old, entry, i, item), item) for i, entry in enumerate(value)]
        elif dataclasses.is_dataclass(hints[key]) and isinstance(value, dict):
            out[key] = _complete_entries(value, getattr(base, key), hints[key])
    return out


def _updated_entry(old: list, entry: dict, i: int, schema):
    """The entry of ``old`` that override entry ``i`` updates (None: it starts from the defaults)."""
    if "name" in _schema_fields(schema) and "name" in entry:
        return next((o for o in old if o.name == entry["name"]), None)
    return old[i] if i < len(old) else None


def _full_entry(entry: dict, base, schema) -> dict:
    base = schema() if base is None else base
    full = dataclasses.asdict(base)
    full.update(_complete_entries(entry, base, schema))
    return full
