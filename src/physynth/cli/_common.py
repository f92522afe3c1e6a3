"""What every command shares: progress bars for the library's progress callbacks, one-line errors."""

from __future__ import annotations

import re
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

import typer
from typer.core import TyperCommand

from ..progress import ProgressCallback, no_progress

EXIT_BAD_INPUT = 2
"""Exit code of a user mistake: bad scenario, recording, dataset, argument or option."""
EXIT_SYSTEM = 1
"""Exit code of a failure of the machine (disk full, permission denied)."""
EXIT_INTERRUPTED = 130
"""Exit code after Ctrl-C (SIGINT); SIGTERM gives 143 and SIGHUP 129 (``128 + signal``)."""
EXIT_BUG = 3
"""Exit code of a bug in PhySynth (an exception that is not a user mistake nor the machine)."""
LOG_INTERVAL_S = 60.0
"""Without a terminal (a log file, a pipe, a batch job) a counted step that runs longer than this
prints its count at most once per interval [s], and its end, instead of drawing a bar."""


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
    bar: Progress | None = None  # started on the first counted call: nothing is drawn for a failed command
    started: dict[str, float] = {}  # without a terminal: when each counted step began
    logged: dict[str, float] = {}  # and when it was last written to the log

    def update(message: str, done: int | None = None, total: int | None = None) -> None:
        nonlocal bar
        if done is None:  # a log gets whole lines (rich would wrap them at 80 columns)
            console.print(f"  - {message}", highlight=False, soft_wrap=not console.is_terminal)
            return
        if not console.is_terminal:  # a log file or a pipe: no bar, a line now and then on long work
            _log_line(message, done, total)
            return
        if bar is None:
            bar = Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                           TimeElapsedColumn(), TimeRemainingColumn(), transient=True, console=console)
            bar.start()
        if message not in tasks:
            tasks[message] = bar.add_task(message, total=total)
        bar.update(tasks[message], completed=done, total=total)

    def _log_line(message: str, done: int, total: int | None) -> None:
        now = time.monotonic()
        began = started.setdefault(message, now)
        finished = total is not None and done >= total
        if not (now - logged.get(message, began) >= LOG_INTERVAL_S or (finished and message in logged)):
            return  # a step done within one interval leaves nothing in the log
        logged[message] = now
        count = f"{done}/{total} ({100.0 * done / total:.0f} %)" if total else f"{done}"
        console.print(f"  - {message}: {count} after {now - began:.0f} s", highlight=False, soft_wrap=True)

    try:
        yield update
    finally:
        if bar is not None:
            bar.stop()


@contextmanager
def status_lines(label: str) -> Iterator[Callable[[str], None]]:
    """A spinner on stderr showing the library's latest step (``progress(message)``) on a terminal.

    Without one (a log file, a pipe, a batch job) each step prints a line when it begins: the first message
    of a stage (the text before its first colon, e.g. ``SYNTH_PHY pre-train (synthetic)`` of ``...: epoch
    3/300``), then at most one per stage every :data:`LOG_INTERVAL_S`, so an hour of epochs leaves a
    readable log instead of nothing.
    """
    from rich.console import Console

    console = Console(stderr=True)
    if console.is_terminal:
        with console.status(label) as status:
            yield status.update
        return
    last: dict[str, float] = {}

    def update(message: str) -> None:
        stage, now = message.split(":", 1)[0], time.monotonic()
        if stage in last and now - last[stage] < LOG_INTERVAL_S:
            return
        last[stage] = now
        console.print(f"  - {message}", highlight=False, soft_wrap=True)  # whole lines, not cut at 80 columns

    yield update


class Command(TyperCommand):
    """Every physynth command (set by :func:`use_command_class`): its help lists an argument under its
    name alone (``DATASET...``), as the usage line does, without typer's ``<list[Path]>`` after it.

    Options show their own ``metavar`` (``--out DIR``, ``--seed SEED``): every valued option declares one,
    since what a value means (a folder, a file, a count) is not in its type."""

    def format_options(self, ctx, formatter) -> None:
        args, opts = [], []
        for param in self.get_params(ctx):
            record = param.get_help_record(ctx)
            if record is None:
                continue
            if param.param_type_name == "argument":
                name = param.metavar or (param.name or "").upper()
                args.append((name + ("..." if param.nargs != 1 else ""), record[1]))
            elif param.param_type_name == "option":
                opts.append(record)
        for title, rows in (("Arguments", args), ("Options", opts)):
            if rows:
                with formatter.section(title):
                    formatter.write_dl(rows)


def use_command_class(app: typer.Typer) -> None:
    """Make :class:`Command` the class of every command of ``app`` and of its groups, at any depth."""
    for info in app.registered_commands:
        if info.cls in (None, TyperCommand):  # typer's default; a command with a class of its own keeps it
            info.cls = Command
    for group in app.registered_groups:
        if group.typer_instance is not None:
            use_command_class(group.typer_instance)


