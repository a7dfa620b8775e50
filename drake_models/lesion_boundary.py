"""What surrounds the electrode in a beating heart: flowing blood and open irrigation.

The paper's bench (``lesion_fem.simulate``) is a still 0.9 % saline bath: pure conduction. In an
atrium the blood flows past the electrode and the wall and carries heat away. RF models of the
Berjano group (Gonzalez-Suarez and Berjano, "Comparative analysis of different methods of
modeling the thermal effect of circulating blood flow during RF cardiac ablation", IEEE Trans.
Biomed. Eng. 63(2):250-259, 2016) replace the blood's flow by a Newton (Robin) condition at the
two interfaces it wets:

    -k dT/dn = h (T - T_blood)   at the electrode-blood (h_E) and the tissue-blood (h_T) surface,

the blood domain conducting the current (its Joule heat carried away by the flow) but not
solved for temperature (it stays at ``T_blood``). ``FLOW_COEFFICIENTS`` holds the low- and
high-flow pairs (h_E, h_T). ASSUMPTION: the numbers (708 / 44 W/(m^2 K) low flow, 3636 / 610
W/(m^2 K) high flow) are the ones commonly cited to that paper; the search tool reached its title
and venue but not its text, so they are not verified here against the paper's table (the low
pair is usually given for about 8.5 cm/s past the tip, the high pair for the ~24 cm/s of a
cardiac chamber; Tangwongsan et al., Biomed. Eng. Online 5:57, 2006, measured 5100-13600
W/(m^2 K) on a 1.9 x 3.2 mm catheter sensor at 0-5 L/min in vitro: the high pair's h_E is at
the low end of that range).

Open irrigation (saline pumped through the tip's holes at 8-30 mL/min) is represented by the
reduced model of Gonzalez-Suarez et al. ("Should fluid dynamics be included in computer models of
RF cardiac ablation by irrigated-tip electrodes?", Biomed. Eng. Online 17:43, 2018): the
electrode held at a constant temperature. They found it predicts the lesion depth within 0.1 mm
and the peak tissue temperature within 3 C of the full fluid-dynamics model, and OVERESTIMATES
the lesion's surface width by up to 5 mm (70 %): the irrigant's jet that cools the tissue
surface around the tip is missing. ASSUMPTION: the tip's temperature, ``IRRIGATED_TIP_C`` =
30 C (room-temperature saline at 17-30 mL/min warmed by the tip; the paper's own value was not
reachable).

Blood (``BLOOD``): sigma 0.7 S/m at 500 kHz and 37 C, +2 %/C like saline (ASSUMPTION on the
coefficient); k 0.52 W/(m K), rho 1050 kg/m^3, c 3617 J/(kg K) (IT'IS tissue database, Hasgall
et al.; the values of the Berjano group's models are close: sigma 0.667-0.748 S/m).

Nothing here changes ``lesion_fem``: the still-saline path, and so the shipped lesion table keyed
by that module's source, stay as they were.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from skfem import BilinearForm, ElementTriP1, FacetBasis, LinearForm, asm

from ballchain.drake_models import tissue as laws
from ballchain.drake_models.lesion_mesh import ELECTRODE, HOLDER, SALINE, TISSUE, AblationMesh
from ballchain.infrastructure.errors import UserInputError, short_repr

BLOOD = laws.Material(
    name="blood",
    electrical_conductivity=0.7,
    sigma_temperature_coefficient=0.02,
    thermal_conductivity=0.52,
    k_temperature_slope=0.0,
    density=1050.0,
    specific_heat=3617.0,
    reference_temperature_C=37.0,
    vaporises=True,
    source=("sigma about 0.7 S/m at 500 kHz (IT'IS database; Berjano group's models 0.667-0.748 S/m), +2 %/C "
            "as saline (assumed); k 0.52, rho 1050, c 3617 (IT'IS database, Hasgall et al.)"),
)
"""Whole blood at 37 C. Used as the fluid when the blood flows (its temperature is then held)."""

FLOW_COEFFICIENTS = {"low": (708.0, 44.0), "high": (3636.0, 610.0)}
"""(h_E electrode-blood, h_T tissue-blood) [W/(m^2 K)] per blood-flow level (module docstring:
cited to Gonzalez-Suarez and Berjano 2016, values not verified here)."""
BLOOD_FLOWS = ("none", "low", "high")
IRRIGATIONS = ("none", "open")
IRRIGATED_TIP_C = 30.0  # [C] ASSUMPTION: the open-irrigated tip's temperature (module docstring)


@dataclass(frozen=True)
class ThermalConditions:
    """The electrode's surroundings: blood flow (Robin coefficients) and irrigation.

    Attributes:
        blood_flow: "none" (still fluid, pure conduction: the bench), "low" or "high".
        irrigation: "none" or "open" (the electrode held at ``irrigant_C``).
        h_electrode, h_tissue: the Robin coefficients [W/(m^2 K)] (0 with no flow).
        irrigant_C: the irrigated tip's temperature [C].
    """

    blood_flow: str = "none"
    irrigation: str = "none"
    h_electrode: float = 0.0
    h_tissue: float = 0.0
    irrigant_C: float = IRRIGATED_TIP_C

    def __post_init__(self) -> None:
        if self.blood_flow not in BLOOD_FLOWS:
            raise UserInputError(f"blood_flow must be one of {BLOOD_FLOWS}, got {short_repr(self.blood_flow)}")
        if self.irrigation not in IRRIGATIONS:
            raise UserInputError(f"irrigation must be one of {IRRIGATIONS}, got {short_repr(self.irrigation)}")
        for name in ("h_electrode", "h_tissue", "irrigant_C"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise UserInputError(f"{name} must be a finite number >= 0, got {short_repr(v)}")

    @property
    def flowing(self) -> bool:
        """Whether the fluid is flowing blood (held at its temperature, Robin at its interfaces)."""
        return self.blood_flow != "none"

    @property
    def still(self) -> bool:
        """The paper's bench: still fluid, no irrigation."""
        return not self.flowing and self.irrigation == "none"


