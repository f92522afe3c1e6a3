"""Exceptions for user mistakes: the command line turns them into one line and exit code 2."""


class PhySynthError(Exception):
    """Bad input from the user (a scenario, a recording, a dataset, an argument).

    The message is one line that names what is wrong; no traceback is shown for it.
    """


class ArgumentError(PhySynthError, ValueError):
    """A function was called with an argument of the wrong type or outside its range (a float seed, a
    negative trace index, a grid rate of 0 Hz, no traces). Also a ``ValueError``, as such mistakes were
    before they were checked at the call."""


class ScenarioError(PhySynthError):
    """A scenario file or object is invalid."""


class DatasetError(PhySynthError):
    """A dataset directory is missing, incomplete or unreadable."""


class RecordingError(PhySynthError):
    """A real recording cannot be imported."""


class AnchorMismatchError(PhySynthError):
    """Two inputs that must share their anchors (real and synthetic traces) do not."""


class OutputExistsError(PhySynthError):
    """An output (dataset, report, file) exists and the caller did not ask to replace it.

    ``path`` names it; the command line adds how to replace it.
    """

    def __init__(self, path: object, what: str = "") -> None:
        self.path = path
        super().__init__(f"{path} already {what or 'exists'}")


class UnsafeOutputError(PhySynthError):
    """An output that PhySynth may not write or replace: a folder it did not write, an input of the
    same command, the current folder, or two arguments naming the same file."""


class OutputLockedError(PhySynthError):
    """Another PhySynth process is writing the same output (its lock file is held)."""


class BudgetError(PhySynthError):
    """A scenario whose size (samples, memory, disk) exceeds the documented budget; the command
    line adds how to go ahead anyway."""


class IntegrityError(DatasetError):
    """A dataset file disagrees with the row counts or checksums recorded in its ``dataset.json``."""


class PhySynthWarning(UserWarning):
    """Something PhySynth did on the user's behalf that they should know about (e.g. it removed the
    temporary folder of an interrupted run); the command line prints it as one line."""


class Interrupted(BaseException):  # noqa: N818 - like KeyboardInterrupt
    """A termination signal (SIGINT, SIGTERM, SIGHUP) received by the command line.

    A ``BaseException``, so that ``except Exception`` does not swallow it and every ``with`` block
    cleans up on the way out. ``signum`` is the signal number (exit code ``128 + signum``).
    """

    def __init__(self, signum: int, note: str = "") -> None:
        self.signum = signum
        self.note = note  # what was kept (e.g. complete shards for --resume); default: nothing
        super().__init__(signum)


class MixedSitesError(PhySynthError):
    """Datasets given to be pooled are not of the same kind of site; the command line adds how to pool
    them anyway."""
