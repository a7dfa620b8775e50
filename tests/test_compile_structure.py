"""How the compiled kernels are compiled (``drake_models/kernels/_common.kernel``): each kernel
once, whatever constants its compiled callers pass; a fresh process loads the solve from
numba's disk cache without compiling; a process that imported a kernel file before it was
edited does not leave its code in the cache for the edited file. Checked through numba's
dispatcher records (signatures, cache hits and misses), never by timing."""

import json
import os
import subprocess
import sys
import textwrap

import pytest
from numba.core.caching import NullCache

from ballchain.drake_models.kernels._common import kernel


@kernel
def _scaled(x, order):
    return x * order


@kernel
def _with_constants(x):
    return _scaled(x, 0) + _scaled(x, 2) + _scaled(x, int(x))


# Compiled in this process every time: loaded from the disk cache (a second run in the same
# checkout), ``_with_constants`` would hold ``_scaled`` inside its cached code and ``_scaled``
# would show no specialisation at all.
_scaled._cache = _with_constants._cache = NullCache()


def test_constant_arguments_compile_one_specialisation():
    """Calls with the constants 0 and 2 and with a variable share one int64 specialisation
    (numba alone compiles one per literal value)."""
    assert _with_constants(3.0) == 15.0
    assert [str(sig) for sig in _scaled.signatures] == ["(float64, int64)"]


# The named cases of the compiled solve (free space, magnets, tip target, plane wall, iteration
# limit, the heart), run in a fresh process: prints, per kernel of the solve, its compiled
# specialisations and its cache hits and misses.
_SOLVES = textwrap.dedent("""
    import json
    import numpy as np
    from ballchain.drake_models import kernels
    from ballchain.drake_models.atrium_sdf import atrium_sdf
    from ballchain.drake_models.field_sources import MagnetSource, UniformField
    from ballchain.drake_models.heart import LeftAtrium
    from ballchain.drake_models.params import BallChain, CylinderMagnet, Sleeve
    from ballchain.optimization import compiled_newton
    from ballchain.optimization.statics import ChainStatics
    from ballchain.optimization.wall_constraints import HeartConstraints, SheathGeometry, base_rotation, sheath_split

    field = UniformField.in_plane(0.023, np.radians(90.0))
    free = ChainStatics(BallChain(n_balls=8, sleeve=Sleeve()), gravity=True).solve(field)
    ChainStatics(BallChain(n_balls=8)).solve(field, tip_target=free.tip_position + [1e-3, 0.0, 0.0])
    ChainStatics(BallChain(n_balls=8)).solve(field, wall=(np.array([0.0, 0.012, 0.0]), np.array([0.0, -1.0, 0.0])))
    ChainStatics(BallChain(n_balls=8), max_iterations=1).solve(field)
    heart = LeftAtrium()
    magnet = MagnetSource.pointing(CylinderMagnet(), heart.p_HP + [0.1651, 0.0, 0.0], [0.0, -1.0, 0.0], "dipole")
    k, a = sheath_split(16, 0.027, 3.175e-3)
    constraints = HeartConstraints(heart.p_HE + a * heart.sheath_axis_H, base_rotation(heart.sheath_axis_H),
                                   atrium_sdf(heart), SheathGeometry(heart.p_HE, heart.sheath_axis_H, 1.8e-3, 0.3e-3),
                                   n_behind=k, gravity=True)
    ChainStatics(BallChain(n_balls=16 - k), gravity=True).solve(magnet, constraints=constraints)
    modules = [compiled_newton] + [getattr(kernels, m) for m in ("charts", "constraints", "dense_qp", "external",
                                                                 "heart_rows", "pair", "reduced", "sdf", "sleeve")]
    out = {}
    for module in modules:
        for name, value in vars(module).items():
            if hasattr(value, "signatures") and value.py_func.__module__ == module.__name__:
                out[f"{module.__name__.rsplit('.', 1)[-1]}.{name}"] = {
                    "signatures": len(value.signatures), "hits": sum(value.stats.cache_hits.values()), "misses": sum(value.stats.cache_misses.values())}
    print(json.dumps(out))
""")


