"""Issue 48: the procedure's fast paths give the answers of the general code.

* The navigator's force model on the compiled held-tip path (``optimization.compiled_held_tip``)
  against ``ChainStatics.solve`` with the ``FieldSources`` it replaces: the same reactions over
  a run of warm-started looks, bit for bit.
* The on-disk cache of plans (``experiments.plan_cache``): a stored set read back exactly, its
  key following every input, a damaged or foreign set recomputed, never trusted.
"""

import os

import numpy as np
import pytest

from ballchain.drake_models import model_files
from ballchain.drake_models.params import BallChain, CylinderMagnet
from ballchain.experiments import plan_cache
from ballchain.optimization.statics import ChainStatics
from ballchain.systems.autonomous_navigator import TargetPlan
from ballchain.systems.tip_force_estimator import TipForceEstimator
from statics_helpers import assert_same_statics


def _looks(n: int, seed: int = 0):
    """A sheath exit, one magnet and ``n`` noisy looks at a tip the 16 free balls reach [m]."""
    rng = np.random.default_rng(seed)
    p_WE, p_WM = np.array([0.01, -0.02, 0.03]), np.array([0.03, 0.0, 0.12])
    tip = p_WE + np.array([0.036, 0.012, 0.008])
    m = np.array([0.0, 0.2, 1.0]) / np.hypot(0.2, 1.0)
    return p_WE, p_WM, [(tip + 0.4e-3 * rng.standard_normal(3),
                         (m + 0.02 * rng.standard_normal(3)).reshape(1, 3)) for _ in range(n)]


def _reference(estimator: TipForceEstimator, looks, s: float, h=None):
    """The reactions by ``ChainStatics.solve`` on ``field_S``'s sources (the code before issue 48)."""
    solver = ChainStatics(estimator.chain.with_balls(estimator.free_balls(s)), max_iterations=25)
    last, out = None, []
    p_WE = estimator.p_WE if h is None else estimator.p_WE + h
    for p_W, m in looks:
        target = estimator.R_WS.T @ (p_W - p_WE)
        answer = None
        for start in (last, None):
            r = solver.solve(estimator.field_S(m, h), start, tip_target=target)
            if r.converged:
                last, answer = r, estimator.R_WS @ r.tip_reaction
                break
        out.append(answer)
    return out


@pytest.mark.parametrize("moving", [False, True], ids=["still", "tracked sheath"])
def test_the_compiled_held_tip_is_the_general_solve(moving):
    """30 warm-started looks with the sensor's noise (and a tracked sheath's offset): every
    reaction equal to the general solve's, to the last bit, the looks beyond reach included."""
    p_WE, p_WM, looks = _looks(30)
    s = 15 * BallChain().ball_diameter
    h = np.array([0.0, 0.0, 3e-3]) if moving else None
    estimator = TipForceEstimator(BallChain(), p_WE, np.eye(3), [(CylinderMagnet(), p_WM)], "dipole", 16)
    fast = [estimator.reaction_W(p + (0 if h is None else h), m, s, h) for p, m in looks]
    slow = _reference(estimator, [(p + (0 if h is None else h), m) for p, m in looks], s, h)
    assert sum(r is not None for r in slow) >= 20  # most looks have a held equilibrium
    for a, b in zip(fast, slow):
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a, b)


def _plan(name: str, k: int = 1, x: float = 0.0) -> TargetPlan:
    rng = np.random.default_rng(abs(hash(name)) % 2**32)
    return TargetPlan(name, rng.standard_normal(3), rng.standard_normal(3), rng.standard_normal((k, 3)),
                      0.05 + x, rng.standard_normal((3, 3)), rng.standard_normal((3, 3 * k)),
                      rng.standard_normal((3, 2)), 0.196 + x, 1e-3 / 3)


def _inputs(force: float = 0.196) -> dict:
    return {"names": ["a", "b"], "force_N": force, "n_balls": 16, "magnets_W": [np.array([0.1, 0.2, 1 / 3])]}


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv(model_files.CACHE_ENV, str(folder))
    return folder


def _compute(calls: list, k: int = 2):
    def compute():
        calls.append(1)
        return [_plan("a", k), _plan("b", k)], ["c"]
    return compute


def _same(a: list, b: list) -> None:
    assert len(a) == len(b)
    for p, q in zip(a, b):
        assert p.name == q.name
        for f in plan_cache._FIELDS:
            np.testing.assert_array_equal(getattr(p, f), getattr(q, f))


def test_plans_come_back_exactly_and_are_computed_once(cache):
    calls: list = []
    plans, missing, _, reused = plan_cache.cached_plans(_inputs(), _compute(calls))
    again, missing2, _, reused2 = plan_cache.cached_plans(_inputs(), _compute(calls))
    assert (reused, reused2, len(calls)) == (False, True, 1)
    assert missing == missing2 == ["c"]
    _same(plans, again)
    assert (cache / plan_cache.FOLDER).is_dir()