def format_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A plain-text table: first column left-aligned, the others right-aligned, two spaces apart.

    Kept narrow on purpose: short headers and 4 significant digits fit 80 columns.
    """
    cells = [list(map(str, headers))] + [list(map(str, r)) for r in rows]
    widths = [max(len(r[j]) for r in cells) for j in range(len(headers))]

    def line(r: list[str]) -> str:
        return "  ".join(c.ljust(w) if j == 0 else c.rjust(w) for j, (c, w) in enumerate(zip(r, widths, strict=True)))

    rule = "  ".join("-" * w for w in widths)
    return "\n".join([line(cells[0]), rule, *(line(r) for r in cells[1:])])


def counted(n: int, word: str, plural: str | None = None) -> str:
    """``1 worker``, ``2 workers``: a count and its noun, in the plural (``plural``, else ``word`` + s)
    unless the count is 1."""
    return f"{n} {word}" if n == 1 else f"{n} {plural or word + 's'}"


_OPTION_NAMES = {"n_synth_traces": "--n-synth", "anchor_policy": "--anchor-layout"}
"""The library parameters whose option is not their name with dashes."""


def _option(name: str) -> str:
    """The command-line option that sets the library parameter ``name`` (``crop_to_uwb``: ``--crop-to-uwb``)."""
    return _OPTION_NAMES.get(name, "--" + name.replace("_", "-"))


def _named(*names: str) -> tuple[tuple[re.Pattern, str], ...]:
    """A parameter's name wherever it stands, and its option."""
    return tuple((re.compile(rf"\b{name}\b"), _option(name)) for name in names)


def _switched_on(*names: str) -> tuple[tuple[re.Pattern, str], ...]:
    """``name=True``, and the option that switches it on."""
    return tuple((re.compile(rf"\b{name}=True\b"), _option(name)) for name in names)


def _valued(*names_values: tuple[str, str]) -> tuple[tuple[re.Pattern, str], ...]:
    """``name='value'`` (value: a regular expression), and the option followed by the value."""
    return tuple((re.compile(rf"\b{name}='({value})'"), _option(name) + r" \1") for name, value in names_values)


PARAMETER_FLAGS = (
    (re.compile(r"\brange_bias='static'"), "--range-bias static"),
    *_named("layout_from", "static_sweeps"),
    *_switched_on("link_budget", "long_outages", "tag_pattern", "run_slopes", "trusted_truth"),
    *_valued(("path_kind", r"[\w-]+"), ("anchor_policy", r"[\w-]+"), ("range_bias_law", r"\w+")),
    *_named("range_bias_law", "crop_to_uwb", "n_synth_traces", "pretrain_epochs", "finetune_epochs",
            "finetune_synth_ratio", "lr_schedule", "ekf_prior", "weight_average"),
    (re.compile(r"\bfigures=False\b"), "--no-figures"),
    (re.compile(r"\bphysynth\.data\.fetch\('([\w-]+)'\)"), r"physynth data fetch \1"),
    *_named("base_url"),
)
"""Library parameter names (which the library's errors and notes name) and the options that set them."""


def cli_words(message: str) -> str:
    """``message`` with the library's parameter names replaced by the command-line options that set them."""
    for pattern, flag in PARAMETER_FLAGS:
        message = pattern.sub(flag, message)
    return message


def check_run_options(resume: bool, overwrite: bool, scheduler: str | None, workers: int, unfinished: str) -> None:
    """Refuse ``--resume`` with ``--overwrite`` and ``--scheduler`` with ``--workers`` (``unfinished``: what
    --resume completes, e.g. ``run of --out``)."""
    from ..errors import PhySynthError

    if resume and overwrite:
        raise PhySynthError(f"--resume and --overwrite exclude each other: --resume completes an unfinished "
                            f"{unfinished}, --overwrite discards it; give one")
    if scheduler is not None and workers:
        raise PhySynthError(f"--scheduler and --workers exclude each other: --scheduler runs on the workers of "
                            f"an existing cluster, --workers {workers} starts its own; give one")


def fail(message: str, code: int = EXIT_BAD_INPUT) -> None:
    """Print the first line of ``message`` as ``physynth: error: ...`` on stderr and exit."""
    fail_each([message], code)


def fail_each(messages: Sequence[str], code: int = EXIT_BAD_INPUT) -> None:
    """Print the first line of each message as its own ``physynth: error: ...`` line on stderr and exit."""
    for message in messages or ["invalid input"]:
        first = message.strip().splitlines()[0] if message.strip() else "invalid input"
        print(f"physynth: error: {cli_words(first)}", file=sys.stderr)
    sys.exit(code)


@contextmanager
def resumable(resume_hint: str) -> Iterator[None]:
    """Around a resumable run (generate, export): the library's "resume it or overwrite" said with the
    flags, and an interruption's line ends with ``resume_hint`` (how to finish the run)."""
    from ..errors import Interrupted, PhySynthError

    try:
        yield
    except PhySynthError as exc:
        hint = "; resume it or overwrite to start over"
        if hint in str(exc):
            raise PhySynthError(str(exc).replace(hint, "; add --resume to complete it or --overwrite to start "
                                                 "over")) from None
        raise
    except Interrupted as exc:  # physynth.cli.main prints one line and exits 128 + signal
        exc.note = resume_hint
        raise
    except KeyboardInterrupt:
        typer.echo(f"physynth: interrupted; {resume_hint}", err=True)
        raise typer.Exit(130) from None