def _solve_kernels(env=None) -> dict:
    proc = subprocess.run([sys.executable, "-c", _SOLVES], capture_output=True, text=True, timeout=1800,
                          env=env or dict(os.environ))
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _check_structure(kernels: dict) -> None:
    """Every kernel the named cases ran is compiled once: the solve's evaluation (called with the
    orders 0 and 2 and a variable), its answer (one constant reason per exit), the heart's rows
    (with and without the Hessian) and every kernel below them."""
    for name in ("compiled_newton.newton", "compiled_newton.evaluate", "compiled_newton._answer",
                 "heart_rows.heart_rows", "reduced.reduced_energy", "sleeve.sleeve_energy"):
        assert kernels[name]["signatures"] == 1, (name, kernels[name])
    for name, k in kernels.items():
        assert k["signatures"] <= 1, f"{name}: {k['signatures']} specialisations"


@pytest.mark.slow
def test_the_solve_compiles_each_kernel_once_and_a_fresh_process_reuses_the_cache(tmp_path):
    """With an empty cache the named cases compile each kernel of the solve once; a second fresh
    process on that cache loads the kernels called from Python (the solve's code carries the
    kernels it calls) and compiles none."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    first = _solve_kernels(env)
    _check_structure(first)
    assert first["compiled_newton.newton"]["misses"] == 1
    second = _solve_kernels(env)
    ran = [name for name, k in second.items() if k["signatures"]]
    assert "compiled_newton.newton" in ran and "charts.chart_frames" in ran
    for name in ran:
        assert (second[name]["signatures"], second[name]["hits"], second[name]["misses"]) == (1, 1, 0), \
            (name, second[name])


_EDITED = """
from ballchain.drake_models.kernels._common import kernel


@kernel
def offset(x):
    return x + {value}
"""

_RUN_WHILE_EDITED = """
import sys
from pathlib import Path
sys.path.insert(0, sys.argv[1])
import edited
if len(sys.argv) > 2:  # the file edited after this process imported it, before its first call
    Path(sys.argv[1], "edited.py").write_text(sys.argv[2])
print(edited.offset(1.0), sum(edited.offset.stats.cache_hits.values()), sum(edited.offset.stats.cache_misses.values()))
"""


@pytest.mark.slow
def test_a_process_running_old_code_does_not_cache_it_for_the_edited_file(tmp_path):
    """A process imports a kernel's file, the file is edited (a constant: numba's own index key,
    the function's bytecode, does not change), then the process compiles and caches the code it
    imported. A fresh process importing the edited file compiles the edit instead of loading the
    old code; the next one loads the edit."""
    folder = tmp_path / "module"
    folder.mkdir()
    (folder / "edited.py").write_text(_EDITED.format(value="1.0"))
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}

    def run(*edit):
        proc = subprocess.run([sys.executable, "-c", _RUN_WHILE_EDITED, str(folder), *edit], capture_output=True,
                              text=True, timeout=300, env=env)
        assert proc.returncode == 0, proc.stderr[-3000:]
        value, hits, misses = proc.stdout.split()
        return float(value), int(hits), int(misses)

    assert run(_EDITED.format(value="2.0")) == (2.0, 0, 1)  # the old code, compiled and cached
    assert run() == (3.0, 0, 1)  # the edited file: compiled, not the old code from the cache
    assert run() == (3.0, 1, 0)  # and now loaded


@pytest.mark.slow
def test_the_solves_kernels_are_compiled_once():
    """The named cases in a fresh process on this run's cache (compiled there, or loaded: then
    only the kernels called from Python are): at most one specialisation per kernel."""
    kernels = _solve_kernels()
    if kernels["compiled_newton.newton"]["misses"]:
        _check_structure(kernels)
    for name, k in kernels.items():
        assert k["signatures"] <= 1, f"{name}: {k['signatures']} specialisations"
