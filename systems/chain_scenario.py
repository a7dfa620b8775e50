"""Scenario schema of the chain-in-a-heart simulation, and loading of named scenarios.

A scenario is data: the dataclass ``ChainScenario`` is the schema, named scenarios live in
``drake_models/station.scenarios.yaml`` (loaded with pydrake's ``yaml_load_typed``), and any
field can be overridden with inline YAML (``load_scenario("heart_left", "{duration: 0.01}")``).
All quantities are SI: m, s, T, N, kg. Drake's own config structs are fields of the scenario
(``plant_config: MultibodyPlantConfig``, ``simulator_config: SimulatorConfig``,
``visualization: VisualizationConfig``); the time step has one home, ``time_step``. The station
builder (``systems/station.py``) turns a scenario into a diagram.
"""


import dataclasses
import math
import numbers
import typing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from pydrake.common.yaml import yaml_load_typed
from pydrake.multibody.plant import MultibodyPlantConfig
from pydrake.systems.analysis import GetIntegrationSchemes, SimulatorConfig
from pydrake.visualization import VisualizationConfig

from ballchain.drake_models import paper
from ballchain.drake_models.errors import UserInputError
from ballchain.drake_models.params import BallChain
from ballchain.systems.chain_plant import ChainPlantConfig, ContactConfig, chain_multibody_plant_config
from ballchain.systems.force_sensor_pin import stability_bound

SCENARIOS_FILE = Path(__file__).resolve().parents[1] / "drake_models" / "station.scenarios.yaml"
if not SCENARIOS_FILE.exists():  # installed (non-editable) layout
    from ballchain import drake_models as _dm

    SCENARIOS_FILE = Path(_dm.__file__).with_name("station.scenarios.yaml")

MODES = ("quasi-static", "dynamics")
ENGINES = ("plant", "statics")
DEFAULT_TIME_STEP = {"quasi-static": 1e-3, "dynamics": 1e-4}


@dataclass
class MagnetScenario:
    """A fixed external magnet (a point dipole unless ``model: exact``).

    Attributes:
        shape: "cylinder" (the prototype's N52 76.2 x 38.1 mm) or "sphere" (119 mm clinical).
        p_WM: centre [m]; when empty, ``distance_from_puncture`` along ``direction_W`` from the
            septal puncture (the paper's 16.51 cm).
        distance_from_puncture: [m].
        direction_W: from the puncture towards the magnet centre.
        m_hat_W: dipole direction.
        model: "dipole" or "exact".
    """

    shape: str = "cylinder"
    p_WM: list[float] = field(default_factory=list)
    distance_from_puncture: float = paper.WORKING_DISTANCE
    direction_W: list[float] = field(default_factory=lambda: [1.0, 0.0, 0.0])
    m_hat_W: list[float] = field(default_factory=lambda: [0.0, 0.0, 1.0])
    model: str = "dipole"


@dataclass
class InsertionScenario:
    """What the feeder does: hold ``initial``, then move at ``speed`` towards ``final``.

    Attributes:
        initial: inserted length at t = 0 [m] (see ``chain_plant`` for its definition).
        final: inserted length reached at the end of the ramp [m].
        start_time: when the ramp starts [s].
        speed: ramp speed [m/s].
        external: when true, the diagram exports the input port ``inserted_length`` (1) [m]
            for a feeder system (e.g. systems/feeder.py) instead of playing this ramp.
        feeder: when true, the stepper Feeder (systems/feeder.py, named ``feeder``) plays the
            ramp as a speed command (its acceleration limit turns it into a trapezoid that
            covers the same distance, about speed / 0.1 m/s^2 later) and its quantised
            ``inserted_length`` drives the slide. ``speed`` must not exceed the feeder's limit.
        feeder_command: with ``feeder``, who commands its speed: "ramp" (the ramp above, the
            system ``feeder_command``) or "external" (another system, e.g. a simulated operator:
            the feeder's ``v_insert_cmd`` input (1) [m/s] is left to ``MakeStation``'s
            ``add_systems`` hook, or exported as the diagram input ``feeder.v_insert_cmd``).
        slide_gains: (kp [N/m], kd [N s/m]) of the PD actuator that holds ball 1's slide on the
            commanded inserted length (implicit in the discrete solver; the plant engine only).
    """

    initial: float = 0.02
    final: float = 0.02
    start_time: float = 0.0
    speed: float = 0.01
    external: bool = False
    feeder: bool = False
    feeder_command: str = "ramp"
    slide_gains: list[float] = field(default_factory=lambda: list(ChainPlantConfig.feeder_gains))


