"""Target touches and Meshcat overlays (systems/meshcat_overlays.py): ports, the touch rule on
hand-placed tips, the tracker's memory, the field and contact-force arrows' quantities, a short
recorded run whose HTML replay holds the overlays, and the simulate JSON fields.

Meshcat is always started on localhost (``MeshcatParams(host="localhost")``); ``StartMeshcat()``
is not used because it binds every interface (host "*")."""

import base64
import json
import re
import resource

import numpy as np
import pytest
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator

from ballchain.cli import main as cli_main
from ballchain.drake_models.params import BallChain
from ballchain.systems.chain_scenario import load_scenario
from ballchain.systems.chain_simulation import MakeStation, run_simulation
from ballchain.systems.target_contact import TOUCH_TOLERANCE, TargetTouchTracker, heart_targets, targets_touched

R_BALL = 0.5 * BallChain().ball_diameter  # 1.5875 mm


@pytest.fixture(scope="module")
def meshcat():
    return Meshcat(MeshcatParams(host="localhost"))


def _tangent(n):
    t = np.cross(n, [0.0, 0.0, 1.0])
    return t / np.linalg.norm(t)


def _html_payload(text: str) -> bytes:
    """The Meshcat commands embedded in a StaticHtml page (base64 msgpack; strings stay raw)."""
    blobs = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", text)
    return b"".join(base64.b64decode(b) for b in blobs)


def test_targets_lie_on_the_wall_with_normals_into_the_chamber(heart):
    names, p_WT, n_W, radius = heart_targets(heart)
    assert len(names) == 38 and names[0] == "left_1" and names[-1] == "right_18"
    assert radius == pytest.approx(2.5e-3)
    np.testing.assert_allclose(np.linalg.norm(n_W, axis=1), 1.0, atol=1e-12)
    # 1 mm along the normal is 1 mm from the (meshed) wall and inside: the rule's h is the wall
    # distance to the mesh's chord sag (0.15 mm).
    probe = p_WT + 1e-3 * n_W
    assert heart.contains(probe).all()
    np.testing.assert_allclose(heart.wall_distance(probe), 1e-3, atol=0.15e-3)


def test_touch_rule_on_hand_placed_tips(heart):
    names, p_WT, n_W, radius = heart_targets(heart)
    k = names.index("left_3")
    p, n = p_WT[k], n_W[k]
    t = _tangent(n)

    def touched(p_tip):
        return [names[i] for i in np.flatnonzero(targets_touched(p_tip, p_WT, n_W, R_BALL, radius))]

    assert touched(p + R_BALL * n) == ["left_3"]  # resting on the target's centre
    assert touched(p + (R_BALL + TOUCH_TOLERANCE - 0.05e-3) * n) == ["left_3"]  # 0.45 mm off the wall
    assert touched(p + (R_BALL - 0.2e-3) * n) == ["left_3"]  # pressed 0.2 mm into the wall
    assert touched(p + (R_BALL + TOUCH_TOLERANCE + 0.05e-3) * n) == []  # 0.55 mm off: not touching
    assert touched(p + R_BALL * n + 2.4e-3 * t) == ["left_3"]  # on the wall, inside the 2.5 mm radius
    assert touched(p + R_BALL * n + 2.6e-3 * t) == []  # on the wall, laterally outside
    assert touched(np.zeros(3)) == []  # the chamber's centre
    # Every target, resting on its centre, is touched alone (targets are > 5 mm apart).
    for i in range(len(names)):
        assert touched(p_WT[i] + R_BALL * n_W[i]) == [names[i]]


def test_tracker_ports_and_memory(heart):
    """Ports; then, stepping with fixed tip poses, a touched target stays touched."""
    names, p_WT, n_W, radius = heart_targets(heart)
    tip = 2
    tracker = TargetTouchTracker(tip, names, p_WT, n_W, radius, R_BALL, period=5e-3)
    assert tracker.get_name() == "target_touches"
    assert tracker.num_input_ports() == 1 and tracker.num_output_ports() == 1
    assert tracker.get_input_port(0).get_name() == "body_poses"
    assert tracker.get_output_port(0).get_name() == "touched" and tracker.get_output_port(0).size() == 38

    def poses(p_tip):
        return [RigidTransform(), RigidTransform([0.0, 0.0, 0.01]), RigidTransform(p_tip)]

    simulator = Simulator(tracker)
    context = simulator.get_mutable_context()
    port = tracker.get_body_poses_input_port()
    port.FixValue(context, poses(np.zeros(3)))
    simulator.Initialize()
    assert tracker.touched_names(context) == []
    k = names.index("right_5")
    port.FixValue(context, poses(p_WT[k] + R_BALL * n_W[k]))
    simulator.AdvanceTo(0.012)
    assert tracker.touched_names(context) == ["right_5"]
    port.FixValue(context, poses(np.zeros(3)))  # leaves: stays touched
    simulator.AdvanceTo(0.024)
    assert tracker.touched_names(context) == ["right_5"]
    j = names.index("left_10")
    port.FixValue(context, poses(p_WT[j] + R_BALL * n_W[j]))
    simulator.AdvanceTo(0.036)
    assert tracker.touched_names(context) == ["left_10", "right_5"]
    np.testing.assert_array_equal(np.flatnonzero(tracker.get_touched_output_port().Eval(context)), sorted([j, k]))


