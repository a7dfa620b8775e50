"""The live view's parts that explain themselves (issue 46), without a browser: the feeder's
retraction stop, the keyboard's feeder command dropped against a stop (no wind-up), the labels in
the scene (veins, targets, the world's axes) and the readouts as page text (Meshcat buttons).
A person's presses are injected as the browser sends them (``tests/test_live_teleop.py``)."""

import msgpack
import numpy as np
import pytest
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from ballchain.drake_models.params import BallChain
from ballchain.infrastructure.errors import UserInputError
from ballchain.systems.feeder import Feeder
from ballchain.systems.meshcat_joystick import KEY_MAP, MeshcatJoystick, end_stop
from ballchain.systems.meshcat_overlays import LABELS_PATH, PageText, add_scene_labels

FEED = next(k.label for k in KEY_MAP if k.action == "feed" and k.sign > 0)
RETRACT = next(k.label for k in KEY_MAP if k.action == "feed" and k.sign < 0)


def _retracted(min_length: float, seconds: float = 1.5) -> float:
    """The feeder's inserted length [m] after retracting at full speed from 20 mm."""
    builder = DiagramBuilder()
    feeder = builder.AddSystem(Feeder(BallChain(n_balls=16), initial_length=0.02, min_length=min_length))
    command = builder.AddSystem(ConstantVectorSource([-0.02]))
    builder.Connect(command.get_output_port(), feeder.get_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(seconds)
    return float(feeder.GetOutputPort("inserted_length").Eval(feeder.GetMyContextFromRoot(simulator.get_context()))[0])


def test_retraction_stops_at_the_feeders_retraction_stop():
    step = Feeder().spec.step_length
    assert _retracted(0.0) == 0.0  # the default: all the way in, as before
    assert abs(_retracted(0.02) - 0.02) <= step  # the live view's: where it started
    assert abs(_retracted(0.012) - 0.012) <= step
    with pytest.raises(UserInputError, match="min_length"):
        Feeder(BallChain(n_balls=16), initial_length=0.01, min_length=0.02)  # above the start


def test_end_stop_names_the_stop_within_its_tolerance():
    low, high, tol = Feeder(BallChain(n_balls=16), initial_length=0.02, min_length=0.02).end_stops()
    assert (low, high) == (0.02, BallChain(n_balls=16).length) and 0 < tol < 20e-6
    assert [end_stop(x, low, high, tol) for x in (low, low + 0.5 * tol, 0.03, high - 0.5 * tol, high)] == [-1, -1, 0, 1, 1]


@pytest.mark.parametrize("length, key, expected", [
    (0.020, RETRACT, 0.0),  # at the retraction stop: retract presses add nothing
    (0.030, RETRACT, -0.02),  # between the stops: four presses, full speed back
    (0.255, FEED, 0.0),  # past the chain's length: the whole chain out, feed adds nothing
    (0.030, FEED, 0.02),
])
def test_a_feeder_command_against_the_stop_is_dropped(length, key, expected):
    """Four presses (the feeder's full 20 mm/s) against the stop the feeder sits at leave the
    command at zero, and the keyboard's command too (no wind-up: it sat at +20 mm/s while the
    chain did not move); away from the stops they count as before."""
    chain = BallChain(n_balls=16)
    high = min(length, chain.length)
    meshcat = Meshcat(MeshcatParams(host="localhost"))
    builder = DiagramBuilder()
    j = builder.AddSystem(MeshcatJoystick(meshcat, ["right_unit"], period=0.02, feeder_speed=0.02,
                                          end_stops=(0.02, chain.length, 16e-6)))
    builder.Connect(builder.AddSystem(ConstantVectorSource([high])).get_output_port(),
                    j.GetInputPort("feeder_inserted_length"))
    simulator = Simulator(builder.Build())
    simulator.Initialize()
    for _ in range(4):
        meshcat._InjectWebsocketMessage(msgpack.packb({"type": "button", "name": key}))
    simulator.AdvanceTo(0.03)
    ctx = j.GetMyContextFromRoot(simulator.get_context())
    assert j.GetOutputPort("v_insert_cmd").Eval(ctx)[0] == pytest.approx(expected, abs=1e-12)
    keyboard = ctx.get_discrete_state(0).get_value()[3]
    assert keyboard == pytest.approx(expected / 0.02, abs=1e-12)


class _RecordingMeshcat:
    """What a drawing sends to Meshcat, by path (objects, transforms, properties) and buttons."""

    def __init__(self):
        self.objects, self.poses, self.properties, self.buttons, self.calls = {}, {}, {}, [], 0

    def SetObject(self, path, shape, rgba=None):
        self.objects[path] = shape

    def SetTransform(self, path, X):
        self.poses[path] = X

    def SetProperty(self, path, name, value):
        self.properties[(path, name)] = value

    def AddButton(self, label):
        self.calls += 1
        self.buttons.append(label)

    def DeleteButton(self, label, strict=True):
        self.calls += 1
        self.buttons.remove(label)


def test_the_scene_names_every_vein_and_target_and_the_world_axes():
    from ballchain.drake_models.heart import LeftAtrium
    from ballchain.systems.target_contact import heart_targets

    heart = LeftAtrium()
    names, p_WT, n_W, radius = targets = heart_targets(heart)
    meshcat = _RecordingMeshcat()
    shown = add_scene_labels(meshcat, heart, targets)
    veins = {p.rsplit("/", 1)[1]: t for p, t in shown.items() if "/veins/" in p}
    assert sorted(veins) == ["LIPV", "LSPV", "RIPV", "RSPV"] and all(veins[v] == v for v in veins)
    labelled = {p.rsplit("/", 1)[1]: t for p, t in shown.items() if "/targets/" in p}
    assert sorted(labelled) == sorted(names) and labelled["right_5"] == "R5" and labelled["left_20"] == "L20"
    assert sorted(t for p, t in shown.items() if "/triad/" in p) == ["x (world)", "y (world)", "z (world)"]
    for path in shown:  # every label is drawn over the semi-transparent wall
        assert meshcat.properties[(f"{path}/<object>", "material.depthTest")] is False
        assert meshcat.properties[(f"{path}/<object>", "renderOrder")] == 10.0
    for k, name in enumerate(names):  # beside its disc, clear of it (the disc's colour shows)
        d = np.linalg.norm(meshcat.poses[f"{LABELS_PATH}/targets/{name}"].translation() - p_WT[k])
        assert 1.5 * radius < d < 2.5 * radius, (name, d / radius)
    # The triad: three axes, their labels at their ends; every vein label inside the atrium's box.
    for axis in "xyz":
        assert f"{LABELS_PATH}/triad/{axis}/shaft" in meshcat.objects
    from ballchain.systems.meshcat_view import atrium_box

    lower, upper = atrium_box(heart)
    for name in veins:
        p = meshcat.poses[f"{LABELS_PATH}/veins/{name}"].translation()
        assert np.all(p > lower) and np.all(p < upper) and heart.contains(p[None])[0], name


def test_page_text_replaces_only_a_changed_text_and_keeps_labels_unique():
    meshcat = _RecordingMeshcat()
    text = PageText(meshcat, "")
    text.show(["t = 1.0 s", "tip force 0.0 gf"])
    assert meshcat.buttons == ["t = 1.0 s", "tip force 0.0 gf"] and meshcat.calls == 2
    text.show(["t = 1.0 s", "tip force 0.0 gf"])
    assert meshcat.calls == 2  # unchanged: nothing sent
    text.show(["t = 2.0 s", "same", "same"])
    assert meshcat.buttons == ["t = 2.0 s", "same", "same (3)"]
    text.show(["feeder: ball 1 moves +0.0 mm/s (command +20.0 mm/s)"])  # wrapped: the panel shows 40 characters
    assert meshcat.buttons == ["feeder: ball 1 moves +0.0 mm/s (command", "+20.0 mm/s)"]
    text.clear()
    assert meshcat.buttons == []


@pytest.mark.parametrize("stop, v_cmd, v_ball_1, says", [
    (1, 0.0, 0.0, "the whole chain is out (16 balls): feed adds nothing"),
    (-1, 0.0, 0.0, "retraction stop (20 mm out, where the run started): retract adds nothing"),
    (0, 0.02, 0.001, "the chain does not follow the command"),  # ball 1 at a twentieth of it
    (0, 0.02, 0.019, None),  # it follows
    (0, 0.0, 0.0, None),  # nothing asked
])
def test_the_readout_says_why_the_chain_does_not_follow(stop, v_cmd, v_ball_1, says):
    from types import SimpleNamespace

    from ballchain.experiments.live_session import LiveSession

    session = object.__new__(LiveSession)  # the readout's rule alone, on a stand-in station
    session.cd = SimpleNamespace(feeder=Feeder(BallChain(n_balls=16), initial_length=0.02, min_length=0.02),
                                 scenario=SimpleNamespace(n_balls=16))
    session.feeder_end_stop = lambda: stop
    assert session.feeder_note(v_cmd, v_ball_1) == says
