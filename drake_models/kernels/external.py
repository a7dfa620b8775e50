"""The external field: point dipoles' flux density and gradient, and the energy ``-M m_hat . B``
of the balls in a field with its derivatives.

The laws of ``dipole.py`` (``dipole_field``, ``dipole_field_gradient``) and of the external term
of ``chain_energy.field_energy``, compiled. Field sources stay Python objects
(``field_sources.FieldSource``): ``external_arrays`` evaluates one at the ball centres and the
kernels take the arrays. It knows a source only through the protocol (``field_and_gradient``,
and the optional ``uniform`` and ``field_gradient_derivative``), so this file imports no field
source: ``field_sources`` imports the kernels.
"""

from __future__ import annotations

import math

import numpy as np

from ballchain.drake_models.dipole import K_DIPOLE
from ballchain.drake_models.kernels._common import kernel


@kernel
def dipole_field_and_gradient(points, centres, moments, r2_min):
    """Flux density and gradient of point dipoles at points, summed over the dipoles.

    The law of ``dipole.dipole_field`` and ``dipole.dipole_field_gradient``:
    ``B = k (3 r (m . r) / r^5 - m / r^3)``,
    ``G[a, b] = 3 k / r^5 (m_a r_b + r_a m_b + (m . r) delta_ab - 5 (m . r) r_a r_b / r^2)``,
    r from the dipole to the point.

    Args:
        points: (n, 3) field points [m].
        centres: (k, 3) dipole positions [m]; moments: (k, 3) dipole moments [A m^2].
        r2_min: (k,) no point may be at a squared distance <= this from a centre [m^2].

    Returns:
        ``(violation, B (n, 3) [T], G (n, 3, 3) [T/m])``; ``violation`` is -1, or
        ``point * k + dipole`` of the first point too close to a dipole (B, G then incomplete).
    """
    n = points.shape[0]
    k = centres.shape[0]
    B = np.zeros((n, 3))
    G = np.zeros((n, 3, 3))
    r = np.empty(3)
    for i in range(n):
        for j in range(k):
            r2 = 0.0
            mr = 0.0
            for c in range(3):
                r[c] = points[i, c] - centres[j, c]
                r2 += r[c] * r[c]
                mr += moments[j, c] * r[c]
            if r2 <= r2_min[j] or r2 <= 0.0:
                return i * k + j, B, G
            inv_r2 = 1.0 / r2
            inv_r = math.sqrt(inv_r2)
            inv_r3 = inv_r2 * inv_r
            inv_r5 = inv_r3 * inv_r2
            for a in range(3):
                B[i, a] += K_DIPOLE * (3.0 * r[a] * mr * inv_r5 - moments[j, a] * inv_r3)
                for b in range(3):
                    g = moments[j, a] * r[b] + r[a] * moments[j, b] - 5.0 * mr * inv_r2 * r[a] * r[b]
                    if a == b:
                        g += mr
                    G[i, a, b] += 3.0 * K_DIPOLE * inv_r5 * g
    return -1, B, G


# The step of ``field_sources.field_gradient_derivative``'s central differences [m].
GRADIENT_STEP = 1e-6


@kernel
def dipole_arrays(points, centres, moments, B0, r2_min, hessian):
    """A uniform field B0 (3,) [T] plus point dipoles at points (n, 3): the arrays
    ``external_arrays`` gives for such a source, all in one compiled call.

    ``dG[k, a, b, c] = d2 B_a / dp_b dp_c`` (when ``hessian``, else zeros) is the central
    difference of the gradient with the step and stencil of
    ``field_sources.field_gradient_derivative``.

    Returns:
        ``(violation, B (n, 3), G (n, 3, 3), dG (n, 3, 3, 3))``: violation as
        ``dipole_field_and_gradient``'s (-1: every point is clear of the dipoles).
    """
    n = points.shape[0]
    violation, B, G = dipole_field_and_gradient(points, centres, moments, r2_min)
    for i in range(n):
        for a in range(3):
            B[i, a] += B0[a]
    dG = np.zeros((n, 3, 3, 3))
    if violation >= 0 or not hessian or centres.shape[0] == 0:  # (no dipole: dG = 0)
        return violation, B, G, dG
    # The stencil's gradients one point at a time (no flux density, no stencil arrays), each summed
    # over the dipoles in order as ``dipole_field_and_gradient`` sums them.
    k = centres.shape[0]
    point = np.empty(3)
    G_plus = np.empty((3, 3))
    G_minus = np.empty((3, 3))
    for i in range(n):
        for c in range(3):
            for s in range(2):
                for e in range(3):
                    point[e] = points[i, e]
                point[c] += GRADIENT_STEP if s == 0 else -GRADIENT_STEP
                out = G_plus if s == 0 else G_minus
                j = _point_gradient(point, centres, moments, r2_min, out)
                if j >= 0:  # the stencil point 6 i + c (+ 3 for the step back) too close to dipole j
                    return (6 * i + c + 3 * s) * k + j, B, G, dG
            for a in range(3):
                for b in range(3):
                    dG[i, a, b, c] = (G_plus[a, b] - G_minus[a, b]) / (2 * GRADIENT_STEP)
    return violation, B, G, dG


