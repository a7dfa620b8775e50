"""A named scenario simulated (``ballchain simulate``): the chain in the left atrium or free space.

Loads the scenario of ``drake_models/station.scenarios.yaml``, applies the ``--set`` overrides,
the mode and the engine, runs ``systems/chain_simulation.run_simulation`` and adds, for the
scenarios that settle on the canonical statics problem, how far the simulated tip is from the
statics equilibrium (two independent computations of the same shape).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ballchain.infrastructure.arg_checks import require_type
from ballchain.infrastructure.errors import UserInputError, short_repr
from ballchain.infrastructure.safe_files import check_output_file, to_jsonable
from ballchain.experiments._result import Result, optional
from ballchain.optimization.statics import uniform_field_equilibrium

if TYPE_CHECKING:  # the systems layer (pydrake) loads with the run, not with the command line
    from ballchain.systems.chain_simulation import SimulationMetrics


@dataclass
class SimulationResult(Result):
    """What ``run`` returns.

    Attributes:
        metrics: the run's ``chain_simulation.SimulationMetrics`` (real-time factor, the
            watchdog's tip position, clearances and overlaps, times, steps, targets touched, the
            tip's wall force, peak memory, the engine's statics stats, html), without the ball
            positions (``metrics.p_W_mm`` is None: they are ``p_W_mm``).
        p_W_mm: the ball centres at the end [mm], shape (n, 3).
        statics_tip_error_mm: distance from the simulated tip to the statics equilibrium [mm]
            (None for scenarios that do not settle on the canonical statics problem).
        anatomy: the anatomy file's name, side, targets and magnets (``Anatomy.describe``; only
            with ``anatomy``).
    """

    metrics: SimulationMetrics
    p_W_mm: list
    statics_tip_error_mm: float | None
    anatomy: dict | None = optional()

    def public(self) -> dict:
        """What the command prints: the metrics and ``statics_tip_error_mm`` in one flat,
        JSON-ready dict (no ball positions)."""
        out = {**to_jsonable(self.metrics), "statics_tip_error_mm": to_jsonable(self.statics_tip_error_mm)}
        return out if self.anatomy is None else {**out, "anatomy": to_jsonable(self.anatomy)}


def run(*, scenario: str, duration: float | None = None, mode: str | None = None, engine: str | None = None,
        overrides: str | None = None, html: Path | None = None, progress: bool = False,
        anatomy: Path | str | None = None) -> SimulationResult:
    """Load the scenario, apply the overrides, the mode and the engine, simulate; returns the metrics.

    Args:
        scenario: a name in ``drake_models/station.scenarios.yaml``.
        duration: simulated time [s] (None: the scenario's).
        mode: "quasi-static" or "dynamics" (None: the scenario's).
        engine: "plant" or "statics", the scenario's ``engine`` field (None: the scenario's).
        overrides: inline YAML overriding scenario fields; a ``mode`` or ``engine`` in it must
            agree with ``mode`` and ``engine`` when those are given.
        html: write a Meshcat recording (HTML) to this file.
        progress: a progress bar on stderr.
        anatomy: an anatomy file (``drake_models.anatomy``): the scenario runs on it, its units
            standing at the file's magnets (``station.apply_anatomy``).

    Returns:
        A ``SimulationResult``: the metrics of ``chain_simulation.run_simulation``, the ball
        positions and ``statics_tip_error_mm``.

    Raises:
        UserInputError: a bad scenario, override, mode, engine, duration or output path (before
            any work).
        SimulationFailure: the run stopped (NaN, escape, chain broken apart); it carries the metrics.
    """
    require_type(scenario, str, "scenario", "a scenario name (str)")
    from ballchain.systems.chain_scenario import apply_overrides, check_steps, load_scenario, parse_overrides
    from ballchain.systems.chain_simulation import replay_bytes, run_simulation

    if html is not None:  # before the run: an unwritable path must not cost the results
        check_output_file(html, "--html")
    changes = _with_flags(parse_overrides(overrides), mode=mode, engine=engine)
    chosen = load_scenario(scenario)
    if changes:
        chosen = apply_overrides(chosen, changes).validate()
    heart = None
    if anatomy is not None:
        from ballchain.drake_models.anatomy import load_anatomy
        from ballchain.systems.station import apply_anatomy

        anatomy = load_anatomy(anatomy)
        apply_anatomy(chosen, anatomy)
        heart = anatomy.atrium()
    if duration is not None:
        check_steps(chosen, duration, "--duration")
    if html is not None:  # room on the disk for the replay of this scenario and duration
        check_output_file(html, "--html", expected_bytes=replay_bytes(chosen, chosen.duration if duration is None
                                                                       else duration))
    metrics = run_simulation(scenario=chosen, duration=duration, html=html, progress=progress, heart=heart)
    p_W_mm = metrics.p_W_mm
    return SimulationResult(metrics=replace(metrics, p_W_mm=None), p_W_mm=p_W_mm,
                            statics_tip_error_mm=statics_tip_error_mm(chosen, p_W_mm),
                            anatomy=None if anatomy is None else anatomy.describe())


def _with_flags(changes: dict, **flags) -> dict:
    """The ``--set`` mapping with the ``--mode`` and ``--engine`` flags (the scenario fields of the
    same names) added; a flag and a ``--set`` entry that disagree are refused."""
    from ballchain.systems.chain_scenario import ENGINES, MODES

    allowed = {"mode": MODES, "engine": ENGINES}
    for name, value in flags.items():
        if value is None:
            continue
        if value not in allowed[name]:
            raise UserInputError(f"--{name} must be one of {', '.join(allowed[name])}, got {short_repr(value)}")
        if name in changes and changes[name] != value:
            raise UserInputError(f"--{name} {value} disagrees with --set {name}: {short_repr(changes[name])}; "
                                 "give only one of them")
        changes = {**changes, name: value}
    return changes


def statics_tip_error_mm(scenario, p_W_mm) -> float | None:
    """Distance [mm] from the simulated tip to the statics equilibrium, for scenarios that settle
    on the canonical problem (free space, no sheath, ball 1 fixed at the origin, a uniform field,
    optionally a flat wall); None for the others (heart, magnets, units, moving feeder).
    ``p_W_mm``: the simulated ball centres [mm], (n, 3)."""
    canonical = (not scenario.heart and not scenario.sheath and not scenario.magnets and not scenario.units
                 and scenario.insertion.initial == 0.0 and scenario.insertion.final == 0.0)
    if not canonical:
        return None
    from ballchain.systems.station import chain_for

    chain = chain_for(scenario)
    wall = None
    if scenario.wall_plane:
        wall = (np.array(scenario.wall_plane[:3]), np.array(scenario.wall_plane[3:]))
    statics = uniform_field_equilibrium(chain, scenario.uniform_field, scenario.gravity, wall)
    return float(np.linalg.norm(np.array(p_W_mm[-1]) - statics.tip_position * 1e3))
