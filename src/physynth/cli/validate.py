"""``physynth validate``: compare a real dataset with synthetic traces and write a report folder.

    physynth validate --real DATASET (--synthetic DATASET | --scenario S [-n N] [--seed S]) [--transfer]
                      [--anchors A,B,...] [--all-truth] --out REPORT_DIR [--no-figures] [--overwrite] [--quiet]

The command parses, calls :func:`physynth.workflows.validate_datasets` and
:func:`physynth.validate.render.write_report`, prints a short summary and exits. Bad input raises
:class:`~physynth.errors.PhySynthError`, which ``physynth.cli.main`` prints as one line (exit code 2).
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import typer

from ._common import counted, progress_bar


def register(app: typer.Typer) -> None:
    """Add the ``validate`` command to the main app."""
    app.command("validate")(validate_cmd)


def validate_cmd(
    real: Path = typer.Option(..., "--real", metavar="DATASET",
                              help="Dataset directory of real traces (with ground truth)."),
    synthetic: Path | None = typer.Option(None, "--synthetic", metavar="DATASET",
                                             help="Dataset directory of synthetic traces to compare."),
    scenario: str | None = typer.Option(None, "--scenario", "-s", metavar="SCENARIO",
                                           help="Preset name or scenario YAML: generate the synthetic traces."),
    n: int | None = typer.Option(None, "-n", "--n-traces", metavar="N", min=1,
                                 help="Traces to generate with --scenario (default 50)."),
    seed: int | None = typer.Option(None, "--seed", metavar="SEED", min=0,
                                    help="Root seed for --scenario (random when omitted; recorded in the report)."),
    transfer: bool = typer.Option(False, "--transfer",
                                  help="Take path geometry, motion and anchor layout from the real dataset; keep "
                                       "every sensor, channel and availability parameter of the scenario "
                                       "(paper IV.C)."),
    anchors: str | None = typer.Option(None, "--anchors", metavar="IDS",
                                       help="Comma-separated anchor ids: the synthetic side uses only these "
                                            "anchors and the real dataset is compared on its full set (the "
                                            "anchor study's relaxed comparison)."),
    out: Path = typer.Option(..., "--out", "-o", metavar="DIR",
                             help="Report directory (report.json, report.md, report.html, figures)."),
    figures: bool = typer.Option(True, "--figures/--no-figures",
                                 help="Draw the figures (needs matplotlib: physynth[report])."),
    overwrite: bool = typer.Option(False, "--overwrite",
                                   help="Replace a report already in --out (only a report PhySynth wrote)."),
    force: bool = typer.Option(False, "--force", help="Go ahead even when the size estimate exceeds the budget."),
    all_truth: bool = typer.Option(False, "--all-truth",
                                   help="Compare the real ranges also where the real dataset says its truth errs "
                                        "(by default left out of the residual metrics and counted). See "
                                        "docs/validation.md."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Validate synthetic traces against a real dataset (paper section IV: Tables I-II, KS, figures)."""
    from ..io.safety import check_output, guarded_outputs

    inputs = [p for p in (real, synthetic, Path(scenario) if scenario else None) if p is not None and p.exists()]
    check_output(out, kind="report", overwrite=overwrite, inputs=inputs)  # fail before the (long) generation
    with guarded_outputs([out]) as (real_out,):  # lock; orphaned temp files removed
        check_output(out, kind="report", overwrite=overwrite, inputs=inputs)
        _validate(real, synthetic, scenario, n, seed, transfer, out, real_out, figures, overwrite, force, quiet,
                  anchors, all_truth)


