"""A compliant atrial wall for the steerable catheter's rod (issue 45: with a rigid wall no loaded
curve reaches right_15-17, and any push past contact costs >= 4.5 N; the tissue gives millimetres
where the rigid wall gives newtons).

``RodStatics`` (``optimization.rod_statics``) holds every free node at least the rod's radius
inside the lumen, sdf(p) >= r: a rigid wall. ``CompliantRodStatics`` lets every free node indent
the wall by d = r - sdf(p) > 0 against a linear normal reaction

    N = k d,   the penalty energy  E_wall = sum_m k d_m^2 / 2  (d_m = max(r - sdf(p_m), 0))

added to the rod's elastic energy, with its exact gradient, dE_wall/dq = -sum_m k d_m grad
sdf(p_m)^T J_m, and its Gauss-Newton Hessian, sum_m k J_m^T grad sdf grad sdf^T J_m (the term
k d_m times the wall's and the chain's curvature is left out: it is of the order of d / r against
the kept one, and the SQP's line search on the exact energy keeps the steps descending).

* **Every free node is compliant**, the tip sphere's centre and the shaft's joints alike: the
  tissue under a shaft bearing on the wall is the same tissue as under the tip. The stiffness is
  per node: the source's k is a catheter tip's (a 2.7 mm dome pressed in), and a node stands for
  h = 3 mm of shaft, of about the same contact width and length; a shaft lying along the wall
  over several nodes is therefore about as stiff per node as a tip (a stated approximation, not a
  measured line stiffness). Not counted: the first joint (at the sheath exit, moved by no joint)
  and the last joint, h / 2 - r = 0.17 mm behind the tip sphere's centre inside the same
  electrode (counting it would double the tip's stiffness; the hard limit still holds it).
* **The rigid wall stays a hard limit beyond ``INDENTATION_CAP``** (sdf(p) >= r - cap, the SQP's
  linearised rows as for the rigid wall, their multipliers added to the node's reaction): the
  atrium's signed-distance grid reaches 2 mm beyond the surface's bounding box
  (``drake_models.atrium_sdf``: ``margin``), so a deeper node could leave it; and the shared touch
  rule (``drake_models.electrode``: the dome's centre within r + 0.5 mm of the wall's plane, on
  either side) holds an electrode indented by up to 2 r + 0.5 = 3.17 mm as touching without
  change: 3 mm keeps both. Ijima et al.'s tip indented 0.7 mm at 10 g and 6.9 mm at 80 g, about
  3.4 mm at 40 g (0.39 N, Matsuda et al.'s excessive force) by their two ends: at k = 0.1 N/mm the
  cap is met at 0.30 N, at 0.14 N/mm at 0.42 N. ``RodSolution.hard_forces`` says how much of a
  node's reaction the hard limit carries.

The source of k: Ijima et al. (ex vivo, the catheter tip inserted perpendicularly into porcine
heart samples, contact forces 10-80 g; the abstract only was read here, the LILACS/BVS record):
"a strong correlation between the CF and insertion depth (ID) (R2 = 0.96, P < 0.001), from 0.7 +-
0.3 mm at 10 g to 6.9 +- 0.1 mm at 80 g". The secant stiffnesses are 0.140 N/mm at 10 g and
0.114 N/mm at 80 g, the chord between them 0.111 N/mm; the abstract gives no fit (their model is
a 3-parameter Mooney-Rivlin solid whose constants the abstract does not give), so the law here is
linear and k is swept over 0.1-0.14 N/mm and a stiffer bound (``SteerableCatheter.wall_stiffness``;
``docs/guide/manual_catheter.md``: the range run).

The wall is frictionless here; ``systems.rod_wall_friction.CompliantFrictionalRodStatics`` adds the
tip's Coulomb friction on it (issue 45, H12: the cone on N = k d).
"""

from __future__ import annotations

import numpy as np

from ballchain.optimization.rod_statics import RodSolution, RodStatics

INDENTATION_CAP = 3e-3  # [m] beyond it the wall is rigid (module docstring)


