"""Which ablation targets the tip touches, and the wall's contact force on a body.

Plain logic, no visualisation: used by the simulated operator, the run's metrics, the target
tracker and the Meshcat overlays alike.

* ``TargetTouchTracker`` (``target_touches``): which of the heart's ablation targets the tip
  ball has touched so far (state; added whenever the atrium has target rings, with or without
  Meshcat, so that the run can report ``targets_touched``).
* ``wall_force_on``: the walls' contact force on a set of geometries from ContactResults.

When the tip ball touches a target (``targets_touched``): with p the tip ball's centre, p_T a
target's centre on the endocardium and n_T the wall's unit normal there (into the chamber),
h = (p - p_T) . n_T is the height of the ball's centre above the wall's tangent plane at the
target and l = |(p - p_T) - h n_T| its lateral distance from the target's centre. The ball
touches the target when |h| <= r_ball + 0.5 mm (its surface within 0.5 mm of the wall, or in
it) and l <= the target's radius (2.5 mm for 5 mm targets). The wall's curvature is ignored
over the target: on the 19 mm semi-axis it bends 0.16 mm away from the tangent plane 2.5 mm
from the centre.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.plant import ContactResults
from pydrake.systems.framework import EventStatus, LeafSystem

from ballchain.drake_models import electrode
from ballchain.systems.chain_model import subsystem_context

TOUCH_TOLERANCE = 0.5e-3  # [m] the ball's surface this close to the wall counts as touching
WALL_GEOMETRY_NAMES = ("heart_wall", "wall_plane")  # chain_plant's collision walls


def wall_geometries(plant, inspector) -> set:
    """The collision geometries of chain_plant's walls (the heart's, or a flat wall)."""
    return {g for g in plant.GetCollisionGeometriesForBody(plant.world_body())
            if inspector.GetName(g).split("::")[-1] in WALL_GEOMETRY_NAMES}


def wall_force_on(results: ContactResults, body_geometries: set, walls: set) -> tuple[np.ndarray, np.ndarray | None]:
    """The walls' total contact force on a body, from the plant's contact results.

    Args:
        results: the plant's ContactResults (hydroelastic and point contacts).
        body_geometries: the body's collision geometry ids.
        walls: the walls' collision geometry ids.

    Returns:
        (f_W (3,) [N], p_WC (3,) [m] or None): the force and where it acts (the contact centroids,
        weighted by force; None without contact).
    """
    f = np.zeros(3)
    points, weights = [], []
    for i in range(results.num_hydroelastic_contacts()):
        info = results.hydroelastic_contact_info(i)
        surface = info.contact_surface()
        M, N = surface.id_M(), surface.id_N()
        if M in body_geometries and N in walls:
            f_body = info.F_Ac_W().translational()  # body A is geometry M's
        elif N in body_geometries and M in walls:
            f_body = -info.F_Ac_W().translational()
        else:
            continue
        f += f_body
        points.append(surface.centroid())
        weights.append(np.linalg.norm(f_body))
    for i in range(results.num_point_pair_contacts()):
        info = results.point_pair_contact_info(i)
        pair = info.point_pair()
        if pair.id_A in walls and pair.id_B in body_geometries:
            f_body = info.contact_force()  # on body B
        elif pair.id_B in walls and pair.id_A in body_geometries:
            f_body = -info.contact_force()
        else:
            continue
        f += f_body
        points.append(info.contact_point())
        weights.append(np.linalg.norm(f_body))
    if not points:
        return f, None
    w = np.asarray(weights)
    w = w / w.sum() if w.sum() > 0 else np.full(len(points), 1.0 / len(points))
    return f, (np.asarray(points) * w[:, None]).sum(axis=0)


class WallForceOnBall(LeafSystem):
    """The walls' contact force on one ball of the plant (``wall_force_on``), as the quasi-static
    engine's ``tip_wall_force`` output.

    Input ports:
        contact_results: abstract ContactResults (the plant's).
        body_poses: abstract list[RigidTransform] indexed by BodyIndex (the plant's).

    Output ports:
        wall_force: (6) f_W [N], then where it acts p_WC [m] (the contact centroids, weighted by
            force; the ball's centre without contact).

    Args:
        plant: the finalised MultibodyPlant.
        inspector: its SceneGraph's ``model_inspector()``.
        body_index: the ball's BodyIndex.
    """

    def __init__(self, plant, inspector, body_index) -> None:
        super().__init__()
        self._index = int(body_index)
        self._body = set(plant.GetCollisionGeometriesForBody(plant.get_body(body_index)))
        self._walls = wall_geometries(plant, inspector)
        self._contact_port = self.DeclareAbstractInputPort("contact_results", AbstractValue.Make(ContactResults()))
        self._poses_port = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        self._output = self.DeclareVectorOutputPort("wall_force", 6, self._calc,
                                                    prerequisites_of_calc={self.all_input_ports_ticket()})

    def get_contact_results_input_port(self):
        return self._contact_port

    def get_body_poses_input_port(self):
        return self._poses_port

    def get_wall_force_output_port(self):
        return self._output

    def _calc(self, context, output):
        f, p_WC = wall_force_on(self._contact_port.Eval(context), self._body, self._walls)
        if p_WC is None:
            p_WC = self._poses_port.Eval(context)[self._index].translation()
        output.SetFromVector(np.concatenate([f, p_WC]))


def heart_targets(heart) -> tuple[list[str], np.ndarray, np.ndarray, float]:
    """The atrium's ablation targets.

    Args:
        heart: an Atrium (``drake_models/atrium.py``; a UserAtrium has no rings unless an anatomy
            file gave it its targets: ``drake_models.anatomy.AnatomyTargets``, names and normals
            its own).

    Returns:
        (names ["left_1", ..., "right_18"] (1-based, as chain_plant's ``target_<ring>_<k>``
        visual geometries), p_WT (n, 3) centres [m], n_W (n, 3) unit wall normals into the
        chamber, target radius [m]).
    """
    names, points = [], []
    for side, ring in heart.rings.items():
        names += list(getattr(ring, "names", None) or [f"{side}_{k + 1}" for k in range(len(ring.p_HT))])
        points.append(np.asarray(ring.p_HT, float))
    if not names:
        return [], np.zeros((0, 3)), np.zeros((0, 3)), 0.0
    p_WT = np.concatenate(points)
    if "anatomy" in heart.rings:  # an anatomy file's targets carry their normals and touch radius
        ring = heart.rings["anatomy"]
        return names, p_WT, np.asarray(ring.n_HT, float), float(ring.radius)
    # The targets lie on the endocardial ellipsoid (heart.py): its outward normal is
    # grad((x/a)^2) ~ p / a^2; the chamber is on the other side.
    outward = p_WT / np.asarray(heart.semi_axes, float) ** 2
    n_W = -outward / np.linalg.norm(outward, axis=1, keepdims=True)
    return names, p_WT, n_W, 0.5 * float(heart.params.target_diameter)


def targets_touched(p_W_tip, p_WT: np.ndarray, n_W: np.ndarray, ball_radius: float, target_radius: float,
                    tolerance: float = TOUCH_TOLERANCE, axis_start=None) -> np.ndarray:
    """Which targets a ball centred at ``p_W_tip`` touches (see the module docstring), or an
    electrode of that radius whose axis runs from ``axis_start`` to ``p_W_tip``, its dome's centre
    (``drake_models.electrode.touches``: the one rule for both, its whole surface counted).

    Args:
        p_W_tip: (3,) the tip ball's centre [m].
        p_WT: (n, 3) target centres on the wall [m].
        n_W: (n, 3) unit wall normals at the targets, into the chamber.
        ball_radius: [m].
        target_radius: [m] (half the target's diameter).
        tolerance: how far the ball's surface may be from the wall [m].
        axis_start: (3,) the electrode axis's proximal end [m] (None: a ball).

    Returns:
        (n,) bool.
    """
    return electrode.touches(p_W_tip, p_WT, n_W, ball_radius, target_radius, tolerance, axis_start)


class TargetTouchTracker(LeafSystem):
    """Remembers which ablation targets the tip ball has touched (``targets_touched``).

    Input ports:
        body_poses: abstract list[RigidTransform] indexed by BodyIndex (the plant's ``body_poses``),
            or with ``n_positions``: ball_positions (3 n) the ball centres [m], the tip's last.

    Output ports:
        touched: (n_targets,) 1.0 for each target touched at any update so far, else 0.0 (the
            discrete state; targets in ``names`` order).

    Updates every ``period`` seconds and at initialisation.

    Args:
        tip_body_index: the plant's BodyIndex of the tip ball.
        names, p_WT, n_W, target_radius: from ``heart_targets``.
        ball_radius: [m].
        period: [s].
        moving_wall: the targets ride on a moving wall (``drake_models.wall_motion``): the input
            port ``anatomy_offsets`` (6, the quasi-static engine's) gives the wall's offset
            (its last 3) for the chain's pose on ``body_poses``; they are at p_WT + offset.
        electrode_length: the electrode's length [m], dome included, along the tip body's z axis
            (``drake_models.electrode``; 0: the tip ball).
        n_positions: read the tip ball's centre from a ``ball_positions`` vector input (3 n, the
            tip's last: the device's centres) instead of ``body_poses`` (every body's frame, of
            which the tracker needs one translation; issue 48): n, or None for ``body_poses``.
            Only for the tip ball (no electrode beyond it: its axis needs the tip's frame).
    """

    def __init__(self, tip_body_index, names: Sequence[str], p_WT: np.ndarray, n_W: np.ndarray,
                 target_radius: float, ball_radius: float, period: float, moving_wall: bool = False,
                 electrode_length: float = 0.0, n_positions: int | None = None) -> None:
        super().__init__()
        self.set_name("target_touches")
        self.names = list(names)
        self._tip = int(tip_body_index)
        self._p_WT = np.asarray(p_WT, float).reshape(-1, 3)
        self._n_W = np.asarray(n_W, float).reshape(-1, 3)
        self._target_radius = float(target_radius)
        self._ball_radius = float(ball_radius)
        self._electrode_length = float(electrode_length)
        if n_positions is not None and self._electrode_length > self._ball_radius:
            raise ValueError("TargetTouchTracker: an electrode beyond the tip ball needs body_poses (n_positions=None)")
        self._body_poses_port = None if n_positions is not None else self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()]))
        self._positions_port = None if n_positions is None else self.DeclareVectorInputPort(
            "ball_positions", 3 * int(n_positions))
        self._anatomy_port = self.DeclareVectorInputPort("anatomy_offsets", 6) if moving_wall else None
        self._state_index = self.DeclareDiscreteState(len(self.names))
        self._touched_port = self.DeclareStateOutputPort("touched", self._state_index)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareInitializationDiscreteUpdateEvent(self._update)

    def get_body_poses_input_port(self):
        """The ``body_poses`` port (None when the tracker reads ``ball_positions``)."""
        return self._body_poses_port

    def get_ball_positions_input_port(self):
        """The ``ball_positions`` port (None when the tracker reads ``body_poses``)."""
        return self._positions_port

    def get_touched_output_port(self):
        return self._touched_port

    def get_anatomy_offsets_input_port(self):
        """The ``anatomy_offsets`` port (None for a fixed wall)."""
        return self._anatomy_port

    def _update(self, context, discrete_state):
        if self._positions_port is not None:
            pose, p_tip = None, self._positions_port.Eval(context)[-3:]
        else:
            pose = self._body_poses_port.Eval(context)[self._tip]
            p_tip = pose.translation()
        p_WT = self._p_WT
        if self._anatomy_port is not None:
            p_WT = p_WT + self._anatomy_port.Eval(context)[3:]
        start = None if self._electrode_length <= self._ball_radius else electrode.axis_start(
            p_tip, pose.rotation().col(2), self._ball_radius, self._electrode_length)
        now = targets_touched(p_tip, p_WT, self._n_W, self._ball_radius, self._target_radius, axis_start=start)
        old = context.get_discrete_state(self._state_index).get_value()
        discrete_state.get_mutable_vector(self._state_index).SetFromVector(np.maximum(old, now))
        return EventStatus.Succeeded()

    def touched_names(self, context) -> list[str]:
        """The names of the targets touched so far (this system's context or the diagram's root context)."""
        x = self._touched_port.Eval(subsystem_context(self, context))
        return [n for n, v in zip(self.names, x) if v > 0.5]
