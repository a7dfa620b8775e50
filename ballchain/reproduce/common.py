"""What every report section shares: the report's title, the summary's verdict rule, the console line."""

from __future__ import annotations

import sys

from tqdm import tqdm

TITLE = "Magnetic ball chain: the paper's numbers in simulation"
AGREES_WITHIN = 0.10
"""The summary's rule: a model value within this fraction of the paper's agrees with it (the
tables beside it hold the numbers; a verdict on a claim rather than a number says so). The
closed-loop rows (teleoperation, robotic vs manual, the procedure: statistics over seeds) use the
interval rule instead (``ballchain.intervals``): they agree only when the paper's number lies
inside the 95 % interval over the seeds, which the row prints beside it."""


def _agrees(paper_value, model_value) -> bool | None:
    """The summary's verdict on a number: within ``AGREES_WITHIN`` of the paper's (None: no number to compare)."""
    if not isinstance(paper_value, (int, float)) or not isinstance(model_value, (int, float)) or not paper_value:
        return None
    return abs(model_value - paper_value) <= AGREES_WITHIN * abs(paper_value)


def _say(message: str) -> None:
    tqdm.write(f"reproduce: {message}", file=sys.stderr)