def conditions(blood_flow: str = "none", irrigation: str = "none", irrigant_C: float = IRRIGATED_TIP_C
               ) -> ThermalConditions:
    """The conditions of a blood-flow level ("none", "low", "high") and an irrigation ("none", "open")."""
    if blood_flow not in BLOOD_FLOWS:
        raise UserInputError(f"blood_flow must be one of {BLOOD_FLOWS}, got {short_repr(blood_flow)}")
    h_e, h_t = FLOW_COEFFICIENTS.get(blood_flow, (0.0, 0.0))
    return ThermalConditions(blood_flow=blood_flow, irrigation=irrigation, h_electrode=h_e, h_tissue=h_t,
                             irrigant_C=irrigant_C)


def interface_facets(am: AblationMesh) -> dict[str, np.ndarray]:
    """The mesh edges between the fluid and the tissue ("tissue") and between the fluid and the
    electrode or its holder ("electrode"): facet indices of ``am.mesh``."""
    f2t = am.mesh.f2t
    interior = np.flatnonzero(f2t[1] >= 0)
    da, db = am.domain[f2t[0, interior]], am.domain[f2t[1, interior]]

    def between(a, bs):
        return interior[((da == a) & np.isin(db, bs)) | ((db == a) & np.isin(da, bs))]

    return {"tissue": between(SALINE, (TISSUE,)), "electrode": between(SALINE, (ELECTRODE, HOLDER))}


@BilinearForm
def _robin(u, v, w):
    return w.h * u * v * w.x[0]


@LinearForm
def _robin_load(v, w):
    return w.h * w.t_inf * v * w.x[0]


def robin_operator(am: AblationMesh, facets: np.ndarray, h: float, t_inf_C: float):
    """The Newton condition -k dT/dn = h (T - t_inf) on ``facets`` (axisymmetric, r-weighted like
    the FEM's operators): (matrix R, load r) with the boundary's heat loss [W / 2 pi] = 1.(R T - r)."""
    n = am.n_nodes
    if len(facets) == 0 or h == 0.0:
        return asm(_robin, FacetBasis(am.mesh, ElementTriP1(), facets=np.arange(1)), h=0.0) * 0.0, np.zeros(n)
    fb = FacetBasis(am.mesh, ElementTriP1(), facets=np.asarray(facets))
    return asm(_robin, fb, h=float(h)), asm(_robin_load, fb, h=float(h), t_inf=float(t_inf_C))
