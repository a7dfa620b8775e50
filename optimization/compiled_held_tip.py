"""The chain's statics with its tip held at a point, under point-dipole magnets, many times a
second: the navigator's force model (``systems.autonomous_navigator.TipForceEstimator``) on
the compiled Newton solve (``compiled_newton.newton``) the engine's equilibria use, called with
its arrays (issue 48).

``ChainStatics.solve`` takes any field source and answers any question: per call it checks its
arguments, builds and validates a ``FieldSources`` of ``MagnetSource``s (a rotation matrix per
magnet), samples the field at the warm start, reads the sources back into arrays and assembles
a whole ``StaticsResult``; for the navigator's look (20 a second) that Python cost more than
the solve. ``HeldTipStatics.reaction`` builds the kernels' model tuple from the dipoles
directly (the same numbers ``compiled_model.field_arrays`` reads from the sources) and returns
only what the force model needs. The answer is the same computation: the same kernel on the
same arrays, judged by the same ``answer_verdict``; anything else (no warm start, a ball inside
a magnet's bounding sphere, a singular step, a non-finite input) goes through
``ChainStatics.solve`` itself, so the two never differ (``tests/test_procedure_speed.py``).
"""

from __future__ import annotations

import time

import numpy as np

from ballchain.drake_models.chain_energy import EnergyTerms
from ballchain.drake_models.field_sources import FieldSources, MagnetSource, rotation_with_z_along
from ballchain.drake_models.kernels import chart_frames, configuration_vectors
from ballchain.optimization.blas_threads import one_blas_thread
from ballchain.optimization.compiled_model import field_arrays, reason_text
from ballchain.optimization.compiled_newton import R_LIMIT, R_MINIMUM, R_MINIMUM_LINE, newton
from ballchain.optimization.reduced_chain import answer_verdict
from ballchain.optimization.statics import ChainStatics, StaticsResult

_ZERO6, _ZERO3, _EYE3 = np.zeros(6), np.zeros(3), np.eye(3)
_NO_GRID, _NO_FRAME, _NO_SHEATH = np.zeros((0, 0, 0)), np.zeros(7), np.zeros(5)
_NO_ROWS, _NO_WEIGHTS = np.zeros(0, np.int64), np.zeros(0)
_GENERAL = ChainStatics.solve  # held_solve's fallback, whatever a caller later puts in its place


class HeldTip:
    """A held equilibrium's configuration and tip reaction (what the force model keeps).

    Attributes:
        positions, dipoles: (n, 3) the configuration (the next look's warm start).
        tip_reaction: (3,) the force [N] the hold exerts on the tip ball (statics frame).
        converged: a verified equilibrium (``ChainStatics.solve``'s verdict).
    """

    __slots__ = ("positions", "dipoles", "tip_reaction", "converged")

    def __init__(self, positions, dipoles, tip_reaction, converged: bool) -> None:
        self.positions, self.dipoles, self.tip_reaction, self.converged = positions, dipoles, tip_reaction, converged


class HeldTipStatics:
    """``ChainStatics(chain, max_iterations=...)`` with the tip held, under fixed point-dipole
    magnets whose directions change from call to call.

    Args:
        statics: the chain's ChainStatics (its settings are read at every call).
        magnets: [(magnet, p_S (3,))] the magnets (``params`` shapes) and centres [m] in the
            statics frame.
        model: the field model ("dipole" is compiled here; "exact" always takes ``statics.solve``).
    """

    def __init__(self, statics: ChainStatics, magnets: list, model: str) -> None:
        self.statics, self.model = statics, model
        self.magnets = [(mag, np.asarray(p, float)) for mag, p in magnets]
        self._r2 = np.ascontiguousarray([mag.bounding_radius**2 for mag, _ in self.magnets], float) \
            if all(hasattr(mag, "bounding_radius") for mag, _ in self.magnets) else None

    def sources(self, m_S: np.ndarray, centres) -> FieldSources:
        """The field ``ChainStatics.solve`` is given: each magnet at its centre, pointing along m_S's row."""
        return FieldSources([MagnetSource(mag, p, rotation_with_z_along(m), self.model)
                             for (mag, _), p, m in zip(self.magnets, centres, m_S)])

    def reaction(self, m_S: np.ndarray, target_S: np.ndarray, start: HeldTip | None,
                 shift_S: np.ndarray | None = None) -> HeldTip:
        """The equilibrium with the tip ball's centre at ``target_S`` (3,) from ``start`` (None:
        the straight chain), the magnets pointing along the rows of ``m_S`` (k, 3) and their
        centres moved by ``-shift_S`` (3,) (None: where they are)."""
        centres = [p if shift_S is None else p - shift_S for _, p in self.magnets]
        m_S = np.asarray(m_S, float)
        answer = None
        if start is not None and self.model == "dipole" and self._fast_ready(m_S, target_S):
            answer = self._compiled(m_S, centres, np.asarray(target_S, float), start)
        if answer is None:  # everything else: the general solve
            warm = None if start is None else _warm(start)
            r = self.statics.solve(self.sources(m_S, centres), warm, tip_target=target_S)
            answer = HeldTip(r.positions, r.dipoles, r.tip_reaction, r.converged)
        return answer

    def _fast_ready(self, m_S, target_S) -> bool:
        s = self.statics
        return (self._r2 is not None and s.compiled and s.method == "newton" and s.qp == "dense"
                and s._model is not None and s._model.backend == "kernel" and not s.gravity
                and np.all(np.isfinite(m_S)) and np.all(np.isfinite(target_S)))

    def _compiled(self, m_S, centres, target, start: HeldTip) -> HeldTip | None:
        s, model = self.statics, self.statics._model
        moments = np.empty((len(centres), 3))
        for j, ((mag, _), m) in enumerate(zip(self.magnets, m_S)):
            norm = np.linalg.norm(m)
            if not norm > 0.0:
                return None
            moments[j] = mag.dipole_moment * (m / norm)  # MagnetSource.m_W of rotation_with_z_along(m)
        settings = np.array([s.tolerance, s.feasibility_tolerance, s.contact_margin, s.max_step, 0.0, 0.5 * model.d])
        flags = np.array([s.max_iterations, 1, 1, 0, 0], dtype=np.int64)  # a field, pinned, no wall, no heart
        tup = (model._params, np.ascontiguousarray(centres, float), moments, np.zeros(3), self._r2, target, _ZERO6,
               _ZERO3, _EYE3, _NO_GRID, _NO_FRAME, _NO_SHEATH, settings, flags)
        p0, m0 = np.ascontiguousarray(start.positions, float), np.ascontiguousarray(start.dipoles, float)
        chart = chart_frames(configuration_vectors(p0, m0))
        try:
            with one_blas_thread():
                reason, _, _, _, _, lam_tip, p, m_hat, terms, gaps, _ = newton(chart, tup, _NO_ROWS, _NO_WEIGHTS)
        except np.linalg.LinAlgError:
            return None  # ChainStatics.solve reports it (not an equilibrium)
        if reason > R_LIMIT:  # R_FIELD, R_ENERGY: ChainStatics.solve decides
            return None
        converged = reason in (R_MINIMUM, R_MINIMUM_LINE)
        converged, _, _ = answer_verdict(model, p, m_hat, EnergyTerms(*terms.tolist()).total, gaps, converged, "")
        return HeldTip(p, m_hat, model.energy_scale / model.d * np.asarray(lam_tip, dtype=float), converged)


