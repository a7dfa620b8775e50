"""A rotating actuation unit's configuration: the one type of the scenario, the actuation
station and the unit's systems.

A unit is a magnet turned in place by three omni-wheels, a Hall sensor below it, the
dipole-direction estimator, the reconfiguration controller, the teleoperation mapper and its
joystick. ``MagnetUnitConfig`` describes all of it: a scenario's ``units`` are MagnetUnitConfigs
(read from YAML, so every field is a plain YAML value), ``actuation_station.make_actuation_station``
takes them, and the unit's systems read them (``RotatingMagnetUnit``, ``HallSensor`` and
``DipoleDirectionEstimator`` directly; the controller and the mapper through
``actuation_station.add_unit``). Every default is typed here once.

A unit's centre is given (``p_WM``) or placed from an anchor (``placed``); the systems need a
placed unit. What no scenario varies (the omni-wheel geometry, the Hall sensor's distance below
the magnet) are properties, not fields.
"""

from dataclasses import dataclass, field, replace

import numpy as np

from ballchain.drake_models import paper
from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.drake_models.field_sources import MagnetSource
from ballchain.drake_models.omniwheel import OmniWheelGeometry
from ballchain.drake_models.params import CylinderMagnet, SphereMagnet

# D, the Hall sensor's distance below the magnet centre along -z [m]: 0.10 m keeps the
# prototype's field (34 mT at most) inside an MLX90393's +-50 mT range; at rho_a + 6.5 mm = 50 mm
# it would read up to 0.30 T and saturate.
SENSOR_DISTANCE = 0.10

# The magnets a unit can turn, by ``shape``: the prototype's N52 76.2 x 38.1 mm cylinder and the
# 119 mm clinical sphere.
MAGNETS = {"cylinder": CylinderMagnet(), "sphere": SphereMagnet()}
FIELD_MODELS = ("dipole", "exact")

