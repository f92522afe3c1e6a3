"""``physynth validate``: compare a real dataset with synthetic traces and write a report folder.

    physynth validate --real DATASET (--synthetic DATASET | --scenario S [-n N] [--seed S]) [--transfer]
                      --out REPORT_DIR [--no-figures] [--overwrite] [--quiet]

The command parses, calls :func:`physynth.workflows.validate_datasets` and
:func:`physynth.validate.render.write_report`, prints a short summary and exits. Bad input raises
:class:`~physynth.errors.PhySynthError`, which ``physynth.cli.main`` prints as one line (exit code 2).
"""

from __future__ import annotations

from pathlib import Path

import typer

from ._common import progress_bar


def register(app: typer.Typer) -> None:
    """Add the ``validate`` command to the main app."""
    app.command("validate")(validate_cmd)


def validate_cmd(
    real: Path = typer.Option(..., "--real", help="Dataset directory of real traces (with ground truth)."),
    synthetic: Path | None = typer.Option(None, "--synthetic",
                                             help="Dataset directory of synthetic traces to compare."),
    scenario: str | None = typer.Option(None, "--scenario", "-s",
                                           help="Preset name or scenario YAML: generate the synthetic traces."),
    n: int = typer.Option(50, "-n", "--n-traces", min=1, help="Traces to generate with --scenario."),
    seed: int | None = typer.Option(None, "--seed", help="Root seed for --scenario (random when omitted; "
                                                             "recorded in the report)."),
    transfer: bool = typer.Option(False, "--transfer",
                                  help="Take path geometry, motion and anchor layout from the real dataset; keep "
                                       "every sensor, channel and availability parameter of the scenario "
                                       "(paper IV.C)."),
    out: Path = typer.Option(..., "--out", "-o", help="Report directory (report.json, report.md, report.html, "
                                                      "figures)."),
    figures: bool = typer.Option(True, "--figures/--no-figures",
                                 help="Draw the figures (needs matplotlib: physynth[report])."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a report already in --out."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Validate synthetic traces against a real dataset (paper section IV: Tables I-II, KS, figures)."""
    from ..errors import AnchorMismatchError, OutputExistsError, PhySynthError
    from ..validate.render import require_matplotlib, write_report
    from ..workflows import validate_datasets

    if (out / "report.json").exists() and not overwrite:  # fail before the (long) generation
        raise OutputExistsError(out, "holds a report")
    if (synthetic is None) == (scenario is None):
        raise PhySynthError("give exactly one of --synthetic DATASET and --scenario SCENARIO "
                            f"({'both' if synthetic is not None else 'neither'} given)")
    if transfer and scenario is None:
        raise PhySynthError("--transfer needs --scenario (it builds a scenario for the real run's geometry)")
    if figures:
        require_matplotlib()  # a missing matplotlib is reported before any work is done
    try:
        with progress_bar(not quiet) as progress:
            report = validate_datasets(real, synthetic=synthetic, scenario=scenario, n=n, seed=seed,
                                       transfer=transfer, progress=progress)
    except AnchorMismatchError as exc:
        hint = "; use --transfer to take the anchor layout from the real dataset" if scenario else ""
        raise PhySynthError(str(exc).split("; transfer the scenario")[0] + hint) from None
    from ..validate.imu_report import ImuValidationReport, write_imu_report

    if isinstance(report, ImuValidationReport):  # an IMU-only real dataset: IMU error tables
        written = write_imu_report(report, out, overwrite=overwrite)
        if not quiet:
            _print_imu_summary(report, out, len(written))
        return
    written = write_report(report, out, figures=figures, overwrite=overwrite)
    if quiet:
        return
    dev = report.relative_deviation_pct
    syn = report.inputs.get("synthetic", {})
    typer.echo(f"real {report.inputs['n_traces']['real']} trace(s) vs synthetic "
               f"{report.inputs['n_traces']['synthetic']} trace(s)"
               + (f" (scenario '{syn.get('scenario_name')}', seed {syn.get('root_seed')}"
                  + (", transfer" if syn.get("transfer") else "") + ")" if "scenario" in syn else ""))
    typer.echo(f"KS {_f(report.ks_statistic)}  fidelity S {_f(report.fidelity_score)}  "
               f"W1 {_f(report.extended.get('residual_wasserstein_m'))} m")
    for key in ("uwb_ge1_frac", "residual_median_m", "abs_residual_p95_m", "mean_aoi_s"):
        typer.echo(f"  {key:20s} real {_f(report.real[key])}  synth {_f(report.synthetic[key])}  "
                   f"({_f(dev[key], 1)} %)")
    typer.echo(f"wrote {len(written)} file(s) to {out} (open {out / 'report.html'})")


def _f(x: object, digits: int = 3) -> str:
    return "-" if not isinstance(x, (int, float)) or x != x else f"{x:.{digits}f}"


def _print_imu_summary(report, out: Path, n_files: int) -> None:
    for key, real in report.real.items():
        synth, dev = report.synthetic.get(key), report.relative_deviation_pct.get(key)
        if real is None or synth is None:
            continue
        typer.echo(f"  {key:26s} real {' / '.join(_f(x) for x in real)}  synth {' / '.join(_f(x) for x in synth)}  "
                   f"({' / '.join(_f(x, 1) for x in dev)} %)")
    typer.echo(f"wrote {n_files} file(s) to {out} (open {out / 'report.html'})")
