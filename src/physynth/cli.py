"""The ``physynth`` command line: thin commands over the library.

User mistakes (``PhySynthError`` and usage errors) print ONE line on stderr and exit with code 2;
a traceback is only ever shown for a bug. Heavy imports happen inside the commands.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer

from .errors import PhySynthError

app = typer.Typer(
    name="physynth",
    help="Physics-based synthetic UWB + IMU + availability + AoI traces, calibrated on real recordings.",
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)
scenario_app = typer.Typer(help="Show built-in scenarios.", no_args_is_help=True)
app.add_typer(scenario_app, name="scenario")


def _register_optional_groups() -> None:
    """Sub-command groups that live in their own modules."""
    from . import cli_calibrate, cli_track, cli_validate
    from .cli_import import app as import_app

    app.add_typer(import_app, name="import")
    cli_calibrate.register(app)
    cli_validate.register(app)
    cli_track.register(app)  # ``study tracking`` (issue 9); torch is imported only when it runs


@app.command()
def generate(
    scenario: str = typer.Option("cablecar-descending", "--scenario", "-s",
                                 help="Preset name or path to a scenario YAML file."),
    n: int = typer.Option(20, "-n", "--n-traces", help="Number of traces to generate."),
    seed: int | None = typer.Option(None, "--seed", help="Root seed (random when omitted; stored)."),
    out: Path = typer.Option(Path("runs/default"), "--out", "-o", help="Output dataset directory."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing dataset."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Generate N synthetic traces from a scenario and write them as a Parquet dataset."""
    from .generate import generate_dataset
    from .scenario import load_scenario

    if n < 1:
        raise PhySynthError(f"-n must be at least 1, got {n}")
    scn = load_scenario(scenario)
    path, root = generate_dataset(scn, n, out, seed=seed, overwrite=overwrite, progress=not quiet)
    if not quiet:
        typer.echo(f"wrote {n} trace(s) of '{scn.name}' to {path} (root seed {root})")


@app.command("scenarios")
def scenarios_cmd() -> None:
    """List the built-in scenario presets."""
    from .scenario import list_presets, load_scenario

    for name in list_presets():
        s = load_scenario(name)
        typer.echo(f"{name:24s} {s.description.splitlines()[0] if s.description else ''}")


@scenario_app.command("show")
def scenario_show(name: str = typer.Argument(..., help="Preset name or scenario file.")) -> None:
    """Print a scenario as YAML."""
    from .scenario import load_scenario, scenario_to_yaml

    typer.echo(scenario_to_yaml(load_scenario(name)), nl=False)


@app.command()
def inspect(
    dataset: Path = typer.Argument(..., help="Dataset directory."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object instead of a table."),
) -> None:
    """Section-5 metrics of a dataset, pooled over its traces."""
    from ._json import jsonable
    from .io import read_dataset
    from .metrics import compute_metrics

    ds = read_dataset(dataset)
    m = compute_metrics(ds.traces)
    if as_json:
        typer.echo(json.dumps(jsonable(m.to_dict()), indent=1))
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{dataset} - {len(ds)} trace(s)")
    table.add_column("metric")
    table.add_column("value", justify="right")
    for key, value in m.to_dict().items():
        if key == "per_anchor":
            continue
        table.add_row(key, " / ".join(f"{v:.3f}" for v in value) if isinstance(value, list) else f"{value:.4g}")
    Console().print(table)
    per = Table(title="per anchor")
    for col in ("anchor", "n_ranges", "fresh_frac", "mean_aoi_s", "residual_std_m", "residual_median_m",
                "abs_residual_p95_m"):
        per.add_column(col, justify="right")
    for a, d in m.per_anchor.items():
        per.add_row(a, *(f"{d[c]:.4g}" if isinstance(d[c], float) else str(d[c]) for c in
                         ("n_ranges", "fresh_frac", "mean_aoi_s", "residual_std_m", "residual_median_m",
                          "abs_residual_p95_m")))
    Console().print(per)


def _fail(message: str) -> None:
    first = message.strip().splitlines()[0] if message.strip() else "invalid input"
    print(f"physynth: error: {first}", file=sys.stderr)
    sys.exit(2)


def main(argv: list[str] | None = None) -> None:
    """Entry point: run the app, turning user mistakes into one line on stderr and exit code 2."""
    _register_optional_groups()
    argv = sys.argv[1:] if argv is None else argv
    if not argv:
        argv = ["--help"]
    try:
        app(args=argv, standalone_mode=False)
    except PhySynthError as exc:
        _fail(str(exc))
    except typer.Abort:
        print("physynth: aborted", file=sys.stderr)
        sys.exit(130)
    except typer.TyperException as exc:  # usage errors: unknown option, bad value, missing argument
        if type(exc).__name__ == "NoArgsIsHelpError":  # a command group without its sub-command
            print(exc.format_message(), file=sys.stderr)
            sys.exit(2)
        _fail(exc.format_message())
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except OSError as exc:  # the machine, not the input: disk full, permission denied, ...
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        print(f"physynth: error: {exc.strerror or exc}{where}", file=sys.stderr)
        sys.exit(1)
    except KeyboardInterrupt:
        print("physynth: interrupted", file=sys.stderr)
        sys.exit(130)


if __name__ == "__main__":
    main()
