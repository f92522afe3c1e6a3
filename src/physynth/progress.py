"""The progress callback every long library call takes (the library itself never draws anything).

``progress(message, done, total)``: ``message`` names the step, ``done`` counts finished units of work
(traces) and ``total`` is their number when known. Steps without a count pass only the message. The
command line turns these calls into progress bars; Python users may pass any callable or nothing.
"""

from __future__ import annotations

from typing import Protocol


class ProgressCallback(Protocol):
    def __call__(self, message: str, done: int | None = None, total: int | None = None) -> None: ...


def no_progress(message: str, done: int | None = None, total: int | None = None) -> None:
    """The default callback: report nothing."""
