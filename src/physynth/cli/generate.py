"""``physynth generate``, ``physynth scenarios``, ``physynth scenario show`` and ``physynth inspect``."""

from __future__ import annotations

import importlib.util
import json
import textwrap
from pathlib import Path
from typing import Any

import typer

from ._common import check_run_options, counted, format_table, progress_bar, resumable

AUTO_CLUSTER_MIN_TRACES = 1000
"""With the default ``--workers 0``, runs of fewer traces stay in this process (no cluster to start)."""


def worker_processes(workers: int, n: int, scheduler: str | None) -> tuple[int, bool]:
    """The worker processes for ``n`` traces (``--workers``; 0: all cores from :data:`AUTO_CLUSTER_MIN_TRACES`
    traces on, else one), and whether that default fell back to one core because Dask is not installed."""
    from ..parallel import available_cores

    n_workers = workers or (available_cores() if n >= AUTO_CLUSTER_MIN_TRACES else 1)
    if not workers and scheduler is None and n_workers > 1 and importlib.util.find_spec("distributed") is None:
        return 1, True  # the default (all cores) without the optional Dask: one core
    return n_workers, False


def workers_option(each: str = "", below: str = "") -> Any:
    """The ``--workers`` option of a command run in parts on worker processes (``each``: what a worker does,
    after "Worker processes"; ``below``: after "one process below that")."""
    return typer.Option(0, "--workers", "-w", metavar="N", min=0,
                        help=f"Worker processes{each}. 0 (the default) picks for you: all cores for "
                             f"{AUTO_CLUSTER_MIN_TRACES} traces or more, one process below that{below}. More than "
                             "one runs an embedded Dask cluster (needs physynth[scale]); the output is the same "
                             "for any number of workers.")


def scheduler_option(sees: str) -> Any:
    """The ``--scheduler`` option (``sees``: what the cluster's workers must see at the same path)."""
    return typer.Option(None, "--scheduler", metavar="ADDRESS",
                        help=f"Run on an existing Dask cluster (e.g. tcp://host:8786) whose workers see {sees}.")


scenario_app = typer.Typer(help="Show built-in scenarios; make one for a surveyed site.", no_args_is_help=True)


def register(app: typer.Typer) -> None:
    """Add the commands of this module to the main app."""
    app.command("generate")(generate_cmd)
    app.command("scenarios")(scenarios_cmd)
    app.command("inspect")(inspect_cmd)
    scenario_app.command("show")(scenario_show_cmd)
    scenario_app.command("survey")(scenario_survey_cmd)
    app.add_typer(scenario_app, name="scenario")


