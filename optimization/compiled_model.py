"""The Python side of the compiled Newton solve (``compiled_newton``): the model's arrays for the
kernels, and the answer read back for ``statics.ChainStatics``.

Kept apart from the kernels' file: numba's cache of those kernels is stamped with their file, so
editing this glue does not recompile them.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from ballchain.drake_models.atrium_sdf import AtriumSDF
from ballchain.drake_models.chain_energy import EnergyTerms
from ballchain.drake_models.field_sources import FieldSources, MagnetSource, UniformField
from ballchain.drake_models.kernels import check_status
from ballchain.drake_models.params import GRAVITY
from ballchain.optimization.blas_threads import one_blas_thread
from ballchain.optimization.reduced_chain import answer_verdict
from ballchain.optimization.wall_constraints import RHO_SMOOTHING, ConstrainedChain, PointDipoles, row_force_W
from ballchain.optimization.compiled_newton import (F_EXTERNAL, R_FIELD, R_LIMIT, R_LINE, R_MINIMUM,
                                                    R_MINIMUM_LINE, R_QP, R_SADDLE, R_ENERGY, S_HEART_WEIGHT, newton)
from ballchain.drake_models.kernels import chart_frames, configuration_vectors

_EMPTY3 = np.zeros((0, 3))
_NO_GRID = np.zeros((0, 0, 0))
# Constant inputs of the kernels (which only read them): no model arrays built for what is absent.
_ZERO3, _ZERO6, _EYE3, _NO_FRAME, _NO_SHEATH = np.zeros(3), np.zeros(6), np.eye(3), np.zeros(7), np.zeros(5)
_NO_ROWS, _NO_WEIGHTS = np.zeros(0, np.int64), np.zeros(0)


def field_arrays(source):
    """``(centres (k, 3), moments (k, 3), B0 (3,), r2_min (k,))`` of a field source made of point
    dipoles and uniform fields (UniformField, MagnetSource with the "dipole" model, the heart's
    PointDipoles, sums of them), or None for any other source (the Python solver takes those).

    A magnet's r2_min is its bounding sphere's: a ball inside it stops the compiled solve and
    the Python solver, which refuses a ball inside the magnet itself, decides."""
    if isinstance(source, UniformField):
        return _EMPTY3, _EMPTY3, np.asarray(source.B_W, float).reshape(3), np.zeros(0)
    if isinstance(source, PointDipoles):
        return source.p, source.m, np.asarray(source.B0, float).reshape(3), np.zeros(len(source.p))
    if isinstance(source, MagnetSource) and source.model == "dipole" \
            and hasattr(source.magnet, "bounding_radius"):
        return (np.asarray(source.p_WM, float).reshape(1, 3), np.asarray(source.m_W, float).reshape(1, 3),
                np.zeros(3), np.array([source.magnet.bounding_radius**2]))
    if isinstance(source, FieldSources):
        parts = [field_arrays(s) for s in source.sources]
        if any(part is None for part in parts):
            return None
        if not parts:
            return _EMPTY3, _EMPTY3, np.zeros(3), np.zeros(0)
        return (np.vstack([p[0] for p in parts]), np.vstack([p[1] for p in parts]),
                np.sum([p[2] for p in parts], axis=0), np.concatenate([p[3] for p in parts]))
    return None


def model_tuple(statics, model, external, constraints, parts=None):
    """The kernels' model tuple for a ChainStatics' model (``ReducedChain`` with its tip target
    and wall set, or ``ConstrainedChain`` with its constraints), or None when the external field
    is not one the kernels evaluate (``field_arrays``). ``parts``: the model's ``model_parts``,
    when the caller has them."""
    if external is None:
        field = None
    else:
        field = field_arrays(external)
        if field is None:
            return None
    return with_field(model_parts(statics, model, constraints) if parts is None else parts, field)


def settings_key(statics) -> tuple:
    """The solver settings ``model_parts`` reads (a caller may change them between solves)."""
    return (statics.tolerance, statics.feasibility_tolerance, statics.contact_margin, statics.max_step,
            statics.max_iterations)


def with_field(parts, field):
    """The model tuple of ``model_parts`` with the external field's ``field_arrays`` (None: no field)."""
    params, tip, wall, p_WB, R_WB, grid, frame, sheath, settings, flags = parts
    if field is None:
        field = (_EMPTY3, _EMPTY3, np.zeros(3), np.zeros(0))
        if flags[F_EXTERNAL] != 0:
            flags = flags.copy()
            flags[F_EXTERNAL] = 0
    centres, moments, B0, r2 = (np.ascontiguousarray(a, float) for a in field)
    return (params, centres, moments, B0, r2, tip, wall, p_WB, R_WB, grid, frame, sheath, settings, flags)


