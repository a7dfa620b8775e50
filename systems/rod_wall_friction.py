"""Coulomb friction where the steerable catheter's rod touches the atrium's wall (issue 45: the
prolapse needs a tip that catches on the wall instead of sliding along it).

``RodStatics`` (``optimization.rod_statics``) holds every free node at least the rod's radius
inside the lumen, the wall frictionless. ``FrictionalRodStatics`` adds a quasi-static Coulomb law
at the nodes in contact (the tip sphere's centre, the electrode's dome, and the shaft's joints):

* A node that touched the wall at the last update (its *anchor*, a world point, kept by the
  caller between updates: ``anchors``) sticks: the solve holds it on the wall's normal line
  through the anchor (two linear rows T (p - a) = 0, T the wall's tangent plane at the anchor,
  beside its normal row sdf(p) >= r), and the rows' multipliers are the wall's tangential
  reaction on the node, f_t = T' mu.
* While |f_t| <= mu_wall N (N the node's normal reaction) it stays stuck. Beyond it the node
  slips: its stick rows are dropped and the wall's friction on it becomes an applied force of
  magnitude mu_wall N against its slip (first the direction of the reaction that would have
  held it, then the direction it moved from its anchor), solved again until the slipping nodes'
  forces settle (``max_rounds``). A stuck node that its rows hold off the wall (N = 0: the rod
  pulls it along, not into the wall) slips likewise; a slipping node whose N vanishes has no
  friction.
* A node that comes into contact during the update (from ``last_nodes``) is stuck where it met
  the wall, its last position moved along the wall's normal onto it (``_touch_point``), and then
  follows the same law; a node with no last position (the first solve) slides frictionlessly and
  sticks where it ended from the next update. The law is incremental: exact as the update's step
  goes to zero (the hand moves the rod by at most 1 mm an update).

One coefficient (static = kinetic): the law has no stick-slip of its own. The solution carries
the anchors for the next update (``RodSolution.anchors``, keyed by the node's material point:
joint index, the tip sphere's centre ``n_joints``) and the wall's tangential force on each free
node (``RodSolution.friction``, (m, 3) [N]); its torque and axial force on the shaft at the exit
include the friction's. The exact penalty of the SQP's line search (``RodStatics._merit``) adds
the stick rows' violation and the applied forces' work.

mu_wall: no measured coefficient of a catheter on endocardium was found in the reference
material here; catheter-on-vessel friction has been measured on porcine aorta (Takashima et
al., Tribology International 40:319, 2007; Lin et al., Sci. Rep. 10:11855, 2020: it depends on
the load, the sliding speed and the endothelial glycocalyx), but their figures could not be
read here. ``SteerableCatheter.wall_mu`` is therefore an assumption (docs/guide/manual_catheter.md:
the range tried).
"""

from __future__ import annotations

import numpy as np

from ballchain.optimization.rod_statics import RodSolution, RodStatics
from ballchain.systems.rod_wall_compliance import CompliantRodStatics


FRICTION_NODES = ("tip", "all")
POLISH_STEP = 1e-5  # [rad] below it a stuck rod's SQP step that does not lower the merit ends the solve


