"""The comparison's atrium seen by the steerable sheath's plan (shared by the sheath-plan tests):
the sheath at its nominal advance along the septal axis, the targets, and the catheter on the
0.14 N/mm wall."""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.atrium_sdf import atrium_sdf
from ballchain.drake_models.sheath import SteerableSheath
from ballchain.experiments import manual_catheter as mc
from ballchain.optimization.rod_statics import frame_along
from ballchain.systems.station import atrium_for
from ballchain.systems.target_contact import heart_targets


def sheath_world() -> dict:
    """{heart, sdf, sheath, p_S, R_S, names, p_WT, n_W, radius, cat}."""
    heart = atrium_for(mc.scenario_for())
    sdf, sheath = atrium_sdf(heart), SteerableSheath().validate()
    axis = np.asarray(heart.sheath_axis_H, float)
    R_S = frame_along(axis)
    p_S = np.asarray(heart.p_HE, float) - sheath.nominal_advance * axis
    names, p_WT, n_W, radius = heart_targets(heart)
    return {"heart": heart, "sdf": sdf, "sheath": sheath, "p_S": p_S, "R_S": R_S, "names": names, "p_WT": p_WT,
            "n_W": n_W, "radius": radius, "cat": mc.comparison_catheter(None, mc.MANUAL_WALL_STIFFNESS)}
