"""The ring verdict on hand-built rings: overlap and no-overlap pairs, a missing target, the
last -> first pair, transmurality, the spacing rule; the PNG map and the Meshcat patches."""

import json

import numpy as np
import pytest

from ballchain.drake_models import lesion_ring as lr
from ballchain.drake_models import lesion_surrogate as ls
from ballchain.infrastructure.errors import UserInputError
from lesion_helpers import tiny_surrogate  # noqa: F401 (a fixture)

WALL = 2.5e-3


def ring_points(n, radius=20e-3, angles=None):
    """n targets on a circle in the z = 0 plane (the wall's normal along +z), names t0..t{n-1}."""
    angles = np.linspace(0.0, 2 * np.pi, n, endpoint=False) if angles is None else np.asarray(angles)
    return [lr.AblationPoint(name=f"t{k}", p_W=np.array([radius * np.cos(a), radius * np.sin(a), 0.0]),
                             n_W=np.array([0.0, 0.0, 1.0]), force_N=0.2, duration_s=30.0, power_W=2.0)
            for k, a in enumerate(angles)]


def lesion(point, width, depth=3e-3):
    return lr.Lesion(point=point, width_m=width, depth_m=depth, magnet_peak_C=60.0, transmural=depth >= WALL,
                     wall_thickness_m=WALL)


def chord(radius, n):
    return 2 * radius * np.sin(np.pi / n)


def test_closed_ring_of_overlapping_transmural_lesions_is_isolated():
    pts = ring_points(20)
    d = chord(20e-3, 20)  # 6.27 mm
    verdict = lr.analyse_ring([lesion(p, d + 0.5e-3) for p in pts], [p.name for p in pts])
    assert verdict.isolated and verdict.gaps == [] and verdict.missing == []
    assert len(verdict.pairs) == 20  # the last -> first pair included
    assert (verdict.pairs[-1]["a"], verdict.pairs[-1]["b"]) == ("t19", "t0")
    np.testing.assert_allclose([p["distance_m"] for p in verdict.pairs], d, rtol=1e-12)
    assert verdict.transmural_fraction == 1.0
    # 6.27 mm apart: over the CLOSE rule's 6 mm although the lesions overlap.
    assert not verdict.spacing_ok and not any(p["spacing_ok"] for p in verdict.pairs)


def test_a_narrow_pair_is_a_gap_exactly_where_the_widths_do_not_reach():
    pts = ring_points(20, radius=18e-3)  # 5.63 mm apart
    d = chord(18e-3, 20)
    widths = [6e-3] * 20
    widths[7] = widths[8] = d - 0.1e-3  # t7-t8 do not overlap; t6-t7 and t8-t9 do (mean > d)
    verdict = lr.analyse_ring([lesion(p, w) for p, w in zip(pts, widths)], [p.name for p in pts])
    assert [(g["kind"], g["a"], g["b"]) for g in verdict.gaps] == [("no_overlap", "t7", "t8")]
    assert not verdict.isolated and verdict.spacing_ok
    # Centre distance == mean width: touching counts as overlapping.
    widths[7] = widths[8] = d
    assert lr.analyse_ring([lesion(p, w) for p, w in zip(pts, widths)], [p.name for p in pts]).isolated


def test_missing_target_is_a_gap_and_its_neighbours_pair_across_it():
    pts = ring_points(12, radius=10e-3)
    kept = [p for p in pts if p.name != "t5"]
    verdict = lr.analyse_ring([lesion(p, 8e-3) for p in kept], [p.name for p in pts])
    assert verdict.missing == ["t5"]
    assert {"kind": "missing", "target": "t5"} in verdict.gaps and not verdict.isolated
    across = [p for p in verdict.pairs if p["across_missing"]]
    assert [(p["a"], p["b"], p["across_missing"]) for p in across] == [("t4", "t6", ["t5"])]
    np.testing.assert_allclose(across[0]["distance_m"], 2 * 10e-3 * np.sin(2 * np.pi / 12), rtol=1e-12)
    assert across[0]["overlap"] is False  # 10 mm apart, 8 mm wide
    assert len(verdict.pairs) == 11


