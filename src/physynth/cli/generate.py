"""``physynth generate``, ``physynth scenarios``, ``physynth scenario show`` and ``physynth inspect``."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from ._common import progress_bar

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
    seed: int | None = typer.Option(None, "--seed", min=0, help="Root seed >= 0 (random when omitted; stored)."),
    out: Path = typer.Option(Path("runs/default"), "--out", "-o", help="Output dataset directory."),
    overwrite: bool = typer.Option(False, "--overwrite",
                                   help="Replace an existing dataset (only a dataset PhySynth wrote)."),
    force: bool = typer.Option(False, "--force", help="Go ahead even when the size estimate exceeds the budget."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Generate N synthetic traces from a scenario and write them as a Parquet dataset."""
    from ..io.scenario_file import load_scenario
    from ..workflows import generate_dataset

    scn = load_scenario(scenario)
    inputs = [Path(scenario)] if Path(scenario).is_file() else []
    with progress_bar(not quiet) as progress:
        path, root = generate_dataset(scn, n, out, seed=seed, overwrite=overwrite, progress=progress,
                                      force=force, inputs=inputs)
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
) -> None:
    """Section-5 metrics of a dataset, pooled over its traces."""
    from .._json import jsonable
    from ..evaluate.metrics import compute_metrics
    from ..io import read_dataset

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
    cols = ("n_ranges", "fresh_frac", "mean_aoi_s", "residual_std_m", "residual_median_m", "abs_residual_p95_m")
    per = Table(title="per anchor")
    for col in ("anchor", *cols):
        per.add_column(col, justify="right")
    for a, d in m.per_anchor.items():
        per.add_row(a, *(f"{d[c]:.4g}" if isinstance(d[c], float) else str(d[c]) for c in cols))
    Console().print(per)
