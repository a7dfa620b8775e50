"""The published catheter lesions (issue 44): the table's completeness, and the model against one point."""

import pytest

from ballchain.drake_models import lesion_literature as lit
from ballchain.experiments import lesion_validation
from ballchain.infrastructure.errors import UserInputError


def test_table_has_three_sources_and_eight_points_each_with_its_spread():
    assert len(lit.PUBLISHED) >= 8
    assert len({p.source for p in lit.PUBLISHED}) >= 3
    assert {p.source for p in lit.PUBLISHED} <= set(lit.SOURCES)
    assert len({p.key for p in lit.PUBLISHED}) == len(lit.PUBLISHED)
    for p in lit.PUBLISHED:
        assert p.depth_mm > 0 and p.duration_s > 0 and p.forces_gf
        assert (p.width_mm is None) == (p.width_sd_mm is None)
    assert sum(p.depth_sd_mm is not None for p in lit.PUBLISHED) >= 8


def test_one_short_point_on_a_coarse_mesh():
    """50 W for 4 s in a saline flow bath (the shortest point): the model's depth within 2 SD of
    the published 2.42 +- 0.61 mm and its delivered power at most the set 50 W."""
    (point,) = [p for p in lit.PUBLISHED if p.key == "S-50W4s"]
    result = lesion_validation.run((point,), h_mm=0.3, progress=False)
    (row,) = result.rows
    assert abs(row["depth_error_sd"]) <= 2.0
    assert 0 < row["model_delivered_W"] <= 50.0 + 1e-9
    assert "S-50W4s" in lesion_validation.markdown_table(result)


def test_bad_mesh_is_refused():
    with pytest.raises(UserInputError, match="h_mm"):
        lesion_validation.run(h_mm=5.0, progress=False)
