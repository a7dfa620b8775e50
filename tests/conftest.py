"""Test-session set-up shared by every test file."""

import signal

import pytest

# A shell without job control starts a background command with SIGINT ignored (POSIX), and an
# ignored signal is inherited by every process the tests start. The commands keep a signal that was
# ignored when they started ignored (as after ``nohup``), so the Ctrl-C tests need SIGINT to be
# delivered as from a terminal: the test process's default handler, which a child gets back on exec.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


# The procedural atrium and its signed-distance grid, built once per session and shared by every
# test in the default heart (each LeftAtrium() is about half a second of mesh generation; no test
# changes it).
@pytest.fixture(scope="session")
def heart():
    from ballchain.drake_models.heart import LeftAtrium

    return LeftAtrium()


@pytest.fixture(scope="session")
def sdf(heart):
    from ballchain.drake_models.atrium_sdf import atrium_sdf

    return atrium_sdf(heart)
