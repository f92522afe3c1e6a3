"""Processes PhySynth starts (Dask's workers, the studies' pools) kept apart from the terminal and stderr.

A terminal's Ctrl-C (and its hangup) reaches every process of the foreground process group. Worker
processes that receive it print tracebacks of their own, and die under the pool that is closing them,
whose libraries then log about it; the process that started them must instead receive the signal
alone and close them. So within :func:`apart` every process started through :mod:`multiprocessing`
(``spawn`` and ``forkserver`` start a new interpreter; ``fork`` copies this one):

- runs in a session of its own (``setsid``): a terminal's signals do not reach it;
- writes its stdout and stderr to the file named by the environment variable :data:`LOG_ENV`
  (appended), or to nowhere: no library's log or traceback of a worker reaches the user's terminal;
- after ``fork``, has the default action for SIGINT, SIGTERM and SIGHUP (not the copy of this
  process's handlers): a worker that is told to stop, stops.

A worker does not outlive the process that started it even when that one is killed: Dask's workers
and the pools' processes exit when their parent's end of a pipe closes. Nothing changes outside the
block; blocks nest and may be entered from any thread.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator

LOG_ENV = "PHYSYNTH_LOG"
"""Environment variable naming a file that receives the worker processes' output and the log records of
the libraries underneath (:mod:`physynth.cli` adds those); without it both are discarded."""

TERMINAL_SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))

_lock = threading.Lock()
_depth = 0
_saved_spawn = None
_fork_hook = False


def log_path() -> str | None:
    """The file named by :data:`LOG_ENV`, or None."""
    return os.environ.get(LOG_ENV, "").strip() or None


def output_fd() -> int:
    """A new descriptor where a worker's output goes: the log file (appended) or the null device."""
    path = log_path()
    if path:
        try:
            return os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        except OSError:
            pass  # an unwritable log is no reason to fail the work: the output is discarded
    return os.open(os.devnull, os.O_WRONLY)


def _spawn_apart(path: str, args: list[str], passfds: object) -> int:
    """:func:`multiprocessing.util.spawnv_passfds` in a new session, stdout and stderr to :func:`output_fd`."""
    fds = sorted({int(f) for f in passfds})  # type: ignore[attr-defined]
    out = output_fd()
    actions = [(os.POSIX_SPAWN_DUP2, out, 1), (os.POSIX_SPAWN_DUP2, out, 2)]
    with _lock:  # the passed descriptors are inheritable only while this one child is started
        was = [os.get_inheritable(f) for f in fds]
        try:
            for f in fds:
                os.set_inheritable(f, True)
            try:
                return os.posix_spawn(path, list(args), dict(os.environ), file_actions=actions, setsid=True)
            except NotImplementedError:  # no POSIX_SPAWN_SETSID in this C library: a process group of its own
                return os.posix_spawn(path, list(args), dict(os.environ), file_actions=actions, setpgroup=0)
        finally:
            for f, w in zip(fds, was, strict=True):
                os.set_inheritable(f, w)
            os.close(out)


def _after_fork_in_child() -> None:
    if _depth <= 0:
        return
    with contextlib.suppress(OSError):
        os.setsid()
    out = output_fd()
    os.dup2(out, 1)
    os.dup2(out, 2)
    os.close(out)
    for s in TERMINAL_SIGNALS:
        signal.signal(s, signal.SIG_DFL)


@contextlib.contextmanager
def apart() -> Iterator[None]:
    """Within the block, processes started through :mod:`multiprocessing` are kept apart (module docstring)."""
    global _depth, _saved_spawn, _fork_hook
    import multiprocessing.util as mpu

    with _lock:
        if _depth == 0:
            _saved_spawn = mpu.spawnv_passfds
            mpu.spawnv_passfds = _spawn_apart
        if not _fork_hook and hasattr(os, "register_at_fork"):
            os.register_at_fork(after_in_child=_after_fork_in_child)  # inert outside the block
            _fork_hook = True
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                mpu.spawnv_passfds = _saved_spawn
