"""The kernels' compilation in a child process, so that a stop ends it within moments.

numba compiles a kernel on its first call with new argument types, when its on-disk cache holds
no compiled code for them: on a machine's first run the chain kernels take a few CPU-minutes,
most of it inside LLVM, where a signal's handler cannot run, in numba's Python code, where the
``ballchain`` command does not raise a stop (``cli.StopSignals``: a raise there crashed the
process). A SIGTERM sent then was answered only minutes later.

So while a ``ballchain`` command runs (``in_a_child()``), each compilation that the cache cannot
answer is done by a child process (``python -m ballchain.infrastructure.kernel_compiler``): the
command sends it the kernel and the argument types, the child compiles them into numba's cache,
and the command waits in plain Python (``WAITS``: a stop is raised there, and the child is
killed), then loads the kernel from the cache as every later run does. The child compiles
nothing unless it finds the same kernel (file, cache folder, source stamp, numba's cache key)
as the command; whatever it cannot do (a kernel defined at run time, a cache the child sees
elsewhere, a child that cannot start or that dies twice) is compiled in the command's process,
as before. A warm cache runs none of this: numba loads the kernel, nothing else happens.

Before the first compilation one line on stderr says what is compiled and about how long it
takes. The child compiles under an exclusive lock on ``ballchain-compile.lock`` in the cache
folder (``fcntl.flock``, with the command's pid in the file): a second command started on the
same empty cache says in one line that it waits for that process, then loads what it compiled.

Only the standard library is imported here: the command line imports this module at start.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import select
import struct
import sys
import threading
import time

LOCK_NAME = "ballchain-compile.lock"
QUIET_WAIT_S = 1.0  # another process's lock held this long: the command says it waits for it
COMPILING_NOTE = ("ballchain: compiling the chain kernels once for this machine (about 1-3 CPU-minutes in all; "
                  "later runs load them from {where})")
WAITING_NOTE = ("ballchain: process {pid} is compiling the chain kernels into {where}; waiting for it, "
                "then loading them")

_HEADER = struct.Struct(">Q")
_server: _Child | None = None
_server_lock = threading.Lock()
_said: set[str] = set()  # the kinds of note ("compiling", "wait") already printed by this process


@contextlib.contextmanager
def in_a_child():
    """While inside: compilations that numba's cache cannot answer are done by a child process
    that a stop can end (the ``ballchain`` command runs each command inside this). The child is
    ended on the way out."""
    global _server
    if _server is not None or not _supported():
        yield
        return
    _server = _Child()
    try:
        yield
    finally:
        server, _server = _server, None
        server.close()


def compiled_elsewhere(dispatcher, sig, target_context) -> bool:
    """Compile ``dispatcher`` for ``sig`` into numba's on-disk cache in the child process; True
    when the child did (or found it there), and the caller can load it from the cache; False
    when it could not (compile here instead). Raises the stop (KeyboardInterrupt) that ends the
    wait; the child is then killed."""
    server = _server
    if server is None:
        return False
    request = _request(dispatcher, sig, target_context)
    with _server_lock:
        if request is not None and server.compile(request):
            return True
    # Compiled in this process after all (no child could start, or it could not find the kernel).
    _say("compiling", COMPILING_NOTE.format(where=_where(dispatcher._cache._cache_path)))
    return False


def _supported() -> bool:
    if os.name != "posix" or not sys.executable or os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return False
    try:
        import fcntl  # noqa: F401
    except ImportError:  # pragma: no cover - not POSIX
        return False
    return True


def _request(dispatcher, sig, target_context) -> bytes | None:
    """What the child needs to find the same kernel and check that it is the same (pickled)."""
    try:
        from numba.core.serialize import dumps

        cache = dispatcher._cache
        py_func = dispatcher.py_func
        key = cache._index_key(sig, target_context.codegen())
        if "<locals>" in py_func.__qualname__:
            return None
        return pickle.dumps({
            "module": py_func.__module__, "qualname": py_func.__qualname__,
            "file": py_func.__code__.co_filename, "line": py_func.__code__.co_firstlineno,
            "cache_path": cache._cache_path, "stamp": cache._cache_file._source_stamp,
            "sig": dumps(sig), "key": dumps(key)})
    except Exception:  # noqa: BLE001 - argument types numba cannot pickle, a cache of another kind
        return None


def _say(kind: str, note: str) -> None:
    if kind in _said:
        return
    _said.add(kind)
    try:
        print(note, file=sys.stderr, flush=True)
    except (OSError, ValueError):  # stderr closed
        pass


class _Child:
    """The compiling child: requests (length-prefixed pickles) on its stdin, one line per answer
    on a pipe of its own ("compiling", "wait PID", then "ok" or "fail REASON")."""

    def __init__(self):
        self._proc = None  # subprocess.Popen
        self._replies: int | None = None
        self._buffer = b""
        self._closed = False

    def _start(self) -> None:
        if self._closed:  # the command is ending (a thread still compiling): compile there
            raise OSError("the compiling child was closed")
        import subprocess  # here: the command line imports this module at start

        read, write = os.pipe()
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "ballchain.infrastructure.kernel_compiler", str(write)],
                stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, pass_fds=(write,), close_fds=True)
        except BaseException:
            os.close(read)
            raise
        finally:
            os.close(write)
        self._replies, self._buffer = read, b""

    def compile(self, request: bytes) -> bool:
        try:
            for _ in range(2):  # a child that died (a kill meant for it alone) is started once more
                if self._proc is None:
                    self._start()
                try:
                    self._proc.stdin.write(_HEADER.pack(len(request)) + request)
                    self._proc.stdin.flush()
                except OSError:  # the child died
                    self._reap()
                    continue
                while True:
                    line = self._next_line()
                    if line is None:
                        self._reap()
                        break
                    word, _, rest = line.partition(" ")
                    if word == "compiling":
                        _say(word, COMPILING_NOTE.format(where=rest))
                    elif word == "wait":
                        pid, _, where = rest.partition(" ")
                        _say(word, WAITING_NOTE.format(pid=pid or "?", where=where))
                    else:
                        return word == "ok"
            return False
        except (OSError, ValueError):  # no child could be started (a process or file limit): compile here
            self._reap()
            return False
        except BaseException:  # a stop while waiting: the child goes with it
            self.close()
            raise

    def _next_line(self) -> str | None:
        """The child's next line, or None when it ended: waits in Python, where a stop can be raised."""
        while b"\n" not in self._buffer:
            ready, _, _ = select.select([self._replies], [], [], 1.0)
            if ready:
                chunk = os.read(self._replies, 65536)
                if not chunk:
                    return None
                self._buffer += chunk
        line, _, self._buffer = self._buffer.partition(b"\n")
        return line.decode(errors="replace")

    def _reap(self) -> None:
        proc, replies = self._proc, self._replies
        self._proc = self._replies = None
        if replies is not None:
            os.close(replies)
        if proc is not None:
            with contextlib.suppress(OSError):
                proc.stdin.close()
            proc.kill()
            proc.wait()

    def close(self) -> None:
        """Kill the child (idle between requests, or compiling for a command that stopped)."""
        self._closed = True
        self._reap()


