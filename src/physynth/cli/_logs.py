"""What the libraries underneath say, kept off stderr: PhySynth's own lines are the only ones there.

dask/distributed, tornado, asyncio, torch, matplotlib and pyarrow speak through :mod:`logging`, through
:mod:`warnings`, and through the tracebacks of exceptions in threads they start
(:func:`threading.excepthook`) or in finalisers (:func:`sys.unraisablehook`). On the command line all of
it goes to the file named by the environment variable ``PHYSYNTH_LOG`` (appended; created only when
something is said), or nowhere; what matters to the user reaches them as PhySynth's own one line (an
error raised to :func:`physynth.cli.main`, a :class:`~physynth.errors.PhySynthWarning`). The worker
processes' own output goes to the same file (:mod:`physynth._children`).

:func:`capture_library_logs` is installed once per process and stays for its life: the libraries log
while the interpreter shuts down too (Dask closes its clusters at exit).
"""

from __future__ import annotations

import logging
import sys
import threading
import traceback

from .._children import log_path

LIBRARY_LOGGERS = ("distributed", "dask", "tornado", "asyncio", "bokeh", "torch", "matplotlib", "pyarrow",
                   "fsspec", "numexpr", "h5py", "py.warnings")
"""Loggers that may have been given a handler of their own on stderr before the capture was installed
(Dask's, when ``distributed`` was imported first): their records are sent to the capture instead."""

_MARK = "_physynth_capture"


def _handler() -> logging.Handler:
    path = log_path()
    if path is None:
        return logging.NullHandler()
    h = logging.FileHandler(path, delay=True, encoding="utf-8")
    h.setLevel(logging.INFO)
    h.setFormatter(logging.Formatter("%(asctime)s %(process)d %(name)s %(levelname)s: %(message)s"))
    return h


def library_log() -> logging.Logger:
    """The logger PhySynth's command line writes what it keeps from the libraries to."""
    return logging.getLogger("physynth.library")


def capture_library_logs() -> None:
    """Send every log record, foreign warning and thread or finaliser traceback to ``PHYSYNTH_LOG`` or nowhere."""
    root = logging.getLogger()
    if any(getattr(h, _MARK, False) for h in root.handlers):
        return
    handler = _handler()
    setattr(handler, _MARK, True)
    root.addHandler(handler)  # a root handler also keeps Dask from adding its own on stderr when imported
    for name in LIBRARY_LOGGERS:
        lg = logging.getLogger(name)
        for h in list(lg.handlers):
            if isinstance(h, logging.StreamHandler) and not isinstance(h, logging.FileHandler):
                lg.removeHandler(h)
        lg.propagate = True

    def excepthook(args: threading.ExceptHookArgs) -> None:
        if args.exc_type is SystemExit:
            return
        text = "".join(traceback.format_exception(args.exc_type, args.exc_value, args.exc_traceback))
        library_log().error("exception in thread %s:\n%s", getattr(args.thread, "name", "?"), text.rstrip())

    def unraisablehook(u: object) -> None:
        exc = getattr(u, "exc_value", None)
        text = "".join(traceback.format_exception(exc)) if exc is not None else ""
        library_log().error("exception ignored in %r: %s", getattr(u, "object", None), text.rstrip())

    threading.excepthook = excepthook
    sys.unraisablehook = unraisablehook


def log_warning(message: object, category: type[Warning], filename: str, lineno: int) -> None:
    """A warning of a library (not PhySynth's own): to the log, not to stderr."""
    logging.getLogger("py.warnings").warning("%s:%d: %s: %s", filename, lineno, category.__name__, message)
