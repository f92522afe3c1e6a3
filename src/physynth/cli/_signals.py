"""Termination signals and PhySynth warnings while a command runs.

:func:`handling_signals` turns SIGINT, SIGTERM and SIGHUP into :class:`~physynth.errors.Interrupted`
(a ``BaseException``), so every writer's ``with`` block removes its temporary files and releases its
lock on the way out; :func:`physynth.cli.main` then prints one line and exits ``128 + signal``. A
second signal during that clean-up, or a clean-up that takes longer than :data:`GRACE_S` (the
exception can be swallowed when the signal lands inside a finaliser; writers also check a flag at
every trace), removes the registered temporary files and exits at once (the next run on the same
output removes anything left, :mod:`physynth.io.safety`). :class:`~physynth.errors.PhySynthWarning`
is printed as one line; numpy's ``RuntimeWarning`` notes (divide by zero, overflow) are not shown to command-line users,
and the other libraries' warnings go to their log (:mod:`physynth.cli._logs`).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import warnings
from collections.abc import Iterator
from contextlib import contextmanager

from ..errors import Interrupted, PhySynthWarning
from ..io.safety import clear_interrupted, remove_registered, set_interrupted
from ._logs import log_warning

SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))


@contextmanager
def handling_signals() -> Iterator[None]:
    """Within the block, SIGINT/SIGTERM/SIGHUP raise Interrupted; PhySynthWarning prints one line."""
    received: list[int] = []
    finished = threading.Event()

    def handler(signum: int, frame: object) -> None:
        if received:  # a second signal while cleaning up: leave now
            _hard_exit(signum)
        received.append(signum)
        set_interrupted(signum)  # writers re-raise at their next trace if this raise is swallowed
        threading.Thread(target=_watchdog, args=(signum, finished), daemon=True).start()
        raise Interrupted(signum)

    previous = {}
    if threading.current_thread() is threading.main_thread():
        for s in SIGNALS:
            previous[s] = signal.signal(s, handler)
    show = warnings.showwarning

    def showwarning(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001
        if issubclass(category, PhySynthWarning):
            from ._common import cli_words

            print(f"physynth: warning: {cli_words(str(message).splitlines()[0])}", file=sys.stderr)
        else:  # a library's warning (torch, matplotlib, ...): to the log, not to stderr (physynth.cli._logs)
            log_warning(message, category, filename, lineno)

    warnings.showwarning = showwarning
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", PhySynthWarning)
            warnings.simplefilter("ignore", RuntimeWarning)  # numpy's divide/overflow notes: not for users
            warnings.showwarning = showwarning
            yield
    finally:
        finished.set()
        clear_interrupted()
        warnings.showwarning = show
        for s, h in previous.items():
            signal.signal(s, h)


GRACE_S = 30.0
"""Seconds a command has to clean up after a signal before it is ended by force (its temporary files
removed first)."""


def _hard_exit(signum: int) -> None:
    remove_registered()
    print(f"physynth: interrupted by {signal_name(signum)}; incomplete output removed", file=sys.stderr, flush=True)
    os._exit(128 + signum)


def _watchdog(signum: int, finished: threading.Event) -> None:
    """Last resort: the signal's exception was swallowed (it landed in a finaliser) and no writer noticed."""
    if not finished.wait(GRACE_S):
        _hard_exit(signum)


def signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"
