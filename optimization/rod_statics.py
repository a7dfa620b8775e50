"""Quasi-static equilibrium of the steerable catheter's distal rod in the atrium.

The rod (``drake_models.steerable_catheter.SteerableCatheter``) leaves the sheath at its exit
p_E along the sheath axis; the part still in the sheath is straight (clamped). Beyond the exit it
is discretised as a Kirchhoff rod by the pseudo-rigid-body (serial joint) rule: joints every
``segment_length`` h at the material points sigma_k = (k + 1/2) h from the tip (the midpoint rule:
a joint carries the bending and twist of the h of rod around it), each joint three revolute angles
in its local frame (a about x, b about y: bending; c about z, the rod's tangent: twist), with the
energy

    E = sum_k EI_k / (2 h) ((a_k)^2 + (b_k - h kappa_k)^2) + GJ_k / (2 h) c_k^2

where kappa_k is the commanded (tendon) curvature of a joint in the deflectable segment (0
elsewhere), towards the material x axis, times the joint's share of its h in the segment (the
segment's end falls inside a joint), and EI_k the segment's, stiffened with its bend
(``SteerableCatheter.tip_EI_factor``). The joint at the sheath exit bends with its free part
only (``RodStatics.share``): the free rod's bend grows continuously as it is pushed out. The
rod's segment, 3 mm, puts the tip within 1 % of the 1 mm solution (``tests/test_catheter_segment.py``). As h -> 0 this is the Kirchhoff rod's energy (bending
EI |kappa - kappa0|^2 / 2 and torsion GJ tau^2 / 2 per unit length).

The base frame at the exit is the sheath axis's frame turned by the shaft's twist at the exit
(``phi``, from the shaft's friction chain). The tip electrode is a sphere of the rod's radius at
the end of the last half segment (its centre is the last node).

Constraints: every free node (the joints outside the sheath, the tip sphere's centre) at least
the rod's radius inside the lumen, ``sdf(p) >= r`` (the atrium's signed-distance grid,
``drake_models.atrium_sdf``); the wall is frictionless. Solved by sequential quadratic
programming: the energy is quadratic in the joint angles (its Hessian, diag(EI/h, EI/h, GJ/h), is
exact and constant), the wall rows are linearised at each iterate, and each step is the dense QP
of the chain's statics (``optimization.active_set_qp``: its compiled kernels, ``RodStatics.qp``;
the numpy reference ``dense_qp`` by ``qp = staticmethod(dense_qp)``), with a cap on the step's
largest angle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.drake_models.vectors import cross
from ballchain.optimization.compiled_rod import rod_pose
from ballchain.optimization.active_set_qp import compiled_dense_qp

MIN_SHARE = 1e-3  # the least free share of the joint at the exit (its stiffness over g: finite)


def _rx(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rz(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _convex(K: np.ndarray, W: np.ndarray) -> np.ndarray:
    """K - t W for the largest t in (1, 1/2, 1/4, ...) that keeps it positive definite (t = 0:
    K, the elastic Hessian, always is): the wall's curvature where it helps, without the cost
    of an eigendecomposition."""
    t = 1.0
    for _ in range(6):
        H = K - t * W
        try:
            np.linalg.cholesky(H)
            return H
        except np.linalg.LinAlgError:
            t *= 0.5
    return K


def frame_along(axis) -> np.ndarray:
    """A rotation whose z column is ``axis`` (unit) and whose x column is the most horizontal
    direction normal to it (world z up), the sheath's frame before any twist."""
    z = np.asarray(axis, float) / np.linalg.norm(axis)
    ref = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(ref, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


@dataclass
class RodPose:
    """The rod's geometry at some joint angles.

    Attributes:
        nodes: (m, 3) free nodes: the free joints, then the tip sphere's centre [m].
        J: (m, 3, 3 f) d nodes / d q.
        J_rot: (3, 3 f) the tip frame's angular velocity per unit dq.
        R_tip: (3, 3) the tip's frame (z: its direction).
        base: (3,) the first free joint's position (or the exit) [m].
    """

    nodes: np.ndarray
    J: np.ndarray
    J_rot: np.ndarray
    R_tip: np.ndarray
    base: np.ndarray
    wall: tuple | None = None  # the wall's (sdf, gradients) at the nodes, once asked (``RodStatics.wall_at``)

    @property
    def tip_centre(self) -> np.ndarray:
        return self.nodes[-1]

    @property
    def tip_direction(self) -> np.ndarray:
        return self.R_tip[:, 2]


@dataclass
class RodSolution:
    """An equilibrium: ``q`` (3 f,), its pose, the wall's normal force on each node [N] (m,),
    the rod's torque on the shaft at the exit about the sheath axis [N m], the iterations,
    whether it converged, and the rod's axial force on the shaft at the exit [N] (the wall's
    forces along the sheath axis: positive pulls the shaft out of the sheath)."""

    q: np.ndarray
    pose: RodPose
    wall_forces: np.ndarray
    base_torque: float
    iterations: int
    converged: bool
    base_force: float = 0.0


class RodStatics:
    """The catheter's distal rod: its joints, energy, pose, and equilibrium (module docstring).

    Args:
        catheter: the SteerableCatheter.
        p_E: (3,) the sheath exit [m]; axis: (3,) the sheath's direction (into the atrium).
        sdf: the atrium's AtriumSDF (or any ``sdf(p, gradient=True) -> (values, gradients)``), or
            None: free space.

    The steps' QP is ``qp``: the compiled ``active_set_qp.compiled_dense_qp`` (1.4-1.7x a manual
    run, ``docs/performance.md`` section 37); its numpy reference ``active_set_qp.dense_qp`` has
    the same signature (the tests' cross-check).
    """

    qp = staticmethod(compiled_dense_qp)

    def __init__(self, catheter: SteerableCatheter, p_E, axis, sdf=None) -> None:
        self.catheter = c = catheter.validate()
        self.h = c.segment_length
        self.n_joints = int(round(c.model_length / self.h))
        self.sigma = (np.arange(self.n_joints)[::-1] + 0.5) * self.h  # joint j, proximal first
        tip = self.sigma < c.deflectable_length
        # The share of each joint's h of rod in the deflectable segment (joint m from the tip
        # covers [m h, (m + 1) h]): the segment's end falls inside one joint's share, whose rest
        # curvature it scales and whose compliance it splits (h / EI = f h / EI_tip + (1 - f) h /
        # EI_shaft); without it the segment's length is quantised to whole joints (at 2-4 mm, one
        # mm more of full-knob bend: 2 mm at the tip).
        self.frac = np.clip(c.deflectable_length / self.h - (self.sigma / self.h - 0.5), 0.0, 1.0)
        tip = self.frac > 0
        self._tip_compliance = self.frac / c.tip_EI
        self._shaft_compliance = (1.0 - self.frac) / c.shaft_EI
        self.EI = 1.0 / (self._tip_compliance + self._shaft_compliance)
        self.GJ = 1.0 / (self.frac / c.tip_GJ + (1.0 - self.frac) / c.shaft_GJ)
        self.deflectable = tip
        self._stiffness_key = None
        # The last answers of ``first_free``, ``share`` and ``rest`` with their arguments (exact keys).
        self._free_key = (None, None)
        self._share_key = (None, None)
        self._rest_key = self._rest = None
        self.p_E = np.asarray(p_E, float)
        self.R_E = frame_along(axis)
        self.sdf = sdf
        self._last_pose = None

    @property
    def max_length(self) -> float:
        """The most rod out of the sheath this model holds [m]."""
        return self.n_joints * self.h

    def first_free(self, length: float) -> int:
        """The first joint outside the sheath for ``length`` of rod beyond the exit: the first
        whose h of rod reaches beyond the exit (sigma - h / 2 < length)."""
        if self._free_key[0] == length:  # (the SQP asks again and again at one length)
            return self._free_key[1]
        free = np.flatnonzero(self.sigma - 0.5 * self.h < length)
        j0 = int(free[0]) if len(free) else self.n_joints
        self._free_key = (length, j0)
        return j0

    def share(self, j0: int, length: float | None) -> tuple[float, float]:
        """The first free joint's rod out of the sheath, (free, of it deflectable) [m] (None: its
        whole h, its share of the deflectable segment): the joint at the exit bends by the
        deflectable part's rest curvature with the free part's compliance, growing from nothing
        as it leaves the sheath to its whole h once out, so that the free rod's bend grows
        continuously with the push (without it a joint of full-knob bend, 0.1 rad at 2 mm,
        appears at once)."""
        if j0 >= self.n_joints:
            return self.h, 0.0
        if length is None:
            return self.h, self.h * float(self.frac[j0])
        if self._share_key[0] == (j0, length):  # the last answer, for the same arguments
            return self._share_key[1]
        lo = self.sigma[j0] - 0.5 * self.h  # its h of rod's distal end
        free = float(np.clip(length - lo, MIN_SHARE * self.h, self.h))
        bent = float(np.clip(min(length, self.catheter.deflectable_length) - lo, 0.0, free))
        self._share_key = ((j0, length), (free, bent))
        return free, bent

    def stiffness(self, j0: int, kappa: float = 0.0, length: float | None = None) -> np.ndarray:
        """diag(EI/h, EI/h, GJ/h) of the free joints j0.. (3 f,), the deflectable segment's EI
        stiffened for the commanded curvature ``kappa`` (``SteerableCatheter.tip_EI_factor``), the
        first joint's from its rod out of the sheath (``share``)."""
        free, bent = self.share(j0, length)
        key = (j0, float(kappa), free, bent)
        if self._stiffness_key == key:
            return self._stiffness
        c = self.catheter
        factor = c.tip_EI_factor(kappa)
        EI = self.EI if factor == 1.0 else 1.0 / (self._tip_compliance / factor + self._shaft_compliance)
        K = np.column_stack([EI[j0:], EI[j0:], self.GJ[j0:]]) / self.h
        if len(K) and length is not None and (free < self.h or bent != self.h * self.frac[j0]):
            K[0, :2] = 1.0 / (bent / (c.tip_EI * factor) + (free - bent) / c.shaft_EI)
            K[0, 2] = 1.0 / (bent / c.tip_GJ + (free - bent) / c.shaft_GJ)
        self._stiffness_key = key
        self._stiffness = K.ravel()
        return self._stiffness

    def rest(self, j0: int, kappa: float, length: float | None = None) -> np.ndarray:
        """The joints' rest angles: b = h kappa times each joint's share in the deflectable segment
        (3 f,), the first joint's from its rod out of the sheath (``share``)."""
        key = (j0, kappa, length)
        if self._rest_key == key:  # the last answer (shared, as ``stiffness``'s: read, never written)
            return self._rest
        r = np.zeros((self.n_joints - j0, 3))
        r[:, 1] = self.h * kappa * self.frac[j0:]
        if len(r) and length is not None:
            r[0, 1] = kappa * self.share(j0, length)[1]
        self._rest_key, self._rest = key, r.ravel()
        return self._rest

    def energy(self, q: np.ndarray, j0: int, kappa: float, length: float | None = None) -> float:
        d = q - self.rest(j0, kappa, length)
        return 0.5 * float(d @ (self.stiffness(j0, kappa, length) * d))

    def pose(self, q: np.ndarray, length: float, phi: float) -> RodPose:
        """The free nodes and their Jacobians for joint angles q, ``length`` beyond the exit and
        the shaft's twist ``phi`` at the exit (the last one computed is kept: the SQP asks for
        the same iterate's pose several times)."""
        q = np.asarray(q, float)
        key = (q.tobytes(), float(length), float(phi))
        if self._last_pose is not None and self._last_pose[0] == key:
            return self._last_pose[1]
        pose = self._pose(q, length, phi)
        self._last_pose = (key, pose)
        return pose

    def _pose(self, q: np.ndarray, length: float, phi: float) -> RodPose:
        """``pose_reference``'s floats by one compiled call (``compiled_rod.rod_pose``; numpy's
        cosines and sines), bit for bit (tests/test_compiled_rod.py)."""
        j0 = self.first_free(length)
        f = self.n_joints - j0
        if not f:
            return self.pose_reference(q, length, phi)
        q = q.reshape(f, 3)
        R = self.R_E @ _rz(phi)
        p = self.p_E + R[:, 2] * (length - self.sigma[j0])
        nodes, J, axes, R_tip = rod_pose(R, np.cos(q), np.sin(q), p, float(self.h),
                                         float(0.5 * self.h - self.catheter.radius))
        # (J transposed as the reference's: the same strides for the products that read it)
        return RodPose(nodes, np.transpose(J, (0, 2, 1)), axes.T.copy(), R_tip, nodes[0].copy())

    def pose_reference(self, q: np.ndarray, length: float, phi: float) -> RodPose:
        """The pose in numpy: the reference of the compiled ``_pose``."""
        j0 = self.first_free(length)
        f = self.n_joints - j0
        q = q.reshape(f, 3)
        R = self.R_E @ _rz(phi)
        p = self.p_E + R[:, 2] * (length - (self.sigma[j0] if f else length))
        # The joints' elementary rotations, all at once; then their product along the chain.
        c, s = np.cos(q), np.sin(q)
        rot = np.zeros((3, f, 3, 3))
        for k, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):  # about x, y, z
            rot[k, :, k, k] = 1.0
            rot[k, :, i, i] = rot[k, :, j, j] = c[:, k]
            rot[k, :, i, j], rot[k, :, j, i] = -s[:, k], s[:, k]
        axes, ends = np.zeros((f, 3, 3)), np.zeros((f, 3))
        for i in range(f):
            axes[i, 0] = R[:, 0]
            R = R @ rot[0, i]
            axes[i, 1] = R[:, 1]
            R = R @ rot[1, i]
            axes[i, 2] = R[:, 2]
            R = R @ rot[2, i]
            ends[i] = R[:, 2]
        steps = np.full(f, self.h)
        if f:
            steps[-1] = 0.5 * self.h - self.catheter.radius
        points = np.cumsum(np.vstack([p[None, :], ends * steps[:, None]]), axis=0)
        joints, axes = points[:f], axes.reshape(3 * f, 3)
        nodes = points if f else p[None, :]
        m = len(nodes)
        col_joint = np.repeat(np.arange(f), 3)
        lever = nodes[:, None, :] - joints[col_joint][None, :, :]  # (m, 3f, 3)
        J = cross(axes[None, :, :], lever)
        J[np.arange(m)[:, None] <= col_joint[None, :]] = 0.0  # a joint moves only the nodes after it
        return RodPose(nodes, np.transpose(J, (0, 2, 1)), axes.T.copy(), R, joints[0] if f else p)

    def gradient(self, q: np.ndarray, length: float, phi: float, kappa: float, force=None, torque=None) -> np.ndarray:
        """dE/dq less the virtual work of a tip force [N] at the tip sphere's centre and a tip
        torque [N m] (both in world)."""
        j0 = self.first_free(length)
        g = self.stiffness(j0, kappa, length) * (q - self.rest(j0, kappa, length))
        if force is not None or torque is not None:
            pose = self.pose(q, length, phi)
            if force is not None:
                g = g - pose.J[-1].T @ np.asarray(force, float)
            if torque is not None:
                g = g - pose.J_rot.T @ np.asarray(torque, float)
        return g

    def wall_at(self, pose: RodPose) -> tuple:
        """The atrium's signed distance and its gradients at the pose's nodes (kept with the pose:
        the SQP's rows, its merit and the wall forces ask at the same iterate)."""
        if pose.wall is None:
            pose.wall = self.sdf(pose.nodes, gradient=True)
        return pose.wall

    def _wall_rows(self, pose: RodPose):
        """Linearised wall rows A dq + b >= 0 (sdf - r, in metres), and the sdf gradients."""
        values, grads = self.wall_at(pose)
        A = np.einsum("mi,mij->mj", grads, pose.J)
        return A, values - self.catheter.radius, grads

    def _merit(self, q, length, phi, kappa, force, rho: float) -> float:
        """Energy, less a tip force's work, plus rho times the wall's violation (metres)."""
        j0 = self.first_free(length)
        value = self.energy(q, j0, kappa, length)
        if force is not None or self.sdf is not None:
            pose = self.pose(q, length, phi)
            if force is not None:
                value -= float(np.asarray(force, float) @ pose.tip_centre)
            if self.sdf is not None:
                gaps = self.wall_at(pose)[0] - self.catheter.radius
                value += rho * float(np.maximum(-gaps, 0.0).sum())
        return value

    def wall_hessian(self, pose: RodPose, lam: np.ndarray) -> np.ndarray:
        """sum_m lam_m d^2 sdf(p_m) / dq^2: the wall rows' curvature in the joint angles (the
        sdf's Hessian through the Jacobian, and the sdf's gradient through the chain's second
        derivatives d^2 p / dq_i dq_j = w_i x (w_j x (p - p_j)), i no later than j)."""
        n = pose.J.shape[2]
        out = np.zeros((n, n))
        active = np.flatnonzero(lam > 0)
        if not len(active):
            return out
        _, grads, hess = self.sdf(pose.nodes[active], gradient=True, hessian=True)
        axes = pose.J_rot.T  # (3f, 3) each column's axis
        col_joint = np.repeat(np.arange(n // 3), 3)
        joints = pose.nodes[:-1]  # node i < f is joint i
        for w, m, gr, He in zip(lam[active], active, grads, hess):
            Jm = pose.J[m]
            out += w * (Jm.T @ He @ Jm)
            lever = pose.nodes[m] - joints[col_joint]  # (3f, 3)
            moving = np.flatnonzero(col_joint < m)  # the joints before node m move it
            inner = cross(axes[moving], lever[moving])  # w_j x (p - p_j)
            # d2[i, j] = gr . (w_i x inner_j) = inner_j . (gr x w_i), for i <= j.
            d2 = cross(gr, axes[moving]) @ inner.T
            d2 = np.triu(d2)
            d2 = d2 + np.triu(d2, 1).T
            out[np.ix_(moving, moving)] += w * d2
        return out

    def _step(self, q, H, g, length, phi):
        """The SQP step and the wall multipliers (one per node) at q."""
        if self.sdf is None or not len(g):
            return -g / np.diag(H) if len(g) else np.zeros(0), np.zeros(0)
        A, b, _ = self._wall_rows(self.pose(q, length, phi))
        near = b < 3e-3  # rows that can become active within a step
        near[0] = False  # the first joint, at the exit (or up to h / 2 behind it), no joint moves
        dq, lam_near, _ = self.qp(H, g, A[near], b[near])
        if dq is None:  # the linearised rows cannot all hold with this energy: back to the wall
            dq, lam_near, _ = self.qp(H, np.zeros(len(g)), A[near], b[near])
        if dq is None:  # nor at all: halfway towards the straight rod
            dq, lam_near, near = -0.5 * q, np.zeros(0), np.zeros(len(b), bool)
        lam = np.zeros(len(b))
        lam[near] = lam_near
        return dq, lam

    def solve(self, length: float, phi: float, kappa: float, q0=None, force=None, torque=None,
              tol: float = 1e-8, max_iterations: int = 80, max_step: float = 0.3) -> RodSolution:
        """The equilibrium with ``length`` of rod beyond the exit, the shaft's twist ``phi`` at
        the exit, the commanded curvature ``kappa`` [1/m] (and an optional tip force / torque),
        from ``q0`` (default: the straight rod) by SQP (module docstring): each step capped at
        ``max_step`` in its largest angle, and halved until it lowers the merit (the energy plus
        an exact penalty on the wall's violation; a tip torque, which has no potential here,
        is taken by whole steps)."""
        length = float(np.clip(length, 0.0, self.max_length))
        j0 = self.first_free(length)
        K = self.stiffness(j0, kappa, length)
        # From the straight rod (out of the sheath's bore: inside the lumen) unless warm-started;
        # a warm start with fewer (more) free joints gains straight joints at the exit (loses the
        # proximal ones): the continuation of pushing (pulling) rod through the exit.
        q = np.zeros(len(K))
        if q0 is not None and len(q0):
            q0 = np.asarray(q0, float)
            keep = min(len(q0), len(K))
            q[len(K) - keep:] = q0[len(q0) - keep:]
        H = np.diag(K)
        lam, rho = np.zeros(0), 1.0
        converged, it = False, 0
        for it in range(1, max_iterations + 1):
            g = self.gradient(q, length, phi, kappa, force, torque)
            if len(lam) and lam.any():  # the Lagrangian's Hessian with the last multipliers
                H = _convex(np.diag(K), self.wall_hessian(self.pose(q, length, phi), lam))
            dq, lam = self._step(q, H, g, length, phi)
            big = np.abs(dq).max() if len(dq) else 0.0
            if big < tol:
                converged = True
                break
            scale = min(1.0, max_step / big)
            if torque is None:
                rho = max(rho, 2.0 * float(lam.max()) if len(lam) else 0.0)
                m0 = self._merit(q, length, phi, kappa, force, rho)
                while scale * big > tol and self._merit(q + scale * dq, length, phi, kappa, force, rho) > m0:
                    scale *= 0.5
            q = q + scale * dq
        pose = self.pose(q, length, phi)
        forces = lam if len(lam) == len(pose.nodes) else np.zeros(len(pose.nodes))
        torque_E = force_E = 0.0
        if forces.any():
            _, grads = self.wall_at(pose)
            moments = np.cross(pose.nodes - self.p_E, forces[:, None] * grads)
            torque_E = float(moments.sum(axis=0) @ self.R_E[:, 2])
            force_E = float((forces[:, None] * grads).sum(axis=0) @ self.R_E[:, 2])
        return RodSolution(q, pose, forces, torque_E, it, converged, force_E)
