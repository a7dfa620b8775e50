"""A toy third device, added through the API alone: a single magnet on an elastic rod.

One magnetic tip (a sphere magnet) on a rod of length l beyond the sheath exit, with a bending
spring at the exit (stiffness EI / l, a cantilever's): at each update the rod points where the
spring's energy 1/2 (EI / l) |theta|^2 less the magnet's -m . B at the tip is least (theta the
rod's rotation from the sheath axis), warm-started from the last. The field is the station's:
its fixed field and the units' magnets on ``magnet_states``. The length follows its own slide,
driven by a feeder command (``v_insert_cmd`` [m/s], clamped to ``MIN_LENGTH``..``MAX_LENGTH``).

Nothing in the package knows it: it is a ``DeviceModel`` subclass and one call,
``register_device_model("magnet_on_rod", "statics", MagnetOnRod)``.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import BasicVector, LeafSystem
from scipy.optimize import minimize

import ballchain as bc
from ballchain.drake_models.field_sources import MagnetSource, rotation_with_z_along
from ballchain.systems.chain_model import subsystem_context
from ballchain.systems.device_model import OperatorInputs

EI = 1e-5  # [N m^2] a soft polymer tube's bending stiffness
MOMENT = 0.0157  # [A m^2] a 3 mm N52 sphere
RADIUS = 1.5e-3  # [m]
MIN_LENGTH, START_LENGTH, MAX_LENGTH = 10e-3, 15e-3, 25e-3  # [m] beyond the sheath exit


class MagnetRod(LeafSystem):
    """The magnet on its rod (module docstring).

    Input ports: magnet_states (6 k), v_insert_cmd (1). Output ports: body_poses (world, the
    rod's base at the exit, the magnet), tip_wall_force (6: zero, then the magnet's centre).
    State (discrete, 3): length [m], the rod's rotation vector (2, across the sheath axis).
    """

    def __init__(self, p_E, axis, coupling, period: float) -> None:
        super().__init__()
        self.set_name("magnet_on_rod")
        self.p_E, self.period = np.asarray(p_E, float), float(period)
        self.R_E = rotation_with_z_along(axis)  # columns: two across the axis, then the axis
        self._coupling = coupling
        k = len(coupling.port_magnets)
        self._states = self.magnet_states = self.DeclareVectorInputPort("magnet_states", 6 * k) if k else None
        self._push = self.DeclareVectorInputPort("v_insert_cmd", 1)
        self._x = self.DeclareDiscreteState(BasicVector([START_LENGTH, 0.0, 0.0]))
        self.DeclareAbstractOutputPort("body_poses", lambda: AbstractValue.Make([RigidTransform()]),
                                       self._calc_poses, prerequisites_of_calc={self.xd_ticket()})
        self.DeclareVectorOutputPort("tip_wall_force", 6, self._calc_force, prerequisites_of_calc={self.xd_ticket()})
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)

    def state(self, context) -> np.ndarray:
        """(length [m], rotation vector (2,)) in this system's context."""
        return context.get_discrete_state(self._x).get_value()

    def rod(self, theta: np.ndarray) -> np.ndarray:
        """The rod's rotation for a rotation vector (2,) across the sheath axis (Rodrigues)."""
        w = self.R_E[:, :2] @ theta
        angle = np.linalg.norm(w)
        if angle < 1e-12:
            return np.eye(3)
        K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) / angle
        return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K

    def tip(self, x: np.ndarray) -> np.ndarray:
        return self.p_E + x[0] * self.rod(x[1:]) @ self.R_E[:, 2]

    def _field(self, context):
        sources = [] if self._coupling.field_source is None else [self._coupling.field_source]
        if self._states is not None:
            s = self._states.Eval(context).reshape(-1, 6)
            sources += [MagnetSource.pointing(m, row[:3], row[3:], self._coupling.model)
                        for m, row in zip(self._coupling.port_magnets, s)]
        return lambda p: sum((src.field(p[None, :])[0] for src in sources), np.zeros(3))

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._x).get_value().copy()
        x[0] = float(np.clip(x[0] + self._push.Eval(context)[0] * self.period, MIN_LENGTH, MAX_LENGTH))
        B = self._field(context)

        def energy(theta):
            d = self.rod(theta) @ self.R_E[:, 2]
            return 0.5 * EI / x[0] * theta @ theta - MOMENT * d @ B(self.p_E + x[0] * d)

        x[1:] = minimize(energy, x[1:], method="BFGS", options={"gtol": 1e-10}).x
        discrete_state.get_mutable_vector(self._x).SetFromVector(x)

    def _calc_poses(self, context, output):
        x = context.get_discrete_state(self._x).get_value()
        R = RotationMatrix(self.rod(x[1:]) @ self.R_E)
        output.set_value([RigidTransform(), RigidTransform(R, self.p_E), RigidTransform(R, self.tip(x))])

    def _calc_force(self, context, output):
        output.SetFromVector(np.concatenate([np.zeros(3), self.tip(context.get_discrete_state(self._x).get_value())]))


class MagnetOnRod(bc.DeviceModel):
    """The magnet on its elastic rod as a device: its bodies the rod's base and the magnet."""

    def __init__(self, system: MagnetRod) -> None:
        self.system = system
        self.time_step = self.move_period = system.period

    @classmethod
    def add_to_station(cls, builder, scenario, heart, coupling, params=None) -> MagnetOnRod:
        p_E, axis = (heart.p_HE, heart.sheath_axis_H) if heart is not None else (np.zeros(3), np.array([1.0, 0, 0]))
        return cls(builder.AddSystem(MagnetRod(p_E, axis, coupling, scenario.statics_period)))

    body_indices = property(lambda self: [1, 2])
    tip_radius = property(lambda self: RADIUS)
    p_WE = property(lambda self: self.system.p_E)
    sheath_axis_W = property(lambda self: self.system.R_E[:, 2])
    length = property(lambda self: MAX_LENGTH)
    initial_inserted_length = property(lambda self: START_LENGTH)

    def max_inserted_length(self) -> float:
        return MAX_LENGTH

    def in_sheath(self, p_W):
        return np.linalg.norm(np.asarray(p_W) - self.p_WE, axis=1) < 1e-9  # the rod's base

    def get_magnet_states_input_port(self):
        return self.system.magnet_states

    def operator_inputs(self) -> OperatorInputs:
        return OperatorInputs(feeder_command_input=self.system.GetInputPort("v_insert_cmd"))

    def get_body_poses_output_port(self):
        return self.system.GetOutputPort("body_poses")

    def get_tip_wall_force_output_port(self):
        return self.system.GetOutputPort("tip_wall_force")

    def add_visualizer(self, builder, meshcat, scenario, heart, targets):
        raise bc.UserInputError("the magnet on its rod has no Meshcat view (a toy)")

    def body_positions(self, context) -> np.ndarray:
        poses = self.get_body_poses_output_port().Eval(subsystem_context(self.system, context))
        return np.array([poses[i].translation() for i in self.body_indices])

    def is_finite(self, context) -> bool:
        return bool(np.isfinite(self.system.state(subsystem_context(self.system, context))).all())

    def non_finite_part(self, context) -> str:
        return "the rod's state"

    def metrics(self, context) -> dict:
        x = self.system.state(self.system.GetMyContextFromRoot(context))
        return {"length_mm": float(x[0] * 1e3), "bend_deg": float(np.degrees(np.linalg.norm(x[1:])))}


# The one registration.
bc.register_device_model("magnet_on_rod", "statics", MagnetOnRod)
