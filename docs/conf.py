"""Sphinx configuration of the ballchain documentation site.

Build it (offline, warnings as errors) with ``python -m sphinx -W -b html docs DIR`` after
``pip install -e ".[docs]"``. The notebooks of ``notebooks/`` (``docs/notebooks`` links to them) are
executed at build time in the quick mode the tests use; ``-D nb_execution_mode=off`` renders them
without running them. The API reference is generated here from ``ballchain.__all__``, so a new
export appears without editing any page.
"""

import inspect
import os
import shutil
from pathlib import Path

import ballchain

DOCS = Path(__file__).resolve().parent

project = "ballchain"
author = "the ballchain authors"
copyright = "the ballchain authors, BSD-3-Clause"
release = version = ballchain.__version__

extensions = [
    "myst_nb",  # Markdown pages (MyST) and the notebooks, executed
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",  # the docstrings are Google style, with units
    "sphinx.ext.mathjax",
]

exclude_patterns = ["_build", "_generated", "figures", "**.ipynb_checkpoints", "notebooks/README*"]
templates_path = ["_templates"]

html_theme = "furo"
html_title = "ballchain"
html_static_path = []

myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3

napoleon_google_docstring = True
napoleon_numpy_docstring = False
autosummary_generate = True
autodoc_member_order = "bysource"
autodoc_typehints = "description"

# The notebooks, as the tests run them (tests/notebook_runner.py): quick mode, figures through the
# Agg backend (each notebook asks for inline figures), one BLAS thread, a fixed hash seed. The kernel
# inherits this environment; a value the caller set is kept.
for _name, _value in {"BALLCHAIN_NOTEBOOK_LONG": "0", "BALLCHAIN_NOTEBOOK_FULL": "0", "MPLBACKEND": "Agg",
                      "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                      "PYTHONHASHSEED": "0"}.items():
    os.environ.setdefault(_name, _value)
nb_execution_mode = "force"
nb_execution_timeout = 1800  # a hang guard, as the tests'
nb_execution_raise_on_error = True  # a notebook that fails breaks the build
nb_execution_show_tb = True
nb_execution_in_temp = True  # what a notebook writes (figures, replays) stays out of the source tree
nb_merge_streams = True


API_HEAD = """\
# API reference

`import ballchain` gives what a script needs: the names below are `ballchain.__all__`, each with
its one-line summary; follow a name for its full documentation. The names load when first used,
so `import ballchain` alone does not import Drake. The experiments are public too, one module each:
`ballchain.experiments.<name>.run` ([the experiments](guide/experiments.md)). Everything else is
private by convention: the modules of the sub-packages (`ballchain.drake_models`,
`ballchain.optimization`, `ballchain.systems`) keep their import paths, but may change without
notice. This page is generated from `ballchain.__all__` when the site is built.

```{{eval-rst}}
.. currentmodule:: ballchain

.. autosummary::
   :toctree: generated
   :nosignatures:

{entries}
```
"""


def is_value(name: str) -> bool:
    """An exported value (such as ``__version__``) rather than a module, class or function: listed
    with its value, as it has no documentation of its own."""
    obj = getattr(ballchain, name)
    return not (callable(obj) or inspect.ismodule(obj))


def write_api_page() -> None:
    """Write ``api.md`` from ``ballchain.__all__`` (only when it changed, so that Sphinx's incremental
    build does not redo it for nothing)."""
    names = list(getattr(ballchain, "__all__", []))
    if not names:
        raise RuntimeError("ballchain.__all__ is empty: the API reference would list nothing")
    entries = "\n".join(f"   {name}" for name in names if not is_value(name))
    values = "".join(f"`ballchain.{name}` = `{getattr(ballchain, name)!r}`\n\n" for name in names if is_value(name))
    text = API_HEAD.format(entries=entries) + ("\n## Values\n\n" + values if values else "")
    page = DOCS / "api.md"
    if not page.exists() or page.read_text() != text:
        page.write_text(text)
    documented = {f"ballchain.{name}.rst" for name in names if not is_value(name)}
    for stub in (DOCS / "generated").glob("*.rst"):  # a name no longer exported leaves no page behind
        if stub.name not in documented:
            stub.unlink()


def write_scenarios_table() -> None:
    """Write ``_generated/scenarios_table.md``: every named scenario with its description, engine and
    mode, read from the scenarios file (the guide's scenarios page includes it)."""
    from ballchain.systems.chain_scenario import load_scenario, scenario_names

    rows = ["| scenario | engine | mode | what it is |", "|---|---|---|---|"]
    for name in scenario_names():
        s = load_scenario(name)
        rows.append(f"| `{name}` | {s.engine} | {s.mode} | {s.description.replace('|', '/')} |")
    out = DOCS / "_generated" / "scenarios_table.md"
    out.parent.mkdir(exist_ok=True)
    text = "\n".join(rows) + "\n"
    if not out.exists() or out.read_text() != text:
        out.write_text(text)


def write_sweep_reference() -> None:
    """Write ``_generated/sweep_reference.md``: for every sweepable experiment, its spec fields
    (type, default, meaning), its output columns and its example spec (``guide/sweep_examples``,
    which the tests run), read from ``ballchain.experiments.studies.EXPERIMENTS``."""
    import dataclasses

    from ballchain.experiments.studies import EXPERIMENTS, field_docs

    cell = lambda text: str(text).replace("|", "/")  # noqa: E731
    parts = []
    for name, exp in EXPERIMENTS.items():
        docs = field_docs(exp.params)
        parts += [f"### `{name}`", "", f"{exp.description[:1].upper()}{exp.description[1:]}. A point takes "
                  f"about {exp.typical_s:g} s of CPU time (typical).", "",
                  "| field | type | default | meaning |", "|---|---|---|---|"]
        for field in dataclasses.fields(exp.params):
            kind = getattr(field.type, "__name__", str(field.type))
            default = field.default
            shown = (str(default).lower() if isinstance(default, bool) else f"{default:g}"
                     if isinstance(default, float) else repr(default))  # as YAML reads it
            parts.append(f"| `{field.name}` | {kind} | `{shown}` | {cell(docs.get(field.name, ''))} |")
        parts += ["", "Output columns (after `key`, `experiment`, the fields and `seed`; then `wall_time_s`, "
                  "`cpu_time_s`, `worker` and `error`, the reason a point failed):", "",
                  "| column | meaning |", "|---|---|"]
        parts += [f"| `{column}` | {cell(meaning)} |" for column, meaning in exp.outputs.items()]
        parts += ["", f"An example (`docs/guide/sweep_examples/{name}.yaml`, run by the tests):", "",
                  f"```{{literalinclude}} /guide/sweep_examples/{name}.yaml", ":language: yaml", "```", ""]
    out = DOCS / "_generated" / "sweep_reference.md"
    out.parent.mkdir(exist_ok=True)
    text = "\n".join(parts)
    if not out.exists() or out.read_text() != text:
        out.write_text(text)


# What this file and autosummary generate inside the source folder, because Sphinx reads its pages
# only from there: removed again when the build ends, so that a build writes only into its output
# folder and leaves the source tree as it found it.
GENERATED = (DOCS / "api.md", DOCS / "generated", DOCS / "_generated")


def remove_generated(app=None, exception=None) -> None:
    """Remove the generated pages from the source folder (Sphinx's ``build-finished`` event)."""
    for path in GENERATED:
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


def setup(app):
    app.connect("build-finished", remove_generated)
    return {"parallel_read_safe": True}


write_api_page()
write_scenarios_table()
write_sweep_reference()
