"""The Python side of the compiled Newton solve (``compiled_newton``): the model's arrays for the
kernels, and the answer read back for ``statics.ChainStatics``.

Kept apart from the kernels' file: numba's cache of those kernels is stamped with their file, so
editing this glue does not recompile them.
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.atrium_sdf import AtriumSDF
from ballchain.drake_models.field_sources import FieldSources, MagnetSource, UniformField
from ballchain.drake_models.kernels import check_status
from ballchain.drake_models.params import GRAVITY
from ballchain.optimization.wall_constraints import RHO_SMOOTHING, PointDipoles
from ballchain.optimization.compiled_newton import (R_FIELD, R_LIMIT, R_LINE, R_MINIMUM, R_MINIMUM_LINE,
                                                    R_QP, R_SADDLE, R_ENERGY, S_HEART_WEIGHT, newton)
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


def model_tuple(statics, model, external, constraints):
    """The kernels' model tuple for a ChainStatics' model (``ReducedChain`` with its tip target
    and wall set, or ``ConstrainedChain`` with its constraints), or None when the external field
    is not one the kernels evaluate (``field_arrays``)."""
    if external is None:
        field, has_external = (_EMPTY3, _EMPTY3, np.zeros(3), np.zeros(0)), 0
    else:
        field, has_external = field_arrays(external), 1
        if field is None:
            return None
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
    flags = np.array([statics.max_iterations, has_external, model.tip_target is not None, model.wall is not None,
                      constraints is not None], dtype=np.int64)
    centres, moments, B0, r2 = (np.ascontiguousarray(a, float) for a in field)
    return (model._params, centres, moments, B0, r2, tip, wall, p_WB, R_WB, grid, frame, sheath, settings, flags)


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


def run(statics, model, external, p0, m0, lam0, constraints):
    """The compiled solve of a ChainStatics' model from (p0, m0): ``(converged, reason,
    iterations, lam_near dict, lam_tip, p, m_hat, terms (4,), gaps, v)``, or None when the
    Python solver must take it (a field or wall the kernels do not evaluate, a ball inside a
    magnet's bounding sphere). Raises ValueError, as the Python model, on two coincident balls
    or a folded sleeve."""
    if not compilable_constraints(constraints):
        return None
    tup = model_tuple(statics, model, external, constraints)
    if tup is None:
        return None
    rows0 = np.fromiter(lam0.keys(), np.int64, len(lam0)) if lam0 else _NO_ROWS
    weights0 = np.fromiter(lam0.values(), float, len(lam0)) if lam0 else _NO_WEIGHTS
    chart = chart_frames(configuration_vectors(np.ascontiguousarray(p0, float), np.ascontiguousarray(m0, float)))
    try:
        reason, status, iterations, rows, lam, lam_tip, p, m_hat, terms, gaps, v = newton(chart, tup, rows0, weights0)
    except np.linalg.LinAlgError as err:  # a step's system singular in floating point
        return _singular(model, chart, err)
    if reason == R_FIELD:
        return None
    if reason == R_ENERGY:
        check_status(status, "ReducedChain.evaluate")
    if reason == R_LIMIT:
        text = f"iteration limit ({statics.max_iterations}) reached"
    else:
        text = REASONS[reason]
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