@dataclass
class JoystickKey:
    """One key of a scripted joystick: from ``time`` on (zero-order hold) the stick reads ``axes``.

    Attributes:
        time: [s].
        axes: (3,) stick axes in [-1, 1]; with the world mapping (the paper's), full stick turns
            the magnet at the unit's ``teleop_omega_max`` about world x, y, z.
        mode: 0 teleoperation (the stick drives the magnet), 1 reconfiguration (the Hall-sensor
            loop turns the magnet back to its neutral direction; the stick is ignored).
    """

    time: float = 0.0
    axes: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    mode: int = 0


@dataclass
class PinScenario:
    """A force-sensor pin holding the tip ball's centre (``systems/force_sensor_pin.py``).

    Off when ``point`` is empty. The station then adds ``force_sensor_pin`` (a stiff explicit
    spring from ``point`` to the tip ball's centre, into the plant's generalized forces) and
    exports its reading as ``pin_reading`` (3) [N] (the force the tip presses on the pin).

    Attributes:
        point: () or (3,) the pin point in world [m].
        stiffness: the spring [N/m]; below ``force_sensor_pin.stability_bound`` at the step
            (with the tip's own magnetic stiffness, see ``experiments/forces_dynamics.py``).
    """

    point: list[float] = field(default_factory=list)
    stiffness: float = 500.0  # [N/m]: 2.4 times below the first failure on Table I's optima (forces_dynamics)


def station_visualization_config(**overrides) -> VisualizationConfig:
    """The station's VisualizationConfig: illustration only, 32 frames a second.

    The station draws the illustration geometry (``MeshcatVisualizer``) and its own overlays
    (the wall's force on the tip, the field, the targets) rather than Drake's proximity,
    contact and inertia visualisers, so those are off.
    """
    values = dict(publish_period=1.0 / 32.0, publish_proximity=False, publish_contacts=False, publish_inertia=False)
    values.update(overrides)
    return VisualizationConfig(**values)


# The VisualizationConfig fields the station reads (the others must keep the station's values).
VISUALIZATION_FIELDS_USED = ("publish_period", "default_illustration_color", "delete_on_initialization_event",
                             "enable_alpha_sliders")
CONTACT_MODELS = ("point", "hydroelastic", "hydroelastic_with_fallback")
DISCRETE_CONTACT_APPROXIMATIONS = ("", "tamsi", "sap", "similar", "lagged")
CONTACT_SURFACE_REPRESENTATIONS = ("triangle", "polygon")

ANCHORS = ("puncture", "centre", "carina_left", "carina_right")
JOYSTICK_SOURCES = ("script", "external")
TELEOP_FRAMES = ("world", "tip")
FEEDER_COMMANDS = ("ramp", "external")


@dataclass
class UnitScenario:
    """A rotating actuation unit (magnet on omni-wheels, drive, Hall sensor, controller, joystick).

    Its systems are named ``<name>.magnet``, ``<name>.drive``, ``<name>.hall_sensor``,
    ``<name>.estimator``, ``<name>.controller``, ``<name>.teleoperation``, ``<name>.mode_switch``,
    ``<name>.joystick`` and ``<name>.mode_command``.

    Attributes:
        name: "right_unit", "left_unit", ... (distinct).
        shape: "cylinder" (the prototype's N52 76.2 x 38.1 mm) or "sphere" (119 mm clinical).
        p_WM: magnet centre [m]; when empty, ``distance`` along ``direction_W`` from ``anchor``.
        anchor: "puncture" (the septal puncture; the origin in free space), "centre" (the LA
            centre, the world origin), "carina_left" or "carina_right" (heart only).
        distance: [m].
        direction_W: from the anchor towards the magnet centre.
        m_hat_W: initial dipole direction; empty: the neutral direction (the field at the sheath
            exit, or at ball 1 in free space, along the insertion direction), which is also
            the reconfiguration controller's target.
        model: "dipole" or "exact" (the same for every unit).
        teleop_omega_max: magnet angular speed at full stick [rad/s].
        sensor_noise: Gaussian noise on the Hall sensor.
        joystick: the scripted stick (zero-order hold; zeros before the first key); with
            ``joystick_source: external`` only its modes are played (``<name>.mode_command``).
        joystick_source: "script" (``joystick``, the system ``<name>.joystick``) or "external"
            (another system moves the stick, e.g. a simulated operator: the mapper's
            ``joystick`` input (3) is left to ``MakeStation``'s ``add_systems`` hook, or
            exported as the diagram input ``<name>.joystick``).
        teleop_frame: the joystick mapping (``teleoperation.TeleoperationMapper``): "world" (the
            paper's: stick axes = magnet angular velocity about world x, y, z) or "tip" (the
            catheter-frame mapping: axes 0/1 swing the field at the tip about the tip frame's z
            and -y, at ``teleop_omega_max``; the tip ball's position and direction are fed to it).
        slip: fraction of the commanded rotation lost between wheels and sphere, in [0, 1).
        wheel_map: the controller's wheel conversion: "derived" (rolling contact) or "paper" (the
            printed map, docs/design.md 4.2).
        controller_gain: the reconfiguration controller's gain K [1/s].
        tolerance_deg: reconfiguration done below this measured error [deg].
        teleop_dead_band: stick dead band (fraction of full stick).
        sensors_see_other_units: each Hall sensor also measures the other units' fields.
        estimator_compensates_other_units: each estimator subtracts the other units' fields.
        (The last seven are ``actuation_station.StationOptions``'s, with its defaults.)
    """

    name: str = "right_unit"
    shape: str = "cylinder"
    p_WM: list[float] = field(default_factory=list)
    anchor: str = "puncture"
    distance: float = paper.WORKING_DISTANCE
    direction_W: list[float] = field(default_factory=lambda: [-1.0, 0.0, 0.0])
    m_hat_W: list[float] = field(default_factory=list)
    model: str = "dipole"
    teleop_omega_max: float = 0.5
    sensor_noise: bool = True
    joystick: list[JoystickKey] = field(default_factory=list)
    joystick_source: str = "script"
    teleop_frame: str = "world"
    slip: float = 0.0
    wheel_map: str = "derived"
    controller_gain: float = 4.0
    tolerance_deg: float = 0.5
    teleop_dead_band: float = 0.1
    sensors_see_other_units: bool = True
    estimator_compensates_other_units: bool = True