def test_the_key_follows_every_input_and_the_code(monkeypatch):
    key = plan_cache.plan_key(_inputs())
    assert plan_cache.plan_key(_inputs()) == key
    assert plan_cache.plan_key(_inputs(0.196 + 1e-15)) != key  # floats exactly (hex), not rounded
    other = _inputs()
    other["magnets_W"] = [np.array([0.1, 0.2, 0.3334])]
    assert plan_cache.plan_key(other) != key
    monkeypatch.setattr(plan_cache, "code_hash", lambda: "other code")
    assert plan_cache.plan_key(_inputs()) != key


@pytest.mark.parametrize("damage", ["truncated", "foreign", "other key", "bad shape"])
def test_a_damaged_or_foreign_set_is_recomputed(cache, damage, capsys):
    """A set cut short, written by someone else (no signature of this user's key), signed but
    naming another key, or of the wrong shape: recomputed (and stored again), never read."""
    calls: list = []
    plan_cache.cached_plans(_inputs(), _compute(calls))
    (folder,) = (cache / plan_cache.FOLDER).iterdir()
    path = folder / plan_cache.FILE
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:100])
    elif damage == "foreign":  # another valid set, planted without this user's signature
        with open(path, "wb") as f:
            np.savez(f, **plan_cache._to_arrays(plan_cache.plan_key(_inputs()), [_plan("a", 2, 1.0)], [], 0.0))
    else:  # signed with this user's key: only the content check stands between it and the run
        key = "0" * 64 if damage == "other key" else plan_cache.plan_key(_inputs())
        arrays = plan_cache._to_arrays(key, [_plan("a", 2, 1.0)], [], 0.0)
        if damage == "bad shape":
            arrays["J_m"] = arrays["J_m"][:, :2]
        tmp = folder / "planted.tmp"
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
        model_files.install_signed(folder / model_files.SIGNATURES, {path: tmp})
    plans, _, _, reused = plan_cache.cached_plans(_inputs(), _compute(calls))
    assert not reused and len(calls) == 2
    _same(plans, _compute([])()[0])
    assert "damaged" in capsys.readouterr().err
    again, _, _, reused = plan_cache.cached_plans(_inputs(), _compute(calls))  # stored again, intact
    assert reused and len(calls) == 2
    _same(again, plans)
    assert not any(name.endswith(".tmp") for name in os.listdir(folder))


@pytest.mark.slow
def test_a_ring_s_plans_from_the_cache_are_the_computed_ones(cache):
    """The first right-ring target planned afresh, then through the cache twice: the second read
    from it, every plan's numbers the computed ones to the last bit."""
    from ballchain.experiments import procedure

    fresh = procedure.plan_ring("right", targets=1, cache=False)
    stored = procedure.plan_ring("right", targets=1)
    read = procedure.plan_ring("right", targets=1)
    assert (fresh.cached, stored.cached, read.cached) == (False, False, True)
    assert read.key == fresh.key and read.missing == fresh.missing
    _same(list(fresh.plans), list(read.plans))
    assert read.cpu_time_s < 0.25 * stored.cpu_time_s


def test_held_solve_is_the_general_solve(monkeypatch):
    """``compiled_held_tip.held_solve`` against ``ChainStatics.solve`` on noisy held tips under a
    turning magnet, each warm-started from the last: every field of every result the same (its
    solve_time aside), the multipliers and pair forces included, converged or not; the general
    solve taken only for the cold start."""

    from ballchain.drake_models.field_sources import FieldSources, MagnetSource
    from ballchain.optimization import compiled_held_tip
    from ballchain.optimization.compiled_held_tip import held_solve

    general = []
    monkeypatch.setattr(compiled_held_tip, "_GENERAL", lambda *a, **k: general.append(1) or ChainStatics.solve(*a, **k))

    p_WE, p_WM, looks = _looks(12, seed=3)
    chain = BallChain(n_balls=16)
    fast, slow = ChainStatics(chain, max_iterations=25), ChainStatics(chain, max_iterations=25)
    field = lambda m: FieldSources([MagnetSource.pointing(CylinderMagnet(), p_WM - p_WE, m[0])])  # noqa: E731
    first = slow.solve(field(looks[0][1]))
    a = b = fast.solve(field(looks[0][1]), first, tip_target=first.tip_position)
    b = slow.solve(field(looks[0][1]), first, tip_target=first.tip_position)
    compared = 0
    for p, m in looks:
        target = p - p_WE
        a, b = held_solve(fast, field(m), a, target), slow.solve(field(m), b, tip_target=target)
        assert_same_statics(a, b)
        compared += a.converged
        if not a.converged:
            a = b = first
    assert compared >= 6 and not general
