"""Scenario schema of the chain-in-a-heart simulation, and loading of named scenarios.

A scenario is data: the dataclass ``ChainScenario`` is the schema, named scenarios live in
``drake_models/station.scenarios.yaml`` (loaded with pydrake's ``yaml_load_typed``), and any
field can be overridden with inline YAML (``load_scenario("heart_left", "{duration: 0.01}")``).
All quantities are SI: m, s, T, N, kg.
"""


from dataclasses import dataclass, field
from pathlib import Path

import yaml
from pydrake.common.yaml import yaml_load_typed

from ballchain.systems.chain_plant import ContactConfig

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
    distance_from_puncture: float = 0.1651
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
            the feeder's ``v_insert_cmd`` input (1) [m/s] is left to ``build_chain_diagram``'s
            ``add_systems`` hook, or exported as the diagram input ``feeder.v_insert_cmd``).
    """

    initial: float = 0.02
    final: float = 0.02
    start_time: float = 0.0
    speed: float = 0.01
    external: bool = False
    feeder: bool = False
    feeder_command: str = "ramp"


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
            ``joystick`` input (3) is left to ``build_chain_diagram``'s ``add_systems`` hook, or
            exported as the diagram input ``<name>.joystick``).
        teleop_frame: the joystick mapping (``teleoperation.TeleoperationMapper``): "world" (the
            paper's: stick axes = magnet angular velocity about world x, y, z) or "tip" (the
            catheter-frame mapping: axes 0/1 swing the field at the tip about the tip frame's z
            and -y, at ``teleop_omega_max``; the tip ball's position and direction are fed to it).
    """

    name: str = "right_unit"
    shape: str = "cylinder"
    p_WM: list[float] = field(default_factory=list)
    anchor: str = "puncture"
    distance: float = 0.1651
    direction_W: list[float] = field(default_factory=lambda: [-1.0, 0.0, 0.0])
    m_hat_W: list[float] = field(default_factory=list)
    model: str = "dipole"
    teleop_omega_max: float = 0.5
    sensor_noise: bool = True
    joystick: list[JoystickKey] = field(default_factory=list)
    joystick_source: str = "script"
    teleop_frame: str = "world"


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
        time_step: [s]; 0 means the mode's default (1e-3 or 1e-4).
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
        publish_period: Meshcat publishing period when recording [s].
        engine: "plant" (the MultibodyPlant: the reference, and the only one for dynamics) or
            "statics" (``systems/quasi_static_engine.py``: the equilibrium solved every
            ``statics_period``, quasi-static mode only).
        statics_period: the statics engine's update period [s] (50 ms: the teleoperated magnet
            turns at most 1.5 deg and the feeder moves 1 mm in one period; larger moves are
            split by the engine's continuation).
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
    publish_period: float = 1.0 / 32.0
    engine: str = "plant"
    statics_period: float = 0.05

    @property
    def effective_time_step(self) -> float:
        return self.time_step if self.time_step > 0 else DEFAULT_TIME_STEP[self.mode]

    def validate(self) -> "ChainScenario":
        """Check the values; raises ValueError saying what is wrong. Returns self."""
        if self.mode not in MODES:
            raise ValueError(f"scenario mode must be one of {MODES}, got {self.mode!r}")
        if self.engine not in ENGINES:
            raise ValueError(f"scenario engine must be one of {ENGINES}, got {self.engine!r}")
        if self.engine == "statics" and (self.mode != "quasi-static" or not 0 < self.statics_period <= 1.0):
            raise ValueError(f"engine: statics needs mode: quasi-static and 0 < statics_period <= 1 s, got "
                             f"mode {self.mode!r}, statics_period {self.statics_period}")
        if self.n_balls < 2:
            raise ValueError(f"scenario n_balls must be >= 2 (ball 1 is the feeder ball), got {self.n_balls}")
        if self.time_step < 0 or self.duration < 0 or self.check_period <= 0:
            raise ValueError("scenario time_step, duration must be >= 0 and check_period > 0")
        if self.atrium_file and len(self.puncture) != 3:
            raise ValueError("a scenario with atrium_file needs puncture: [x, y, z] (m), the septal "
                             "puncture on that surface")
        if self.sheath_aim and len(self.sheath_aim) != 3:
            raise ValueError(f"scenario sheath_aim must have 3 components [m], got {self.sheath_aim}")
        if len(self.uniform_field) != 3:
            raise ValueError(f"scenario uniform_field must have 3 components [T], got {self.uniform_field}")
        for k, m in enumerate(self.magnets):
            if m.shape not in ("cylinder", "sphere"):
                raise ValueError(f"magnet {k + 1}: shape must be 'cylinder' or 'sphere', got {m.shape!r}")
            if m.model not in ("dipole", "exact"):
                raise ValueError(f"magnet {k + 1}: model must be 'dipole' or 'exact', got {m.model!r}")
            if m.p_WM and len(m.p_WM) != 3:
                raise ValueError(f"magnet {k + 1}: p_WM must have 3 components [m], got {m.p_WM}")
        self._validate_units()
        ins = self.insertion
        if ins.feeder_command not in FEEDER_COMMANDS:
            raise ValueError(f"insertion.feeder_command must be one of {FEEDER_COMMANDS}, got {ins.feeder_command!r}")
        if ins.feeder_command == "external" and not ins.feeder:
            raise ValueError("insertion.feeder_command: external needs the feeder (insertion.feeder: true)")
        if self.mode == "dynamics" and self.effective_time_step > 5e-4:
            raise ValueError(
                f"time step {self.effective_time_step} s is too large for the dynamics mode: the "
                "magnetic forces are explicit and need about 1e-4 s (use quasi-static for larger steps)")
        return self


    def _validate_units(self) -> None:
        names = [u.name for u in self.units]
        if len(set(names)) != len(names):
            raise ValueError(f"scenario units must have distinct names, got {names}")
        for u in self.units:
            where = f"unit {u.name!r}"
            if not u.name or "." in u.name:
                raise ValueError(f"{where}: name must be non-empty and without dots")
            if u.shape not in ("cylinder", "sphere"):
                raise ValueError(f"{where}: shape must be 'cylinder' or 'sphere', got {u.shape!r}")
            if u.model not in ("dipole", "exact") or u.model != self.units[0].model:
                raise ValueError(f"{where}: model must be 'dipole' or 'exact', the same for every unit")
            if u.p_WM and len(u.p_WM) != 3:
                raise ValueError(f"{where}: p_WM must have 3 components [m], got {u.p_WM}")
            if u.m_hat_W and (len(u.m_hat_W) != 3 or not any(u.m_hat_W)):
                raise ValueError(f"{where}: m_hat_W must be 3 components, not all zero, got {u.m_hat_W}")
            if not u.p_WM:
                if u.anchor not in ANCHORS:
                    raise ValueError(f"{where}: anchor must be one of {ANCHORS}, got {u.anchor!r}")
                if u.anchor.startswith("carina") and not self.heart:
                    raise ValueError(f"{where}: anchor {u.anchor!r} needs the heart (heart: true)")
                if len(u.direction_W) != 3 or not any(u.direction_W) or u.distance <= 0:
                    raise ValueError(f"{where}: needs direction_W (3, non-zero) and distance > 0 [m]")
            if u.joystick_source not in JOYSTICK_SOURCES:
                raise ValueError(f"{where}: joystick_source must be one of {JOYSTICK_SOURCES}, got {u.joystick_source!r}")
            if u.teleop_frame not in TELEOP_FRAMES:
                raise ValueError(f"{where}: teleop_frame must be one of {TELEOP_FRAMES}, got {u.teleop_frame!r}")
            if u.teleop_omega_max <= 0:
                raise ValueError(f"{where}: teleop_omega_max must be > 0 [rad/s]")
            times = [k.time for k in u.joystick]
            if any(t < 0 for t in times) or any(b < a for a, b in zip(times, times[1:])):
                raise ValueError(f"{where}: joystick key times must be >= 0 and non-decreasing, got {times}")
            for k in u.joystick:
                if len(k.axes) != 3 or k.mode not in (0, 1):
                    raise ValueError(f"{where}: joystick key at t = {k.time} s needs 3 axes and mode 0 or 1")


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
        ValueError: unknown name, a field that does not exist, or a bad value (the message
            says which).
    """
    names = scenario_names(filename)
    if name not in names:
        raise ValueError(f"unknown scenario {name!r}; known scenarios: {', '.join(names)}")
    try:
        scenario = yaml_load_typed(schema=ChainScenario, filename=str(filename), child_name=name,
                                   defaults=ChainScenario())
        if overrides:
            scenario = yaml_load_typed(schema=ChainScenario, data=overrides, defaults=scenario)
    except RuntimeError as err:  # yaml_load_typed reports unknown keys and bad types this way
        raise ValueError(f"scenario {name!r}: {err}") from None
    return scenario.validate()
