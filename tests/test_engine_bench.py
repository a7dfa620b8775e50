"""``ballchain bench engine|scaling`` (fields and argument errors, never times) and the quasi-static
engine's outputs: the published poses against the ball positions, the engine's states against a
direct ``ChainStatics`` solve, the continuation's step count, the compiled solve against the
Python reference."""

import json

import numpy as np
import pytest

from ballchain.cli import main as cli_main
from ballchain.drake_models.field_sources import UniformField
from ballchain.drake_models.params import BallChain
from ballchain.experiments import engine_bench
from ballchain.optimization.statics import ChainStatics
from ballchain.optimization.wall_constraints import PlaneSDF
from ballchain.systems.quasi_static_engine import (
    QuasiStaticEngine,
    ball_frames,
    rotation_with_x_along,
    rotations_with_x_along,
)

FIELD = UniformField(np.array([0.0, 0.023, 0.0]))  # the canonical problem: 23 mT at 90 deg


def _wall_engine(**changes) -> QuasiStaticEngine:
    """8 balls, ball 1 held on its slide along +x, pressed on the wall y = 12 mm by 23 mT at 90 deg
    (the free_space_wall scenario's problem), solving every 1 ms."""
    chain = BallChain(n_balls=8)
    d = chain.ball_diameter
    args = dict(chain=chain, ball_body_indices=range(1, 9), p_WE=[(8 - 0.5) * d, 0.0, 0.0], axis_W=[1.0, 0.0, 0.0],
                sdf=PlaneSDF([0.0, 0.012, 0.0], [0.0, -1.0, 0.0]), field_source=FIELD, gravity=False,
                period=1e-3)
    return QuasiStaticEngine(**{**args, **changes})


def _start(engine, s: float = 0.0):
    context = engine.CreateDefaultContext()
    engine.get_feeder_state_input_port().FixValue(context, [s, 0.0])
    engine.ExecuteInitializationEvents(context)
    return context


def _advance(engine, context, s: float) -> None:
    engine.get_feeder_state_input_port().FixValue(context, [s, 0.0])
    context.SetDiscreteState(engine.EvalUniquePeriodicDiscreteUpdate(context))


def _ball_frames_numpy(directions, centres):
    """The numpy formula the compiled ``ball_frames`` replaced (x the unit direction, y = helper x x
    normalised, z = x x y; numpy's cross product term for term, norms as summed squares)."""
    x = directions / np.sqrt(np.add.reduce(directions * directions, axis=1))[:, None]
    x0, x1, x2 = x[:, 0], x[:, 1], x[:, 2]
    along_x = np.abs(x0) < 0.9
    y = np.empty_like(x)
    y[:, 0] = np.where(along_x, 0.0 * x2 - 0.0 * x1, 1.0 * x2 - 0.0 * x1)
    y[:, 1] = np.where(along_x, 0.0 * x0 - 1.0 * x2, 0.0 * x0 - 0.0 * x2)
    y[:, 2] = np.where(along_x, 1.0 * x1 - 0.0 * x0, 0.0 * x1 - 1.0 * x0)
    y /= np.sqrt(np.add.reduce(y * y, axis=1))[:, None]
    z = np.stack([x1 * y[:, 2] - x2 * y[:, 1], x2 * y[:, 0] - x0 * y[:, 2], x0 * y[:, 1] - x1 * y[:, 0]], axis=1)
    return np.concatenate([np.stack([x, y, z], axis=2), centres[:, :, None]], axis=2)


def test_ball_frames_are_each_balls_rotation_and_centre():
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(40, 3)) * rng.uniform(1e-3, 1e3, size=(40, 1))
    directions[:10, 1:] *= 1e-3  # near +-x: the other helper axis
    centres = rng.normal(size=(40, 3))
    X = ball_frames(directions, centres)
    # The compiled kernel computes the numpy formula's floats exactly.
    assert np.array_equal(X, _ball_frames_numpy(directions, centres))
    for k in range(40):
        # rotation_with_x_along normalises with np.linalg.norm, a BLAS dot product whose rounding
        # depends on the machine's kernel (fused multiply-adds): the same rotation to a few ulps.
        assert np.abs(X[k, :, :3] - rotation_with_x_along(directions[k])).max() <= 4 * np.finfo(float).eps
        assert np.array_equal(X[k, :, 3], centres[k])
    assert np.array_equal(rotations_with_x_along(directions), X[:, :, :3])


def test_poses_are_the_ball_positions_and_dipoles():
    engine = _wall_engine()
    context = _start(engine)
    _advance(engine, context, 0.4e-3)
    p = engine.ball_positions(context)
    m = engine.state_vector(context)[engine._slices["m"]].reshape(-1, 3)
    poses = engine.get_body_poses_output_port().Eval(context)
    assert len(poses) == 9 and poses[0].IsExactlyIdentity()
    for i in range(8):
        X = poses[i + 1]
        R = X.rotation().matrix()
        assert np.array_equal(X.translation(), p[i])
        assert np.allclose(R[:, 0], m[i] / np.linalg.norm(m[i]), rtol=0, atol=1e-15)
        assert np.allclose(R.T @ R, np.eye(3), rtol=0, atol=1e-14) and np.linalg.det(R) == pytest.approx(1, abs=1e-14)
    assert np.array_equal(engine.get_ball_positions_output_port().Eval(context), p.ravel())


