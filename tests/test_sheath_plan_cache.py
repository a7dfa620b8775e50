"""The manual hand's sheath plans computed once per ring and kept on disk (issue 45, H13:
``systems/sheath_plan_cache.py``, its signed store ``drake_models/result_cache.py``).

* A ring's table read back gives the plan's answers (``SheathPlan.plan``, ``approach``, ``dials``)
  to the last bit, and a warm table is read, not computed: no ``SheathPlan`` made, none asked.
* The key follows every number the planning reads and the code (``plan_inputs``, ``code_hash``).
* A damaged, foreign or mislabelled entry is recomputed, with one line on stderr.
* The hand takes its sheath's goal and re-approach from the cache; a run is the same with a cold
  cache, a warm one and the plan asked directly (the code before; slow).

Every cache here is in ``tmp_path``: never the user's.
"""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from ballchain.drake_models import model_files, result_cache
from ballchain.drake_models.atrium_sdf import AtriumSDF
from ballchain.drake_models.sheath import SteerableSheath
from ballchain.experiments import manual_catheter as mc
from ballchain.systems import sheath_plan_cache as spc
from ballchain.systems.catheter_station import HandParams, ManualHand
from ballchain.systems.sheath_plan import SheathPlan
from ballchain.systems.target_contact import heart_targets

from sheath_world import sheath_world  # noqa: E402

# right_1 (the fixed sheath's setting kept, its curve dialled), right_3 (kept, not dialled) and
# right_13 (the sheath curled): 1 CPU-s of planning.
RING = ("right_1", "right_3", "right_13")


@pytest.fixture(scope="module")
def world():
    w = sheath_world()
    ring = [w["names"].index(n) for n in RING]
    return {**w, "p_T": w["p_WT"][ring], "n_T": w["n_W"][ring]}


def _args(w) -> tuple:
    return w["sheath"], w["cat"], w["p_S"], w["R_S"], w["sdf"], w["radius"]


def _plans(w, folder, **kwargs) -> spc.RingSheathPlans:
    return spc.RingSheathPlans(*_args(w), [(w["p_T"], w["n_T"])], min_out=6e-3, folder=folder, **kwargs)


def _answers(plan, w) -> list:
    return [(plan.plan(p, n), plan.approach(p, n), plan.dials(p, n)) for p, n in zip(w["p_T"], w["n_T"])]


class _Counted(SheathPlan):
    """A SheathPlan that counts its making and its refinements and rod solves."""

    calls: list = []

    def __init__(self, *args, **kwargs):
        _Counted.calls.append("init")
        super().__init__(*args, **kwargs)

    def refine(self, *args):
        _Counted.calls.append("refine")
        return super().refine(*args)

    def rod_miss(self, *args):
        _Counted.calls.append("rod_miss")
        return super().rod_miss(*args)


@pytest.fixture
def counted(monkeypatch):
    _Counted.calls = []
    monkeypatch.setattr(spc, "SheathPlan", _Counted)
    return _Counted.calls


@pytest.fixture(scope="module")
def direct(world) -> list:
    """The plan's own answers for the ring's targets (the code before the cache), made once."""
    return _answers(SheathPlan(*_args(world), min_out=6e-3), world)


@pytest.fixture(scope="module")
def stored(world, tmp_path_factory) -> tuple:
    """A cache folder the ring's table was computed into (a cold pass, made once): (the folder,
    the cold pass's answers, what it made and asked of the plan)."""
    folder = tmp_path_factory.mktemp("sheath_plans")
    with pytest.MonkeyPatch.context() as m:
        _Counted.calls = []
        m.setattr(spc, "SheathPlan", _Counted)
        cold = _plans(world, folder)
        answers = _answers(cold, world)
        assert cold.reused == {0: False}
        return folder, answers, list(_Counted.calls)


