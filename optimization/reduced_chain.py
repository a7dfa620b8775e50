"""The chain in reduced coordinates: energy, gradient, Hessian and rigidity constraints.

Adjacent balls touch, so a configuration of the canonical problem is fully described by the
n-1 unit link directions u_l (ball l to ball l+1, p_k = d sum_{l<k} u_l) and the n-1 free unit
dipole directions (ball 1's dipole is held along +x). The only constraints left are the
non-adjacent rigidity constraints |p_i - p_j| >= d (j >= i + 2), written as the dimensionless
``c_ij = |p_j - p_i|^2 / d^2 - 1 >= 0``.

Each of the K = 2(n-1) unit vectors is written in a chart centred on the warm start r0,

    w(a, b) = cos b (cos a r0 + sin a t1) + sin b t2,

with t2 the out-of-plane direction (z, or x near the poles) made orthogonal to r0 and
t1 = t2 x r0. The initial guess is always q = 0, planar problems move in ``a`` only and the
chart's singularity (w = +-t2) stays 90 degrees away. Coordinates: q = (a_1..a_K, b_1..b_K).

The physics and the chain rule run as the compiled kernels of ``drake_models.kernels``
(``backend="kernel"``, the default): O(n^2) memory, the rigidity Jacobian built only for the rows
asked for (``ConstraintJacobian``). ``backend="numpy"`` is the reference the tests hold the kernels
to: ``drake_models.chain_energy`` (``field_energy``, ``sleeve_bending``) and the chain rule as
dense matrix products (incidence matrices of O(n^3) memory: small chains only). The energy is
scaled by E0, the pair energy of two touching coaxial balls, so that the solvers see numbers of
order one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ballchain.drake_models import kernels as ck
from ballchain.drake_models.chain_energy import EnergyTerms, field_energy, sleeve_bending
from ballchain.drake_models.dipole import K_DIPOLE
from ballchain.drake_models.field_sources import FieldSource
from ballchain.drake_models.params import GRAVITY, BallChain
from ballchain.infrastructure.errors import UserInputError

X_AXIS = np.array([1.0, 0.0, 0.0])
Z_AXIS = np.array([0.0, 0.0, 1.0])


@dataclass
class Evaluation:
    """Energy (scaled by E0) and rigidity constraints at one q; derivatives when asked."""

    energy: float
    terms: EnergyTerms
    gaps: np.ndarray  # c_ij for every non-adjacent pair
    gradient: np.ndarray | None = None  # (nq,)
    jacobian: "np.ndarray | ConstraintJacobian | None" = None  # (pairs, nq): index rows, J[rows]
    hessian: np.ndarray | None = None  # (nq, nq)
    tip_residual: np.ndarray | None = None  # (p_tip - target) / d, when a tip target is set
    tip_jacobian: np.ndarray | None = None  # (3, nq)


class ConstraintJacobian:
    """The constraints' Jacobian (rows, nq), built row by row on demand by a kernel.

    ``J[rows]`` (an index array, a slice or a boolean mask) returns those rows as a dense array;
    ``np.asarray(J)``, ``J @ X`` and ``J.T`` build every row (O(n^3) memory for n balls: the
    solvers only ask for the rows near contact).
    """

    def __init__(self, n_rows: int, nq: int, p, V, d: float, normal):
        self.shape = (n_rows, nq)
        self._args = (p, V, d, normal)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, rows) -> np.ndarray:
        if isinstance(rows, tuple):  # J[rows, columns]: build the rows, then index the columns
            return self[rows[0]][(slice(None),) * (np.ndim(np.arange(self.shape[0])[rows[0]])) + rows[1:]]
        index = np.arange(self.shape[0])[rows]
        if index.ndim == 0:
            return ck.constraint_rows(index.reshape(1).astype(np.int64), *self._args)[0]
        return ck.constraint_rows(np.ascontiguousarray(index, dtype=np.int64), *self._args)

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        dense = self[:]
        return dense if dtype is None else dense.astype(dtype)

    def __matmul__(self, other):
        return self[:] @ other

    @property
    def T(self) -> np.ndarray:
        return self[:].T


class ReducedChain:
    """The canonical chain problem in chart coordinates.

    Args:
        chain: the chain.
        external: external field source or None.
        gravity: gravity along -z.
        backend: "kernel" (compiled, the default) or "numpy" (the tests' reference).
    """

    def __init__(self, chain: BallChain, external: FieldSource | None, gravity: bool,
                 backend: str = "kernel"):
        if chain.n_balls < 2:
            raise ValueError("the reduced chain needs at least 2 balls (ball 1 is held)")
        if backend not in ("kernel", "numpy"):
            raise UserInputError(f"backend must be 'kernel' or 'numpy', got {backend!r}")
        self.backend = backend
        self.chain = chain
        self.external = external
        self.gravity = gravity
        n = chain.n_balls
        self.n_links = n - 1
        self.n_vectors = 2 * (n - 1)
        self.nq = 2 * self.n_vectors
        self.d = chain.ball_diameter
        self.energy_scale = 2.0 * K_DIPOLE * chain.dipole_moment**2 / self.d**3
        self.sleeve_stiffness = (
            chain.sleeve.bending_stiffness / self.d if chain.sleeve is not None else 0.0
        )
        i, j = np.triu_indices(n, k=2)
        self.pair_i, self.pair_j = i, j
        self._pair_links = None  # the numpy reference's incidence matrices, built on first use
        self._C3_matrix = None
        self.tip_target: np.ndarray | None = None  # pin the tip's centre here [m] (equality)
        self.n_pairs = len(i)
        self.wall: tuple[np.ndarray, np.ndarray] | None = None  # (point, unit normal) of a plane
        self._last = None  # (q bytes, order, Evaluation) of the last evaluation

    @property
    def weight(self) -> float:
        """A ball's weight [N] when gravity is on, else 0."""
        return self.chain.ball_mass * GRAVITY if self.gravity else 0.0

    @property
    def _params(self) -> np.ndarray:
        """The kernels' parameters, for the chain and gravity as they are now."""
        key = (self.gravity, self.sleeve_stiffness, self.energy_scale)
        if getattr(self, "_params_key", None) != key:
            self._params_key = key
            self._params_array = ck.reduced_params(self.d, self.chain.dipole_moment, self.weight,
                                                   self.sleeve_stiffness, self.energy_scale, X_AXIS)
        return self._params_array

    @property
    def pair_links(self) -> np.ndarray:
        """(pairs, L) incidence: pair (i, j) spans links i..j-1 (numpy reference only: O(n^3))."""
        if self._pair_links is None:
            links = np.arange(self.n_links)
            i, j = self.pair_i, self.pair_j
            self._pair_links = ((links[None, :] >= i[:, None]) & (links[None, :] < j[:, None])).astype(float)
        return self._pair_links

    @property
    def _C3(self) -> np.ndarray:
        """(3n, 3L): p = d C u with C[k, l] = 1 for l < k (numpy reference only)."""
        if self._C3_matrix is None:
            n = self.n_links + 1
            C = (np.arange(n)[:, None] > np.arange(self.n_links)[None, :]).astype(float)
            self._C3_matrix = np.kron(C, np.eye(3))
        return self._C3_matrix

    # --- chart -------------------------------------------------------------------------
    def set_chart(self, w0: np.ndarray) -> None:
        """Centre the chart on the unit vectors w0 (K, 3)."""
        if self.backend == "kernel":
            self.r0, self.t1, self.t2 = ck.chart_frames(np.ascontiguousarray(w0, dtype=float))
            self._last = None
            return
        r0 = w0 / np.linalg.norm(w0, axis=1)[:, None]
        t2 = Z_AXIS - r0 * r0[:, 2:3]
        norms = np.linalg.norm(t2, axis=1)
        near_pole = norms < 0.3
        if np.any(near_pole):
            alt = X_AXIS - r0 * r0[:, 0:1]
            t2[near_pole] = alt[near_pole]
            norms = np.linalg.norm(t2, axis=1)
        self.r0 = r0
        self.t2 = t2 / norms[:, None]
        self.t1 = np.ascontiguousarray(np.cross(self.t2, r0))
        self.r0 = np.ascontiguousarray(self.r0)
        self.t2 = np.ascontiguousarray(self.t2)
        self._last = None  # a new chart (and possibly a new field, target or wall): forget

    def chart_from_configuration(self, positions: np.ndarray, dipoles: np.ndarray) -> None:
        """Centre the chart on a configuration's link and free dipole directions."""
        if self.backend == "kernel":
            self.set_chart(ck.configuration_vectors(np.ascontiguousarray(positions, dtype=float),
                                                    np.ascontiguousarray(dipoles, dtype=float)))
            return
        links = np.diff(positions, axis=0)
        self.set_chart(np.vstack([links / np.linalg.norm(links, axis=1)[:, None], dipoles[1:]]))

    def unit_vectors(self, q: np.ndarray):
        K = self.n_vectors
        a, b = q[:K, None], q[K:, None]
        ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
        in_plane = ca * self.r0 + sa * self.t1
        w = cb * in_plane + sb * self.t2
        dw_da = cb * (-sa * self.r0 + ca * self.t1)
        dw_db = -sb * in_plane + cb * self.t2
        return w, dw_da, dw_db, in_plane, (ca, sa, cb, sb)

    def configuration(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(positions (n, 3) [m], unit dipoles (n, 3)) at q."""
        if self.backend == "kernel":
            V = ck.chart_vectors(np.ascontiguousarray(q, dtype=float), self.r0, self.t1, self.t2)
            return ck.chain_configuration(V[0], self.n_links, self.d)
        w = self.unit_vectors(q)[0]
        return self._configuration(w)

    def _configuration(self, w):
        u = w[: self.n_links]
        p = np.zeros((self.n_links + 1, 3))
        p[1:] = self.d * np.cumsum(u, axis=0)
        return p, np.vstack([X_AXIS, w[self.n_links :]])

    # --- evaluation ------------------------------------------------------------------------
    def evaluate(self, q: np.ndarray, order: int = 2) -> Evaluation:
        """Energy/E0 and constraints at q, with derivatives up to ``order`` (0, 1 or 2).

        The last evaluation is remembered: asking again at the same q (same chart) is free.
        """
        key = q.tobytes()
        if self._last is not None and self._last[0] == key and self._last[1] >= order:
            return self._last[2]
        if self.backend == "kernel":
            ev = self._evaluate_kernel(q, order)
        else:
            ev = self._evaluate_numpy(q, order)
        self._last = (key, order, ev)
        return ev

    def _evaluate_kernel(self, q: np.ndarray, order: int) -> Evaluation:
        V = ck.chart_vectors(np.ascontiguousarray(q, dtype=float), self.r0, self.t1, self.t2)
        L, K = self.n_links, self.n_vectors
        p, m_hat = ck.chain_configuration(V[0], L, self.d)
        has_ext, B, G, dG = ck.external_arrays(self.external, p, hessian=order >= 2)
        status, t, grad, hess = ck.reduced_energy(V, p, m_hat, B, G, dG, self._params, has_ext, order)
        ck.check_status(status, "ReducedChain.evaluate")
        terms = EnergyTerms(float(t[0]), float(t[1]), float(t[2]), float(t[3]))
        gaps = ck.rigidity_gaps(p, self.d)
        if self.wall is not None:  # every free ball on the open side: n . (p - p0) / d >= 1/2
            p0, normal = self.wall
            gaps = np.concatenate([gaps, (p[1:] - p0) @ normal / self.d - 0.5])
        ev = Evaluation(terms.total / self.energy_scale, terms, gaps)
        if self.tip_target is not None:
            ev.tip_residual = (p[-1] - self.tip_target) / self.d
        if order < 1:
            return ev
        ev.gradient = grad
        normal = np.zeros(3) if self.wall is None else np.ascontiguousarray(self.wall[1], dtype=float)
        ev.jacobian = ConstraintJacobian(len(gaps), self.nq, p, V, self.d, normal)
        if self.tip_target is not None:  # p_tip / d = sum_l u_l
            ev.tip_jacobian = np.zeros((3, self.nq))
            ev.tip_jacobian[:, :L] = V[1, :L].T
            ev.tip_jacobian[:, K : K + L] = V[2, :L].T
        if order >= 2:
            ev.hessian = hess
        return ev

    def _evaluate_numpy(self, q: np.ndarray, order: int) -> Evaluation:
        w, dw_da, dw_db, in_plane, (ca, sa, cb, sb) = self.unit_vectors(q)
        p, m_hat = self._configuration(w)
        L, K = self.n_links, self.n_vectors
        out = field_energy(self.chain, p, m_hat, self.external, self.gravity, hessian=order >= 2)
        terms, dU_dp, dU_dm = out[:3]
        u = w[:L]
        if self.sleeve_stiffness > 0.0:
            s_out = sleeve_bending(u, X_AXIS, self.sleeve_stiffness, hessian=order >= 2)
            terms.sleeve = s_out[0]
        S = p[self.pair_j] - p[self.pair_i]
        gaps = np.einsum("ij,ij->i", S, S) / self.d**2 - 1.0
        if self.wall is not None:  # every free ball on the open side: n . (p - p0) / d >= 1/2
            p0, normal = self.wall
            gaps = np.concatenate([gaps, (p[1:] - p0) @ normal / self.d - 0.5])
        E0 = self.energy_scale
        ev = Evaluation(terms.total / E0, terms, gaps)
        if self.tip_target is not None:
            ev.tip_residual = (p[-1] - self.tip_target) / self.d
        if order < 1:
            return ev
        dU_du = self.d * np.cumsum(dU_dp[:0:-1], axis=0)[::-1]
        if self.sleeve_stiffness > 0.0:
            dU_du = dU_du + s_out[1]
        g_w = np.vstack([dU_du, dU_dm[1:]])  # (K, 3)
        ev.gradient = np.concatenate(
            [np.einsum("ij,ij->i", g_w, dw_da), np.einsum("ij,ij->i", g_w, dw_db)]
        ) / E0
        jac = np.zeros((len(gaps), self.nq))
        P = self.n_pairs
        jac[:P, :L] = (2.0 / self.d) * self.pair_links * (S @ dw_da[:L].T)
        jac[:P, K : K + L] = (2.0 / self.d) * self.pair_links * (S @ dw_db[:L].T)
        if self.wall is not None:  # p_i / d = sum_{l < i} w_l: cumulative sums over the links
            normal = self.wall[1]
            jac[P:, :L] = np.tril(np.ones((L, L))) * (dw_da[:L] @ normal)
            jac[P:, K : K + L] = np.tril(np.ones((L, L))) * (dw_db[:L] @ normal)
        ev.jacobian = jac
        if self.tip_target is not None:  # p_tip / d = sum_l u_l
            ev.tip_jacobian = np.zeros((3, self.nq))
            ev.tip_jacobian[:, :L] = dw_da[:L].T
            ev.tip_jacobian[:, K : K + L] = dw_db[:L].T
        if order < 2:
            return ev
        H_pp, H_pm, H_mm = out[3]
        n = L + 1
        C3 = self._C3
        H_pp = H_pp.reshape(3 * n, 3 * n)
        H_uu = self.d**2 * (C3.T @ H_pp @ C3)
        if self.sleeve_stiffness > 0.0:
            H_uu += s_out[2].reshape(3 * L, 3 * L)
        H_um = self.d * (C3.T @ H_pm.reshape(3 * n, 3 * n)[:, 3:])
        H_ww = np.empty((6 * L, 6 * L))
        H_ww[: 3 * L, : 3 * L] = H_uu
        H_ww[: 3 * L, 3 * L :] = H_um
        H_ww[3 * L :, : 3 * L] = H_um.T
        H_ww[3 * L :, 3 * L :] = H_mm.reshape(3 * n, 3 * n)[3:, 3:]
        # Chart Jacobian as a block-diagonal (3K, 2K) matrix: column s*K + i holds dw_i/dq_s.
        Jw = np.zeros((K, 3, 2, K))
        idx = np.arange(K)
        Jw[idx, :, 0, idx] = dw_da
        Jw[idx, :, 1, idx] = dw_db
        Jw = Jw.reshape(3 * K, 2 * K)
        H = Jw.T @ H_ww @ Jw
        # Curvature of the chart: g_w . d2w/dq2, per vector.
        d_ab = np.einsum("ij,ij->i", g_w, -sb * (-sa * self.r0 + ca * self.t1))
        H[idx, idx] += np.einsum("ij,ij->i", g_w, -cb * in_plane)
        H[idx, K + idx] += d_ab
        H[K + idx, idx] += d_ab
        H[K + idx, K + idx] -= np.einsum("ij,ij->i", g_w, w)
        ev.hessian = H / E0
        return ev

    def constraint_hessian(self, q: np.ndarray, pairs: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """sum_k weights_k d2 c_k / dq2 over the given pair indices (nq, nq).

        c = |S|^2/d^2 - 1 with S = d sum_{l in span} w_l, so
        d2c/dq2 = (2/d^2) J_S^T J_S + (2/d^2) S . d2S/dq2, d2S/dq2 = d sum_l d2w_l/dq2.
        """
        H = np.zeros((self.nq, self.nq))
        if len(pairs) == 0:
            return H
        pairs, weights = np.asarray(pairs), np.asarray(weights, dtype=float)
        if self.backend == "kernel":
            return self._constraint_hessian_kernel(q, pairs, weights)
        wall_rows = pairs >= self.n_pairs
        if np.any(wall_rows):
            # Wall row for ball i (= row - n_pairs + 1) is linear in the w_l, l < i: its
            # curvature is the chart's, weighted by normal x (sum of the rows' weights beyond l).
            per_ball = np.zeros(self.n_links)
            per_ball[pairs[wall_rows] - self.n_pairs] = weights[wall_rows]
            per_link = np.cumsum(per_ball[::-1])[::-1]
            H += self.links_hessian(q, per_link[:, None] * self.wall[1])
            pairs, weights = pairs[~wall_rows], weights[~wall_rows]
            if len(pairs) == 0:
                return H
        w, dw_da, dw_db, in_plane, (ca, sa, cb, sb) = self.unit_vectors(q)
        p, _ = self._configuration(w)
        K = self.n_vectors
        d2_aa = -cb * in_plane
        d2_ab = -sb * (-sa * self.r0 + ca * self.t1)
        d2_bb = -w
        for k, weight in zip(pairs, weights):
            span = self.pair_links[k].astype(bool)
            links = np.flatnonzero(span)
            S = p[self.pair_j[k]] - p[self.pair_i[k]]
            J_S = np.zeros((3, self.nq))
            J_S[:, links] = self.d * dw_da[links].T
            J_S[:, K + links] = self.d * dw_db[links].T
            Hk = (2.0 / self.d**2) * (J_S.T @ J_S)
            s_aa = (2.0 / self.d) * (d2_aa[links] @ S)
            s_ab = (2.0 / self.d) * (d2_ab[links] @ S)
            s_bb = (2.0 / self.d) * (d2_bb[links] @ S)
            Hk[links, links] += s_aa
            Hk[links, K + links] += s_ab
            Hk[K + links, links] += s_ab
            Hk[K + links, K + links] += s_bb
            H += weight * Hk
        return H

    def _constraint_hessian_kernel(self, q, pairs, weights) -> np.ndarray:
        V = ck.chart_vectors(np.ascontiguousarray(q, dtype=float), self.r0, self.t1, self.t2)
        wall_rows = pairs >= self.n_pairs
        H = np.zeros((self.nq, self.nq))
        if np.any(wall_rows):
            # Wall row for ball i (= row - n_pairs + 1) is linear in the w_l, l < i: its
            # curvature is the chart's, weighted by normal x (sum of the rows' weights beyond l).
            per_ball = np.zeros(self.n_links)
            per_ball[pairs[wall_rows] - self.n_pairs] = weights[wall_rows]
            per_link = np.cumsum(per_ball[::-1])[::-1]
            H += ck.links_hessian(np.ascontiguousarray(per_link[:, None] * self.wall[1]), V)
        rigid = ~wall_rows
        if np.any(rigid):
            p, _ = ck.chain_configuration(V[0], self.n_links, self.d)
            H += ck.rigidity_hessian(np.ascontiguousarray(pairs[rigid], dtype=np.int64),
                                     np.ascontiguousarray(weights[rigid]), p, V, self.d)
        return H

    def tip_hessian(self, q: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """sum_k weights_k d2 (p_tip,k / d) / dq2 (nq, nq): the chart's curvature along the links."""
        return self.links_hessian(q, np.tile(np.asarray(weights, dtype=float), (self.n_links, 1)))

    def links_hessian(self, q: np.ndarray, W: np.ndarray) -> np.ndarray:
        """sum_l W_l . d2 w_l / dq2 (nq, nq) for per-link weight vectors W (L, 3)."""
        if self.backend == "kernel":
            V = ck.chart_vectors(np.ascontiguousarray(q, dtype=float), self.r0, self.t1, self.t2)
            return ck.links_hessian(np.ascontiguousarray(W, dtype=float), V)
        w, dw_da, dw_db, in_plane, (ca, sa, cb, sb) = self.unit_vectors(q)
        K, L = self.n_vectors, self.n_links
        links = np.arange(L)
        H = np.zeros((self.nq, self.nq))
        d_ab = np.einsum("ij,ij->i", -sb[:L] * (-sa[:L] * self.r0[:L] + ca[:L] * self.t1[:L]), W)
        H[links, links] = np.einsum("ij,ij->i", -cb[:L] * in_plane[:L], W)
        H[links, K + links] = d_ab
        H[K + links, links] = d_ab
        H[K + links, K + links] = -np.einsum("ij,ij->i", w[:L], W)
        return H


def answer_verdict(model, p: np.ndarray, m_hat: np.ndarray, total: float, row_gaps, converged: bool,
                   reason: str) -> tuple[bool, str, float]:
    """A solver's answer judged on its own numbers: ``(converged, reason, max_violation [m])``,
    converged overruled (with the reason) by a non-finite configuration or energy, or by a
    rigidity or wall row violated by more than 1e-7 of a ball diameter.

    ``row_gaps``: the rows' values (``Evaluation.gaps``): rigidity rows first (``model.n_pairs``),
    then wall rows."""
    P, d = model.n_pairs, model.d
    # The smallest gap [m]: rigidity rows |p_j - p_i| - d (monotone in c_ij: its smallest),
    # then wall rows n . (p - p0) - d/2.
    smallest = [float(np.sqrt(max(row_gaps[:P].min() + 1.0, 0.0)) * d - d)] if P else []
    if len(row_gaps) > P:
        smallest.append(float(row_gaps[P:].min() * d))
    max_violation = max(0.0, -min(smallest)) if smallest else 0.0
    if not (np.isfinite(p).all() and np.isfinite(m_hat).all()):
        converged, reason = False, "non-finite configuration"
    elif not np.isfinite(total):
        converged, reason = False, f"non-finite energy ({total}) at the solver's answer"
    elif converged and max_violation > 1e-7 * d:
        converged, reason = False, f"rigidity or wall violated by {max_violation:.3g} m"
    return converged, reason, max_violation