# Where the ``ballchain`` command's stop handler may raise although numba's code called it: the
# wait for the child (``cli._inside_numba_or_llvmlite``).
WAITS = frozenset({_Child._next_line.__code__})


# ------------------------------------------------------------------ the child

def _die_with_parent() -> None:
    """Linux: SIGKILL this process when its parent dies (a SIGKILL of the command ends both)."""
    with contextlib.suppress(Exception):
        import ctypes
        import signal

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG


def _find(request: dict):
    """The dispatcher the request names, in this process (imported), or LookupError."""
    import importlib

    module = importlib.import_module(request["module"])
    candidates = [module]
    for part in request["qualname"].split("."):
        candidates = [getattr(candidates[-1], part, None)]
    candidates += list(vars(module).values())
    for value in candidates:
        py_func = getattr(value, "py_func", None)
        code = getattr(py_func, "__code__", None)
        if (code is not None and hasattr(value, "_cache") and py_func.__qualname__ == request["qualname"]
                and code.co_filename == request["file"] and code.co_firstlineno == request["line"]):
            return value
    raise LookupError(f"{request['module']}.{request['qualname']} is not a kernel here")


def _where(cache_path: str) -> str:
    """numba's cache, as a user finds it: ``$NUMBA_CACHE_DIR``, the ``__pycache__`` folders beside
    the kernels' files, or numba's user-wide folder (the sources' folders not writable)."""
    import numba

    if numba.config.CACHE_DIR:
        return numba.config.CACHE_DIR
    if os.path.basename(cache_path) == "__pycache__":
        return "the __pycache__ folders beside their sources"
    return os.path.dirname(cache_path)


@contextlib.contextmanager
def _compile_lock(directory: str, where: str, tell):
    """An exclusive lock on the cache folder's lock file while compiling; ``tell("wait PID WHERE")``
    when another process holds it for longer than QUIET_WAIT_S."""
    import fcntl

    try:
        os.makedirs(directory, exist_ok=True)
        fd = os.open(os.path.join(directory, LOCK_NAME), os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:  # nowhere to lock: compile unlocked, as numba alone does
        yield
        return
    try:
        deadline = time.monotonic() + QUIET_WAIT_S
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    owner = os.pread(fd, 32, 0).decode(errors="replace").split()
                    tell(f"wait {owner[0] if owner else '?'} {where}")
                    fcntl.flock(fd, fcntl.LOCK_EX)
                    break
                time.sleep(0.05)
            except OSError:  # a file system without locks
                break
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getppid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock


def _compile(request: dict, tell) -> str:
    import numba

    dispatcher = _find(request)
    cache = dispatcher._cache
    if cache._cache_path != request["cache_path"] or cache._cache_file._source_stamp != request["stamp"]:
        return "fail another cache or source here"
    sig = pickle.loads(request["sig"])
    key = cache._index_key(sig, dispatcher.targetctx.codegen())
    if key != pickle.loads(request["key"]):
        return "fail another cache key here"
    where = _where(cache._cache_path)
    with _compile_lock(numba.config.CACHE_DIR or cache._cache_path, where, tell):
        if key not in cache._cache_file._load_index():  # else another process compiled it: loaded
            tell(f"compiling {where}")
        dispatcher.compile(sig)
    return "ok"


def serve(reply_fd: int) -> None:
    """The child: compile each request into numba's cache until stdin ends."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the terminal's process group: the parent kills us
    _die_with_parent()
    replies = os.fdopen(reply_fd, "w", buffering=1)

    def tell(line: str) -> None:
        replies.write(" ".join(line.split()) + "\n")

    stdin = sys.stdin.buffer
    with contextlib.suppress(OSError):  # the command went away (its pipes closed): end quietly
        while True:
            head = stdin.read(_HEADER.size)
            if len(head) < _HEADER.size:
                return
            body = stdin.read(_HEADER.unpack(head)[0])
            try:
                answer = _compile(pickle.loads(body), tell)
            except Exception as err:  # noqa: BLE001 - the command compiles it itself, and shows any error
                answer = f"fail {type(err).__name__}: {err}"
            tell(answer)


if __name__ == "__main__":
    serve(int(sys.argv[1]))
