"""The engine's shortcuts give the very same numbers as the work they skip: the initial
equilibrium taken from the warm-up, the compiled solve's short path (``HeartSolve``), the
watchdog's finiteness test and the one-thread BLAS context."""

import numpy as np
import pytest


def _station(overrides: str = ""):
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation

    return MakeStation(load_scenario("heart_left_quasi_static", "{engine: statics, mode: quasi-static"
                                     + overrides + "}"))


def _run(cd, duration: float):
    from ballchain.systems.chain_simulation import run_station

    run = run_station(cd, duration=duration)
    assert run.failure is None
    engine = cd.chain.engine_system
    return engine.state_vector(engine.GetMyContextFromRoot(run.context)).copy(), engine


def test_initial_equilibrium_from_the_warm_up_is_the_solved_one():
    """The initialisation's equilibrium taken from the warm-up (same insertion, same field) and
    solved afresh: the same state bit for bit, the same solves and iterations, over a run."""
    reused = _station()
    assert reused.chain.engine_system._warm is not None
    solved = _station()
    solved.chain.engine_system._warm = None  # as before: the initialisation solves
    x_reused, e_reused = _run(reused, 0.15)
    x_solved, e_solved = _run(solved, 0.15)
    assert np.array_equal(x_reused, x_solved)
    assert len(e_reused.solve_times) == len(e_solved.solve_times) > 1
    assert e_reused.iterations == e_solved.iterations
    assert e_reused._multipliers.keys() == e_solved._multipliers.keys()
    for k in e_reused._multipliers:
        assert e_reused._multipliers[k] == e_solved._multipliers[k]


def test_initial_equilibrium_is_solved_when_the_problem_differs():
    """Another insertion or field source than the warm-up's: the initialisation solves it."""
    cd = _station()
    engine = cd.chain.engine_system
    field, s0, answer, times, iterations = engine._warm
    calls = []
    original = engine._equilibrium

    def counting(*args, **kwargs):
        calls.append(args[0])
        return original(*args, **kwargs)

    engine._equilibrium = counting
    p, _, _ = engine._initial_equilibrium(s0, None)
    assert calls == [] and np.array_equal(p, answer[0])
    p_other, _, _ = engine._initial_equilibrium(s0 + 1e-3, None)
    assert calls == [s0 + 1e-3] and not np.array_equal(p_other, answer[0])
    engine._field_source = type(field)(**vars(field))  # an equal source, but not the warm-up's
    engine._initial_equilibrium(s0, None)
    assert calls == [s0 + 1e-3, s0]


def test_finite_state_check_finds_any_non_finite_entry():
    cd = _station()
    model = cd.chain
    context = cd.diagram.CreateDefaultContext()
    engine_context = model.engine_system.GetMyContextFromRoot(context)
    x = model.engine_system.state_vector(engine_context)
    assert model.is_finite(engine_context)
    state = engine_context.get_mutable_discrete_state(0)
    big = x.copy()
    big[:2] = 1e308  # finite entries whose sum overflows: still finite
    state.SetFromVector(big)
    assert model.is_finite(engine_context)
    for bad in (np.nan, np.inf, -np.inf):
        y = x.copy()
        y[3] = bad
        state.SetFromVector(y)
        assert not model.is_finite(engine_context)


def test_one_blas_thread_context_restores_the_thread_counts():
    from threadpoolctl import threadpool_info, threadpool_limits

    from ballchain.systems.quasi_static_engine import _one_blas_thread

    def counts():
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    _one_blas_thread()  # loads scipy's OpenBLAS (the controller's snapshot)
    with threadpool_limits(limits=2, user_api="blas"):
        before = counts()
        with _one_blas_thread():
            assert all(n == 1 for n in counts())
        assert counts() == before
    with threadpool_limits(limits=1, user_api="blas"):
        with _one_blas_thread():
            assert all(n == 1 for n in counts())
        assert all(n == 1 for n in counts())


def _without_short_path(monkeypatch):
    """``HeartSolve.solve`` declining every solve: the engine calls ``ChainStatics.solve``."""
    from ballchain.optimization.compiled_model import HeartSolve

    monkeypatch.setattr(HeartSolve, "solve", lambda self, *args, **kwargs: None)


def _short_path_run(name: str, duration: float):
    """A named scenario on the engine for ``duration``: (the engine's state, the engine, the short
    path's answers and declines)."""
    from ballchain.optimization.compiled_model import HeartSolve
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation, run_station

    counts = [0, 0]
    solve = HeartSolve.solve

    def counting(self, *args, **kwargs):
        answer = solve(self, *args, **kwargs)
        counts[answer is None] += 1
        return answer

    cd = MakeStation(load_scenario(name, "{engine: statics, mode: quasi-static}"))
    HeartSolve.solve = counting
    try:
        run = run_station(cd, duration=duration)
    finally:
        HeartSolve.solve = solve
    assert run.failure is None
    engine = cd.chain.engine_system
    return engine.state_vector(engine.GetMyContextFromRoot(run.context)).copy(), engine, counts


