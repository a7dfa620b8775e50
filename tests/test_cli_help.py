"""The command line explains itself: every option's help shows its default, ``ballchain --help``
says where to start, ``simulate --scenario list`` describes the scenarios, ``--engine`` sets
the scenario's engine."""

import argparse
import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

from ballchain.cli import COMMANDS, START_HERE, DefaultsHelpFormatter, build_parser, format_default, main
from ballchain.systems.chain_scenario import ENGINES, load_scenario, scenario_descriptions

SMALL = "free_space_uniform_90deg"


def _parsers():
    parser, subparsers = build_parser()
    for name, (module, _) in COMMANDS.items():
        importlib.import_module(f"ballchain.commands.{module}").add_arguments(subparsers[name])
    return subparsers


def _help_of(capsys, *argv) -> str:
    with pytest.raises(SystemExit) as exit_:
        main([*argv, "--help"])
    assert exit_.value.code == 0
    return " ".join(capsys.readouterr().out.split())  # argparse's wrapping undone


def test_every_option_with_a_default_shows_it():
    missing = []
    for name, parser in _parsers().items():
        assert parser.formatter_class is DefaultsHelpFormatter, name
        formatter = parser._get_formatter()
        for action in parser._actions:
            if (not action.option_strings or action.default in (None, False, argparse.SUPPRESS)
                    or isinstance(action, argparse._HelpAction)):
                continue
            if "default" not in formatter._get_help_string(action).lower():
                missing.append(f"{name} {action.option_strings[-1]}")
    assert not missing, missing


@pytest.mark.parametrize("argv,shown", [
    (["statics"], ["--balls BALLS number of balls (1..200) (default: 16)", "(default: 23)", "(default: newton)"]),
    (["teleop"], ["(default: left)", "(default: world)"]),
    (["forces"], ["(default: LSPV LIPV RSPV RIPV)", "(default: results/forces)"]),
    (["workspace"], ["(default: 16.51)"]),
])
def test_help_shows_the_defaults_as_a_user_types_them(capsys, argv, shown):
    text = _help_of(capsys, *argv)
    for piece in shown:
        assert piece in text


def test_defaults_are_written_as_typed():
    assert format_default(0.1651 * 100) == "16.51"
    assert format_default([8.0, 12.0, 16.509999999999998]) == "8 12 16.51"
    assert format_default(1e-12) == "1e-12"
    assert format_default(Path("results") / "forces") == "results/forces"
    assert format_default(1 / 3) == "0.3333333333"


def test_top_level_help_says_where_to_start(capsys):
    text = _help_of(capsys)
    assert "ballchain reproduce --out results" in text and "ballchain simulate --scenario list" in text
    assert "import ballchain" in text
    # Every command it suggests exists.
    for line in START_HERE.splitlines():
        words = line.split()
        if words and words[0] == "ballchain" and words[1] != "COMMAND":
            assert words[1] in COMMANDS, line


def test_top_level_help_does_not_load_drake():
    code = ("import sys\nfrom ballchain.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(any(m.split('.')[0] == 'pydrake' for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "start here" in out and out.split()[-1] == "False"


def test_scenario_list_gives_engine_mode_and_description(capsys):
    assert main(["simulate", "--scenario", "list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    descriptions = scenario_descriptions()
    for name, description in descriptions.items():
        scenario = load_scenario(name)
        row = [line for line in lines if line.split()[:1] == [name]]
        assert len(row) == 1, name
        assert f"{scenario.engine}, {scenario.mode}" in row[0] and row[0].rstrip().endswith(description)
    assert main(["simulate", "--scenario", "list", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["scenarios"] == list(descriptions)
    assert [(d["name"], d["description"]) for d in data["details"]] == list(descriptions.items())
    assert all(d["engine"] in ENGINES for d in data["details"])


def test_simulate_help_names_the_engine(capsys):
    text = _help_of(capsys, "simulate")
    assert "--engine {plant,statics}" in text and "engine field" in text and "'list'" in text


@pytest.mark.parametrize("argv,message", [
    (["--engine", "sap"], "--engine: invalid choice: 'sap'"),
    (["--engine", "statics", "--set", "{engine: plant}"], "--engine statics disagrees with --set engine: 'plant'"),
    (["--mode", "dynamics", "--set", "{mode: quasi-static}"], "--mode dynamics disagrees with --set mode"),
    (["--engine", "statics", "--mode", "dynamics"], "engine: statics needs mode: quasi-static"),
])
def test_bad_engine_flags_exit_2_with_one_line(capsys, argv, message):
    try:
        code = main(["simulate", "--scenario", SMALL, *argv])
    except SystemExit as exc:  # argparse's own check of the choices
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("extra", [[], ["--set", "{engine: statics}"]])
def test_engine_flag_sets_the_scenario_engine(capsys, extra):
    """``--engine statics`` runs the quasi-static engine (a ``--set`` that agrees is accepted); it
    settles on the statics equilibrium of the canonical problem, as the plant does."""
    argv = ["simulate", "--scenario", SMALL, "--engine", "statics", "--duration", "0.1", "--no-progress", "--json"]
    assert main(argv + extra) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["engine"] == "statics" and data["statics"]["solves"] >= 1
    assert data["statics_tip_error_mm"] < 1e-3
