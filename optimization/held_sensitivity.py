"""The held tip's pressing force differentiated through its equilibrium: the implicit function
theorem on the statics' KKT system (issue 48).

A held equilibrium (``ChainStatics.solve(..., tip_target=t)``) is a minimum of the scaled energy
``E(q; m) = U / E0`` in the chart coordinates q subject to the tip target
``c_t(q; t) = (p_tip(q) - t) / d = 0`` and the rigidity rows in contact ``c_r(q) = 0`` (the rows
of ``StaticsResult.multipliers`` with a positive multiplier): ``grad E = A' lam`` with
``A = [dc_r/dq; dc_t/dq]``. Differentiating it along a parameter theta (a source's moment m_j,c,
the target t):

    [H_L  A'] [ dq/dtheta  ]   [ -d(grad E)/dtheta ]
    [ A   0 ] [-dlam/dtheta] = [ -dc/dtheta        ]

with ``H_L = Hess E - sum lam_k Hess c_k`` (the SQP's ``compiled_newton.lagrangian_hessian``).
The mixed derivatives ``d(grad E)/dm`` are ``compiled_sensitivity.moment_columns`` (the external
energy is linear in each moment); ``dc_t/dt = -I / d``. The tip's reaction is
``E0 / d lam_t`` (``ChainStatics._assemble``), the force it presses in a basis
``basis' (-reaction)`` (``inverse_statics.HeldTip.pressing``). One linear solve with 3k + 3
right-hand sides replaces 3k + 2 warm-started held solves of forward differences; its dq/dtheta
is the tangent of the held equilibria (``pressing_sensitivity``), from which ``HeldTip``
predicts the next evaluation's warm start.

The system is regular when A has full row rank and H_L is positive definite on A's null space
(second-order sufficiency: the solve verified positive semi-definiteness only); either failing
(a fold of the held equilibria, degenerate contact rows) answers None, and the caller falls
back to differences.
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.kernels import OK, chart_frames, configuration_vectors
from ballchain.optimization.blas_threads import one_blas_thread
from ballchain.optimization.compiled_model import field_arrays
from ballchain.optimization.compiled_newton import evaluate, jacobian_rows, lagrangian_hessian, tip_jacobian
from ballchain.optimization.compiled_sensitivity import KKT_OK, kkt_solve, moment_columns

_ZERO6, _ZERO3, _EYE3 = np.zeros(6), np.zeros(3), np.eye(3)
_NO_GRID, _NO_FRAME, _NO_SHEATH = np.zeros((0, 0, 0)), np.zeros(7), np.zeros(5)
_NO_FIELD = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(3), np.zeros(0))
ACTIVE = 1e-12  # a contact row's multiplier above this holds it as an equality (``_assemble``'s forces)
RANK = 1e-10  # A's smallest singular value below this times its largest (or 1): rows degenerate
DEFINITE = 1e-9  # the reduced Hessian less this times its largest diagonal entry (or 1) not definite: singular
PARALLEL = 1e-12  # a source's moment off its direction by more than this (relative): not the held tip's magnet


def _held_model(statics, model, field, target):
    """The kernels' model tuple of a held solve (``compiled_held_tip.held_solve``'s): the chain's
    parameters, the field's arrays, the tip target, no wall, no heart."""
    centres, moments, B0, r2 = (np.ascontiguousarray(a, float) for a in field)
    settings = np.array([statics.tolerance, statics.feasibility_tolerance, statics.contact_margin, statics.max_step,
                         0.0, 0.5 * model.d])
    flags = np.array([statics.max_iterations, 1, 1, 0, 0], dtype=np.int64)  # a field, pinned, no wall, no heart
    return (model._params, centres, moments, B0, r2, np.ascontiguousarray(target, float), _ZERO6, _ZERO3, _EYE3,
            _NO_GRID, _NO_FRAME, _NO_SHEATH, settings, flags)


def reaction_sensitivity(statics, external, result, target):
    """``(dR/dm (3, 3k), dR/dt (3, 3))``: the tip reaction's derivatives [N per A m^2, N/m] with
    respect to the moments of ``external``'s k point dipoles (``field_arrays`` order, 3 per
    source) and the tip target, at the held equilibrium ``result`` of
    ``statics.solve(external, ..., tip_target=target)``; None where the sensitivity is not
    this law's: an unconverged result, a field the kernels do not evaluate (None: no field, no
    moment columns), a ball inside a magnet's bounding sphere, or a singular KKT system (see
    the module)."""
    field = _NO_FIELD if external is None else field_arrays(external)
    out = _sensitivity(statics, field, result, target)
    if out is None:
        return None
    k3 = field[1].size
    return out[0][:, :k3], out[0][:, k3:]


