"""The scenario's checks (``ChainScenario.validate`` runs ``check_fields``): every field finite, of
its kind (``check_kinds``), one of the allowed choices, in range, in plausible units (SI), and
taking effect. ``chain_scenario`` re-exports every name.

The scenario's own defaults are its class's (``type(s)``: ``chain_scenario.ChainScenario``, which
imports this module).
"""


import dataclasses
import math
import numbers
import typing
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import GetIntegrationSchemes
from pydrake.visualization import VisualizationConfig

from ballchain.drake_models import wall_motion
from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.drake_models.localisation import check_figures
from ballchain.systems.world_scenario import check_world
from ballchain.infrastructure.safe_files import register_input
from ballchain.infrastructure.safe_yaml import check_value, schema_fields as _schema_fields
from ballchain.drake_models.params import BallChain
from ballchain.systems.device_model import DEVICE_MODELS, DEVICES, ENGINES, engines
from ballchain.systems.engine_config import ScenarioChoice, choices_with
from ballchain.systems.feeder import FeederSpec, batch_steps
from ballchain.systems.force_sensor_pin import stability_bound
from ballchain.systems.randomness import check_random_seed
from ballchain.systems.scenario_schema import (ANCHORS, CONTACT_MODELS, CONTACT_SURFACE_REPRESENTATIONS,
                                               DISCRETE_CONTACT_APPROXIMATIONS, FEEDER_COMMANDS,
                                               JOYSTICK_SOURCES, MODES, TELEOP_FRAMES, UNIT_SYSTEMS,
                                               VISUALIZATION_FIELDS_USED, MagnetScenario, PinScenario,
                                               WallMotionScenario, station_visualization_config)
from ballchain.systems.unit_config import MagnetUnitConfig
from ballchain.drake_models.atrium_mesh import MESH_NOUN
from ballchain.drake_models.model_files import resolve_uri
from ballchain.infrastructure.input_files import MAX_MESH_BYTES, check_input_file
from ballchain.infrastructure.safe_yaml import MAX_BYTES

# ------------------------------------------------------------------------------------------------
# Validation at the edge: the YAML's shape against the schema before pydrake reads it,
# and every field's value (finite, in range, plausible units, taking effect) before anything is built.

MAX_BALLS = 100  # the paper's chain has 16; the procedural atrium is about 50 mm across
MIN_TIME_STEP = 1e-6  # [s]
MAX_TIME_STEP = 1e-2  # [s]: the quasi-static contact model needs about 1e-3
MAX_DYNAMICS_STEP = 5e-4  # [s]: the magnetic forces are explicit; true dynamics needs about 1e-4
MAX_DURATION = 3600.0  # [s] of simulated time
MAX_STEPS = 5_000_000  # updates of the most frequent periodic event: hours of wall time at a few ms each
MAX_UNIFORM_FIELD = 0.5  # [T]: clinical fields are tens of mT; 23 here means 23 T (mT typed)
MAX_DISTANCE = 1.0  # [m]: magnets, points and walls farther away are a unit mistake (mm typed as m)
MAX_CHECK_PERIOD = 1.0  # [s]: the watchdog looks at least once a second (an escape or a break is not missed for longer)
# [N s/m], [N m s]: 1000x the defaults; beyond them a ball barely moves in a run (a quasi-static
# joint's time constant damping / stiffness grows past the run's length) and large values overflow.
MAX_DAMPING = {"translational_damping": 1e3, "angular_damping": 1e-2}
MIN_SAMPLES_PER_CYCLE = 8  # the statics engine's updates per cycle of a moving wall's fastest motion

