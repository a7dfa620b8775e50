"""The manual arm of the paper's comparison (Sec. V-C): a steerable catheter in the atrium and a
hand on its handle, the systems of its device model (``catheter_model.CatheterModel``).

``MakeStation`` builds them for a scenario with ``device: steerable_catheter`` into the same
station as the ball chain's: the same atrium, the same sheath exit and axis, the same target
rings and ``TargetTouchTracker``, the same ``add_systems`` hook for an operator and the same run
loop, with the catheter instead of the chain and the hand instead of the units:

* ``SteerableCatheterSystem``: the catheter's quasi-static state, advanced every ``period`` from
  the handle's position (the push past the start [m], the handle's twist [rad], the knob in
  [-1, 1]): the shaft's friction chains in the sheath (``drake_models.steerable_catheter``:
  stick-slip in twist and in push), then the distal rod's equilibrium in the atrium
  (``optimization.rod_statics``), warm-started from the last one. Outputs ``body_poses`` (the
  rod's nodes as bodies 1..n + 1, the tip sphere's centre last, for the operator's camera and
  the touch test), ``tip_position`` (3: the tip's end) and ``windup`` (3: the handle's twist,
  the twist at the sheath exit [rad], slips so far).
* ``ManualHand``: the hand on the handle, driven like the robotic console (a stick with a dead
  band and a feeder command, so that the same ``SimulatedOperator`` drives it): stick axis 0 turns
  the handle, axis 1 the knob, the feeder command pushes or pulls, each within a human-like rate
  limit. It feels the shaft's torque at the handle (the catheter's ``handle_load``); when the
  torque it turns against reaches its threshold (``HandParams.torque_threshold``, a human
  parameter: the windup the paper describes is felt, not counted in degrees), its strategy is to
  ``keep`` turning or to ``switch``: turn the handle back by half a turn while moving the knob to
  the opposite tendon (the same bend, the other wire), during which it takes no other command. The ``switch`` hand does the same when the
  knob is at the F tendon's end and asked for more bend: the D tendon (the tighter curve) and the
  handle half a turn towards neutral.

Exported inputs (when the hook leaves them unconnected): ``hand.joystick`` (3),
``feeder.v_insert_cmd`` (1) (the hand's push: the station's names for every device).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.geometry import Rgba, Sphere
from pydrake.systems.framework import EventStatus, LeafSystem

from ballchain.infrastructure.errors import UserInputError, require_finite_fields
from ballchain.drake_models.sheath import SteerableSheath
from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.infrastructure.arg_checks import require_type
from ballchain.systems.rod_wall_friction import FrictionalRodStatics, rod_statics_class
from ballchain.systems.meshcat_view import frame_scene
from ballchain.systems.manual_hand import STRATEGIES, HandParams, ManualHand, _finite  # noqa: F401 (re-exported)
from ballchain.systems.sheath_plan import SheathPlan  # noqa: F401 (re-exported)

SHEATH_SUBSTEP = 1.0  # [deg or mm] the largest move of a steerable sheath between the rod's solves


@dataclass
class _CatheterState:
    """The catheter's state between updates (an abstract state value)."""

    q: np.ndarray
    twist: np.ndarray  # the shaft's twist chain nodes [rad] (handle first)
    push: np.ndarray  # the shaft's push chain nodes [m]
    length: float  # rod beyond the sheath exit [m]
    torque: float  # the rod's torque on the shaft at the exit [N m]
    nodes: np.ndarray  # (n + 1, 3): every joint (those in the sheath on its axis) and the tip centre
    R_tip: np.ndarray
    slips: int = 0
    force: float = 0.0  # the rod's axial force on the shaft at the exit [N]
    push_slips: int = 0
    failures: list = field(default_factory=list)
    anchors: dict = field(default_factory=dict)  # the wall's stuck nodes (``systems.rod_wall_friction``)
    last_nodes: dict = field(default_factory=dict)  # the free nodes at the last update, by material key
    peak_wall_force: float = 0.0  # the largest total wall force on the rod at any update so far [N]
    peak_tip_force: float = 0.0  # the largest wall force on the tip sphere at any update so far [N]
    wall_force: tuple = (0.0, 0.0)  # the last update's total wall force on the rod and on the tip sphere [N]

    def __deepcopy__(self, memo):
        new = copy.copy(self)
        for name in ("q", "twist", "push", "nodes", "R_tip"):
            setattr(new, name, getattr(self, name).copy())
        new.failures = list(self.failures)
        new.anchors, new.last_nodes = dict(self.anchors), dict(self.last_nodes)
        return new


