"""The scenario's parts (``chain_scenario.ChainScenario``'s fields): the fixed magnets, the
insertion, the pin, the moving wall, the localisation, the station's ``VisualizationConfig``, and
the choices the checks allow (``scenario_checks``). ``chain_scenario`` re-exports every name.

No ``from __future__ import annotations``: pydrake's ``yaml_load_typed`` reads the dataclasses'
field types as objects.
"""


from dataclasses import dataclass, field

from pydrake.visualization import VisualizationConfig

from ballchain.drake_models import paper, wall_motion
from ballchain.drake_models.localisation import LocalisationParams
from ballchain.systems.chain_plant import ChainPlantConfig

MODES = ("quasi-static", "dynamics")
UNIT_SYSTEMS = ("compiled", "python")
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
        feeder_command: with ``feeder``, who commands its speed: "ramp" (the ramp above, played
            by the feeder as its speed schedule; with the quasi-static engine its 2 ms steps are
            made in batches at the engine's updates, with the same numbers: ``Feeder(schedule=,
            batch_period=)``) or "external" (another system, e.g. a simulated operator:
            the feeder's ``v_insert_cmd`` input (1) [m/s] is left to ``MakeStation``'s
            ``add_systems`` hook, or exported as the diagram input ``feeder.v_insert_cmd``).
        feeder_command_period: with ``feeder_command: external``, 0 (the command may change at
            any time), or the period [s] of the system that sets the command in its periodic
            updates (offset 0: a simulated operator's looks, 0.05 s): the feeder then makes its
            2 ms steps in batches at those updates, with the same numbers and a fifth of the
            simulator steps (``Feeder(command_period=)``; a whole multiple of the 2 ms step).
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
    feeder_command_period: float = 0.0
    slide_gains: list[float] = field(default_factory=lambda: list(ChainPlantConfig.feeder_gains))


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


@dataclass
class OscillationScenario:
    """One sinusoidal translation of the anatomy, ``amplitude sin(2 pi frequency t) direction_W``
    (``drake_models.wall_motion.Oscillation``).

    Attributes:
        amplitude: [m], half the peak-to-peak excursion (0: still).
        frequency: [Hz].
        direction_W: the direction of the motion (normalised).
    """

    amplitude: float = 0.0
    frequency: float = 1.0
    direction_W: list[float] = field(default_factory=lambda: [0.0, 0.0, 1.0])


def _oscillation(amplitude: float, frequency: float, direction) -> OscillationScenario:
    return OscillationScenario(amplitude, frequency, list(direction))


@dataclass
class WallMotionScenario:
    """The moving wall (``drake_models.wall_motion``): off unless ``enabled``; the defaults are
    the literature's (sources in ``wall_motion``'s docstring). ``engine: statics`` only.

    Attributes:
        enabled: move the anatomy.
        respiratory: the heart's and the sheath's motion relative to the magnets (5 mm along +z
            at 0.25 Hz).
        cardiac: the wall's motion relative to the sheath (1 mm along the long axis, (1, 1, -1),
            at 1.2 Hz).
    """

    enabled: bool = False
    respiratory: OscillationScenario = field(default_factory=lambda: _oscillation(
        wall_motion.RESPIRATORY_AMPLITUDE, wall_motion.RESPIRATORY_FREQUENCY, wall_motion.RESPIRATORY_DIRECTION))
    cardiac: OscillationScenario = field(default_factory=lambda: _oscillation(
        wall_motion.CARDIAC_AMPLITUDE, wall_motion.CARDIAC_FREQUENCY, wall_motion.CARDIAC_DIRECTION))

    def law(self) -> "wall_motion.WallMotion | None":
        """The motion law, or None when off or still (both amplitudes 0: nothing moves). A
        checked scenario (``check_wall_motion``)."""
        if not self.enabled:
            return None
        r, c = self.respiratory, self.cardiac
        law = wall_motion.WallMotion(wall_motion.Oscillation(r.amplitude, r.frequency, tuple(r.direction_W)),
                                     wall_motion.Oscillation(c.amplitude, c.frequency, tuple(c.direction_W)))
        return None if law.still else law


@dataclass
class LocalisationScenario:
    """The tip tracker an autonomous navigator reads (``drake_models.localisation``: the
    defaults are the NDI Aurora's, their sources there). Read by the simulated procedure
    (``ballchain procedure``, ``experiments/procedure.py``) when its run is not given figures.

    Attributes:
        noise_std: per-axis standard deviation of the position error [m] (0.40 mm).
        rate: samples per second [Hz] (40).
        latency: delay from sampling to the reading [s] (50 ms), a whole number of samples.
    """

    noise_std: float = LocalisationParams.noise_std
    rate: float = LocalisationParams.rate
    latency: float = LocalisationParams.latency

    def params(self) -> LocalisationParams:
        """The figures as ``LocalisationParams`` (a checked scenario)."""
        return LocalisationParams(self.noise_std, self.rate, self.latency)


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