# Contact parameters: (low, high, unit, why). The bounds keep the contact physical and the
# discrete solver well conditioned; outside them a run fails inside Drake ("Call to Solve()
# failed: factorization not ready" at 1e30 N/m) or the chain blows apart at once. Measured on
# free_space_wall (20 ms at 1 ms and at 0.1 ms steps): 1e5..1e9 N/m run at 0.1 ms, 1e4 N/m
# breaks the chain at both steps, a relaxation time of 0.01 s breaks it at 1 ms.
CONTACT_BOUNDS = {
    # A 3.175 mm steel ball's Hertz stiffness against steel is ~1e8 N/m: 1e9 is stiffer than any
    # material here. Below 1e5 N/m the magnetic attraction between neighbours (~1 N) presses the
    # balls into each other by more than 10 um and the chain comes apart.
    "ball_point_stiffness": (1e5, 1e9, "N/m", "softer, neighbours sink into each other and the chain comes apart; "
                             "stiffer than steel on steel, the solver's factorisation fails"),
    # SAP's dissipation time scale: 0 is "the time step"; beyond 0.1 s the contact is a dashpot
    # that holds the balls for longer than a quasi-static settling lasts.
    "relaxation_time": (0.0, 0.1, "s", "0 is the time step; a longer one is a dashpot that outlasts the settling"),
    # Coulomb coefficients of steel, PTFE and tissue are below 1.
    "friction": (0.0, 2.0, "", "steel, PTFE and tissue are below 1"),
    # Atrial tissue is ~1e4-1e5 Pa; the wall model is stiffer on purpose (see ContactConfig);
    # cortical bone is ~1e10 Pa.
    "wall_hydroelastic_modulus": (1e4, 1e10, "Pa", "atrial tissue is ~1e4-1e5 Pa, bone ~1e10 Pa"),
    # Distances at the scale of a ball (3.175 mm): a margin or mesh size beyond it is larger
    # than the gaps it resolves; a resolution below 0.1 mm meshes each ball with ~1e5 triangles.
    "hydroelastic_margin": (1e-6, 1e-3, "m", "at most a third of a ball"),
    "ball_resolution_hint": (1e-4, 1e-2, "m", "finer meshes each ball with ~1e5 triangles"),
}
MAX_SLIDE_KP = 1e9  # [N/m]: the slide actuator is implicit in SAP; the same conditioning as the contact
PLANT_CONFIG_BOUNDS = {  # MultibodyPlantConfig's numbers: (low, high, low open, what)
    "penetration_allowance": (0.0, 1e-2, True, "m (a penetration of 1 cm is larger than a ball)"),
    "stiction_tolerance": (0.0, 1.0, True, "m/s (the chain moves at mm/s)"),
    "sap_near_rigid_threshold": (0.0, 1.0, False, "(Drake's default is 1)"),
}


def _list_item_schema(tp):
    """The schema of a list's items when they are mappings (a dataclass), else None."""
    if typing.get_origin(tp) in (list, tuple) and typing.get_args(tp):
        item = typing.get_args(tp)[0]
        return item if dataclasses.is_dataclass(item) else None
    return None


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


def check_kinds(obj, schema=None, path: str = "") -> None:
    """A scenario built or changed in Python (``ChainScenario(...)``, ``dataclasses.replace``,
    an attribute set) against its schema, every field recursively: each part an instance of its
    dataclass or pydrake config struct, each list a list, each value what ``safe_yaml.check_value``
    allows in the YAML. Numpy numbers and arrays, and tuples, are stored as the plain numbers and
    lists they hold (what ``load_scenario`` gives), so the checks after this one read plain data.

    Raises:
        UserInputError: "scenario: {path} must be {what}, got {value}", naming the field path.
    """
    schema = type(obj) if schema is None else schema
    for name, tp in _schema_fields(schema).items():
        where = f"{path}.{name}" if path else name
        value = getattr(obj, name)
        plain = _plain(value)
        _check_kind(plain, tp, where)
        if plain is not value and dataclasses.is_dataclass(obj):  # pydrake's structs convert on their own
            setattr(obj, name, plain)


