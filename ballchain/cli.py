"""The ``ballchain`` command: one entry point, one subcommand per job.

Each subcommand lives in ``ballchain/commands/<name>.py`` with ``add_arguments(parser)`` and
``main(args) -> int``; modules load only when their subcommand runs, so ``ballchain --help`` is
fast. Every subcommand that computes something takes ``--json``. Bad input (argparse's errors
and ``UserInputError``) exits with status 2 and a one-line message on stderr, never a traceback;
any other exception is a bug and stays a traceback (exit status 1), so that it gets reported.
A result file that cannot be written (full disk, ...) is one line too, exit status 1.

Stopping: Ctrl-C (SIGINT), SIGTERM (``kill``, ``timeout``, a batch scheduler's time limit) and
SIGHUP (the terminal closed) are one request to stop, handled once, here (``StopSignals``): the
first raises ``StopRequest`` (a KeyboardInterrupt) where Ctrl-C would, so every command keeps
what finished as it does on Ctrl-C (the replay so far, the finished sections of a report, the
finished points of a sweep: result files are written atomically, so what was written is whole);
signals after it are recorded while that is saved. The command then exits with status
128 + the signal's number (130, 143, 129) and a one-line note (a command that ends its run
itself on a stop returns ``INTERRUPTED``, 130, to get the same), and no later signal can change
that status.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import os
import signal
import sys
import threading

from ballchain.infrastructure import kernel_compiler
from ballchain.infrastructure.errors import OutputError, StopRequest, UserInputError, caused_by_interrupt
from ballchain.drake_models.model_files import CACHE_ENV, check_cache_dir
from ballchain.infrastructure.resource_limits import address_space_refusal, limit_message

# subcommand -> (module under ballchain.commands, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "statics": ("statics", "equilibrium shape of a chain in a uniform field"),
    "alignment": ("alignment", "tip-to-field alignment for 1..16 balls (paper's model figure)"),
    "sizing": ("sizing", "clinical actuation magnet sizing (paper Section V-A)"),
    "field-models": ("field_models", "point dipole vs exact cylinder field of the prototype magnet"),
    "bench": ("bench", "benchmarks (statics solve against an SLSQP baseline)"),
    "forces": ("forces", "tip forces on the pulmonary veins, both configurations (paper Table I)"),
    "plan": ("plan", "inverse statics for every ablation target and a visiting plan (beyond the paper)"),
    "procedure": ("procedure", "simulated ablation procedure: autonomous navigation, sensorless force hold (beyond the paper)"),
    "sensitivity": ("sensitivity", "the procedure's force estimate in a world it does not know, per perturbation (issue 43)"),
    "workspace": ("workspace", "workspace with one rotating magnet 16.51 cm away (paper Fig. 9)"),
    "validation": ("validation", "model validation: uniform vs dipole vs exact field, 5..10 balls"),
    "reproduce": ("reproduce", "run the paper checks and write a report (the main job)"),
    "simulate": ("simulate", "simulate the chain in the left atrium for a named scenario"),
    "reconfigure": ("reconfigure", "closed-loop magnet axis reconfiguration study (Hall sensor, slip, noise)"),
    "wheels": ("wheels", "omni-wheel kinematics: derived wheel-to-magnet map vs the paper's"),
    "teleop": ("teleop", "simulated operator touches the ablation targets (paper Tasks I/II), two joystick mappings"),
    "ablation": ("ablation", "RF lesions of the ball chain and a standard catheter: electro-thermal FEM (paper Sec. V-D)"),
    "sweep": ("sweep", "run a sweep spec or a shipped study on Dask (local cores, a scheduler or a job queue)"),
    "trials": ("trials", "closed-loop arms over many seeds on Dask, each row with its 95 % interval (issue 43)"),
    "clinical": ("clinical", "the paper's clinical design (two 119 mm spheres) in simulation, and the model's sizing"),
}


DESCRIPTION = ("Simulation and optimisation of magnetic ball-chain ablation catheters on Drake:\n"
               "the paper's checks, named scenarios, studies and sweeps, one subcommand per job.")
START_HERE = """\
start here:
  ballchain reproduce --out results    the paper's checks in simulation; open results/report.html
  ballchain simulate --scenario list   the named scenarios (engine, mode, description)
  ballchain simulate --scenario free_space_uniform_90deg
  ballchain COMMAND --help             a command's flags, with their defaults
