"""A hand check of the lesion FEM's electric solve (the ablation notebook's first result).

The tip ball half immersed in a uniform half space whose surface is insulated (no saline
conducting), the ground on a concentric hemisphere ``outer_radius`` away: the resistance is
exactly (1/a - 1/b) / (2 pi sigma) (``drake_models/tissue.py``,
``spreading_resistance_hemisphere``). The FEM (``drake_models/lesion_fem.py``,
``electrode_resistance``) on the same geometry gives it up to its mesh error (-0.13 % at the
default 0.1 mm spacing).
"""

from __future__ import annotations

from dataclasses import dataclass

from ballchain.drake_models import lesion_fem as fem
from ballchain.drake_models import tissue as laws
from ballchain.experiments._result import Result
from ballchain.experiments.ablation import check_settings
from ballchain.infrastructure.errors import UserInputError, short_repr


@dataclass
class FemCheckResult(Result):
    """What ``run`` returns: the FEM's resistance of the half-immersed tip ball against the exact one.

    Attributes:
        h_mm: the mesh spacing near the electrode [mm]; n_nodes: the mesh's nodes.
        conductivity_S_per_m: the uniform conductivity of the half space [S/m].
        ball_radius_mm: the tip ball's radius [mm]; ground_radius_mm: the ground hemisphere's [mm].
        fem_ohm, exact_ohm: the resistances [Ohm]; error_pct: FEM against exact [%].
    """

    h_mm: float
    n_nodes: int
    conductivity_S_per_m: float
    ball_radius_mm: float
    ground_radius_mm: float
    fem_ohm: float
    exact_ohm: float
    error_pct: float


def run(*, h_mm: float = 0.1, conductivity_S_per_m: float = laws.TISSUES["myocardium"].electrical_conductivity
        ) -> FemCheckResult:
    """The tip ball (radius a) sunk to its equator in a uniform half space: FEM against exact.

    Args:
        h_mm: the FEM's mesh spacing near the electrode [mm], in [0.03, 0.3].
        conductivity_S_per_m: the half space's conductivity [S/m], in (0, 100] (the relative
            error does not depend on it; default the myocardium's at 37 C).

    Returns:
        A ``FemCheckResult``.
    """
    check_settings(h_mm=h_mm)
    sigma = conductivity_S_per_m
    if isinstance(sigma, bool) or not isinstance(sigma, (int, float)) or not 0.0 < sigma <= 100.0:
        raise UserInputError(f"conductivity_S_per_m must be in (0, 100] S/m, got {short_repr(sigma)}")
    ball = fem.ball_chain_tip()
    ball = fem.ball_chain_tip(indentation=ball.radius)  # sunk to its equator: a hemisphere in the tissue
    mesh = fem.build_mesh(ball, h=h_mm * 1e-3)
    fem_ohm = fem.electrode_resistance(mesh, sigma, saline_sigma=0.0)
    exact_ohm = laws.spreading_resistance_hemisphere(sigma, ball.radius, mesh.outer_radius)
    return FemCheckResult(h_mm=float(h_mm), n_nodes=int(mesh.n_nodes), conductivity_S_per_m=float(sigma),
                          ball_radius_mm=ball.radius * 1e3, ground_radius_mm=mesh.outer_radius * 1e3,
                          fem_ohm=float(fem_ohm), exact_ohm=float(exact_ohm),
                          error_pct=float(100.0 * (fem_ohm / exact_ohm - 1.0)))
