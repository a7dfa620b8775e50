"""The Gymnasium environments of learned navigation (issue 47; docs/guide/rl.md).

``NavigationEnv`` is the teleoperation station (``experiments.procedure.scenario_for``: the
16-ball chain in the atrium, one rotating unit beyond the right carina in the world mapping, the
stepper feeder) on the quasi-static engine, built once by ``MakeStation`` with a localisation
sensor, and advanced by a Drake Simulator (``chain_simulation.StationRunner``, its watchdog
``ChainMonitor``) one control period per ``step``. ``reset`` restarts the cached diagram's
context (``StationRunner.restart``) and draws the run's Drake randomness (the localisation noise,
the units' sensor noise: ``randomness.set_random_context``) from the environment's generator:
``reset(seed=s)`` gives the same episode for the same ``s``. ``reset`` then runs one control
period at rest, so that the sensor's first sample and the units' estimates exist before the
first observation.

Two tasks (registered by ``ballchain.rl``):

* ``ballchain/TargetReach-v0`` (``task="reach"``): one target per episode, drawn uniformly from
  the ring (``ring``: "right" or "left" on the procedural atrium, or an anatomy file's prefix) or
  from the names in ``targets``.
* ``ballchain/RingTask-v0`` (``task="ring"``): the ring's targets in order; the observation's
  target is the next one; the episode succeeds when the last one is touched.

Action (``Box``, float32): each unit's commanded magnet rotation rate about world x, y, z
[rad/s] in +-``teleop_omega_max`` (the scenario's unit, 0.5 rad/s), then the feeder's insertion
speed [m/s] in +-``FeederSpec.max_speed`` (20 mm/s); held for one control period
(``control_rate``, 20 Hz by default). A rate becomes the stick the unit's mapper reads
(``TeleoperationMapper``: past its dead band, scaled to its full-stick speed), the speed the
feeder's command (it keeps its own acceleration limit).

Observation (``Box``, float32, layout in ``obs_layout``): the localisation sensor's tip position
(3) [m] (``LocalisationSensor``: the scenario's noise, rate and latency); per unit the estimated
dipole direction ``m_hat_W`` (3) (its Hall-sensor estimator) and the magnet's angular velocity
``omega_WM_W`` (3) [rad/s] (its wheel encoders); the feeder's inserted length (1) [m]; the
target's centre (3) [m] and wall normal into the chamber (3); with ``force_estimate`` the
model-based contact force estimate along the target's normal (1) [N]
(``autonomous_navigator.TipForceEstimator``, 0 when it has no held equilibrium; a contact
force only in contact: away from the wall, the reaction that would hold the tip at the noisy
measured point); with
``privileged`` the true tip centre (3) [m] and the walls' force on the tip (3) [N]. Never the
true state unless ``privileged``.

Reward per step (constants below; the true state, the environment's own bookkeeping):
``REWARD_PROGRESS`` per millimetre the true tip centre came closer to the touch point (the target
centre plus a ball radius along its normal), ``REWARD_SUCCESS`` on a touch with the contact
force along the target's normal inside ``FORCE_WINDOW_GF`` (the procedure's 10..40 gf window),
minus ``PENALTY_FORCE`` per gf the tip's wall force exceeds ``FORCE_LIMIT_GF`` (40 gf), minus
``PENALTY_STOP`` when the watchdog stops the run (an escape from the heart, a ball sunk into the
wall, a broken chain), minus ``PENALTY_TIME`` per step.

Termination: success (the target touched with the force in the window; on the ring, the last
target), or a watchdog stop (``info["failure"]``); truncation at ``time_limit`` [s] of simulated
time. ``info``: target, distance_mm, touched, force_normal_gf, tip_force_gf, success, failure,
targets_done (ring).
"""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from pydrake.common import RandomGenerator

from ballchain.drake_models.params import gram_force
from ballchain.experiments import procedure, teleop
from ballchain.experiments.planner import anatomy_targets
from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.systems.chain_monitor import ChainMonitor, near_ostium_rim
from ballchain.systems.chain_simulation import StationRunner
from ballchain.systems.feeder import FeederSpec
from ballchain.systems.localisation_sensor import LocalisationSensor
from ballchain.systems.randomness import MAX_SEED, set_random_context
from ballchain.systems.station import MakeStation
from ballchain.systems.target_contact import targets_touched