@pytest.mark.parametrize("name", ["teleop_right_unit", "heart_left_quasi_static"])
def test_short_path_of_the_compiled_solve_is_chain_statics_solve(monkeypatch, name):
    """The engine's solves through ``HeartSolve`` (the kernel called with what ChainStatics.solve
    gives it, without the rest) and through ``ChainStatics.solve``: the same states bit for bit,
    the same solves, iterations, multipliers, and the same last StaticsResult. teleop_right_unit's
    magnet is on a port (point dipoles), heart_left_quasi_static's a fixed MagnetSource."""
    x_short, e_short, counts = _short_path_run(name, 0.3)
    assert counts[0] >= 5 and counts[1] == 0  # the short path answered every solve
    with monkeypatch.context() as m:
        _without_short_path(m)
        x_full, e_full, _ = _short_path_run(name, 0.3)
    assert np.array_equal(x_short, x_full)
    assert len(e_short.solve_times) == len(e_full.solve_times)
    assert e_short.iterations == e_full.iterations
    assert e_short._multipliers == e_full._multipliers
    a, b = e_short.last_result, e_full.last_result
    assert a.converged and a.reason == b.reason and a.iterations == b.iterations
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.positions_W, b.positions_W)
    assert a.multipliers == b.multipliers and a.pair_forces == b.pair_forces
    for forces_a, forces_b in ((a.wall_forces_W, b.wall_forces_W), (a.sheath_forces_W, b.sheath_forces_W)):
        assert forces_a.keys() == forces_b.keys()
        assert all(np.array_equal(forces_a[k], forces_b[k]) for k in forces_a)


def test_short_path_leaves_a_non_finite_field_to_chain_statics():
    """A NaN in the magnets' states: the short path declines, and ChainStatics.solve reports the
    field (the engine's error names it), as without the short path."""
    from ballchain.optimization.statics import StaticsError
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation

    cd = MakeStation(load_scenario("teleop_right_unit", "{engine: statics, mode: quasi-static}"))
    engine = cd.chain.engine_system
    from pydrake.systems.analysis import Simulator

    sim = Simulator(cd.diagram)
    sim.Initialize()
    s, mags = engine._inputs(engine.GetMyContextFromRoot(sim.get_context()))
    p, m, result, k = engine.equilibrium(s, mags)
    assert result.converged and engine._lean[engine._n - k].usable()
    bad = mags.copy()
    bad[3] = np.nan
    with pytest.raises(StaticsError, match="not finite"):
        engine.equilibrium(s, bad, p, m)


def test_short_path_declines_a_ball_inside_a_magnets_bounding_sphere():
    """A port magnet whose bounding sphere holds a ball of the warm start: the short path declines
    (ChainStatics.solve refuses such a field, naming the magnet); one just outside it: answered."""
    from ballchain.infrastructure.errors import UserInputError
    from ballchain.optimization.statics import StaticsResult
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation
    from ballchain.systems.magnetic_wrench import PortDipoles

    cd = MakeStation(load_scenario("teleop_right_unit", "{engine: statics, mode: quasi-static}"))
    engine = cd.chain.engine_system
    p_W, m_W = engine.straight(engine._s0)
    k, c = engine._constraints(engine._s0)
    engine.equilibrium(engine._s0, None)  # builds the solver of this sub-chain
    lean = engine._lean[engine._n - k]
    p_B, m_B = c.to_base(p_W[k:], m_W[k:])
    radius = 0.05
    tip = p_W[-1]
    for offset, inside in ((0.9 * radius, True), (1.1 * radius, False)):
        magnet = PortDipoles(np.array([tip + [0.0, 0.0, offset]]), np.array([[0.0, 0.0, 1.0]]), np.array([radius]))
        answer = lean.solve(magnet, c, p_B, m_B, None)
        assert (answer is None) == inside
        if inside:
            with pytest.raises(UserInputError, match="bounding sphere"):
                lean.statics.solve(magnet, StaticsResult(p_B, m_B, 0.0, None, True, "", "", 0, 0.0), constraints=c)


def test_short_path_follows_the_solvers_settings():
    """The short path keeps the model's parts per constraints; a solver setting changed between two
    solves on the same constraints is used (the same answer as ChainStatics.solve with it)."""
    from ballchain.optimization.statics import StaticsResult
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation

    cd = MakeStation(load_scenario("heart_wall_contact", "{engine: statics, mode: quasi-static}"))
    engine = cd.chain.engine_system
    s = engine._s0 + 0.01
    p, m, _, k = engine.equilibrium(s, None)
    c = engine._constraints(s)[1]
    lean = engine._lean[engine._n - k]
    field = engine._field(None)
    p_B, m_B = c.to_base(engine.straight(s)[0][k:], engine.straight(s)[1][k:])
    for max_iterations in (50, 2):
        lean.statics.max_iterations = max_iterations
        answer = lean.solve(field, c, p_B, m_B, None)
        reference = lean.statics.solve(field, StaticsResult(p_B, m_B, 0.0, None, True, "", "", 0, 0.0), constraints=c)
        assert answer.iterations == reference.iterations <= max_iterations
        assert answer.converged == reference.converged and answer.reason == reference.reason
        assert np.array_equal(answer.positions, reference.positions)
    assert not answer.converged and "iteration limit (2)" in answer.reason