def test_cold_and_warm_tables_are_the_plan_s_answers_exactly(world, stored, direct, tmp_path, counted):
    assert [a[2] for a in direct] == [True, False, False]  # right_1 dialled, right_13's sheath moved
    assert direct[2][0] != SteerableSheath().validate().nominal_advance
    folder, cold, made = stored
    assert cold == direct
    assert made.count("init") == 1 and "rod_miss" in made  # computed there, the rod's checks too
    warm = _plans(world, folder)
    got = _answers(warm, world)
    assert got == direct and warm.reused == {0: True}
    assert counted == []  # no plan made, none asked: read from the cache
    for setting, approach, dials in got:
        assert all(type(v) is float for v in (*setting, *approach)) and type(dials) is bool
    # A target of no ring is asked of the plan itself (made then), as before the cache.
    k = world["names"].index("right_2")
    assert warm.plan(world["p_WT"][k], world["n_W"][k]) == SheathPlan(*_args(world), min_out=6e-3).plan(
        world["p_WT"][k], world["n_W"][k])
    assert counted.count("init") == 1
    # Without the cache: nothing stored, the plan asked (the dialled target: its answers alone).
    counted.clear()
    off = _plans(world, tmp_path / "off", cache=False)
    p, n = world["p_T"][0], world["n_T"][0]
    assert (off.plan(p, n), off.approach(p, n), off.dials(p, n)) == direct[0]
    assert not (tmp_path / "off").exists() and counted.count("init") == 1


def _inputs(w, **change) -> dict:
    args = {"sheath": w["sheath"], "catheter": w["cat"], "p_S": w["p_S"], "R_S": w["R_S"],
            "wall": spc.wall_numbers(w["sdf"]), "target_radius": w["radius"], "top": 12, "min_out": 6e-3,
            "p_T": w["p_T"], "n_T": w["n_T"]}
    args.update(change)
    return spc.plan_inputs(**args)


def test_the_key_follows_every_input_and_the_code(world, monkeypatch):
    key = spc.plan_key(_inputs(world))
    assert spc.plan_key(_inputs(world)) == key
    moved = world["p_T"].copy()
    moved[1, 0] += 1e-12  # a target moved by a picometre: floats exactly (hex), not rounded
    tilted = world["n_T"].copy()
    tilted[0] = tilted[0] + [0.0, 1e-9, 0.0]
    values = world["sdf"].values.copy()
    values[10, 10, 10] += 1e-9  # one node of the wall's grid
    sdf = world["sdf"]
    wall = spc.wall_numbers(AtriumSDF(sdf.origin, sdf.spacing, values, sdf.band))
    others = {
        "a target moved": _inputs(world, p_T=moved),
        "a wall normal": _inputs(world, n_T=tilted),
        "a target fewer": _inputs(world, p_T=world["p_T"][:2], n_T=world["n_T"][:2]),
        "the catheter's wall stiffness": _inputs(world, catheter=mc.comparison_catheter(None, 141.0)),
        "the catheter's braid": _inputs(world, catheter=mc.comparison_catheter(0, 140.0)),
        "the sheath's reach": _inputs(world, sheath=SteerableSheath(max_advance=0.035)),
        "the sheath at the septum": _inputs(world, p_S=world["p_S"] + [0.0, 0.0, 1e-9]),
        "its frame": _inputs(world, R_S=world["R_S"][:, [1, 0, 2]] * [1.0, 1.0, -1.0]),
        "the wall": _inputs(world, wall=wall),
        "free space": _inputs(world, wall=None),
        "the touch radius": _inputs(world, target_radius=world["radius"] + 1e-6),
        "the plan's breadth": _inputs(world, top=11),
        "the hand's shortest": _inputs(world, min_out=5e-3),
    }
    keys = {name: spc.plan_key(inputs) for name, inputs in others.items()}
    assert key not in keys.values() and len(set(keys.values())) == len(keys), keys
    monkeypatch.setattr(spc, "force_limit", lambda: 0.5)  # the planned curves' force limit
    assert spc.plan_key(_inputs(world)) != key
    monkeypatch.undo()
    monkeypatch.setattr(spc, "code_hash", lambda: "other code")
    assert spc.plan_key(_inputs(world)) != key


