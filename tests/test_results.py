"""The experiments' results serialise one way (``experiments/_result.py`` on ``safe_files.to_jsonable``):
the fields in their order, numpy to plain Python, NaN to null, optional fields left out while None."""

import dataclasses
import json

import numpy as np

from ballchain.commands._common import json_text
from ballchain.experiments import _result, alignment, field_models, forces_dynamics, sizing_check, wheels
from ballchain.drake_models.params import BallChain
from ballchain.drake_models.safe_files import OMIT_IF_NONE
from ballchain.optimization.sizing import SizingInputs


def test_fields_in_order_numpy_to_lists_nan_to_null_optional_left_out_while_none():
    summary = alignment.AlignmentSummary(float("nan"), None, 1.4)
    result = alignment.AlignmentResult(rows=[{"n_balls": np.int64(2), "tip_angle_deg": np.float64(0.5)}],
                                       shapes={0.0: np.zeros((2, 3))}, summary=summary)
    data = json.loads(result.to_json())
    assert list(data) == ["rows", "shapes", "summary"]  # no "files" without out
    assert data["rows"] == [{"n_balls": 2, "tip_angle_deg": 0.5}]
    assert data["shapes"] == {"0.0": [[0.0, 0.0, 0.0]] * 2}
    assert data["summary"] == {"max_tip_angle_deg_beyond_10_balls": None,
                               "max_tip_angle_deg_beyond_10_balls_at_180deg": None, "paper_claim_deg": 1.4}
    result.files = []  # an optional field that is set, even empty, is written
    assert list(json.loads(result.to_json())) == ["rows", "shapes", "summary", "files"]
    # One serialisation: the method, the command's printer and to_dict agree.
    assert result.to_json() == json_text(result) == json_text(result.to_dict())


def test_every_result_field_is_a_key_of_the_json_and_nothing_else():
    """Real results: the JSON's keys are the dataclass's fields, in order (the optional ones
    only when set)."""
    results = [
        sizing_check.run(inputs=SizingInputs()),
        field_models.run(distances_m=[0.1], angles_deg=[0.0], ball=BallChain()),
        wheels.run(samples=5),
    ]
    for result in results:
        assert isinstance(result, _result.Result)
        names = [f.name for f in dataclasses.fields(result)
                 if not (f.metadata.get(OMIT_IF_NONE) and getattr(result, f.name) is None)]
        assert list(json.loads(result.to_json())) == names, type(result).__name__


def test_the_pin_simulation_result_leaves_statics_loaded_out_unless_set():
    fields = {f.name: None for f in dataclasses.fields(forces_dynamics.PinForceResult)}
    fields.update(settled=False, stiffness_N_per_m=500.0, time_step_s=1e-3, sim_time_s=0.0, wall_time_s=0.0,
                  steps=0, reason="too short")
    del fields["statics_loaded_N"]
    result = forces_dynamics.PinForceResult(**fields)
    assert "statics_loaded_N" not in result.to_dict()
    result.statics_loaded_N = 0.01
    assert list(result.to_dict())[-1] == "statics_loaded_N"
