"""A field-following operator: steers the tip towards one point by turning a unit's magnet.

``FieldFollowingOperator`` is the station notebook's operator, a LeafSystem in the station
diagram (added with ``MakeStation``'s ``add_systems`` hook, the unit's ``joystick_source:
external``). It uses the paper's simplification, the tip aligns with the field at the tip, and
closes it through the tip's position every ``period`` (100 ms):

1. it looks at the tip (its centre and its direction from the ball before it: ``TipObserver``)
   and tilts the wanted tip direction towards the target (``wanted_tip_direction``): by the
   angle under which the error across the tip is seen from ``lever`` behind the tip, at most
   ``max_tilt``;
2. it asks for the dipole whose field at the tip points that way (``neutral_direction``, the
   inverse dipole law, for the magnet's fixed centre);
3. it moves the stick (the paper's world-frame mapping: the stick is the magnet's angular
   velocity in world) to turn the magnet's dipole, as it is now, there along the shortest
   rotation at full stick, and releases it when the rotation is done
   (``station_units.joystick_keys_for_rotation``: the stick, pre-compensated for the mapper's
   dead band, and for how long).

Unlike ``simulated_operator.SimulatedOperator`` (which learns an unknown mapping by watching,
probes the stick for its first 1.5 s, drives the feeder and touches wall targets), this one
knows the magnet's pose and the field law, and leaves the feeder to the scenario: it shows what
the field alone does to the tip, in a run of a second or two.

It does not plan around the wall: a chain leaning on the endocardium can stall short of the
target. ``add_field_following_operator`` adds it (with a ``TipObserver``) for one unit in
``MakeStation``'s ``add_systems`` hook; ``notebooks/station.ipynb`` runs it with ``run_station``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from ballchain.drake_models.dipole_inversion import neutral_direction
from ballchain.infrastructure.errors import UserInputError, require_finite_fields
from ballchain.systems.station_units import TipObserver, joystick_keys_for_rotation
from ballchain.systems.unit_config import MagnetUnitConfig


@dataclass
class FieldFollowingParams:
    """The field-following operator's settings (SI).

    Attributes:
        p_W_target: (3,) the point it steers the tip ball's centre to [m].
        p_WM: (3,) the centre of the magnet it turns [m] (the unit's ``config.p_WM``).
        omega_max: the unit's angular speed at full stick [rad/s] (``teleop_omega_max``).
        dead_band: the unit's stick dead band (``teleop_dead_band``), in [0, 1).
        period: how often it looks and moves the stick [s].
        start_time: its first look [s] (before it, the stick rests).
        max_tilt: the largest tilt of the wanted tip direction per look [rad].
        lever: the error across the tip is turned into a tilt as seen from this far behind the
            tip [m] (the tilt is ``atan(|error across| / lever)``, at most ``max_tilt``).
    """

    p_W_target: tuple
    p_WM: tuple
    omega_max: float
    dead_band: float = MagnetUnitConfig.teleop_dead_band
    period: float = 0.1
    start_time: float = 0.0
    max_tilt: float = np.deg2rad(15.0)
    lever: float = 5e-3

    def validate(self) -> "FieldFollowingParams":
        require_finite_fields(self)
        for name in ("p_W_target", "p_WM"):
            if np.shape(getattr(self, name)) != (3,):
                raise UserInputError(f"FieldFollowingParams.{name} must be a point (3,) [m], got {getattr(self, name)!r}")
        for name in ("omega_max", "period", "lever"):
            if not getattr(self, name) > 0:
                raise UserInputError(f"FieldFollowingParams.{name} must be > 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.dead_band < 1.0:
            raise UserInputError(f"FieldFollowingParams.dead_band must be in [0, 1), got {self.dead_band!r}")
        if not 0.0 <= self.max_tilt <= np.pi / 2:
            raise UserInputError(f"FieldFollowingParams.max_tilt must be in [0, pi/2] rad, got {self.max_tilt!r}")
        return self


def wanted_tip_direction(p_tip: np.ndarray, d_tip: np.ndarray, p_target: np.ndarray, max_tilt: float,
                         lever: float) -> np.ndarray:
    """The tip direction the operator wants: ``d_tip`` tilted towards the target.

    Only the error across the tip (perpendicular to ``d_tip``) is what a tilt can fix; the tilt
    is the angle under which it is seen from ``lever`` behind the tip, at most ``max_tilt``.

    Args:
        p_tip: (3,) the tip ball's centre [m].
        d_tip: (3,) the tip's unit direction.
        p_target: (3,) the target [m].
        max_tilt: [rad]. lever: [m].

    Returns:
        (3,) unit vector in the plane of ``d_tip`` and the error (``d_tip`` with no error across).
    """
    d = np.asarray(d_tip, float)
    e = np.asarray(p_target, float) - np.asarray(p_tip, float)
    e_perp = e - (e @ d) * d
    size = float(np.linalg.norm(e_perp))
    tilt = min(max_tilt, float(np.arctan2(size, lever)))
    return np.cos(tilt) * d + np.sin(tilt) * e_perp / max(size, 1e-12)


class FieldFollowingOperator(LeafSystem):
    """Steers the tip towards one point through a unit's world-frame joystick (module docstring).

    Input ports:
        p_WT: (3,) the tip ball's centre [m] (``TipObserver``).
        tip_direction_W: (3,) the tip's unit direction (``TipObserver``).
        m_W: (3,) the magnet's dipole, any length (the unit magnet's ``m_W``).

    Output ports:
        joystick: (3,) stick axes in [-1, 1] (into the unit's TeleoperationMapper, world frame).

    State: discrete (4,): the stick (3,) and when it is released [s]. The stick is set at each
    look (a periodic discrete update: like every discrete system, the plant sees it from its
    next step on) and reads zero from the release time on.

    Args:
        params: FieldFollowingParams.
    """

    def __init__(self, params: FieldFollowingParams, name: str = "operator") -> None:
        super().__init__()
        self.params = p = params.validate()
        self.set_name(name)
        self._target = np.asarray(p.p_W_target, float)
        self._p_WM = np.asarray(p.p_WM, float)
        self._p = self.DeclareVectorInputPort("p_WT", 3)
        self._d = self.DeclareVectorInputPort("tip_direction_W", 3)
        self._m = self.DeclareVectorInputPort("m_W", 3)
        # A zero stick released at t = 0: it rests until the first look.
        self._state = self.DeclareDiscreteState(BasicVector(np.zeros(4)))
        self.DeclareVectorOutputPort("joystick", 3, self._calc_joystick,
                                     prerequisites_of_calc={self.time_ticket(), self.xd_ticket()})
        self.DeclarePeriodicDiscreteUpdateEvent(p.period, p.start_time, self._look)

    def get_p_WT_input_port(self):
        return self._p

    def get_tip_direction_input_port(self):
        return self._d

    def get_m_W_input_port(self):
        return self._m

    def stick_for(self, p_tip: np.ndarray, d_tip: np.ndarray, m_W: np.ndarray, t: float) -> tuple[np.ndarray, float]:
        """The stick (3,) and its release time [s] decided at a look at time t [s]."""
        p = self.params
        d_goal = wanted_tip_direction(p_tip, d_tip, self._target, p.max_tilt, p.lever)
        m_goal = neutral_direction(self._p_WM, p_tip, d_goal)  # the dipole whose field at the tip is along d_goal
        keys = joystick_keys_for_rotation(m_W, m_goal, p.omega_max, start_time=t, dead_band=p.dead_band)
        if len(keys) == 1:  # already there
            return np.zeros(3), t
        return np.asarray(keys[0].axes, float), float(keys[1].time)

    def _look(self, context, discrete_state):
        stick, release = self.stick_for(self._p.Eval(context), self._d.Eval(context), self._m.Eval(context),
                                        context.get_time())
        discrete_state.get_mutable_vector().SetFromVector(np.append(stick, release))
        return EventStatus.Succeeded()

    def _calc_joystick(self, context, output):
        x = context.get_discrete_state_vector().CopyToVector()
        output.SetFromVector(x[:3] if context.get_time() < x[3] else np.zeros(3))


def add_field_following_operator(builder, ports, unit, p_W_target, start_time: float = 0.0,
                                 period: float = 0.1, name: str = "operator") -> dict:
    """Add the operator for one unit to a station (``MakeStation``'s ``add_systems`` hook).

    Adds ``tip_observer`` (TipObserver on the chain's body poses) and the operator, reading the
    tip and the unit magnet's ``m_W`` and driving the unit's ``joystick`` input.

    Args:
        builder: the station's DiagramBuilder (the hook's first argument).
        ports: the hook's ``StationPorts``.
        unit: the unit's ``MagnetUnitConfig`` (``joystick_source: external``, ``teleop_frame: world``):
            its name, ``teleop_omega_max`` and ``teleop_dead_band``.
        p_W_target: (3,) where to steer the tip ball's centre [m].
        start_time: the operator's first look [s]. period: between looks [s].
        name: the operator system's name.

    Returns:
        {"operator": FieldFollowingOperator, "tip_observer": TipObserver} (the hook's dict).

    Raises:
        UserInputError: the unit's stick is not external, or its mapping is not the world frame.
    """
    if unit.joystick_source != "external":
        raise UserInputError(f"unit {unit.name!r}: the field-following operator needs joystick_source: external, "
                             f"got {unit.joystick_source!r}")
    if unit.name not in ports.joystick_inputs:
        raise UserInputError(f"unit {unit.name!r} is not a unit of this station with an external stick "
                             f"(those: {sorted(ports.joystick_inputs)})")
    if unit.teleop_frame != "world":
        raise UserInputError(f"unit {unit.name!r}: the field-following operator moves the world-frame stick "
                             f"(teleop_frame: world), got {unit.teleop_frame!r}")
    cp = ports.chain
    tip = builder.AddSystem(TipObserver(cp.ball_body_indices[-1], cp.ball_body_indices[-2]))
    builder.Connect(ports.body_poses, tip.get_body_poses_input_port())
    handles = ports.units[unit.name]
    operator = builder.AddSystem(FieldFollowingOperator(FieldFollowingParams(
        p_W_target=tuple(np.asarray(p_W_target, float)), p_WM=tuple(np.asarray(handles.config.p_WM, float)),
        omega_max=unit.teleop_omega_max, dead_band=unit.teleop_dead_band, period=period, start_time=start_time),
        name=name))
    builder.Connect(tip.GetOutputPort("p_WT"), operator.get_p_WT_input_port())
    builder.Connect(tip.GetOutputPort("tip_direction_W"), operator.get_tip_direction_input_port())
    builder.Connect(handles.magnet.GetOutputPort("m_W"), operator.get_m_W_input_port())
    builder.Connect(operator.GetOutputPort("joystick"), ports.joystick_inputs[unit.name])
    return {"operator": operator, "tip_observer": tip}
