"""MagneticWrenchSystem: the magnetic (and sleeve) wrenches on every ball of a chain, for a plant.

Every number comes from the chain's energy as the compiled kernel
``drake_models.kernels.chain_wrenches`` (ball-ball dipole interactions, the external
field, the sleeve's bending; the numpy ``chain_energy`` is its tests' reference): the force on
ball i is -dU/dp_i and its torque m_hat_i x (-dU/dm_hat_i). Gravity is left to the plant. Ball i's dipole points along
its body frame's +x axis.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialForce
from pydrake.multibody.plant import ExternallyAppliedSpatialForce
from pydrake.systems.framework import LeafSystem

from ballchain.infrastructure.arg_checks import require_type
from ballchain.drake_models.kernels import chain_wrenches, dipole_field_and_gradient
from ballchain.infrastructure.errors import NonFiniteSignal, UserInputError
from ballchain.drake_models.field_sources import FieldSource, FieldSources, MagnetSource
from ballchain.drake_models.params import BallChain, CylinderMagnet, SphereMagnet


class PortDipoles:
    """The point-dipole field of the port magnets, all at once (a FieldSource).

    The same law as ``MagnetSource(model="dipole")`` (``dipole.dipole_field`` and
    ``dipole_field_gradient``, as the compiled ``kernels.dipole_field_and_gradient``),
    without building a MagnetSource per magnet per step: the wrench system rebuilds its external
    field every step while the units turn.

    Args:
        p_WM: (k, 3) magnet centres [m].
        m_W: (k, 3) dipole moments [A m^2].
        bounding_radii: (k,) no field point may be closer than this to a centre [m].
    """

    def __init__(self, p_WM: np.ndarray, m_W: np.ndarray, bounding_radii: np.ndarray):
        self.p_WM = np.ascontiguousarray(p_WM, dtype=float)
        self.m_W = np.ascontiguousarray(m_W, dtype=float)
        self._r2_min = np.ascontiguousarray(np.asarray(bounding_radii, dtype=float) ** 2)

    def field_and_gradient(self, p_W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(B_W (n, 3) [T], G_W (n, 3, 3) [T/m]) summed over the magnets at the points p_W (n, 3)."""
        p = np.ascontiguousarray(p_W, dtype=float).reshape(-1, 3)
        if not np.all(np.isfinite(p)):
            raise NonFiniteSignal("magnetic field points are not finite (NaN or inf)")
        violation, B, G = dipole_field_and_gradient(p, self.p_WM, self.m_W, self._r2_min)
        if violation >= 0:
            i, k = divmod(int(violation), len(self.p_WM))
            raise UserInputError(f"field point {p[i]} m lies within port magnet {k + 1}'s "
                             f"bounding sphere (centre {self.p_WM[k]} m): a magnet cannot be placed on the chain")
        return B, G


def external_field_source(field_source, port_magnets, port_moments, port_radii, magnet_states, model: str):
    """The external field: a fixed source plus the magnets on a ``magnet_states`` port.

    Args:
        field_source: the fixed FieldSource, or None.
        port_magnets: the port magnets' CylinderMagnet / SphereMagnet, in port order.
        port_moments, port_radii: (k,) their dipole moments [A m^2] and bounding radii [m].
        magnet_states: (6 k,) centre p_WM and dipole direction per magnet, or None.
        model: "dipole" (all port magnets at once, ``PortDipoles``) or "exact".

    Returns:
        A FieldSource, or None when there is no field.
    """
    sources = [] if field_source is None else [field_source]
    if magnet_states is not None and len(port_magnets):
        x = np.asarray(magnet_states).reshape(-1, 6)
        if model == "dipole":
            m_hat = x[:, 3:] / np.linalg.norm(x[:, 3:], axis=1, keepdims=True)
            sources.append(PortDipoles(x[:, :3], port_moments[:, None] * m_hat, port_radii))
        else:
            sources += [MagnetSource.pointing(m, row[:3], row[3:], model) for m, row in zip(port_magnets, x)]
    if not sources:
        return None
    return sources[0] if len(sources) == 1 else FieldSources(sources)


