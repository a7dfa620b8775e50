"""The paper's numbers, each typed once (Pittiglio et al.; docs/design.md, section 3).

Experiments, reports and tests cite these by name; the model's own results are never tuned to
them. Lengths in metres, forces in grams-force (as printed), times in seconds.
"""

from __future__ import annotations

WORKING_DISTANCE = 0.1651
"""Actuation magnet centre to the septal puncture in the force and workspace experiments [m]."""

CLINICAL_DISTANCE = 0.2965
"""d_c: the heart to the outside of the patient's arm in the clinical sizing [m]."""

ALIGNMENT_MAX_DEG = 1.4
"""Tip-to-field angle below this for chains longer than 10 balls (23 mT, 0..180 deg)."""

TABLE_I_GF = {  # (vein, configuration, sleeve) -> tip force [gf]
    ("LSPV", "1", False): 20.4, ("LSPV", "2", False): 91.8, ("LSPV", "both", False): 112.2,
    ("LIPV", "1", False): 20.4, ("LIPV", "2", False): 86.7, ("LIPV", "both", False): 107.1,
    ("RSPV", "1", False): 81.6, ("RSPV", "2", False): 40.8, ("RSPV", "both", False): 122.4,
    ("RIPV", "1", False): 81.6, ("RIPV", "2", False): 40.8, ("RIPV", "both", False): 122.4,
    ("LSPV", "1", True): 30.6, ("LSPV", "2", True): 107.1, ("LSPV", "both", True): 137.7,
    ("LIPV", "1", True): 30.6, ("LIPV", "2", True): 102.0, ("LIPV", "both", True): 132.6,
    ("RSPV", "1", True): 81.6, ("RSPV", "2", True): 51.0, ("RSPV", "both", True): 132.6,
    ("RIPV", "1", True): 81.6, ("RIPV", "2", True): 51.0, ("RIPV", "both", True): 132.6,
}

SIZING = {"alpha": 0.32, "measured_force_gf": 132.6, "desired_force_gf": 10.0,
          "diameter_mm": 119.0, "mass_kg": 6.6, "force_between_magnets_gf": 500.0}

WORKSPACE = {"half_area_bare_mm2": 3345.0, "half_area_sleeve_mm2": 2939.0, "reduction_pct": 12.0,
             "tip_to_tip_mm": 8.0}

TELEOP_TASKS = {  # Task I (left) and Task II (right): targets, ring path, the operator's learned time
    "left": {"targets": 20, "path_mm": 115.0, "human_time_s": 40.0},
    "right": {"targets": 18, "path_mm": 95.0, "human_time_s": 26.0},
}

ABLATION = {  # lesions after 90 s: the ball chain at 15 W, a standard 8 Fr catheter at 30 W
    "ball_chain": {"power_W": 15.0, "duration_s": 90.0, "width_mm": 5.7, "depth_mm": 3.1},
    "standard_catheter": {"power_W": 30.0, "duration_s": 90.0, "width_mm": 5.4, "depth_mm": 3.3},
    "criterion": {"min_depth_mm": 2.9, "width_mm": (5.2, 6.0)},
}
