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
    """

    initial: float = 0.02
    final: float = 0.02
    start_time: float = 0.0
    speed: float = 0.01
    external: bool = False


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
        insertion: the feeder's motion.
        contact: contact parameters.
        duration: default simulated time [s].
        break_gap: a gap between neighbours larger than this means the chain broke [m].
        check_period: how often the monitor checks escape, breaks and clearance [s].
        publish_period: Meshcat publishing period when recording [s].
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
    insertion: InsertionScenario = field(default_factory=InsertionScenario)
    contact: ContactConfig = field(default_factory=ContactConfig)
    duration: float = 0.1
    break_gap: float = 1e-3
    check_period: float = 5e-3
    publish_period: float = 1.0 / 32.0

    @property
    def effective_time_step(self) -> float:
        return self.time_step if self.time_step > 0 else DEFAULT_TIME_STEP[self.mode]

    def validate(self) -> "ChainScenario":
        """Check the values; raises ValueError saying what is wrong. Returns self."""
        if self.mode not in MODES:
            raise ValueError(f"scenario mode must be one of {MODES}, got {self.mode!r}")
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
        if self.mode == "dynamics" and self.effective_time_step > 5e-4:
            raise ValueError(
                f"time step {self.effective_time_step} s is too large for the dynamics mode: the "
                "magnetic forces are explicit and need about 1e-4 s (use quasi-static for larger steps)")
        return self


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
