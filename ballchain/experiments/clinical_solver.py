"""The clinical system's stand and the best force on one target (``ballchain.experiments.clinical``).

The two chains, the two spheres placed by the paper's sizing equation (``clinical_stand``), both
magnets' directions optimised for the force along a target's axis inside the friction cone
(``TargetSolver``), the force's make-up (``force_breakdown``) and the diameter at which a target
reaches 10 gf (``threshold_diameter``); the module docstring of ``clinical`` says how and why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ballchain.drake_models import paper
from ballchain.drake_models.dipole_inversion import moment_from_field
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.field_sources import FieldSources, MagnetSource, rotation_with_z_along
from ballchain.drake_models.heart import LeftAtrium
from ballchain.drake_models.params import (
    BallChain,
    Sleeve,
    SphereMagnet,
    gram_force,
    newtons_from_gram_force,
)
from ballchain.experiments._result import Result
from ballchain.experiments.forces import Stand, build_stand
from ballchain.experiments.planner import teleop_stand
from ballchain.optimization.inverse_statics import HeldTip, max_force_orientation, max_force_penalised, pin_tip
from ballchain.optimization.statics import ChainStatics, StaticsResult

PAPER = {
    "diameter_mm": paper.SIZING["diameter_mm"],
    "mass_kg": paper.SIZING["mass_kg"],
    "heart_to_surface_cm": paper.CLINICAL_DISTANCE * 100,
    "ball_diameter_8fr_mm": 2.17,
    "catheter_od_mm": 2.67,
    "alpha": paper.SIZING["alpha"],
    "tip_force_gf": paper.SIZING["desired_force_gf"],
}
"""The paper's clinical design (Section V-A)."""

VEINS = ("LSPV", "LIPV", "RSPV", "RIPV")
MIN_FORCE_GF = PAPER["tip_force_gf"]
TODAY_BALLS = 16


def todays_chain(sleeve: bool = True) -> BallChain:
    """Today's chain: 16 N52 balls of 3.175 mm, in today's sleeve (ID 3.0, OD 3.5 mm)."""
    return BallChain(n_balls=TODAY_BALLS, sleeve=Sleeve() if sleeve else None)


def eight_french_chain(sleeve: bool = True) -> BallChain:
    """The paper's 8 Fr chain: balls of 2.17 mm, at least today's inserted length, sleeve OD 2.67 mm.

    The sleeve's OD - ID is today's 0.5 mm (the paper's "0.5 mm thickness"), so its ID is the
    ball diameter; same silicone (``Sleeve().youngs_modulus``).
    """
    d = PAPER["ball_diameter_8fr_mm"] * 1e-3
    od = PAPER["catheter_od_mm"] * 1e-3
    today = todays_chain()
    n = int(math.ceil(today.length / d - 1e-9))
    thickness = Sleeve().outer_diameter - Sleeve().inner_diameter
    return BallChain(n_balls=n, ball_diameter=d,
                     sleeve=Sleeve(inner_diameter=od - thickness, outer_diameter=od) if sleeve else None)


CHAINS = {"8Fr": eight_french_chain, "today": todays_chain}


def magnet_distance(diameter: float, heart_to_surface: float, reference: str = "surface") -> float:
    """Atrium centre to magnet centre [m]: d_c + D/2 ("surface", the paper's sizing) or d_c ("centre")."""
    if reference == "surface":
        return heart_to_surface + 0.5 * diameter
    if reference == "centre":
        return heart_to_surface
    raise UserInputError(f"--reference must be 'surface' or 'centre', got {reference!r}")


def clinical_stand(chain: BallChain, diameter: float = PAPER["diameter_mm"] * 1e-3,
                   heart_to_surface: float = PAPER["heart_to_surface_cm"] * 1e-2, reference: str = "surface",
                   atrium: LeftAtrium | None = None) -> Stand:
    """Veins (Table I's pins) and both rings' targets, and the two spheres "R" and "L", in the statics frame."""
    atrium = atrium or LeftAtrium()
    d = chain.ball_diameter
    veins = build_stand(atrium, d)
    targets = dict(veins.targets)
    for task in ("left", "right"):
        targets.update(teleop_stand(atrium, task, d).targets)
    R_HS, p_HE = veins.R_HS, veins.p_HE
    r = magnet_distance(diameter, heart_to_surface, reference)
    to_S = lambda p_H: R_HS.T @ (np.asarray(p_H) - p_HE)  # noqa: E731
    magnets = {"R": to_S(np.array([-r, 0.0, 0.0])), "L": to_S(np.array([r, 0.0, 0.0]))}
    return Stand(targets, magnets, R_HS, p_HE)


