"""Live steering in Meshcat: the camera framing, MeshcatJoystick, and ``ballchain teleop --live``.

Meshcat is always started on localhost. A person's input is injected the way the browser sends
it (``Meshcat._InjectWebsocketMessage`` with a msgpack'd "button" or "gamepad" message, as
pydrake's own Meshcat tests do); nothing touches the network beyond localhost.
"""

import base64
import json
import re

import msgpack
import numpy as np
import pytest
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.systems.analysis import Simulator

from ballchain.cli import main as cli_main
from ballchain.experiments import teleop
from ballchain.systems.meshcat_joystick import KEY_MAP, MeshcatJoystick, key_map_text, pad_command
from ballchain.systems.meshcat_view import MESHCAT_FOV_DEG, atrium_box, camera_pose_for_box, frame_scene

LABELS = {(k.action, k.index, k.sign): k.label for k in KEY_MAP}


def _meshcat():
    return Meshcat(MeshcatParams(host="localhost"))


def _click(meshcat, label: str, times: int = 1) -> None:
    for _ in range(times):
        meshcat._InjectWebsocketMessage(msgpack.packb({"type": "button", "name": label}))


def _pad(meshcat, axes, buttons=None) -> None:
    buttons = [0.0] * 17 if buttons is None else buttons
    meshcat._InjectWebsocketMessage(msgpack.packb(
        {"type": "gamepad", "name": "", "gamepad": {"index": 0, "button_values": buttons, "axes": list(axes)}}))


def _label(action: str, index: int = 0, sign: float = 1.0) -> str:
    return LABELS[(action, index, sign)]


def _html_commands(html: str) -> list:
    """The msgpack'd Meshcat commands embedded in a StaticHtml page."""
    out = []
    for b in re.findall(r"base64,([A-Za-z0-9+/=]+)", html):
        try:
            out.append(msgpack.unpackb(base64.b64decode(b)))
        except (ValueError, msgpack.ExtraData):
            continue
    return out


def _camera_in_html(html: str) -> tuple[np.ndarray, np.ndarray]:
    """(camera position, target) in Drake's z-up world from a page's commands (three.js is y-up:
    (x, y, z)_three = (x, z, -y)_drake)."""
    position = target = None
    for c in _html_commands(html):
        if not isinstance(c, dict):
            continue
        if c.get("type") == "set_target":
            target = np.asarray(c["value"], float)
        if c.get("type") == "set_property" and c.get("path") == "/Cameras/default/rotated/<object>" \
                and c.get("property") == "position":
            position = np.asarray(c["value"], float)
    assert position is not None and target is not None, "the page does not set the camera"
    to_drake = lambda v: np.array([v[0], -v[2], v[1]])  # noqa: E731
    return to_drake(position), to_drake(target)


