"""The chain in the heart for the statics: the atrium's wall and the sheath as constraint rows.

The statics' canonical problem (ball 1 held at the origin, dipole along +x; ``reduced_chain``)
is the chain in the heart seen from the sheath: frame B has its origin at the centre of the
*held ball*, the last ball still inside the sheath's bore, and its +x along the sheath axis.
Everything that is not in the canonical problem enters here:

* Insertion (``sheath_split``): the feeder pushes ball 1 along the axis (``chain_plant``: ball i,
  0-based, sits ``s - (n - 1/2 - i) d`` along the axis from the sheath exit at inserted length
  s). The balls whose centres are past the exit plane are free; so are the last ``free_in_bore``
  balls before it (default 1, ``base_ball``): in the plant they can turn their dipoles and move
  within the bore's clearance, and the sheath rows hold them there. The ball behind them is the
  canonical problem's ball 1 (held, its position the fractional part of the insertion); the
  balls behind it are a straight chain of dipoles inside the sheath whose field acts on the
  others (``PointDipoles``).
* The external field and gravity are turned into frame B (``FieldInFrame``; gravity along
  R_WB^T (-z_W) is added to the energy by ``ConstrainedChain``).
* Wall rows, one per free ball: ``c = (sdf(p_k) - r) / d >= 0``, the ball's centre at least a
  radius inside the lumen (``drake_models.atrium_sdf``). The wall is frictionless: its push on
  ball k is the row's multiplier along the SDF's gradient (the normal), nothing tangential. A ball
  in the bore (behind the exit plane and within r_c of the axis) has none: the sheath holds it, and
  the SDF sees the septal puncture as closed wall. A ball behind the exit plane but outside the
  sheath (a chain curled back beside it) has its wall row like any other.
* Sheath rows, one per free ball: the sheath is a tube of bore radius R whose wall ends in a
  rounded lip (the collision cage's rods, radius r_rod, centres at r_c = R + r_rod around the
  axis, ending at the exit plane). A ball may not overlap it:
  ``g = (rho - r_c)^2 + max(a, 0)^2 - (r + r_rod)^2 >= 0`` with a the ball centre's distance
  past the exit plane and rho its distance from the axis (smoothed at the axis). For a <= 0
  this keeps a ball in the bore (rho <= R - r) and one beside the sheath outside it
  (rho >= r_c + r + r_rod), for a > 0 off the lip; it is C1 across the
  exit plane, written in squared form so that its gradient never vanishes or jumps (a plain
  tangent plane per ball made the solves fail).

All rows are dimensionless like the rigidity rows, so the solver's margins and tolerances apply.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ballchain.drake_models.dipole import dipole_field, dipole_field_gradient
from ballchain.drake_models.field_sources import (FieldSource, FieldSources, MagnetSource, UniformField,
                                                  rotation_with_z_along)
from ballchain.drake_models.params import GRAVITY, BallChain
from ballchain.optimization.reduced_chain import Evaluation, ReducedChain

RHO_SMOOTHING = 1e-6  # [m]: rho = sqrt(|x_perp|^2 + eps^2), smooth on the axis


@dataclass
class SheathGeometry:
    """The sheath tube as the statics sees it (world frame W).

    Attributes:
        p_WE: (3,) centre of the exit plane [m].
        axis_W: (3,) unit insertion direction.
        bore_radius: inner radius R [m].
        lip_radius: radius of the lip (half the tube wall) [m].
    """

    p_WE: np.ndarray
    axis_W: np.ndarray
    bore_radius: float
    lip_radius: float


def sheath_split(n_balls: int, inserted_length: float, d: float) -> tuple[int, float]:
    """Which ball is held and where, for an inserted length s.

    Returns:
        ``(k, a)``: the held ball's 0-based index (balls k+1..n-1 are free) and its centre's
        position along the axis past the exit plane [m] (in (-d, 0]).
    """
    along = inserted_length - (n_balls - 0.5 - np.arange(n_balls)) * d
    inside = np.flatnonzero(along <= 1e-12)
    k = int(inside[-1]) if len(inside) else 0
    return k, float(along[k])


def base_ball(n_balls: int, inserted_length: float, d: float, free_in_bore: int = 1) -> tuple[int, float]:
    """The sub-chain's held ball for an inserted length s: ``free_in_bore`` balls behind the last
    ball in the bore (``sheath_split``), or ball 1.

    Returns:
        ``(b, a)``: its 0-based index and its centre's position past the exit plane [m].
    """
    k, a = sheath_split(n_balls, inserted_length, d)
    b = max(k - free_in_bore, 0)
    return b, a - (k - b) * d


def base_rotation(axis_W) -> np.ndarray:
    """R_WB (3, 3) with its first column along the sheath axis (the other two as chain_plant's
    feeder frame, so the canonical chart's out-of-plane direction is deterministic)."""
    return rotation_with_z_along(axis_W)[:, [2, 0, 1]]


class FieldInFrame:
    """A world FieldSource seen in frame B: B_B(p_B) = R_WB^T B_W(p_WB + R_WB p_B)."""

    def __init__(self, source: FieldSource, p_WB: np.ndarray, R_WB: np.ndarray):
        self.source, self.p_WB, self.R_WB = source, np.asarray(p_WB, float), np.asarray(R_WB, float)

    def field_and_gradient(self, p_B):
        p_W = self.p_WB + np.asarray(p_B, float).reshape(-1, 3) @ self.R_WB.T
        B_W, G_W = self.source.field_and_gradient(p_W)
        R = self.R_WB
        return B_W @ R, np.einsum("ia,kij,jb->kab", R, G_W, R)


class PointDipoles:
    """Point dipoles (centres p (k, 3) [m], moments m (k, 3) [A m^2]) plus a uniform field B0
    (3,) [T]: a FieldSource. In frame B it holds the balls behind the held ball (straight along
    -x in the sheath) and the point-dipole magnets and uniform fields of the scenario, turned
    into B, all in one evaluation."""

    def __init__(self, p: np.ndarray, m: np.ndarray, B0=None):
        self.p = np.asarray(p, float).reshape(-1, 3)
        self.m = np.asarray(m, float).reshape(-1, 3)
        self.B0 = np.zeros(3) if B0 is None else np.asarray(B0, float)

    def field_and_gradient(self, p_B):
        p_B = np.ascontiguousarray(np.asarray(p_B, float).reshape(-1, 3))
        if _dipole_kernel is not None and len(self.p):
            # The same law as dipole.dipole_field(_gradient), compiled (drake_models.kernels).
            status, B, G = _dipole_kernel(p_B, np.ascontiguousarray(self.p), np.ascontiguousarray(self.m),
                                          np.zeros(len(self.p)))
            if status < 0:
                return self.B0 + B, G
        r = p_B[:, None, :] - self.p[None]
        m = np.broadcast_to(self.m, r.shape)
        return self.B0 + dipole_field(r, m).sum(axis=1), dipole_field_gradient(r, m).sum(axis=1)


try:  # the compiled point-dipole law when the kernels are there; numpy (dipole.py) otherwise
    from ballchain.drake_models.kernels import dipole_field_and_gradient as _dipole_kernel
except ImportError:  # pragma: no cover - depends on the branch
    _dipole_kernel = None


class StackedJacobian:
    """The rigidity rows' Jacobian (an array, or a row-on-demand object such as the kernels'
    ``ConstraintJacobian``) with the wall and sheath rows below it: indexing with an array of
    row numbers builds only those rows, as the statics asks for the rows near contact."""

    def __init__(self, base, rows: np.ndarray):
        self.base, self.rows, self.n_base = base, rows, len(base)

    def __len__(self) -> int:
        return self.n_base + len(self.rows)

    def __getitem__(self, index):
        if isinstance(index, tuple):
            return np.asarray(self)[index]
        idx = np.arange(len(self))[index] if not isinstance(index, np.ndarray) or index.dtype == bool \
            else np.asarray(index, int)
        idx = np.atleast_1d(idx)
        out = np.empty((len(idx), self.rows.shape[1]))
        mine = idx >= self.n_base
        if np.any(~mine):
            out[~mine] = np.asarray(self.base[idx[~mine]])
        out[mine] = self.rows[idx[mine] - self.n_base]
        return out

    def __array__(self, dtype=None, copy=None):
        full = np.vstack([np.asarray(self.base), self.rows])
        return full if dtype is None else full.astype(dtype)

    @property
    def T(self) -> np.ndarray:
        return np.asarray(self).T


def _point_dipoles_W(source) -> tuple[list, list, np.ndarray] | None:
    """(centres, moments, uniform B) [SI, world] of a source made only of point dipoles and
    uniform fields (MagnetSource with model "dipole", any object with ``p_WM`` and ``m_W`` arrays
    such as the wrench's PortDipoles, UniformField, sums of them), else None."""
    if isinstance(source, FieldSources):
        p, m, B = [], [], np.zeros(3)
        for s in source.sources:
            part = _point_dipoles_W(s)
            if part is None:
                return None
            p += part[0]
            m += part[1]
            B = B + part[2]
        return p, m, B
    if isinstance(source, UniformField):
        return [], [], np.asarray(source.B_W, float)
    if isinstance(source, MagnetSource):
        return ([source.p_WM], [source.m_W], np.zeros(3)) if source.model == "dipole" else None
    if hasattr(source, "p_WM") and hasattr(source, "m_W"):  # PortDipoles: all point dipoles
        return list(np.atleast_2d(source.p_WM)), list(np.atleast_2d(source.m_W)), np.zeros(3)
    return None


@functools.lru_cache(maxsize=64)
def _behind_B(n_behind: int, d: float, moment: float) -> tuple[np.ndarray, np.ndarray]:
    """The balls behind the held ball in frame B (straight along -x, d apart): centres and
    moments (n_behind, 3), read-only (shared by every solve with these values)."""
    p = -d * np.arange(1, n_behind + 1)[:, None] * np.array([1.0, 0.0, 0.0])
    m = np.tile([moment, 0.0, 0.0], (n_behind, 1))
    p.flags.writeable = m.flags.writeable = False
    return p, m


@dataclass
class HeartConstraints:
    """Where the sub-chain is and what holds it (one solve's worth).

    Attributes:
        p_WB: (3,) the held ball's centre [m]; R_WB: (3, 3) frame B (x along the sheath axis).
        sdf: the atrium's AtriumSDF, or None (no wall).
        sheath: SheathGeometry, or None (no sheath rows).
        n_behind: balls inside the sheath behind the held ball (their dipoles act).
        gravity: gravity along -z_W.
    """

    p_WB: np.ndarray
    R_WB: np.ndarray
    sdf: object = None
    sheath: SheathGeometry | None = None
    n_behind: int = 0
    gravity: bool = True

    def to_world(self, positions_B: np.ndarray, dipoles_B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.p_WB + positions_B @ self.R_WB.T, dipoles_B @ self.R_WB.T

    def full_configuration(self, positions_B: np.ndarray, dipoles_B: np.ndarray, d: float) -> tuple[np.ndarray, np.ndarray]:
        """All balls in world [m] (the ``n_behind`` in the sheath first, straight behind the held
        ball d apart, then the sub-chain), and their dipole directions."""
        p_W, m_W = self.to_world(positions_B, dipoles_B)
        axis = self.R_WB[:, 0]
        behind = self.p_WB - np.arange(self.n_behind, 0, -1)[:, None] * d * axis
        return np.concatenate([behind, p_W]), np.concatenate([np.tile(axis, (self.n_behind, 1)), m_W])

    def to_base(self, positions_W: np.ndarray, dipoles_W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (positions_W - self.p_WB) @ self.R_WB, dipoles_W @ self.R_WB

    def external_in_base(self, external_W: FieldSource | None, chain: BallChain) -> FieldSource | None:
        """The field on the sub-chain in frame B: the external source and the balls behind."""
        p_behind, m_behind = _behind_B(self.n_behind, chain.ball_diameter, chain.dipole_moment)
        parts = ([], [], np.zeros(3)) if external_W is None else _point_dipoles_W(external_W)
        if parts is not None:  # one evaluation for everything
            p_W, m_W, B_W = parts
            p = np.concatenate([p_behind] + [((np.asarray(x) - self.p_WB) @ self.R_WB)[None] for x in p_W])
            m = np.concatenate([m_behind] + [(np.asarray(x) @ self.R_WB)[None] for x in m_W])
            if len(p) == 0 and not np.any(B_W):
                return None
            return PointDipoles(p, m, B_W @ self.R_WB)
        sources = [FieldInFrame(external_W, self.p_WB, self.R_WB)]
        if self.n_behind:
            sources.append(PointDipoles(p_behind.copy(), m_behind.copy()))
        return sources[0] if len(sources) == 1 else FieldSources(sources)


class ConstrainedChain(ReducedChain):
    """A ReducedChain (no gravity of its own) with gravity along any direction and the wall and
    sheath rows of ``HeartConstraints`` appended after the rigidity rows.

    Rows: ``n_pairs`` rigidity rows, then one wall row per free ball (balls 1..L of the
    sub-chain), then one sheath row per free ball. Only the public interface of ReducedChain is
    used (``evaluate``, ``unit_vectors``, ``configuration``, ``links_hessian``,
    ``constraint_hessian`` for the rigidity rows).
    """

    def __init__(self, chain: BallChain):
        super().__init__(chain, None, gravity=False)
        self.constraints: HeartConstraints | None = None
        self._cache = None
        self.r = 0.5 * chain.ball_diameter

    def set_constraints(self, constraints: HeartConstraints) -> None:
        self.constraints = constraints
        self._cache = None
        self._last = None

    def set_chart(self, w0: np.ndarray) -> None:
        super().set_chart(w0)
        self._cache = None

    @property
    def wall_rows(self) -> slice:
        return slice(self.n_pairs, self.n_pairs + self.n_links)

    @property
    def sheath_rows(self) -> slice:
        return slice(self.n_pairs + self.n_links, self.n_pairs + 2 * self.n_links)

    # --- rows ------------------------------------------------------------------------------------
    def _rows(self, p_B: np.ndarray, hessian: bool):
        """(values (2L,), v (2L, 3), M (2L, 3, 3) or None) of the wall and sheath rows at the free
        balls' centres p_B (L, 3): c_k = f_k / scale, dc/dq = v_k . sum_{l<k} dw_l/dq, and
        d2c/dq2 = T_k^T M_k T_k + v_k . sum_{l<k} d2w_l/dq2 (see ``constraint_hessian``)."""
        c = self.constraints
        L, d, r = self.n_links, self.d, self.r
        values = np.full(2 * L, 10.0)  # rows without a constraint: far from active
        v = np.zeros((2 * L, 3))
        M = np.zeros((2 * L, 3, 3)) if hessian else None
        if c.sdf is not None:
            p_W = c.p_WB + p_B @ c.R_WB.T
            out = c.sdf(p_W, gradient=True, hessian=hessian)
            s, grad_W = out[0], out[1]
            wall = np.ones(L, bool)
            if c.sheath is not None:
                # Balls still in the bore (behind the exit plane, within r_c of the axis) have no
                # wall row: the sheath holds them, and the SDF's inside test sees the septal
                # puncture as closed wall. A ball curled back beside the sheath has one.
                r_c = c.sheath.bore_radius + c.sheath.lip_radius
                wall = ((p_B[:, 0] > float((c.sheath.p_WE - c.p_WB) @ c.R_WB[:, 0]))
                        | (p_B[:, 1] ** 2 + p_B[:, 2] ** 2 >= r_c**2))
            values[:L] = np.where(wall, (s - r) / d, 10.0)
            v[:L] = np.where(wall[:, None], grad_W @ c.R_WB, 0.0)  # c = (s - r)/d, dc/dp = grad/d
            if hessian:
                M[:L] = wall[:, None, None] * d * np.einsum("ia,kij,jb->kab", c.R_WB, out[2], c.R_WB)
        if c.sheath is not None:
            sh = c.sheath
            a_E = float((sh.p_WE - c.p_WB) @ c.R_WB[:, 0])  # exit plane along x_B
            r_c = sh.bore_radius + sh.lip_radius
            reach = r + sh.lip_radius
            a = p_B[:, 0] - a_E
            perp = p_B[:, 1:]
            rho = np.sqrt((perp**2).sum(axis=1) + RHO_SMOOTHING**2)
            ap = np.maximum(a, 0.0)
            g = (rho - r_c) ** 2 + ap**2 - reach**2
            values[L:] = g / d**2
            dg = np.zeros((L, 3))
            dg[:, 0] = 2.0 * ap
            dg[:, 1:] = 2.0 * ((rho - r_c) / rho)[:, None] * perp
            v[L:] = dg / d  # c = g / d^2
            if hessian:
                e = perp / rho[:, None]
                Hg = np.zeros((L, 3, 3))
                Hg[:, 0, 0] = 2.0 * (a > 0)
                Hg[:, 1:, 1:] = 2.0 * (e[:, :, None] * e[:, None, :] + ((rho - r_c) / rho)[:, None, None]
                                       * (np.eye(2) - e[:, :, None] * e[:, None, :]))
                M[L:] = Hg
        return values, v, M

    # --- evaluation --------------------------------------------------------------------------------
    def evaluate(self, q: np.ndarray, order: int = 2) -> Evaluation:
        key = q.tobytes()
        if self._cache is not None and self._cache[0] == key and self._cache[1] >= order:
            return self._cache[2]
        base = ReducedChain.evaluate(self, q, order)
        ev = Evaluation(base.energy, base.terms, base.gaps, base.gradient, base.jacobian, base.hessian,
                        base.tip_residual, base.tip_jacobian)
        c = self.constraints
        w, dw_da, dw_db, *_ = self.unit_vectors(q)
        L, K, E0, d = self.n_links, self.n_vectors, self.energy_scale, self.d
        p_B = self._configuration(w)[0]
        if c.gravity:  # U_g = sum_k m g z_W(p_k) = const + d sum_l (L - l) c_g . w_l
            c_g = self.chain.ball_mass * GRAVITY * c.R_WB[2]  # R_WB^T z_W
            U_g = self.chain.ball_mass * GRAVITY * float((c.p_WB[2] * (L + 1)) + (p_B @ c.R_WB[2]).sum())
            ev.terms = type(base.terms)(base.terms.balls, base.terms.external, base.terms.sleeve, U_g)
            ev.energy = ev.terms.total / E0
            W_g = d * (L - np.arange(L))[:, None] * c_g  # (L, 3) per-link weights
            if order >= 1:
                ev.gradient = ev.gradient.copy()
                ev.gradient[:L] += np.einsum("ij,ij->i", W_g, dw_da[:L]) / E0
                ev.gradient[K:K + L] += np.einsum("ij,ij->i", W_g, dw_db[:L]) / E0
            if order >= 2:
                ev.hessian = ev.hessian + self.links_hessian(q, W_g) / E0
        values, v, _ = self._rows(p_B[1:], hessian=False)
        ev.gaps = np.concatenate([base.gaps, values])
        if order >= 1:
            tri = np.tril(np.ones((L, L)))
            rows = np.zeros((2 * L, self.nq))
            for part in (slice(0, L), slice(L, 2 * L)):
                rows[part, :L] = tri * (v[part] @ dw_da[:L].T)
                rows[part, K:K + L] = tri * (v[part] @ dw_db[:L].T)
            ev.jacobian = StackedJacobian(base.jacobian, rows)
        self._cache = (key, order, ev)
        return ev

    def constraint_hessian(self, q: np.ndarray, pairs: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """sum_k weights_k d2 c_k / dq2 over rigidity, wall and sheath rows (nq, nq)."""
        pairs, weights = np.asarray(pairs, int), np.asarray(weights, float)
        mine = pairs >= self.n_pairs
        H = ReducedChain.constraint_hessian(self, q, pairs[~mine], weights[~mine])
        if not np.any(mine):
            return H
        L, K = self.n_links, self.n_vectors
        w, dw_da, dw_db, *_ = self.unit_vectors(q)
        p_B = self._configuration(w)[0]
        _, v, M = self._rows(p_B[1:], hessian=True)
        rows, wts = pairs[mine] - self.n_pairs, weights[mine]
        ball = rows % L  # free ball index - 1
        # Curvature of the chart: per-link weights sum over the rows of the balls beyond the link.
        per_ball = np.zeros((L, 3))
        np.add.at(per_ball, ball, wts[:, None] * v[rows])
        per_link = np.cumsum(per_ball[::-1], axis=0)[::-1]
        H += self.links_hessian(q, per_link)
        for row, b, wt in zip(rows, ball, wts):
            T = np.zeros((3, self.nq))
            T[:, : b + 1] = dw_da[: b + 1].T
            T[:, K : K + b + 1] = dw_db[: b + 1].T
            H += wt * (T.T @ M[row] @ T)
        return H

    def forces_at(self, q: np.ndarray, lam_near: dict) -> tuple[dict, dict]:
        """The wall's and the sheath's push on each free ball at chart coordinates q, in world [N]:
        ``({ball: f_W (3,)}, {ball: f_W (3,)})``, ball 0-based in the sub-chain, from the
        statics' multipliers ``lam_near`` (row -> multiplier). Frictionless: along the rows'
        gradients (the wall's normal), nothing tangential."""
        w = self.unit_vectors(q)[0]
        p_B = self._configuration(w)[0]
        _, v, _ = self._rows(p_B[1:], hessian=False)
        return self.forces_of_rows(v, lam_near)

    def forces_of_rows(self, v: np.ndarray, lam_near: dict) -> tuple[dict, dict]:
        """``forces_at`` from the rows' gradients v (2L, 3) through the centres (``_rows``)."""
        L = self.n_links
        E0, d, R = self.energy_scale, self.d, self.constraints.R_WB
        wall, sheath = {}, {}
        for k, lam in lam_near.items():
            if k < self.n_pairs or lam <= 1e-12:
                continue
            row = k - self.n_pairs
            (wall if row < L else sheath)[row % L + 1] = row_force_W(R, v[row], lam, E0, d)
        return wall, sheath


def row_force_W(R_WB: np.ndarray, v_row: np.ndarray, lam: float, E0: float, d: float) -> np.ndarray:
    """A wall or sheath row's push on its ball in world [N] from its multiplier lam (scaled by the
    energy scale E0): lambda E0 dc/dp with dc/dp = v / d (both row kinds, see ``_rows``), turned
    from frame B by R_WB."""
    return R_WB @ (lam * E0 * v_row / d)


class PlaneSDF:
    """A flat wall as a signed distance: ``n . (p - p0)`` (> 0 on the free side), for the statics'
    wall rows in free space (``chain_plant``'s ``wall_plane``: a point on the surface and the
    outward normal, pointing to where the chain is)."""

    def __init__(self, point, normal):
        self.point = np.asarray(point, float).reshape(3)
        n = np.asarray(normal, float).reshape(3)
        self.normal = n / np.linalg.norm(n)

    def translated(self, offset) -> "PlaneSDF":
        """The same wall moved rigidly by ``offset`` (3,) [m] (``wall_motion``)."""
        return PlaneSDF(self.point + np.asarray(offset, float), self.normal)

    def __call__(self, p, gradient: bool = True, hessian: bool = False):
        p = np.atleast_2d(np.asarray(p, float))
        s = (p - self.point) @ self.normal
        if not gradient and not hessian:
            return s
        g = np.tile(self.normal, (len(p), 1))
        return (s, g, np.zeros((len(p), 3, 3))) if hessian else (s, g)