def model_parts(statics, model, constraints):
    """Everything of the model tuple but the external field (``with_field`` adds it): the chain's
    parameters, tip target, wall, the heart's frame, SDF grid and sheath, the solver's settings
    and flags (the field's flag set)."""
    tip = _ZERO3 if model.tip_target is None else np.asarray(model.tip_target, float)
    wall = _ZERO6 if model.wall is None else np.concatenate(model.wall).astype(float)
    settings = np.array([statics.tolerance, statics.feasibility_tolerance, statics.contact_margin,
                         statics.max_step, 0.0, 0.5 * model.d])
    p_WB, R_WB, grid, frame, sheath = _ZERO3, _EYE3, _NO_GRID, _NO_FRAME, _NO_SHEATH
    if constraints is not None:
        p_WB = np.ascontiguousarray(constraints.p_WB, float)
        R_WB = np.ascontiguousarray(constraints.R_WB, float)
        if constraints.gravity:
            settings[S_HEART_WEIGHT] = model.chain.ball_mass * GRAVITY
        if constraints.sdf is not None:
            grid, frame = _sdf_arrays(constraints.sdf)
        if constraints.sheath is not None:
            sh = constraints.sheath
            a_E = float((sh.p_WE - p_WB) @ R_WB[:, 0])
            sheath = np.array([1.0, a_E, sh.bore_radius + sh.lip_radius, model.r + sh.lip_radius, RHO_SMOOTHING])
    flags = np.array([statics.max_iterations, 1, model.tip_target is not None, model.wall is not None,
                      constraints is not None], dtype=np.int64)
    return model._params, tip, wall, p_WB, R_WB, grid, frame, sheath, settings, flags


def _sdf_arrays(sdf):
    """(padded node values, (origin, spacing, shape)) of an AtriumSDF (or any object with the
    same grid); a plane or other SDF is not compiled (raises TypeError: the caller checks)."""
    cached = getattr(sdf, "_compiled_arrays", None)
    if cached is None:
        frame = np.concatenate([np.asarray(sdf.origin, float), [float(sdf.spacing)],
                                np.asarray(sdf._shape, float)])
        cached = (np.ascontiguousarray(sdf._padded, float), frame)
        sdf._compiled_arrays = cached
    return cached


def compilable_constraints(constraints) -> bool:
    """Whether the kernels evaluate this HeartConstraints' wall (an AtriumSDF grid, or none)."""
    return constraints is None or constraints.sdf is None or isinstance(constraints.sdf, AtriumSDF)


REASONS = {
    R_MINIMUM: "local minimum (KKT and second-order conditions)",
    R_MINIMUM_LINE: "local minimum (stationary within line-search precision)",
    R_QP: "QP step infeasible (rigidity or tip constraints)",
    R_SADDLE: "stuck at a saddle point",
    R_LINE: "line search failed (no descent)",
}


def reason_text(statics, reason: int) -> str:
    """``StaticsResult.reason`` of the kernel's reason code."""
    return f"iteration limit ({statics.max_iterations}) reached" if reason == R_LIMIT else REASONS[reason]