def ring_names(stand: Stand) -> list[str]:
    return [k for k in stand.targets if k not in VEINS]


class ClinicalField:
    """(2, 3) dipole directions -> the field of the two spheres (R then L)."""

    def __init__(self, stand: Stand, magnet: SphereMagnet):
        self.magnet = magnet
        self.centres = [stand.magnets["R"], stand.magnets["L"]]

    def __call__(self, m: np.ndarray) -> FieldSources:
        m = np.asarray(m, float).reshape(-1, 3)
        return FieldSources([MagnetSource(self.magnet, c, rotation_with_z_along(u)) for c, u in zip(self.centres, m)])

    def aiming(self, b_hat, at=np.zeros(3)) -> np.ndarray:
        """(2, 3) dipole directions whose fields at ``at`` both point along ``b_hat``."""
        return np.array([_unit(moment_from_field(np.asarray(b_hat, float), np.asarray(at) - c)) for c in self.centres])


def _slerp(a: np.ndarray, b: np.ndarray, s: float) -> np.ndarray:
    """Rows of unit vectors turned from ``a`` towards ``b`` by the fraction ``s`` of the angle
    (about any perpendicular axis when a row of ``b`` is opposite to ``a``'s)."""
    out = []
    for u, v in zip(np.asarray(a, float), np.asarray(b, float)):
        sin, cos = float(np.linalg.norm(np.cross(u, v))), float(u @ v)
        if sin < 1e-9 and cos > 0:
            out.append(u)
            continue
        if sin >= 1e-9:
            axis = np.cross(u, v) / sin
        else:  # opposite: any axis perpendicular to u
            axis = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
            axis /= np.linalg.norm(axis)
        angle = s * math.atan2(sin, cos)
        out.append(math.cos(angle) * u + math.sin(angle) * np.cross(axis, u)
                   + (1 - math.cos(angle)) * (axis @ u) * axis)
    return np.array(out)


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def seed_directions() -> np.ndarray:
    """The field directions tried first: the 6 axes and the 8 cube diagonals (statics frame)."""
    axes = np.vstack([np.eye(3), -np.eye(3)])
    diagonals = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float) / math.sqrt(3.0)
    return np.vstack([axes, diagonals])


@dataclass
class TargetForce(Result):
    """The best force on one target.

    Attributes:
        target: name.
        force_gf: normal force at the re-checked optimum [gf] (None: no held equilibrium found).
        feasible: that equilibrium lies inside the friction cone.
        friction_needed: |F_t| / F_n there.
        gradient_pull_gf: the field's gradient force on balls 2..n along the target's axis [gf].
        sheath_push_gf: the rest (through ball 1: the torque on the bent chain) [gf].
        dipoles: (2, 3) the magnets' directions (R, L).
        evaluations: equilibria solved.
        status: SNOPT's answer or why there is none.
    """

    target: str
    force_gf: float | None
    feasible: bool
    friction_needed: float | None
    gradient_pull_gf: float | None
    sheath_push_gf: float | None
    dipoles: list | None
    evaluations: int
    status: str

    @property
    def effective_gf(self) -> float:
        """The force that counts: the optimum's if inside the cone, else 0."""
        return self.force_gf if (self.feasible and self.force_gf is not None) else 0.0


def force_breakdown(chain: BallChain, external, result: StaticsResult, axis) -> tuple[float, float]:
    """(gradient pull on balls 2..n, sheath push) along ``axis`` [N]; their sum is the pin's push."""
    B, G = external.field_and_gradient(result.positions)
    F_grad = chain.dipole_moment * np.einsum("kab,ka->kb", G, result.dipoles)
    pull = float(F_grad[1:].sum(axis=0) @ axis)
    press = float(-result.tip_reaction @ axis)
    return pull, press - pull


