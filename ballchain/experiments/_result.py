"""The one serialisation of the experiments' results (a small base class).

Every ``run(...)`` of ``ballchain.experiments`` returns a dataclass result; its JSON (what a
command prints, what ``reproduce`` writes to ``OUT/sections/<name>.json``) is
``drake_models.safe_files.to_jsonable`` of it: the fields in their order, numpy arrays as lists,
NaN and inf as null, the fields made with ``optional()`` left out while None, those made with
``not_in_json()`` always.
"""

from __future__ import annotations

import dataclasses

from ballchain.infrastructure.safe_files import NOT_IN_JSON, json_text, optional_field, to_jsonable

# A field that defaults to None and is left out of the JSON while None: for the parts of a result
# that exist only in some runs (the files written with ``out``, the replay with ``html``).
optional = optional_field


def not_in_json(**kwargs):
    """A dataclass field that is never in the JSON (default None, not in the repr).

    For a working object a result keeps for its figures or a caller (the simulated fields of an
    ablation run), which is no result number.
    """
    return dataclasses.field(default=None, repr=False, metadata={NOT_IN_JSON: True}, **kwargs)


class Result:
    """Base of the experiments' result dataclasses: ``to_dict`` / ``to_json`` in one place."""

    def to_dict(self) -> dict:
        """The JSON-ready dict of the result (``safe_files.to_jsonable``: plain Python, no NaN)."""
        return to_jsonable(self)

    def to_json(self) -> str:
        """The result as JSON text (``safe_files.json_text``)."""
        return json_text(self)
