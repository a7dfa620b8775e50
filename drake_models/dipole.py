"""The point-dipole laws: the one source of truth for every magnetic quantity in the stack.

All functions are vectorised numpy in SI units. A dipole ``m`` (A m^2) at the origin makes at
``r`` (m) the flux density

    B(r) = mu0 / (4 pi) * (3 r (m . r) / |r|^5 - m / |r|^3)              [T]

whose spatial gradient ``G[a, b] = dB_a / dr_b`` is symmetric and traceless (curl- and
divergence-free field). A dipole ``m'`` in a field ``B`` with gradient ``G`` has energy
``-m' . B``, feels the force ``G m'`` (= grad(m' . B) because G is symmetric) and the torque
``m' x B``.
"""

from __future__ import annotations

import functools

import numpy as np

MU0 = 4e-7 * np.pi  # vacuum permeability [T m / A] (the SI value differs by < 1e-9 relative)
K_DIPOLE = MU0 / (4.0 * np.pi)  # [T m / A]


def _check_finite(r: np.ndarray, m: np.ndarray, what: str) -> None:
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(m))):
        raise ValueError(f"{what}: positions or moments are not finite (NaN or inf)")


def _check_separation(r2: np.ndarray, what: str) -> None:
    if np.any(r2 <= 0.0):
        raise ValueError(f"{what}: a field point coincides with a dipole (zero separation)")