def _sensitivity(statics, field, result, target):
    """``(dR (3, 3k + 3), dq (nq, 3k + 3), chart)`` at ``result`` for the field's ``field_arrays``:
    the reaction's and the chart coordinates' derivatives with respect to the k moments and the
    target, in the chart centred on the result (``reaction_sensitivity``'s None cases: None)."""
    model = statics._model
    if (result is None or not result.converged or statics.method != "newton" or model is None
            or not hasattr(model, "_params") or result.positions.shape != (statics.chain.n_balls, 3)):
        return None
    if field is None or not all(np.isfinite(a).all() for a in field[:3]):
        return None
    tup = _held_model(statics, model, field, target)
    p0 = np.ascontiguousarray(result.positions, float)
    chart = chart_frames(configuration_vectors(p0, np.ascontiguousarray(result.dipoles, float)))
    nq = 4 * (p0.shape[0] - 1)
    active = {k: v for k, v in result.multipliers.items() if v > ACTIVE}
    rows = np.fromiter(active.keys(), np.int64, len(active))
    lam = np.fromiter(active.values(), float, len(active))
    lam_tip = np.asarray(result.tip_reaction, float) * (model.d / model.energy_scale)
    with one_blas_thread():
        ev = evaluate(np.zeros(nq), 2, chart, tup)
        if ev[0] != OK:
            return None
        violation, C = moment_columns(ev[7], ev[8], ev[9], tup[0], tup[1], tup[4])
        if violation >= 0:
            return None
        H = lagrangian_hessian(ev, rows, lam, True, lam_tip, tup)
        A = np.vstack((jacobian_rows(rows, ev, tup), tip_jacobian(ev[7])))
        r, k3 = A.shape[0], C.shape[1]
        top = np.zeros((nq, k3 + 3))
        top[:, :k3] = -C  # -d(grad E)/dm
        bottom = np.zeros((r, k3 + 3))
        bottom[r - 3:, k3:] = np.eye(3) / model.d  # -dc_t/dt
        status, dq, y = kkt_solve(H, A, top, bottom, RANK, DEFINITE)
    if status != KKT_OK:
        return None
    dR = (model.energy_scale / model.d) * -y[r - 3:]
    return dR, dq, chart


def pressing_jacobian(statics, external, result, target, directions, basis):
    """The Jacobian (3, 3k + 2) of ``basis' (-tip_reaction)`` (``HeldTip.pressing``) with respect
    to x = (the k magnets' raw direction rows ``directions`` (k, 3), unit or not, the touch
    offset o (2,) along ``basis[:, 1:]``) at the held equilibrium ``result``, where the field is
    ``external`` (source j: the magnet's moment along the unit row j) and the tip target
    ``target``; None where ``reaction_sensitivity`` is, or when ``external``'s dipoles are not
    the k magnets along ``directions``."""
    out = pressing_sensitivity(statics, external, result, target, directions, basis)
    return None if out is None else out[0]


def pressing_sensitivity(statics, external, result, target, directions, basis):
    """``(J (3, 3k + 2), T (nq, 3k + 2), chart)``: ``pressing_jacobian``'s J, and T the chart
    coordinates' derivatives with respect to the same x in the chart centred on ``result``
    (``chart_frames`` of its configuration: the tangent of the held equilibria); None as
    ``pressing_jacobian``."""
    directions = np.asarray(directions, float).reshape(-1, 3)
    field = field_arrays(external) if external is not None else None
    if field is None or field[1].shape != directions.shape:
        return None
    norms = np.linalg.norm(directions, axis=1)
    units = directions / norms[:, None]
    strengths = np.linalg.norm(field[1], axis=1)
    if not np.all(np.abs(field[1] - strengths[:, None] * units) <= PARALLEL * strengths[:, None]):
        return None
    out = _sensitivity(statics, field, result, target)
    if out is None:
        return None
    dR, dq, chart = out
    k = directions.shape[0]
    D = np.vstack((-basis.T @ dR, dq))  # the pressing force's and the coordinates' derivatives
    raw = np.empty((D.shape[0], 3 * k + 2))
    for j in range(k):  # m_j = |m_j| x_j / |x_j|: d m_j / d x_j = |m_j| (I - u u') / |x_j|
        u = units[j]
        raw[:, 3 * j:3 * j + 3] = D[:, 3 * j:3 * j + 3] @ ((strengths[j] / norms[j]) * (np.eye(3) - np.outer(u, u)))
    raw[:, 3 * k:] = D[:, 3 * k:] @ basis[:, 1:]  # the target moves along the wall's basis
    return raw[:3], raw[3:], chart
