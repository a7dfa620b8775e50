"""Table I's gap taken apart effect by effect: could any of them turn 9.6 gf into 91.8 gf?

The model's best force on the LSPV pin with the prototype magnet on the left (Configuration 2,
bare chain) is about 9.6 gf; the paper measured 91.8 gf. Each effect below is a small model with
the force range it can produce:

(a) **Sensor resolution.** Every Table I value is a whole multiple of 0.05 N (5.10 gf): a
    reading rounds the force to that step, at most half a step either way.
(b) **A ferromagnetic pin or sensor body** attracting the magnetic tip ball
    (``drake_models.image_dipole``: the image of every ball of the equilibrium chain in a
    soft-iron half-space at the pin's face): the extra force along the sensor's axis, against
    the gap between the ball and the steel. It enters the reading only when the steel is on the
    sensor's fixed side (a plastic pin in front of a steel body); a steel sensing element feels
    the ball's contact push and the magnetic pull as equal and opposite parts of its load.
(c) **The chain supported sideways** by the stand's channel up to a few balls from the pin: the
    same pin and magnet, with the sheath's clamp moved to ball n - k of the optimum equilibrium
    (its position, its link direction), k free balls left; the magnet's orientation optimised
    again (``forces.max_normal_force``).
(d) **Friction at the pin.** At the optimum the pin also pushes sideways; the friction that
    holding the tip there needs is |F_t| / F_n. With a Coulomb cone of mu the best force is
    lower (``inverse_statics.max_force_orientation``).
(e) **The inserted length as a continuous feeder variable**: the chain advanced against a pin
    on the sheath's axis, in a field along the axis; the push rises to the chain's buckling load
    and plateaus (no fold).

Plus the make-up of the optimum's force: the field's gradient pull on balls 2..n against what
the sheath pushes in (the torque on the bent chain), and the optimum re-solved with the gradient
switched off (each ball keeps the field it had, with no gradient).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ballchain.infrastructure.arg_checks import require_bool
from ballchain.drake_models.field_sources import UniformField
from ballchain.drake_models.image_dipole import image_dipole, normal_attraction
from ballchain.drake_models.dipole import dipole_field_gradient, force_on_dipole
from ballchain.drake_models.params import BallChain, gram_force, newtons_from_gram_force
from ballchain.experiments._result import Result
from ballchain.experiments.forces import PAPER_GF, Stand, build_stand, max_normal_force, stand_field
from ballchain.optimization.inverse_statics import HeldTip, max_force_orientation, max_force_penalised, pin_tip
from ballchain.optimization.statics import ChainStatics

SENSOR_STEP_N = 0.05
"""Every Table I value is a whole multiple of this [N] (the force sensor's resolution)."""

CASE = ("LSPV", "2", False)
"""The row taken apart: LSPV, magnet on the left, bare chain (the paper's 91.8 gf)."""


@dataclass
class Resolution(Result):
    """(a): the sensor's step [gf], every Table I value in steps ({"vein config bare|sleeve":
    steps}), the largest distance of one from a whole step [steps] and the reading's largest
    rounding error [gf]."""

    step_gf: float
    multiples: dict
    largest_distance_from_a_whole_step: float
    max_rounding_error_gf: float


@dataclass
class FerroRow(Result):
    """(b) at one gap [mm]: the soft iron's pull on the whole chain along the sensor's axis, and
    on the tip ball alone with its dipole normal and parallel to the face [gf]."""

    gap_mm: float
    chain_pull_along_axis_gf: float
    tip_ball_alone_normal_gf: float
    tip_ball_alone_parallel_gf: float


@dataclass
class SupportRow(Result):
    """(c) with ``free_balls`` balls beyond the clamp: the best force [gf] (None: none held, and
    why)."""

    free_balls: int
    force_gf: float | None
    reason: str


@dataclass
class ConeRow(Result):
    """(d) inside one friction cone: the best force [gf], whether it is inside, the solver's word."""

    mu: float
    force_gf: float
    inside_cone: bool
    status: str


@dataclass
class FrictionNeeded(Result):
    """(d): the optimum's normal and lateral push [gf], the friction it needs (lateral / normal)
    and the best force inside each cone."""

    normal_gf: float
    lateral_gf: float
    mu_needed: float
    cones: list[ConeRow]


@dataclass
class PushCurve(Result):
    """(e) in one axial field [mT]: the push along the axis against the advance ([(mm, gf)],
    sorted), its peak and its value at the furthest advance (None: no point converged)."""

    field_mT: float
    curve_mm_gf: list
    peak_gf: float | None
    plateau_gf: float | None


@dataclass
class GradientSplit(Result):
    """The optimum's push [gf] split by force balance into the gradient pull on balls 2..n and
    the sheath's push, and the push re-solved with the gradient switched off (None: did not
    converge)."""

    force_gf: float
    gradient_pull_gf: float
    sheath_push_gf: float
    without_gradient_gf: float | None


@dataclass
class EffectRow(Result):
    """One row of the table (a)-(e): the effect, its model, the force range it can produce [gf]
    (None: nothing to range), the sensor's reading of the model's force [gf] (only (a)) and
    whether it could bring the model's force to the paper's."""

    effect: str
    model: str
    force_range_gf: list | None
    reading_of_model_gf: float | None
    could_reach_paper: str


@dataclass
class EffectsCase(Result):
    """The row taken apart (``CASE``): the model's and the paper's force [gf], the shortfall, the
    optimum's lateral push [gf], its dipole direction and the equilibria its search solved."""

    vein: str
    config: str
    sleeve: bool
    model_gf: float
    paper_gf: float
    shortfall_gf: float
    lateral_gf: float
    dipole: list
    evaluations: int


class FrozenField(UniformField):
    """Each ball in its own uniform field: the one it saw at an equilibrium; no gradient at all.

    The field with the gradient switched off: the torques stay, the gradient forces vanish.
    Ball i gets row i of ``B_balls`` (the chain's statics query the field at the n ball centres
    in order); a UniformField, so the statics' Hessian takes no field derivative of it.
    """

    def __init__(self, source, positions: np.ndarray):  # noqa: D107 (not the dataclass init)
        self.B_balls, _ = source.field_and_gradient(np.asarray(positions, float))
        self.B_W = self.B_balls[0]

    def field_and_gradient(self, p_W):
        p = np.atleast_2d(np.asarray(p_W, float))
        if p.shape[0] != self.B_balls.shape[0]:
            raise ValueError(f"FrozenField holds {self.B_balls.shape[0]} balls' fields, asked at {p.shape[0]} points")
        return self.B_balls.copy(), np.zeros((p.shape[0], 3, 3))


class FrameField:
    """A field source seen from a frame C with origin ``t`` and axes ``R`` (columns) in S."""

    def __init__(self, source, R: np.ndarray, t: np.ndarray):
        self.source, self.R, self.t = source, np.asarray(R, float), np.asarray(t, float)

    def field_and_gradient(self, p_C):
        p_S = np.atleast_2d(p_C) @ self.R.T + self.t
        B, G = self.source.field_and_gradient(p_S)
        return B @ self.R, np.einsum("ai,kab,bj->kij", self.R, G, self.R)


def frame_along(x_axis: np.ndarray) -> np.ndarray:
    """A rotation whose first column is ``x_axis``."""
    x = np.asarray(x_axis, float) / np.linalg.norm(x_axis)
    helper = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    y = np.cross(helper, x)
    y /= np.linalg.norm(y)
    return np.column_stack([x, y, np.cross(x, y)])


def sensor_resolution() -> Resolution:
    """(a): every Table I value in units of 0.05 N, and what the step does to the model's force."""
    step_gf = gram_force(SENSOR_STEP_N)
    multiples = {f"{v} {c} {'sleeve' if s else 'bare'}": gf / step_gf for (v, c, s), gf in PAPER_GF.items()}
    worst = max(abs(m - round(m)) for m in multiples.values())
    return Resolution(step_gf=step_gf, multiples=multiples, largest_distance_from_a_whole_step=worst,
                      max_rounding_error_gf=0.5 * step_gf)


def ferromagnetic_pin(chain: BallChain, result, target, axis, gaps_mm=(0.0, 0.25, 0.5, 1.0, 2.0)) -> list[FerroRow]:
    """(b): the pull of a soft-iron half-space at the pin's face on the whole equilibrium chain.

    The face is perpendicular to the sensor's axis, ``gap`` beyond the tip ball's contact point;
    each ball feels the gradient force of all balls' images (the chain's moments as they are at
    the equilibrium; the iron also pulls the chain's shape a little, not followed here).
    """
    M, d = chain.dipole_moment, chain.ball_diameter
    p, m = result.positions, M * result.dipoles
    rows = []
    for gap in gaps_mm:
        point = np.asarray(target) + (0.5 * d + 1e-3 * gap) * np.asarray(axis)
        p_img, m_img = image_dipole(p, m, point, -np.asarray(axis))
        r = p[:, None, :] - p_img[None, :, :]
        G = dipole_field_gradient(r, np.broadcast_to(m_img[None, :, :], r.shape)).sum(axis=1)
        F = force_on_dipole(m, G)
        along = float(F.sum(axis=0) @ axis)
        tip_alone = normal_attraction(M, 0.5 * d + 1e-3 * gap)
        rows.append(FerroRow(gap_mm=gap, chain_pull_along_axis_gf=gram_force(along),
                             tip_ball_alone_normal_gf=gram_force(tip_alone),
                             tip_ball_alone_parallel_gf=gram_force(normal_attraction(M, 0.5 * d + 1e-3 * gap,
                                                                                     math.pi / 2))))
    return rows


def side_support(chain: BallChain, stand: Stand, best: dict, vein: str, free_balls=(3, 4, 5, 6, 8, 10),
                 grid: int = 6, refine: int = 30) -> list[SupportRow]:
    """(c): the clamp moved to ball n - k of the optimum equilibrium, k balls free, magnet re-optimised."""
    target, axis = stand.targets[vein]
    p = best["result"].positions
    rows = []
    for k in free_balls:
        j = chain.n_balls - 1 - k  # 0-based index of the new clamped ball
        if j < 1:
            continue
        R = frame_along(p[j] - p[j - 1])
        t = p[j]
        sub = Stand({vein: (R.T @ (target - t), R.T @ axis)}, {c: R.T @ (v - t) for c, v in stand.magnets.items()},
                    stand.R_HS, stand.p_HE)
        out = max_normal_force(chain.with_balls(k + 1), sub, vein, ("2",), grid, refine)
        rows.append(SupportRow(free_balls=k, force_gf=out.get("force_gf"), reason=out.get("reason", "")))
    return rows


def friction_needed(chain: BallChain, stand: Stand, best: dict, vein: str, mus=(0.1, 0.3, 0.5)) -> FrictionNeeded:
    """(d): |F_t| / F_n at the optimum, and the best force inside cones of mu."""
    target, axis = stand.targets[vein]
    F = -best["result"].tip_reaction
    normal = float(F @ axis)
    lateral = float(np.linalg.norm(F - normal * axis))
    solver = ChainStatics(chain, max_iterations=25)
    field_for = lambda m: stand_field(stand, ("2",), _angles(m.reshape(-1, 3)[0]))  # noqa: E731
    m0 = np.asarray(best["dipoles"]).reshape(1, 3)
    rows = []
    scale = newtons_from_gram_force(10.0)
    for mu in mus:
        # From the frictionless optimum (outside a small cone): the penalised search first, then SNOPT.
        held = HeldTip(solver, field_for, target, axis, best["result"], n_magnets=1)
        m1, res1, F1 = max_force_penalised(held, m0, 0.0, mu, scale)
        held = HeldTip(solver, field_for, target, axis, res1, n_magnets=1)
        plan = max_force_orientation(held, m1, 0.0, mu, scale, major_iterations=25, max_evaluations=200)
        inside1 = bool(F1[0] > 0 and np.hypot(F1[1], F1[2]) <= mu * F1[0] * (1 + 1e-3))
        options = [(inside1, float(F1[0]), "Nelder-Mead")]
        if plan.force_N is not None:
            options.append((bool(plan.feasible), plan.force_N, plan.solver_status))
        inside, force, status = max(options)
        rows.append(ConeRow(mu=mu, force_gf=gram_force(force), inside_cone=inside, status=status))
    return FrictionNeeded(normal_gf=gram_force(normal), lateral_gf=gram_force(lateral), mu_needed=lateral / normal,
                          cones=rows)


def _angles(u) -> np.ndarray:
    u = np.asarray(u, float) / np.linalg.norm(u)
    return np.array([math.atan2(u[1], u[0]), math.asin(float(np.clip(u[2], -1.0, 1.0)))])


def push_curve(n_balls: int = 16, fields_mT=(0.0, 9.0, 23.0), advance_balls: float = 2.0,
               steps: int = 24) -> list[PushCurve]:
    """(e): the pin on the sheath's axis, the chain advanced continuously against it.

    The tip held at ((n-1) d - s) along the axis for advances s up to ``advance_balls`` d; a
    field along the axis (0: none). The furthest advance is reached from a chain bent by a
    lateral field (which picks the buckling side; a nearly straight chain held at almost full
    extension is too ill-conditioned to start from), then the field is turned onto the axis and
    the advance walked back to 0.05 d with continuation. Returns, per field, the push along the
    axis at each advance [mm, gf], its peak and its value at the furthest advance (the plateau).
    """
    chain = BallChain(n_balls=n_balls)
    d = chain.ball_diameter
    solver = ChainStatics(chain, max_iterations=200)
    rows = []
    for B in fields_mT:
        magnitude = 1e-3 * max(B, 1.0)
        bend = UniformField(magnitude * np.array([math.cos(0.3), math.sin(0.3), 0.0]))
        external = UniformField(np.array([1e-3 * B, 0.0, 0.0])) if B > 0 else None
        advances = np.linspace(advance_balls * d, 0.05 * d, steps)
        tip = lambda s: np.array([(n_balls - 1) * d - s, 0.0, 0.0])  # noqa: E731
        current = pin_tip(solver, bend, tip(advances[0]), solver.solve(bend), steps=10)
        curve = []
        for s in advances:
            if current is None:
                break
            current = solver.solve(external, current, tip_target=tip(s))
            if not current.converged:
                break
            curve.append((1e3 * s, gram_force(float(-current.tip_reaction[0]))))
        curve.sort()
        pushes = [f for _, f in curve]
        rows.append(PushCurve(field_mT=B, curve_mm_gf=curve, peak_gf=max(pushes) if pushes else None,
                              plateau_gf=pushes[-1] if pushes else None))
    return rows


def gradient_switched_off(chain: BallChain, stand: Stand, best: dict, vein: str) -> GradientSplit:
    """The optimum's force split by force balance, and re-solved with the gradient switched off."""
    target, axis = stand.targets[vein]
    external = stand_field(stand, ("2",), best["angles_rad"])
    res = best["result"]
    _, G = external.field_and_gradient(res.positions)
    pull = float((chain.dipole_moment * np.einsum("kab,ka->kb", G, res.dipoles))[1:].sum(axis=0) @ axis)
    press = float(-res.tip_reaction @ axis)
    frozen = ChainStatics(chain, max_iterations=200).solve(FrozenField(external, res.positions), res, tip_target=target)
    return GradientSplit(force_gf=gram_force(press), gradient_pull_gf=gram_force(pull),
                         sheath_push_gf=gram_force(press - pull),
                         without_gradient_gf=gram_force(float(-frozen.tip_reaction @ axis)) if frozen.converged else None)


@dataclass
class EffectsResult(Result):
    """What ``run`` returns: the table (a)-(e) and each effect's details (edge units)."""

    table: list[EffectRow]
    case: EffectsCase
    resolution: Resolution
    ferromagnetic: list[FerroRow]
    side_support: list[SupportRow]
    friction: FrictionNeeded
    push: list[PushCurve]
    gradient: GradientSplit
    compute_time_s: float
    notes: dict = field(default_factory=dict)


def run(*, quick: bool = False) -> EffectsResult:
    """Every effect on Table I's LSPV / Configuration 2 / bare row; ``quick``: coarser searches."""
    require_bool(quick, "quick")
    t0 = time.perf_counter()
    vein, config, sleeve = CASE
    chain = BallChain(n_balls=16)
    stand = build_stand()
    # A coarser search than Table I's (grid 8, 40 evaluations: 9.57 gf); it lands within a few % of it.
    best = max_normal_force(chain, stand, vein, (config,), grid=4, refine_evaluations=10 if quick else 25)
    if best.get("force_N") is None:
        raise RuntimeError(f"no held equilibrium on the {vein} pin: {best.get('reason')}")
    target, axis = stand.targets[vein]
    model_gf, paper_gf = best["force_gf"], PAPER_GF[CASE]
    shortfall = paper_gf - model_gf
    resolution = sensor_resolution()
    ferro = ferromagnetic_pin(chain, best["result"], target, axis)
    support = side_support(chain, stand, best, vein, free_balls=(3, 6) if quick else (3, 4, 5, 6, 8),
                           grid=4 if quick else 6, refine=10 if quick else 30)
    friction = friction_needed(chain, stand, best, vein, mus=(0.1,) if quick else (0.1, 0.5))
    push = push_curve(fields_mT=(0.0, 23.0) if quick else (0.0, 9.0, 23.0), steps=12 if quick else 24)
    gradient = gradient_switched_off(chain, stand, best, vein)

    def could(extra_max_gf):
        return "yes" if extra_max_gf is not None and extra_max_gf >= shortfall else "no"

    ferro_max = max(r.chain_pull_along_axis_gf for r in ferro)
    ferro_min = min(r.chain_pull_along_axis_gf for r in ferro)
    support_forces = [r.force_gf for r in support if r.force_gf is not None]
    cone_forces = [r.force_gf for r in friction.cones if r.force_gf is not None]
    peaks = [r.peak_gf for r in push if r.peak_gf is not None]
    table = [
        EffectRow(effect="(a) sensor resolution (whole multiples of 0.05 N)",
                  model=f"reading = force rounded to {resolution.step_gf:.2f} gf",
                  force_range_gf=[-resolution.max_rounding_error_gf, resolution.max_rounding_error_gf],
                  reading_of_model_gf=resolution.step_gf * round(model_gf / resolution.step_gf),
                  could_reach_paper=could(resolution.max_rounding_error_gf)),
        EffectRow(effect="(b) ferromagnetic pin or sensor body (soft-iron image of the chain)",
                  model="pull along the sensor axis, steel face 0-2 mm beyond the tip ball",
                  force_range_gf=[ferro_min, ferro_max], reading_of_model_gf=None,
                  could_reach_paper=could(ferro_max) + " (only with steel within about 0.5 mm, on the sensor's "
                                                       "fixed side)"),
        EffectRow(effect="(c) chain supported sideways up to k balls from the pin",
                  model=f"clamp at ball n-k of the optimum, k = {', '.join(str(r.free_balls) for r in support)}",
                  force_range_gf=[min(support_forces), max(support_forces)] if support_forces else None,
                  reading_of_model_gf=None,
                  could_reach_paper=could(max(support_forces) - model_gf if support_forces else None)),
        EffectRow(effect="(d) friction at the pin",
                  model=f"mu needed {friction.mu_needed:.2f}; best force inside cones mu = "
                        + ", ".join(f"{r.mu:g}" for r in friction.cones),
                  force_range_gf=[min(cone_forces), model_gf] if cone_forces else None, reading_of_model_gf=None,
                  could_reach_paper="no (friction can only let the tip keep the frictionless optimum)"),
        EffectRow(effect="(e) continuous insertion against the pin (push curve)",
                  model="pin on the sheath axis, field along it: " + ", ".join(f"{r.field_mT:g}" for r in push) + " mT",
                  force_range_gf=[min(peaks), max(peaks)] if peaks else None, reading_of_model_gf=None,
                  could_reach_paper=could(max(peaks) - model_gf if peaks else None)),
    ]
    case = EffectsCase(vein=vein, config=config, sleeve=sleeve, model_gf=model_gf, paper_gf=paper_gf,
                       shortfall_gf=shortfall, lateral_gf=friction.lateral_gf, dipole=best["dipoles"][0].tolist(),
                       evaluations=best["evaluations"])
    return EffectsResult(table, case, resolution, ferro, support, friction, push, gradient, time.perf_counter() - t0)
