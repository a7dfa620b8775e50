"""Published catheter lesions (issue 44): the protocol points the lesion model is checked against.

Each entry is one protocol point of a published experiment with an open-irrigated 3.5 mm-tip
catheter (the model's ``catheter_8fr``): the set power, the RF time, the contact force(s) it is
the mean over, the irrigation, the fluid and its flow, and the measured lesion depth (and width
where the source gives it) as mean +- SD. Only numbers read in the sources' abstracts (through the
search tool) are here; what the abstracts do not give is marked as the model's ASSUMPTION in
``assumed``. Nothing of the model is fitted to them.

Sources (three groups, ten protocol points):

- ``THIAGALINGAM_2010``: Thiagalingam A, D'Avila A, Foley L, Guerrero JL, Lambert H, Leo G,
  Ruskin JN, Reddy VY. "Importance of catheter contact force during irrigated radiofrequency
  ablation: evaluation in a porcine ex vivo model using a force-sensing catheter." J. Cardiovasc.
  Electrophysiol. 21(7):806-811, 2010. Excised porcine hearts perfused and superfused with
  heparinised oxygenated swine blood; TactiCath (3.5 mm tip) irrigated at 17 mL/min; 60 s; three
  power strategies (15 Ohm impedance-drop target, 20 W, 30 W) x three forces (2, 20, 60 g), 101
  lesions. Only the marginal means are in the abstract: depth 5.0 +- 1.6 mm (20 W) and 6.7 +- 2.5
  mm (30 W) over the three forces; 4.4 +- 1.8, 5.8 +- 1.6, 6.6 +- 2.0 mm (2, 20, 60 g) over the
  three power strategies (the model averages 20 and 30 W: it has no impedance-drop mode).
- ``SCIREP_2025``: "vHP-SD vs HP-SD" ex vivo porcine myocardium in a circulating saline bath,
  an irrigated catheter with temperature-based power regulation (QDOT-type), 120 lesions per
  protocol, Sci. Rep. 2025, doi:10.1038/s41598-025-06533-5 (authors not reached). Depth and
  maximum diameter: 50 W 4 s 2.42 +- 0.61 / 6.02 +- 1.00 mm; 90 W 4 s 3.16 +- 0.41 / 7.34 +-
  0.92 mm; 50 W 15 s 4.49 +- 0.66 / 9.13 +- 1.59 mm. The contact forces are not in the abstract.
- ``JACC_EP_2018``: "Longer duration versus increasing power during radiofrequency ablation yields
  different ablation lesion characteristics", JACC Clin. Electrophysiol. 2018 (ACC journal scan
  of 9 May 2018; authors not reached): in vivo porcine thigh, open-irrigated catheter at 10 g:
  depth 2.0 mm at 50 W / 5 s and 2.9 mm at 20 W / 30 s (no SD in the abstract).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PublishedLesion:
    """One published protocol point.

    Attributes:
        key: short name.
        source: the citation key (module docstring).
        preparation: the tissue and the fluid.
        power_W: set power [W].
        duration_s: RF time [s].
        forces_gf: the contact forces the published mean is over [gf] (the model averages them).
        powers_W: the set powers the mean is over (when more than one) [W].
        irrigation: "open".
        blood_flow: the model's flow level for the preparation (``lesion_boundary``).
        fluid: "blood" or "saline".
        depth_mm, depth_sd_mm: published depth, mean and SD (SD None: not given).
        width_mm, width_sd_mm: published maximum diameter (None: not given).
        assumed: what the model assumes where the abstract is silent.
    """

    key: str
    source: str
    preparation: str
    power_W: float
    duration_s: float
    forces_gf: tuple
    depth_mm: float
    depth_sd_mm: float | None
    width_mm: float | None = None
    width_sd_mm: float | None = None
    powers_W: tuple = ()
    irrigation: str = "open"
    blood_flow: str = "low"
    fluid: str = "blood"
    assumed: str = ""

    @property
    def protocol_powers_W(self) -> tuple:
        return self.powers_W or (self.power_W,)


_T = "THIAGALINGAM_2010"
_T_PREP = "ex vivo porcine heart, blood-perfused and superfused"
_T_ASSUMED = "blood flow 'low' (superfusion's flow not in the abstract)"
_S = "SCIREP_2025"
_S_PREP = "ex vivo porcine myocardium, circulating saline bath"
_S_ASSUMED = ("contact force 20 gf (not in the abstract); saline flowing 'low'; the catheter's temperature-based "
              "power regulation modelled as set power with the 100 C cut-off")
_J = "JACC_EP_2018"
_J_PREP = "in vivo porcine thigh, open-irrigated catheter, 10 g"
_J_ASSUMED = "blood flow 'low' over the thigh preparation (not in the abstract)"

PUBLISHED = (
    PublishedLesion("T-20W", _T, _T_PREP, 20.0, 60.0, (2.0, 20.0, 60.0), 5.0, 1.6, assumed=_T_ASSUMED),
    PublishedLesion("T-30W", _T, _T_PREP, 30.0, 60.0, (2.0, 20.0, 60.0), 6.7, 2.5, assumed=_T_ASSUMED),
    PublishedLesion("T-2g", _T, _T_PREP, 25.0, 60.0, (2.0,), 4.4, 1.8, powers_W=(20.0, 30.0),
                    assumed=_T_ASSUMED + "; mean of 20 and 30 W (the 15 Ohm group is not modelled)"),
    PublishedLesion("T-20g", _T, _T_PREP, 25.0, 60.0, (20.0,), 5.8, 1.6, powers_W=(20.0, 30.0),
                    assumed=_T_ASSUMED + "; mean of 20 and 30 W (the 15 Ohm group is not modelled)"),
    PublishedLesion("T-60g", _T, _T_PREP, 25.0, 60.0, (60.0,), 6.6, 2.0, powers_W=(20.0, 30.0),
                    assumed=_T_ASSUMED + "; mean of 20 and 30 W (the 15 Ohm group is not modelled)"),
    PublishedLesion("S-50W4s", _S, _S_PREP, 50.0, 4.0, (20.0,), 2.42, 0.61, 6.02, 1.00, fluid="saline",
                    assumed=_S_ASSUMED),
    PublishedLesion("S-90W4s", _S, _S_PREP, 90.0, 4.0, (20.0,), 3.16, 0.41, 7.34, 0.92, fluid="saline",
                    assumed=_S_ASSUMED),
    PublishedLesion("S-50W15s", _S, _S_PREP, 50.0, 15.0, (20.0,), 4.49, 0.66, 9.13, 1.59, fluid="saline",
                    assumed=_S_ASSUMED),
    PublishedLesion("J-50W5s", _J, _J_PREP, 50.0, 5.0, (10.0,), 2.0, None, assumed=_J_ASSUMED),
    PublishedLesion("J-20W30s", _J, _J_PREP, 20.0, 30.0, (10.0,), 2.9, None, assumed=_J_ASSUMED),
)
"""The protocol points (module docstring)."""

SOURCES = {
    _T: "Thiagalingam et al., J. Cardiovasc. Electrophysiol. 21(7):806-811, 2010",
    _S: "Sci. Rep. 2025, doi:10.1038/s41598-025-06533-5 (vHP-SD vs HP-SD, ex vivo)",
    _J: "JACC Clin. Electrophysiol. 2018, 'Longer duration versus increasing power ...' (in vivo thigh)",
}