# Reward and termination (module docstring; docs/guide/rl.md).
REWARD_PROGRESS = 1.0  # per mm of the true tip's approach to the touch point
REWARD_SUCCESS = 20.0  # a touch with the normal force inside the window
PENALTY_FORCE = 0.1  # per gf of the tip's wall force above FORCE_LIMIT_GF, per step
PENALTY_STOP = 20.0  # the watchdog stopped the run (escape, sinking, break)
PENALTY_TIME = 0.05  # per step
FORCE_WINDOW_GF = procedure.WINDOW_GF  # (10, 40) gf: the procedure's force window (its home)
FORCE_LIMIT_GF = FORCE_WINDOW_GF[1]
CONTROL_RATE = 20.0  # [Hz] default: the quasi-static engine's 50 ms update
TIME_LIMIT = 20.0  # [s] of simulated time per target (reach) by default
TASKS = ("reach", "ring")
# The observation space's bounds by part (far beyond what the station reaches): [m], unit vectors,
# [rad/s], [N].
OBS_BOUND = {"position": 1.0, "m_hat_W": 1.5, "target_n_W": 1.5, "omega_WM_W": 100.0, "force_estimate": 100.0,
             "tip_wall_force": 100.0}


def _check_number(value, name: str, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or not low <= value <= high:
        raise UserInputError(f"NavigationEnv {name} must be a number in {low:g}..{high:g}, got {short_repr(value)}")
    return float(value)


def _overrides(overrides: str | None, world) -> str | None:
    """The scenario overrides with the ``world:`` block (the scenario's perturbations) added."""
    if world is None:
        return overrides
    from ballchain.systems.chain_scenario import ChainScenario, parse_overrides

    if "world" not in getattr(ChainScenario, "__dataclass_fields__", {}):
        raise UserInputError("NavigationEnv world: this version's scenario has no world block; leave world=None")
    if not isinstance(world, dict):
        raise UserInputError(f"NavigationEnv world must be a mapping (the scenario's world block, e.g. "
                             f"{{'preset': 'literature'}}), got {short_repr(world)}")
    changes = parse_overrides(overrides)
    if "world" in changes:
        raise UserInputError("NavigationEnv: give the world either as world= or in the overrides, not both")
    return json.dumps({**changes, "world": world})


class NavigationEnv(gym.Env):
    """Reach ablation targets with the ball chain (module docstring: spaces, reward, termination).

    Args:
        task: "reach" (one target per episode) or "ring" (the ring's targets in order).
        ring: the procedural atrium's "right" (default) or "left" ring, or an anatomy file's
            target prefix (None with an anatomy: all its targets).
        targets: None (the whole ring), or target names of the ring to draw from (reach) or to
            visit in this order (ring).
        anatomy: an anatomy file (``drake_models.anatomy``) instead of the procedural atrium.
        control_rate: steps per simulated second [Hz] (a whole number of the feeder's 2 ms steps
            per period; 20 Hz: the engine's update).
        time_limit: simulated seconds before truncation (ring: per target, times their number).
        force_estimate: add the model-based force estimate to the observation.
        privileged: add the true tip centre and its wall force to the observation.
        world: the scenario's ``world:`` block (the world perturbations), or None.
        overrides: inline YAML overrides of the station's scenario.
    """

    metadata = {"render_modes": []}

    def __init__(self, task: str = "reach", ring: str | None = "right", targets=None, anatomy=None,
                 control_rate: float = CONTROL_RATE, time_limit: float = TIME_LIMIT, force_estimate: bool = False,
                 privileged: bool = False, world=None, overrides: str | None = None):
        if task not in TASKS:
            raise UserInputError(f"NavigationEnv task must be one of {TASKS}, got {short_repr(task)}")
        rate = _check_number(control_rate, "control_rate", 1.0, 500.0)
        self.time_limit = _check_number(time_limit, "time_limit", 0.05, 3600.0)
        for name, flag in (("force_estimate", force_estimate), ("privileged", privileged)):
            if not isinstance(flag, bool):
                raise UserInputError(f"NavigationEnv {name} must be true or false, got {short_repr(flag)}")
        self.task, self.period = task, 1.0 / rate
        self.force_estimate, self.privileged = force_estimate, privileged
        self.anatomy, self.ring, chosen = anatomy_targets(anatomy, ring)
        ring_names = [self.anatomy.target_names[k] for k in chosen]
        if targets is not None:
            targets = [targets] if isinstance(targets, str) else list(targets)
            unknown = [t for t in targets if t not in ring_names]
            if not targets or unknown:
                raise UserInputError(f"NavigationEnv targets must be names of ring {self.ring!r} "
                                     f"({', '.join(ring_names)}), got {short_repr(targets)}")
            ring_names = targets
        self.target_names = ring_names
        scenario = procedure.scenario_for("one", _overrides(overrides, world), self.anatomy)
        teleop.command_period(scenario, self.period)
        self.scenario = scenario
        self.station = cd = MakeStation(scenario, heart=self.anatomy.atrium(), add_systems=self._add_sensor)
        self._build_handles(cd)
        self.runner = StationRunner(cd, monitor=ChainMonitor(cd, tolerate_sinking=lambda p: near_ostium_rim(cd.heart, p)),
                                    restartable=True)
        self._fix_inputs()
        self._cache_contexts()
        self._define_spaces()
        self._k = 0
        self._steps = 0
        self._t0 = 0.0

    # -- construction ------------------------------------------------------------------------
    def _add_sensor(self, builder, ports):
        cp = ports.chain
        sensor = builder.AddSystem(LocalisationSensor(cp.config.chain.n_balls, self.scenario.localisation.params(), 0))
        builder.Connect(cp.get_ball_positions_output_port(), sensor.get_ball_positions_input_port())
        self._ports = ports
        return {"localisation": sensor}

    def _build_handles(self, cd) -> None:
        names, p_WT, n_W, radius = self._ports.targets
        index = {n: i for i, n in enumerate(names)}
        missing = [n for n in self.target_names if n not in index]
        if missing:
            raise UserInputError(f"NavigationEnv: the atrium has no targets {missing}")
        sel = [index[n] for n in self.target_names]
        self.p_WT, self.n_W, self.target_radius = np.asarray(p_WT)[sel], np.asarray(n_W)[sel], float(radius)
        self.ball_radius = float(cd.chain.tip_radius)
        self.p_touch = self.p_WT + self.ball_radius * self.n_W  # the tip centre touching each target
        self.units = list(self._ports.joystick_inputs)
        self.unit_configs = [cd.units[u].config for u in self.units]
        self.omega_max = np.array([c.teleop_omega_max for c in self.unit_configs])
        self.dead_band = np.array([c.teleop_dead_band for c in self.unit_configs])
        self.v_max = FeederSpec().max_speed
        self.geometry = {"p_WE": np.asarray(cd.chain.p_WE, float), "sheath_axis_W": np.asarray(cd.chain.sheath_axis_W, float),
                         "p_WM": [np.asarray(c.p_WM, float) for c in self.unit_configs],
                         "ball_diameter": 2.0 * self.ball_radius,
                         "max_length": float(cd.chain.max_inserted_length())}
        self._sensor = cd.added["localisation"]
        self._feeder = cd.feeder
        self._magnets = [cd.units[u].magnet for u in self.units]
        self._estimators = [cd.units[u].estimator for u in self.units]
        self._estimator = self._force_estimator(cd) if self.force_estimate else None

    def _force_estimator(self, cd):
        from ballchain.drake_models.field_sources import rotation_with_z_along
        from ballchain.drake_models.params import BallChain
        from ballchain.systems.tip_force_estimator import TipForceEstimator

        heart = cd.heart
        R_WS = rotation_with_z_along(heart.sheath_axis_H)[:, [2, 0, 1]]
        magnets = [(c.magnet, np.asarray(c.p_WM, float)) for c in self.unit_configs]
        return TipForceEstimator(BallChain(), heart.p_HE, R_WS, magnets, self.unit_configs[0].model,
                                 cd.chain.config.chain.n_balls)

    def _fix_inputs(self) -> None:
        d, ctx = self.station.diagram, self.runner.context
        self._sticks = [d.GetInputPort(f"{u}.joystick").FixValue(ctx, np.zeros(3)) for u in self.units]
        self._feed = d.GetInputPort("feeder.v_insert_cmd").FixValue(ctx, np.zeros(1))

    def _define_spaces(self) -> None:
        k = len(self.units)
        high = np.concatenate([np.repeat(self.omega_max, 3), [self.v_max]]).astype(np.float32)
        self.action_space = spaces.Box(-high, high, dtype=np.float32)
        layout = [("tip_measured", 3)]
        for u in self.units:
            layout += [(f"{u}.m_hat_W", 3), (f"{u}.omega_WM_W", 3)]
        layout += [("inserted_length", 1), ("target_p_W", 3), ("target_n_W", 3)]
        if self.force_estimate:
            layout.append(("force_estimate", 1))
        if self.privileged:
            layout += [("tip_true", 3), ("tip_wall_force", 3)]
        self.obs_layout, start = {}, 0
        for name, size in layout:
            self.obs_layout[name] = slice(start, start + size)
            start += size
        bound = np.full(start, OBS_BOUND["position"], np.float32)  # generous physical bounds (never clipped)
        for name, part in self.obs_layout.items():
            kind = name.rsplit(".", 1)[-1]
            bound[part] = OBS_BOUND.get(kind, OBS_BOUND["position"])
        self.observation_space = spaces.Box(-bound, bound, (start,), dtype=np.float32)
        assert len(high) == 3 * k + 1

    # -- readings ----------------------------------------------------------------------------
    def _cache_contexts(self) -> None:
        """Each read system's context in the root context, found once: ``GetMyContextFromRoot``
        validates the whole context tree (about 0.8 ms each time on this diagram); the subsystem
        contexts stay the same objects across ``StationRunner.restart``."""
        root, chain = self.runner.context, self.station.chain
        systems = [self._sensor, self._feeder, *self._magnets, *self._estimators, chain.system]
        self._contexts = {id(s): s.GetMyContextFromRoot(root) for s in systems}
        force_port = chain.get_tip_wall_force_output_port()
        self._force = (force_port, force_port.get_system().GetMyContextFromRoot(root))
        self._chain_context = self._contexts[id(chain.system)]

    def _read(self, system, port: str) -> np.ndarray:
        return np.asarray(system.GetOutputPort(port).Eval(self._contexts[id(system)]), float)

    def tip_true(self) -> np.ndarray:
        """The true tip ball centre (3,) [m] (a copy; ``Station.tip_position``)."""
        return np.array(self.station.chain.body_positions(self._chain_context)[-1], float)

    def tip_wall_force(self) -> np.ndarray:
        """The walls' force on the tip ball (3,) [N] (``Station.tip_wall_force``)."""
        port, context = self._force
        return np.array(port.Eval(context)[:3], float)

    def _observe(self) -> np.ndarray:
        parts = [self._read(self._sensor, "p_WT_measured")]
        for magnet, estimator in zip(self._magnets, self._estimators):
            parts += [self._read(estimator, "m_hat_W"), self._read(magnet, "omega_WM_W")]
        length = self._read(self._feeder, "inserted_length")
        parts += [length, self.p_WT[self._k], self.n_W[self._k]]
        if self._estimator is not None:
            dipoles = np.array([self._read(m, "m_W") for m in self._magnets])
            reaction = self._estimator.reaction_W(parts[0], dipoles, float(length[0]))
            parts.append([0.0 if reaction is None else float(reaction @ self.n_W[self._k])])
        if self.privileged:
            parts += [self.tip_true(), self.tip_wall_force()]
        return np.concatenate(parts).astype(np.float32)

    def _distance(self) -> float:
        return float(np.linalg.norm(self.tip_true() - self.p_touch[self._k]))

    # -- the Gymnasium API -------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Restart the cached station (its initial state) with fresh Drake randomness drawn from
        the environment's generator; reach: draw the episode's target (``options["target"]``: a
        name of ``target_names`` instead)."""
        super().reset(seed=seed)
        options = options or {}
        self.runner.restart()
        drake_seed = int(self.np_random.integers(0, MAX_SEED + 1))
        set_random_context(self.station.diagram, self.runner.context, RandomGenerator(drake_seed))
        if self.task == "reach":
            self._k = int(self.np_random.integers(len(self.target_names)))
            if "target" in options:
                if options["target"] not in self.target_names:
                    raise UserInputError(f"reset options target must be one of {self.target_names}, "
                                         f"got {short_repr(options['target'])}")
                self._k = self.target_names.index(options["target"])
        else:
            self._k = 0
        for stick in self._sticks:
            stick.GetMutableData().get_mutable_value().SetFromVector(np.zeros(3))
        self._feed.GetMutableData().get_mutable_value().SetFromVector(np.zeros(1))
        self._steps = 0
        # One control period at rest: the sensor's first sample, the units' estimates and the
        # engine's first equilibrium exist before the first observation.
        failure = self.runner.advance_to(self.period)
        if failure is not None:  # the scenario's own start fails: not the agent's doing
            raise RuntimeError(f"NavigationEnv reset: the station failed at rest: {failure}")
        self._t0 = self.period
        self._dist = self._distance()
        return self._observe(), self._info(False, False, None, 0.0, 0.0)

    def sticks(self, action: np.ndarray) -> list[np.ndarray]:
        """The stick axes that make each unit's mapper command ``action``'s rates (past its dead band)."""
        out = []
        for j, (w, db) in enumerate(zip(self.omega_max, self.dead_band)):
            u = np.clip(np.asarray(action[3 * j:3 * j + 3], float) / w, -1.0, 1.0)
            out.append(np.where(np.abs(u) > 1e-9, np.sign(u) * (db + (1.0 - db) * np.abs(u)), 0.0))
        return out

    def step(self, action):
        a = np.clip(np.asarray(action, float).reshape(-1), self.action_space.low, self.action_space.high)
        if a.shape != self.action_space.shape or not np.all(np.isfinite(a)):
            raise UserInputError(f"NavigationEnv action must be finite, of shape {self.action_space.shape}, "
                                 f"got {short_repr(action)}")
        for stick, axes in zip(self._sticks, self.sticks(a)):
            stick.GetMutableData().get_mutable_value().SetFromVector(axes)
        self._feed.GetMutableData().get_mutable_value().SetFromVector(a[-1:])
        self._steps += 1
        failure = self.runner.advance_to(self._t0 + self._steps * self.period)
        f_W = self.tip_wall_force() if failure is None else np.zeros(3)
        f_normal, f_tip = gram_force(float(f_W @ self.n_W[self._k])), gram_force(float(np.linalg.norm(f_W)))
        reward = -PENALTY_TIME - PENALTY_FORCE * max(0.0, f_tip - FORCE_LIMIT_GF)
        success = touched = False
        if failure is not None:
            reward -= PENALTY_STOP
        else:
            dist = self._distance()
            reward += REWARD_PROGRESS * 1e3 * (self._dist - dist)
            self._dist = dist
            tip = self.tip_true()
            touched = bool(targets_touched(tip, self.p_WT[self._k:self._k + 1], self.n_W[self._k:self._k + 1],
                                           self.ball_radius, self.target_radius)[0])
            if touched and FORCE_WINDOW_GF[0] <= f_normal <= FORCE_WINDOW_GF[1]:
                reward += REWARD_SUCCESS
                if self.task == "ring" and self._k + 1 < len(self.target_names):
                    self._k += 1
                    self._dist = self._distance()
                else:
                    success = True
        n_limit = len(self.target_names) if self.task == "ring" else 1
        truncated = not success and failure is None and self._steps * self.period >= self.time_limit * n_limit - 1e-9
        obs = self._observe() if failure is None else self._last_obs_after_failure()
        return obs, float(reward), bool(success or failure is not None), bool(truncated), \
            self._info(touched, success, failure, f_normal, f_tip)

    def _last_obs_after_failure(self) -> np.ndarray:
        try:
            obs = self._observe()
        except RuntimeError:  # the stopped engine's outputs: nothing to read
            obs = np.zeros(self.observation_space.shape, np.float32)
        return np.nan_to_num(obs, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32)

    def _info(self, touched, success, failure, f_normal, f_tip) -> dict:
        return {"target": self.target_names[self._k], "distance_mm": 1e3 * self._dist, "touched": touched,
                "force_normal_gf": f_normal, "tip_force_gf": f_tip, "success": success, "failure": failure,
                "targets_done": self._k + int(success) if self.task == "ring" else int(success),
                "time_s": self._steps * self.period}