def _validate(real: Path, synthetic: Path | None, scenario: str | None, n: int | None, seed: int | None,
              transfer: bool,
              out: Path, real_out: Path, figures: bool, overwrite: bool, force: bool, quiet: bool,
              anchors: str | None = None, all_truth: bool = False) -> None:
    from ..errors import AnchorMismatchError, PhySynthError
    from ..validate.render import require_matplotlib, write_report
    from ..workflows import validate_datasets

    if (synthetic is None) == (scenario is None):
        raise PhySynthError("give exactly one of --synthetic DATASET and --scenario SCENARIO "
                            f"({'both' if synthetic is not None else 'neither'} given)")
    if transfer and scenario is None:
        raise PhySynthError("--transfer needs --scenario (it builds a scenario for the real run's geometry)")
    for given, option in ((n is not None, "-n"), (seed is not None, "--seed")):
        if given and scenario is None:
            raise PhySynthError(f"{option} needs --scenario (it applies to generated traces); --synthetic "
                                "DATASET compares every trace of the dataset as it was generated")
    if figures:
        require_matplotlib()  # a missing matplotlib is reported before any work is done
    try:
        with progress_bar(not quiet) as progress:
            report = validate_datasets(real, synthetic=synthetic, scenario=scenario, n=50 if n is None else n,
                                       seed=seed, transfer=transfer, progress=progress, force=force,
                                       all_truth=all_truth,
                                       anchors=None if anchors is None else [a.strip() for a in anchors.split(",")])
    except AnchorMismatchError as exc:
        hint = "; use --transfer to take the anchor layout from the real dataset" if scenario else ""
        raise PhySynthError(str(exc).split("; transfer the scenario")[0] + hint) from None
    from ..validate.imu_report import ImuValidationReport, write_imu_report

    if isinstance(report, ImuValidationReport):  # an IMU-only real dataset: IMU error tables
        written = write_imu_report(report, real_out, overwrite=True, figures=figures)
        if not quiet:
            _print_imu_summary(report, out, len(written))
        return
    from ..io.safety import atomic_folder

    with atomic_folder(real_out) as tmp:  # the report folder appears complete or not at all
        written = write_report(report, tmp, figures=figures, overwrite=True)
    if quiet:
        return
    syn = report.inputs.get("synthetic", {})
    typer.echo(f"real {counted(report.inputs['n_traces']['real'], 'trace')} vs synthetic "
               f"{counted(report.inputs['n_traces']['synthetic'], 'trace')}"
               + (f" (scenario '{syn.get('scenario_name')}', seed {syn.get('root_seed')}"
                  + (", transfer" if syn.get("transfer") else "") + ")" if "scenario" in syn else ""))
    if report.inputs.get("anchor_subset") is not None:
        from ..validate.tables import anchor_subset_line

        typer.echo(textwrap.fill(anchor_subset_line(report.inputs), SUMMARY_WIDTH))
    truth = report.inputs.get("real", {}).get("truth") or {}
    if truth.get("untrusted_truth_ranges"):
        from ..validate.tables import truth_line

        hint = " (--all-truth compares them)" if truth.get("untrusted_left_out_of_residuals") else ""
        typer.echo(textwrap.fill(truth_line(truth) + hint, SUMMARY_WIDTH))
    from ..validate.compare import truth_past_uwb_line

    past = truth_past_uwb_line(report.inputs.get("real", {}).get("truth_past_last_uwb_s") or 0.0)
    if past:
        typer.echo(textwrap.fill(past[:-1] + " (physynth import hanyang --crop-to-uwb).", SUMMARY_WIDTH))
    typer.echo(f"KS {_f(report.ks_statistic)}  fidelity S {_f(report.fidelity_score)}  "
               f"W1 {_f(report.extended.get('residual_wasserstein_m'))} m")
    for line in _metric_lines(report):
        typer.echo(line)
    imu = report.imu_errors or {}
    for key, d in imu.get("relative_deviation_pct", {}).items():
        if d is not None:  # body-frame IMU errors, when both sides have them
            for line in _axis_lines(key, imu["real"][key], imu["synthetic"][key], d):
                typer.echo(line)
    typer.echo(f"wrote {counted(len(written), 'file')} to {out} (open {out / 'report.html'})")


SUMMARY_WIDTH = 79
"""The terminal summary's lines fit an 80-column terminal."""


def _metric_lines(report) -> list[str]:
    """One line per headline metric: real, synthetic (the median synthetic run for the mean AoI, as the
    report's Table II), the deviation, the synthetic 5-95 % band and whether the real value is in it."""
    lines, pooled = [], None
    for key in ("uwb_ge1_frac", "residual_median_m", "abs_residual_p95_m", "mean_aoi_s"):
        c = report.comparison.get(key, {})
        dev = c.get("deviation")
        delta = (f"{dev:+.3f} m" if c.get("deviation_kind") == "absolute" and dev is not None
                 else f"{_f(report.relative_deviation_pct.get(key), 1)} %")
        synth = report.synthetic[key]
        if c.get("typical") is not None:  # heavy-tailed: compared with the median synthetic run
            synth, pooled = c["typical"], report.synthetic[key]
        band = c.get("band_5_95")
        inside = ("  band —" if c.get("n_traces_in_band") is not None else "") if band is None else (
            f"  band {_f(band[0])}-{_f(band[1])} " + ("in" if c.get("real_in_band") else "OUT"))
        lines.append(f"  {key:18s} real {_f(report.real[key])}  synth {_f(synth)}  Δ {delta:>8s}{inside}")
    if pooled is not None:
        lines.append(f"  (mean_aoi_s synth: the median synthetic run's; pooled over the runs {_f(pooled)} s)")
    from ..validate.compare import band_note
    from ..validate.tables import few_band_traces

    few = few_band_traces(report)
    if few is not None:
        lines += textwrap.wrap(band_note(few), SUMMARY_WIDTH, initial_indent="  ", subsequent_indent="  ")
    return lines


def _f(x: object, digits: int = 3, sign: str = "") -> str:
    return "-" if not isinstance(x, (int, float)) or x != x else f"{x:{sign}.{digits}f}"


def _axis_lines(key: str, real, synth, dev) -> list[str]:
    """A per-axis metric in three lines of at most :data:`SUMMARY_WIDTH` characters."""
    axes = "E/N/U" if key.startswith("imu_") else "x/y/z"
    return [f"  {key} ({axes})", f"{'':6s}real  {' '.join(_f(x) for x in real)}",
            f"{'':6s}synth {' '.join(_f(x) for x in synth)}  deviation % {' '.join(_f(x, 1, '+') for x in dev)}"]


def _print_imu_summary(report, out: Path, n_files: int) -> None:
    typer.echo("IMU-only recording: error std per axis, real vs synthetic (docs/imu.md)")
    for key, real in report.real.items():
        synth, dev = report.synthetic.get(key), report.relative_deviation_pct.get(key)
        if real is None or synth is None:
            continue
        for line in _axis_lines(key, real, synth, dev or [None] * len(real)):
            typer.echo(line)
    typer.echo(f"wrote {counted(n_files, 'file')} to {out} (open {out / 'report.html'})")
