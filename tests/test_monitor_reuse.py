"""The watchdog's reuse of a passed check (``ChainMonitor.check``): a device whose state key is the
one of the last check that passed passes again without looking, and its metrics are those of a
watchdog that looks every time. Hand-made states on a fake station, so every branch is reached."""

from types import SimpleNamespace

import numpy as np

from ballchain.systems.chain_simulation import ChainMonitor

BALL = 2.5e-3  # [m]
WALL = 2e-3  # [m] the fake heart's wall thickness
RADIUS = 20e-3  # [m] the fake heart: a ball of this radius about the origin


class _Heart:
    """A spherical lumen; counts its queries (a check that looks asks it)."""

    def __init__(self):
        self.queries = 0
        self.params = SimpleNamespace(wall_thickness=WALL)

    def contains(self, p):
        self.queries += 1
        return np.linalg.norm(p, axis=1) < RADIUS + WALL

    def wall_distance(self, p):
        return RADIUS - np.linalg.norm(p, axis=1)


class _Chain(SimpleNamespace):
    """The parts of a DeviceModel the watchdog reads; ``failure`` is the state's."""

    @property
    def failure(self):
        return self.state["failure"]


def _chain_at(offset, n: int = 4):
    """n touching balls along x, the first at ``offset`` (3,)."""
    return np.asarray(offset, float) + BALL * np.arange(n)[:, None] * np.array([1.0, 0.0, 0.0])


def _monitor(keyed: bool, tolerate=None, n: int = 4):
    """A watchdog on a fake station whose chain's state is ``state["p"]`` (keyed: with its state
    key, else None: no reuse)."""
    state = {"p": np.zeros((n, 3)), "failure": None}
    chain = _Chain(state=state, system=SimpleNamespace(GetMyContextFromRoot=lambda root: root),
                   config=SimpleNamespace(chain=SimpleNamespace(ball_diameter=BALL, length=n * BALL)),
                   body_indices=list(range(1, n + 1)), body_radius=BALL / 2, move_period=1e-3,
                   in_sheath=lambda p: np.zeros(len(p), bool),
                   is_finite=lambda ctx: bool(np.all(np.isfinite(state["p"]))),
                   non_finite_part=lambda ctx: "a ball", body_positions=lambda ctx: state["p"].copy(),
                   neighbour_gaps=lambda p: np.linalg.norm(np.diff(p, axis=0), axis=1) - BALL,
                   anatomy_offsets=lambda ctx: None,
                   state_key=(lambda ctx: state["p"].tobytes()) if keyed else (lambda ctx: None))
    heart = _Heart()
    cd = SimpleNamespace(chain=chain, heart=heart, scenario=SimpleNamespace(check_period=5e-3, break_gap=1e-3))
    return ChainMonitor(cd, tolerate_sinking=tolerate), state, heart


def _metrics(m: ChainMonitor) -> tuple:
    return (m.checks, m.min_clearance, m.max_gap, m.max_penetration, m.max_ball_overlap, m.max_wall_penetration,
            m._last_wall_time, list(m.tolerated_sinkings))


def test_an_unchanged_state_passes_without_looking_and_a_changed_one_is_looked_at():
    monitor, state, heart = _monitor(keyed=True)
    context = SimpleNamespace(get_time=lambda: 1.0)
    state["p"] = _chain_at([0.0, 0.0, 0.0])
    assert monitor.check(context, wall=True) is None
    asked = heart.queries
    assert asked == 1
    for wall in (True, False, True):
        assert monitor.check(context, wall=wall) is None
    assert heart.queries == asked  # not looked at again
    assert monitor.checks == 4
    state["p"] = _chain_at([1e-3, 0.0, 0.0])  # moved: looked at
    assert monitor.check(context, wall=True) is None
    assert heart.queries == asked + 1


def test_a_check_with_the_wall_after_one_without_it_looks():
    monitor, state, heart = _monitor(keyed=True)
    context = SimpleNamespace(get_time=lambda: 1.0)
    state["p"] = _chain_at([0.0, 0.0, 0.0])
    assert monitor.check(context, wall=False) is None
    assert heart.queries == 0
    assert monitor.check(context, wall=False) is None
    assert heart.queries == 0
    assert monitor.check(context, wall=True) is None
    assert heart.queries == 1  # the wall was never checked for this state: it is now
    assert monitor.check(context, wall=True) is None
    assert heart.queries == 1


def test_a_failure_reported_by_the_device_is_returned_even_for_an_unchanged_state():
    monitor, state, heart = _monitor(keyed=True)
    context = SimpleNamespace(get_time=lambda: 1.0)
    state["p"] = _chain_at([0.0, 0.0, 0.0])
    assert monitor.check(context, wall=True) is None
    state["failure"] = "quasi-static engine at t = 1.0000 s: no equilibrium"
    assert monitor.check(context, wall=True) == state["failure"]


def test_a_failed_check_is_made_again():
    monitor, state, heart = _monitor(keyed=True)
    context = SimpleNamespace(get_time=lambda: 1.0)
    state["p"] = _chain_at([RADIUS + 3 * WALL, 0.0, 0.0])  # outside the heart
    first = monitor.check(context, wall=True)
    assert first is not None and "escaped the heart" in first
    assert monitor.check(context, wall=True) == first
    assert heart.queries == 2


def test_a_tolerated_sinking_is_looked_at_again_and_recorded_as_without_reuse():
    """A ball past the wall's middle, tolerated: the check passes, but is made again at the same
    state, and the record (at most one per ball per 0.1 s) is the same as with no reuse."""
    runs = []
    for keyed in (False, True):
        monitor, state, heart = _monitor(keyed, tolerate=lambda p: True)
        t = [0.0]
        context = SimpleNamespace(get_time=lambda: t[0])
        # the last ball 0.6 of the wall beyond the lumen's radius: sunk past the wall's middle
        state["p"] = _chain_at([RADIUS + 0.6 * WALL - 3 * BALL, 0.0, 0.0])
        for k in range(30):
            t[0] = 0.01 * k
            assert monitor.check(context, wall=True) is None
        runs.append((_metrics(monitor), heart.queries))
    (plain, q_plain), (reused, q_reused) = runs
    assert plain == reused
    assert len(plain[-1]) == 3  # t = 0, 0.1, 0.2
    assert q_reused == q_plain == 30


def test_a_random_walk_gives_the_metrics_of_a_watchdog_that_always_looks():
    rng = np.random.default_rng(7)
    offsets = [rng.normal(scale=3e-3, size=3) for _ in range(12)]
    sequence = [offsets[int(i)] for i in rng.integers(0, 4, size=200)]  # states repeat, in runs and apart
    walls = rng.random(200) < 0.3
    results = []
    for keyed in (False, True):
        monitor, state, heart = _monitor(keyed)
        t = [0.0]
        context = SimpleNamespace(get_time=lambda: t[0])
        messages = []
        for k, (o, wall) in enumerate(zip(sequence, walls)):
            t[0] = 0.005 * k
            state["p"] = _chain_at(o)
            messages.append(monitor.check(context, wall=bool(wall)))
        results.append((messages, _metrics(monitor), heart.queries))
    (m0, metrics0, q0), (m1, metrics1, q1) = results
    assert m0 == m1
    assert metrics0 == metrics1
    assert q1 < q0  # and it looked less