# ------------------------------------------------------------------------------------ camera
@pytest.mark.parametrize("direction", [(-0.25, 1.0, 0.3), (1.0, 0.0, 0.0), (0.3, -0.6, -0.5)])
def test_camera_pose_keeps_every_corner_of_the_box_in_view_and_is_tight(direction):
    """Each corner's angle off the view axis, up/down and sideways, is within half the field of
    view; with no margin the farthest-out corner sits on the edge (tight to 1e-9)."""
    lower, upper = np.array([-0.027, -0.033, -0.025]), np.array([0.033, 0.019, 0.026])
    half = np.radians(MESHCAT_FOV_DEG) / 2
    for margin, tight in ((1.0, True), (1.1, False)):
        p_WC, p_WT = camera_pose_for_box(lower, upper, direction, margin=margin)
        np.testing.assert_allclose(p_WT, 0.5 * (lower + upper), atol=1e-15)
        forward = (p_WT - p_WC) / np.linalg.norm(p_WT - p_WC)
        np.testing.assert_allclose(forward, -np.asarray(direction) / np.linalg.norm(direction), atol=1e-12)
        right = np.cross(forward, [0, 0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        corners = np.array([[x, y, z] for x in (lower[0], upper[0]) for y in (lower[1], upper[1])
                            for z in (lower[2], upper[2])]) - p_WC
        depth = corners @ forward
        assert np.all(depth > 0)
        worst = np.max(np.maximum(np.abs(corners @ right), np.abs(corners @ up)) / depth)
        assert worst <= np.tan(half) + 1e-12
        if tight:
            assert worst == pytest.approx(np.tan(half), rel=1e-9)
        else:
            assert worst < np.tan(half) * 0.99


def test_the_atrium_is_framed_in_the_static_html():
    """The camera pose set by frame_scene is part of Meshcat's scene tree, so the self-contained
    replay page carries it: target at the atrium box's centre, camera along the view direction."""
    from ballchain.drake_models.heart import LeftAtrium

    heart = LeftAtrium()
    meshcat = _meshcat()
    p_WC, p_WT = frame_scene(meshcat, heart)
    lower, upper = atrium_box(heart)
    np.testing.assert_allclose(p_WT, 0.5 * (lower + upper), atol=1e-12)
    # The heart is 6 cm across: the camera is a few centimetres away, not metres.
    assert 0.04 < np.linalg.norm(p_WC - p_WT) < 0.2
    html_C, html_T = _camera_in_html(meshcat.StaticHtml())
    np.testing.assert_allclose(html_C, p_WC, atol=1e-9)
    np.testing.assert_allclose(html_T, p_WT, atol=1e-9)


def test_a_free_space_station_is_framed_on_the_chain():
    """MakeStation frames every Meshcat scene: in free space the chain's reach around ball 1."""
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation

    meshcat = _meshcat()
    cd = MakeStation(load_scenario("free_space_uniform_90deg", "{n_balls: 3}"), meshcat=meshcat)
    p_WC, p_WT = _camera_in_html(meshcat.StaticHtml())
    np.testing.assert_allclose(p_WT, cd.chain.p_WE, atol=1e-9)
    L = cd.chain.config.chain.length
    assert L < np.linalg.norm(p_WC - p_WT) < 10 * L


# ------------------------------------------------------------------------ MeshcatJoystick
def test_pad_command_follows_the_standard_gamepad_mapping():
    buttons = [0.0] * 17
    buttons[7], buttons[6] = 0.8, 0.3  # right trigger feeds, left retracts
    stick, feed = pad_command([0.4, -0.6, -1.5, 0.9], buttons)
    np.testing.assert_allclose(stick, [0.4, 0.6, -1.0])  # stick up is +; clipped to [-1, 1]
    assert feed == pytest.approx(0.5)
    np.testing.assert_allclose(pad_command([], [])[0], np.zeros(3))


def test_a_space_read_with_moves_centres_the_stick_and_later_moves_count():
    """Meshcat keeps no order between the clicks of one reading: a Space read with W presses
    centres the stick (the stop wins); W presses read after it move the stick."""
    meshcat = _meshcat()
    j = MeshcatJoystick(meshcat, ["right_unit"], period=0.02, key_step=0.25, feeder_speed=0.02)
    simulator = Simulator(j)
    ctx = simulator.get_mutable_context()
    simulator.Initialize()
    right, feed = j.GetOutputPort("joystick_right_unit"), j.GetOutputPort("v_insert_cmd")
    _click(meshcat, _label("feed", 0, 1.0), 4)
    simulator.AdvanceTo(0.03)
    np.testing.assert_allclose(feed.Eval(ctx), [0.02], atol=0)
    _click(meshcat, _label("centre"))
    _click(meshcat, _label("axis", 1, 1.0), 4)
    simulator.AdvanceTo(0.05)
    np.testing.assert_allclose(right.Eval(ctx), np.zeros(3), atol=0)
    np.testing.assert_allclose(feed.Eval(ctx), [0.0], atol=0)
    _click(meshcat, _label("axis", 1, 1.0), 4)
    simulator.AdvanceTo(0.07)
    np.testing.assert_allclose(right.Eval(ctx), [0.0, 1.0, 0.0], atol=0)
    np.testing.assert_allclose(feed.Eval(ctx), [0.0], atol=0)


def test_meshcat_joystick_ports_keys_gamepad_and_quit():
    """Ports; keys move a sticky virtual stick by key_step; the gamepad adds to it; N selects the
    next unit; Space centres; Escape quits; clicks before the run starts do not count."""
    meshcat = _meshcat()
    j = MeshcatJoystick(meshcat, ["right_unit", "left_unit"], period=0.02, key_step=0.25, feeder_speed=0.02)
    assert j.num_input_ports() == 0
    names = [j.get_output_port(k).get_name() for k in range(j.num_output_ports())]
    assert names == ["joystick_right_unit", "joystick_left_unit", "v_insert_cmd", "selected_unit", "quit"]
    assert [j.get_output_port(k).size() for k in range(j.num_output_ports())] == [3, 3, 1, 1, 1]
    assert set(meshcat.GetButtonNames()) == {k.label for k in KEY_MAP}
    _click(meshcat, _label("axis", 1, 1.0), 3)  # before the run: ignored
    simulator = Simulator(j)
    ctx = simulator.get_mutable_context()
    simulator.Initialize()
    right, left = j.GetOutputPort("joystick_right_unit"), j.GetOutputPort("joystick_left_unit")
    feed = j.GetOutputPort("v_insert_cmd")
    simulator.AdvanceTo(0.05)
    np.testing.assert_allclose(right.Eval(ctx), np.zeros(3), atol=0)

    _click(meshcat, _label("axis", 0, 1.0), 2)
    _click(meshcat, _label("axis", 2, -1.0), 5)  # clipped at -1
    _click(meshcat, _label("feed", 0, 1.0), 3)
    _click(meshcat, _label("feed", 0, -1.0), 1)
    simulator.AdvanceTo(0.1)
    np.testing.assert_allclose(right.Eval(ctx), [0.5, 0.0, -1.0], atol=1e-15)
    np.testing.assert_allclose(left.Eval(ctx), np.zeros(3), atol=0)
    np.testing.assert_allclose(feed.Eval(ctx), [0.5 * 0.02], atol=1e-15)

    _pad(meshcat, [0.25, -0.5, 0.5, 0.0])  # left stick right and up, right stick right
    _click(meshcat, _label("next"))
    simulator.AdvanceTo(0.15)
    assert j.selected_unit(ctx) == "left_unit"
    np.testing.assert_allclose(left.Eval(ctx), [0.75, 0.5, -0.5], atol=1e-15)
    np.testing.assert_allclose(right.Eval(ctx), np.zeros(3), atol=0)

    _pad(meshcat, [0.0, 0.0, 0.0, 0.0])
    _click(meshcat, _label("centre"))
    simulator.AdvanceTo(0.2)
    np.testing.assert_allclose(left.Eval(ctx), np.zeros(3), atol=0)
    np.testing.assert_allclose(feed.Eval(ctx), [0.0], atol=0)
    assert not j.quit_requested(ctx)

    buttons = [0.0] * 17
    buttons[5] = 1.0  # RB: next unit (once per press, not per update while held)
    _pad(meshcat, [0.0] * 4, buttons)
    simulator.AdvanceTo(0.3)
    assert j.selected_unit(ctx) == "right_unit"
    _click(meshcat, _label("quit"))
    simulator.AdvanceTo(0.35)
    assert j.quit_requested(ctx) and j.GetOutputPort("quit").Eval(ctx)[0] == 1.0
    j.remove_buttons()
    assert meshcat.GetButtonNames() == []


def test_key_map_text_names_every_key():
    text = key_map_text()
    for k in KEY_MAP:
        assert k.code in text


def test_bad_live_input_fails_before_any_work(capsys):
    assert cli_main(["teleop", "--live", "--duration", "-1"]) == 2
    assert "--duration must be in (0, 3600] s of simulated time, got -1.0" in capsys.readouterr().err
    assert cli_main(["teleop", "--live", "--units", "three"]) == 2
    assert "--units must be one of" in capsys.readouterr().err
    assert cli_main(["teleop", "--live", "--realtime-rate", "-2"]) == 2
    assert "--realtime-rate must be in [0, 100] (0: as fast as possible), got -2.0" in capsys.readouterr().err
    assert cli_main(["teleop", "--live", "--set", "{no_such_field: 1}", "--duration", "0.1"]) == 2
    assert "no_such_field" in capsys.readouterr().err
    assert cli_main(["teleop", "--live", "--html", "x.html"]) == 2
    assert "--html does not apply to --live" in capsys.readouterr().err


# ---------------------------------------------------------------------------- live station
def _magnet_angle_about_z(session, unit: str) -> tuple[float, float]:
    u = session.cd.units[unit]
    m = u.magnet.GetOutputPort("m_W").Eval(u.magnet.GetMyContextFromRoot(session.root))
    m = m / np.linalg.norm(m)
    return float(np.arctan2(m[1], m[0])), float(m[2])


@pytest.mark.slow
def test_gamepad_turns_the_magnet_keys_move_the_feeder_and_quit_ends_the_run():
    """In the station (8 balls in the atrium, world mapping, unit omega_max 0.5 rad/s):
    the right stick held fully right for 0.5 s turns the magnet 0.25 rad about world +z (after the
    stick springs back and the wheels stop; stepper steps and the 20 ms read period: within 2 %),
    its dipole's z component unchanged; two presses of ArrowUp (half command: 10 mm/s) for 0.5 s
    feed 10 mm/s x 0.5 s less the 0.1 s acceleration ramp's 0.5 mm = 4.5 mm (feeder within 0.1 mm),
    and ball 1 in the plant follows the feeder within 0.1 mm; Escape ends the run at once.
    Measured: 0.2514 rad, feeder 4.49 mm, ball 1 4.47 mm."""
    session = teleop.build_live(n_balls=8, realtime_rate=0.0, overrides="{engine: plant}")
    meshcat, root = session.meshcat, session.root
    cp = session.cd.chain
    plant_context = cp.plant.GetMyContextFromRoot(root)
    feeder = session.cd.feeder
    feeder_context = feeder.GetMyContextFromRoot(root)

    def fed():
        return float(feeder.GetOutputPort("inserted_length").Eval(feeder_context)[0])

    def ball_1_along_sheath():
        return float((cp.ball_positions(plant_context)[0] - cp.p_WE) @ cp.sheath_axis_W)

    assert session.advance_to(0.1) is None
    a0, z0 = _magnet_angle_about_z(session, "right_unit")
    _pad(meshcat, [0.0, 0.0, 1.0, 0.0])
    assert session.advance_to(0.6) is None
    _pad(meshcat, [0.0, 0.0, 0.0, 0.0])
    assert session.advance_to(0.7) is None
    a1, z1 = _magnet_angle_about_z(session, "right_unit")
    assert a1 - a0 == pytest.approx(0.25, rel=0.02)
    assert abs(z1 - z0) < 1e-9

    s0, b0 = fed(), ball_1_along_sheath()
    _click(meshcat, _label("feed", 0, 1.0), 2)
    assert session.advance_to(1.2) is None
    assert fed() - s0 == pytest.approx(4.5e-3, abs=0.1e-3)
    assert ball_1_along_sheath() - b0 == pytest.approx(fed() - s0, abs=0.1e-3)
    a2, _ = _magnet_angle_about_z(session, "right_unit")
    assert abs(a2 - a1) < 1e-3  # the magnet stayed put while feeding

    _click(meshcat, _label("quit"))
    assert session.advance_to(5.0) == "quit"
    assert root.get_time() < 1.25


@pytest.mark.slow
def test_two_units_next_magnet_moves_the_stick_to_the_other_unit():
    """With both units, E (stick 2 +) four times is full stick on the right unit: it turns about +z
    at 0.5 rad/s while the left one stays; after N the same stick drives the left unit and the
    right one stops (0.3 s each: 0.15 rad within 3 %)."""
    session = teleop.build_live(units="two", n_balls=8, realtime_rate=0.0)
    meshcat = session.meshcat
    assert session.advance_to(0.1) is None
    r0, _ = _magnet_angle_about_z(session, "right_unit")
    l0, _ = _magnet_angle_about_z(session, "left_unit")
    _click(meshcat, _label("axis", 2, 1.0), 4)
    assert session.advance_to(0.4) is None
    l1, _ = _magnet_angle_about_z(session, "left_unit")
    _click(meshcat, _label("next"))
    assert session.advance_to(0.7) is None
    r1, _ = _magnet_angle_about_z(session, "right_unit")
    _click(meshcat, _label("centre"))
    assert session.advance_to(0.8) is None
    r2, _ = _magnet_angle_about_z(session, "right_unit")
    l2, _ = _magnet_angle_about_z(session, "left_unit")
    assert abs(l1 - l0) < 1e-3  # the left unit waits while the stick drives the right one
    assert r2 - r0 == pytest.approx(0.15, rel=0.03)
    assert l2 - l1 == pytest.approx(0.15, rel=0.03)
    assert abs(r2 - r1) < 1e-3  # and the right one stops once the stick moved on


@pytest.mark.slow
def test_live_run_headless_with_a_bounded_duration(capsys):
    """``ballchain teleop --live --duration`` runs headless on localhost, prints the URL and the key
    map (to stderr with --json) and stops at the duration with the achieved real-time rate."""
    code = cli_main(["teleop", "--live", "--balls", "8", "--duration", "0.2", "--json", "--no-wait"])
    assert code == 0
    out = capsys.readouterr()
    data = json.loads(out.out)
    assert data["ended"] == "duration" and data["failure"] is None
    assert "engine" not in (data["settings"]["overrides"] or "")  # the default: the quasi-static engine
    assert teleop.live_scenario_for("world").engine == teleop.DEFAULT_ENGINE == "statics"
    assert teleop.live_scenario_for("world", overrides="{engine: plant}").engine == "plant"
    assert data["sim_time_s"] == pytest.approx(0.2, abs=1e-9)
    assert data["url"].startswith("http://localhost:")
    assert data["realtime_factor"] > 0 and data["target_realtime_rate"] == 1.0
    assert data["n_targets"] == 38
    assert "Meshcat: http://localhost:" in out.err
    for k in KEY_MAP:
        assert k.code in out.err


@pytest.mark.slow
def test_ctrl_c_ends_a_live_run_cleanly():
    """Ctrl-C (SIGINT) during a live run without --duration ends it with a summary and status 130."""
    import signal
    import subprocess
    import sys

    code = "import sys; from ballchain.cli import main; sys.exit(main(sys.argv[1:]))"
    # SIGINT back to its default in the child: a test runner may have it ignored.
    p = subprocess.Popen([sys.executable, "-c", code, "teleop", "--live", "--balls", "8", "--no-wait"], stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        seen = []
        for line in p.stdout:  # wait until it is running: the first status line
            seen.append(line)
            if line.startswith("t = "):
                break
        p.send_signal(signal.SIGINT)
        rest, _ = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, "".join(seen) + rest
    assert "ended (interrupted)" in rest