def _plain(value):
    """Numpy numbers and arrays, and tuples, as the Python numbers and lists they hold."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    if isinstance(value, list) and any(isinstance(v, (np.generic, np.ndarray, tuple)) for v in value):
        return [_plain(v) for v in value]
    return value


def _a(name: str) -> str:
    return f"{'an' if name[:1] in 'AEIOU' else 'a'} {name}"


def _check_kind(value, tp, path: str) -> None:
    if isinstance(tp, type) and issubclass(tp, ScenarioChoice):  # the engine, the device: a config or its name
        _require(isinstance(value, tp), f"scenario: {path} must be {_a(tp.__name__)} or its name (a string), "
                                        f"got {type(value).__name__} {short_repr(value)}")
        return
    if typing.get_origin(tp) is typing.Union and type(None) in typing.get_args(tp):  # Optional[T]
        if value is None:
            return
        (tp,) = [a for a in typing.get_args(tp) if a is not type(None)]
    item = _list_item_schema(tp)
    if _schema_fields(tp) is not None:
        if not isinstance(value, tp):
            hint = (f" (a mapping is the YAML's form: {tp.__name__}(**fields), or load_scenario's overrides)"
                    if isinstance(value, dict) else "")
            raise UserInputError(f"scenario: {path} must be {_a(tp.__name__)}{hint}, "
                                 f"got {type(value).__name__} {short_repr(value)}")
        check_kinds(value, tp, path)
    elif item is not None:
        if not isinstance(value, list):
            raise UserInputError(f"scenario: {path} must be a list of {item.__name__}, "
                                 f"got {type(value).__name__} {short_repr(value)}")
        for i, entry in enumerate(value):
            _check_kind(entry, item, f"{path}[{i}]")
    else:
        check_value(value, tp, path, "scenario")


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise UserInputError(message)


def _one_of(value, allowed, name: str) -> None:
    _require(value in allowed, f"scenario {name} must be one of {', '.join(map(repr, allowed))}, "
                               f"got {short_repr(value)}")


def _point(v, name: str, empty_ok: bool = True) -> None:
    """[] (when ``empty_ok``) or 3 coordinates in metres within MAX_DISTANCE of the origin."""
    _require((empty_ok and not v) or (len(v) == 3 and np.linalg.norm(v) <= MAX_DISTANCE),
             f"scenario {name} must be {'[] or ' if empty_ok else ''}3 coordinates in metres "
             f"(within {MAX_DISTANCE:g} m), got {short_repr(v)}")


def _direction(v, name: str, empty_ok: bool = False) -> None:
    _require((empty_ok and not v) or (len(v) == 3 and any(v)),
             f"scenario {name} must be {'[] or ' if empty_ok else ''}3 components, not all zero, got {short_repr(v)}")


def check_fields(s: "ChainScenario") -> None:
    """Every field of a scenario in one pass, reporting the first bad one: finite, one of the
    allowed choices, in range, in plausible units (SI), and taking effect (a field the
    scenario's other choices would ignore is refused). Called by ``ChainScenario.validate``.

    Raises:
        UserInputError: naming the field, the value and what is allowed.
    """
    for path, value in _finite_fields(s):
        raise UserInputError(f"scenario {path} must be a finite number, got {value}")
    check_kinds(s)  # a scenario built in Python: every field of its kind, before anything reads one
    _one_of(s.mode, MODES, "mode")
    _one_of(s.engine, ENGINES, "engine")
    _one_of(s.unit_systems, UNIT_SYSTEMS, "unit_systems")
    _one_of(s.device, DEVICES, "device")
    s.device.check(s)  # each config checks the scenario for itself (engine_config)
    _require((s.device, s.engine) in DEVICE_MODELS,
             f"scenario engine {short_repr(s.engine)} has no model of device {s.device!r}: its engines: "
             f"{', '.join(map(repr, engines(s.device)))}")
    s.engine.check(s)
    if s.random_seed is not None:
        check_random_seed(s.random_seed, "scenario random_seed")
    check_timing(s)
    check_atrium(s)
    check_field_sources(s)
    check_units(s)
    check_insertion(s)
    check_contact(s)
    check_drake_configs(s)
    check_wall_motion(s)
    loc = s.localisation
    check_figures(loc.noise_std, loc.rate, loc.latency, "scenario localisation.")
    check_world(s)
    if s.pin.point:
        check_pin(s)
    _require(s.pin.point or s.pin.stiffness == PinScenario.stiffness,
             f"scenario pin.stiffness = {s.pin.stiffness:g} N/m: without pin.point there is no pin "
             "(give pin.point, or leave pin out)")


def check_timing(s: "ChainScenario") -> None:
    """The chain's length, the steps and periods, the run's length and the damping."""
    whole = isinstance(s.n_balls, numbers.Integral) and not isinstance(s.n_balls, bool)
    _require(whole and 2 <= s.n_balls <= MAX_BALLS,
             f"scenario n_balls must be an integer in 2..{MAX_BALLS} (ball 1 is the feeder ball), got {s.n_balls!r}")
    _require(s.time_step == 0.0 or MIN_TIME_STEP <= s.time_step <= MAX_TIME_STEP,
             f"scenario time_step must be 0 (the mode's default) or in {MIN_TIME_STEP:g}..{MAX_TIME_STEP:g} s, "
             f"got {s.time_step:g}")
    _require(s.mode != "dynamics" or s.effective_time_step <= MAX_DYNAMICS_STEP,
             f"scenario time_step {s.effective_time_step:g} s is too large for the dynamics mode: the magnetic "
             "forces are explicit and need about 1e-4 s (use quasi-static for larger steps)")
    _require(0.0 < s.statics_period <= 1.0, f"scenario statics_period must be in (0, 1] s, got {s.statics_period:g}")
    for name in ("break_gap", "check_period"):
        _require(getattr(s, name) > 0.0, f"scenario {name} must be > 0, got {getattr(s, name):g}")
    _require(s.check_period <= MAX_CHECK_PERIOD,
             f"scenario check_period must be at most {MAX_CHECK_PERIOD:g} s (the watchdog's checks), got {s.check_period:g}")
    _require(s.break_gap <= MAX_DISTANCE, f"scenario break_gap must be at most {MAX_DISTANCE:g} m, got {s.break_gap:g}")
    check_steps(s, s.duration, "scenario duration")
    for name in ("translational_damping", "angular_damping"):
        _require(0.0 <= getattr(s, name) <= MAX_DAMPING[name],
                 f"scenario {name} must be in 0..{MAX_DAMPING[name]:g}, got {getattr(s, name):g}")
        if s.mode == "dynamics" or not s.engine.has_plant:  # only the plant's quasi-static joints are damped
            _require(getattr(s, name) == getattr(type(s), name),
                     f"scenario {name} = {getattr(s, name):g} damps the plant's quasi-static joints: "
                     f"{'mode: dynamics' if s.mode == 'dynamics' else f'engine: {s.engine}'} does not read it "
                     "(leave it out, or use mode: quasi-static with engine: plant)")


def update_periods(s: "ChainScenario") -> dict:
    """{field: period [s]} of the run's periodic events: the engine's step (the plant's time
    step or the statics engine's update), the monitor's checks, the publishing, and the
    simulator's largest step."""
    return dict([s.engine.update(s), ("check_period", s.check_period),
                 ("visualization.publish_period", s.visualization.publish_period),
                 ("simulator_config.max_step_size", s.simulator_config.max_step_size)])


def check_steps(s: "ChainScenario", duration: float, what: str = "--duration") -> None:
    """A run of ``duration``: positive, at most MAX_DURATION, and at most MAX_STEPS updates of
    each periodic event of ``update_periods``.

    Raises:
        UserInputError: naming ``what`` and the period's field.
    """
    if isinstance(duration, bool) or not isinstance(duration, numbers.Real):
        raise UserInputError(f"{what} must be a number in (0, {MAX_DURATION:g}] s, got {short_repr(duration)}")
    if not (math.isfinite(duration) and 0.0 < duration <= MAX_DURATION):
        raise UserInputError(f"{what} must be in (0, {MAX_DURATION:g}] s, got {duration:g}")
    for name, period in update_periods(s).items():
        if period > 0.0 and duration / period > MAX_STEPS:
            raise UserInputError(f"{what} {duration:g} s at a {period:g} s {name} is {duration / period:.3g} updates, "
                                 f"more than {MAX_STEPS:.0e}: shorten it or raise {name}")


def check_atrium(s: "ChainScenario") -> None:
    """The heart's fields, each only where it takes effect: the procedural atrium's size and
    mesh, or a user's atrium (file, units, puncture, sheath aim); a flat wall only in free space."""
    _require(0.1 <= s.heart_scale <= 5.0, f"scenario heart_scale must be in 0.1..5, got {s.heart_scale:g}")
    _require(1 <= s.heart_subdivisions <= 6,
             f"scenario heart_subdivisions must be in 1..6, got {s.heart_subdivisions}")
    _one_of(s.atrium_units, ("auto", "m", "mm"), "atrium_units")
    for name in ("puncture", "sheath_aim"):
        _point(getattr(s, name), name)
    default = type(s)()
    procedural = ("heart_scale", "heart_subdivisions")
    user = ("atrium_file", "atrium_units", "puncture", "sheath_aim")
    if s.anatomy:
        check_anatomy_field(s, procedural + user, default)
    for name in procedural + user:
        changed = getattr(s, name) != getattr(default, name)
        _require(not changed or s.heart, f"scenario {name} is for the heart: heart: false does not read it "
                                         "(leave it out, or use heart: true)")
        if name in procedural:
            _require(not changed or not s.atrium_file,
                     f"scenario {name} shapes the procedural atrium: with atrium_file it is not read (leave it out)")
        elif name != "atrium_file":
            _require(not changed or s.atrium_file,
                     f"scenario {name} is for a user's atrium (atrium_file): the procedural atrium does not read "
                     "it, it has its own puncture and sheath axis (leave it out, or give atrium_file)")
    if s.atrium_file:
        _require(len(s.puncture) == 3, "scenario atrium_file needs puncture: [x, y, z] (m), the septal "
                                       "puncture on that surface")
        check_atrium_file(s.atrium_file)
    _require(len(s.wall_plane) in (0, 6),
             f"scenario wall_plane must be [] or 6 numbers (point, normal) [m], got {short_repr(s.wall_plane)}")
    if s.wall_plane:
        _point(s.wall_plane[:3], "wall_plane point", empty_ok=False)
        _direction(s.wall_plane[3:], "wall_plane normal")
        _require(not s.heart, "scenario wall_plane is for free space (heart: false): the heart has its own wall")


def check_field_sources(s: "ChainScenario") -> None:
    """The fixed field: a uniform field in tesla and fixed magnets within MAX_DISTANCE."""
    _require(len(s.uniform_field) == 3,
             f"scenario uniform_field must have 3 components [T], got {short_repr(s.uniform_field)}")
    B = float(np.linalg.norm(s.uniform_field))
    _require(B <= MAX_UNIFORM_FIELD,
             f"scenario uniform_field |B| = {B:g} T exceeds {MAX_UNIFORM_FIELD:g} T: it is in tesla "
             "(23 mT is 0.023)")
    default = MagnetScenario()
    for k, m in enumerate(s.magnets):
        where = f"magnets[{k}]"
        _one_of(m.shape, ("cylinder", "sphere"), f"{where}.shape")
        _one_of(m.model, ("dipole", "exact"), f"{where}.model")
        _require(0.0 < m.distance_from_puncture <= MAX_DISTANCE,
                 f"scenario {where}.distance_from_puncture must be in (0, {MAX_DISTANCE:g}] m, "
                 f"got {m.distance_from_puncture:g}")
        for name in ("direction_W", "m_hat_W"):
            _direction(getattr(m, name), f"{where}.{name}")
        _point(m.p_WM, f"{where}.p_WM")
        for name in ("distance_from_puncture", "direction_W"):
            _require(not m.p_WM or getattr(m, name) == getattr(default, name),
                     f"scenario {where}.{name} places the magnet from the puncture: with p_WM it is not read "
                     "(give one of them)")


def check_units(s: "ChainScenario") -> None:
    """The rotating units: distinct names, choices, placement within MAX_DISTANCE, the
    controller's numbers, and joysticks with keys in time order."""
    names = [u.name for u in s.units]
    _require(len(set(names)) == len(names), f"scenario units must have distinct names, got {short_repr(names)}")
    default = MagnetUnitConfig()
    for k, u in enumerate(s.units):
        where = f"units[{k}]"
        _require(bool(u.name) and "." not in u.name, f"scenario {where}.name must be non-empty and without dots, "
                                                     f"got {short_repr(u.name)}")
        _one_of(u.shape, ("cylinder", "sphere"), f"{where}.shape")
        _one_of(u.model, ("dipole", "exact"), f"{where}.model")
        _require(u.model == s.units[0].model, f"scenario {where}.model must be the same for every unit, got "
                                              f"{u.model!r} and {s.units[0].model!r}")
        _one_of(u.anchor, ANCHORS, f"{where}.anchor")
        _require(not u.anchor.startswith("carina") or s.heart or u.p_WM,
                 f"scenario {where}.anchor {u.anchor!r} needs the heart (heart: true)")
        _one_of(u.joystick_source, JOYSTICK_SOURCES, f"{where}.joystick_source")
        _one_of(u.teleop_frame, TELEOP_FRAMES, f"{where}.teleop_frame")
        _one_of(u.wheel_map, ("derived", "paper"), f"{where}.wheel_map")
        _require(0.0 < u.distance <= MAX_DISTANCE,
                 f"scenario {where}.distance must be in (0, {MAX_DISTANCE:g}] m, got {u.distance:g}")
        _direction(u.direction_W, f"{where}.direction_W")
        _direction(u.m_hat_W, f"{where}.m_hat_W", empty_ok=True)
        _point(u.p_WM, f"{where}.p_WM")
        for name in ("anchor", "distance", "direction_W"):
            _require(not u.p_WM or getattr(u, name) == getattr(default, name),
                     f"scenario {where}.{name} places the unit from its anchor: with p_WM it is not read "
                     "(give one of them)")
        _check_unit_numbers(u, where)


def _check_unit_numbers(u: "MagnetUnitConfig", where: str) -> None:
    _require(u.teleop_omega_max > 0.0,
             f"scenario {where}.teleop_omega_max must be > 0 rad/s, got {u.teleop_omega_max:g}")
    _require(0.0 <= u.slip < 1.0, f"scenario {where}.slip must be in [0, 1), got {u.slip:g}")
    _require(0.0 < u.controller_gain <= 100.0,
             f"scenario {where}.controller_gain must be in (0, 100] 1/s, got {u.controller_gain:g}")
    _require(0.0 < u.tolerance_deg < 90.0,
             f"scenario {where}.tolerance_deg must be in (0, 90) deg, got {u.tolerance_deg:g}")
    _require(0.0 <= u.teleop_dead_band < 1.0,
             f"scenario {where}.teleop_dead_band must be in [0, 1), got {u.teleop_dead_band:g}")
    times = [key.time for key in u.joystick]
    _require(all(t >= 0 for t in times) and all(b >= a for a, b in zip(times, times[1:])),
             f"scenario {where}.joystick key times must be >= 0 and non-decreasing, got {short_repr(times)}")
    for j, key in enumerate(u.joystick):
        _require(len(key.axes) == 3 and all(abs(a) <= 1.0 for a in key.axes),
                 f"scenario {where}.joystick[{j}].axes must be 3 numbers in [-1, 1], got {short_repr(key.axes)}")
        _require(key.mode in (0, 1), f"scenario {where}.joystick[{j}].mode must be 0 (teleoperation) or "
                                     f"1 (reconfiguration), got {key.mode!r}")


def _whole_steps(period: float) -> bool:
    try:
        batch_steps(period, FeederSpec().update_period)
    except UserInputError:
        return False
    return True


def check_insertion(s: "ChainScenario") -> None:
    """The feeder's ramp (lengths within MAX_DISTANCE, a positive speed), its command, and the
    slide actuator's gains."""
    ins = s.insertion
    for name in ("initial", "final"):
        _require(0.0 <= getattr(ins, name) <= MAX_DISTANCE,
                 f"scenario insertion.{name} must be in [0, {MAX_DISTANCE:g}] m, got {getattr(ins, name):g}")
    _require(ins.start_time >= 0.0, f"scenario insertion.start_time must be >= 0 s, got {ins.start_time:g}")
    _require(ins.speed > 0.0 or (ins.final == ins.initial and ins.speed == 0.0),
             f"scenario insertion.speed must be > 0 m/s (the ramp's direction comes from initial -> final), "
             f"got {ins.speed:g}")
    _one_of(ins.feeder_command, FEEDER_COMMANDS, "insertion.feeder_command")
    _require(ins.feeder_command != "external" or ins.feeder,
             "scenario insertion.feeder_command: external needs the feeder (insertion.feeder: true)")
    period = ins.feeder_command_period
    _require(period == 0.0 or (ins.feeder_command == "external" and 0.0 < period <= 1.0
                               and _whole_steps(period)),
             "scenario insertion.feeder_command_period must be 0, or with feeder_command: external a whole "
             f"multiple of the feeder's {FeederSpec().update_period:g} s step up to 1 s, got {period:g}")
    kp_kd = ins.slide_gains
    _require(len(kp_kd) == 2 and all(math.isfinite(g) and g >= 0.0 for g in kp_kd) and 0.0 < kp_kd[0] <= MAX_SLIDE_KP,
             f"scenario insertion.slide_gains must be [kp in (0, {MAX_SLIDE_KP:g}] N/m, kd >= 0 N s/m], "
             f"got {short_repr(kp_kd)}")


def check_contact(s: "ChainScenario") -> None:
    """The contact parameters within CONTACT_BOUNDS (see there for the reasons)."""
    c = s.contact
    for name, (lo, hi, unit, why) in CONTACT_BOUNDS.items():
        v = getattr(c, name)
        _require(lo <= v <= hi, f"scenario contact.{name} must be in [{lo:g}, {hi:g}]{' ' + unit if unit else ''} "
                                f"({why}), got {v:g}")


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
                 f"scenario plant_config.{name} must be one of {allowed}, got {short_repr(getattr(p, name))}")
    for name, (lo, hi, lo_open, unit) in PLANT_CONFIG_BOUNDS.items():
        v = getattr(p, name)
        _require(math.isfinite(v) and (lo < v if lo_open else lo <= v) and v <= hi,
                 f"scenario plant_config.{name} must be in {'(' if lo_open else '['}{lo:g}, {hi:g}] {unit}, got {v:g}")
    c = s.simulator_config
    schemes = GetIntegrationSchemes()
    _require(c.integration_scheme in schemes,
             f"scenario simulator_config.integration_scheme must be one of {', '.join(schemes)}, "
             f"got {short_repr(c.integration_scheme)}")
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
                f"scenario visualization.{f.name} = {short_repr(getattr(v, f.name))} is not supported by the station "
                f"(it reads only {', '.join(VISUALIZATION_FIELDS_USED)}; {f.name} stays {getattr(default, f.name)!r})")