class TargetSolver:
    """Best force on one target as the magnets' size changes (warm-started across sizes)."""

    def __init__(self, chain: BallChain, target: str, friction: float, target_radius: float,
                 heart_to_surface: float, reference: str, atrium: LeftAtrium, major_iterations: int = 25):
        self.chain = chain
        self.target = target
        self.friction = friction
        self.radius = target_radius
        self.heart_to_surface = heart_to_surface
        self.reference = reference
        self.atrium = atrium
        self.major_iterations = major_iterations
        self.solver = ChainStatics(chain, max_iterations=25)
        self.last_dipoles: np.ndarray | None = None
        self.last_result: StaticsResult | None = None
        self.solves = 0

    def solve(self, diameter: float) -> TargetForce:
        """The best force on the target with spheres of ``diameter`` [m].

        From the last size's optimum when there is one (SNOPT polishes it); otherwise, or when
        that leaves the cone, SNOPT from the best of the seed field directions; when that too
        leaves the cone, Nelder-Mead on a penalised force (the cone as an exact penalty) and
        SNOPT from its answer. The best answer inside the cone is kept.
        """
        stand = clinical_stand(self.chain, diameter, self.heart_to_surface, self.reference, self.atrium)
        centre, axis = stand.targets[self.target]
        if np.linalg.norm(centre) > (self.chain.n_balls - 1) * self.chain.ball_diameter:
            return TargetForce(self.target, None, False, None, None, None, None, 0, "out of reach")
        field_for = ClinicalField(stand, SphereMagnet(diameter=diameter))
        best = None
        if self.last_dipoles is not None:
            home = self.solver.solve(field_for(self.last_dipoles), self.last_result, tip_target=centre)
            self.solves += 1
            if home.converged:
                best = self._polish(field_for, centre, axis, self.last_dipoles, home)
        if best is None or not best[0]:
            seeds = self._seeds(field_for, centre, axis)
            if seeds:
                m0, home = seeds[0]
                candidates = [best, self._polish(field_for, centre, axis, m0, home)]
                if not (candidates[-1] and candidates[-1][0]):  # SNOPT left the cone: a penalised search first
                    m_nm, res_nm, F_nm = self._penalty_search(field_for, centre, axis, m0, home)
                    candidates.append((self._inside(F_nm), float(F_nm[0]), m_nm, res_nm, F_nm, "Nelder-Mead"))
                    candidates.append(self._polish(field_for, centre, axis, m_nm, res_nm))
                for option in candidates:
                    if option is not None and (best is None or option[:2] > best[:2]):
                        best = option
        if best is None:
            return TargetForce(self.target, None, False, None, None, None, None, self.solves,
                               "no held equilibrium")
        feasible, force, m, result, F, status = best
        self.last_dipoles, self.last_result = m, result
        pull, push = force_breakdown(self.chain, field_for(m), result, axis)
        needed = float(np.hypot(F[1], F[2]) / F[0]) if F[0] > 0 else None
        return TargetForce(self.target, gram_force(force), bool(feasible), needed,
                           gram_force(pull), gram_force(push), m.tolist(), self.solves, status)

    def restart(self) -> None:
        """Forget the last size's optimum: the next solve starts from the seed directions."""
        self.last_dipoles, self.last_result = None, None

    def _inside(self, F) -> bool:
        return bool(F[0] > 0 and np.hypot(F[1], F[2]) <= self.friction * F[0] * (1 + 1e-3))

    def _polish(self, field_for, centre, axis, m0, home):
        """SNOPT from (m0, home): (inside the cone, force [N], dipoles, equilibrium, F, status) or None."""
        held = HeldTip(self.solver, field_for, centre, axis, home, n_magnets=2)
        plan = max_force_orientation(held, m0, self.radius, self.friction, newtons_from_gram_force(MIN_FORCE_GF),
                                     major_iterations=self.major_iterations, max_evaluations=250)
        self.solves += plan.evaluations
        if plan.result is None:
            return None
        F = held.basis.T @ (-plan.result.tip_reaction)
        # The re-checked equilibrium holds the tip on the touch point SNOPT chose.
        return (bool(plan.feasible), float(F[0]), plan.dipoles, plan.result, F, plan.solver_status)

    def _penalty_search(self, field_for, centre, axis, m0, home):
        held = HeldTip(self.solver, field_for, centre, axis, home, n_magnets=2)
        out = max_force_penalised(held, m0, self.radius, self.friction, newtons_from_gram_force(MIN_FORCE_GF))
        self.solves += held.evaluations
        return out

    def _seeds(self, field_for: ClinicalField, centre, axis) -> list:
        """Held equilibria for the seed field directions, best first (penalised by the cone).

        The first is brought onto the target from the free chain; each next one is reached by
        turning the magnets from the last held one in a few steps with the tip held (the way the
        real magnets would turn), since a held equilibrium far from the warm start rarely converges.
        """
        scored = []
        last = None  # (dipoles, held equilibrium)
        for b in seed_directions():
            m = field_for.aiming(b)
            if last is None:
                result = pin_tip(self.solver, field_for(m), centre, None, steps=6)
                self.solves += 7
            else:
                result = last[1]
                for s in np.linspace(0.0, 1.0, 5)[1:]:
                    m_s = _slerp(last[0], m, s)
                    result = self.solver.solve(field_for(m_s), result, tip_target=centre)
                    self.solves += 1
                    if not result.converged:
                        result = None
                        break
            if result is None and last is not None:  # not reachable by turning: from the free chain
                result = pin_tip(self.solver, field_for(m), centre, None, steps=6)
                self.solves += 7
            if result is None:
                continue
            last = (m, result)
            F = -np.asarray(result.tip_reaction)
            n = float(F @ axis)
            t = float(np.linalg.norm(F - n * axis))
            scored.append((n - max(0.0, t - self.friction * n), m, result))
        scored.sort(key=lambda s: -s[0])
        return [(m, r) for _, m, r in scored]