def run(statics, model, external, p0, m0, lam0, constraints, chart0=None):
    """The compiled solve of a ChainStatics' model from (p0, m0): ``(converged, reason,
    iterations, lam_near dict, lam_tip, p, m_hat, terms (4,), gaps, v)``, or None when the
    Python solver must take it (a field or wall the kernels do not evaluate, a ball inside a
    magnet's bounding sphere). Raises ValueError, as the Python model, on two coincident balls
    or a folded sleeve.

    ``chart0``: a one-element list remembering the chart of (p0, m0) (the caller's cold start,
    the same arrays at every call): filled at the first call, copied at every call (the kernel
    re-centres its chart in place)."""
    if not compilable_constraints(constraints):
        return None
    parts = None
    if constraints is None and model.tip_target is None and model.wall is None:
        # The free chain's parts depend on the solver's settings only.
        key = settings_key(statics)
        cached = statics._free_parts
        if cached is None or cached[0] is not model or cached[1] != key:
            cached = statics._free_parts = (model, key, model_parts(statics, model, None))
        parts = cached[2]
    tup = model_tuple(statics, model, external, constraints, parts)
    if tup is None:
        return None
    rows0 = np.fromiter(lam0.keys(), np.int64, len(lam0)) if lam0 else _NO_ROWS
    weights0 = np.fromiter(lam0.values(), float, len(lam0)) if lam0 else _NO_WEIGHTS
    if chart0 is None or chart0[0] is None:
        chart = chart_frames(configuration_vectors(np.ascontiguousarray(p0, float), np.ascontiguousarray(m0, float)))
        if chart0 is not None:
            chart0[0] = tuple(a.copy() for a in chart)
    else:
        chart = tuple(a.copy() for a in chart0[0])
    try:
        with one_blas_thread():  # LAPACK's threads only slow these small systems (blas_threads)
            reason, status, iterations, rows, lam, lam_tip, p, m_hat, terms, gaps, v = newton(chart, tup, rows0,
                                                                                               weights0)
    except np.linalg.LinAlgError as err:  # a step's system singular in floating point
        return _singular(model, chart, err)
    if reason == R_FIELD:
        return None
    if reason == R_ENERGY:
        check_status(status, "ReducedChain.evaluate")
    text = reason_text(statics, reason)
    lam_near = dict(zip(rows.tolist(), lam.tolist()))
    return (reason in (R_MINIMUM, R_MINIMUM_LINE), text, int(iterations), lam_near, lam_tip, p, m_hat, terms,
            gaps, v)


def _singular(model, chart, err) -> tuple:
    """``run``'s answer when a Newton step's system was singular: not an equilibrium, reported
    like any other failure, at the chart's centre (the warm start, or where the chart was last
    re-centred), without multipliers (as the Python solver)."""
    model.r0, model.t1, model.t2 = chart
    model._last = None
    if hasattr(model, "_cache"):
        model._cache = None
    q = np.zeros(model.nq)
    ev = model.evaluate(q, 0)
    p, m_hat = model.configuration(q)
    v = np.zeros((0, 3))
    terms = np.array([ev.terms.balls, ev.terms.external, ev.terms.sleeve, ev.terms.gravity])
    return (False, f"Newton step: {err} (a singular Hessian or constraint system)", 0, {}, np.zeros(3), p, m_hat,
            terms, ev.gaps, v)