def generate_cmd(
    scenario: str = typer.Option("cablecar-descending", "--scenario", "-s", metavar="SCENARIO",
                                 help="Preset name or path to a scenario YAML file."),
    n: int = typer.Option(20, "-n", "--n-traces", metavar="N", min=1, help="Number of traces to generate."),
    seed: int | None = typer.Option(None, "--seed", metavar="SEED", min=0,
                                    help="Root seed >= 0 (random when omitted; stored)."),
    out: Path = typer.Option(Path("runs/default"), "--out", "-o", metavar="DIR", help="Output dataset directory."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing dataset (only a dataset "
                                                              "PhySynth wrote) or discard an unfinished run of it."),
    workers: int = workers_option(below=", since starting workers takes seconds"),
    scheduler: str | None = scheduler_option("--out at the same path"),
    resume: bool = typer.Option(False, "--resume", help="Complete a killed run of --out: keep its complete "
                                                        "shards, write the others (same seed unless --seed)."),
    shard_traces: int = typer.Option(128, "--shard-traces", metavar="N", min=1,
                                     help="Traces per shard (the unit of work, of atomic writes and of --resume)."),
    regime: str | None = typer.Option(None, "--regime", metavar="REGIME",
                                      help="Channel regime applied to the scenario: nominal, dense, sparse or degraded "
                                           "(docs/anchors.md)."),
    vary_site: bool = typer.Option(False, "--vary-site",
                                   help="Give every trace its own anchor layout (jittered) and path (turned and "
                                        "shifted), as the scenario's variation section says, or with that "
                                        "section's defaults when it has none (docs/scale.md): training data "
                                        "for trackers that must work beyond one site."),
    force: bool = typer.Option(False, "--force", help="Go ahead even when the size estimate exceeds the budget."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Generate N synthetic traces from a scenario and write them as a Parquet dataset."""
    from ..workflows import generate_dataset

    check_run_options(resume, overwrite, scheduler, workers, "run of --out")
    scn, added = _prepared_scenario(scenario, regime, vary_site)
    inputs = [Path(scenario)] if Path(scenario).is_file() else []
    n_workers, without_dask = worker_processes(workers, n, scheduler)
    if without_dask and not quiet and n > shard_traces:  # said once
        from ..extras import install_hint

        typer.echo(f"physynth: Dask is not installed, generating on one core ({install_hint('scale')} "
                   "for all cores)", err=True)
    resume_hint = f"complete shards are kept: run the same command with --resume to finish {out}"
    if resume:
        from ..io.safety import resolve_output
        from ..io.shards import finished_run
        from ..scenario import scenario_to_dict

        done = finished_run(resolve_output(out), scenario_to_dict(scn), seed, n, shard_traces)
        if done is not None:
            typer.echo(f"{out} is already complete ({counted(n, 'trace')}, root seed {done}): nothing to resume")
            return
    with resumable(resume_hint), progress_bar(not quiet) as progress:
        path, root = generate_dataset(scn, n, out, seed=seed, overwrite=overwrite, progress=progress,
                                      workers=n_workers, scheduler=scheduler, resume=resume,
                                      shard_traces=shard_traces, force=force, inputs=inputs)
    if not quiet:
        where = f"on {scheduler}" if scheduler else counted(min(n_workers, -(-n // shard_traces)), "worker")
        typer.echo(f"wrote {counted(n, 'trace')} of '{scn.name}' to {path} (root seed {root}, {where})")
        _say_variation(scn, added)


def _prepared_scenario(scenario: str, regime: str | None, vary_site: bool):
    """The scenario to generate, after ``--regime`` and ``--vary-site``; and whether ``--vary-site`` added
    the variation section (the scenario had none)."""
    from ..errors import PhySynthError
    from ..io.scenario_file import load_scenario

    scn = load_scenario(scenario)
    if regime is not None:
        from ..studies.regimes import apply_regime, check_regime

        if not scn.anchors:  # a regime changes the UWB channel and availability only: nothing to change
            raise PhySynthError(f"--regime {check_regime(regime)}: scenario '{scn.name}' has no anchors, so a "
                                "channel regime changes nothing; leave --regime out")
        scn = apply_regime(scn, regime)
    added = vary_site and scn.variation is None  # the section's defaults, with the layouts a calibration recorded
    if added:
        from ..models.variation import recorded_layouts
        from ..scenario import SiteVariationParams

        scn = scn.model_copy(update={"variation": SiteVariationParams(
            layouts=recorded_layouts(scn.provenance, scn.anchor_ids))})
    return scn, added


def _say_variation(scn, added: bool) -> None:
    """The summary's line on how the site varies per trace (nothing without a variation section)."""
    if scn.variation is None:
        return
    source = ("--vary-site defaults" + ("; the layouts the calibration recorded" if scn.variation.layouts else "")
              if added else "the scenario's variation section")
    dist = scn.variation.layout_distribution
    if not scn.anchors:
        line = f"path varied per trace ({source}; no anchors)"
    elif dist is not None:
        lo, hi = dist.anchor_count
        line = (f"site varied per trace: a layout of {lo}-{hi} anchors drawn from variation.layout_distribution, "
                f"each with the channel of one of the scenario's {len(scn.anchors)} ({source})")
    else:
        lays = counted(len(scn.variation.layouts), "anchor layout") if scn.variation.layouts else "its own layout"
        line = f"site varied per trace around {lays} ({source})"
    typer.echo(textwrap.fill(line, 79, initial_indent="  ", subsequent_indent="    "))


def scenarios_cmd() -> None:
    """List the built-in scenario presets."""
    import shutil

    from ..io.scenario_file import list_presets, load_scenario

    width = max(shutil.get_terminal_size((80, 24)).columns, 40)  # the terminal's, or $COLUMNS, else 80
    for name in list_presets():
        words = " ".join(load_scenario(name).description.split())  # the whole description, wrapped under itself
        typer.echo(textwrap.fill(words, width, initial_indent=f"{name:24s} ", subsequent_indent=" " * 25,
                                 break_on_hyphens=False) if words else name)


def scenario_show_cmd(name: str = typer.Argument(..., metavar="SCENARIO",
                                                 help="Preset name or scenario file.")) -> None:
    """Print a scenario as YAML."""
    from ..io.scenario_file import load_scenario, scenario_to_yaml

    typer.echo(scenario_to_yaml(load_scenario(name)), nl=False)


def scenario_survey_cmd(
    base: str = typer.Argument(..., metavar="SCENARIO", help="The scenario whose channel, availability, motion and "
                               "IMU the site takes (a preset, or one calibrated at a similar site)."),
    anchors: Path = typer.Option(..., "--anchors", metavar="CSV", help="The site's anchor survey: columns id, e, n, u "
                                 "[m], one row per anchor."),
    route: Path = typer.Option(None, "--route", metavar="CSV", help="A route sketch: columns e, n, u [m], one row per "
                               "waypoint (default: the scenario's path, moved with the anchors)."),
    out: Path = typer.Option(..., "--out", "-o", metavar="YAML", help="The site's scenario file."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a scenario file already there."),
) -> None:
    """A scenario for a site known from its anchor survey and a route sketch only (docs/tracking.md)."""
    from ..io.safety import SURVEY_MARKER, check_output, guarded_outputs
    from ..io.scenario_file import load_scenario, save_scenario
    from ..survey import survey_scenario

    check_output(out, kind="scenario", overwrite=overwrite, inputs=[anchors, *([route] if route else [])])
    ids, pos = _read_points(anchors, ("id", "e", "n", "u"), "--anchors")
    way = _read_points(route, ("e", "n", "u"), "--route")[1] if route is not None else None
    scn = survey_scenario(load_scenario(base), ids, pos, way, name=out.stem)
    out.parent.mkdir(parents=True, exist_ok=True)
    with guarded_outputs([out]) as real:
        check_output(out, kind="scenario", overwrite=overwrite)
        save_scenario(scn, real[0], header=f"{SURVEY_MARKER[2:]}: {base} at the site surveyed in {anchors.name}"
                      + (f", route {route.name}" if route else ""))
    typer.echo(f"wrote {out} ({len(ids)} anchors, " + ("the route sketched" if route else "the scenario's path moved "
               "with the anchors") + ")")


def _read_points(path: Path, columns: tuple[str, ...], flag: str) -> tuple[list[str], Any]:
    """(ids, (N, 3) positions) of a CSV with ``columns`` (case and spaces ignored); one clear line when not."""
    import numpy as np
    import pandas as pd

    from ..errors import PhySynthError

    try:
        df = pd.read_csv(path, skipinitialspace=True)
    except FileNotFoundError:
        raise PhySynthError(f"{flag}: {path} does not exist") from None
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        raise PhySynthError(f"{flag}: {path} is not a readable CSV file ({str(exc).splitlines()[0]})") from None
    df.columns = [str(c).strip().lower() for c in df.columns]
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise PhySynthError(f"{flag}: {path} lacks the column(s) {', '.join(missing)} (it needs {', '.join(columns)})")
    xyz = df[["e", "n", "u"]].apply(pd.to_numeric, errors="coerce").to_numpy(float)
    bad = np.flatnonzero(~np.isfinite(xyz).all(axis=1))
    if bad.size:
        raise PhySynthError(f"{flag}: {path} row {int(bad[0]) + 2} has no number in e, n or u")
    ids = [str(v).strip() for v in df["id"]] if "id" in columns else []
    return ids, xyz


UWB_METRICS = ("uwb_ge1_frac", "uwb_ge2_frac", "residual_std_m", "residual_median_m", "abs_residual_p95_m",
               "abs_residual_p99_m", "mean_aoi_s")
"""The metrics that describe ranging: left out of ``inspect``'s table for a dataset without anchors."""


def inspect_cmd(
    dataset: Path = typer.Argument(..., metavar="DATASET", help="Dataset directory."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object instead of a table."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Metrics of a dataset (docs/data-and-metrics.md), pooled over its traces; streamed, any size."""
    from .._json import jsonable
    from ..io.dataset import recorded_grid_rate_hz
    from ..workflows import inspect_dataset

    with progress_bar(not quiet) as progress:
        m, meta = inspect_dataset(dataset, progress=progress)
    if as_json:
        typer.echo(json.dumps(jsonable(m.to_dict()), indent=1))
        return
    typer.echo(f"{dataset} - {counted(m.n_traces, 'trace')}, {counted(m.n_residuals, 'range residual')}")
    flagged = sum(bool(t.get("truth_untrusted_s")) for t in meta.get("traces", []))
    if flagged:
        typer.echo(textwrap.fill(f"({counted(flagged, 'trace')} {'flags' if flagged == 1 else 'flag'} spans where "
                                 "the truth errs (truth_untrusted_s): the ranges there are left out of the "
                                 "residuals; docs/validation.md)", 79))
    no_uwb = not m.per_anchor  # no anchors (an IMU-only recording): the UWB metrics are no numbers
    rows = []
    for key, value in m.to_dict().items():
        if key == "per_anchor" or (no_uwb and key in UWB_METRICS):
            continue
        rows.append((key, " / ".join(f"{v:.3f}" for v in value) if isinstance(value, list) else f"{value:.4g}"))
    typer.echo(format_table(("metric", "value"), rows))
    if no_uwb:
        typer.echo("no anchors (IMU only): the UWB metrics do not apply")
        return
    cols = ("n_ranges", "fresh_frac", "mean_aoi_s", "residual_std_m", "residual_median_m", "abs_residual_p95_m")
    heads = ("anchor", "ranges", "fresh", "AoI s", "std m", "med m", "p95 m")
    per = [(a, *(f"{d[c]:.4g}" if isinstance(d[c], float) else str(d[c]) for c in cols))
           for a, d in m.per_anchor.items()]
    typer.echo(f"\nper anchor (fresh = fraction of {recorded_grid_rate_hz(meta):g} Hz bins with a range; "
               "|residual| P95)")
    typer.echo(format_table(heads, per))
