"""The tip ball's clinical lesion table and the dwell by a lesion criterion (issue 44), on a tiny
table (2 coarse FEM runs of 8 s in a temporary cache), and the procedure's lesions from it; the
report's clinical table shipped in the package, for the current code."""

import hashlib
import shutil

import numpy as np
import pytest

from ballchain.cli import main as cli_main
from ballchain.drake_models import lesion_dwell as ld
from ballchain.drake_models import model_files
from ballchain.drake_models.lesion_surrogate import MAGNET_MARGIN_C
from ballchain.drake_models.params import GRAVITY, magnet_grade
from ballchain.experiments.procedure_report import CLINICAL_LESIONS
from ballchain.experiments.procedure_result import ProcedureResult, with_lesions
from ballchain.infrastructure.errors import UserInputError

TINY = ld.DwellTableSpec(indentations_m=(0.8e-3, 1.2e-3), duration_s=8.0, output_every_s=2.0, h_m=0.3e-3)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("BALLCHAIN_CACHE", str(tmp_path_factory.getbasetemp() / "dwell_cache"))
    try:
        yield ld.DwellSurrogate(TINY, progress=False)
    finally:
        mp.undo()


def gf(v):
    return v * 1e-3 * GRAVITY


def test_table_holds_the_magnet_below_its_limit(tiny):
    """N52: 80 C less the 5 C margin; the generator's loop holds the ball's peak there."""
    assert tiny.table["magnet_peak_C"].max() <= 75.0 + 1e-6
    assert np.all(tiny.table["mean_power_W"][:, 1:] <= TINY.power_W + 1e-9)
    assert np.all(np.diff(tiny.table["depth_mm"], axis=1) >= -1e-9)  # the lesion only grows


def test_transmural_dwell_is_the_first_time_the_depth_reaches_the_wall(tiny):
    """The criterion's time: deep enough then, not 0.25 s before (the search's step)."""
    depth_end = tiny.predict(gf(20), TINY.duration_s)["depth_m"]
    wall = 0.8 * depth_end
    c = ld.LesionConditions(criterion="transmural", wall_thickness_m=wall, time_limit_s=8.0)
    t = tiny.dwell_for(gf(20), c, fixed_s=5.0)
    assert 0.25 <= t < 8.0
    assert tiny.predict(gf(20), t)["depth_m"] >= wall - 1e-12
    assert tiny.predict(gf(20), t - 0.25)["depth_m"] < wall
    # A wall deeper than the table reaches: the time limit.
    deep = ld.LesionConditions(criterion="transmural", wall_thickness_m=2 * depth_end + 1e-3, time_limit_s=6.0)
    assert tiny.dwell_for(gf(20), deep, fixed_s=5.0) == 6.0


def test_contiguous_dwell_waits_for_the_width_too(tiny):
    """"contiguous": transmural and as wide as the farthest neighbour: never sooner than transmural,
    and wide enough when it stops (or the time limit)."""
    wall = 0.5 * tiny.predict(gf(20), TINY.duration_s)["depth_m"]
    width = 0.95 * tiny.predict(gf(20), TINY.duration_s)["width_m"]
    trans = ld.LesionConditions(criterion="transmural", wall_thickness_m=wall, time_limit_s=8.0)
    cont = ld.LesionConditions(criterion="contiguous", wall_thickness_m=wall, time_limit_s=8.0)
    t_trans = tiny.dwell_for(gf(20), trans, fixed_s=5.0)
    t_cont = tiny.dwell_for(gf(20), cont, fixed_s=5.0, width_target_m=width)
    assert t_cont >= t_trans
    assert tiny.predict(gf(20), t_cont)["width_m"] >= width - 1e-12
    assert tiny.dwell_for(gf(20), cont, fixed_s=5.0, width_target_m=0.0) == t_trans


def test_neighbour_distances_close_the_loop():
    pts = [{"name": n, "p_W": p} for n, p in (("a", [0, 0, 0]), ("b", [3e-3, 0, 0]), ("c", [3e-3, 4e-3, 0]))]
    d = ld.neighbour_distances(pts)
    assert d["a"] == pytest.approx(5e-3) and d["b"] == pytest.approx(4e-3) and d["c"] == pytest.approx(5e-3)


def test_fti_and_fixed_dwells():
    c = ld.LesionConditions(criterion="fti", time_limit_s=60.0)
    model = object.__new__(ld.DwellSurrogate)
    model.spec = ld.DwellTableSpec()
    assert model.dwell_for(gf(20), c, fixed_s=10.0) == pytest.approx(20.0)  # 400 gf s / 20 gf
    assert model.dwell_for(gf(4), c, fixed_s=10.0) == 60.0  # 100 s capped at the limit
    fixed = ld.LesionConditions(criterion="fixed")
    assert model.dwell_for(gf(20), fixed, fixed_s=10.0) == 10.0