@dataclass
class ChainScenario:
    """One simulation scenario (see the module docstring).

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
        units: rotating actuation units driven by scripted joysticks (systems/station_units.py).
        insertion: the feeder's motion.
        contact: contact parameters.
        wall_plane: () or (x, y, z, nx, ny, nz): a flat compliant wall in free space (point on
            its surface, outward normal) [m].
        duration: default simulated time [s].
        break_gap: a gap between neighbours larger than this means the chain broke [m].
        check_period: how often the monitor checks escape, breaks and clearance [s].
        engine: "plant" (the MultibodyPlant: the reference, and the only one for dynamics) or
            "statics" (``systems/quasi_static_engine.py``: the equilibrium solved every
            ``statics_period``, quasi-static mode only).
        statics_period: the statics engine's update period [s] (50 ms: the teleoperated magnet
            turns at most 1.5 deg and the feeder moves 1 mm in one period; larger moves are
            split by the engine's continuation).
        pin: a force-sensor pin on the tip ball (off by default; plant engine only).
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
    units: list[UnitScenario] = field(default_factory=list)
    insertion: InsertionScenario = field(default_factory=InsertionScenario)
    contact: ContactConfig = field(default_factory=ContactConfig)
    wall_plane: list[float] = field(default_factory=list)
    duration: float = 0.1
    break_gap: float = 1e-3
    check_period: float = 5e-3
    engine: str = "plant"
    statics_period: float = 0.05
    pin: PinScenario = field(default_factory=PinScenario)

    @property
    def effective_time_step(self) -> float:
        return self.time_step if self.time_step > 0 else DEFAULT_TIME_STEP[self.mode]

    def validate(self) -> "ChainScenario":
        """Check the values; raises UserInputError saying what is wrong. Returns self."""
        check_fields(self)
        if self.mode not in MODES:
            raise UserInputError(f"scenario mode must be one of {MODES}, got {self.mode!r}")
        if self.engine not in ENGINES:
            raise UserInputError(f"scenario engine must be one of {ENGINES}, got {self.engine!r}")
        if self.engine == "statics" and (self.mode != "quasi-static" or not 0 < self.statics_period <= 1.0):
            raise UserInputError(f"engine: statics needs mode: quasi-static and 0 < statics_period <= 1 s, got "
                                 f"mode {self.mode!r}, statics_period {self.statics_period}")
        if self.n_balls < 2:
            raise UserInputError(f"scenario n_balls must be >= 2 (ball 1 is the feeder ball), got {self.n_balls}")
        if self.time_step < 0 or self.duration < 0 or self.check_period <= 0:
            raise UserInputError("scenario time_step, duration must be >= 0 and check_period > 0")
        if self.atrium_file and len(self.puncture) != 3:
            raise UserInputError("a scenario with atrium_file needs puncture: [x, y, z] (m), the septal "
                             "puncture on that surface")
        if self.sheath_aim and len(self.sheath_aim) != 3:
            raise UserInputError(f"scenario sheath_aim must have 3 components [m], got {self.sheath_aim}")
        if len(self.uniform_field) != 3:
            raise UserInputError(f"scenario uniform_field must have 3 components [T], got {self.uniform_field}")
        for k, m in enumerate(self.magnets):
            if m.shape not in ("cylinder", "sphere"):
                raise UserInputError(f"magnet {k + 1}: shape must be 'cylinder' or 'sphere', got {m.shape!r}")
            if m.model not in ("dipole", "exact"):
                raise UserInputError(f"magnet {k + 1}: model must be 'dipole' or 'exact', got {m.model!r}")
            if m.p_WM and len(m.p_WM) != 3:
                raise UserInputError(f"magnet {k + 1}: p_WM must have 3 components [m], got {m.p_WM}")
        self._validate_units()
        ins = self.insertion
        if ins.feeder_command not in FEEDER_COMMANDS:
            raise UserInputError(f"insertion.feeder_command must be one of {FEEDER_COMMANDS}, got {ins.feeder_command!r}")
        if ins.feeder_command == "external" and not ins.feeder:
            raise UserInputError("insertion.feeder_command: external needs the feeder (insertion.feeder: true)")
        if self.mode == "dynamics" and self.effective_time_step > 5e-4:
            raise UserInputError(
                f"time step {self.effective_time_step} s is too large for the dynamics mode: the "
                "magnetic forces are explicit and need about 1e-4 s (use quasi-static for larger steps)")
        return self


    def _validate_units(self) -> None:
        names = [u.name for u in self.units]
        if len(set(names)) != len(names):
            raise UserInputError(f"scenario units must have distinct names, got {names}")
        for u in self.units:
            where = f"unit {u.name!r}"
            if not u.name or "." in u.name:
                raise UserInputError(f"{where}: name must be non-empty and without dots")
            if u.shape not in ("cylinder", "sphere"):
                raise UserInputError(f"{where}: shape must be 'cylinder' or 'sphere', got {u.shape!r}")
            if u.model not in ("dipole", "exact") or u.model != self.units[0].model:
                raise UserInputError(f"{where}: model must be 'dipole' or 'exact', the same for every unit")
            if u.p_WM and len(u.p_WM) != 3:
                raise UserInputError(f"{where}: p_WM must have 3 components [m], got {u.p_WM}")
            if u.m_hat_W and (len(u.m_hat_W) != 3 or not any(u.m_hat_W)):
                raise UserInputError(f"{where}: m_hat_W must be 3 components, not all zero, got {u.m_hat_W}")
            if not u.p_WM:
                if u.anchor not in ANCHORS:
                    raise UserInputError(f"{where}: anchor must be one of {ANCHORS}, got {u.anchor!r}")
                if u.anchor.startswith("carina") and not self.heart:
                    raise UserInputError(f"{where}: anchor {u.anchor!r} needs the heart (heart: true)")
                if len(u.direction_W) != 3 or not any(u.direction_W) or u.distance <= 0:
                    raise UserInputError(f"{where}: needs direction_W (3, non-zero) and distance > 0 [m]")
            if u.joystick_source not in JOYSTICK_SOURCES:
                raise UserInputError(f"{where}: joystick_source must be one of {JOYSTICK_SOURCES}, got {u.joystick_source!r}")
            if u.teleop_frame not in TELEOP_FRAMES:
                raise UserInputError(f"{where}: teleop_frame must be one of {TELEOP_FRAMES}, got {u.teleop_frame!r}")
            if u.teleop_omega_max <= 0:
                raise UserInputError(f"{where}: teleop_omega_max must be > 0 [rad/s]")
            times = [k.time for k in u.joystick]
            if any(t < 0 for t in times) or any(b < a for a, b in zip(times, times[1:])):
                raise UserInputError(f"{where}: joystick key times must be >= 0 and non-decreasing, got {times}")
            for k in u.joystick:
                if len(k.axes) != 3 or k.mode not in (0, 1):
                    raise UserInputError(f"{where}: joystick key at t = {k.time} s needs 3 axes and mode 0 or 1")


def scenario_names(filename: Path = SCENARIOS_FILE) -> list[str]:
    """Names of the scenarios in a scenarios file (keys not starting with an underscore)."""
    data = yaml.safe_load(Path(filename).read_text()) or {}
    return [k for k in data if not str(k).startswith("_")]


def load_scenario(name: str, overrides: str | None = None, filename: Path = SCENARIOS_FILE) -> ChainScenario:
    """Load a named scenario, apply inline-YAML overrides, validate it.

    Args:
        name: a scenario name in ``filename``.
        overrides: inline YAML mapping (e.g. "{mode: dynamics, duration: 0.01}"), or None.
        filename: the scenarios file.

    Raises:
        UserInputError: unknown name, YAML that does not parse, a field that does not exist, a
            value of the wrong type, or a bad value (the message names the field).
    """
    names = scenario_names(filename)
    if name not in names:
        raise UserInputError(f"unknown scenario {name!r}; known scenarios: {', '.join(names)}")
    check_yaml_schema(yaml.safe_load(Path(filename).read_text())[name], ChainScenario, f"scenario {name!r}")
    data = parse_overrides(overrides)
    try:
        scenario = yaml_load_typed(schema=ChainScenario, filename=str(filename), child_name=name,
                                   defaults=ChainScenario())
        if data:
            scenario = yaml_load_typed(schema=ChainScenario, data=overrides, defaults=scenario)
    except RuntimeError as err:  # yaml_load_typed reports unknown keys and bad types this way
        raise UserInputError(f"scenario {name!r}: {err}") from None
    return scenario.validate()


# ------------------------------------------------------------------------------------------------
# Validation at the edge: the YAML's shape against the schema before pydrake reads it,
# and every field's value (finite, in range, plausible units) before anything is built.

MAX_BALLS = 100  # the paper's chain has 16; the procedural atrium is about 50 mm across
MIN_TIME_STEP = 1e-6  # [s]
MAX_TIME_STEP = 1e-2  # [s]: the quasi-static contact model needs about 1e-3
MAX_DURATION = 3600.0  # [s] of simulated time
MAX_STEPS = 5_000_000  # duration / time_step: hours of wall time at a few ms per step
MAX_UNIFORM_FIELD = 0.5  # [T]: clinical fields are tens of mT; 23 here means 23 T (mT typed)
MAX_DISTANCE = 1.0  # [m]: magnets and points farther away are a unit mistake (mm typed as m)


def parse_overrides(overrides: str | None) -> dict:
    """The ``--set`` inline YAML as a mapping checked against the schema ({} for None/empty).

    Raises:
        UserInputError: it does not parse, is not a mapping, names an unknown field or gives a
            value of the wrong shape (a number where a list or mapping belongs, ...).
    """
    if overrides is None or not str(overrides).strip():
        return {}
    try:
        data = yaml.safe_load(overrides)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at column {mark.column + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise UserInputError(f"--set {overrides!r} is not valid YAML: {problem}{where} "
                             "(give a mapping such as '{n_balls: 10, duration: 0.5}')") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise UserInputError(f"--set must be a YAML mapping of scenario fields such as "
                             f"'{{n_balls: 10}}', got {overrides!r}")
    check_yaml_schema(data, ChainScenario, "--set")
    return data


def _schema_fields(tp) -> dict | None:
    """{field name: type} of a schema: a dataclass, or a pydrake config struct (``__fields__``,
    e.g. MultibodyPlantConfig); None for any other type."""
    if dataclasses.is_dataclass(tp):
        return typing.get_type_hints(tp)
    fields = getattr(tp, "__fields__", None) if isinstance(tp, type) else None
    if isinstance(fields, tuple) and all(hasattr(f, "name") and hasattr(f, "type") for f in fields):
        return {f.name: f.type for f in fields}
    return None


def _type_name(tp, plural: bool = False) -> str:
    origin = typing.get_origin(tp)
    if origin in (list, tuple):
        args = typing.get_args(tp)
        return "a list" + (f" of {_type_name(args[0], plural=True)}" if args else "")
    if _schema_fields(tp) is not None:
        return f"{tp.__name__} mappings" if plural else f"a mapping of {tp.__name__} fields"
    names = {bool: ("true or false", "true/false values"), int: ("an integer", "integers"),
             float: ("a number", "numbers"), str: ("a string", "strings")}
    return names[tp][plural] if tp in names else str(tp)


def _check_value(value, tp, path: str, where: str) -> None:
    origin = typing.get_origin(tp)
    ok = True
    if tp is bool:
        ok = isinstance(value, bool)
    elif tp is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif tp is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        if isinstance(value, str):  # YAML 1.1 (PyYAML) reads 1e-3 as a string; Drake's parser reads a number
            try:
                float(value)
                ok = True
            except ValueError:
                ok = False
    elif tp is str:
        ok = isinstance(value, str)
    elif origin in (list, tuple):
        ok = isinstance(value, list)
        if ok:
            args = typing.get_args(tp)
            for i, item in enumerate(value):
                if args:
                    _check_value(item, args[0], f"{path}[{i}]", where)
    elif _schema_fields(tp) is not None:
        if not isinstance(value, dict):
            raise UserInputError(f"scenario field {path} must be {_type_name(tp)} "
                                 f"({', '.join(_schema_fields(tp))}), got {value!r}")
        check_yaml_schema(value, tp, where, path)
        return
    if not ok:
        raise UserInputError(f"scenario field {path} must be {_type_name(tp)}, got {value!r}")


def check_yaml_schema(data, schema, where: str, path: str = "") -> None:
    """Check parsed YAML against a dataclass schema: known fields, value shapes and types.

    Args:
        data: the parsed YAML (a dict).
        schema: the dataclass (ChainScenario or one of its parts) or a pydrake config struct
            nested in it (MultibodyPlantConfig, SimulatorConfig, VisualizationConfig).
        where: what the YAML came from, for messages ("--set", "scenario 'heart_left'").
        path: the field path of ``data`` inside the scenario ("" at the top, "units[0]", ...).

    Raises:
        UserInputError: naming the field path, what it must be and what it got.
    """
    if not isinstance(data, dict):
        raise UserInputError(f"{where} must be {_type_name(schema)}, got {data!r}")
    hints = _schema_fields(schema)
    for key, value in data.items():
        if key not in hints:
            raise UserInputError(f"{where}: unknown field {key!r}{f' in {path}' if path else ''}; "
                                 f"{schema.__name__} fields are {', '.join(hints)}")
        _check_value(value, hints[key], f"{path}.{key}" if path else str(key), where)


def _finite_fields(obj, where: str = ""):
    """Yield (path, value) of every non-finite number in a dataclass tree."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        path = f"{where}{f.name}"
        items = value if isinstance(value, list) else [value]
        for i, item in enumerate(items):
            p = f"{path}[{i}]" if isinstance(value, list) else path
            if dataclasses.is_dataclass(item):
                yield from _finite_fields(item, f"{p}.")
            elif isinstance(item, float) and not math.isfinite(item):
                yield p, item


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise UserInputError(message)


