"""A tiny lesion table (4 coarse FEM runs of 4 s) in a temporary cache, for the quick tests."""

import pytest

from ballchain.drake_models import lesion_surrogate as ls

TINY_SPEC = ls.TableSpec(indentations_m=(0.8e-3, 1.2e-3), powers_W=(1.0, 6.0), duration_s=4.0, output_every_s=2.0,
                         h_m=0.3e-3, dt_max_s=1.0)


@pytest.fixture(scope="module")
def tiny_surrogate(tmp_path_factory):
    """The surrogate of ``TINY_SPEC``, built once per test session in its own cache folder."""
    mp = pytest.MonkeyPatch()
    mp.setenv("BALLCHAIN_CACHE", str(tmp_path_factory.getbasetemp() / "lesion_cache"))
    try:
        yield ls.LesionSurrogate(TINY_SPEC, progress=False)
    finally:
        mp.undo()
