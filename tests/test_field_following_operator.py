"""The field-following operator (systems/field_following_operator.py), the station notebook's:
its tilt rule against its definition, and its stick, through the world-frame TeleoperationMapper,
checked against the forward dipole law (the turned magnet's field at the tip is along the wanted
tip direction)."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from ballchain.drake_models.dipole import dipole_field
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.vectors import angle_between
from ballchain.systems.field_following_operator import (
    FieldFollowingOperator,
    FieldFollowingParams,
    add_field_following_operator,
    wanted_tip_direction,
)
from ballchain.systems.teleoperation import TeleoperationMapper

MAX_TILT = np.deg2rad(15.0)
LEVER = 5e-3


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def test_the_wanted_direction_tilts_towards_the_target_by_the_lever_angle_at_most_the_cap():
    p, d = np.array([0.01, -0.02, 0.005]), _unit([0.3, 0.8, -0.2])
    side = _unit(np.cross(d, [0.0, 0.0, 1.0]))
    # Straight ahead: no error across the tip, no tilt.
    assert np.allclose(wanted_tip_direction(p, d, p + 0.02 * d, MAX_TILT, LEVER), d, atol=1e-15)
    for across, tilt in ((1e-3, np.arctan(1e-3 / LEVER)), (4e-3, MAX_TILT)):  # below, and at, the cap
        target = p + 0.01 * d + across * side  # the part along d does not count
        w = wanted_tip_direction(p, d, target, MAX_TILT, LEVER)
        assert abs(np.linalg.norm(w) - 1.0) < 1e-12
        assert abs(angle_between(w, d) - tilt) < 1e-12
        assert abs(angle_between(w, side) - (0.5 * np.pi - tilt)) < 1e-12  # towards the target


def test_ports():
    op = FieldFollowingOperator(FieldFollowingParams(p_W_target=(0.0, 0.0, 0.0), p_WM=(0.1, 0.0, 0.0), omega_max=1.0))
    assert [(op.get_input_port(i).get_name(), op.get_input_port(i).size()) for i in range(op.num_input_ports())] == [
        ("p_WT", 3), ("tip_direction_W", 3), ("m_W", 3)]
    assert [(op.get_output_port(i).get_name(), op.get_output_port(i).size()) for i in range(op.num_output_ports())] == [
        ("joystick", 3)]
    assert op.get_name() == "operator"


def _run_operator(m_now, p_tip, d_tip, target, p_WM, omega_max, dead_band, start, period=0.1):
    builder = DiagramBuilder()
    op = builder.AddSystem(FieldFollowingOperator(FieldFollowingParams(
        p_W_target=tuple(target), p_WM=tuple(p_WM), omega_max=omega_max, dead_band=dead_band, start_time=start,
        period=period)))
    mapper = builder.AddSystem(TeleoperationMapper(frame="world", omega_max=omega_max, dead_band=dead_band))
    for port, value in ((op.get_p_WT_input_port(), p_tip), (op.get_tip_direction_input_port(), d_tip),
                        (op.get_m_W_input_port(), m_now)):
        builder.Connect(builder.AddSystem(ConstantVectorSource(np.asarray(value, float))).get_output_port(), port)
    builder.Connect(op.GetOutputPort("joystick"), mapper.GetInputPort("joystick"))
    builder.ExportOutput(mapper.get_output_port(), "omega")
    diagram = builder.Build()
    return diagram, op, Simulator(diagram)


def test_the_stick_turns_the_magnet_to_the_dipole_whose_field_at_the_tip_is_the_wanted_direction():
    """Through the mapper's dead band, the stick held until its release turns the magnet's dipole
    (as it is at the look) to one whose field at the tip (forward dipole law) is along the wanted
    tip direction; the largest axis is at full speed; the stick rests before the first look and
    after the release."""
    p_WM = np.array([-0.059, -0.1048, 0.0])
    p_tip, d_tip = np.array([-0.002, -0.012, -0.015]), _unit([0.1, 0.3, -0.9])
    target = np.array([-0.007, -0.0102, -0.0193])
    m_now = 2.3 * _unit([-0.92, 0.314, -0.235])  # any length: the unit's dipole
    omega_max, dead_band, start = 1.0, 0.1, 0.3
    # One look (a long period): the magnet here does not turn, so every look would ask again.
    diagram, op, simulator = _run_operator(m_now, p_tip, d_tip, target, p_WM, omega_max, dead_band, start, period=10.0)
    context = simulator.get_mutable_context()
    omega_port = diagram.GetOutputPort("omega")
    simulator.AdvanceTo(start - 1e-3)
    assert np.all(omega_port.Eval(context) == 0.0)
    simulator.AdvanceTo(start + 1e-3)  # after the look at ``start``
    omega = omega_port.Eval(context)
    release = op.GetMyContextFromRoot(context).get_discrete_state_vector().GetAtIndex(3)
    assert release > start + 1e-3
    assert abs(np.abs(omega).max() - omega_max) < 1e-12
    # Rodrigues: the dipole turned about omega for the stick's time.
    angle = np.linalg.norm(omega) * (release - start)
    k = omega / np.linalg.norm(omega)
    m = _unit(m_now)
    m_end = m * np.cos(angle) + np.cross(k, m) * np.sin(angle) + k * (k @ m) * (1.0 - np.cos(angle))
    wanted = wanted_tip_direction(p_tip, d_tip, target, MAX_TILT, LEVER)
    assert angle_between(dipole_field(p_tip - p_WM, m_end), wanted) < 1e-9
    assert angle_between(m_end, m) > 0.01  # it did have to turn
    simulator.AdvanceTo(release + 1e-3)
    assert np.all(omega_port.Eval(context) == 0.0)


def test_an_aligned_magnet_gets_no_stick():
    p_WM, p_tip, d_tip = np.array([-0.06, -0.1, 0.0]), np.zeros(3), _unit([0.0, 0.2, -1.0])
    target = p_tip + 0.01 * d_tip  # straight ahead: the wanted direction is the tip's
    from ballchain.drake_models.dipole_inversion import neutral_direction

    m_now = neutral_direction(p_WM, p_tip, d_tip)
    diagram, _, simulator = _run_operator(m_now, p_tip, d_tip, target, p_WM, 1.0, 0.1, 0.0)
    simulator.AdvanceTo(0.05)
    assert np.allclose(diagram.GetOutputPort("omega").Eval(simulator.get_context()), 0.0, atol=1e-6)


@pytest.mark.parametrize("field, value", [("omega_max", 0.0), ("period", -0.1), ("dead_band", 1.0),
                                          ("p_WM", (0.0, 1.0)), ("lever", float("nan"))])
def test_bad_params_name_the_field(field, value):
    params = FieldFollowingParams(p_W_target=(0.0, 0.0, 0.0), p_WM=(0.1, 0.0, 0.0), omega_max=1.0)
    setattr(params, field, value)
    with pytest.raises(UserInputError, match=field):
        FieldFollowingOperator(params)


def test_the_hook_needs_an_external_world_frame_stick():
    from types import SimpleNamespace

    from ballchain.systems.unit_config import MagnetUnitConfig

    for change, match in (({"joystick_source": "script"}, "joystick_source"),
                          ({"joystick_source": "external", "teleop_frame": "tip"}, "teleop_frame")):
        unit = MagnetUnitConfig(name="right_unit", **change)
        # The station leaves a unit's joystick input to the hook only with joystick_source: external.
        ports = SimpleNamespace(joystick_inputs={"right_unit": object()} if unit.joystick_source == "external" else {})
        with pytest.raises(UserInputError, match=match):
            add_field_following_operator(DiagramBuilder(), ports, unit, np.zeros(3))
