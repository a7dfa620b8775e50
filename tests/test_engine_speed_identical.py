"""The engine's shortcuts give the very same numbers as the work they skip: the initial
equilibrium taken from the warm-up, the watchdog's finiteness test and the one-thread BLAS
context."""

import numpy as np


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
    original = engine.equilibrium

    def counting(*args, **kwargs):
        calls.append(args[0])
        return original(*args, **kwargs)

    engine.equilibrium = counting
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