class CompliantRodStatics(RodStatics):
    """``RodStatics`` on a compliant wall (module docstring).

    Args:
        catheter, p_E, axis, sdf: as ``RodStatics``.
        stiffness: the wall's normal stiffness k per node [N/m] (default ``catheter.wall_stiffness``);
            0: the rigid wall, exactly ``RodStatics``.
        cap: the deepest indentation before the hard limit [m] (default ``INDENTATION_CAP``).
    """

    # True while a step is taken on a Hessian that already holds the penalty's (the frictional
    # subclass's stuck step, ``rod_wall_friction.CompliantFrictionalRodStatics``): not added again.
    _penalty_in_H = False

    def __init__(self, catheter, p_E, axis, sdf=None, stiffness: float | None = None,
                 cap: float | None = None) -> None:
        super().__init__(catheter, p_E, axis, sdf)
        self.k = float(catheter.wall_stiffness if stiffness is None else stiffness)
        if not (np.isfinite(self.k) and self.k >= 0.0):
            raise ValueError(f"CompliantRodStatics stiffness must be finite and >= 0 [N/m], got {self.k}")
        self.cap = float(INDENTATION_CAP if cap is None else cap)
        if not (np.isfinite(self.cap) and 0.0 < self.cap):
            raise ValueError(f"CompliantRodStatics cap must be > 0 [m], got {self.cap}")

    @property
    def compliant(self) -> bool:
        return self.k > 0.0 and self.sdf is not None

    # -------------------------------------------------------------- the penalty
    def indentation(self, pose) -> tuple[np.ndarray, np.ndarray]:
        """Each free node's indentation d = max(r - sdf, 0) [m] (0 at the first joint, which no
        joint moves, and at the last, inside the electrode: module docstring) and the sdf's
        gradients (m, 3)."""
        values, grads = self.wall_at(pose)
        d = np.maximum(self.catheter.radius - values, 0.0)
        d[0] = 0.0
        if len(d) > 1:
            d[-2] = 0.0  # the last joint: within the electrode, 0.17 mm behind the tip sphere's centre
        return d, grads

    def wall_energy(self, pose) -> float:
        """sum k d^2 / 2 [J]."""
        d = self.indentation(pose)[0]
        return 0.5 * self.k * float(d @ d)

    def wall_reactions(self, pose) -> np.ndarray:
        """The compliant wall's force on each node, k d grad sdf (m, 3) [N] (into the lumen)."""
        d, grads = self.indentation(pose)
        return (self.k * d)[:, None] * grads

    def gradient(self, q, length, phi, kappa, force=None, torque=None):
        g = super().gradient(q, length, phi, kappa, force, torque)
        if not self.compliant:
            return g
        pose = self.pose(q, length, phi)
        f = self.wall_reactions(pose)
        touching = np.flatnonzero(np.abs(f).sum(axis=1) > 0.0)
        for m in touching:  # dE/dq = -sum k d grad^T J
            g = g - pose.J[m].T @ f[m]
        return g

    def penalty_hessian(self, pose) -> np.ndarray:
        """The penalty's Gauss-Newton Hessian, sum k J^T grad grad^T J over the indented nodes."""
        d, grads = self.indentation(pose)
        n = pose.J.shape[2]
        rows = [grads[m] @ pose.J[m] for m in np.flatnonzero(d > 0.0)]
        if not rows:
            return np.zeros((n, n))
        A = np.vstack(rows)
        return self.k * (A.T @ A)

    # -------------------------------------------------------------- the SQP's pieces
    def _wall_rows(self, pose):
        """The hard limit's rows, sdf - r + cap >= 0 (the rigid wall's when not compliant)."""
        A, b, grads = super()._wall_rows(pose)
        return (A, b + self.cap, grads) if self.compliant else (A, b, grads)

    def _merit(self, q, length, phi, kappa, force, rho: float) -> float:
        """The energy with the wall's penalty, less a tip force's work, plus rho times the hard
        limit's violation."""
        if not self.compliant:
            return super()._merit(q, length, phi, kappa, force, rho)
        j0 = self.first_free(length)
        pose = self.pose(q, length, phi)
        value = self.energy(q, j0, kappa, length) + self.wall_energy(pose)
        if force is not None:
            value -= float(np.asarray(force, float) @ pose.tip_centre)
        gaps = self.wall_at(pose)[0] - self.catheter.radius + self.cap
        return value + rho * float(np.maximum(-gaps, 0.0).sum())

    def _step(self, q, H, g, length, phi):
        if not self.compliant or self._penalty_in_H:
            return super()._step(q, H, g, length, phi)
        return super()._step(q, H + self.penalty_hessian(self.pose(q, length, phi)), g, length, phi)

    def solve(self, length: float, phi: float, kappa: float, q0=None, force=None, torque=None,
              **kwargs) -> RodSolution:
        """``RodStatics.solve`` on the compliant wall: the solution's ``wall_forces`` are each
        node's whole normal reaction (k d plus the hard limit's), its exit torque and axial force
        include the compliant wall's; it adds ``indentation`` ((m,) [m]) and ``hard_forces`` ((m,)
        [N], the hard limit's share)."""
        sol = super().solve(length, phi, kappa, q0, force, torque, **kwargs)
        pose = sol.pose
        if not self.compliant:
            sol.indentation, sol.hard_forces = np.zeros(len(pose.nodes)), sol.wall_forces.copy()
            return sol
        d, grads = self.indentation(pose)
        f = (self.k * d)[:, None] * grads
        sol.hard_forces = sol.wall_forces.copy()
        sol.wall_forces = sol.wall_forces + self.k * d
        sol.indentation = d
        if f.any():
            moments = np.cross(pose.nodes - self.p_E, f)
            sol.base_torque += float(moments.sum(axis=0) @ self.R_E[:, 2])
            sol.base_force += float(f.sum(axis=0) @ self.R_E[:, 2])
        return sol