def check_wall_motion(s: "ChainScenario") -> None:
    """The moving wall: each oscillation's amplitude, frequency and direction
    (``wall_motion.check_oscillation``), sampled at least ``MIN_SAMPLES_PER_CYCLE`` times a cycle
    by the engine's updates; on only with ``engine: statics`` (the plant's wall is fixed) and
    the magnetic chain; its fields only when it is on.

    Raises:
        UserInputError: naming the field (``wall_motion.<part>.<field>``).
    """
    w = s.wall_motion
    _require(isinstance(w.enabled, bool),
             f"scenario wall_motion.enabled must be true or false, got {short_repr(w.enabled)}")
    for name in ("respiratory", "cardiac"):
        o = getattr(w, name)
        where = f"scenario wall_motion.{name}"
        wall_motion.check_oscillation(o.amplitude, o.frequency, o.direction_W, where, "direction_W")
        samples = 1.0 / (o.frequency * s.statics_period)
        _require(not w.enabled or o.amplitude == 0.0 or samples >= MIN_SAMPLES_PER_CYCLE,
                 f"{where}.frequency {o.frequency:g} Hz is sampled {samples:.1f} times a cycle by statics_period "
                 f"{s.statics_period:g} s: at least {MIN_SAMPLES_PER_CYCLE} (lower statics_period or the frequency)")
    if not w.enabled:
        _require(repr(w) == repr(WallMotionScenario()),
                 "scenario wall_motion: its amplitudes, frequencies and directions are read only with "
                 "wall_motion.enabled: true (add it, or leave them out)")
        return
    _require(s.engine.moves_wall, f"scenario wall_motion needs engine: {choices_with('engine', ENGINES, 'moves_wall')} "
                                  f"(the quasi-static engine places the wall for each update; the plant's wall is "
                                  f"fixed), got {s.engine!r}"
                                  + ("" if s.mode == "quasi-static" else f" (mode {s.mode} runs only on the plant)"))
    _require(s.device.takes_wall_motion, f"scenario wall_motion is for the magnetic chain (device: "
                                         f"{choices_with('device', DEVICES, 'takes_wall_motion')})")
    _require(s.heart or bool(s.wall_plane), "scenario wall_motion moves a wall: it needs the heart or a wall_plane")