in Python: import ballchain (its __all__ is the public API); docs: README.md and docs/"""


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """Help that shows every option's default: "(default: X)" is added to an option's help
    unless the help already speaks of its default, or there is none to show (None, a flag)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (not action.option_strings or default is None or default is False or default is argparse.SUPPRESS
                or "default" in text.lower() or "%(default)" in text):
            return text
        return f"{text} (default: {format_default(default).replace('%', '%%')})".lstrip()


def format_default(value) -> str:
    """A default as a user would type it: 16.51, not 16.509999999999998; lists space-separated."""
    if isinstance(value, (list, tuple)):
        return " ".join(format_default(v) for v in value)
    if isinstance(value, float):
        return f"{value:g}" if float(f"{value:g}") == value else f"{value:.10g}"
    return str(value)


class _OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line (no usage block): exit status 2."""

    def error(self, message):
        message = " ".join(str(message).split())
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    """The top-level parser and one (argument-less) subparser per subcommand."""
    parser = _OneLineParser(prog="ballchain", description=DESCRIPTION, epilog=START_HERE,
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    subparsers = {}
    for name, (module, help_text) in COMMANDS.items():
        # argparse %-formats a help string (``%(default)s``): a literal "95 %" is escaped, not a format
        subparsers[name] = sub.add_parser(name, help=help_text.replace("%", "%%"), description=help_text,
                                          formatter_class=DefaultsHelpFormatter)
    return parser, subparsers


INTERRUPTED = 130  # what a command returns when it ended its run itself on a stop (Ctrl-C's status)
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


class StopSignals:
    """The one handler of the stop signals (SIGINT, SIGTERM, SIGHUP) while a command runs.

    The first signal is recorded (``signum``) and raises ``StopRequest(signum)``, a
    KeyboardInterrupt, so the command stops as on Ctrl-C and keeps what finished. Later signals
    (a second Ctrl-C, a process group's kill reaching the process twice) are only recorded
    (``later``), with a one-line note, so that they cannot cut the saving short nor change the
    exit status (SIGKILL stops at once). A signal that was ignored when the command started
    (``nohup``, a background job) stays ignored. Only the main thread can install handlers;
    elsewhere this does nothing.

    Python runs a signal's handler wherever the main thread happens to be, and an exception raised
    inside a finaliser (an object's ``__del__``, a weakref callback: a progress bar closed by the
    garbage collector) is printed and dropped, never propagated. Such a swallowed stop is caught by
    ``sys.unraisablehook`` and delivered again a moment later (``REDELIVER_S``), until it reaches
    the command's own code. A stop that lands inside numba's or llvmlite's Python code is not
    raised there but delivered again the same way: numba does not check the exception of
    ``_numba_unpickle`` (the Python call with which a compiled kernel returns a new array), and a
    raise inside llvmlite's disposal of an LLVM object can leave it to be disposed of twice; the
    process died of SIGSEGV or SIGABRT, or ran on. A kernel's compilation, minutes of LLVM on a
    machine's first run, is therefore done by a child process (``kernel_compiler``), and the
    stop is raised in the wait for it, though numba's cache called that wait.
    """

    REDELIVER_S = 0.02  # after a stop swallowed by a finaliser: long enough for the finaliser to end

    def __init__(self):
        self.signum: int | None = None
        self.later: list[int] = []
        self._previous: dict[int, object] = {}
        self._swallowed = False
        self._hook = None

    def install(self) -> None:
        if threading.current_thread() is threading.main_thread():
            for signum in STOP_SIGNALS:
                previous = signal.getsignal(signum)
                if previous is not signal.SIG_IGN:
                    self._previous[signum] = previous
                    signal.signal(signum, self._handle)
            self._hook, sys.unraisablehook = sys.unraisablehook, self._unraisable

    def _handle(self, signum, frame):
        if (self.signum is None or self._swallowed) and _inside_numba_or_llvmlite(frame):
            # Not exception-safe there: numba hands a compiled kernel's new array back through a
            # Python call (``numba.core.serialize._numba_unpickle``) whose exception its compiled
            # code does not check, and llvmlite disposes of LLVM objects (loading a kernel from
            # numba's cache, its finalisers) in steps a raise can split, disposing of one twice.
            # Either crashed the process (SIGSEGV, SIGABRT) or lost the stop. Deliver it again a
            # moment later, as a stop dropped by a finaliser.
            self.signum = self.signum or signum
            self._swallowed = True
            threading.Timer(self.REDELIVER_S, self._redeliver).start()
            return
        if self.signum is None or self._swallowed:
            self._swallowed = False
            self.signum = self.signum or signum
            raise StopRequest(self.signum)
        self.later.append(signum)
        if len(self.later) == 1:  # os.write: a print here could land inside another print
            try:
                os.write(2, f"ballchain: {signal.Signals(signum).name} received while saving what finished; "
                            "it finishes first (SIGKILL stops at once)\n".encode())
            except OSError:
                pass

    def _unraisable(self, unraisable) -> None:
        """``sys.unraisablehook`` while installed: a stop dropped by a finaliser is sent again."""
        if isinstance(unraisable.exc_value, StopRequest) and self._previous:
            self._swallowed = True
            threading.Timer(self.REDELIVER_S, self._redeliver).start()
            return
        (self._hook or sys.__unraisablehook__)(unraisable)

    def _redeliver(self) -> None:
        if self._swallowed and self._previous:  # still installed, and not raised meanwhile
            os.kill(os.getpid(), self.signum)

    def _unhook(self) -> None:
        if self._hook is not None and sys.unraisablehook == self._unraisable:
            sys.unraisablehook = self._hook
        self._hook = None

    def ignore(self) -> None:
        """From now on the stop signals are ignored: nothing can raise or kill any more."""
        for signum in self._previous:
            signal.signal(signum, signal.SIG_IGN)
        self._swallowed = False
        self._unhook()

    def restore(self) -> None:
        """The handlers from before (when the command ran inside another program, e.g. a test)."""
        for signum, previous in self._previous.items():
            signal.signal(signum, previous)
        self._previous = {}
        self._swallowed = False
        self._unhook()

    def settle(self, program: bool) -> None:
        """End of the command: ignore the stop signals (``program``) or restore the handlers from
        before. A first signal landing meanwhile raises: then again, until it is done."""
        while True:
            try:
                self.ignore() if program else self.restore()
                return
            except KeyboardInterrupt:
                continue

    def status(self) -> int:
        """The exit status of a stopped command: 128 + the first signal's number (Ctrl-C: 130)."""
        return 128 + (self.signum or signal.SIGINT)

    def note(self) -> str:
        """How the command was stopped, for its one-line note."""
        if self.signum in (None, signal.SIGINT):
            return "interrupted"
        return f"interrupted by {signal.Signals(self.signum).name}"


def _inside_numba_or_llvmlite(frame) -> bool:
    """Whether a signal's handler runs inside numba's or llvmlite's Python code (or what it
    calls): ``_numba_unpickle``, the Python call numba's compiled code makes to box a kernel's
    array result (numba 0.68); numba's compiler and cache; llvmlite's LLVM objects. Not the wait
    for a kernel compiled by a child process (``kernel_compiler.WAITS``), though numba's cache
    called it: plain Python, where the stop is raised and the child killed."""
    while frame is not None:
        if frame.f_code in kernel_compiler.WAITS:
            return False
        name = frame.f_code.co_filename
        if _NUMBA_DIR in name or _LLVMLITE_DIR in name:
            return True
        frame = frame.f_back
    return False


_NUMBA_DIR = f"{os.sep}numba{os.sep}"
_LLVMLITE_DIR = f"{os.sep}llvmlite{os.sep}"
_stop: StopSignals | None = None


def stop_signal() -> int | None:
    """The stop signal (its number) the running ``ballchain`` command received, or None: for a
    command that ends a run itself on KeyboardInterrupt and wants to say which signal it was.
    If the command then returns ``INTERRUPTED`` (130), the exit status is 128 + that number."""
    return None if _stop is None else _stop.signum


def main(argv: list[str] | None = None) -> int:
    """Run ``ballchain`` with ``argv`` (default: the process's arguments) and return its exit status.

    Called as the program (``argv`` None), a stopped command flushes its output and ends the
    process with 128 + the signal's number at once, and after a finished command the stop
    signals are ignored: nothing left to run (interpreter shutdown, a library's exit hook) can
    turn the status into another one or die by a second signal.
    """
    global _stop
    program = argv is None
    argv = sys.argv[1:] if program else argv
    stop = _stop = StopSignals()
    try:
        stop.install()
        # As the program, a kernel's first compilation runs in a child process that a stop ends
        # (``kernel_compiler``); called from Python (a test), compilations stay in this process.
        with kernel_compiler.in_a_child() if program else contextlib.nullcontext():
            code = _run(argv, stop)
    except KeyboardInterrupt:  # a stop outside the command's own handling (as it starts or ends)
        code = stop.status()
    finally:
        stop.settle(program)
        _stop = None
    if program:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except BaseException:  # noqa: BLE001 - a closed pipe, or an interrupt a compiled call left set
                pass
        if stop.signum is not None:
            os._exit(code)  # nothing more runs: no exit hook nor shutdown step can change the status
    return code


def _run(argv: list[str], stop: StopSignals) -> int:
    parser, subparsers = build_parser()
    if not argv or argv[0] not in COMMANDS:
        parser.parse_args(argv)  # prints help or the error, and exits
        return 2
    if (refusal := address_space_refusal()) is not None:  # before the libraries load (they hang below it)
        print(f"ballchain {argv[0]}: error: {refusal}", file=sys.stderr)
        return 1
    try:
        # Load only the chosen subcommand's module, give its parser the arguments, then parse.
        module = importlib.import_module(f"ballchain.commands.{COMMANDS[argv[0]][0]}")
        module.add_arguments(subparsers[argv[0]])
        args = parser.parse_args(argv)
        from threadpoolctl import threadpool_limits

        from ballchain.optimization.statics import StaticsError
    except BaseException as err:  # a stop while the libraries load (pydrake wraps it): nothing was started
        if not caused_by_interrupt(err):
            raise
        print(f"ballchain {argv[0]}: {stop.note()}", file=sys.stderr)
        return stop.status()

    try:
        # Every matrix here is small (at most a few hundred rows): threaded BLAS only adds
        # synchronisation, and under load it makes solves several times slower.
        with threadpool_limits(limits=1, user_api="blas"):
            if os.environ.get(CACHE_ENV):  # a bad cache folder is said before any work
                check_cache_dir()
            code = int(module.main(args) or 0)
        # A command that ends its run itself on a stop and keeps its results (a sweep) says so
        # with INTERRUPTED; the status then names the signal. Any other status is the command's.
        return stop.status() if stop.signum is not None and code == INTERRUPTED else code
    except UserInputError as err:
        message = " ".join(str(err).split())  # one line, whatever the message holds
        print(f"ballchain {args.command}: error: {message}", file=sys.stderr)
        return 2
    except OutputError as err:
        print(f"ballchain {args.command}: error: {' '.join(str(err).split())}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"ballchain {args.command}: {stop.note()} (files already written are complete)", file=sys.stderr)
        return stop.status()
    except BrokenPipeError:  # the reader of stdout went away (``ballchain ... | head``): not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except StaticsError as err:
        print(f"ballchain {args.command}: {' '.join(str(err).split())}", file=sys.stderr)
        return 1
    except OSError as err:
        if err.errno not in (errno.ENOSPC, errno.EDQUOT):  # a full disk outside the result files (a cache)
            return _resource_limit(args.command, err)
        print(f"ballchain {args.command}: error: {err.strerror}: {err.filename or ''} (files already written "
              "are complete)", file=sys.stderr)
        return 1
    except Exception as err:
        if not caused_by_interrupt(err):  # a machine's limit met (one line, status 1), else a bug: the traceback
            return _resource_limit(args.command, err)
        print(f"ballchain {args.command}: {stop.note()} (files already written are complete)", file=sys.stderr)
        return stop.status()


def _resource_limit(command: str, err: BaseException) -> int:
    """Status 1 and one line when ``err`` comes from a limit of the machine (open files, processes,
    memory: ``resource_limits``); otherwise ``err`` is raised again (a bug: the traceback)."""
    message = limit_message(err)
    if message is None:
        raise err
    print(f"ballchain {command}: error: {' '.join(message.split())} (files already written are complete)",
          file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