def test_engine_state_is_a_direct_solve():
    """The engine's first equilibrium (from the straight chain) is ChainStatics' on the same rows."""
    engine = _wall_engine()
    context = _start(engine, 0.0)
    k, constraints = engine._constraints(0.0)
    statics = ChainStatics(BallChain(n_balls=8).with_balls(8 - k), gravity=False, tolerance=engine.tolerance)
    statics.feasibility_tolerance = 1e-9
    result = statics.solve(FIELD, None, constraints=constraints)
    assert result.converged and len(result.wall_forces_W) >= 1  # pressed on the wall
    p, m = constraints.full_configuration(result.positions, result.dipoles, engine._d)
    assert np.abs(engine.ball_positions(context) - p).max() <= 1e-12
    x = engine.state_vector(context)
    assert np.abs(x[engine._slices["m"]].reshape(-1, 3) - m).max() <= 1e-12
    assert p[:, 1].max() <= 0.012 - 0.5 * engine._d + 1e-9  # on the free side of the wall
    tip = x[engine._slices["tip"]]
    f = result.wall_forces_W.get(7)
    if f is not None:  # the tip's contact: its force and the point a radius along it
        assert np.allclose(tip[:3], f, rtol=0, atol=1e-15)


def test_continuation_takes_one_solve_per_insertion_step():
    engine = _wall_engine()
    context = _start(engine)
    before = len(engine.solve_times)
    _advance(engine, context, 3.5 * engine.max_insertion_step)  # ceil(3.5) = 4 steps
    assert len(engine.solve_times) - before == 4 and not engine.events
    assert engine.state_vector(context)[engine._slices["s"]][0] == 3.5 * engine.max_insertion_step
    before = len(engine.solve_times)
    _advance(engine, context, 3.5 * engine.max_insertion_step)  # nothing moved: no solve, no step size
    assert len(engine.solve_times) == before and engine.state_vector(context)[engine._slices["u"]][0] == 0.0


def test_compiled_engine_matches_the_reference():
    compiled = _wall_engine()
    reference = compiled.replica(compiled=False)
    assert compiled.compiled and not reference.compiled
    contexts = [_start(e) for e in (compiled, reference)]
    for s in np.linspace(0.0, 2e-3, 5)[1:]:
        for e, c in zip((compiled, reference), contexts):
            _advance(e, c, s)
        assert np.abs(compiled.ball_positions(contexts[0]) - reference.ball_positions(contexts[1])).max() <= 1e-9


def _check_engine_json(out: dict) -> None:
    for name in ("compiled", "reference"):
        u = out[name]["update"]
        assert u["updates"] == out["path_points"] - 1
        assert u["median_ms"] <= u["p99_ms"] <= u["max_ms"]
        assert u["achieved_rate_hz"] == pytest.approx(1e3 / u["mean_ms"], rel=1e-12)
        assert 0.0 <= u["within_period"] <= 1.0 and out[name]["failures"] == 0
        assert out[name]["solve"]["updates"] >= u["updates"]  # at least one solve per update
    assert out["speedup_median"] == pytest.approx(
        out["reference"]["update"]["median_ms"] / out["compiled"]["update"]["median_ms"], rel=1e-12)
    assert out["max_position_difference_m"] <= 1e-9


