"""The steerable catheter as a device model (``device: steerable_catheter``, ``engine: statics``).

The paper's manual comparison arm behind the ``DeviceModel`` interface, so that ``MakeStation``
builds it into the same ``Station`` as the ball chain and ``run_station`` runs it: the
``SteerableCatheterSystem`` (quasi-static, updated every ``scenario.statics_period``) and the
``ManualHand`` on its handle (``systems/catheter_station.py``). Its bodies are the rod's nodes
(``body_poses`` 1..n + 1, the tip sphere's centre last); its electrode is the distal 3.5 mm
(cylinder and dome, ``CatheterElectrode``: its whole surface touches); its
actuation input is ``handle`` (3), driven by the hand, whose stick and push an operator drives
(``operator_inputs``: ``hand.joystick``, and the push as the feeder command); its metrics are
the windup (the handle's twist, the twist at the sheath exit, slips) and the hand's switches.
It feels no field (it is not magnetic) and reports no wall force (zero).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ballchain.drake_models.atrium_sdf import atrium_sdf
from ballchain.drake_models.electrode import CATHETER_ELECTRODE_LENGTH
from ballchain.infrastructure.errors import UserInputError
from ballchain.systems.catheter_station import CatheterMeshcat, CatheterParams, ManualHand, SteerableCatheterSystem
from ballchain.systems.sheath_plan_cache import RingSheathPlans, heart_rings
from ballchain.systems.target_contact import heart_targets
from ballchain.systems.chain_model import subsystem_context
from ballchain.systems.device_model import DeviceModel, Electrode, OperatorInputs


@dataclass
class CatheterElectrode(Electrode):
    """The catheter's distal electrode: the tip sphere's centre is its dome's centre, its axis
    runs ``length - radius`` back along the tip (``drake_models.electrode``)."""

    length: float = CATHETER_ELECTRODE_LENGTH


class CatheterModel(DeviceModel):
    """The steerable catheter and the hand on its handle in a station (module docstring).

    Attributes (besides ``DeviceModel``'s):
        system: the SteerableCatheterSystem; hand: the ManualHand.
    """

    device = "steerable_catheter"
    engine = "statics"
    params_type = CatheterParams
    station_overlays = False  # its Meshcat view draws the atrium, the targets and the rod
    diagram_name = "catheter_in_heart"

    def __init__(self, system: SteerableCatheterSystem, hand: ManualHand) -> None:
        self.system, self.hand = system, hand
        self.time_step = self.move_period = system.period

    @classmethod
    def add_to_station(cls, builder, scenario, heart, coupling, params: CatheterParams | None = None) -> CatheterModel:
        """The catheter at the atrium's sheath exit and the hand on its handle.

        Raises:
            UserInputError: a field to feel (the catheter is not magnetic).
        """
        if coupling.field_source is not None or coupling.port_magnets:
            raise UserInputError("MakeStation: device: steerable_catheter takes no field (field_source, "
                                 "uniform_field, magnets or units): it is not magnetic")
        params = params or CatheterParams()
        sdf = atrium_sdf(heart)
        cat = builder.AddSystem(SteerableCatheterSystem(params.catheter, heart.p_HE, heart.sheath_axis_H, sdf,
                                                        params.initial_length, scenario.statics_period,
                                                        sheath=params.sheath))
        # A steerable sheath: the hand's plans of each ring computed once, kept in the cache (issue 45, H13)
        plan = None if params.sheath is None else RingSheathPlans(
            params.sheath, cat.catheter, cat.septum[0], cat.septum[1], sdf, heart_targets(heart)[3],
            heart_rings(heart), min_out=params.hand.sheath_retract_out)
        hand = builder.AddSystem(ManualHand(params.hand, plan, params.initial_length))
        builder.Connect(hand.GetOutputPort("handle"), cat.GetInputPort("handle"))
        if plan is not None:
            builder.Connect(hand.GetOutputPort("sheath"), cat.GetInputPort("sheath"))
            builder.Connect(cat.GetOutputPort("windup"), hand.GetInputPort("windup"))
            builder.Connect(cat.GetOutputPort("length_out"), hand.GetInputPort("length_out"))
        builder.Connect(cat.GetOutputPort("handle_load"), hand.GetInputPort("handle_load"))
        return cls(cat, hand)

    # --- the geometry --------------------------------------------------------------------------
    @property
    def body_indices(self) -> list:
        return list(range(1, self.system.n_bodies + 1))

    @property
    def tip_radius(self) -> float:
        return self.system.catheter.radius

    @property
    def electrode(self) -> CatheterElectrode:
        """The distal electrode (3.5 mm, cylinder and dome: ``drake_models.electrode``) on the
        tip sphere's body, touching with its whole surface."""
        return CatheterElectrode(int(self.tip_body_index), self.tip_radius, CATHETER_ELECTRODE_LENGTH)

    @property
    def p_WE(self) -> np.ndarray:
        return self.system.rod.p_E

    @property
    def sheath_axis_W(self) -> np.ndarray:
        return self.system.rod.R_E[:, 2]

    @property
    def length(self) -> float:
        return self.system.rod.max_length

    @property
    def initial_inserted_length(self) -> float:
        return self.system.initial_length

    def max_inserted_length(self) -> float:
        return self.system.rod.max_length

    def in_sheath(self, p_W: np.ndarray) -> np.ndarray:
        """The rod's nodes still in the sheath: on its axis behind the exit (a steerable sheath:
        along its centreline, and behind the septum on its axis)."""
        return self.system.in_sheath(p_W, self.tip_radius)

    # --- ports ----------------------------------------------------------------------------------
    def actuation_input_ports(self) -> dict:
        return {"handle": self.system.GetInputPort("handle")}

    def operator_inputs(self) -> OperatorInputs:
        return OperatorInputs({"hand": self.hand.GetInputPort("joystick")}, self.hand.GetInputPort("v_insert_cmd"))

    def get_body_poses_output_port(self):
        return self.system.GetOutputPort("body_poses")

    def get_tip_wall_force_output_port(self):
        return self.system.GetOutputPort("tip_wall_force")

    def add_visualizer(self, builder, meshcat, scenario, heart, targets):
        """``catheter_meshcat``: the atrium, the targets and the rod's nodes, a frame every
        ``scenario.visualization.publish_period``."""
        view = builder.AddSystem(CatheterMeshcat(meshcat, heart, self.system.n_bodies, self.tip_radius, targets,
                                                 scenario.visualization.publish_period))
        builder.Connect(self.get_body_poses_output_port(), view.GetInputPort("body_poses"))
        return view

    # --- the state ------------------------------------------------------------------------------
    def body_positions(self, context) -> np.ndarray:
        return self.system.state(subsystem_context(self.system, context)).nodes.copy()

    def is_finite(self, context) -> bool:
        return bool(np.isfinite(self.body_positions(context)).all())

    def non_finite_part(self, context) -> str:
        return "the rod's nodes"

    def metrics(self, context) -> dict:
        """{switches (the hand's tendon switches), slips (the shaft's), windup_rad (the handle's
        twist, the twist at the sheath exit), rod_warnings (the first three distinct, or None),
        peak_wall_force_N and peak_tip_force_N (the largest total wall force on the rod, and on
        its tip sphere, at any update)} in the diagram's root context."""
        st = self.system.state(self.system.GetMyContextFromRoot(context))
        hand_state = self.hand.GetOutputPort("state").Eval(self.hand.GetMyContextFromRoot(context))
        return {"switches": int(hand_state[6]), "slips": int(st.slips), "push_slips": int(st.push_slips),
                "windup_rad": [float(st.twist[0]), float(st.twist[-1])],
                "rod_warnings": "; ".join(sorted(set(st.failures))[:3]) or None,
                "peak_wall_force_N": float(st.peak_wall_force), "peak_tip_force_N": float(st.peak_tip_force)}