def test_last_to_first_pair_is_checked():
    # Targets on 300 degrees of the circle: every neighbour 5.24 mm apart except t9 -> t0.
    angles = np.radians(np.linspace(0.0, 300.0, 10))
    pts = ring_points(10, radius=10e-3, angles=angles)
    verdict = lr.analyse_ring([lesion(p, 6e-3) for p in pts], [p.name for p in pts])
    assert [(g["a"], g["b"]) for g in verdict.gaps] == [("t9", "t0")]
    np.testing.assert_allclose(verdict.pairs[-1]["distance_m"], 10e-3, rtol=1e-12)  # 60 degrees: one radius


def test_shallow_lesions_are_not_transmural_and_the_ring_not_isolated():
    pts = ring_points(10, radius=8e-3)
    depths = [3e-3] * 10
    depths[2] = 2.4e-3
    verdict = lr.analyse_ring([lesion(p, 6e-3, depth=z) for p, z in zip(pts, depths)])
    assert verdict.gaps == [] and verdict.non_transmural == ["t2"]
    assert verdict.transmural_fraction == pytest.approx(0.9) and not verdict.isolated


def test_ring_order_defaults_to_the_lesions_and_reorders_pairs():
    pts = ring_points(6, radius=5e-3)
    lesions = [lesion(p, 6e-3) for p in pts]
    reordered = lr.analyse_ring(lesions, ["t0", "t2", "t1", "t3", "t4", "t5"])
    assert [(p["a"], p["b"]) for p in reordered.pairs][:3] == [("t0", "t2"), ("t2", "t1"), ("t1", "t3")]
    assert [(p["a"], p["b"]) for p in lr.analyse_ring(lesions).pairs][0] == ("t0", "t1")


def test_a_target_ablated_twice_sits_in_its_slot():
    pts = ring_points(6, radius=5e-3)
    again = lr.AblationPoint("t2", pts[2].p_W + [0.5e-3, 0, 0], pts[2].n_W, 0.2, 10.0, 2.0)
    lesions = [lesion(p, 6e-3) for p in pts[:3]] + [lesion(again, 6e-3)] + [lesion(p, 6e-3) for p in pts[3:]]
    verdict = lr.analyse_ring(lesions, [p.name for p in pts])
    assert [(p["a"], p["b"]) for p in verdict.pairs][1:4] == [("t1", "t2"), ("t2", "t2"), ("t2", "t3")]
    assert verdict.isolated


def test_to_dict_is_json_in_mm():
    pts = ring_points(8, radius=8e-3)
    verdict = lr.analyse_ring([lesion(p, 6.5e-3) for p in pts[:-1]], [p.name for p in pts])
    data = json.loads(json.dumps(verdict.to_dict()))
    assert data["isolated"] is False and data["missing"] == ["t7"]
    assert data["wall_thickness_mm"] == 2.5 and data["spacing_rule_mm"] == 6.0
    assert data["pairs"][0]["distance_mm"] == pytest.approx(1e3 * chord(8e-3, 8), abs=1e-4)
    les = json.loads(json.dumps(lesion(pts[0], 6.5e-3).to_dict()))
    assert les["width_mm"] == 6.5 and les["force_gf"] == pytest.approx(0.2 / 9.80665e-3, abs=1e-3)
    assert les["transmural"] is True and les["magnet_ok"] is True  # 60 C < N52's 80 C
    kinds = sorted(g["kind"] for g in data["gaps"])
    assert kinds == ["missing", "no_overlap"]  # t6 -> t0 across t7: 11.3 mm apart, 6.5 mm wide


def test_bad_ring_input_is_a_user_error():
    pts = ring_points(4)
    lesions = [lesion(p, 5e-3) for p in pts]
    with pytest.raises(UserInputError, match="not in ring_order"):
        lr.analyse_ring(lesions, ["t0", "t1", "t2"])
    with pytest.raises(UserInputError, match="distinct"):
        lr.analyse_ring(lesions, ["t0", "t1", "t2", "t3", "t0"])
    bad = lr.AblationPoint("x", np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 2.0]), 0.2, 10.0, 1.0)
    with pytest.raises(UserInputError, match=r"points\[0\].n_W"):
        lr.lesions_for([bad])
    with pytest.raises(UserInputError, match="grade"):
        lr.lesions_for([], grade="N99")


