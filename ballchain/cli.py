"""The ``ballchain`` command: one entry point, one subcommand per job.

Each subcommand lives in ``ballchain/commands/<name>.py`` with ``add_arguments(parser)`` and
``main(args) -> int``; modules load only when their subcommand runs, so ``ballchain --help`` is
fast. Every subcommand that computes something takes ``--json``. Bad input (argparse's errors
and ``UserInputError``) exits with status 2 and a one-line message on stderr, never a traceback;
any other exception is a bug and stays a traceback (exit status 1), so that it gets reported.
Ctrl-C stops with status 130 and a one-line note (result files are written atomically, so what
was finished stays intact).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from ballchain.drake_models.errors import UserInputError, caused_by_interrupt
from ballchain.drake_models.model_files import CACHE_ENV, check_cache_dir

# subcommand -> (module under ballchain.commands, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "statics": ("statics", "equilibrium shape of a chain in a uniform field"),
    "alignment": ("alignment", "tip-to-field alignment for 1..16 balls (paper's model figure)"),
    "sizing": ("sizing", "clinical actuation magnet sizing (paper Section V-A)"),
    "field-models": ("field_models", "point dipole vs exact cylinder field of the prototype magnet"),
    "bench": ("bench", "benchmarks (statics solve against an SLSQP baseline)"),
    "forces": ("forces", "tip forces on the pulmonary veins, both configurations (paper Table I)"),
    "plan": ("plan", "inverse statics for every ablation target and a visiting plan (beyond the paper)"),
    "workspace": ("workspace", "workspace with one rotating magnet 16.51 cm away (paper Fig. workspace)"),
    "validation": ("validation", "model validation: uniform vs dipole vs exact field, 5..10 balls"),
    "reproduce": ("reproduce", "run the paper checks and write a report (the main job)"),
    "simulate": ("simulate", "simulate the chain in the left atrium for a named scenario"),
    "reconfigure": ("reconfigure", "closed-loop magnet axis reconfiguration study (Hall sensor, slip, noise)"),
    "wheels": ("wheels", "omni-wheel kinematics: derived wheel-to-magnet map vs the paper's"),
    "teleop": ("teleop", "simulated operator touches the ablation targets (paper Tasks I/II), two joystick mappings"),
    "ablation": ("ablation", "RF lesions of the ball chain and a standard catheter: electro-thermal FEM (paper Sec. V-D)"),
    "sweep": ("sweep", "run a sweep spec or a shipped study on Dask (local cores, a scheduler or a job queue)"),
    "clinical": ("clinical", "the paper's clinical design (two 119 mm spheres) in simulation, and the model's sizing"),
}


class _OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line (no usage block): exit status 2."""

    def error(self, message):
        message = " ".join(str(message).split())
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    """The top-level parser and one (argument-less) subparser per subcommand."""
    parser = _OneLineParser(prog="ballchain", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    subparsers = {}
    for name, (module, help_text) in COMMANDS.items():
        subparsers[name] = sub.add_parser(name, help=help_text, description=help_text)
    return parser, subparsers


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser, subparsers = build_parser()
    if not argv or argv[0] not in COMMANDS:
        parser.parse_args(argv)  # prints help or the error, and exits
        return 2
    try:
        # Load only the chosen subcommand's module, give its parser the arguments, then parse.
        module = importlib.import_module(f"ballchain.commands.{COMMANDS[argv[0]][0]}")
        module.add_arguments(subparsers[argv[0]])
        args = parser.parse_args(argv)
        from threadpoolctl import threadpool_limits

        from ballchain.optimization.statics import StaticsError
    except KeyboardInterrupt:  # Ctrl-C while the libraries load: nothing was started
        print(f"ballchain {argv[0]}: interrupted", file=sys.stderr)
        return 130

    try:
        # Every matrix here is small (at most a few hundred rows): threaded BLAS only adds
        # synchronisation, and under load it makes solves several times slower.
        with threadpool_limits(limits=1, user_api="blas"):
            if os.environ.get(CACHE_ENV):  # a bad cache folder is said before any work
                check_cache_dir()
            return int(module.main(args) or 0)
    except UserInputError as err:
        message = " ".join(str(err).split())  # one line, whatever the message holds
        print(f"ballchain {args.command}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"ballchain {args.command}: interrupted (files already written are complete)", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of stdout went away (``ballchain ... | head``): not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except StaticsError as err:
        print(f"ballchain {args.command}: {' '.join(str(err).split())}", file=sys.stderr)
        return 1
    except Exception as err:
        if not caused_by_interrupt(err):  # a bug: the traceback
            raise
        print(f"ballchain {args.command}: interrupted (files already written are complete)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
