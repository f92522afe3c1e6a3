"""The ``physynth`` command line: thin commands over :mod:`physynth.workflows` and the library.

Every command module has a ``register(app)`` function; :func:`main` registers them all. The library
raises errors that speak of parameters and reports progress through a callback; only this package
draws progress bars, names options and chooses exit codes:

- 0: success;
- 1: the machine failed (disk full, permission denied): one line on stderr;
- 2: a user mistake (``PhySynthError``, a bad option or argument): one line on stderr;
- 130: interrupted (Ctrl-C).

A traceback is only ever shown for a bug. Heavy imports happen inside the commands.
"""

from __future__ import annotations

import sys

import typer

from ..errors import OutputExistsError, PhySynthError
from ._common import EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_SYSTEM, fail

app = typer.Typer(
    name="physynth",
    help="Physics-based synthetic UWB + IMU + availability + AoI traces, calibrated on real recordings.",
    add_completion=True,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
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


def _register_commands() -> None:
    """Every command module adds its commands through the same ``register(app)``."""
    global _registered
    if _registered:
        return
    from . import bench, calibrate, export, generate, imports, validate

    for module in (generate, imports, calibrate, validate, export, bench):
        module.register(app)
    _registered = True


def main(argv: list[str] | None = None) -> None:
    """Entry point: run the app, turning user mistakes into one line on stderr and exit code 2."""
    _register_commands()
    argv = sys.argv[1:] if argv is None else argv
    if not argv:
        argv = ["--help"]
    try:
        app(args=argv, standalone_mode=False)
    except OutputExistsError as exc:
        fail(f"{exc} (use --overwrite to replace it)")
    except PhySynthError as exc:
        fail(str(exc))
    except typer.Abort:
        print("physynth: aborted", file=sys.stderr)
        sys.exit(EXIT_INTERRUPTED)
    except typer.TyperException as exc:  # usage errors: unknown option, bad value, missing argument
        if type(exc).__name__ == "NoArgsIsHelpError":  # a command group without its sub-command
            print(exc.format_message(), file=sys.stderr)
            sys.exit(EXIT_BAD_INPUT)
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


if __name__ == "__main__":
    main()
