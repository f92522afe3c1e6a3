"""What every command shares: progress bars for the library's progress callbacks, one-line errors."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

from ..progress import ProgressCallback, no_progress

EXIT_BAD_INPUT = 2
"""Exit code of a user mistake: bad scenario, recording, dataset, argument or option."""
EXIT_SYSTEM = 1
"""Exit code of a failure of the machine (disk full, permission denied)."""
EXIT_INTERRUPTED = 130
"""Exit code after Ctrl-C (SIGINT); SIGTERM gives 143 and SIGHUP 129 (``128 + signal``)."""
EXIT_BUG = 3
"""Exit code of a bug in PhySynth (an exception that is not a user mistake nor the machine)."""


@contextmanager
def progress_bar(enabled: bool = True) -> Iterator[ProgressCallback]:
    """A rich progress bar on stderr driven by the library's ``progress(message, done, total)`` calls.

    Calls with a count advance a bar per message; calls without a count print the step as a line.
    """
    if not enabled:
        yield no_progress
        return
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn, TimeRemainingColumn

    console = Console(stderr=True)
    tasks: dict[str, int] = {}
    with Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), TimeRemainingColumn(), transient=True, console=console) as bar:
        def update(message: str, done: int | None = None, total: int | None = None) -> None:
            if done is None:
                bar.console.print(f"  - {message}", highlight=False)
                return
            if message not in tasks:
                tasks[message] = bar.add_task(message, total=total)
            bar.update(tasks[message], completed=done, total=total)

        yield update


def fail(message: str, code: int = EXIT_BAD_INPUT) -> None:
    """Print the first line of ``message`` as ``physynth: error: ...`` on stderr and exit."""
    first = message.strip().splitlines()[0] if message.strip() else "invalid input"
    print(f"physynth: error: {first}", file=sys.stderr)
    sys.exit(code)