class HeartSolve:
    """``ChainStatics.solve(field, warm_start, constraints=c)`` of a sub-chain in the heart with
    the least Python around the compiled call: the quasi-static engine's inner loop.

    The kernel gets the very inputs ``ChainStatics.solve`` gives it (the field turned into the
    base frame by ``HeartConstraints.external_in_base``, the chart of the warm start, the last
    multipliers), so the equilibrium is the same, bit for bit; what is skipped is the work whose
    answer the engine does not read: the field evaluated at the balls for its finiteness (here
    the field's arrays are checked instead), the argument checks of a user's call, the model
    tuple rebuilt (its parts are kept per constraints), and the ``StaticsResult`` with its
    force dictionaries (``result`` builds it when asked).

    ``solve`` returns None wherever ``ChainStatics.solve`` must decide: a field the kernels do
    not evaluate, a non-finite field, a ball inside a port magnet's bounding sphere, a singular
    step, the kernel's field or energy failures; the caller then calls ``ChainStatics.solve``,
    which reports them as it always has.
    """

    def __init__(self, statics):
        self.statics = statics
        if statics._constrained is None:
            statics._constrained = ConstrainedChain(statics.chain)
        self.model = statics._constrained
        self._parts = None  # (constraints, settings, model_parts) of the last solve

    def usable(self) -> bool:
        """Whether the solver's settings are those of the compiled path."""
        s = self.statics
        return s.compiled and s.method == "newton" and s.qp == "dense" and self.model.backend == "kernel"

    def solve(self, field_W, constraints, p0_B, m0_B, lam0: dict | None):
        """The equilibrium from (p0_B, m0_B) (base frame, unit dipoles) in the world field
        ``field_W`` (None, a ``UniformField``, the engine's ``PortDipoles`` or a ``FieldSources``
        of those): a ``HeartAnswer``, or None (see the class)."""
        if not _plain_dipoles(field_W) or not compilable_constraints(constraints):
            return None
        start = time.perf_counter()  # the result's solve_time, as ChainStatics.solve's
        if field_W is not None and not _outside_bounding_spheres(field_W, constraints, p0_B):
            return None
        statics, model = self.statics, self.model
        external = constraints.external_in_base(field_W, statics.chain)
        field = None if external is None else field_arrays(external)
        if field is not None and not (np.isfinite(field[0]).all() and np.isfinite(field[1]).all()
                                      and np.isfinite(field[2]).all()):
            return None
        # The parts depend on the constraints and the solver's settings (a caller may change those).
        key = settings_key(statics)
        if self._parts is None or self._parts[0] is not constraints or self._parts[1] != key:
            self._parts = (constraints, key, model_parts(statics, model, constraints))
        tup = with_field(self._parts[2], field)
        rows0 = np.fromiter(lam0.keys(), np.int64, len(lam0)) if lam0 else _NO_ROWS
        weights0 = np.fromiter(lam0.values(), float, len(lam0)) if lam0 else _NO_WEIGHTS
        chart = chart_frames(configuration_vectors(np.ascontiguousarray(p0_B, float), np.ascontiguousarray(m0_B, float)))
        try:
            with one_blas_thread():
                reason, status, iterations, rows, lam, lam_tip, p, m_hat, terms, gaps, v = newton(chart, tup, rows0,
                                                                                                   weights0)
        except np.linalg.LinAlgError:
            return None
        if reason in (R_FIELD, R_ENERGY):
            return None
        return HeartAnswer(self, constraints, reason, int(iterations), rows, lam, lam_tip, p, m_hat, terms, gaps, v,
                           time.perf_counter() - start)


def _plain_dipoles(source) -> bool:
    """Whether a world source is None, a UniformField, a MagnetSource with the "dipole" model and a
    bounding sphere, point dipoles with bounding radii (``p_WM``, ``m_W``, ``_r2_min``: the
    engine's PortDipoles) or a FieldSources of those."""
    if source is None or isinstance(source, UniformField):
        return True
    if isinstance(source, FieldSources):
        return all(_plain_dipoles(s) for s in source.sources)
    if isinstance(source, MagnetSource):
        return source.model == "dipole" and hasattr(source.magnet, "bounding_radius")
    return hasattr(source, "p_WM") and hasattr(source, "m_W") and hasattr(source, "_r2_min")


