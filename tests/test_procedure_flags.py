"""``ballchain procedure``'s tracker flags against the scenario's ``localisation`` (--set): the
flags given win, none given leaves the scenario's figures, both for the same thing is refused."""

from __future__ import annotations

import pytest

from ballchain.cli import build_parser
from ballchain.commands import procedure as command
from ballchain.infrastructure.errors import UserInputError
from ballchain.drake_models.localisation import LocalisationParams


def _args(*argv: str):
    parser, subparsers = build_parser()
    command.add_arguments(subparsers["procedure"])
    return parser.parse_args(["procedure", "--task", "right", *argv])


def test_no_tracker_flag_leaves_the_scenarios_figures():
    assert command._localisation(_args()) is None
    assert command._localisation(_args("--set", "{localisation: {rate: 20.0}}")) is None


def test_the_flags_given_set_those_figures_and_the_others_stay_at_their_defaults():
    got = command._localisation(_args("--noise", "0.8", "--rate", "20"))
    default = LocalisationParams()
    assert got.noise_std == pytest.approx(0.8e-3, rel=1e-12) and got.rate == 20.0
    assert got.latency == default.latency


def test_a_flag_and_set_localisation_together_are_refused_naming_both():
    with pytest.raises(UserInputError, match=r"--rate and --set localisation"):
        command._localisation(_args("--rate", "20", "--set", "{localisation: {rate: 30.0}}"))
