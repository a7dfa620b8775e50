"""The device model: one interface for every device in a station, and the one registry of them.

A ``DeviceModel`` is a device (the magnetic ball chain, the manual steerable catheter, a user's
own) as Drake systems in a station diagram. ``MakeStation`` (``systems/station.py``) looks its
class up by the scenario's ``(device, engine)`` (``device_model_class``), lets it add itself
(``add_to_station``), and from then on sees only this interface; so do ``run_station``, the
watchdog (``ChainMonitor``), the target tracker, the simulated operator and the report.

==========================  ======  ================================================================
port                        size    what
==========================  ======  ================================================================
actuation inputs (in)       --      named by the device (``actuation_input_ports``): the chain's
                                    ``magnet_states`` (6 k) and ``feeder_state`` (2), which the
                                    station's units and insertion drive; the catheter's ``handle``
                                    (3), which its own hand drives
``body_poses`` (out)        list    RigidTransform per body index (the device's at
                                    ``body_indices``, the tip last)
``tip_wall_force`` (out)    6       the wall's push on the tip f_W [N], then where it acts [m]
``anatomy_offsets`` (out)   6       where the state's anatomy is: the heart's (and sheath's)
                                    offset, then the wall's [m]; None: the anatomy stands still
==========================  ======  ================================================================

Besides the ports: the tip body (``tip_body_index``) and its radius, the electrode
(``electrode``), where the device leaves the sheath (``p_WE``, ``sheath_axis_W``), its reach and
inserted length (for the operator's feeder readout), the watchdog's geometry (``body_positions``,
``body_radius``, ``in_sheath``, ``neighbour_gaps``), the state's checks (``is_finite``,
``non_finite_part``, ``failure``, ``events``, ``solver_stats``) and its own metrics
(``metrics``: e.g. the catheter's windup).

A new device is a subclass and one registration::

    @register_device_model("magnet_on_rod", "statics")
    class MagnetOnRod(DeviceModel):
        ...

The devices and engines of the registry are the scenario's vocabulary (``devices()``,
``engines()``; ``chain_scenario.DEVICES`` and ``ENGINES`` are views of them). The built-in
devices are registered here by the import path of their class (loaded on first use: the
modules that define them import this one).
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ballchain.infrastructure.errors import UserInputError, short_repr


@dataclass
class Electrode:
    """The device's ablation electrode: a sphere of ``radius`` [m] centred on the origin of body
    ``body_index`` (the ball chain's tip ball; the catheter's distal electrode, its tip sphere)."""

    body_index: int
    radius: float


@dataclass
class OperatorInputs:
    """The inputs a device brings for an operator to drive (besides the station's units and
    feeder): {name: a joystick input (3)} and a feeder command input (1) [m/s] or None. The
    station exports them as ``<name>.joystick`` and ``feeder.v_insert_cmd`` when nothing drives
    them (the catheter's hand: ``hand.joystick``)."""

    joystick_inputs: dict = field(default_factory=dict)
    feeder_command_input: object | None = None


class DeviceModel(ABC):
    """A device in a station diagram: the interface every device implements (module docstring).

    Attributes:
        device, engine: the scenario's names of this model (its registry key).
        system: the Drake system whose context holds the device's state.
        time_step: the device's step [s] (a plant's step, an engine's period).
        move_period: the device moves only at updates this far apart [s], or 0 when it moves at
            every step: checking more often finds nothing new. A model with a period reports an
            update that leaves its state non-finite through ``failure`` at once.
        params_type: the type of the device's own parameters (``MakeStation(device_params=...)``),
            or None: it takes none.
        station_overlays: the station draws its Meshcat overlays (targets, field at the tip, the
            tip's wall force) for this device; False: its own view draws what it shows.
        diagram_name: the built station diagram's name.
    """

    device: str
    engine: str
    system: object
    time_step: float
    move_period: float = 0.0
    params_type: type | None = None
    station_overlays: bool = True
    diagram_name: str = "device_in_heart"

    @classmethod
    @abstractmethod
    def add_to_station(cls, builder, scenario, heart, coupling, params=None) -> DeviceModel:
        """Add the device (and what only it drives, e.g. a hand on its handle) to ``builder``.

        Args:
            scenario: the validated scenario; heart: the atrium, or None in free space;
            coupling: the fields it feels (``chain_model.FieldCoupling``: the fixed field and
                the magnets on ``magnet_states``); params: a ``params_type``, or None (defaults).
        """

    # --- the geometry --------------------------------------------------------------------------
    @property
    @abstractmethod
    def body_indices(self) -> list:
        """The device's bodies' indices in ``body_poses``, from the sheath to the tip."""

    @property
    def tip_body_index(self) -> int:
        """The tip body's index in ``body_poses``."""
        return self.body_indices[-1]

    @property
    def tip_base_body_index(self) -> int:
        """The body before the tip (the tip's direction points from it to the tip)."""
        return self.body_indices[-2]

    @property
    @abstractmethod
    def tip_radius(self) -> float:
        """The tip body's radius [m] (the target touch test's)."""

    @property
    def electrode(self) -> Electrode:
        """The ablation electrode (default: the tip body's sphere)."""
        return Electrode(int(self.tip_body_index), self.tip_radius)

    @property
    def body_radius(self) -> float:
        """The radius of the bodies the watchdog checks against the wall [m] (default: the tip's)."""
        return self.tip_radius

    @property
    @abstractmethod
    def p_WE(self) -> np.ndarray:
        """(3,) the sheath exit [m]."""

    @property
    @abstractmethod
    def sheath_axis_W(self) -> np.ndarray:
        """(3,) the unit insertion direction."""

    @property
    def start_point(self) -> np.ndarray:
        """Where the free device starts (the units' neutral field is defined there; default the
        sheath exit) [m]."""
        return self.p_WE

    @property
    @abstractmethod
    def length(self) -> float:
        """How far the device reaches beyond the sheath at most [m] (the watchdog's free-space test)."""

    @property
    @abstractmethod
    def initial_inserted_length(self) -> float:
        """The inserted length at the start, as the feeder's readout shows it [m]."""

    @abstractmethod
    def max_inserted_length(self) -> float:
        """The largest inserted length [m]."""

    def fed_chain(self):
        """The ``BallChain`` the station's stepper feeder pushes (``insertion.feeder``: its length
        and pitch).

        Raises:
            UserInputError: the device has no chain to feed (default).
        """
        raise UserInputError(f"scenario insertion.feeder: device {self.device!r} has no chain for the stepper "
                             "feeder to push (insertion: {feeder: false})")

    def in_sheath(self, p_W: np.ndarray) -> np.ndarray:
        """Whether points (k, 3) lie inside the sheath (default: no sheath)."""
        return np.zeros(len(p_W), bool)

    def neighbour_gaps(self, p_W: np.ndarray) -> np.ndarray | None:
        """The gaps between neighbouring bodies' surfaces [m] for body centres (n, 3), when the
        device is a chain of touching bodies (the watchdog then checks breaks and overlaps);
        None (default): it cannot come apart."""
        return None

    # --- ports ----------------------------------------------------------------------------------
    def get_magnet_states_input_port(self):
        """``magnet_states`` (6 k) the station's units drive, or None (default: not magnetic)."""
        return None

    def get_feeder_state_input_port(self):
        """The slide's desired state (s, ds/dt) (2) the station's insertion drives, or None."""
        return None

    def actuation_input_ports(self) -> dict:
        """The device's actuation inputs by name (default: ``magnet_states`` and
        ``feeder_state``, those it has)."""
        ports = {"magnet_states": self.get_magnet_states_input_port(),
                 "feeder_state": self.get_feeder_state_input_port()}
        return {name: port for name, port in ports.items() if port is not None}

    def operator_inputs(self) -> OperatorInputs:
        """What the device brings for an operator to drive (default: nothing)."""
        return OperatorInputs()

    @abstractmethod
    def get_body_poses_output_port(self):
        """``body_poses``: abstract list[RigidTransform] indexed by body index."""

    @abstractmethod
    def get_tip_wall_force_output_port(self):
        """``tip_wall_force`` (6): f_W [N] on the tip, then where it acts [m]."""

    def get_anatomy_offsets_output_port(self):
        """``anatomy_offsets`` (6): the heart's (and sheath's) offset, then the wall's [m]; None
        (default): the anatomy stands still."""
        return None

    @abstractmethod
    def add_visualizer(self, builder, meshcat, scenario, heart, targets):
        """Draw the device in ``meshcat`` (``scenario.visualization``); returns the visualizer,
        which records a replay (``StartRecording``, ``StopRecording``, ``PublishRecording``)."""

    def add_pin(self, builder, point: np.ndarray, stiffness: float):
        """A force-sensor pin on the tip: only a model with forces can hold one."""
        raise TypeError(f"the {self.device!r} model ({self.engine!r}) cannot hold a force-sensor pin")

    # --- the state ------------------------------------------------------------------------------
    @abstractmethod
    def body_positions(self, context) -> np.ndarray:
        """The bodies' centres (n, 3) [m], the tip last, from ``system``'s context or the root's."""

    @abstractmethod
    def is_finite(self, context) -> bool:
        """Whether the device's state in ``system``'s context is finite."""

    @abstractmethod
    def non_finite_part(self, context) -> str:
        """Which part of the state is not finite (for a failure message)."""

    def anatomy_offsets(self, context) -> tuple[np.ndarray, np.ndarray] | None:
        """(heart and sheath offset (3,), wall offset (3,)) [m] in ``system``'s context or the
        root's; None (default): the anatomy does not move."""
        return None

    @property
    def failure(self) -> str | None:
        """A failure the model found itself (a failed solve), or None."""
        return None

    def clear_failure(self) -> None:
        """Forget ``failure`` (a run started over from its initial context)."""

    @property
    def events(self) -> list:
        """What the model reported during the run (snap-throughs, failed solves)."""
        return []

    def solver_stats(self):
        """The solves of the run (``chain_model.StaticsEngineStats``), or None: no solver."""
        return None

    def metrics(self, context) -> dict:
        """The device's own metrics in the diagram's root context (e.g. the catheter's windup)."""
        return {}


# ------------------------------------------------------------------------------------------------
# The registry: (device, engine) -> the model's class (or, for the built-in ones, "module:Class").

DEVICE_MODELS: dict[tuple[str, str], type[DeviceModel] | str] = {
    ("ball_chain", "plant"): "ballchain.systems.chain_plant:PlantChainModel",
    ("ball_chain", "statics"): "ballchain.systems.quasi_static_engine:StaticsChainModel",
    ("steerable_catheter", "statics"): "ballchain.systems.catheter_model:CatheterModel",
}


def register_device_model(device: str, engine: str, model: type[DeviceModel] | None = None):
    """Register a DeviceModel subclass as the scenario's ``device`` on ``engine`` (one call).

    Without ``model``, a class decorator. Sets the class's ``device`` and ``engine``.

    Raises:
        ValueError: a name that is not an identifier, or a key registered to another class.
    """

    def register(cls):
        if not (isinstance(cls, type) and issubclass(cls, DeviceModel)):
            raise TypeError(f"register_device_model: {cls!r} is not a DeviceModel subclass")
        for what, name in (("device", device), ("engine", engine)):
            if not (isinstance(name, str) and name.isidentifier()):
                raise ValueError(f"register_device_model: {what} must be a name (an identifier), got {name!r}")
        known = DEVICE_MODELS.get((device, engine))
        if known is not None and known is not cls and _resolve(known) is not cls:
            raise ValueError(f"register_device_model: ({device!r}, {engine!r}) is already {known!r}")
        cls.device, cls.engine = device, engine
        DEVICE_MODELS[(device, engine)] = cls
        return cls

    return register if model is None else register(model)


def _resolve(entry) -> type[DeviceModel]:
    if not isinstance(entry, str):
        return entry
    module, name = entry.split(":")
    return getattr(importlib.import_module(module), name)


def device_model_class(device: str, engine: str) -> type[DeviceModel]:
    """The registered model of ``device`` on ``engine``.

    Raises:
        UserInputError: a pair the registry does not hold (naming the device's engines).
    """
    key = (device, engine)
    if key not in DEVICE_MODELS:
        if device not in devices():
            raise UserInputError(f"scenario device must be one of {', '.join(map(repr, devices()))}, "
                                 f"got {short_repr(device)}")
        raise UserInputError(f"scenario engine {short_repr(engine)} has no model of device {device!r}: "
                             f"its engines: {', '.join(map(repr, engines(device)))}")
    cls = DEVICE_MODELS[key] = _resolve(DEVICE_MODELS[key])
    cls.device, cls.engine = device, engine
    return cls


def devices() -> tuple[str, ...]:
    """The registered devices, in registration order."""
    return tuple(dict.fromkeys(device for device, _ in DEVICE_MODELS))


def engines(device: str | None = None) -> tuple[str, ...]:
    """The registered engines (of ``device``, or of any), in registration order."""
    return tuple(dict.fromkeys(engine for d, engine in DEVICE_MODELS if device is None or d == device))


class RegistryNames(Sequence):
    """A live, read-only tuple of names from the registry (``chain_scenario.DEVICES``, ``ENGINES``):
    a device registered later is in it."""

    def __init__(self, names) -> None:
        self._names = names

    def __getitem__(self, index):
        return self._names()[index]

    def __len__(self) -> int:
        return len(self._names())

    def __eq__(self, other) -> bool:
        return tuple(self) == (tuple(other) if isinstance(other, (tuple, list, RegistryNames)) else other)

    def __hash__(self) -> int:
        return hash(tuple(self))

    def __repr__(self) -> str:
        return repr(tuple(self))


DEVICES = RegistryNames(devices)
ENGINES = RegistryNames(engines)