def threshold_diameter(solver: TargetSolver, first: TargetForce, first_diameter: float,
                       min_force_gf: float = MIN_FORCE_GF, max_diameter: float = 1.0,
                       rel_tol: float = 0.02) -> dict:
    """The sphere diameter at which the target's best force reaches ``min_force_gf``.

    A bracketing search on g(log D) = log(F(D) / F_min), F the best force inside the cone
    (monotone in D: the field in the atrium grows as D^3 / (d_c + D/2)^3): the bracket is
    found by power-law steps from ``first_diameter``, then narrowed by false position with the
    Illinois rule (a bisection that uses the curve's smoothness) until it is ``rel_tol`` wide.
    Each step is one warm-started ``solver.solve``.

    Returns:
        ``{"diameter_m": D (None if above max_diameter), "bracket_m": (lo, hi), "steps": n,
        "history": [(D [m], F [gf]), ...]}``.
    """
    history = [(first_diameter, first.effective_gf)]
    if first.status == "out of reach":  # no magnet helps a target the chain cannot reach
        return {"diameter_m": None, "bracket_m": (None, None), "steps": 0, "history": history}

    def g(force_gf):
        return math.log(max(force_gf, 1e-3) / min_force_gf)

    def F(D):
        value = solver.solve(D).effective_gf
        if value == 0.0 and hasattr(solver, "restart"):
            # Nothing inside the cone from the last size's optimum: a search failure, not physics
            # (the force grows with D); once more from the seed directions.
            solver.restart()
            value = solver.solve(D).effective_gf
        history.append((D, value))
        return value

    def F_checked(D, limit=math.inf):
        """F(D), stepping 2 % up (at most twice, staying below ``limit``) where the search fails
        above a size that pressed: a failure there is the search's, and taking it as 'too small'
        would break the bracket."""
        value = F(D)
        for _ in range(2):
            if value > 0.0 or not any(f > 0.0 and d < D for d, f in history[:-1]) or 1.02 * D >= limit:
                break
            D *= 1.02
            value = F(D)
        return D, value

    lo, hi = None, None
    D, f = first_diameter, first.effective_gf
    # Grow (or shrink) by the power law F ~ D^2 until the bracket closes.
    while True:
        if f >= min_force_gf:
            hi = (D, f)
            if lo is not None:
                break
            D = D * max(0.5, (min_force_gf / max(f, 1e-3)) ** 0.5 * 0.95)
        else:
            lo = (D, f)
            if hi is not None:
                break
            if D >= max_diameter:
                return {"diameter_m": None, "bracket_m": (D, None), "steps": len(history) - 1, "history": history}
            D = min(max_diameter, D * min(2.0, (min_force_gf / max(f, 1e-3)) ** 0.5 * 1.05))
        D, f = F_checked(D)
    x_lo, x_hi, y_lo, y_hi = math.log(lo[0]), math.log(hi[0]), g(lo[1]), g(hi[1])
    retained = None
    while hi[0] - lo[0] > rel_tol * hi[0]:
        x = x_lo - y_lo * (x_hi - x_lo) / (y_hi - y_lo) if y_hi != y_lo else 0.5 * (x_lo + x_hi)
        width = x_hi - x_lo
        x = min(max(x, x_lo + 0.1 * width), x_hi - 0.1 * width)  # every step shrinks the bracket
        D, f = F_checked(math.exp(x), limit=hi[0])
        x = math.log(D)
        if f >= min_force_gf:
            hi, x_hi, y_hi = (math.exp(x), f), x, g(f)
            if retained == "lo":
                y_lo *= 0.5  # Illinois: an end kept twice in a row counts half
            retained = "lo"
        else:
            lo, x_lo, y_lo = (math.exp(x), f), x, g(f)
            if retained == "hi":
                y_hi *= 0.5
            retained = "hi"
    # The crossing by linear interpolation of log F in log D inside the final bracket.
    x_lo, x_hi, y_lo, y_hi = math.log(lo[0]), math.log(hi[0]), g(lo[1]), g(hi[1])
    x = x_lo - y_lo * (x_hi - x_lo) / (y_hi - y_lo) if y_hi != y_lo else x_hi
    return {"diameter_m": math.exp(min(max(x, x_lo), x_hi)), "bracket_m": (lo[0], hi[0]),
            "steps": len(history) - 1, "history": history}
