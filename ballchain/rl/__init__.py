"""Learned navigation (issue 47; docs/guide/rl.md): Gymnasium environments on the station and the
quasi-static engine, their vectorised and Dask-distributed evaluation, and a numpy-only learned
baseline.

``import ballchain.rl`` registers ``ballchain/TargetReach-v0`` (one target per episode) and
``ballchain/RingTask-v0`` (the ring's targets in order)::

    import gymnasium as gym
    import ballchain.rl
    env = gym.make("ballchain/TargetReach-v0")
    obs, info = env.reset(seed=0)

Needs the ``rl`` extra (``pip install -e ".[rl]"``: gymnasium).
"""

from __future__ import annotations

try:
    import gymnasium as gym
except ImportError as err:  # the optional extra
    raise ImportError("ballchain.rl needs gymnasium: pip install -e \".[rl]\" (or the test extra)") from err

from ballchain.rl.env import NavigationEnv  # noqa: F401
from ballchain.rl.evaluate import EvaluationResult, evaluate, make_vector_env, rollout  # noqa: F401

ENVIRONMENTS = {"ballchain/TargetReach-v0": {"task": "reach"}, "ballchain/RingTask-v0": {"task": "ring"}}

for _name, _kwargs in ENVIRONMENTS.items():
    if _name not in gym.registry:
        gym.register(id=_name, entry_point="ballchain.rl.env:NavigationEnv", kwargs=dict(_kwargs))