def check_pin(s: "ChainScenario") -> None:
    """A pin point (3, in metres) and a stiffness below the explicit spring's stability bound.

    Raises:
        UserInputError: naming ``pin.point`` or ``pin.stiffness``.
    """
    _point(s.pin.point, "pin.point")
    _require(s.engine.holds_pin, f"scenario pin needs engine: {choices_with('engine', ENGINES, 'holds_pin')} (the pin "
                                 f"is a force on the plant), got {s.engine!r}")
    chain = BallChain(n_balls=s.n_balls)
    damping = s.translational_damping if s.mode == "quasi-static" else 0.0
    bound = stability_bound(s.effective_time_step, damping, chain.ball_mass)
    _require(0.0 < s.pin.stiffness < bound,
             f"scenario pin.stiffness {s.pin.stiffness:g} N/m must be > 0 and below the explicit spring's "
             f"stability bound {bound:g} N/m at a {s.effective_time_step:g} s step: lower it or the step")

def check_anatomy_field(s: "ChainScenario", others: tuple, default: "ChainScenario") -> None:
    """An anatomy file takes the heart's place: heart: true, none of the procedural or user
    atrium's fields, and a file that exists (its fields are checked when it is loaded, before the
    build: ``station.atrium_for``)."""
    _require(s.heart, "scenario anatomy is for the heart: heart: false does not read it (leave it out, or use "
                      "heart: true)")
    for name in others:
        _require(getattr(s, name) == getattr(default, name),
                 f"scenario {name} cannot go with anatomy: the anatomy file gives the surface, its units, the "
                 f"sheath and the targets (leave {name} out)")

    path = check_input_file(s.anatomy, f"scenario anatomy {short_repr(s.anatomy)}", MAX_BYTES,
                            "an anatomy file (YAML)")
    register_input(path, "scenario anatomy file")


def check_atrium_file(path: str) -> None:
    """An atrium file that exists and is a file (a package:// URI must resolve).

    Raises:
        UserInputError: naming atrium_file.
    """
    if str(path).startswith("package://"):

        try:
            resolved = resolve_uri(path)
        except Exception as err:  # pydrake's PackageMap raises RuntimeError on an unknown package
            first = " ".join(str(err).split())[:200]
            raise UserInputError(f"scenario atrium_file {path!r} does not resolve: {first}") from None
    else:
        resolved = Path(path)

    check_input_file(resolved, f"scenario atrium_file {short_repr(path)}", MAX_MESH_BYTES, MESH_NOUN)
    register_input(resolved, "scenario atrium_file")