def test_the_code_hash_reads_the_sources(tmp_path, monkeypatch):
    """``result_cache.code_hash`` hashes the listed modules' files: an edit is another hash; every
    module the sheath plan's key lists is found."""
    monkeypatch.syspath_prepend(str(tmp_path))
    source = tmp_path / "h13_probe_module.py"
    source.write_text("X = 1\n")
    before = result_cache.code_hash((), ["h13_probe_module"])
    source.write_text("X = 2\n")
    assert result_cache.code_hash((), ["h13_probe_module"]) != before
    assert "h13_probe_module" not in sys.modules  # found, not imported
    assert len(spc.code_hash()) == 64


def _table(x: float = 0.0) -> spc.SheathTable:
    p_T = np.array([[0.01, 0.02, 0.03], [0.0, 0.0, 1 / 3]])
    return spc.SheathTable(p_T, np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]),
                           np.array([[3.5e-3, 0.0, 0.0], [0.02, 2.1 + x, np.pi]]),
                           np.array([[0.0315, 1.0, 4.1], [0.009, 0.8, 4.45]]), np.array([True, False]))


def _synthetic_inputs() -> dict:
    t = _table()
    return {"p_T": t.p_T, "n_T": t.n_T, "catheter": {"wall_stiffness": 140.0}}


def _same(a: spc.SheathTable, b: spc.SheathTable) -> None:
    for f in ("p_T", "n_T", "settings", "approaches", "dials"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
        assert getattr(a, f).dtype == getattr(b, f).dtype


@pytest.mark.parametrize("damage", ["truncated", "foreign", "other key", "bad shape", "other targets"])
def test_a_damaged_or_foreign_entry_is_recomputed(tmp_path, damage, capsys, monkeypatch):
    """An entry cut short, written by someone else (no signature of this user's key), or signed but
    naming another key, of the wrong shape or of other targets: recomputed (and stored again),
    never read."""
    monkeypatch.setenv(model_files.CACHE_ENV, str(tmp_path / "cache"))  # this user's signing key there
    calls: list = []

    def compute():
        calls.append(1)
        return _table()

    folder = tmp_path / "plans"
    spc.cached_table(_synthetic_inputs(), compute, folder)
    (entry,) = folder.iterdir()
    path = entry / spc.FILE
    key = spc.plan_key(_synthetic_inputs())
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:100])
    elif damage == "foreign":  # another valid table, planted without this user's signature
        with open(path, "wb") as f:
            np.savez(f, key=np.array(key), **spc._to_arrays(_table(1.0), 0.0))
    else:  # signed with this user's key: only the content check stands between it and the run
        arrays = {**spc._to_arrays(_table(1.0), 0.0), "key": np.array("0" * 64 if damage == "other key" else key)}
        if damage == "bad shape":
            arrays["settings"] = arrays["settings"][:, :2]
        if damage == "other targets":
            arrays["p_T"] = arrays["p_T"] + 1e-3
        tmp = entry / "planted.tmp"
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
        model_files.install_signed(entry / model_files.SIGNATURES, {path: tmp})
    table, _, reused = spc.cached_table(_synthetic_inputs(), compute, folder)
    assert not reused and len(calls) == 2
    _same(table, _table())
    err = capsys.readouterr().err
    assert "damaged" in err and len(err.strip().splitlines()) == 1
    again, _, reused = spc.cached_table(_synthetic_inputs(), compute, folder)  # stored again, intact
    assert reused and len(calls) == 2
    _same(again, _table())
    assert not any(name.endswith(".tmp") for name in os.listdir(entry))