def check_fields(s: "ChainScenario") -> None:
    """Every field of a scenario: finite, in range, in plausible units (SI). Called by validate().

    Raises:
        UserInputError: naming the field, the value and what is allowed.
    """
    for path, value in _finite_fields(s):
        raise UserInputError(f"scenario {path} must be a finite number, got {value}")
    whole = isinstance(s.n_balls, numbers.Integral) and not isinstance(s.n_balls, bool)
    _require(whole and 2 <= s.n_balls <= MAX_BALLS,
             f"scenario n_balls must be an integer in 2..{MAX_BALLS} (ball 1 is the feeder ball), got {s.n_balls!r}")
    _require(s.time_step == 0.0 or MIN_TIME_STEP <= s.time_step <= MAX_TIME_STEP,
             f"scenario time_step must be 0 (the mode's default) or in {MIN_TIME_STEP:g}..{MAX_TIME_STEP:g} s, "
             f"got {s.time_step:g}")
    _require(0.0 < s.duration <= MAX_DURATION,
             f"scenario duration must be in (0, {MAX_DURATION:g}] s, got {s.duration:g}")
    if s.mode in MODES:
        check_duration(s.duration, s.effective_time_step, "scenario duration")
    for name in ("translational_damping", "angular_damping"):
        _require(getattr(s, name) >= 0.0, f"scenario {name} must be >= 0, got {getattr(s, name):g}")
    _require(0.1 <= s.heart_scale <= 5.0, f"scenario heart_scale must be in 0.1..5, got {s.heart_scale:g}")
    _require(1 <= s.heart_subdivisions <= 6,
             f"scenario heart_subdivisions must be in 1..6, got {s.heart_subdivisions}")
    _require(s.atrium_units in ("auto", "m", "mm"),
             f"scenario atrium_units must be 'auto', 'm' or 'mm', got {s.atrium_units!r}")
    if s.atrium_file:
        check_atrium_file(s.atrium_file)
    for name in ("puncture", "sheath_aim"):
        v = getattr(s, name)
        _require(not v or (len(v) == 3 and np.linalg.norm(v) <= MAX_DISTANCE),
                 f"scenario {name} must be 3 coordinates in metres (within {MAX_DISTANCE:g} m), got {v}")
    _require(len(s.uniform_field) == 3,
             f"scenario uniform_field must have 3 components [T], got {s.uniform_field}")
    B = float(np.linalg.norm(s.uniform_field))
    _require(B <= MAX_UNIFORM_FIELD,
             f"scenario uniform_field |B| = {B:g} T exceeds {MAX_UNIFORM_FIELD:g} T: it is in tesla "
             "(23 mT is 0.023)")
    _require(len(s.wall_plane) in (0, 6),
             f"scenario wall_plane must be [] or 6 numbers (point, normal) [m], got {s.wall_plane}")
    for name in ("break_gap", "check_period"):
        _require(getattr(s, name) > 0.0, f"scenario {name} must be > 0, got {getattr(s, name):g}")
    check_drake_configs(s)
    if s.pin.point:
        check_pin(s)
    for k, m in enumerate(s.magnets):
        where = f"magnets[{k}]"
        _require(0.0 < m.distance_from_puncture <= MAX_DISTANCE,
                 f"scenario {where}.distance_from_puncture must be in (0, {MAX_DISTANCE:g}] m, "
                 f"got {m.distance_from_puncture:g}")
        for name in ("direction_W", "m_hat_W"):
            v = getattr(m, name)
            _require(len(v) == 3 and any(v), f"scenario {where}.{name} must be 3 components, not all zero, got {v}")
        _require(not m.p_WM or (len(m.p_WM) == 3 and np.linalg.norm(m.p_WM) <= MAX_DISTANCE),
                 f"scenario {where}.p_WM must be 3 coordinates in metres (within {MAX_DISTANCE:g} m), got {m.p_WM}")
    for k, u in enumerate(s.units):
        where = f"units[{k}]"
        _require(0.0 < u.distance <= MAX_DISTANCE,
                 f"scenario {where}.distance must be in (0, {MAX_DISTANCE:g}] m, got {u.distance:g}")
        _require(not u.p_WM or (len(u.p_WM) == 3 and np.linalg.norm(u.p_WM) <= MAX_DISTANCE),
                 f"scenario {where}.p_WM must be 3 coordinates in metres (within {MAX_DISTANCE:g} m), got {u.p_WM}")
        _require(u.teleop_omega_max > 0.0,
                 f"scenario {where}.teleop_omega_max must be > 0 rad/s, got {u.teleop_omega_max:g}")
        _require(0.0 <= u.slip < 1.0, f"scenario {where}.slip must be in [0, 1), got {u.slip:g}")
        _require(u.wheel_map in ("derived", "paper"),
                 f"scenario {where}.wheel_map must be 'derived' or 'paper', got {u.wheel_map!r}")
        _require(0.0 < u.controller_gain <= 100.0,
                 f"scenario {where}.controller_gain must be in (0, 100] 1/s, got {u.controller_gain:g}")
        _require(0.0 < u.tolerance_deg < 90.0,
                 f"scenario {where}.tolerance_deg must be in (0, 90) deg, got {u.tolerance_deg:g}")
        _require(0.0 <= u.teleop_dead_band < 1.0,
                 f"scenario {where}.teleop_dead_band must be in [0, 1), got {u.teleop_dead_band:g}")
        for j, key in enumerate(u.joystick):
            _require(len(key.axes) == 3 and all(abs(a) <= 1.0 for a in key.axes),
                     f"scenario {where}.joystick[{j}].axes must be 3 numbers in [-1, 1], got {key.axes}")
    ins = s.insertion
    _require(ins.initial >= 0.0 and ins.final >= 0.0,
             f"scenario insertion.initial and insertion.final must be >= 0 m, got {ins.initial:g}, {ins.final:g}")
    _require(ins.start_time >= 0.0, f"scenario insertion.start_time must be >= 0 s, got {ins.start_time:g}")
    _require(ins.speed > 0.0 or (ins.final == ins.initial and ins.speed == 0.0),
             f"scenario insertion.speed must be > 0 m/s (the ramp's direction comes from initial -> final), "
             f"got {ins.speed:g}")
    _require(len(ins.slide_gains) == 2 and all(math.isfinite(g) and g >= 0.0 for g in ins.slide_gains)
             and ins.slide_gains[0] > 0.0,
             f"scenario insertion.slide_gains must be [kp > 0 N/m, kd >= 0 N s/m], got {ins.slide_gains}")
    c = s.contact
    for name in ("ball_point_stiffness", "wall_hydroelastic_modulus", "hydroelastic_margin", "ball_resolution_hint"):
        _require(getattr(c, name) > 0.0, f"scenario contact.{name} must be > 0, got {getattr(c, name):g}")
    _require(c.relaxation_time >= 0.0, f"scenario contact.relaxation_time must be >= 0 s, got {c.relaxation_time:g}")
    _require(c.friction >= 0.0, f"scenario contact.friction must be >= 0, got {c.friction:g}")