def tangent_basis(normal) -> np.ndarray:
    """(2, 3): two orthonormal rows normal to ``normal`` (unit or not)."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(n, ref)
    t1 /= np.linalg.norm(t1)
    return np.vstack([t1, np.cross(n, t1)])


class FrictionalRodStatics(RodStatics):
    """``RodStatics`` with Coulomb friction at the wall (module docstring).

    Args:
        catheter, p_E, axis, sdf: as ``RodStatics``.
        mu: the wall's friction coefficient (default ``catheter.wall_mu``).
        max_rounds: the stick/slip rounds of one solve.
        nodes: "tip" (the friction at the tip sphere's centre only, the electrode's dome: the
            shaft's joints on the wall frictionless) or "all" (every free node). Two joints stuck
            on the wall hold the rigid segments between them (the rod is inextensible): the
            stuck shaft jams, its QP rows often infeasible, and the solve falls back to the
            frictionless wall (on the fixed exit's loop, 10 of 29 solves not converged); the
            tip alone is the default.

    Attributes:
        anchors: {node key: (3,) world point}: where the nodes stuck at the last update (set by
            the caller from the last solution's ``anchors``; empty: nothing stuck).
        last_nodes: {node key: (3,)}: the nodes at the last update (the last solution's
            ``last_nodes``): a node coming into contact sticks where it met the wall (empty: it
            slides to its equilibrium, frictionless, and sticks there from the next update).
    """

    def __init__(self, catheter, p_E, axis, sdf=None, mu: float | None = None, max_rounds: int = 6,
                 nodes: str = "tip") -> None:
        super().__init__(catheter, p_E, axis, sdf)
        if nodes not in FRICTION_NODES:
            raise ValueError(f"FrictionalRodStatics nodes must be one of {FRICTION_NODES}, got {nodes!r}")
        self.nodes = nodes
        self.mu = float(catheter.wall_mu if mu is None else mu)
        if not self.mu >= 0.0:
            raise ValueError(f"FrictionalRodStatics mu must be >= 0, got {self.mu}")
        self.max_rounds = int(max_rounds)
        self.anchors: dict = {}
        self.last_nodes: dict = {}
        self._stick: dict = {}  # during a solve: node index -> (anchor, T (2, 3))
        self._applied: dict = {}  # during a solve: node index -> the wall's friction on a slipping node (3,)
        self._eq = None  # the last QP step's stick multipliers
        self._lam = None  # and its wall rows' (while nodes are stuck)
        self._rho_eq = 0.0

    def node_keys(self, length: float) -> list:
        """Each free node's material key (its joint index; the tip sphere's centre ``n_joints``)."""
        return list(range(self.first_free(length), self.n_joints)) + [self.n_joints]

    # -------------------------------------------------------------- the SQP's pieces, with friction
    def gradient(self, q, length, phi, kappa, force=None, torque=None):
        g = super().gradient(q, length, phi, kappa, force, torque)
        if self._applied:
            pose = self.pose(q, length, phi)
            for m, f in self._applied.items():
                g = g - pose.J[m].T @ f
        return g

    def _stick_rows(self, pose):
        E = np.vstack([T @ pose.J[m] for m, (_, T) in self._stick.items()])
        e = np.concatenate([T @ (pose.nodes[m] - a) for m, (a, T) in self._stick.items()])
        return E, e

    def _merit(self, q, length, phi, kappa, force, rho: float) -> float:
        """``RodStatics._merit`` (the energy, a tip force's work, the wall rows' exact penalty)
        less the applied friction's work, with the stick rows' exact penalty; while nodes are
        stuck, less the last step's multipliers times the rows (the Lagrangian's merit: without
        it the rows' second-order error rejects the SQP's full steps near the solution, the
        Maratos effect, and a caught tip's solve stalled at 1e-6 rad steps)."""
        return self._with_friction(super()._merit(q, length, phi, kappa, force, rho), q, length, phi, rho, 0.0)

    def _with_friction(self, value: float, q, length, phi, rho: float, row_offset: float) -> float:
        """``value`` (a merit without friction) less the applied friction's work, plus the stick
        rows' exact penalty and, while stuck, less the last multipliers times the stick rows and
        the wall rows (sdf - r + ``row_offset``: the rows the multipliers belong to)."""
        if self._applied or self._stick:
            pose = self.pose(q, length, phi)
            for m, f in self._applied.items():
                value -= float(f @ pose.nodes[m])
            if self._stick:
                e = self._stick_rows(pose)[1]
                value += max(rho, self._rho_eq) * float(np.abs(e).sum())
                if self._eq is not None:
                    value -= float(self._eq @ e)
                    if self._lam is not None and len(self._lam) == len(pose.nodes):
                        gaps = self.wall_at(pose)[0] - self.catheter.radius + row_offset
                        value -= float(self._lam @ gaps)
        return value

    def wall_hessian(self, pose, lam: np.ndarray) -> np.ndarray:
        """``RodStatics.wall_hessian`` and the stick rows' curvature: sum over the stuck nodes of
        f_t . d^2 p_m / dq^2, f_t = T' mu their tangential reaction (the geometric stiffness a
        caught tip's reaction gives the rod: what buckles it; without it the SQP's steps ignore
        the softening of the pushed rod and stall)."""
        out = super().wall_hessian(pose, lam)
        if self._eq is None or not self._stick:
            return out
        nodes = list(self._stick)
        forces = np.array([T.T @ self._eq[2 * i:2 * i + 2] for i, (_, T) in enumerate(self._stick.values())])
        weights = np.zeros(len(pose.nodes))
        weights[nodes] = 1.0
        sdf = self.sdf
        # The rows are linear in the nodes: the "sdf" whose gradient is the reaction, no Hessian.
        self.sdf = lambda p, gradient=True, hessian=False: (None, forces, np.zeros((len(p), 3, 3)))
        try:
            out = out + super().wall_hessian(pose, weights)
        finally:
            self.sdf = sdf
        return out

    def _step(self, q, H, g, length, phi):
        if not self._stick:
            return super()._step(q, H, g, length, phi)
        pose = self.pose(q, length, phi)
        A, b, _ = self._wall_rows(pose)
        near = b < 3e-3
        near[list(self._stick)] = True  # a stuck node's wall row always (the QP needs an inequality row)
        near[0] = False
        E, e = self._stick_rows(pose)
        dq, lam_near, mu = self.qp(H, g, A[near], b[near], E, e)
        if dq is None:  # the stick rows with the wall's cannot hold: released for this solve
            self._stick, self._eq = {}, None
            return super()._step(q, H, g, length, phi)
        self._eq = mu
        self._rho_eq = max(self._rho_eq, 2.0 * float(np.abs(mu).max()))
        lam = np.zeros(len(b))
        lam[near] = lam_near
        self._lam = lam
        if np.abs(dq).max() < POLISH_STEP:
            # Within the QP's precision: its dual's regularisation leaves a stuck node's wall row
            # violated by about 1e-13 times its force (m), which the merit's exact penalty weighs
            # above the step's energy; a step that no longer lowers the merit is none.
            kappa, force = self._merit_args
            rho = max(1.0, 2.0 * float(lam.max()))
            if self._merit(q + dq, length, phi, kappa, force, rho) >= self._merit(q, length, phi, kappa, force, rho):
                dq = np.zeros_like(dq)
        return dq, lam

    # -------------------------------------------------------------- the law
    def _touch_point(self, p_prev) -> np.ndarray:
        """Where a node coming from ``p_prev`` (the last update) meets the wall: its position
        moved along the wall's normal to the contact distance (the incremental contact point)."""
        value, grad = self.sdf(np.asarray(p_prev, float)[None], gradient=True)
        g = grad[0] / np.linalg.norm(grad[0])
        return np.asarray(p_prev, float) - (float(value[0]) - self.catheter.radius) * g

    def solve(self, length: float, phi: float, kappa: float, q0=None, force=None, torque=None,
              **kwargs) -> RodSolution:
        """``RodStatics.solve`` with the wall's friction (module docstring) from ``anchors`` (and
        ``last_nodes``: where each node was at the last update, for a node coming into contact);
        the solution carries ``anchors`` and ``last_nodes`` for the next update and ``friction``
        ((m, 3) [N])."""
        if self.mu <= 0.0 or self.sdf is None:
            sol = super().solve(length, phi, kappa, q0, force, torque, **kwargs)
            return self._finish(sol, length, {}, {}, {})
        length = float(np.clip(length, 0.0, self.max_length))
        keys = self.node_keys(length)
        index = {k: m for m, k in enumerate(keys)}
        stick = {index[k]: np.asarray(a, float) for k, a in self.anchors.items()
                 if index.get(k, 0) > 0 and (self.nodes == "all" or k == self.n_joints)}
        applied, anchor = {}, dict(stick)  # anchor: each node's stick point in this solve
        reaction, sol = {}, None
        for _ in range(self.max_rounds):
            self._stick = {m: (a, tangent_basis(self.sdf(a[None], gradient=True)[1][0])) for m, a in stick.items()}
            self._applied, self._eq, self._lam, self._rho_eq = dict(applied), None, None, 0.0
            self._merit_args = (kappa, force)
            sol = super().solve(length, phi, kappa, q0, force, torque, **kwargs)
            q0 = sol.q
            held = self._stick
            reaction = {}
            if self._eq is not None and len(held):
                for i, (m, (_, T)) in enumerate(held.items()):
                    reaction[m] = T.T @ self._eq[2 * i:2 * i + 2]
            stick = {m: stick[m] for m in held}  # none when the rows could not hold (``_step``)
            changed = False
            N = sol.wall_forces
            for m in list(stick):
                ft = reaction.get(m, np.zeros(3))
                if N[m] <= 0.0:  # held off the wall by its stick rows: it slides on it (kinetic friction)
                    applied[m] = np.zeros(3)
                    del stick[m]
                    changed = True
                elif np.linalg.norm(ft) > self.mu * N[m] * (1.0 + 1e-9):  # beyond the cone: slips
                    applied[m] = self.mu * N[m] * ft / np.linalg.norm(ft)
                    del stick[m]
                    changed = True
            for m in list(applied):
                if m in self._applied:  # slipped in the last solve: kinetic friction against its slip
                    T = tangent_basis(self.sdf(anchor[m][None], gradient=True)[1][0])
                    slip = T.T @ (T @ (sol.pose.nodes[m] - anchor[m]))
                    size = np.linalg.norm(slip)
                    direction = -slip / size if size > 1e-9 else applied[m] / max(np.linalg.norm(applied[m]), 1e-300)
                    new = self.mu * max(float(N[m]), 0.0) * direction
                    if np.linalg.norm(new - applied[m]) > 1e-3 * max(self.mu * float(N[m]), 1e-6):
                        changed = True
                    applied[m] = new
            for m in np.flatnonzero(N > 0.0):  # come into contact: stuck where it met the wall
                m = int(m)
                if self.nodes == "tip" and m != len(keys) - 1:
                    continue
                if m > 0 and m not in anchor and keys[m] in self.last_nodes:
                    anchor[m] = stick[m] = self._touch_point(self.last_nodes[keys[m]])
                    changed = True
            if not changed:
                break
        self._stick, self._eq = {}, None
        out = self._finish(sol, length, {m: reaction[m] for m in stick if m in reaction}, self._applied, anchor)
        self._applied = {}
        return out

    def _finish(self, sol: RodSolution, length: float, reaction: dict, applied: dict, anchor: dict) -> RodSolution:
        """The solution's friction forces, its exit loads with them, and the next update's
        anchors (a stuck node's; every other node in contact where it ended) and nodes."""
        keys = self.node_keys(length)
        friction = np.zeros((len(sol.pose.nodes), 3))
        for m, f in list(reaction.items()) + list(applied.items()):
            friction[m] = f
        if friction.any():
            moments = np.cross(sol.pose.nodes - self.p_E, friction)
            sol.base_torque += float(moments.sum(axis=0) @ self.R_E[:, 2])
            sol.base_force += float(friction.sum(axis=0) @ self.R_E[:, 2])
        anchors = {}
        if self.mu > 0.0:
            for m in np.flatnonzero(sol.wall_forces > 0.0):
                if m > 0 and (self.nodes == "all" or m == len(keys) - 1):
                    anchors[keys[m]] = (anchor[m].copy() if m in reaction else sol.pose.nodes[m].copy())
        sol.friction, sol.anchors = friction, anchors
        sol.last_nodes = {k: p.copy() for k, p in zip(keys, sol.pose.nodes)}
        return sol


class CompliantFrictionalRodStatics(FrictionalRodStatics, CompliantRodStatics):
    """The tip's Coulomb friction (``FrictionalRodStatics``) on the compliant wall
    (``CompliantRodStatics``; issue 45, H12): the friction cone on the penalty's normal force,
    |f_t| <= mu N with N = k d (plus the hard limit's share beyond the cap). A stuck node is held
    on the wall's normal line through its anchor (its tangential position) while it indents the
    wall along that line; the cone, the slip's kinetic force and a node coming into contact as in
    ``FrictionalRodStatics``, with N the node's whole normal reaction (``CompliantRodStatics.solve``'s
    ``wall_forces``, which ``FrictionalRodStatics.solve`` reads). The SQP's Hessian carries the
    penalty's Gauss-Newton term once, with or without stick rows (``_step``). Selected by
    ``SteerableCatheter`` with both ``wall_mu`` and ``wall_stiffness`` > 0.
    """

    def _step(self, q, H, g, length, phi):
        if not self.compliant or not self._stick:  # the compliant step (or the rigid wall's)
            return CompliantRodStatics._step(self, q, H, g, length, phi)
        H = H + self.penalty_hessian(self.pose(q, length, phi))
        self._penalty_in_H = True  # a fallback inside the stuck step must not add it again
        try:
            return FrictionalRodStatics._step(self, q, H, g, length, phi)
        finally:
            self._penalty_in_H = False

    def _merit(self, q, length, phi, kappa, force, rho: float) -> float:
        """``FrictionalRodStatics._merit`` on the compliant energy, its Lagrangian term on the hard
        limit's rows (sdf - r + cap, the rows the multipliers belong to)."""
        if not self.compliant:
            return FrictionalRodStatics._merit(self, q, length, phi, kappa, force, rho)
        return self._with_friction(CompliantRodStatics._merit(self, q, length, phi, kappa, force, rho), q, length, phi,
                                   rho, self.cap)


def rod_statics_class(catheter):
    """The rod's statics for the catheter's wall: frictional and compliant, frictional, compliant
    or rigid (``SteerableCatheter.wall_mu``, ``wall_stiffness``)."""
    if catheter.wall_mu > 0:
        return CompliantFrictionalRodStatics if catheter.wall_stiffness > 0 else FrictionalRodStatics
    return CompliantRodStatics if catheter.wall_stiffness > 0 else RodStatics
