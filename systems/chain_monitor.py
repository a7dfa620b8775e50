"""The station's watchdog: ``ChainMonitor``, the per-step checks and metrics of a run of any device
(through its ``DeviceModel``), where a sinking near a vein ostium's rim is tolerated
(``near_ostium_rim``), and the Simulator monitor of a run around it (``station_monitor``). ``chain_simulation`` (the run loop) installs it and re-exports it.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import EventStatus

from ballchain.drake_models.kernels._common import kernel
from ballchain.infrastructure.arg_checks import require_int
from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.systems.station import Station


RIM_BAND = 3e-3  # [m] how close to an ostium's rim the wall mesh is too soft to hold a ball


def near_ostium_rim(heart, p_W: np.ndarray) -> bool:
    """Whether a ball centre is near a vein ostium's rim, where the watchdog tolerates sinking.

    Near: within ``RIM_BAND`` of the rim radially, and along the vein axis within a vein radius
    of the ostium's centre. There the atrium's compliant wall mesh has
    next to no stiffness (the pressure field of the tetrahedral shell vanishes on the cut faces of
    the opening, and the vein tube's shell overlaps it): measured with a rigid ball pressed 0.3 to
    1.2 mm into the wall 0.5 to 1.5 mm from the LIPV rim, the wall pushes back with 0.03 to 0.09 N
    that does not grow with depth, against 0.05 to 0.69 N on the plain wall. A ball sinking past
    the wall's middle there is recorded instead of stopping the run (``ChainMonitor``'s ``tolerate_sinking``). An atrium without ostia (a
    user's) has no rim."""
    for o in heart.ostia:
        rel = np.asarray(p_W) - o.p_HO
        along = float(rel @ o.axis_H)
        rho = float(np.linalg.norm(rel - along * o.axis_H))
        if abs(along) < 0.5 * o.diameter and abs(rho - 0.5 * o.diameter) < RIM_BAND:
            return True
    return False


@kernel
def closest_pair_distance(p):
    """The smallest distance [m] between two of the points (n, 3), n >= 2: ``np.linalg.norm(p[i] -
    p[j], axis=1).min()`` over the pairs i < j, the same floats (each distance's squares summed
    left to right, as numpy's norm along a row), without the (n (n - 1) / 2, 3) temporaries."""
    best = np.inf
    n = p.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            dx, dy, dz = p[i, 0] - p[j, 0], p[i, 1] - p[j, 1], p[i, 2] - p[j, 2]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            if d < best or d != d:  # a NaN is the minimum, as numpy's min
                best = d
                if d != d:
                    return d
    return best


_SUCCEEDED = EventStatus.Succeeded()  # the watchdog's answer between its checks (returned by value)
_FAILED = EventStatus.Severity.kFailed


class ChainMonitor:
    """Per-step watchdog and metrics of a Station (install with ``simulator.set_monitor``).

    It reads any device through its model (``DeviceModel``: ``body_positions``, ``body_radius``,
    ``neighbour_gaps``, ``in_sheath``, ``is_finite``, ``failure``).

    Every ``scenario.check_period`` it checks the state for NaN, a chain of touching bodies (the
    ball chain: ``neighbour_gaps``) for breaks and overlaps (cheap; between those checks, the state for NaN at every step, unless the chain
    moves only at its updates and reports a non-finite one as its ``failure``: the engine);
    every ``wall_check_every``-th of those checks it also checks escapes from the heart and the
    wall clearance (mesh queries, about 2 ms for 16 balls: checked every
    period they cost about 0.4 ms a step). The simulated trajectory does not depend on either;
    the clearance and penetration metrics are samples at the coarser period (plus one at the
    end, in ``metrics``).

    Args:
        cd: the diagram.
        tolerate_sinking: None, or ``tolerate_sinking(p_W (3,)) -> bool``: where a ball sinking
            past the middle of the wall is recorded (``tolerated_sinkings``: [(t, ball, depth [m])],
            at most one entry per ball per 0.1 s) instead of stopping the run (e.g. at the ostium
            rims, where the compliant wall mesh has next to no stiffness). Escapes stay fatal.
        wall_check_every: check escapes and clearance every this many periodic checks (>= 1;
            1 checks them every ``check_period``).
    """

    def __init__(self, cd: Station, tolerate_sinking=None, wall_check_every: int = 4):
        if not (hasattr(cd, "chain") and hasattr(cd, "scenario")):  # what it reads of a Station
            raise UserInputError(f"ChainMonitor cd must be a Station (MakeStation(scenario)), got {type(cd).__name__}")
        require_int(wall_check_every, "ChainMonitor wall_check_every", 1)
        if tolerate_sinking is not None and not callable(tolerate_sinking):
            raise UserInputError(f"ChainMonitor tolerate_sinking must be a function of a point or None, "
                                 f"got {short_repr(tolerate_sinking)}")
        self._cd = cd
        self._chain = cd.chain
        self._system = cd.chain.system  # the system whose context holds the chain
        self._d = 2.0 * cd.chain.body_radius
        # A chain that moves only at its updates (the engine's) shows nothing new in between.
        self._period = max(cd.scenario.check_period, cd.chain.move_period)
        self._quiet_between = cd.chain.move_period > 0
        self._next_check = 0.0
        self._wall_every = int(wall_check_every)
        self._since_wall = self._wall_every - 1  # the first periodic check includes the wall
        self._last_wall_time = -np.inf
        self.failure: str | None = None
        self.min_clearance = np.inf
        self.max_gap = -np.inf
        self.max_penetration = 0.0
        self.max_ball_overlap = 0.0
        self.max_wall_penetration = 0.0
        self.checks = 0
        self._iu = np.triu_indices(len(cd.chain.body_indices), k=1)
        self._tolerate_sinking = tolerate_sinking
        self.tolerated_sinkings: list[tuple[float, int, float]] = []

    def __getstate__(self) -> dict:
        """Its numbers (the metrics, the failure, the tolerated sinkings) without the station it
        watches, which cannot be pickled: an unpickled monitor is a record, it checks nothing."""
        return {**self.__dict__, "_cd": None, "_chain": None, "_system": None, "_tolerate_sinking": None}

    def restart(self) -> None:
        """Forget the failure and the check schedule: the run starts over from its initial state
        (``StationRunner.restart``); the metrics keep their extremes over every start."""
        self.failure = None
        self._next_check = 0.0
        self._since_wall = self._wall_every - 1
        self._last_wall_time = -np.inf

    def check(self, plant_context, wall: bool = True) -> str | None:
        """Check a state now; returns a failure message or None, and updates the metrics.

        Args:
            plant_context: the chain system's context (``Station.chain.system``'s).
            wall: also check escapes from the heart and the wall clearance.
        """
        t = plant_context.get_time()
        chain = self._chain
        if not chain.is_finite(plant_context):
            return f"NaN or inf in the state at t = {t:.4f} s: {chain.non_finite_part(plant_context)}"
        if chain.failure:
            return chain.failure
        p = chain.body_positions(plant_context)
        self.checks += 1
        gaps = chain.neighbour_gaps(p)
        if gaps is not None:
            self.max_gap = max(self.max_gap, float(gaps.max()))
            closest = closest_pair_distance(np.ascontiguousarray(p, dtype=float)) if len(p) > 1 else (
                np.linalg.norm(p[self._iu[0]] - p[self._iu[1]], axis=1).min())  # (an empty min's error)
            self.max_ball_overlap = max(self.max_ball_overlap, float(self._d - closest))
            self.max_penetration = max(self.max_penetration, self.max_ball_overlap)
        heart = self._cd.heart
        if heart is not None and not wall:
            return self._check_gaps(gaps, t)
        if heart is not None:
            self._last_wall_time = t
            p_S, p_H = p, p  # the balls seen from the sheath and from the wall (the rest poses)
            offsets = chain.anatomy_offsets(plant_context)
            if offsets is not None:  # a moving wall (wall_motion): where the state's solve put them
                p_S, p_H = p - offsets[0], p - offsets[1]
            in_sheath = chain.in_sheath(p_S)
            outside = ~heart.contains(p_H) & ~in_sheath
            if np.any(outside):
                i = int(np.argmax(outside))
                where = ("entered the solid (or left the working box)" if getattr(heart, "side", "lumen") == "solid"
                         else "escaped the heart")
                return f"ball {i + 1} {where} at t = {t:.4f} s: centre at {np.round(p[i] * 1e3, 2).tolist()} mm"
            free = ~in_sheath
            if np.any(free):
                clearance = heart.wall_distance(p_H[free]) - 0.5 * self._d
                self.min_clearance = min(self.min_clearance, float(clearance.min()))
                self.max_wall_penetration = max(self.max_wall_penetration, float(-clearance.min()))
                self.max_penetration = max(self.max_penetration, self.max_wall_penetration)
                half_wall = 0.5 * heart.params.wall_thickness
                if -clearance.min() > half_wall:
                    i = int(np.flatnonzero(free)[np.argmin(clearance)])
                    if self._tolerate_sinking is not None and self._tolerate_sinking(p_H[i]):
                        last = [e for e in self.tolerated_sinkings if e[1] == i + 1]
                        if not last or t - last[-1][0] >= 0.1:
                            self.tolerated_sinkings.append((t, i + 1, float(-clearance.min())))
                        return self._check_gaps(gaps, t)
                    return (f"ball {i + 1} sank {-clearance.min() * 1e3:.2f} mm into the wall at "
                            f"t = {t:.4f} s, past its middle ({half_wall * 1e3:.2f} mm), where the "
                            "compliant wall would push it out: raise contact.wall_hydroelastic_modulus")
        elif np.any(np.linalg.norm(p, axis=1) > 10 * chain.length + 0.1):
            i = int(np.argmax(np.linalg.norm(p, axis=1)))
            return f"ball {i + 1} flew away at t = {t:.4f} s: centre at {np.round(p[i] * 1e3, 1).tolist()} mm"
        return self._check_gaps(gaps, t)

    def _check_gaps(self, gaps: np.ndarray | None, t: float) -> str | None:
        if gaps is not None and gaps.max() > self._cd.scenario.break_gap:
            i = int(np.argmax(gaps))
            return (f"the chain broke between balls {i + 1} and {i + 2} at t = {t:.4f} s "
                    f"(gap {gaps[i] * 1e3:.2f} mm > {self._cd.scenario.break_gap * 1e3:.2f} mm)")
        return None

    def __call__(self, root_context):
        t = root_context.get_time()
        if t + 1e-12 < self._next_check and not self._chain.failure:
            # A chain that moves only at its updates (the engine) reports a non-finite update as
            # its failure (above): between the checks its state holds nothing new to look at.
            if self._quiet_between or self._chain.is_finite(self._system.GetMyContextFromRoot(root_context)):
                return _SUCCEEDED
        plant_context = self._system.GetMyContextFromRoot(root_context)
        self._next_check = t + self._period
        self._since_wall += 1
        wall = self._since_wall >= self._wall_every
        if wall:
            self._since_wall = 0
        self.failure = self.check(plant_context, wall=wall)
        if self.failure:
            return EventStatus.Failed(self._cd.diagram, self.failure)
        return EventStatus.Succeeded()

    def metrics(self, plant_context) -> dict:
        """The watchdog's part of ``SimulationMetrics`` (tip_position_mm .. monitor_checks, by
        field name) at the end of a run; the wall clearance is checked once more here."""
        p = self._chain.body_positions(plant_context)
        if (self._cd.heart is not None and plant_context.get_time() > self._last_wall_time
                and np.all(np.isfinite(p)) and self.failure is None):
            # The clearance at the end of the run too (the wall check runs at a coarser period).
            checks = self.checks
            self.check(plant_context, wall=True)
            self.checks = checks
        return {
            "tip_position_mm": (p[-1] * 1e3).round(3).tolist() if np.all(np.isfinite(p)) else None,
            "min_wall_clearance_mm": None if not np.isfinite(self.min_clearance) else round(self.min_clearance * 1e3, 4),
            "max_neighbor_gap_um": round(self.max_gap * 1e6, 3) if np.isfinite(self.max_gap) else None,
            "max_penetration_um": round(self.max_penetration * 1e6, 3),
            "max_ball_overlap_um": round(self.max_ball_overlap * 1e6, 3),
            "max_wall_penetration_um": round(self.max_wall_penetration * 1e6, 3),
            "monitor_checks": self.checks,
        }


def station_monitor(cd: Station, monitor: ChainMonitor, stop=None, on_time=None, check=None):
    """The Simulator monitor of a station run: ``check``, the watchdog, then ``on_time``, then ``stop``.

    Args:
        cd: the diagram.
        monitor: the watchdog (its failure ends the run).
        stop: None, or ``stop(root_context) -> bool``: a termination when True.
        on_time: None, or ``on_time(t)`` called with the simulated time [s] (a progress bar).
        check: None, or ``check(root_context) -> str | None``: the run's own failure test (e.g.
            the force pin's), called first; a message ends the run as a failure.

    Returns:
        ``monitor(root_context) -> EventStatus`` for ``Simulator.set_monitor``.
    """

    if check is None and on_time is None and stop is None:
        return monitor

    def watch(root_context):
        if check is not None:
            message = check(root_context)
            if message:
                return EventStatus.Failed(cd.diagram, message)
        status = monitor(root_context)
        if status is not _SUCCEEDED and status.severity() == _FAILED:
            return status
        if on_time is not None:
            on_time(root_context.get_time())
        if stop is not None and stop(root_context):
            return EventStatus.ReachedTermination(cd.diagram, "the stop condition")
        return status

    return watch