class SteerableCatheterSystem(LeafSystem):
    """The steerable catheter in the atrium, quasi-static (module docstring).

    Input ports: handle (3: push past the start [m], handle twist [rad], knob in [-1, 1]).
    Output ports: body_poses (abstract list[RigidTransform]: index 0 the world, 1..n + 1 the rod's
    nodes, the tip sphere's centre last, with the tip's frame), tip_position (3: the tip's end),
    windup (3: handle twist, twist at the sheath exit [rad], slips so far), tip_wall_force (6: zero, the rod
    statics do not report the wall's force, then the tip sphere's centre), handle_load (2), wall_force
    (2: the wall's normal force at the last update, its total on the rod and on the tip sphere [N]).

    Args:
        catheter: the SteerableCatheter.
        p_E, axis: the sheath exit [m] and its direction.
        sdf: the atrium's signed distance (``drake_models.atrium_sdf``).
        initial_length: rod beyond the exit at the start [m].
        period: the update period [s].
    """

    def __init__(self, catheter: SteerableCatheter, p_E, axis, sdf, initial_length: float = 20e-3,
                 period: float = 0.05, sheath: SteerableSheath | None = None) -> None:
        super().__init__()
        self.set_name("steerable_catheter")
        self.catheter = catheter.validate()
        # The wall's friction (``SteerableCatheter.wall_mu`` > 0, ``systems.rod_wall_friction``) or
        # compliance (``wall_stiffness`` > 0, ``systems.rod_wall_compliance``); 0: the frictionless
        # rigid wall's statics, as before.
        statics = rod_statics_class(self.catheter)
        self.rod = statics(self.catheter, p_E, axis, sdf)
        # A steerable sheath (issue 45, the manual arm): its exit moves with its input (advance
        # beyond the septum [m], rotation [rad], deflection [rad]); None: the paper's fixed exit.
        self.sheath = None if sheath is None else require_type(sheath, SteerableSheath, "sheath",
                                                                "a SteerableSheath or None").validate()
        self._p_S = self.rod.p_E - (0.0 if sheath is None else sheath.nominal_advance) * self.rod.R_E[:, 2]
        self._R_S = self.rod.R_E.copy()
        self.sheath_setting = None if sheath is None else (sheath.nominal_advance, 0.0, 0.0)
        if not 0.0 < initial_length <= self.rod.max_length:
            raise UserInputError(f"SteerableCatheterSystem initial_length must be in (0, "
                                 f"{self.rod.max_length * 1e3:.0f} mm], got {initial_length}")
        self.initial_length = float(initial_length)
        self.period = float(period)
        self._twist_chain, self._push_chain = self.catheter.chains()
        # The coupling's scales: the chains' kinetic friction, the shaft unloaded.
        c = self.catheter
        self._torque_scale = c.mu_kinetic * c.radius * c.sheath_normal_force()
        self._force_scale = c.mu_kinetic * c.sheath_normal_force()
        self.n_bodies = self.rod.n_joints + 1
        self._handle = self.DeclareVectorInputPort("handle", 3)
        self._sheath = None if sheath is None else self.DeclareVectorInputPort("sheath", 3)
        self._index = self.DeclareAbstractState(AbstractValue.Make(self._solve(self._start(), 0.0, 0.0, 0.0)))
        ticket = {self.abstract_state_ticket(self._index)}
        self.DeclareAbstractOutputPort("body_poses", lambda: AbstractValue.Make([RigidTransform()]),
                                       self._calc_poses, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("tip_position", 3, self._calc_tip, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("windup", 3, self._calc_windup, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("tip_wall_force", 6, self._calc_wall_force, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("handle_load", 2, self._calc_handle_load, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("wall_force", 2, self._calc_wall_forces, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("length_out", 1, self._calc_length_out, prerequisites_of_calc=ticket)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update)

    def _start(self) -> _CatheterState:
        return _CatheterState(np.zeros(0), self._twist_chain.initial(), self._push_chain.initial(),
                              self.initial_length, 0.0, np.zeros((self.n_bodies, 3)), np.eye(3))

    def state(self, context) -> _CatheterState:
        return context.get_abstract_state(self._index).get_value()

    def _solve(self, st: _CatheterState, push: float, twist: float, knob: float) -> _CatheterState:
        """``st`` advanced (in place, and returned) to the handle at (push, twist, knob): the shaft's
        chains through the sheath's bends (the axial one under the rod's axial force, the
        torsional one under the rod's torque and pressed by the axial one's tension), then the
        rod; the chains see the rod's new loads once more (the quasi-static coupling)."""
        kappa = self.catheter.curvature(knob)
        bends = self.catheter.sheath_friction == "bends"
        start = st.twist.copy()  # the twist chain before this update
        friction = isinstance(self.rod, FrictionalRodStatics)
        if friction:  # every solve of this update sticks where the last update's nodes were stuck
            self.rod.anchors, self.rod.last_nodes = st.anchors, st.last_nodes
        for _ in range(2):
            if bends:
                st.push, slips_push = self._push_chain.step(st.push, push, st.force)
                tension = self._push_chain.mean_tension(st.push, st.force)
                st.twist, slips = self._twist_chain.step(st.twist, twist, st.torque, tension)
            else:  # the earlier model (SteerableCatheter.sheath_friction): no axial load, no capstan
                st.push, slips_push = self._push_chain.step(st.push, push)
                st.twist, slips = self._twist_chain.step(st.twist, twist, st.torque)
            length = float(np.clip(self.initial_length + st.push[-1], 2 * self.rod.h, self.rod.max_length))
            st.push_slips += slips_push
            if self.sheath is not None:  # the exit twist and the rod's torque solved together
                st.twist, slips, sol = self.coupled_twist(start, twist, tension if bends else None, length, kappa,
                                                          st.q, st.failures)
            else:  # the paper's fixed sheath: the alternating coupling (its runs' numbers kept)
                sol = self.rod.solve(length, st.twist[-1], kappa, q0=st.q if len(st.q) else None)
            st.slips += slips
            if not (np.all(np.isfinite(sol.q)) and np.isfinite(sol.base_torque) and np.isfinite(sol.base_force)):
                if len(st.failures) < 20:
                    st.failures.append(f"rod statics not finite at length {length * 1e3:.1f} mm")
                return st  # the last finite state stays
            if not sol.converged and len(st.failures) < 20:  # the first few, for the run's warnings
                st.failures.append(f"rod statics did not converge at length {length * 1e3:.1f} mm")
            changed = (abs(sol.base_torque - st.torque) > 0.05 * self._torque_scale
                       or abs(sol.base_force - st.force) > 0.05 * self._force_scale)
            st.q, st.torque, st.force, st.length = sol.q, sol.base_torque, sol.base_force, length
            if not changed:
                break
        st.R_tip = sol.pose.R_tip
        if len(sol.wall_forces):
            st.peak_wall_force = max(st.peak_wall_force, float(sol.wall_forces.sum()))
            st.peak_tip_force = max(st.peak_tip_force, float(sol.wall_forces[-1]))
            st.wall_force = (float(sol.wall_forces.sum()), float(sol.wall_forces[-1]))
        if friction:
            st.anchors, st.last_nodes = sol.anchors, sol.last_nodes
        j0 = self.rod.first_free(length)
        inside = self.behind_exit(self.rod.sigma[:j0] - length)
        st.nodes = np.vstack([inside, sol.pose.nodes])
        return st

    def coupled_twist(self, chain_x, handle: float, tension, length: float, kappa: float, q0,
                      failures: list, xtol: float = 1e-7, max_evaluations: int = 80, max_step: float = 0.1):
        """The twist chain stepped from ``chain_x`` to ``handle`` with the rod's torque at its own
        exit twist (issue 45): the root of F(phi) = (the chain's exit node under the rod's torque
        at phi) - phi, bracketed outward from the last exit twist (where ``q0`` holds) in steps
        growing to ``max_step`` [rad], each rod solve warm-started from the nearest one done (the
        quasi-static path: a far jump lands the rod on another of its equilibria against the
        wall), then refined by the Illinois regula falsi on the values kept. Alternating the two
        (the fixed sheath's coupling) runs away when the rod's torsional stiffness exceeds the
        shaft's, as with the short rod beyond a curled sheath. ``tension`` None: "even" chains.

        Returns:
            (chain nodes, slips, the RodSolution at the exit twist)."""
        q0 = q0 if len(q0) else None
        chain, seen = self._twist_chain, {}
        step = ((lambda load: chain.step(chain_x, handle, load)) if tension is None
                else (lambda load: chain.step(chain_x, handle, load, tension)))

        def F(phi):
            near = min(seen, key=lambda p: abs(p - phi)) if seen else None
            sol = self.rod.solve(length, phi, kappa, q0=q0 if near is None else seen[near][0].q)
            if not (np.all(np.isfinite(sol.q)) and np.isfinite(sol.base_torque)):
                raise FloatingPointError
            x, slips = step(sol.base_torque)
            seen[phi] = (sol, x, slips)
            return float(x[-1]) - phi

        try:
            a = float(chain_x[-1])
            fa = F(a)
            if abs(fa) > xtol:
                d = float(np.sign(fa)) * min(abs(fa), 0.02)
                b, fb = a + d, F(a + d)
                while fb * fa > 0 and len(seen) < max_evaluations // 2:
                    a, fa, d = b, fb, float(np.sign(d)) * min(2 * abs(d), max_step)
                    b, fb = a + d, F(a + d)
                while fb * fa < 0 and abs(b - a) > xtol and len(seen) < max_evaluations:
                    m = b - fb * (b - a) / (fb - fa)  # the Illinois regula falsi on the bracket's values
                    fm = F(m)
                    if fm * fb < 0:
                        a, fa = b, fb
                    else:
                        fa *= 0.5
                    b, fb = m, fm
            phi = min(seen, key=lambda p: abs(seen[p][1][-1] - p))
            # F jumps where a chain node starts to slip (static above kinetic): a bracket closed on
            # the jump is the node at the edge of slipping, balanced (its nodes as the chain left them).
            edge = abs(fa) > xtol and fb * fa < 0 and abs(b - a) <= xtol
        except FloatingPointError:
            phi, edge = None, False
        if phi is None or (abs(seen[phi][1][-1] - phi) > 1e3 * xtol and not edge):  # the last finite try
            if len(failures) < 20:
                failures.append(f"exit twist not balanced at length {length * 1e3:.1f} mm ({len(seen)} solves)")
            if phi is None:
                sol = self.rod.solve(length, float(chain_x[-1]), kappa, q0=q0)
                return np.asarray(chain_x, float).copy(), 0, sol
        sol, x, slips = seen[phi]
        return x, slips, sol

    @property
    def septum(self) -> tuple:
        """(p_S, R_S): where the sheath crosses the septum and the fixed sheath's frame there."""
        return self._p_S, self._R_S

    def behind_exit(self, d) -> np.ndarray:
        """Points (k, 3) ``d`` (k,) behind the exit along the sheath [m]: on the fixed sheath's
        axis, or along the steerable sheath's centreline and then its axis behind the septum."""
        d = np.asarray(d, float)
        if self.sheath is None:
            return self.rod.p_E[None, :] - np.outer(d, self.rod.R_E[:, 2])
        return self.sheath.behind_exit(self._p_S, self._R_S, *self.sheath_setting, d)

    def in_sheath(self, p_W, radius: float) -> np.ndarray:
        """Which points (k, 3) lie in the sheath (within ``radius`` of its centreline)."""
        p_W = np.atleast_2d(np.asarray(p_W, float))
        if self.sheath is None:
            line = self.rod.p_E[None, :]
        else:
            line = self.behind_exit(np.linspace(0.0, self.sheath.max_advance, 81))
        axis = self._R_S[:, 2]
        start = line[-1] if self.sheath is not None else self.rod.p_E
        rel = p_W - start
        along = rel @ axis
        behind = (along <= 1e-9) & (np.linalg.norm(rel - along[:, None] * axis, axis=1) <= radius)
        if self.sheath is None:
            return behind
        near = np.min(np.linalg.norm(p_W[:, None, :] - line[None], axis=2), axis=1) <= radius + 0.5e-3
        return behind | near

    def place_sheath(self, advance: float, rotation: float, deflection: float) -> None:
        """The rod's base at the steerable sheath's exit for its (advance [m], rotation [rad],
        deflection [rad]) (``SteerableSheath.exit_pose``): the next solve starts there, warm-started
        from the last joint angles (a quasi-static move: the catheter rides in the sheath)."""
        self.sheath_setting = (float(advance), float(rotation), float(deflection))
        p, R, _ = self.sheath.exit_pose(self._p_S, self._R_S, advance, rotation, deflection)
        if not (np.array_equal(p, self.rod.p_E) and np.array_equal(R, self.rod.R_E)):
            self.rod.p_E, self.rod.R_E = p, R
            self.rod._last_pose = None  # its cached pose is keyed by the joint angles only, not the base

    def _update(self, context, state):
        push, twist, knob = _finite(self._handle.Eval(context))
        if self._sheath is not None and self._sheath.HasValue(context):
            new = _finite(self._sheath.Eval(context))
            old = np.array(self.sheath_setting)
            # In steps of at most SHEATH_SUBSTEP's degrees (or mm): the rod's solve is warm-started
            # from the last one, which a large jump of its base leaves too far behind.
            turn = np.degrees(np.abs(new - old))
            n = int(np.ceil(max(turn[1] * abs(new[2]) / np.pi, turn[2], abs(new[0] - old[0]) * 1e3) / SHEATH_SUBSTEP))
            for k in range(1, n):
                self.place_sheath(*(old + (new - old) * k / n))
                self._solve(state.get_mutable_abstract_state(self._index).get_mutable_value(), float(push),
                            float(twist), float(knob))
            self.place_sheath(*(float(v) for v in new))
        # Drake hands the update a copy of the state: the catheter's is advanced in place there.
        self._solve(state.get_mutable_abstract_state(self._index).get_mutable_value(), float(push), float(twist),
                    float(knob))
        return EventStatus.Succeeded()

    def _calc_poses(self, context, output):
        st = self.state(context)
        poses = [RigidTransform()] + [RigidTransform(p) for p in st.nodes[:-1]]
        poses.append(RigidTransform(RotationMatrix(st.R_tip), st.nodes[-1]))
        output.set_value(poses)

    def _calc_tip(self, context, output):
        st = self.state(context)
        output.SetFromVector(st.nodes[-1] + self.catheter.radius * st.R_tip[:, 2])

    def _calc_windup(self, context, output):
        st = self.state(context)
        output.SetFromVector([st.twist[0], st.twist[-1], float(st.slips)])

    def _calc_length_out(self, context, output):
        """The catheter out of the sheath's exit at the last update [m] (the push chain's end: what
        fluoroscopy shows of it beyond the sheath's tip, where the handle's readout shows its push)."""
        output.SetAtIndex(0, self.state(context).length)

    def _calc_wall_forces(self, context, output):
        """The wall's normal force at the last update [N]: its total on the rod and on the tip sphere."""
        output.SetFromVector(list(self.state(context).wall_force))

    def _calc_handle_load(self, context, output):
        """What the hand feels: the shaft's torque [N m] and axial force [N] at the handle (its
        first elements', positive when the shaft resists the handle's positive twist / push)."""
        st = self.state(context)
        output.SetFromVector([-self._twist_chain.forces(st.twist)[0], -self._push_chain.forces(st.push)[0]])

    def _calc_wall_force(self, context, output):
        output.SetFromVector(np.concatenate([np.zeros(3), self.state(context).nodes[-1]]))


class CatheterMeshcat(LeafSystem):
    """The catheter in Meshcat: the atrium's blood-side surface and the targets drawn once, the
    rod's nodes (spheres of its radius) moved at every publish from ``body_poses``, at the
    publish's time (while the Meshcat records, these are the replay's frames). It records a
    replay as the station's visualizer does (``StartRecording``, ``StopRecording``,
    ``PublishRecording``: ``run_station(html=...)``), a frame every ``period``.

    Input ports: body_poses (abstract list[RigidTransform]).
    """

    def __init__(self, meshcat, heart, n_bodies: int, radius: float, targets=None, period: float = 0.05) -> None:
        super().__init__()
        self.set_name("catheter_meshcat")
        self._meshcat, self._n, self._period = meshcat, n_bodies, period
        self._poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        frame_scene(meshcat, heart)  # the camera on the atrium (and a replay opens on the same view)
        V, F = heart.blood_surface
        meshcat.SetTriangleMesh("catheter_view/atrium", np.asarray(V, float).T, np.asarray(F).T,
                                Rgba(0.85, 0.45, 0.45, 0.25))
        if targets is not None:
            for name, p in zip(targets[0], targets[1]):
                meshcat.SetObject(f"catheter_view/targets/{name}", Sphere(targets[3]), Rgba(0.2, 0.6, 0.9, 0.6))
                meshcat.SetTransform(f"catheter_view/targets/{name}", RigidTransform(p))
        for i in range(n_bodies):
            meshcat.SetObject(f"catheter_view/rod/{i}", Sphere(radius), Rgba(0.3, 0.3, 0.3, 1.0))
        self.DeclarePeriodicPublishEvent(period, 0.0, self._publish)
        self.DeclareForcedPublishEvent(self._publish)

    def _publish(self, context):
        poses = self._poses.Eval(context)
        for i in range(self._n):
            self._meshcat.SetTransform(f"catheter_view/rod/{i}", poses[i + 1], context.get_time())
        return EventStatus.Succeeded()

    def StartRecording(self) -> None:
        """Record the frames (the poses set at their times), one every ``period``."""
        self._meshcat.StartRecording(1.0 / self._period, False)

    def StopRecording(self) -> None:
        self._meshcat.StopRecording()

    def PublishRecording(self) -> None:
        self._meshcat.PublishRecording()


@dataclass
class CatheterParams:
    """The catheter device's own parameters (``MakeStation(device_params=...)``).

    Attributes:
        catheter: the SteerableCatheter (default: its defaults).
        hand: the HandParams of the hand on its handle (default: its defaults).
        initial_length: rod beyond the sheath exit at the start [m].
        sheath: a steerable sheath the hand moves (``SteerableSheath``, issue 45), or None: the
            paper's fixed sheath.
    """

    catheter: SteerableCatheter = field(default_factory=SteerableCatheter)
    hand: HandParams = field(default_factory=HandParams)
    initial_length: float = 20e-3
    sheath: SteerableSheath | None = None
