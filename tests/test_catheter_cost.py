"""The comparison's cost cuts keep its results: each shortcut gives the same floats as what it
replaces (the whole runs' bit-identity: ``benchmarks/manual_bench.py``)."""

from __future__ import annotations

import copy

import numpy as np

from ballchain.drake_models.steerable_catheter import SteerableCatheter
from ballchain.optimization.rod_statics import RodStatics
from ballchain.systems.catheter_station import _finite
from ballchain.systems.simulated_operator import TargetRecord, _Memory


def test_operator_memory_copy_shares_only_closed_records():
    """A closed record (moved on from) is shared by the copies, the open one is copied: changing
    the copy's open record leaves the original's alone."""
    closed = TargetRecord("left_1", 0.0, t_touch=1.0, accuracy=1e-3, t_end=1.0)
    mem = _Memory(J=np.zeros((3, 2)), P=np.eye(2), queue=[np.zeros(3)], applied=np.zeros(3),
                  records=[closed, TargetRecord("left_2", 1.0)])
    new = copy.deepcopy(mem)
    assert new.records[0] is closed and new.records[1] is not mem.records[1]
    new.records[1].bursts += 1
    new.J[0, 0] = 1.0
    assert mem.records[1].bursts == 0 and mem.J[0, 0] == 0.0


class _CountingWall:
    """A flat wall z >= 0 (the sdf is z), counting its calls."""

    calls = 0

    def __call__(self, p, gradient=True, hessian=False):
        self.calls += 1
        p = np.atleast_2d(p)
        grads = np.tile([0.0, 0.0, 1.0], (len(p), 1))
        return (p[:, 2].copy(), grads, np.zeros((len(p), 3, 3))) if hessian else (p[:, 2].copy(), grads)


def test_rod_wall_values_are_asked_once_per_iterate_and_are_the_sdfs():
    """The wall's values at a pose are the sdf's at its nodes, computed once for that pose; the
    solve against the wall gives the same equilibrium as one whose sdf is asked every time."""
    wall = _CountingWall()
    cat = SteerableCatheter()
    rod = RodStatics(cat, [0.0, 0.0, 0.03], [1.0, 0.0, -1.0], wall)
    pose = rod.pose(np.full(3 * rod.n_joints, 0.01), rod.max_length, 0.2)
    values, grads = rod.wall_at(pose)
    again, _ = rod.wall_at(pose)
    assert wall.calls == 1 and again is values
    assert np.array_equal(values, pose.nodes[:, 2]) and np.array_equal(grads[:, 2], np.ones(len(pose.nodes)))
    sol = rod.solve(80e-3, 0.3, cat.curvature(0.5))
    ref = _Uncached(cat, [0.0, 0.0, 0.03], [1.0, 0.0, -1.0], _CountingWall()).solve(80e-3, 0.3, cat.curvature(0.5))
    assert sol.wall_forces.any()  # pressed on the wall
    assert np.array_equal(sol.q, ref.q) and np.array_equal(sol.wall_forces, ref.wall_forces)


class _Uncached(RodStatics):
    """The rod asking the sdf at every use, as before the values were kept with the pose."""

    def wall_at(self, pose):
        return self.sdf(pose.nodes, gradient=True)


def test_finite_is_nan_to_num_and_a_copy():
    x = np.array([1.5, -2.0, 0.25])
    y = _finite(x)
    assert np.array_equal(y, x) and y is not x
    z = _finite([np.nan, np.inf, 1.0])
    assert np.array_equal(z, np.nan_to_num(np.array([np.nan, np.inf, 1.0])))
