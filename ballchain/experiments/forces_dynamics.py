"""Table I from the simulation: the steady contact force of the damped chain on a force-sensor pin.

The statics (``experiments.forces``) finds, for each vein and configuration, the magnet
orientations that maximise the force the tip presses along the vein's axis, with the tip ball's
centre held on the pin point by a bilateral constraint. Here the same chain in the same field is
simulated as a Drake MultibodyPlant in the statics frame S (ball 1 on its feeder slide at the
origin, sheath axis +x, no heart, no sheath cage, no gravity, frictionless ball contacts), the
magnetic wrenches from ``MagneticWrenchSystem`` (the same energy, the same field source), the
free balls' floating joints damped (the chain plant's quasi-static mode, damping implicit in the
discrete solver): the steady state of this damped motion is an equilibrium of the same energy.
The pin is a force sensor (``systems.force_sensor_pin.ForceSensorPin``): a stiff linear spring
from the pin point to the tip ball's centre, whose reading is the force the chain presses on it.

Design (``PinSimulationConfig``):

* Step h = 1 ms and translational damping c = 1 N s/m on each free ball: the chain plant's
  quasi-static mode (its damping is implicit in the discrete solver, the magnetic forces and the
  pin's spring explicit).
* The spring: on a ball of mass m = 0.126 g an explicit stiffness K is stable for
  K < 2 (2 m + c h) / h^2 = 2.5e3 N/m (``force_sensor_pin.stability_bound``), and K is the pin's
  k plus the magnetic stiffness the tip already has, of the order of 1.6e3 N/m (the largest
  eigenvalue of the statics energy's Hessian at the optima over d^2). Measured on the Table I optima: k =
  1.2e3 N/m makes the sleeved LSPV/1 chain chatter, 1.5e3 N/m blows the sleeved RSPV/2 chain
  apart within 10 ms. k = 500 N/m (a factor 2.4 below the first failure) settles the tip on
  the spring in a few steps (the iteration's eigenvalues have modulus 0.33) and gives the
  sensor a deflection of 2 mm per N: 20 um per gram-force, up to 0.31 mm in Table I (whose
  largest readings, across the axis included, are 16 gf). The force hardly depends on it: the
  statics with the tip held at the deflection differs from the rigid pin's by -0.3 to +0.3 %
  (``statics_loaded_N``, the rows' ``statics_at_deflection_gf``).
* Angular damping 1e-4 N m s (the quasi-static default is 1e-5): with 1e-5 the magnetic
  torques (explicit, up to 8e-3 N m/rad) and the pin couple into a step-to-step chatter of the
  sleeved chains at k = 1e3 N/m. Damping does not move an equilibrium.
* Ball contacts frictionless (the statics is), the chain plant's point-contact stiffness:
  neighbours settle at about 5 um of overlap, which shortens the chain by 70 um and moves the
  steady force by a few tenths of a percent (RSPV/1: +0.3 % after 6 s; with ten times stiffer
  contacts that simulation ends on the statics to 0.005 %).
* The start: the statics equilibrium with the tip where the loaded pin holds it
  (``pin_force_from_statics``), the links shortened by 4 um (about their equilibrium overlap,
  so that every touching pair is a contact from the first step). Starting out of balance is
  fine up to about 0.1 N (tested: the tip 0.2 mm off, k = 500 N/m); much more moves a ball a
  tenth of a millimetre in a step, over its neighbour and out of contact, and the explicit
  2 N attraction then pulls it through.
* Steady state: the reading moved by less than ``rel_tol`` (0.1 %) of its size over the last
  ``window`` (0.1 s), no ball faster than 1 mm/s or 0.1 rad/s (a chattering chain can hold a
  steady mean reading), at least ``min_time`` (0.2 s) in; after ``max_time`` (3 s) without it
  the row reports no force and why. The chain's slowest mode relaxes in about a second, so the
  test stops with up to about 0.5 % of slow creep left (measured from starts on both sides).
* The run: the station's one run loop (``chain_simulation.run_station``), the pin's tests
  (``PinSteadyState``) its ``check`` and ``stop``, the station's watchdog (``ChainMonitor``, at
  the pin's samples) guarding it too. The watchdog only reads the state: the readings, steps and
  reasons are bit for bit those of the pin's former loop of its own (measured on nine runs:
  settled, not settled, tip off the pin, chains blown apart). Only a NaN in a state the reading
  does not see yet, or a ball flown away with the pin's tests loosened, now ends the run earlier,
  with the watchdog's message.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix

from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.drake_models.params import BallChain, gram_force
from ballchain.optimization.statics import ChainStatics, StaticsResult, straight_chain
from ballchain.experiments._result import Result, optional
from ballchain.systems.chain_plant import ContactConfig
from ballchain.systems.chain_scenario import ChainScenario, InsertionScenario, PinScenario
from ballchain.systems.station import MakeStation, Station, chain_for


@dataclass
class PinSimulationConfig:
    """How the pinned chain is simulated and when it is steady.

    Attributes:
        time_step: the plant's discrete step [s] (the chain plant's quasi-static default).
        translational_damping: on each free ball's floating joint [N s/m] (quasi-static default).
        angular_damping: on each free ball's floating joint [N m s] (10 times the quasi-static
            default, against the chatter of the magnetic torques and the pin; see above).
        stiffness: the sensor pin's spring [N/m]; with the tip's magnetic stiffness it must stay
            below ``stability_bound`` (see above).
        feeder_gains: (kp [N/m], kd [N s/m]) of ball 1's slide, held at the origin; stiff, since
            the statics clamps ball 1 (the PD is implicit in the discrete solver).
        contact_stiffness: point-contact stiffness of a ball [N/m] (the chain plant's default;
            two balls in series: about 5 um of overlap under the 2 N of a touching pair).
        overlap: initial overlap of neighbouring balls [m] (about their equilibrium overlap).
        check_period: how often the reading is sampled [s].
        window: the steady-state window [s].
        rel_tol: steady when the reading moved by less than this fraction of its size over the
            window.
        abs_tol: ... or by less than this [N] (a reading near zero).
        max_speed, max_angular_speed: and no ball moves faster than these [m/s], [rad/s] (a chain
            chattering step to step about a fixed shape can hold a steady mean reading).
        min_time: earliest steady state [s].
        max_time: give up after [s].
        max_deflection: the tip may leave the pin by at most this [m] (else it slipped off).
        max_gap: neighbouring balls may be at most this far from touching (gap or overlap) [m]
            (else the chain broke apart or a ball passed through its neighbour).
    """

    time_step: float = 1e-3
    translational_damping: float = 1.0
    angular_damping: float = 1e-4
    stiffness: float = PinScenario.stiffness  # 500 N/m (see above)
    feeder_gains: tuple = (1e6, 1e3)
    contact_stiffness: float = 1e6
    overlap: float = 4e-6
    check_period: float = 0.01
    window: float = 0.1
    rel_tol: float = 1e-3
    abs_tol: float = 1e-6
    max_speed: float = 1e-3
    max_angular_speed: float = 0.1
    min_time: float = 0.2
    max_time: float = 3.0
    max_deflection: float = 2e-3
    max_gap: float = 0.1e-3


# The pinned chain is a station (``systems/station.py``) with its pin step on: the Station's
# ``pin``, ``chain``, ``diagram`` (output ``pin_reading``) are what the run reads.
PinDiagram = Station


def pin_scenario(chain: BallChain, pin_point, config: PinSimulationConfig = PinSimulationConfig()) -> ChainScenario:
    """The station scenario of the pinned chain: free space in the statics frame (ball 1 on its
    slide held at the origin, sheath axis +x), no heart, no sheath cage, no gravity,
    frictionless ball contacts, the damped (quasi-static) floating joints, the stiff slide and
    the sensor pin of ``config``.

    Raises:
        UserInputError: a chain the scenario cannot express (only ``n_balls`` and the standard
            sleeve are scenario fields), or a pin stiffness above the stability bound.
    """
    scenario = ChainScenario(
        description="the chain's tip on a force-sensor pin (experiments/forces_dynamics.py)",
        n_balls=chain.n_balls, sleeve=chain.sleeve is not None, heart=False, sheath=False, gravity=False,
        mode="quasi-static", time_step=config.time_step, translational_damping=config.translational_damping,
        angular_damping=config.angular_damping,
        insertion=InsertionScenario(initial=0.0, final=0.0, slide_gains=list(config.feeder_gains)),
        contact=ContactConfig(ball_point_stiffness=config.contact_stiffness, friction=0.0),  # frictionless statics
        duration=config.max_time, check_period=config.check_period,  # the watchdog checks at the pin's samples
        pin=PinScenario(point=np.asarray(pin_point, float).reshape(3).tolist(), stiffness=config.stiffness))
    if chain_for(scenario) != chain:
        raise UserInputError(f"the pinned chain must be a scenario's chain (n_balls, the standard sleeve or none), "
                             f"got {chain}")
    return scenario.validate()


def build_pin_diagram(chain: BallChain, external, pin_point,
                      config: PinSimulationConfig = PinSimulationConfig()) -> Station:
    """The chain in free space in the statics frame, in ``external``, its tip held by a sensor pin.

    Built by the station builder (``MakeStation``) from ``pin_scenario``, the stand's field given
    as a prebuilt field source.

    Args:
        chain: the chain (ball 1 at the origin on its slide, the sheath axis +x).
        external: the external FieldSource (or None).
        pin_point: (3,) the pin point in S [m].
        config: the simulation's parameters.
    """
    return MakeStation(pin_scenario(chain, pin_point, config), field_source=external)


def set_chain_state(pd: PinDiagram, plant_context, positions: np.ndarray, dipoles: np.ndarray, overlap: float) -> None:
    """Ball poses from a statics configuration (ball 1 stays on its slide at the origin).

    The links keep their directions and are shortened by ``overlap``; each ball's body x (its
    dipole) along the configuration's dipole. Velocities zero.
    """
    cp = pd.chain
    plant = cp.plant
    positions = np.asarray(positions, float)
    dipoles = np.asarray(dipoles, float)
    if not np.allclose(positions[0], 0.0, atol=1e-12) or not np.allclose(dipoles[0], [1.0, 0.0, 0.0], atol=1e-9):
        raise ValueError("the statics configuration must have ball 1 at the origin with its dipole along +x")
    links = np.diff(positions, axis=0)
    d = cp.config.chain.ball_diameter
    p = np.vstack([np.zeros(3), np.cumsum(links * (1.0 - overlap / d), axis=0)])
    cp.feeder_joint.set_translation(plant_context, 0.0)
    for i in range(1, cp.n_balls):
        m = dipoles[i] / np.linalg.norm(dipoles[i])
        R = RotationMatrix(rotation_with_z_along(m)[:, [2, 0, 1]])  # body x along the dipole
        plant.GetJointByName(f"ball_{i + 1}_floating").SetPose(plant_context, RigidTransform(R, p[i]))
    plant.SetVelocities(plant_context, np.zeros(plant.num_velocities()))


@dataclass
class PinForceResult(Result):
    """What ``simulate_pin_force`` returns: the steady reading of the sensor pin (SI units).

    Attributes:
        force_N, force_gf: the reading along the axis (None when the run failed or did not
            settle, with the ``reason``).
        lateral_N, lateral_gf: its magnitude across the axis.
        reading_N: the pin's reading (3,) [N]; deflection_m: the pin's deflection (3,) [m].
        positions: the ball centres at the end (n, 3) [m].
        settled: the steady-state test passed.
        drift_rel: the reading's change over the last window over its size.
        max_speed: (the fastest ball's speed [m/s], angular speed [rad/s]) at the last test.
        stiffness_N_per_m: the pin's spring; time_step_s: the plant's step [s].
        sim_time_s, wall_time_s: simulated and wall time [s]; steps: the plant's steps.
        reason: "steady state" or why not.
        statics_loaded_N: (``pin_force_from_statics`` only) the statics force along the axis with
            the tip at the loaded pin's deflection (None if that solve failed).
    """

    force_N: float | None
    force_gf: float | None
    lateral_N: float | None
    lateral_gf: float | None
    reading_N: np.ndarray | None
    deflection_m: np.ndarray | None
    positions: np.ndarray | None
    settled: bool
    drift_rel: float | None
    max_speed: tuple | None
    stiffness_N_per_m: float
    time_step_s: float
    sim_time_s: float
    wall_time_s: float
    steps: int
    reason: str | None
    statics_loaded_N: float | None = optional()


class PinSteadyState:
    """The pin run's own tests, sampled every ``config.check_period`` (from t = 0) by the run loop.

    ``failure`` is ``run_station``'s ``check``: at each sample it reads the pin and fails the run
    on a non-finite reading, a broken chain (neighbours more than ``max_gap`` from touching) or
    a tip off the pin; ``steady`` is its ``stop``: at each sample, once ``min_time`` is in and a
    window of readings exists, the steady-state test (the reading moved by less than ``rel_tol``
    of its size over the window, no ball faster than ``max_speed`` / ``max_angular_speed``), and
    the end at the first sample at or after ``max_time``. Between samples both return at once.

    Attributes:
        readings: the readings so far (3,) [N], one a sample.
        settled: the steady-state test passed.
        drift_rel, max_speed: as in ``PinForceResult`` (at the last test).
        reason: why the run ended (None while it runs, and when it settled).
        duration: the time of the last sample the run may need [s] (at or after max_time).
    """

    def __init__(self, pd: Station, chain: BallChain, config: PinSimulationConfig):
        self._pd, self._chain, self._config = pd, chain, config
        self._plant = pd.chain.system  # the MultibodyPlant (the pin needs forces: engine plant)
        self._n_window = int(round(config.window / config.check_period))
        self._t = 0.0  # the next sample's time: the same sums of check_period as the samples
        self._sampled = False  # a sample was taken at this call and awaits the steady-state test
        self.readings: list[np.ndarray] = []
        self.settled = False
        self.drift_rel: float | None = None
        self.max_speed: tuple | None = None
        self.reason: str | None = None
        t = 0.0
        while t < config.max_time - 1e-12:
            t = round(t + config.check_period, 12)
        self.duration = t

    def _due(self, root) -> bool:
        # The plant steps at time_step; a sample is due at the first step at (or a rounding
        # error before) its time.
        return root.get_time() >= self._t - 1e-9

    def failure(self, root) -> str | None:
        """The failure tests at a sample (``run_station``'s ``check``); None between samples."""
        if not self._due(root):
            return None
        t, config, pd = self._t, self._config, self._pd
        reading = pd.diagram.GetOutputPort("pin_reading").Eval(root).copy()
        deflection = pd.pin.deflection(pd.pin.GetMyContextFromRoot(root))
        if not np.all(np.isfinite(reading)):
            self.reason = f"NaN in the state at t = {t:.3f} s"
            return self.reason
        p = pd.chain.ball_positions(self._plant.GetMyContextFromRoot(root))
        gaps = np.linalg.norm(np.diff(p, axis=0), axis=1) - self._chain.ball_diameter
        if np.abs(gaps).max() > config.max_gap:
            i = int(np.argmax(np.abs(gaps)))
            self.reason = (f"the chain broke apart at t = {t:.3f} s: balls {i + 1} and {i + 2} are "
                           f"{gaps[i] * 1e3:+.3f} mm from touching")
            return self.reason
        if np.linalg.norm(deflection) > config.max_deflection:
            self.reason = (f"the tip left the pin: {np.linalg.norm(deflection) * 1e3:.2f} mm from it at "
                           f"t = {t:.3f} s (> {config.max_deflection * 1e3:.1f} mm)")
            return self.reason
        self.readings.append(reading)
        self._sampled = True
        return None

    def steady(self, root) -> bool:
        """The steady-state test at a sample, and the end at max_time (``run_station``'s ``stop``)."""
        if not self._sampled:
            return False
        self._sampled = False
        t, config = self._t, self._config
        self._t = round(t + config.check_period, 12)
        reading = self.readings[-1]
        if len(self.readings) > self._n_window and t >= config.min_time - 1e-12:
            recent = np.array(self.readings[-self._n_window - 1:])
            drift = float(np.linalg.norm(recent - reading, axis=1).max())
            size = float(np.linalg.norm(reading))
            self.drift_rel = drift / size if size > 0 else None
            plant_context = self._plant.GetMyContextFromRoot(root)
            v = self._plant.GetVelocities(plant_context)[1:].reshape(-1, 6)  # [w, v] of balls 2..n
            self.max_speed = (float(np.linalg.norm(v[:, 3:], axis=1).max()),
                              float(np.linalg.norm(v[:, :3], axis=1).max()))
            at_rest = self.max_speed[0] < config.max_speed and self.max_speed[1] < config.max_angular_speed
            if drift < max(config.rel_tol * size, config.abs_tol) and at_rest:
                self.settled = True
                return True
        if t >= config.max_time - 1e-12:
            if self.drift_rel is None:
                why = "too short for the steady-state test"
            else:
                why = (f"the reading still moved by {100 * self.drift_rel:.2g} % over the last {config.window:g} s, "
                       f"the balls at up to {self.max_speed[0] * 1e3:.2g} mm/s and {self.max_speed[1]:.2g} rad/s")
            self.reason = f"did not settle in {config.max_time:g} s: {why}"
            return True
        return False


def simulate_pin_force(chain: BallChain, external, pin_point, axis, start=None,
                       config: PinSimulationConfig = PinSimulationConfig()) -> PinForceResult:
    """The steady reading of the sensor pin holding the tip of the damped chain.

    Runs through the station's one run loop (``chain_simulation.run_station``): the pin's tests
    (``PinSteadyState``) are its ``check`` and ``stop``, and the station's watchdog
    (``ChainMonitor``: NaN in any state, a chain broken by more than the scenario's
    ``break_gap``, a ball flown away) guards the run too; its message is the reason when it
    stops the run first (it checks the state every step for NaN, the pin only at its samples).

    Args:
        chain: the chain.
        external: the external FieldSource.
        pin_point: (3,) the pin point in S [m].
        axis: (3,) the vein's axis (the pin pressed into the vein reads positive along it).
        start: where to start: a StaticsResult (the statics equilibrium), a (positions (n, 3),
            dipoles (n, 3)) pair of any chain configuration with touching neighbours and ball 1
            at the origin along +x, or None (the straight chain).
        config: the simulation's parameters.

    Returns:
        A ``PinForceResult``; its force_N is None (with the reason) when the run failed or did
        not settle.
    """
    from ballchain.systems.chain_simulation import ChainMonitor, run_station

    t0 = time.perf_counter()
    pin_point = np.asarray(pin_point, float).reshape(3)
    axis = np.asarray(axis, float).reshape(3)
    axis = axis / np.linalg.norm(axis)
    pd = build_pin_diagram(chain, external, pin_point, config)
    root = pd.diagram.CreateDefaultContext()
    plant_context = pd.chain.system.GetMyContextFromRoot(root)
    if start is None:
        positions, dipoles = straight_chain(chain)
    elif isinstance(start, StaticsResult):
        positions, dipoles = start.positions, start.dipoles
    else:
        positions, dipoles = start
    set_chain_state(pd, plant_context, positions, dipoles, config.overlap)
    test = PinSteadyState(pd, chain, config)
    watchdog = ChainMonitor(pd)
    run = run_station(pd, duration=test.duration, monitor=watchdog, check=test.failure, stop=test.steady,
                      context=root)
    reason = test.reason
    if run.failure is not None and reason is None:  # the watchdog's, or the solver's error
        reason = run.failure if watchdog.failure else f"the simulation failed {run.failure}"
    out = dict(force_N=None, force_gf=None, lateral_N=None, lateral_gf=None, reading_N=None, deflection_m=None,
               positions=None, settled=test.settled, drift_rel=test.drift_rel, max_speed=test.max_speed,
               stiffness_N_per_m=config.stiffness, time_step_s=config.time_step, sim_time_s=run.sim_time,
               wall_time_s=time.perf_counter() - t0, steps=int(round(run.sim_time / config.time_step)),
               reason=reason)
    if not test.settled:
        return PinForceResult(**out)
    reading = test.readings[-1]
    along = float(reading @ axis)
    lateral = float(np.linalg.norm(reading - along * axis))
    out.update(force_N=along, force_gf=gram_force(along), lateral_N=lateral, lateral_gf=gram_force(lateral),
               reading_N=reading, deflection_m=pd.pin.deflection(pd.pin.GetMyContextFromRoot(run.context)),
               positions=pd.chain.ball_positions(plant_context), reason="steady state")
    return PinForceResult(**out)


def pin_force_from_statics(chain: BallChain, external, pin_point, axis, result: StaticsResult,
                           config: PinSimulationConfig = PinSimulationConfig()) -> PinForceResult:
    """Simulate a statics optimum on the sensor pin, starting from the equilibrium with the pin loaded.

    The start is the statics equilibrium with the tip held where the loaded spring puts it,
    ``pin_point - result.tip_reaction / k`` (one warm-started solve), so that the spring starts
    balanced against the chain: an unbalanced start moves the tip a tenth of a millimetre per
    step, and a ball sliding that far over its neighbour in one step leaves the contact (the
    ball contacts hold about 5 um of overlap) and is pulled through it by the explicit magnetic
    attraction at the next. Falls back on ``result`` itself if that solve fails.

    Returns:
        ``simulate_pin_force``'s result with ``statics_loaded_N`` (the statics force along the
        axis with the tip at the loaded pin's deflection, None if that solve failed): its
        difference from the rigid pin's is the sensor's compliance effect.
    """
    t0 = time.perf_counter()
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    loaded_target = np.asarray(pin_point, float) - result.tip_reaction / config.stiffness
    loaded = ChainStatics(chain, max_iterations=50).solve(external, result, tip_target=loaded_target)
    start = loaded if loaded.converged else result
    out = simulate_pin_force(chain, external, pin_point, axis, start, config)
    out.statics_loaded_N = float(-loaded.tip_reaction @ axis) if loaded.converged else None
    out.wall_time_s = time.perf_counter() - t0  # with the loaded statics solve
    return out
