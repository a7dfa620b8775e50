"""The examples (``>>>``) in the docstrings of the public entry points run as they stand.

Each entry point's docstring shows a short call with what it returns, units included (as
magpylib's do); the API reference renders them. A docstring that loses its example, or whose
example no longer prints what it says, fails here.
"""

import doctest

import pytest

import ballchain as bc
from ballchain.experiments import alignment
from ballchain.sweep import runner as sweep_runner

ENTRY_POINTS = {
    "MakeStation": bc.MakeStation,
    "run_station": bc.run_station,
    "StationRunner": bc.StationRunner,
    "ChainStatics.solve": bc.ChainStatics.solve,
    "load_scenario": bc.load_scenario,
    "load_anatomy": bc.load_anatomy,
    "UniformField": bc.UniformField,
    "MagnetSource": bc.MagnetSource,
    "run_sweep": sweep_runner.run_sweep,
    "experiments.alignment.run": alignment.run,
}


@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_the_docstring_example_runs(name):
    obj = ENTRY_POINTS[name]
    tests = doctest.DocTestFinder(recurse=False).find(obj, name, globs={})
    examples = sum(len(t.examples) for t in tests)
    assert examples >= 2, f"{name}'s docstring has no example (>>>)"
    runner = doctest.DocTestRunner(optionflags=doctest.NORMALIZE_WHITESPACE)
    for test in tests:
        runner.run(test)
    results = runner.summarize(verbose=False)
    assert results.failed == 0 and results.attempted == examples, f"{name}: {results}"


def test_ten_entry_points_have_examples():
    assert len(ENTRY_POINTS) >= 10
