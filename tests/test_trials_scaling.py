"""benchmarks/trials_scaling.py: the scaling table's model (makespan, warm-up, estimate) and its --from-json."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from script_helpers import load_benchmark

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def scaling():
    return load_benchmark("trials_scaling")


def _measurement():
    rows = [{"workers": 0, "wall_s": 12.0, "cpu_s": 11.0, "load": 1.0, "run_cpu_s": [4.0, 3.0, 2.0, 1.0],
             "run_wall_s": [4.0, 3.0, 2.0, 1.0]},
            {"workers": 1, "wall_s": 16.0, "cpu_s": 15.0, "load": 1.0, "run_cpu_s": [4.0, 3.0, 2.0, 1.0],
             "run_wall_s": [4.0, 3.0, 2.0, 1.0]}]
    overhead = {"cluster_start_s": 0.5, "cluster_stop_s": 0.5, "task_round_trip_s": 0.25, "task_throughput_s": 0.01,
                "tasks": 10}
    return rows, overhead


def test_makespan_schedules_the_longest_runs_first(scaling):
    assert scaling.makespan([4.0, 3.0, 2.0, 1.0], 1) == 10.0
    assert scaling.makespan([4.0, 3.0, 2.0, 1.0], 2) == 5.0  # {4, 1}, {3, 2}
    assert scaling.makespan([4.0, 3.0, 2.0, 1.0], 8) == 4.0  # the longest run bounds it


def test_the_estimate_is_calibrated_on_the_one_worker_row(scaling):
    rows, overhead = _measurement()
    # 16 = 12 + 0.5 + 0.5 + 4 x 0.25 + warm-up
    assert scaling.warm_up(rows, overhead) == pytest.approx(2.0, abs=1e-12)
    assert scaling.estimate(rows, overhead, 1) == pytest.approx(16.0, abs=1e-12)  # reproduces its own row
    # fixed 2 + start/stop 1 + warm-up 2 + makespan 5 + 4 x 0.25 / 2
    assert scaling.estimate(rows, overhead, 2) == pytest.approx(10.5, abs=1e-12)
    assert scaling.warm_up(rows[:1], overhead) == 0.0


def test_from_json_prints_the_tables_of_a_saved_measurement(tmp_path):
    rows, overhead = _measurement()
    saved = tmp_path / "scaling.json"
    saved.write_text(json.dumps({"arms": ["robotic_right"], "seeds": 4, "targets": None, "rows": rows,
                                 "overhead": overhead}))
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "trials_scaling.py"), "--from-json", str(saved),
                           "--nodes", "1", "2"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "| 2 | 10.5 | 2.62 |" in proc.stdout
    assert "a worker's warm-up 2.0 s" in proc.stdout
