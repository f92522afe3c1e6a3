"""``physynth generate``, ``physynth scenarios``, ``physynth scenario show`` and ``physynth inspect``."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from ._common import format_table, progress_bar

scenario_app = typer.Typer(help="Show built-in scenarios.", no_args_is_help=True)


def register(app: typer.Typer) -> None:
    """Add the commands of this module to the main app."""
    app.command("generate")(generate_cmd)
    app.command("scenarios")(scenarios_cmd)
    app.command("inspect")(inspect_cmd)
    scenario_app.command("show")(scenario_show_cmd)
    app.add_typer(scenario_app, name="scenario")


def generate_cmd(
    scenario: str = typer.Option("cablecar-descending", "--scenario", "-s",
                                 help="Preset name or path to a scenario YAML file."),
    n: int = typer.Option(20, "-n", "--n-traces", min=1, help="Number of traces to generate."),
    seed: int | None = typer.Option(None, "--seed", help="Root seed (random when omitted; stored)."),
    out: Path = typer.Option(Path("runs/default"), "--out", "-o", help="Output dataset directory."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing dataset."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Generate N synthetic traces from a scenario and write them as a Parquet dataset."""
    from ..io.scenario_file import load_scenario
    from ..workflows import generate_dataset

    scn = load_scenario(scenario)
    with progress_bar(not quiet) as progress:
        path, root = generate_dataset(scn, n, out, seed=seed, overwrite=overwrite, progress=progress)
    if not quiet:
        typer.echo(f"wrote {n} trace(s) of '{scn.name}' to {path} (root seed {root})")


def scenarios_cmd() -> None:
    """List the built-in scenario presets."""
    from ..io.scenario_file import list_presets, load_scenario

    for name in list_presets():
        s = load_scenario(name)
        typer.echo(f"{name:24s} {s.description.splitlines()[0] if s.description else ''}")


def scenario_show_cmd(name: str = typer.Argument(..., help="Preset name or scenario file.")) -> None:
    """Print a scenario as YAML."""
    from ..io.scenario_file import load_scenario, scenario_to_yaml

    typer.echo(scenario_to_yaml(load_scenario(name)), nl=False)


def inspect_cmd(
    dataset: Path = typer.Argument(..., help="Dataset directory."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object instead of a table."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Section-5 metrics of a dataset, pooled over its traces (streamed: any number of traces)."""
    from .._json import jsonable
    from ..workflows import inspect_dataset

    with progress_bar(not quiet) as progress:
        m, _ = inspect_dataset(dataset, progress=progress)
    if as_json:
        typer.echo(json.dumps(jsonable(m.to_dict()), indent=1))
        return
    typer.echo(f"{dataset} - {m.n_traces} trace(s), {m.n_residuals} range residual(s)")
    rows = []
    for key, value in m.to_dict().items():
        if key == "per_anchor":
            continue
        rows.append((key, " / ".join(f"{v:.3f}" for v in value) if isinstance(value, list) else f"{value:.4g}"))
    typer.echo(format_table(("metric", "value"), rows))
    cols = ("n_ranges", "fresh_frac", "mean_aoi_s", "residual_std_m", "residual_median_m", "abs_residual_p95_m")
    heads = ("anchor", "ranges", "fresh", "AoI s", "std m", "med m", "p95 m")
    per = [(a, *(f"{d[c]:.4g}" if isinstance(d[c], float) else str(d[c]) for c in cols))
           for a, d in m.per_anchor.items()]
    typer.echo("\nper anchor (fresh = fraction of 100 Hz bins with a range; |residual| P95)")
    typer.echo(format_table(heads, per))
