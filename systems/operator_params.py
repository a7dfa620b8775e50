"""The simulated operator's parameters (``OperatorParams``) and its record of one target
(``TargetRecord``). ``simulated_operator`` re-exports them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ballchain.infrastructure.errors import UserInputError, require_finite_fields
from ballchain.systems.unit_config import MagnetUnitConfig

# The re-learning wiggles on one target at which its record calls a miss "confused"
# (``TargetRecord.reason``); also the failed attempts (re-learns and bursts) after which the manual
# arm's hand re-approaches the target with its plan's curve (``manual_hand.ManualHand``, issue 45, H14).
CONFUSED_RELEARNS = 3


@dataclass
class OperatorParams:
    """The simulated operator's settings (SI).

    Attributes:
        period: how often it looks and decides [s] (20 Hz).
        reaction_steps: a decision takes effect this many periods after the look (0.1 s).
        axes: the stick axes it uses (the mapping's meaningful ones).
        dead_band: the stick's dead band (felt, and compensated: it pushes the stick past it).
        feeder_speed: the feeder's speed at full command [m/s] (the stepper feeder's limit).
        gain: desired tip velocity per unit of error [1/s].
        max_speed: cap on the desired tip speed [m/s].
        press: it aims the ball's wall-side point this far inside the wall [m].
        hover: it first brings the ball's wall-side point this far above the target [m] ...
        descend_lateral: ... and presses down once the tip is within this of the target's
            centre laterally (along the wall) [m].
        contact_margin: the tip counts as at the wall (no feeding forward) when its centre is
            within a ball radius plus this of the target's wall plane [m].
        forgetting: recursive-least-squares forgetting factor per look.
        initial_covariance: of the estimate's rows [(mm/s)^-2 per unit deflection: trust in data].
        max_covariance: cap on the covariance's trace (against wind-up without excitation).
        damping: damped least squares: damping as a fraction of J's largest singular value.
        tremor: amplitude of the hand's random tremor on each stick axis (uniform).
        seed: of the tremor (the default of the operator's seed parameter), 0..2**32 - 1.
        probe_amplitude: stick deflection of the probing wiggle.
        probe_time: duration of each half of a wiggle [s].
        confusion_window: [s] averaging time of the prediction check.
        stall_window: [s] without ``stall_progress`` towards the target means no progress.
        stall_progress: [m].
        burst: duration of a feeding or retraction burst [s].
        burst_command: feeder command of a burst (fraction of full).
        jam_window, jam_feed, jam_ratio: jammed chain: in the last ``jam_window`` seconds or so it
            fed more than ``jam_feed`` [m] and the tip went forward less than ``jam_ratio`` of it.
        p_WE: (3,) the sheath exit [m] (seen in the camera), or None: no cap on the feeding.
        initial_length, max_length: chain fed out at the start, and all of it [m] (the feeder's
            readout: it keeps its own count from its commands).
        min_length: it never retracts below this length [m] (0: all the way).
        reach_factor: it feeds at most this times the sheath exit's distance to the target.
        keep_out: the vein openings it sees, by neighbouring pairs: ((c1, c2, r1, r2, a1, a2), ...)
            (centres (3,) and radii [m], outward axes (3,)).
        keep_out_margin: it steers away from the openings when the tip is this close to them [m].
        timeout: seconds on one target before giving up.
        learn_feeder: it learns the feeder's effect beyond its expected share along the tip (off:
            the prior alone).
        dwell: after touching a target it holds still this long (stick and feeder at rest: an
            RF application) before the next [s]; 0: it moves on at once (the teleoperation tasks).
        start_time: when it starts [s].
        ball_radius: the tip ball's radius [m] (for the touch test and the aim).
        target_radius: [m] (half the target's diameter).
        electrode_length: the electrode's length along the tip, dome included [m], for the touch
            test (``drake_models.electrode``: its whole surface; 0: the tip ball).
    """

    period: float = 0.05
    reaction_steps: int = 2
    axes: tuple = (0, 1, 2)
    dead_band: float = MagnetUnitConfig.teleop_dead_band
    feeder_speed: float = 0.02
    gain: float = 2.0
    max_speed: float = 0.015
    press: float = 1.0e-3
    hover: float = 4.0e-3
    descend_lateral: float = 2.0e-3
    contact_margin: float = 1.0e-3
    forgetting: float = 0.95
    initial_covariance: float = 10.0
    max_covariance: float = 1.0e3
    damping: float = 0.1
    tremor: float = 0.1
    seed: int = 0
    probe_amplitude: float = 0.6
    probe_time: float = 0.25
    confusion_window: float = 0.5
    stall_window: float = 1.5
    stall_progress: float = 0.5e-3
    burst: float = 0.5
    burst_command: float = 0.5
    jam_window: float = 0.5
    jam_feed: float = 2e-3
    jam_ratio: float = 0.3
    p_WE: tuple | None = None
    initial_length: float = 0.0
    min_length: float = 0.0
    max_length: float = np.inf
    reach_factor: float = 1.6
    keep_out: tuple = ()
    keep_out_margin: float = 2e-3
    timeout: float = 20.0
    learn_feeder: bool = True
    dwell: float = 0.0
    start_time: float = 0.0
    ball_radius: float = 0.5 * 3.175e-3
    target_radius: float = 2.5e-3
    electrode_length: float = 0.0

    def validate(self) -> "OperatorParams":
        require_finite_fields(self, allow_inf=("max_length",))  # inf: no end stop known
        if not self.period > 0 or self.reaction_steps < 0:
            raise UserInputError("OperatorParams: period must be > 0 and reaction_steps >= 0")
        if not self.axes or any(a not in (0, 1, 2) for a in self.axes) or len(set(self.axes)) != len(self.axes):
            raise UserInputError(f"OperatorParams.axes must be distinct stick axes among 0, 1, 2, got {self.axes}")
        if not 0.0 <= self.dead_band < 1.0 or not 0.0 < self.forgetting <= 1.0:
            raise UserInputError("OperatorParams: dead_band in [0, 1) and forgetting in (0, 1]")
        if not self.timeout > 0 or not self.feeder_speed > 0 or not self.max_speed > 0:
            raise UserInputError("OperatorParams: timeout, feeder_speed and max_speed must be > 0")
        if self.dwell < 0:
            raise UserInputError(f"OperatorParams.dwell must be >= 0 s, got {self.dwell}")
        if not 0.0 <= self.min_length <= self.max_length:
            raise UserInputError(f"OperatorParams.min_length must be in [0, max_length] m, got {self.min_length}")
        return self


@dataclass
class TargetRecord:
    """One target's outcome: ``t_start`` when the operator turned to it, ``t_touch`` (None: missed)."""

    target: str
    t_start: float
    t_touch: float | None = None
    accuracy: float | None = None  # [m]
    t_end: float | None = None  # when it moved on (touched or gave up)
    relearns: int = 0  # probing wiggles after the first (confusion)
    bursts: int = 0  # feeding / retraction bursts (no progress, jams)
    looks: int = 0  # looks while pursuing it (after the probing wiggle)
    jammed_looks: int = 0  # ... with the chain jammed (fed, the tip did not go forward)
    capped_looks: int = 0  # ... with the target ahead but the feeder at its length cap
    closest: float = np.inf  # closest the ball's wall-side point came to the target's centre [m]

    def reason(self) -> str | None:
        """Why it was missed, from what the operator recorded (None: touched, or still open).

        "chain jammed": the chain jammed in more than a quarter of its looks; "out of reach": the
        target lay ahead but the feeder was at its length cap in more than half of them;
        "confused": ``CONFUSED_RELEARNS`` (three) or more re-learning wiggles; otherwise "timeout" (steering, sliding or
        pressing beside it until the timeout). The closest approach is in the row.
        """
        if self.t_touch is not None or self.t_end is None:
            return None
        looks = max(self.looks, 1)
        if self.jammed_looks > 0.25 * looks:
            return "chain jammed"
        if self.capped_looks > 0.5 * looks:
            return "out of reach"
        if self.relearns >= CONFUSED_RELEARNS:
            return "confused"
        return "timeout"

    def row(self, t_now: float | None = None) -> dict:
        touched = self.t_touch is not None
        end = self.t_end if self.t_end is not None else t_now
        return {"target": self.target, "touched": touched,
                "time_s": None if end is None else round(end - self.t_start, 3),
                "t_touch_s": None if not touched else round(self.t_touch, 3),
                "accuracy_mm": None if not touched else round(self.accuracy * 1e3, 3),
                "relearns": self.relearns, "bursts": self.bursts, "reason": self.reason(),
                "closest_mm": None if not np.isfinite(self.closest) else round(self.closest * 1e3, 3)}