class MagneticWrenchSystem(LeafSystem):
    """Applied spatial forces on the balls of a chain from the chain's own dipoles and outside.

    Input ports:
        body_poses: abstract list[RigidTransform] indexed by BodyIndex (connect the plant's
            ``body_poses`` output).
        magnet_states: (only when ``port_magnets`` is not empty) vector of size 6 k: for each
            magnet its centre p_WM (3) [m] then its dipole direction m_hat_W (3) (unit, or any
            non-zero vector that is normalised).

    Output ports:
        spatial_forces: abstract list[ExternallyAppliedSpatialForce], one per ball, applied at
            the ball's centre, force [N] and torque [N m] in world (connect to the plant's
            ``applied_spatial_force`` input).

    Args:
        chain: the chain's parameters (the sleeve is included when ``chain.sleeve``).
        ball_body_indices: the plant's BodyIndex of balls 1..n, in chain order.
        field_source: a fixed external FieldSource (e.g. MagnetSource, UniformField), or None.
        port_magnets: magnets whose poses come from the ``magnet_states`` port.
        base_direction_W: (3,) sheath axis clamping the sleeve's first bend.
        model: "dipole" or "exact" field model of the port magnets.
    """

    def __init__(
        self,
        chain: BallChain,
        ball_body_indices: Sequence,
        field_source: FieldSource | None = None,
        port_magnets: Sequence[CylinderMagnet | SphereMagnet] = (),
        base_direction_W=(1.0, 0.0, 0.0),
        model: str = "dipole",
    ):
        super().__init__()
        require_type(chain, BallChain, "MagneticWrenchSystem chain", "a BallChain")
        if len(ball_body_indices) != chain.n_balls:
            raise UserInputError(
                f"MagneticWrenchSystem: {len(ball_body_indices)} body indices for a chain of "
                f"{chain.n_balls} balls"
            )
        self._chain = chain
        self._indices = [int(i) for i in ball_body_indices]
        self._field_source = field_source
        self._port_magnets = list(port_magnets)
        self._model = model
        base = np.asarray(base_direction_W, float)
        self._base = base / np.linalg.norm(base)
        self._body_poses_port = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()]))
        self._magnet_port = None
        self._port_moments = np.array([m.dipole_moment for m in self._port_magnets])
        self._port_radii = np.array([m.bounding_radius for m in self._port_magnets])
        if self._port_magnets:
            self._magnet_port = self.DeclareVectorInputPort(
                "magnet_states", 6 * len(self._port_magnets))
        # The output's elements are allocated once and updated in place every step.
        self._forces = []
        for index in self._indices:
            f = ExternallyAppliedSpatialForce()
            f.body_index = self._body_index_type(index)
            f.p_BoBq_B = np.zeros(3)
            f.F_Bq_W = SpatialForce(np.zeros(3), np.zeros(3))
            self._forces.append(f)
        self._spatial_forces_port = self.DeclareAbstractOutputPort(
            "spatial_forces",
            lambda: AbstractValue.Make(list(self._forces)),
            self._calc_spatial_forces,
        )

    @staticmethod
    def _body_index_type(index: int):
        from pydrake.multibody.tree import BodyIndex

        return BodyIndex(index)

    def get_body_poses_input_port(self):
        return self._body_poses_port

    def get_magnet_states_input_port(self):
        return self._magnet_port

    def get_spatial_forces_output_port(self):
        return self._spatial_forces_port

    def external_field(self, context) -> FieldSource | None:
        """The field source in effect for this context (the fixed one plus the port magnets)."""
        states = None if self._magnet_port is None else self._magnet_port.Eval(context)
        x = None if states is None else np.asarray(states).reshape(-1, 6)
        if x is not None and not (np.isfinite(x).all() and x[:, 3:].any(axis=1).all()):
            for k, row in enumerate(x):  # name the magnet, the part and the time, not just "not finite"
                what = None
                if not np.all(np.isfinite(row[:3])):
                    what = f"centre p_WM {row[:3].tolist()} is not finite"
                elif not np.all(np.isfinite(row[3:])):
                    what = f"dipole direction {row[3:].tolist()} is not finite"
                elif not np.any(row[3:]):
                    what = "dipole direction is zero (it cannot be normalised)"
                if what:
                    raise NonFiniteSignal(f"{self.get_name()}: input port 'magnet_states', magnet {k + 1} "
                                          f"of {len(x)}: {what} at t = {context.get_time():.6g} s")
        return external_field_source(self._field_source, self._port_magnets, self._port_moments,
                                     self._port_radii, states, self._model)

    def ball_states(self, context) -> tuple[np.ndarray, np.ndarray]:
        """Ball centres p_W (n, 3) [m] and dipole directions m_hat_W (n, 3) from the poses."""
        poses = self._body_poses_port.Eval(context)
        X = np.array([poses[i].GetAsMatrix34() for i in self._indices])  # (n, 3, 4)
        if not np.all(np.isfinite(X)):
            ball = int(np.argmax(~np.all(np.isfinite(X.reshape(len(X), -1)), axis=1)))
            raise NonFiniteSignal(f"{self.get_name()}: input port 'body_poses': the pose of ball {ball + 1} "
                                  f"is not finite at t = {context.get_time():.6g} s")
        return X[:, :, 3], X[:, :, 0]

    def calc_wrenches(self, context) -> tuple[np.ndarray, np.ndarray]:
        """Forces (n, 3) [N] and torques (n, 3) [N m] on the balls, in world."""
        p, m_hat = self.ball_states(context)
        return chain_wrenches(self._chain, p, m_hat, self.external_field(context), self._base)

    def _calc_spatial_forces(self, context, output) -> None:
        forces, torques = self.calc_wrenches(context)
        for f, force, torque in zip(self._forces, forces, torques):
            f.F_Bq_W = SpatialForce(torque, force)
        output.set_value(self._forces)