def check_drake_configs(s: "ChainScenario") -> None:
    """The Drake config structs of a scenario: plant_config, simulator_config, visualization.

    Raises:
        UserInputError: naming the field (``plant_config.time_step`` is refused: the time step's
            one home is the scenario's ``time_step``).
    """
    p = s.plant_config
    _require(p.time_step == 0.0,
             f"scenario plant_config.time_step = {p.time_step:g}: the time step has one home, the scenario's "
             "time_step (0: the mode's default); leave plant_config.time_step out")
    for name, allowed in (("contact_model", CONTACT_MODELS),
                          ("discrete_contact_approximation", DISCRETE_CONTACT_APPROXIMATIONS),
                          ("contact_surface_representation", CONTACT_SURFACE_REPRESENTATIONS)):
        _require(getattr(p, name) in allowed,
                 f"scenario plant_config.{name} must be one of {allowed}, got {getattr(p, name)!r}")
    for name in ("penetration_allowance", "stiction_tolerance", "sap_near_rigid_threshold"):
        v = getattr(p, name)
        _require(math.isfinite(v) and (v >= 0.0 if name == "sap_near_rigid_threshold" else v > 0.0),
                 f"scenario plant_config.{name} must be a finite number "
                 f"{'>= 0' if name == 'sap_near_rigid_threshold' else '> 0'}, got {v:g}")
    if s.engine == "statics":  # the engine has no plant: a plant setting would be silently ignored
        _require(repr(p) == repr(chain_multibody_plant_config()),
                 "scenario plant_config configures the MultibodyPlant: engine: statics does not read it "
                 "(leave plant_config out, or use engine: plant)")
        _require(list(s.insertion.slide_gains) == list(ChainPlantConfig.feeder_gains),
                 "scenario insertion.slide_gains are the plant's slide actuator: engine: statics does not read "
                 "them (leave them out, or use engine: plant)")
    c = s.simulator_config
    schemes = GetIntegrationSchemes()
    _require(c.integration_scheme in schemes,
             f"scenario simulator_config.integration_scheme must be one of {', '.join(schemes)}, "
             f"got {c.integration_scheme!r}")
    for name in ("max_step_size", "accuracy"):
        v = getattr(c, name)
        _require(math.isfinite(v) and v > 0.0, f"scenario simulator_config.{name} must be > 0, got {v:g}")
    _require(math.isfinite(c.target_realtime_rate) and c.target_realtime_rate >= 0.0,
             f"scenario simulator_config.target_realtime_rate must be >= 0 (0: as fast as possible), "
             f"got {c.target_realtime_rate:g}")
    _require(c.start_time == 0.0, f"scenario simulator_config.start_time must be 0 (a station run starts at "
                                  f"t = 0), got {c.start_time:g}")
    v = s.visualization
    _require(math.isfinite(v.publish_period) and v.publish_period > 0.0,
             f"scenario visualization.publish_period must be > 0 s, got {v.publish_period:g}")
    default = station_visualization_config()
    for f in VisualizationConfig.__fields__:
        if f.name not in VISUALIZATION_FIELDS_USED and repr(getattr(v, f.name)) != repr(getattr(default, f.name)):
            raise UserInputError(
                f"scenario visualization.{f.name} = {getattr(v, f.name)!r} is not supported by the station "
                f"(it reads only {', '.join(VISUALIZATION_FIELDS_USED)}; {f.name} stays {getattr(default, f.name)!r})")