def dipole_field(r: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Flux density of point dipoles.

    Args:
        r: (..., 3) vectors from each dipole to each field point [m].
        m: (..., 3) dipole moments, broadcast against ``r`` [A m^2].

    Returns:
        (..., 3) flux density [T].
    """
    r = np.asarray(r, dtype=float)
    m = np.asarray(m, dtype=float)
    _check_finite(r, m, "dipole_field")
    r2 = squared_norms(r)
    _check_separation(r2, "dipole_field")
    return _dipole_field(r, m, r2)


def dipole_field_of_checked(r: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``dipole_field`` (the same numbers) for arguments its caller has checked once: float
    arrays, finite, no field point at a dipole."""
    return _dipole_field(r, m, squared_norms(r))


def squared_norms(r: np.ndarray) -> np.ndarray:
    """``|r|^2`` over the last axis, as ``dipole_field`` computes it."""
    return np.einsum("...i,...i->...", r, r)


def _dipole_field(r: np.ndarray, m: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """The law of ``dipole_field`` given ``r2 = |r|^2``."""
    inv_r = 1.0 / np.sqrt(r2)
    inv_r3 = inv_r**3
    mr = np.einsum("...i,...i->...", m, r)
    return K_DIPOLE * (3.0 * r * (mr * inv_r3 * inv_r * inv_r)[..., None] - m * inv_r3[..., None])


class DipoleFieldAtPoint:
    """The flux density at one fixed offset ``r`` (3,) [m] from a point dipole whose moment turns:
    ``dipole_field(r[None], m)[0]``, the same numbers, for a sensor sampling a turning magnet.

    What does not depend on the moment (``1/|r|``, ``1/|r|^3``, ``3 r``) is computed once with
    ``_dipole_field``'s own numpy expressions; a call does the rest of that law's arithmetic on
    plain floats, operation for operation (IEEE products and differences, the same in numpy and
    Python), with ``m . r`` by numpy's ``einsum`` as the law takes it.
    """

    def __init__(self, r: np.ndarray) -> None:
        r = np.asarray(r, dtype=float).reshape(1, 3)
        _check_finite(r, np.zeros(3), "DipoleFieldAtPoint")
        r2 = squared_norms(r)
        _check_separation(r2, "DipoleFieldAtPoint")
        inv_r = 1.0 / np.sqrt(r2)
        self._r = r
        self._inv_r, self._inv_r3 = float(inv_r[0]), float((inv_r**3)[0])
        self._r3 = (3.0 * r)[0].tolist()

    @property
    def law_constants(self) -> np.ndarray:
        """(8,) what a call reads besides the moment, ``(3 r, r, 1/|r|, 1/|r|^3)``: the compiled
        form of this law (``kernels.actuation.dipole_field``) takes them."""
        return np.array([*self._r3, *self._r[0].tolist(), self._inv_r, self._inv_r3])

    def __call__(self, m: np.ndarray) -> np.ndarray:
        """(3,) flux density [T] of the moment ``m`` (3,) float [A m^2] (finite: the caller's)."""
        inv_r, inv_r3 = self._inv_r, self._inv_r3
        c = float(np.einsum("...i,...i->...", m, self._r)[0]) * inv_r3 * inv_r * inv_r
        (x, y, z), (m0, m1, m2) = self._r3, m.tolist()
        return np.array([K_DIPOLE * (x * c - m0 * inv_r3), K_DIPOLE * (y * c - m1 * inv_r3),
                         K_DIPOLE * (z * c - m2 * inv_r3)])


def dipole_field_gradient(r: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Spatial gradient ``G[..., a, b] = dB_a / dr_b`` of point dipoles' flux density.

    Args:
        r: (..., 3) vectors from each dipole to each field point [m].
        m: (..., 3) dipole moments [A m^2].

    Returns:
        (..., 3, 3) gradient [T/m], symmetric and traceless.
    """
    r = np.asarray(r, dtype=float)
    m = np.asarray(m, dtype=float)
    _check_finite(r, m, "dipole_field_gradient")
    r2 = np.einsum("...i,...i->...", r, r)
    _check_separation(r2, "dipole_field_gradient")
    inv_r2 = 1.0 / r2
    inv_r5 = inv_r2 * inv_r2 * np.sqrt(inv_r2)
    mr = np.einsum("...i,...i->...", m, r)
    eye = np.eye(3)
    G = (
        np.einsum("...a,...b->...ab", m, r)
        + np.einsum("...a,...b->...ab", r, m)
        + mr[..., None, None] * eye
        - 5.0 * (mr * inv_r2)[..., None, None] * np.einsum("...a,...b->...ab", r, r)
    )
    return 3.0 * K_DIPOLE * inv_r5[..., None, None] * G


def force_on_dipole(m: np.ndarray, G: np.ndarray) -> np.ndarray:
    """Force ``G m`` on dipoles ``m`` (..., 3) [A m^2] in a field with gradient ``G`` (..., 3, 3) [T/m]; returns N."""
    return np.einsum("...ab,...b->...a", G, m)


def torque_on_dipole(m: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Torque ``m x B`` [N m] on dipoles ``m`` (..., 3) [A m^2] in the flux density ``B`` (..., 3) [T]."""
    return np.cross(m, B)


def energy_of_dipole(m: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Potential energy ``-m . B`` [J] of dipoles ``m`` (..., 3) in the flux density ``B`` (..., 3)."""
    return -np.einsum("...i,...i->...", m, B)


def chain_interactions(p: np.ndarray, m: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Mutual dipole-dipole interaction of a set of magnets, all pairs at once.

    Args:
        p: (n, 3) dipole positions [m].
        m: (n, 3) dipole moments [A m^2].

    Returns:
        ``(U, F, B)``: the total pair energy ``sum_{i<j} -m_i . B_j(p_i)`` [J]; ``F`` (n, 3) the
        force on each dipole from all the others [N]; ``B`` (n, 3) the flux density at each dipole
        made by all the others [T]. The torque on each is ``m x B`` and ``dU/dm_i = -B_i``,
        ``dU/dp_i = -F_i``.
    """
    p = np.asarray(p, dtype=float)
    m = np.asarray(m, dtype=float)
    n = p.shape[0]
    if n < 2:
        return 0.0, np.zeros_like(p), np.zeros_like(p)
    if not np.all(np.isfinite(p)) or not np.all(np.isfinite(m)):
        raise ValueError("chain_interactions: positions or moments are not finite (NaN or inf)")
    r = p[:, None, :] - p[None, :, :]  # r[i, j] = p_i - p_j
    r2 = np.einsum("ijk,ijk->ij", r, r)
    np.fill_diagonal(r2, 1.0)
    if np.any(r2 <= 0.0):
        i, j = np.argwhere(r2 <= 0.0)[0]
        raise ValueError(f"chain_interactions: dipoles {i} and {j} are at the same position")
    inv_r2 = 1.0 / r2
    np.fill_diagonal(inv_r2, 0.0)
    inv_r = np.sqrt(inv_r2)
    inv_r3 = inv_r2 * inv_r
    mi_r = np.einsum("ik,ijk->ij", m, r)  # m_i . r_ij
    mj_r = np.einsum("jk,ijk->ij", m, r)  # m_j . r_ij
    mi_mj = m @ m.T
    # Field at i from j: k (3 r (m_j . r) / r^5 - m_j / r^3).
    B = K_DIPOLE * (
        3.0 * np.einsum("ij,ijk->ik", mj_r * inv_r3 * inv_r2, r) - inv_r3 @ m
    )
    # Pair energy, each pair once.
    e = K_DIPOLE * inv_r3 * (mi_mj - 3.0 * mi_r * mj_r * inv_r2)
    U = 0.5 * float(e.sum())
    # Force on i from j: 3k/r^5 [(m_i.r) m_j + (m_j.r) m_i + (m_i.m_j) r - 5 (m_i.r)(m_j.r) r / r^2].
    c5 = 3.0 * K_DIPOLE * inv_r3 * inv_r2
    F = (
        (c5 * mi_r) @ m
        + (c5 * mj_r).sum(axis=1)[:, None] * m
        + np.einsum("ij,ijk->ik", c5 * (mi_mj - 5.0 * mi_r * mj_r * inv_r2), r)
    )
    return U, F, B


@functools.lru_cache(maxsize=64)
def _pairs(n: int):
    """Pair indices i < j (each (pairs,))."""
    return np.triu_indices(n, k=1)


def _sum_onto_balls(n: int, index: np.ndarray, terms: np.ndarray) -> np.ndarray:
    """sum_k terms[k] onto ball index[k]: (n, ...) (O(n^2) memory, unlike an incidence matrix)."""
    out = np.zeros((n,) + terms.shape[1:])
    np.add.at(out, index, terms)
    return out


def chain_interaction_hessian(p: np.ndarray, m: np.ndarray):
    """Pair energy, forces, fields and second derivatives of ``chain_interactions``, pair by pair.

    With phi = 1/|r| the pair energy is ``e = -k m_i . (grad grad phi)(r) m_j`` (r = p_i - p_j), so
    every second derivative is a contraction of the third and fourth derivative tensors of
    1/|r|; each unordered pair is computed once.

    Args:
        p: (n, 3) dipole positions [m].
        m: (n, 3) dipole moments [A m^2].

    Returns:
        ``(U, F, B, H_pp, H_pm, H_mm)``: U, F, B as in ``chain_interactions``; the Hessians are
        each (n, 3, n, 3): ``H_pp[i, :, j, :] = d2U / dp_i dp_j``,
        ``H_pm[i, :, j, :] = d2U / dp_i dm_j``, ``H_mm[i, :, j, :] = d2U / dm_i dm_j``.
    """
    p = np.asarray(p, dtype=float)
    m = np.asarray(m, dtype=float)
    n = p.shape[0]
    iu, ju = _pairs(n)
    r = p[iu] - p[ju]
    r2 = np.einsum("ij,ij->i", r, r)
    if np.any(r2 <= 0.0) or not np.all(np.isfinite(r2)):
        raise ValueError("chain_interaction_hessian: two dipoles coincide or positions are not finite")
    x, y = m[iu], m[ju]
    inv_r2 = 1.0 / r2
    inv_r3 = inv_r2 * np.sqrt(inv_r2)
    inv_r5 = inv_r3 * inv_r2
    inv_r7 = inv_r5 * inv_r2
    xr = np.einsum("ij,ij->i", x, r)
    yr = np.einsum("ij,ij->i", y, r)
    xy = np.einsum("ij,ij->i", x, y)
    k = K_DIPOLE
    eye = np.eye(3)
    col = lambda a: a[:, None]  # noqa: E731
    mat = lambda a: a[:, None, None]  # noqa: E731
    # Energy, fields, forces.
    U = float(k * np.sum(xy * inv_r3 - 3.0 * xr * yr * inv_r5))
    B = _sum_onto_balls(n, iu, k * (3.0 * col(yr * inv_r5) * r - col(inv_r3) * y)) + _sum_onto_balls(
        n, ju, k * (3.0 * col(xr * inv_r5) * r - col(inv_r3) * x)
    )
    f = 3.0 * k * col(inv_r5) * (col(xr) * y + col(yr) * x + col(xy) * r - 5.0 * col(xr * yr * inv_r2) * r)
    F = _sum_onto_balls(n, iu, f) - _sum_onto_balls(n, ju, f)
    # Second derivatives.
    rr = r[:, :, None] * r[:, None, :]

    def sym_outer(a, b):
        o = a[:, :, None] * b[:, None, :]
        return o + o.transpose(0, 2, 1)

    v = -15.0 * col(inv_r7) * (col(yr) * x + col(xr) * y)
    Q = (
        mat(105.0 * inv_r7 * inv_r2 * xr * yr - 15.0 * inv_r7 * xy) * rr
        + sym_outer(v, r)
        + mat(-15.0 * inv_r7 * xr * yr + 3.0 * inv_r5 * xy) * eye
        + mat(3.0 * inv_r5) * sym_outer(x, y)
    )
    T_y = mat(-15.0 * yr * inv_r7) * rr + mat(3.0 * inv_r5) * sym_outer(y, r) + mat(3.0 * inv_r5 * yr) * eye
    T_x = mat(-15.0 * xr * inv_r7) * rr + mat(3.0 * inv_r5) * sym_outer(x, r) + mat(3.0 * inv_r5 * xr) * eye
    D = mat(3.0 * inv_r5) * rr - mat(inv_r3) * eye
    H_pp = np.zeros((n, n, 3, 3))
    H_pm = np.zeros((n, n, 3, 3))
    H_mm = np.zeros((n, n, 3, 3))
    kQ = k * Q
    H_pp[iu, ju] = kQ
    H_pp[ju, iu] = kQ
    idx = np.arange(n)
    H_pp[idx, idx] = -(_sum_onto_balls(n, iu, kQ) + _sum_onto_balls(n, ju, kQ))
    # A_ij = d2 e / dp_i dm_i = -k T[m_j](r), A_ji = +k T[m_i](r); d2 e / dp_j dm_i = -A_ij.
    A_ij, A_ji = -k * T_y, k * T_x
    H_pm[idx, idx] = _sum_onto_balls(n, iu, A_ij) + _sum_onto_balls(n, ju, A_ji)
    H_pm[ju, iu] = -A_ij
    H_pm[iu, ju] = -A_ji
    H_mm[iu, ju] = -k * D
    H_mm[ju, iu] = -k * D
    swap = lambda H: H.transpose(0, 2, 1, 3)  # noqa: E731  [i, j, a, b] -> [i, a, j, b]
    return U, F, B, swap(H_pp), swap(H_pm), swap(H_mm)