# The omni-wheel geometry of every unit (wheel axes in world: the units are mounted level).
_GEOMETRY = OmniWheelGeometry()


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
class MagnetUnitConfig:
    """A rotating actuation unit (magnet on omni-wheels, drive, Hall sensor, controller, joystick).

    Its systems are named ``<name>.magnet``, ``<name>.drive``, ``<name>.hall_sensor``,
    ``<name>.estimator``, ``<name>.controller``, ``<name>.teleoperation``, ``<name>.mode_switch``,
    and in a scenario's station ``<name>.joystick`` and ``<name>.mode_command``.

    Attributes:
        name: "right_unit", "left_unit", ... (distinct; the dotted-name prefix of its systems).
        shape: "cylinder" (the prototype's N52 76.2 x 38.1 mm) or "sphere" (119 mm clinical).
        p_WM: magnet centre in world [m] (fixed: the unit only turns the magnet); when empty,
            ``distance`` along ``direction_W`` from ``anchor`` (``placed``).
        anchor: "puncture" (the septal puncture; the origin in free space), "centre" (the LA
            centre, the world origin), "carina_left" or "carina_right" (heart only).
        distance: [m].
        direction_W: from the anchor towards the magnet centre.
        m_hat_W: initial dipole direction in a scenario's station; empty: the neutral direction
            (the field at the sheath exit, or at ball 1 in free space, along the insertion
            direction), which is also the reconfiguration controller's target.
        model: the field model, "dipole" or "exact" (magpylib's cylinder; the sphere is exact as a
            dipole); the same for every unit of a scenario.
        teleop_omega_max: angular speed at full stick [rad/s] (of the magnet with the world
            mapping, of the field at the tip with the tip mapping).
        sensor_noise: Gaussian noise on the Hall sensor.
        joystick: the scripted stick of a scenario's station (zero-order hold; zeros before the
            first key); with ``joystick_source: external`` only its modes are played
            (``<name>.mode_command``).
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
        sensors_see_other_units: the Hall sensor also measures the other units' fields.
        estimator_compensates_other_units: the estimator subtracts the other units' predicted
            fields at its sensor (their poses known); without it they bias it by up to 2.4 deg.
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

    def __post_init__(self) -> None:
        if not isinstance(self.p_WM, list):  # a tuple or an array from code: the YAML shape
            try:
                p = None if isinstance(self.p_WM, (str, bytes, dict)) or self.p_WM is None else \
                    np.asarray(self.p_WM, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                p = None
            if p is None or p.size not in (0, 3):
                raise UserInputError(f"MagnetUnitConfig.p_WM must be [] or 3 numbers [m] (the magnet's centre), "
                                     f"got {short_repr(self.p_WM)}")
            self.p_WM = [float(v) for v in p]

    @property
    def magnet(self) -> CylinderMagnet | SphereMagnet:
        """The magnet the unit turns (by ``shape``)."""
        if self.shape not in MAGNETS:
            raise UserInputError(f"unit {self.name!r}: shape must be one of {tuple(MAGNETS)}, "
                                 f"got {short_repr(self.shape)}")
        return MAGNETS[self.shape]

    @property
    def geometry(self) -> OmniWheelGeometry:
        """The omni-wheel geometry (wheel axes in world: the unit is mounted level)."""
        return _GEOMETRY

    @property
    def sensor_distance(self) -> float:
        """D, the Hall sensor's distance below the magnet centre [m] (``SENSOR_DISTANCE``)."""
        return SENSOR_DISTANCE

    @property
    def p_WS(self) -> np.ndarray:
        """(3,) Hall sensor position in world [m]."""
        return np.asarray(self.p_WM, dtype=float) - np.array([0.0, 0.0, self.sensor_distance])

    def source(self, R_WM: np.ndarray) -> MagnetSource:
        """The shared field model of this unit's magnet at orientation R_WM (3, 3)."""
        return MagnetSource(self.magnet, np.asarray(self.p_WM), np.asarray(R_WM), self.model)

    def placed(self, anchors: dict[str, np.ndarray]) -> "MagnetUnitConfig":
        """A copy with ``p_WM`` set: as given, or ``distance`` along ``direction_W`` from ``anchor``.

        Args:
            anchors: {"puncture", "centre", ...}: (3,) anchor points in world [m].

        Raises:
            UserInputError: the anchor is not among ``anchors`` (a user's atrium has no carinas).
        """
        if self.p_WM:
            p_WM = np.asarray(self.p_WM, float)
        else:
            if self.anchor not in anchors:
                raise UserInputError(f"unit {self.name!r}: anchor {self.anchor!r} is not available here (a user's "
                                     "atrium has no carinas): give p_WM")
            direction = np.asarray(self.direction_W, float)
            p_WM = anchors[self.anchor] + self.distance * direction / np.linalg.norm(direction)
        return replace(self, p_WM=[float(v) for v in p_WM])

    def check_placed(self) -> "MagnetUnitConfig":
        """What a unit's systems need: a centre (3 finite numbers), a known shape and field model,
        a slip in [0, 1). Returns self.

        Raises:
            UserInputError: naming the unit and the field.
        """
        p = np.asarray(self.p_WM, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise UserInputError(f"unit {self.name!r}: p_WM must be 3 finite numbers (a placed unit), "
                                 f"got {short_repr(self.p_WM)}")
        if self.model not in FIELD_MODELS:
            raise UserInputError(f"unit {self.name!r}: model must be 'dipole' or 'exact', got {short_repr(self.model)}")
        if not (0.0 <= self.slip < 1.0):
            raise UserInputError(f"unit {self.name!r}: slip must be in [0, 1), got {short_repr(self.slip)}")
        if not self.sensor_distance > self.magnet.bounding_radius:
            raise UserInputError(f"unit {self.name!r}: the sensor distance ({self.sensor_distance} m) must exceed "
                                 f"the magnet's bounding radius ({self.magnet.bounding_radius:.4f} m)")
        return self


# The actuation station's units: the paper's actuation distance, unit centre 16.51 cm from the
# septal puncture (the origin).
UNIT_DISTANCE = paper.WORKING_DISTANCE  # [m]


def right_unit(**overrides) -> MagnetUnitConfig:
    """The right-side unit (patient's right is world -y here), 16.51 cm from the origin."""
    return replace(MagnetUnitConfig(name="right_unit", p_WM=[0.0, -UNIT_DISTANCE, 0.0]), **overrides)


def left_unit(**overrides) -> MagnetUnitConfig:
    """The left-side unit (world +y), 16.51 cm from the origin."""
    return replace(MagnetUnitConfig(name="left_unit", p_WM=[0.0, UNIT_DISTANCE, 0.0]), **overrides)