def check_pin(s: "ChainScenario") -> None:
    """A pin point (3, in metres) and a stiffness below the explicit spring's stability bound.

    Raises:
        UserInputError: naming ``pin.point`` or ``pin.stiffness``.
    """
    _require(len(s.pin.point) == 3 and np.linalg.norm(s.pin.point) <= MAX_DISTANCE,
             f"scenario pin.point must be [] (no pin) or 3 coordinates in metres (within {MAX_DISTANCE:g} m), "
             f"got {s.pin.point}")
    _require(s.engine == "plant", f"scenario pin needs engine: plant (the pin is a force on the plant), got {s.engine!r}")
    chain = BallChain(n_balls=s.n_balls)
    damping = s.translational_damping if s.mode == "quasi-static" else 0.0
    bound = stability_bound(s.effective_time_step, damping, chain.ball_mass)
    _require(0.0 < s.pin.stiffness < bound,
             f"scenario pin.stiffness {s.pin.stiffness:g} N/m must be > 0 and below the explicit spring's "
             f"stability bound {bound:g} N/m at a {s.effective_time_step:g} s step: lower it or the step")


def check_duration(duration: float, time_step: float, what: str = "--duration") -> None:
    """A simulated time that is positive, at most MAX_DURATION, and at most MAX_STEPS steps.

    Raises:
        UserInputError: naming ``what``.
    """
    if not (math.isfinite(duration) and 0.0 < duration <= MAX_DURATION):
        raise UserInputError(f"{what} must be in (0, {MAX_DURATION:g}] s, got {duration:g}")
    steps = duration / time_step
    if steps > MAX_STEPS:
        raise UserInputError(f"{what} {duration:g} s at a {time_step:g} s step is {steps:.3g} steps, more than "
                             f"{MAX_STEPS:.0e}: shorten it or use a larger time_step")


def check_atrium_file(path: str) -> None:
    """An atrium file that exists and is a file (a package:// URI must resolve).

    Raises:
        UserInputError: naming atrium_file.
    """
    if str(path).startswith("package://"):
        from ballchain.drake_models.model_files import resolve_uri

        try:
            resolved = resolve_uri(path)
        except Exception as err:  # pydrake's PackageMap raises RuntimeError on an unknown package
            first = " ".join(str(err).split())[:200]
            raise UserInputError(f"scenario atrium_file {path!r} does not resolve: {first}") from None
    else:
        resolved = Path(path)
    if not resolved.exists():
        raise UserInputError(f"scenario atrium_file {path!r}: no such file")
    if not resolved.is_file():
        raise UserInputError(f"scenario atrium_file {path!r} is not a file (a folder?); give an .obj or .stl file")