def _hand_goal(plan, p_T, n_T) -> np.ndarray:
    """The hand's state after its first update on the target (p_T, n_T): the sheath's goal and the
    re-approach it takes from the plan."""
    hand = ManualHand(HandParams(), plan, initial_length=20e-3)
    ctx = hand.CreateDefaultContext()
    hand.GetInputPort("joystick").FixValue(ctx, [0.0, 0.0, 0.0])
    hand.GetInputPort("v_insert_cmd").FixValue(ctx, [0.0])
    hand.GetInputPort("handle_load").FixValue(ctx, [0.0, 0.0])
    hand.GetInputPort("target").FixValue(ctx, np.concatenate([p_T, n_T]))
    return hand.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector().CopyToVector()


class _Answers:
    """The plan's answers for the ring's targets, as a plan the hand can ask (the code before)."""

    def __init__(self, w, answers):
        self.nominal = (SteerableSheath().validate().nominal_advance, 0.0, 0.0)
        self._w, self._answers = w, answers

    def _k(self, p_T, n_T) -> int:
        return next(k for k, (p, n) in enumerate(zip(self._w["p_T"], self._w["n_T"]))
                    if np.array_equal(p, p_T) and np.array_equal(n, n_T))

    def plan(self, p_T, n_T):
        return self._answers[self._k(p_T, n_T)][0]

    def approach(self, p_T, n_T):
        return self._answers[self._k(p_T, n_T)][1]

    def dials(self, p_T, n_T):
        return self._answers[self._k(p_T, n_T)][2]


def test_the_hand_takes_its_plan_from_the_cache(world, stored, direct, counted):
    """On a warm cache the hand's goal and re-approach for a moved sheath (right_13) and a dial
    (right_1) are those of the plan's answers, and no plan is made or asked."""
    for k in (0, 2):
        p, n = world["p_T"][k], world["n_T"][k]
        expected = _hand_goal(_Answers(world, direct), p, n)
        warm = _hand_goal(_plans(world, stored[0]), p, n)
        assert counted == []
        np.testing.assert_array_equal(warm, expected)
    assert warm[12] > 0.5 * np.pi  # right_13: the sheath's goal curled (the plan's, from the cache)


def test_the_rings_split_the_hearts_targets(world):
    names, p_WT, n_W, _ = heart_targets(world["heart"])
    rings = spc.heart_rings(world["heart"])
    assert [len(p) for p, _ in rings] == [len(r.p_HT) for r in world["heart"].rings.values()]
    np.testing.assert_array_equal(np.concatenate([p for p, _ in rings]), p_WT)
    np.testing.assert_array_equal(np.concatenate([n for _, n in rings]), n_W)


@pytest.mark.slow
def test_a_run_is_the_same_with_a_cold_a_warm_cache_and_none(tmp_path, monkeypatch, counted):
    """Two right-ring targets with the steerable sheath at 0.14 N/mm: the rows and settings the
    same (timings aside) with the plan asked directly (the code before the cache), a cold cache
    (the whole ring planned once) and a warm one (no plan made)."""
    from ballchain.systems import catheter_model

    monkeypatch.setattr(spc, "cache_folder", lambda: tmp_path / "sheath_plans")

    def run():
        r = mc.run(task="right", targets=2, sheath="steerable", catheter=mc.comparison_catheter(None, 140.0))
        return r.rows, {k: v for k, v in r.settings.items() if k != "path"}, r.settings["path"]

    with monkeypatch.context() as m:  # the code before: the hand asks the SheathPlan itself
        m.setattr(catheter_model, "RingSheathPlans", lambda *a, **k: SheathPlan(*a[:6], **k))  # (not the rings)
        before = run()
    counted.clear()
    cold = run()
    assert counted.count("init") == 1
    counted.clear()
    warm = run()
    assert counted == []
    for a in (cold, warm):
        assert a[0] == before[0] and a[1] == before[1]
        for key in before[2]:
            np.testing.assert_array_equal(a[2][key], before[2][key])
