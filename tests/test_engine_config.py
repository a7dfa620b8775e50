"""The scenario's engine and device as typed configs (systems/engine_config.py): plain names and
tagged configs load the same scenario, each config answers what the name branches used to, and
the device-model registry resolves its built-in models lazily."""

import json
import pickle
import subprocess
import sys

import pytest

from ballchain.infrastructure.errors import UserInputError
from ballchain.systems import engine_config as ec
from ballchain.systems.chain_scenario import (ChainScenario, apply_overrides, load_scenario, parse_overrides,
                                              scenario_names, update_periods)
from ballchain.systems.device_model import DEVICES, ENGINES

from toy_device import MagnetOnRod  # noqa: F401, E402  (registers "magnet_on_rod")


def _tagged(name: str) -> str:
    return ec.tag_of(name) + " {}"


def test_every_named_scenario_loads_the_same_from_names_and_tags():
    """Each shipped scenario: its engine and device the configs of its names; given again as
    tagged configs, the same classes and the same update periods (the engine's step included)."""
    for name in scenario_names():
        s = load_scenario(name)
        assert type(s.engine) is ec.ENGINE_CONFIGS[str(s.engine)] and type(s.device) is ec.DEVICE_CONFIGS[str(s.device)]
        t = load_scenario(name, f"{{engine: {_tagged(s.engine)}, device: {_tagged(s.device)}}}")
        assert (type(t.engine), type(t.device)) == (type(s.engine), type(s.device)), name
        assert update_periods(t) == update_periods(s), name
        # The engine's answer is the name branch it replaced (scenario_checks.update_periods before).
        old = ("statics_period", s.statics_period) if s.engine == "statics" else ("time_step", s.effective_time_step)
        assert s.engine.update(s) == old, name


def test_a_config_is_its_name():
    s = load_scenario("free_space_uniform_90deg", "{engine: !Statics {}}")
    assert s.engine == "statics" and s.engine.name == "statics" and type(s.engine.name) is str
    assert ("ball_chain", s.engine) in {("ball_chain", "statics"): 1}  # the registry's keys read as before
    assert json.loads(json.dumps({"engine": s.engine})) == {"engine": "statics"}
    assert type(pickle.loads(pickle.dumps(s.engine))) is ec.StaticsEngine
    assert s.engine != ec.PlantEngine() and f"{s.engine}" == "statics" and repr(s.engine) == "'statics'"
    s.engine = "plant"  # a name set from Python is converted
    assert type(s.engine) is ec.PlantEngine and s.engine.own_period(s) is None
    assert type(ChainScenario(engine="statics", device="steerable_catheter").device) is ec.SteerableCatheterDevice
    assert type(apply_overrides(load_scenario("free_space_uniform_90deg"), {"engine": "statics"}).engine) \
        is ec.StaticsEngine
    assert parse_overrides("{engine: !Statics {}, device: !BallChain }") == {"engine": "statics", "device": "ball_chain"}
    with pytest.raises(ValueError, match="must be 'statics'"):
        ec.StaticsEngine("plant")


def test_each_engine_answers_as_the_name_branches_did():
    """The answers against what the removed branches said of each name."""
    assert set(ec.ENGINE_CONFIGS) == set(ENGINES) and set(ec.DEVICE_CONFIGS) <= set(DEVICES)
    plant, statics = ec.PlantEngine(), ec.StaticsEngine()
    assert (plant.has_plant, plant.holds_pin, plant.moves_wall, plant.modes) == \
        (True, True, False, ("quasi-static", "dynamics"))
    assert (statics.has_plant, statics.holds_pin, statics.moves_wall, statics.modes) == \
        (False, False, True, ("quasi-static",))
    assert ec.BallChainDevice().takes_wall_motion and not ec.SteerableCatheterDevice().takes_wall_motion
    s = load_scenario("teleop_right_unit", "{engine: statics, statics_period: 0.025}")
    assert s.engine.own_period(s) == 0.025 and s.engine.update(s) == ("statics_period", 0.025)
    assert ec.choices_with("engine", ENGINES, "holds_pin") == "plant"
    # A device registered without a config class of its own: the base class's, by name or tag.
    toy = load_scenario("teleop_right_unit", "{device: !MagnetOnRod {}, engine: statics}").device
    assert type(toy) is ec.DeviceConfig and toy == "magnet_on_rod" and not toy.takes_wall_motion


@pytest.mark.parametrize("overrides, message", [
    ("{engine: fast}", "scenario engine must be one of 'plant', 'statics', got 'fast'"),
    ("{engine: 5}", r"--set: engine must be one of 'plant', 'statics' or a tagged config \(!Plant \{\}, !Statics"),
    ("{engine: !Fast {}}", r"a YAML tag \(!\.\.\.\) is refused .* or the tags !BallChain, .*!Statics"),
    ("{engine: !Statics {period: 0.1}}", r"engine !Statics takes no settings, got 'period'"),
    ("{engine: !Statics [1]}", r"a YAML tag \(!\.\.\.\) is refused"),
    ("{engine: !Statics {}, mode: dynamics}", "engine: statics needs mode: quasi-static"),
    ("{device: !SteerableCatheter {}}", "steerable_catheter is a manual catheter in the atrium"),
    ("{engine: !Statics {}, pin: {point: [0.05, 0.0, 0.0]}}", "pin needs engine: plant"),
    ("{engine: plant, wall_motion: {enabled: true}}", "wall_motion needs engine: statics"),
    ("{engine: !Statics {}, insertion: {slide_gains: [1.0e+5, 20.0]}}", "slide_gains .* engine: statics does not"),
])
def test_bad_engines_and_devices_are_one_line_naming_the_field(overrides, message):
    with pytest.raises(UserInputError, match=message) as err:
        load_scenario("free_space_uniform_90deg", overrides)
    assert "\n" not in str(err.value)


def test_a_tag_in_another_yaml_is_still_refused():
    from ballchain.infrastructure.safe_yaml import load_yaml

    with pytest.raises(UserInputError, match=r"a YAML tag \(!\.\.\.\) is refused"):
        load_yaml("{engine: !Statics {}}", "sweep spec")
    assert load_yaml("{engine: !Statics {}}", "x", tags=("!Statics",)) == {"engine": {"_tag": "!Statics"}}


def test_the_registry_imports_no_engine_until_a_lookup():
    """Importing the device-model registry imports none of the built-in models' modules (they are
    "module:Class" strings); the first lookup imports its own."""
    code = ("import sys\nfrom ballchain.systems import device_model as dm\n"
            "engines = ('chain_plant', 'quasi_static_engine', 'catheter_model')\n"
            "before = [m for m in engines if 'ballchain.systems.' + m in sys.modules]\n"
            "cls = dm.device_model_class('steerable_catheter', 'statics')\n"
            "after = [m for m in engines if 'ballchain.systems.' + m in sys.modules]\n"
            "print(before, after, cls.__name__, isinstance(dm.DEVICE_MODELS[('ball_chain', 'plant')], str))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd="/").stdout
    assert out.split("\n")[0] == "[] ['catheter_model'] CatheterModel True"
