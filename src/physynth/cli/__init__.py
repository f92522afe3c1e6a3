"""The ``physynth`` command line: thin commands over :mod:`physynth.workflows` and the library.

Every command module has a ``register(app)`` function; :func:`register_commands` (which :func:`main` calls)
registers them all. The library
raises errors that speak of parameters and reports progress through a callback; only this package
draws progress bars, names options and chooses exit codes:

- 0: success (also the help that ``physynth`` and every command group print when given no arguments);
- 1: the machine failed (disk full, permission denied): one line on stderr;
- 2: a user mistake (``PhySynthError``, a bad option or argument), an output that may not be
  replaced, an output locked by another run, a size over budget: one line on stderr;
- 3: a bug in PhySynth: one line on stderr (``PHYSYNTH_DEBUG=1`` shows the traceback);
- 129, 130, 143: interrupted by SIGHUP, SIGINT (Ctrl-C), SIGTERM (``128 + signal``); temporary
  files are removed and nothing that looks complete is left.

No traceback reaches the user, and nothing but PhySynth's own lines reaches stderr: the libraries'
logs and the worker processes' output go to ``PHYSYNTH_LOG`` or nowhere (:mod:`physynth.cli._logs`,
:mod:`physynth._children`; docs/reliability.md). Heavy imports happen inside the commands.
"""

from __future__ import annotations

import os
import signal
import sys


def _interrupted_before_main(signum: int, frame: object) -> None:
    """A signal while the command line is still being imported: nothing was written; one line, 128 + signal."""
    os.write(2, f"physynth: interrupted by {signal.Signals(signum).name}; nothing was written\n".encode())
    os._exit(128 + signum)


# Run as the program (`physynth ...`, `python -m physynth.cli`): a Ctrl-C while the imports run is one line
# too, not a KeyboardInterrupt traceback; main() puts its own handlers in place (physynth.cli._signals).
if os.path.basename(sys.argv[0]) in ("physynth", "-m") and __name__ == "physynth.cli":
    for _s in ("SIGINT", "SIGTERM", "SIGHUP"):
        if hasattr(signal, _s) and signal.getsignal(getattr(signal, _s)) is not signal.SIG_IGN:
            signal.signal(getattr(signal, _s), _interrupted_before_main)

# One BLAS thread per process unless the user says otherwise (set before NumPy loads OpenBLAS): the
# parallelism is the workers' (Dask's worker processes get the same from their nanny), so a run with
# --workers 1 computes as one worker does and `bench`'s one-core rates use one core (docs/scale.md).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import typer  # noqa: E402

from .._children import apart  # noqa: E402
from ..errors import BudgetError, Interrupted, MixedSitesError, OutputExistsError, PhySynthError  # noqa: E402
from ._common import EXIT_BUG, EXIT_INTERRUPTED, EXIT_SYSTEM, fail, use_command_class  # noqa: E402
from ._logs import capture_library_logs  # noqa: E402
from ._signals import handling_signals, signal_name  # noqa: E402

app = typer.Typer(
    name="physynth",
    help="Physics-based synthetic UWB + IMU + availability + AoI traces, calibrated on real recordings.",
    add_completion=True,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    context_settings={"help_option_names": ["-h", "--help"]},  # inherited by every command and group
)

_registered = False


def _version(value: bool) -> None:
    if value:
        from .. import __version__

        print(f"physynth {__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(version: bool = typer.Option(False, "--version", is_eager=True, callback=_version,
                                       help="Print the version and exit.")) -> None:
    """Physics-based synthetic UWB + IMU + availability + AoI traces, calibrated on real recordings.

    Documentation: the README and docs/ folder shipped with PhySynth.
    """


def register_commands() -> None:
    """Add every command to :data:`app` (each command module through the same ``register(app)``); once per
    process, before the app runs or its command tree is read."""
    global _registered
    if _registered:
        return
    from . import bench, calibrate, data, export, generate, imports, study, validate, verify

    for module in (generate, imports, calibrate, validate, study, export, bench, verify, data):
        module.register(app)
    use_command_class(app)
    _registered = True


def main(argv: list[str] | None = None) -> None:
    """Entry point: run the app, turning user mistakes into one line on stderr and exit code 2."""
    register_commands()
    capture_library_logs()  # the libraries' logs, warnings and thread tracebacks: not on stderr
    argv = sys.argv[1:] if argv is None else argv
    try:
        with handling_signals(), apart():  # worker processes: apart from the terminal's signals and stderr
            rc = app(args=argv, standalone_mode=False)
        if isinstance(rc, int) and rc != 0:  # typer returns 130 for a KeyboardInterrupt it caught
            print("physynth: interrupted" if rc == EXIT_INTERRUPTED else f"physynth: exit {rc}", file=sys.stderr)
            sys.exit(rc)
    except Interrupted as exc:
        kept = exc.note or "incomplete output removed"
        print(f"physynth: interrupted by {signal_name(exc.signum)}; {kept}", file=sys.stderr)
        sys.exit(128 + exc.signum)
    except OutputExistsError as exc:
        fail(f"{exc} (use --overwrite to replace it)")
    except BudgetError as exc:
        fail(f"{exc} (use --force to go ahead anyway)")
    except MixedSitesError as exc:
        fail(f"{exc} (use --allow-mixed to pool them anyway)")
    except PhySynthError as exc:
        fail(str(exc))
    except typer.Abort:
        print("physynth: aborted", file=sys.stderr)
        sys.exit(EXIT_INTERRUPTED)
    except typer.TyperException as exc:  # usage errors: unknown option, bad value, missing argument
        if type(exc).__name__ == "NoArgsIsHelpError":  # physynth, or a group, without a command: asking for help
            print(exc.format_message())
            sys.exit(0)
        fail(exc.format_message())
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except OSError as exc:  # the machine, not the input: disk full, permission denied, ...
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        print(f"physynth: error: {exc.strerror or exc}{where}", file=sys.stderr)
        sys.exit(EXIT_SYSTEM)
    except KeyboardInterrupt:
        print("physynth: interrupted", file=sys.stderr)
        sys.exit(EXIT_INTERRUPTED)
    except MemoryError:
        print("physynth: error: out of memory (see the size budget in docs/reliability.md)", file=sys.stderr)
        sys.exit(EXIT_SYSTEM)
    except Exception as exc:  # a bug: one line, exit 3; the traceback only on request
        if os.environ.get("PHYSYNTH_DEBUG", "") not in ("", "0"):
            raise
        first = (str(exc).strip().splitlines() or [""])[0][:300]
        print(f"physynth: internal error: {type(exc).__name__}: {first} (a bug in PhySynth; please report it; "
              "PHYSYNTH_DEBUG=1 shows the traceback)", file=sys.stderr)
        sys.exit(EXIT_BUG)


if __name__ == "__main__":
    main()