def test_overlay_ports_and_field_at_the_tip(heart, meshcat):
    """With a unit: the overlay's ports and wiring, and its field at the tip equals the wrench
    system's external field there (the same sources, to 1e-12 relative)."""
    cd = MakeStation(load_scenario("teleop_right_unit"), meshcat=meshcat, heart=heart)
    overlays = cd.meshcat_overlays
    assert overlays.get_name() == "meshcat_overlays"
    assert {"target_touches", "meshcat_overlays"} <= {s.get_name() for s in cd.diagram.GetSystems()}
    inputs = [overlays.get_input_port(i) for i in range(overlays.num_input_ports())]
    assert [p.get_name() for p in inputs] == ["body_poses", "tip_wall_force", "touched", "magnet_states"]
    assert overlays.get_touched_input_port().size() == 38 and overlays.get_magnet_states_input_port().size() == 6
    assert overlays.num_output_ports() == 0
    for path in ("overlays/targets/left_1/open", "overlays/targets/right_18/touched",
                 "overlays/tip_field/shaft", "overlays/tip_contact_force/head"):
        assert meshcat.HasPath(path), path
    context = cd.diagram.CreateDefaultContext()
    o_context = overlays.GetMyContextFromRoot(context)
    w_context = cd.chain.wrench.GetMyContextFromRoot(context)
    tip = cd.chain.ball_positions(cd.chain.plant.GetMyContextFromRoot(context))[-1]
    B_wrench = cd.chain.wrench.external_field(w_context).field_and_gradient(tip[None])[0][0]
    B = overlays.tip_field(o_context)
    assert np.linalg.norm(B) > 1e-3  # about 12 mT near the sheath exit
    np.testing.assert_allclose(B, B_wrench, rtol=1e-12)


def _one_step_with_the_tip_at(cd, p_W_tip):
    """One plant step from the default state with the tip ball moved to p_W_tip; returns the
    simulator. The plant's contact results are sampled: they are the step's, from that state."""
    plant = cd.chain.plant
    simulator = Simulator(cd.diagram)
    plant_context = plant.GetMyContextFromRoot(simulator.get_mutable_context())
    plant.SetFreeBodyPose(plant_context, cd.chain.ball_bodies[-1], RigidTransform(p_W_tip))
    simulator.AdvanceTo(cd.scenario.effective_time_step)
    return simulator


def test_contact_force_on_the_tip_from_the_wall_and_a_touch_in_the_diagram(heart, meshcat):
    """The tip ball placed 0.2 mm into the wall at target left_3 for one step: the wall pushes it
    out along the wall's normal from a centroid at the target,
    and the diagram's tracker has left_3 touched. Placed 1 mm off the wall: no force, no touch."""
    cd = MakeStation(load_scenario("heart_wall_contact"), meshcat=meshcat, heart=heart)
    overlays, tracker = cd.meshcat_overlays, cd.target_touches
    names, p_WT, n_W, _ = heart_targets(heart)
    k = names.index("left_3")
    simulator = _one_step_with_the_tip_at(cd, p_WT[k] + (R_BALL - 0.2e-3) * n_W[k])
    o_context = overlays.GetMyContextFromRoot(simulator.get_context())
    f, p_WC = overlays.tip_contact_force(o_context)
    normal = f @ n_W[k]
    print(f"wall force on the tip {f} N, at {p_WC} m")
    assert normal > 0.01  # [N]
    # Within 15 deg of the ellipsoid's normal (measured 7 deg: the wall mesh's facets and the friction
    # holding the displaced tip against gravity and its neighbour's pull).
    assert normal > np.cos(np.radians(15.0)) * np.linalg.norm(f)
    assert np.linalg.norm(p_WC - p_WT[k]) < 0.5e-3
    np.testing.assert_allclose(overlays.tip_field(o_context), [0.0, 0.0, 0.03], atol=1e-15)  # uniform 30 mT
    assert tracker.touched_names(tracker.GetMyContextFromRoot(simulator.get_context())) == ["left_3"]
    simulator = _one_step_with_the_tip_at(cd, p_WT[k] + (R_BALL + 1e-3) * n_W[k])
    f, p_WC = overlays.tip_contact_force(overlays.GetMyContextFromRoot(simulator.get_context()))
    assert p_WC is None and np.all(f == 0.0)
    assert tracker.touched_names(tracker.GetMyContextFromRoot(simulator.get_context())) == []


def test_short_recorded_run_has_the_overlays_in_its_html(heart, meshcat, tmp_path):
    html = tmp_path / "run.html"
    result = run_simulation(scenario=load_scenario("heart_wall_contact"), duration=0.04, html=html, meshcat=meshcat,
                            heart=heart)
    payload = _html_payload(html.read_text())
    for path in (b"overlays/targets/left_1/open", b"overlays/targets/left_1/touched",
                 b"overlays/targets/right_18/open", b"overlays/tip_field/shaft", b"overlays/tip_field/head",
                 b"overlays/tip_contact_force/shaft"):
        assert path in payload, path
    assert b"animation" in payload and b"visible" in payload
    assert result.targets_touched == []  # the chain is still in the middle of the chamber


def test_json_reports_targets_touched_and_peak_memory(capsys):
    argv = ["simulate", "--scenario", "free_space_uniform_90deg", "--duration", "0.002",
            "--set", "{n_balls: 4}", "--json"]
    assert cli_main(argv) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["targets_touched"] == []  # no heart, no targets
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # MiB, never decreases
    assert 10.0 < data["peak_memory_MB"] <= peak + 0.1
