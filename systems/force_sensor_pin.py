"""ForceSensorPin: a force-sensor pin holding a ball's centre on a point through a stiff spring.

The paper measures the tip force with force-sensor pins at the pulmonary-vein ostia. In a
simulation the pin is a linear spring of stiffness k from the pin point p_WP to the centre of the
held body B (the chain's tip ball):

    force on B:                 f_W = -k (p_WB - p_WP)
    the sensor's reading:       r_W = -f_W = k (p_WB - p_WP)

the reading being the force the body presses on the pin (with the body pushing the pin along
a direction a, the pin gives way along a and ``r_W . a > 0``). The spring acts at B's centre, so
it applies no torque.

The force enters the plant as generalized forces (``applied_generalized_force`` input): B must
be a free body whose inboard joint is a QuaternionFloatingJoint from the world frame to B's body
frame, whose velocities are [w_WB, v_WB] expressed in world, so the generalized force of the
translational velocities is the world force at B's origin.

The spring is explicit in a discrete plant (the input is the last step's pose). With the joint's
implicit translational damping c [N s/m], the ball's mass m and the time step h, the spring
alone (m x'' + c x' + k x = 0, semi-implicit Euler) is stable for k < 2 (2 m + c h) / h^2,
about 2 c / h when the ball is overdamped (m << c h): ``stability_bound`` returns it.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import BasicVector, LeafSystem
from ballchain.infrastructure.arg_checks import as_vector, require_positive
from ballchain.infrastructure.errors import UserInputError


def stability_bound(time_step: float, damping: float, mass: float) -> float:
    """The largest stable stiffness [N/m] of an explicit spring on a damped (implicit) body.

    Semi-implicit Euler of m x'' = -k x - c x' with the damping implicit: the iteration matrix's
    eigenvalues stay inside the unit circle for k h^2 / (m + c h) < 2 (1 + m / (m + c h)), i.e.
    k < 2 (2 m + c h) / h^2.
    """
    if time_step <= 0 or damping < 0 or mass <= 0:
        raise UserInputError("stability_bound: time step and mass must be positive, damping non-negative")
    return 2.0 * (2.0 * mass + damping * time_step) / time_step**2


def _floating_translation_indices(plant, body) -> np.ndarray:
    """Indices in v of the world-frame translational velocity of a body on a world floating joint."""
    joints = [plant.get_joint(j) for j in plant.GetJointIndices()
              if plant.get_joint(j).child_body().index() == body.index()]
    if len(joints) != 1 or joints[0].type_name() != "quaternion_floating":
        raise UserInputError(f"ForceSensorPin: body {body.name()!r} must hang on a QuaternionFloatingJoint")
    joint = joints[0]
    identity = RigidTransform()
    if (joint.parent_body().index() != plant.world_body().index()
            or not joint.frame_on_parent().GetFixedPoseInBodyFrame().IsExactlyEqualTo(identity)
            or not joint.frame_on_child().GetFixedPoseInBodyFrame().IsExactlyEqualTo(identity)):
        raise UserInputError(f"ForceSensorPin: the floating joint of {body.name()!r} must go from the world "
                         "frame to the body frame (its velocities are then [w_WB, v_WB] in world)")
    start = joint.velocity_start()
    return np.arange(start + 3, start + 6)


class ForceSensorPin(LeafSystem):
    """A linear spring from a fixed pin point to a free body's centre, read as a force sensor.

    Input ports:
        body_poses: abstract list[RigidTransform] indexed by BodyIndex (the plant's
            ``body_poses`` output).

    Output ports:
        generalized_force: (plant.num_velocities(),) the spring's force on the body as
            generalized forces (connect to the plant's ``applied_generalized_force`` input).
        reading: (3,) the force [N] the body presses on the pin, in world: k (p_WB - p_WP).
        deflection: (3,) p_WB - p_WP [m], how far the pin gives way.

    Args:
        plant: the finalised MultibodyPlant.
        body: the held body (on a QuaternionFloatingJoint from the world frame).
        p_WP: (3,) the pin point in world [m].
        stiffness: k [N/m], positive.
    """

    def __init__(self, plant, body, p_WP, stiffness: float):
        super().__init__()
        as_vector(p_WP, "ForceSensorPin p_WP", unit="m")
        require_positive(stiffness, "ForceSensorPin stiffness", "N/m")
        if not plant.is_finalized():
            raise UserInputError("ForceSensorPin: finalise the plant first")
        self._p_WP = np.asarray(p_WP, dtype=float).reshape(3)
        if not np.all(np.isfinite(self._p_WP)):
            raise UserInputError(f"ForceSensorPin: the pin point must be finite, got {p_WP}")
        if not (np.isfinite(stiffness) and stiffness > 0):
            raise UserInputError(f"ForceSensorPin: the stiffness must be positive, got {stiffness}")
        self._k = float(stiffness)
        self._body_index = int(body.index())
        self._v_indices = _floating_translation_indices(plant, body)
        self._nv = plant.num_velocities()
        self._poses_port = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        self._generalized_port = self.DeclareVectorOutputPort(
            "generalized_force", BasicVector(self._nv), self._calc_generalized_force)
        self._reading_port = self.DeclareVectorOutputPort("reading", BasicVector(3), self._calc_reading)
        self._deflection_port = self.DeclareVectorOutputPort("deflection", BasicVector(3), self._calc_deflection)

    @property
    def stiffness(self) -> float:
        return self._k

    @property
    def p_WP(self) -> np.ndarray:
        return self._p_WP.copy()

    def get_body_poses_input_port(self):
        return self._poses_port

    def get_generalized_force_output_port(self):
        return self._generalized_port

    def get_reading_output_port(self):
        return self._reading_port

    def get_deflection_output_port(self):
        return self._deflection_port

    def deflection(self, context) -> np.ndarray:
        """p_WB - p_WP [m]."""
        return self._poses_port.Eval(context)[self._body_index].translation() - self._p_WP

    def _calc_deflection(self, context, output) -> None:
        output.SetFromVector(self.deflection(context))

    def _calc_reading(self, context, output) -> None:
        output.SetFromVector(self._k * self.deflection(context))

    def _calc_generalized_force(self, context, output) -> None:
        tau = np.zeros(self._nv)
        tau[self._v_indices] = -self._k * self.deflection(context)
        output.SetFromVector(tau)
