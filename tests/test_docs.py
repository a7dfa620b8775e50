"""The documentation site: the API reference lists every exported name; notebooks show their figures.

The slow test builds the site with warnings as errors (notebooks not executed: they have their own
tests) into a temporary folder, from a copy of docs/, notebooks/ and the README, so the build
writes nothing into the source tree. CI builds the site once, notebooks executed, and passes the
folder in ``$BALLCHAIN_DOCS_HTML``; the tests then read that build instead.
"""

import dataclasses
import inspect
import os
import shutil
import subprocess
import sys
from pathlib import Path

import nbformat
import pytest

import ballchain

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
BUILT_ENV = "BALLCHAIN_DOCS_HTML"  # a finished build of the site (notebooks executed), e.g. from .ci/run


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The HTML of the site: the build named by $BALLCHAIN_DOCS_HTML, else a fresh one."""
    if os.environ.get(BUILT_ENV):
        return Path(os.environ[BUILT_ENV])
    src = tmp_path_factory.mktemp("src")
    shutil.copytree(ROOT / "docs", src / "docs", symlinks=True,
                    ignore=shutil.ignore_patterns("_build", "generated", "_generated", "api.md"))
    shutil.copytree(ROOT / "notebooks", src / "notebooks")
    shutil.copy(ROOT / "README.md", src / "README.md")
    html = src / "html"
    before = _files(src / "docs")
    run = subprocess.run([sys.executable, "-m", "sphinx", "-W", "-q", "-b", "html", "-D", "nb_execution_mode=off",
                          str(src / "docs"), str(html)], capture_output=True, text=True, timeout=1800)
    assert run.returncode == 0, run.stderr[-3000:]
    # the build writes only into its output folder: the source folder is as it was
    assert _files(src / "docs") == before, sorted(_files(src / "docs") ^ before)[:10]
    return html


def _files(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


@pytest.mark.slow
def test_api_reference_lists_every_exported_name(site):
    api = (site / "api.html").read_text()
    for name in ballchain.__all__:
        value = getattr(ballchain, name)
        if not (callable(value) or inspect.ismodule(value)):  # a value such as __version__: shown as it is
            assert f"ballchain.{name}" in api and repr(value) in api, name
            continue
        page = site / "generated" / f"ballchain.{name}.html"
        assert f'href="generated/ballchain.{name}.html"' in api, name
        assert page.exists() and f"ballchain.{name}" in page.read_text(), name


@pytest.mark.slow
def test_the_api_reference_documents_every_public_method(site):
    """Each exported class's page documents its own public methods, with their arguments: the
    site listed ``ChainStatics.solve`` as a name with one line, and its ``wall`` and
    ``tip_target`` were on no page."""
    statics = (site / "generated" / "ballchain.ChainStatics.html").read_text()
    solve = statics.split('id="ballchain.ChainStatics.solve"', 1)[1].split('id="ballchain.ChainStatics.', 1)[0]
    for argument in ("tip_target", "wall", "constraints", "warm_start"):
        assert argument in solve, argument
    for name in ballchain.__all__:
        value = getattr(ballchain, name)
        if not inspect.isclass(value):
            continue
        page = (site / "generated" / f"ballchain.{name}.html").read_text()
        own = [m for m, v in vars(value).items() if not m.startswith("_") and inspect.isfunction(v)]
        for method in own:
            assert f'id="ballchain.{name}.{method}"' in page, f"{name}.{method}"


@pytest.mark.slow
def test_every_page_of_the_guide_is_built(site):
    for page in ("index", "getting_started", "results", "design", "notebooks", "testing", "guide/scenarios",
                 "guide/station", "guide/statics", "guide/teleoperation", "guide/experiments", "guide/sweeps",
                 "guide/anatomy", "guide/long_runs", "guide/ablation", "guide/world", "guide/trials", "guide/rl",
                 "guide/procedure", "guide/manual_catheter", *(f"notebooks/{p.stem}" for p in NOTEBOOKS)):
        assert (site / f"{page}.html").exists(), page
    # the sweep reference: every experiment's fields, outputs and example
    from ballchain.experiments.studies import EXPERIMENTS

    sweeps = (site / "guide" / "sweeps.html").read_text()
    for exp in EXPERIMENTS.values():
        for name in [*exp.outputs, *(f.name for f in dataclasses.fields(exp.params))]:
            assert f"<code class=\"docutils literal notranslate\"><span class=\"pre\">{name}</span></code>" in sweeps, name
    for name in EXPERIMENTS:  # the example specs, highlighted
        assert f'<span class="nt">experiment</span><span class="p">:</span><span class="w"> </span><span class="l l-Scalar l-Scalar-Plain">{name}</span>' in sweeps, name
    # the design notes render as a page: their sections and tables
    design = (site / "design.html").read_text()
    assert "Where the paper is wrong" in design and design.count("<table") >= 2


@pytest.mark.slow
def test_executed_notebooks_show_their_figures(site):
    if not os.environ.get(BUILT_ENV):
        pytest.skip(f"the notebooks run in their own tests; ${BUILT_ENV} names a build that executed them")
    for path in NOTEBOOKS:
        assert "<img" in (site / "notebooks" / f"{path.stem}.html").read_text(), path.stem


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebooks_draw_inline_under_any_backend(path):
    """With MPLBACKEND=Agg (the tests, the docs build) a notebook's figures reach its outputs only if
    it asks for the inline backend before it draws."""
    cells = [c.source for c in nbformat.read(path, as_version=4).cells if c.cell_type == "code"]
    draws = [i for i, source in enumerate(cells) if "plt." in source or "figure_" in source or "Image(" in source]
    inline = [i for i, source in enumerate(cells) if "%matplotlib inline" in source]
    assert draws and inline and inline[0] <= draws[0]