def test_ring_figure_writes_a_png(tmp_path):
    pts = ring_points(12, radius=10e-3)
    lesions = [lesion(p, 6e-3, depth=3e-3 if k != 3 else 2e-3) for k, p in enumerate(pts) if k != 5]
    verdict = lr.analyse_ring(lesions, [p.name for p in pts])
    path = tmp_path / "ring.png"
    lr.ring_figure(verdict, lesions, path, title="test ring")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_draw_lesions_puts_patches_gaps_and_missing_targets_in_meshcat():
    from pydrake.geometry import Meshcat, MeshcatParams

    meshcat = Meshcat(MeshcatParams(host="localhost"))
    pts = ring_points(8, radius=10e-3)
    lesions = [lesion(p, 3e-3) for p in pts if p.name != "t4"]
    verdict = lr.analyse_ring(lesions, [p.name for p in pts])
    lr.draw_lesions(meshcat, lesions, verdict, prefix="lesions", targets={p.name: p.p_W for p in pts})
    for p in pts:
        assert meshcat.HasPath(f"lesions/{p.name}") == (p.name != "t4")
    assert meshcat.HasPath("lesions/missing/t4")
    assert meshcat.HasPath("lesions/gaps/t0__t1")  # 7.65 mm apart, 3 mm wide


def test_lesions_for_reads_the_surrogate(tiny_surrogate, monkeypatch):
    monkeypatch.setattr(ls, "default_surrogate", lambda: tiny_surrogate)
    dwells = [(0.15, 3.0, 2.0), (0.0, 4.0, 3.0), (0.5, 1.0, 1.5)]  # (force, duration, power); no contact; past the table
    pts = [lr.AblationPoint(p.name, p.p_W, p.n_W, force_N=f, duration_s=t, power_W=w)
           for p, (f, t, w) in zip(ring_points(3), dwells)]
    lesions = lr.lesions_for(pts, wall_thickness_m=1e-3)
    expected = [tiny_surrogate.predict(p.force_N, p.power_W, p.duration_s) for p in pts]
    for les, e in zip(lesions, expected):
        assert (les.width_m, les.depth_m, les.magnet_peak_C) == (e.width_m, e.depth_m, e.magnet_peak_C)
        assert les.transmural == (e.depth_m >= 1e-3)
    assert lesions[1].width_m == 0.0 and lesions[1].magnet_peak_C == ls.BODY_TEMPERATURE_C  # no contact


def test_unrolled_ring_puts_missing_targets_between_their_neighbours():
    pts = ring_points(6, radius=6e-3)  # 6 mm apart
    lesions = [lesion(p, 6.5e-3) for p in pts if p.name not in ("t0", "t3")]
    verdict = lr.analyse_ring(lesions, [p.name for p in pts])
    s, total = lr._unrolled(lesions, verdict)
    # From t1: t2 at 6 mm, t3 (missing) half way along the 10.4 mm chord t2-t4, t4, t5, then t0
    # (missing) half way back to t1; the whole ring is the sum of the four pairs' chords.
    long = 2 * 6e-3 * np.sin(np.pi / 3)
    np.testing.assert_allclose(s, [2 * 6e-3 + 1.5 * long, 0, 6e-3, 6e-3 + 0.5 * long, 6e-3 + long,
                                   2 * 6e-3 + long], rtol=1e-12)
    assert total == pytest.approx(2 * 6e-3 + 2 * long, rel=1e-12)


def test_ring_figure_text_is_legible_and_names_targets_by_what_tells_them_apart(tmp_path, monkeypatch):
    """Every text of the ring figure is at least LABEL_PT points at a width a report shows (its
    tick labels were 6 pt on a 13-inch figure: about 5 px in the report), and targets right_1 ..
    right_18 are labelled 1 .. 18."""
    import dataclasses

    from matplotlib.text import Text

    import ballchain.infrastructure.safe_files as sf

    pts = [dataclasses.replace(p, name=f"right_{k + 1}") for k, p in enumerate(ring_points(18, radius=14e-3))]
    lesions = [lesion(p, 6e-3) for k, p in enumerate(pts) if k != 5]
    verdict = lr.analyse_ring(lesions, [p.name for p in pts])
    saved = []
    monkeypatch.setattr(sf, "save_figure", lambda fig, path, **kw: saved.append(fig))
    lr.ring_figure(verdict, lesions, tmp_path / "ring.png")
    (fig,) = saved
    assert fig.get_size_inches()[0] * 110 <= 1200  # shown near its own size in a report
    texts = [t for t in fig.findobj(Text) if t.get_text().strip()]
    assert texts and min(t.get_fontsize() for t in texts) >= lr.LABEL_PT
    shown = {t.get_text() for t in texts}
    assert {"1", "18", "1 again", "5-7", "18-1"} <= shown and not any(s.startswith("right_") for s in shown)