def _warm(start: HeldTip) -> StaticsResult:
    """A warm start for ``ChainStatics.solve`` (which reads its configuration only)."""
    return StaticsResult(start.positions, start.dipoles, float("nan"), EnergyTerms(0.0, 0.0, 0.0, 0.0), True, "",
                         "newton", 0, 0.0)


def held_solve(statics: ChainStatics, external, warm_start: StaticsResult, tip_target) -> StaticsResult:
    """``statics.solve(external, warm_start, tip_target=tip_target)``, the same ``StaticsResult``
    (its ``solve_time`` aside), without the general solve's per-call Python when ``external`` is
    made of point dipoles and uniform fields (``compiled_model.field_arrays``) and the solver has
    solved once (its model built): the kernels' model tuple built here, the answer assembled by
    ``statics._assemble`` as ``solve`` does. Anything else goes through ``statics.solve``.

    For the planner's held-tip solves (``inverse_statics.HeldTip``, ``pin_tip``): about 0.35 ms
    of Python per solve there (``docs/performance.md``, section 23); not wired into them yet.
    """
    model = statics._model
    field = None
    if (warm_start is not None and tip_target is not None and statics.compiled and statics.method == "newton"
            and statics.qp == "dense" and model is not None and model.backend == "kernel"
            and warm_start.positions.shape == (statics.chain.n_balls, 3)):
        field = field_arrays(external) if external is not None else None
    target = None if field is None else np.asarray(tip_target, dtype=float).reshape(3)
    if field is None or not (all(np.isfinite(a).all() for a in field[:3]) and np.isfinite(target).all()):
        return _GENERAL(statics, external, warm_start, tip_target=tip_target)
    start = time.perf_counter()
    centres, moments, B0, r2 = (np.ascontiguousarray(a, float) for a in field)
    settings = np.array([statics.tolerance, statics.feasibility_tolerance, statics.contact_margin, statics.max_step,
                         0.0, 0.5 * model.d])
    flags = np.array([statics.max_iterations, 1, 1, 0, 0], dtype=np.int64)  # a field, pinned, no wall, no heart
    tup = (model._params, centres, moments, B0, r2, target, _ZERO6, _ZERO3, _EYE3, _NO_GRID, _NO_FRAME, _NO_SHEATH,
           settings, flags)
    p0 = np.ascontiguousarray(warm_start.positions, float)
    chart = chart_frames(configuration_vectors(p0, np.ascontiguousarray(warm_start.dipoles, float)))
    try:
        with one_blas_thread():
            reason, _, iterations, rows, lam, lam_tip, p, m_hat, terms, gaps, v = newton(chart, tup, _NO_ROWS,
                                                                                         _NO_WEIGHTS)
    except np.linalg.LinAlgError:
        return _GENERAL(statics, external, warm_start, tip_target=tip_target)
    if reason > R_LIMIT:  # R_FIELD, R_ENERGY: the general solve decides (and says why)
        return _GENERAL(statics, external, warm_start, tip_target=tip_target)
    lam_near = dict(zip(rows.tolist(), lam.tolist()))
    return statics._assemble(model, p, m_hat, EnergyTerms(*terms.tolist()), gaps, reason in (R_MINIMUM, R_MINIMUM_LINE),
                             reason_text(statics, reason), int(iterations), lam_near, lam_tip, None, start, v)
