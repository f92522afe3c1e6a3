"""Exceptions for user mistakes: the command line turns them into one line and exit code 2."""


class PhySynthError(Exception):
    """Bad input from the user (a scenario, a recording, a dataset, an argument).

    The message is one line that names what is wrong; no traceback is shown for it.
    """


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