def _outside_bounding_spheres(source, constraints, p0_B) -> bool:
    """Whether the warm start's balls are outside every magnet's bounding sphere, where
    ``ChainStatics.solve``'s check of the field at the balls passes (inside one, that check
    decides: a ball inside a magnet is refused with the reason)."""
    reach = float(np.sqrt(np.add.reduce(p0_B * p0_B, axis=1).max()))  # the balls' distance from p_WB
    return _outside(source, constraints, p0_B, reach)


def _outside(source, constraints, p0_B, reach: float) -> bool:
    if isinstance(source, FieldSources):
        return all(_outside(s, constraints, p0_B, reach) for s in source.sources)
    if isinstance(source, UniformField):
        return True
    if isinstance(source, MagnetSource):
        centres, r2_min = np.asarray(source.p_WM, float).reshape(1, 3), np.array([source.magnet.bounding_radius**2])
    else:
        centres, r2_min = source.p_WM, source._r2_min
    p_WB = constraints.p_WB
    for c, r2 in zip(centres.tolist(), r2_min.tolist()):  # far: every ball is within ``reach`` of p_WB
        far = math.sqrt((c[0] - p_WB[0]) ** 2 + (c[1] - p_WB[1]) ** 2 + (c[2] - p_WB[2]) ** 2) - reach
        if not (far > 0.0 and far * far > 2.0 * r2):
            break
    else:
        return True
    p_W = p_WB + p0_B @ constraints.R_WB.T
    r = p_W[:, None, :] - centres[None]
    return bool(np.all(np.einsum("kij,kij->ki", r, r) > r2_min[None]))


class HeartAnswer:
    """What ``HeartSolve.solve`` found: ``converged``, ``positions``/``dipoles`` (base frame),
    ``multipliers`` and ``iterations`` as a ``StaticsResult`` has them, the tip's wall push
    (``tip_wall_force_W``) and the whole ``StaticsResult`` on demand (``result()``)."""

    def __init__(self, solve: HeartSolve, constraints, reason, iterations, rows, lam, lam_tip, p, m_hat, terms, gaps,
                 v, elapsed):
        self._solve, self._constraints = solve, constraints
        self._raw = (reason, rows, lam, lam_tip, terms, gaps, v)
        self.positions, self.dipoles, self.iterations, self.solve_time = p, m_hat, iterations, elapsed
        # ChainStatics._assemble's verdict (its reason text is built when asked, ``result``).
        total = float(terms[0]) + float(terms[1]) + float(terms[2]) + float(terms[3])  # EnergyTerms.total
        self.converged = answer_verdict(solve.model, p, m_hat, total, gaps, reason in (R_MINIMUM, R_MINIMUM_LINE),
                                        "")[0]
        self.multipliers = dict(zip(rows.tolist(), lam.tolist()))
        self._result = None

    @property
    def reason(self) -> str:
        """Why the solve stopped (``StaticsResult.reason``)."""
        return self.result().reason

    def tip_wall_force_W(self) -> np.ndarray | None:
        """The wall's push on the sub-chain's tip ball [N] (``StaticsResult.wall_forces_W``'s
        entry, the same arithmetic), or None when it does not touch."""
        model = self._solve.model
        L = model.n_links
        lam = self.multipliers.get(model.n_pairs + L - 1)
        if lam is None or lam <= 1e-12:
            return None
        return row_force_W(self._constraints.R_WB, self._raw[6][L - 1], lam, model.energy_scale, model.d)

    def result(self):
        """The ``StaticsResult`` ``ChainStatics.solve`` returns for this answer."""
        if self._result is None:
            reason, rows, lam, lam_tip, terms, gaps, v = self._raw
            statics, model = self._solve.statics, self._solve.model
            model.set_constraints(self._constraints)
            result = statics._assemble(model, self.positions, self.dipoles, EnergyTerms(*terms.tolist()), gaps,
                                       reason in (R_MINIMUM, R_MINIMUM_LINE), reason_text(statics, reason),
                                       self.iterations,
                                       dict(self.multipliers), lam_tip, self._constraints, 0.0, v)
            self._result = replace(result, solve_time=self.solve_time)
        return self._result