def test_bench_engine_json(capsys, monkeypatch):
    """The replay on a path of the feeder pushing the wall problem's chain 0.1 mm per update."""
    points = [(1e-4 * i, None) for i in range(6)]
    monkeypatch.setattr(engine_bench, "record_path", lambda *args: (_wall_engine(), points, 0))
    rc = cli_main(["bench", "engine", "--path-s", "0.005", "--clock", "cpu", "--no-progress", "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["benchmark"] == "engine" and out["clock"] == "cpu" and out["rate_hz"] == 1000
    assert out["path_points"] == 6 and out["skipped"] == 0
    _check_engine_json(out)
    assert out["in_contact"] == 1.0 and out["median_wall_contacts"] >= 1


@pytest.mark.slow
def test_bench_engine_on_the_recorded_teleoperation_path(capsys):
    rc = cli_main(["bench", "engine", "--path-s", "0.12", "--rate-hz", "500", "--no-progress", "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["path_points"] + out["skipped"] == round(0.12 * 500) + 1 and out["path_points"] >= 10
    _check_engine_json(out)
    assert out["in_contact"] == 1.0  # PATH_INSERTION keeps the chain on the wall


def test_bench_scaling_writes_the_table(tmp_path, capsys):
    rc = cli_main(["bench", "scaling", "--sizes", "3,4", "--repeats", "1", "--no-progress",
                   "--out", str(tmp_path / "scaling")])
    assert rc == 0
    text = capsys.readouterr().out
    assert "| balls | case |" in text
    files = sorted(p.name for p in (tmp_path / "scaling").iterdir())
    assert files == ["scaling.csv", "scaling.md", "scaling.png"]
    lines = (tmp_path / "scaling" / "scaling.csv").read_text().splitlines()
    assert len(lines) == 1 + 2 * 2 * 2  # sizes x (free, contact) x (cold, warm)


def test_scaling_rows_agree_and_touch_the_wall():
    out = engine_bench.run_scaling(sizes=(4,), repeats=1, progress=False)
    rows = {(r["case"], r["start"]): r for r in out.rows}
    assert set(rows) == {("free", "cold"), ("free", "warm"), ("contact", "cold"), ("contact", "warm")}
    for r in out.rows:
        assert r["converged"] and r["max_position_difference_m"] <= 1e-9
        assert r["speedup"] == pytest.approx(r["reference_ms"] / r["compiled_ms"], rel=1e-12)
    assert rows["free", "cold"]["wall_contacts"] == 0 and rows["contact", "cold"]["wall_contacts"] >= 1
    assert rows["contact", "warm"]["compiled_iterations"] <= rows["contact", "cold"]["compiled_iterations"]


@pytest.mark.parametrize("argv, message", [
    (["bench", "engine", "--balls", "8"], "--balls does not apply to bench engine"),
    (["bench", "statics", "--sizes", "8"], "--sizes does not apply to bench statics"),
    (["bench", "scaling", "--path-s", "0.1"], "--path-s does not apply to bench scaling"),
    (["bench", "engine", "--scenario", "heart_nowhere"], "--scenario must be one of"),
    (["bench", "engine", "--path-s", "5"], "--path-s must be a number in"),
    (["bench", "engine", "--rate-hz", "1"], "--rate-hz must be a number in"),
    (["bench", "engine", "--path-s", "0.001", "--rate-hz", "1000"], "fewer than 2 updates"),
    (["bench", "scaling", "--sizes", "8,x"], "--sizes must be comma-separated integers"),
    (["bench", "scaling", "--sizes", "1,8"], "--sizes must be integers in 2..128"),
])
def test_bad_values_exit_2_with_one_line_before_any_work(argv, message, capsys, monkeypatch):
    def no_work(*args, **kwargs):
        raise AssertionError("work started before the arguments were checked")

    monkeypatch.setattr(engine_bench, "record_path", no_work)
    monkeypatch.setattr(engine_bench, "_scaling_rows", no_work)
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err


@pytest.mark.parametrize("argv", [["bench", "engine", "--clock", "gpu"], ["bench", "engine", "--rate-hz", "nan"]])
def test_bad_flags_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        cli_main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "error" in err and len(err.splitlines()) == 1


def test_scaling_out_that_is_a_file_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(engine_bench, "_scaling_rows", lambda *a, **k: pytest.fail("work started"))
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert cli_main(["bench", "scaling", "--sizes", "4", "--out", str(blocker)]) == 2
    err = capsys.readouterr().err.strip()
    assert "--out" in err and len(err.splitlines()) == 1


def test_one_blas_thread_limits_the_compiled_solves_lapack_too():
    """numba's np.linalg calls scipy's OpenBLAS, not numpy's: the engine's limit must reach it."""
    from threadpoolctl import threadpool_info

    from ballchain.systems.quasi_static_engine import _one_blas_thread

    with _one_blas_thread():
        libraries = {i["filepath"].rsplit("/", 1)[-1]: i["num_threads"] for i in threadpool_info()
                     if i["user_api"] == "blas"}
    assert any(name.startswith("libscipy_openblas") and "64" not in name for name in libraries), libraries
    assert all(threads == 1 for threads in libraries.values()), libraries


def test_a_users_compiled_solve_runs_blas_on_one_thread(monkeypatch):
    """ChainStatics.solve's compiled call limits every BLAS library to one thread (a 64-ball solve
    from a script took ten times the CPU time on OpenBLAS's threads) and restores them after."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from ballchain.optimization import compiled_model

    def blas_threads():
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    seen = []
    newton = compiled_model.newton

    def recording(*args):
        seen.append(blas_threads())
        return newton(*args)

    monkeypatch.setattr(compiled_model, "newton", recording)
    compiled_model.one_blas_thread()  # loads scipy's OpenBLAS
    with threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        result = ChainStatics(BallChain(n_balls=8)).solve(FIELD)
        assert blas_threads() == before
    assert result.converged and seen and all(n == 1 for counts in seen for n in counts), seen


def test_station_bench_profiles_the_python_solvers_pieces(monkeypatch):
    """``benchmarks/station_bench.py``'s per-piece profile times the Python solver's functions
    (each piece called: a compiled solve would leave them at zero, as it once did) and the
    compiled solve of the same equilibria beside it."""
    from script_helpers import load_benchmark

    module = load_benchmark("station_bench", monkeypatch)  # its dataclasses look themselves up
    out = module.profile_equilibrium(repeats=1)
    for piece in ("evaluation", "chain_energy", "constraint_hessian", "qp", "compiled_equilibrium", "equilibrium"):
        assert out[f"{piece}_ms"] > 0, piece
    assert out["wall_contacts"] >= 1 and out["qp_rows"] >= 1
    assert out["qp_step_difference"] < 1e-6