@kernel
def _point_gradient(point, centres, moments, r2_min, out):
    """The dipoles' field gradient at one point (3,), written into ``out`` (3, 3) (the law and the
    order of the sums of ``dipole_field_and_gradient``); returns -1, or the first dipole the point
    is too close to (out then incomplete)."""
    for a in range(3):
        for b in range(3):
            out[a, b] = 0.0
    for j in range(centres.shape[0]):
        r = (point[0] - centres[j, 0], point[1] - centres[j, 1], point[2] - centres[j, 2])
        r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
        mr = moments[j, 0] * r[0] + moments[j, 1] * r[1] + moments[j, 2] * r[2]
        if r2 <= r2_min[j] or r2 <= 0.0:
            return j
        inv_r2 = 1.0 / r2
        inv_r = math.sqrt(inv_r2)
        inv_r3 = inv_r2 * inv_r
        inv_r5 = inv_r3 * inv_r2
        for a in range(3):
            for b in range(3):
                g = moments[j, a] * r[b] + r[a] * moments[j, b] - 5.0 * mr * inv_r2 * r[a] * r[b]
                if a == b:
                    g += mr
                out[a, b] += 3.0 * K_DIPOLE * inv_r5 * g
    return -1


@kernel
def add_external(p, m_hat, M, B, G, dU_dp, dU_dm):
    """Add ``U_e = -M sum_k m_hat_k . B_k`` to the gradients; returns U_e [J]."""
    n = p.shape[0]
    U = 0.0
    for k in range(n):
        for a in range(3):
            U -= M * m_hat[k, a] * B[k, a]
            dU_dm[k, a] -= M * B[k, a]
            for b in range(3):
                dU_dp[k, b] -= M * G[k, a, b] * m_hat[k, a]
    return U


@kernel
def external_hessian_blocks(m_hat, M, G, dG):
    """The external field's per-ball Hessian blocks.

    Args:
        m_hat: (n, 3) unit dipoles; M: dipole moment [A m^2].
        G: (n, 3, 3) field gradient [T/m]; dG: (n, 3, 3, 3) its derivative [T/m^2].

    Returns:
        ``(H_pp, H_pm)`` (n, 3, 3): ``d2U_e / dp_k dp_k`` and ``d2U_e / dp_k dm_hat_k``.
    """
    n = m_hat.shape[0]
    H_pp = np.zeros((n, 3, 3))
    H_pm = np.zeros((n, 3, 3))
    for k in range(n):
        for b in range(3):
            for c in range(3):
                acc = 0.0
                for a in range(3):
                    acc += m_hat[k, a] * dG[k, a, b, c]
                H_pp[k, b, c] = -M * acc
                H_pm[k, b, c] = -M * G[k, c, b]
    return H_pp, H_pm


_ZEROS: dict = {}


def _zeros(shape) -> np.ndarray:
    """A cached array of zeros (the kernels only read their field inputs)."""
    z = _ZEROS.get(shape)
    if z is None:
        z = _ZEROS[shape] = np.zeros(shape)
    return z


def field_gradient_derivative(source, p: np.ndarray, step: float = GRADIENT_STEP) -> np.ndarray:
    """Second spatial derivative ``dG[k, a, b, c] = d2 B_a / dp_b dp_c`` (k, 3, 3, 3) [T/m^2] of a
    FieldSource at the points p (k, 3) [m] (checked by the caller).

    Zero for a uniform source (``source.uniform``); the source's own
    ``field_gradient_derivative(p, step)`` when it has one (a sum of sources sums its parts');
    otherwise central differences of the source's analytic (or, for the exact cylinder,
    finite-difference) gradient. ``field_sources.field_gradient_derivative`` checks the points
    and calls this.
    """
    if getattr(source, "uniform", False):
        return np.zeros((p.shape[0], 3, 3, 3))
    own = getattr(source, "field_gradient_derivative", None)
    if own is not None:
        return own(p, step)
    offsets = np.concatenate([np.eye(3) * step, -np.eye(3) * step])
    stencil = (p[:, None, :] + offsets[None, :, :]).reshape(-1, 3)
    _, G = source.field_and_gradient(stencil)
    G = G.reshape(p.shape[0], 6, 3, 3)
    return ((G[:, :3] - G[:, 3:]) / (2 * step)).transpose(0, 2, 3, 1)


def external_arrays(external, p: np.ndarray, hessian: bool = False):
    """(has_external, B (n, 3), G (n, 3, 3), dG (n, 3, 3, 3)) of a FieldSource (or None) at p.

    dG (from ``field_gradient_derivative``) only when ``hessian``; zeros otherwise.
    The zero arrays are shared between calls (the kernels only read them): do not write to them.
    """
    n = p.shape[0]
    if external is None:
        return False, _zeros((n, 3)), _zeros((n, 3, 3)), _zeros((n, 3, 3, 3))
    if getattr(external, "uniform", False):  # the same field B_W everywhere: no gradient
        B = np.empty((n, 3))
        B[:] = external.B_W
        return True, B, _zeros((n, 3, 3)), _zeros((n, 3, 3, 3))
    B, G = external.field_and_gradient(p)
    dG = field_gradient_derivative(external, p) if hessian else np.zeros((n, 3, 3, 3))
    return True, np.ascontiguousarray(B, dtype=float), np.ascontiguousarray(G, dtype=float), \
        np.ascontiguousarray(dG, dtype=float)