def test_procedure_lesions_from_the_clinical_table(tiny, monkeypatch):
    """``with_lesions`` with ``settings["lesions"]``: each lesion's RF time by the criterion, its
    power the delivered mean, the verdict recomputed from them."""
    monkeypatch.setattr(ld, "dwell_surrogate", lambda spec: tiny)
    wall = 0.8 * tiny.predict(gf(20), TINY.duration_s)["depth_m"]
    cond = ld.LesionConditions(criterion="transmural", wall_thickness_m=wall, time_limit_s=8.0)
    rows = []
    for k, force in enumerate((20.0, 20.0, 0.0)):
        p = np.array([2e-3 * k, 0.0, 0.0])
        rows.append({"target": f"t{k}", "point": {"name": f"t{k}", "p_W": p.tolist(), "n_W": [0.0, 0.0, 1.0],
                                                   "force_N": gf(force), "duration_s": 5.0}})
    result = ProcedureResult(task=None, navigator="auto", rows=rows, summary={}, settings={"lesions": cond.to_dict()})
    with_lesions(result, ["t0", "t1", "t2"])
    strong, weak = result.lesions[0], result.lesions[2]
    assert strong["transmural"] and strong["duration_s"] < 8.0 and 0 < strong["power_W"] < cond.power_W
    assert not weak["transmural"] and weak["depth_mm"] == 0.0  # no force, no lesion
    assert result.summary["isolated"] is False and result.ring["n_lesions"] == 3
    assert rows[0]["point"]["rf_duration_s"] == strong["duration_s"]


def test_bad_conditions_are_refused():
    with pytest.raises(UserInputError, match="criterion"):
        ld.LesionConditions(criterion="impedance")
    with pytest.raises(UserInputError, match="blood_flow"):
        ld.LesionConditions(blood_flow="fast")
    with pytest.raises(UserInputError, match="time_limit_s"):
        ld.LesionConditions(time_limit_s=0.0)


def test_procedure_refuses_a_bad_grade_before_running(capsys):
    assert cli_main(["procedure", "--blood-flow", "high", "--magnet-grade", "N99"]) == 2
    assert "--magnet-grade" in capsys.readouterr().err


def _no_build(*args, **kwargs):
    pytest.fail("the clinical table was built (or read from the cache), not taken from the package")


def test_the_reports_clinical_table_ships_for_the_current_code(tmp_path, monkeypatch):
    """The procedure report's clinical verdict loads its table from the package (no FEM run, nothing
    in an empty cache). A change to the code that makes the table changes its key: then this fails
    and says how to regenerate it."""
    spec = CLINICAL_LESIONS.table_spec()
    assert spec in ld.SHIPPED_SPECS, f"CLINICAL_LESIONS' table {spec} is not in lesion_dwell.SHIPPED_SPECS"
    path = ld.shipped_path(spec)
    shipped = sorted(d.name for d in ld.SHIPPED.iterdir())
    assert path.exists(), (f"the shipped clinical lesion table is not for the current code (its key is now "
                           f"{spec.key()}, shipped: {shipped}): regenerate it with `{ld.SHIP_COMMAND}` (about "
                           f"3 CPU-s) and commit drake_models/generated/lesion_dwell/")
    assert (path.parent / model_files.DIGESTS).read_text().split() == [hashlib.sha1(path.read_bytes()).hexdigest(),
                                                                      path.name]
    assert shipped == sorted({s.key() for s in ld.SHIPPED_SPECS}), "a stale shipped table: " + ld.SHIP_COMMAND
    monkeypatch.setenv("BALLCHAIN_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(model_files, "cached_files", _no_build)
    table = ld.cached_dwell_table(spec, progress=False)
    assert not (tmp_path / "cache" / "lesion_dwell").exists()
    # The table of this spec: its axes, the magnet held at its grade's limit less the margin, the
    # delivered power under the set power, lesions that only grow.
    np.testing.assert_array_equal(table["indentation_m"], spec.indentations_m)
    np.testing.assert_array_equal(table["duration_s"], spec.durations_s)
    assert table["magnet_peak_C"].max() <= magnet_grade(spec.grade).max_operating_C - MAGNET_MARGIN_C + 1e-6
    assert np.all(table["mean_power_W"] <= spec.power_W + 1e-9) and table["mean_power_W"][:, 1:].min() > 0.0
    assert np.all(np.diff(table["depth_mm"], axis=1) >= -1e-9) and table["depth_mm"][:, -1].min() > 1.0


def test_a_shipped_table_of_other_code_or_altered_is_not_used(tmp_path, monkeypatch):
    """The key carries the code's version: another version finds no shipped table; a shipped file
    whose SHA-1 is not the listed one is not read (the table is built into the cache instead)."""
    spec = ld.SHIPPED_SPECS[0]
    key = spec.key()
    monkeypatch.setattr(ld, "DWELL_TABLE_VERSION", ld.DWELL_TABLE_VERSION + 1)
    assert spec.key() != key and not ld.shipped_path(spec).exists()
    monkeypatch.undo()
    altered = tmp_path / "lesion_dwell"
    shutil.copytree(ld.SHIPPED, altered)
    (altered / key / "dwell_table.npz").write_bytes((ld.SHIPPED / key / "dwell_table.npz").read_bytes() + b"\0")
    monkeypatch.setattr(ld, "SHIPPED", altered)

    class FellThrough(Exception):
        pass

    def cached_files(directory, names, write):
        raise FellThrough(directory)

    monkeypatch.setattr(model_files, "cached_files", cached_files)
    with pytest.raises(FellThrough) as fell:
        ld.cached_dwell_table(spec, progress=False)
    assert fell.value.args[0].name == key  # to the cache, under the same key
