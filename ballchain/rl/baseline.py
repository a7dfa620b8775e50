"""A learned baseline that needs only numpy: a small linear policy on engineered features, trained
by the cross-entropy method (CEM) on ``TargetReach`` (docs/guide/rl.md, "The learned baseline").

Features (``features``), from the observation and the station's fixed geometry (what a clinical
system knows: the sheath exit ``p_WE``, the magnet's centre ``p_WM``), in the world frame:

* ``c_aim``: the rotation that turns the measured dipole ``m_hat`` towards the dipole whose field
  at the measured tip points from the sheath exit to the touch point (a point dipole's field
  inverted: m ~ (3/2 r r^T - I) b, r the unit vector from the magnet to the tip):
  ``m_hat x m_aim`` (3);
* ``c_err``: the same towards the dipole whose field at the tip points from the tip to the touch
  point: ``m_hat x m_err`` (3);
* ``e``: the tip's error to the touch point [cm] (3);
* ``s_err``: the inserted length the straight chain to the touch point needs minus the feeder's
  length [cm] (1); ``d``: the tip's distance to the touch point [cm] (1); 1 (a bias).

The policy (``LinearPolicy``): the magnet rate ``omega_max tanh(k_aim c_aim + k_err c_err +
k_e e)`` and the feeder speed ``v_max tanh(k_s (s_err + slack) + k_d d + b)``: seven numbers
(``PARAMETER_NAMES``), a linear map of the features with its weights shared across the axes
(the features are vectors in the world frame: the map must not depend on the frame's axes).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ballchain.infrastructure.errors import UserInputError, short_repr

PARAMETER_NAMES = ("k_aim", "k_err", "k_e", "k_s", "slack", "k_d", "b")
# The CEM's starting mean and spread (a hand-made guess: aim gain 1, feed towards the length).
PRIOR_MEAN = np.array([2.0, 1.0, 0.0, 1.0, 0.3, 0.0, 0.0])
PRIOR_STD = np.array([2.0, 2.0, 1.0, 2.0, 0.5, 1.0, 0.5])


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v)
    return v / n if n > 1e-12 else np.zeros_like(v)


def dipole_for_field(b_dir: np.ndarray, r_dir: np.ndarray) -> np.ndarray:
    """The unit dipole whose point-dipole field at unit offset ``r_dir`` points along ``b_dir``:
    B ~ (3 r r^T - I) m, inverted: m ~ (3/2 r r^T - I) b."""
    return _unit(1.5 * r_dir * (r_dir @ b_dir) - b_dir)


@dataclass
class LinearPolicy:
    """``policy(obs) -> action`` (module docstring) for one unit; picklable (Dask).

    Attributes:
        theta: the seven parameters (``PARAMETER_NAMES``).
        layout: the environment's ``obs_layout``; geometry: its ``geometry`` (p_WE, p_WM, ...);
        high: the action space's high bound.
    """

    theta: np.ndarray
    layout: dict
    geometry: dict
    high: np.ndarray
    unit: str = field(default="")

    @classmethod
    def for_env(cls, env, theta) -> "LinearPolicy":
        u = env.unwrapped
        if len(u.units) != 1:
            raise UserInputError(f"LinearPolicy steers one unit, the environment has {len(u.units)}")
        theta = np.asarray(theta, float).reshape(-1)
        if theta.shape != (len(PARAMETER_NAMES),) or not np.all(np.isfinite(theta)):
            raise UserInputError(f"LinearPolicy theta must be {len(PARAMETER_NAMES)} finite numbers "
                                 f"({', '.join(PARAMETER_NAMES)}), got {short_repr(theta)}")
        return cls(theta, dict(u.obs_layout), dict(u.geometry), np.asarray(u.action_space.high, float), u.units[0])

    def features(self, obs: np.ndarray) -> dict:
        o, g = np.asarray(obs, float), self.geometry
        tip, m_hat = o[self.layout["tip_measured"]], _unit(o[self.layout[f"{self.unit}.m_hat_W"]])
        p_touch = o[self.layout["target_p_W"]] + 0.5 * g["ball_diameter"] * o[self.layout["target_n_W"]]
        r_dir = _unit(tip - g["p_WM"][0])
        m_aim = dipole_for_field(_unit(p_touch - g["p_WE"]), r_dir)
        m_err = dipole_for_field(_unit(p_touch - tip), r_dir)
        e = p_touch - tip
        need = np.linalg.norm(p_touch - g["p_WE"]) + 0.5 * g["ball_diameter"]
        return {"c_aim": np.cross(m_hat, m_aim), "c_err": np.cross(m_hat, m_err), "e": 100.0 * e,
                "s_err": 100.0 * (need - o[self.layout["inserted_length"]][0]), "d": 100.0 * np.linalg.norm(e)}

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        k_aim, k_err, k_e, k_s, slack, k_d, b = self.theta
        f = self.features(obs)
        omega = np.tanh(k_aim * f["c_aim"] + k_err * f["c_err"] + k_e * f["e"])
        feed = np.tanh(k_s * (f["s_err"] + slack) + k_d * f["d"] + b)
        return (self.high * np.append(omega, feed)).astype(np.float32)


def split_targets(names: list[str]) -> tuple[list[str], list[str]]:
    """(training, held-out) targets of a ring: every other one held out (odd positions)."""
    return list(names[0::2]), list(names[1::2])


def score(env, theta, targets: list[str], seed: int) -> tuple[float, float]:
    """(mean return, success fraction) of ``LinearPolicy(theta)`` over one episode per target."""
    from ballchain.rl.evaluate import run_episode

    policy = LinearPolicy.for_env(env, theta)
    records = [run_episode(env.unwrapped, policy, seed + k, t) for k, t in enumerate(targets)]
    return float(np.mean([r["return"] for r in records])), float(np.mean([r["success"] for r in records]))


@dataclass
class TrainResult:
    """What ``train_cem`` returns: the best parameters, the history and the cost."""

    theta: np.ndarray
    history: list
    cpu_s: float
    episodes: int
    settings: dict


def train_cem(env, targets: list[str], *, iterations: int = 6, population: int = 8, elite: int = 3,
              seed: int = 0, mean=None, std=None, progress: bool = True) -> TrainResult:
    """The cross-entropy method over ``LinearPolicy``'s parameters: each iteration draws
    ``population`` parameter vectors from a diagonal Gaussian, scores each by its mean return over
    one episode per training target (``score``), and refits the Gaussian to the ``elite`` best
    (plus a small floor on the spread). Returns the best vector seen (by mean return)."""
    from tqdm import tqdm

    for name, v, lo in (("iterations", iterations, 1), ("population", population, 2), ("elite", elite, 1)):
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise UserInputError(f"train_cem {name} must be an integer >= {lo}, got {short_repr(v)}")
    if elite > population:
        raise UserInputError(f"train_cem elite {elite} must not exceed population {population}")
    rng = np.random.default_rng(seed)
    mu = np.array(PRIOR_MEAN if mean is None else mean, float)
    sigma = np.array(PRIOR_STD if std is None else std, float)
    best, best_score, history, cpu, episodes = mu.copy(), -np.inf, [], time.process_time(), 0
    for it in tqdm(range(iterations), desc="CEM", unit="iteration", disable=not progress):
        thetas = mu + sigma * rng.standard_normal((population, len(mu)))
        thetas[0] = mu  # the mean itself is scored too
        scores = [score(env, th, targets, seed + 1000 * it) for th in thetas]
        episodes += population * len(targets)
        returns = np.array([s[0] for s in scores])
        order = np.argsort(returns)[::-1]
        if returns[order[0]] > best_score:
            best, best_score = thetas[order[0]].copy(), float(returns[order[0]])
        elites = thetas[order[:elite]]
        mu, sigma = elites.mean(axis=0), np.maximum(elites.std(axis=0), 0.05 * PRIOR_STD)
        history.append({"iteration": it, "best_return": round(float(returns[order[0]]), 3),
                        "mean_return": round(float(returns.mean()), 3),
                        "best_success": round(scores[order[0]][1], 3), "mean": mu.round(4).tolist()})
    return TrainResult(best, history, time.process_time() - cpu, episodes,
                       {"iterations": iterations, "population": population, "elite": elite, "seed": seed,
                        "targets": list(targets)})
