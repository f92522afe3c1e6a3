"""``physynth import ...``: turn real recordings into PhySynth datasets.

Every recording is imported first (a bad one stops the command with one error line before anything
is written); then the traces are written as one dataset whose ``dataset.json`` holds
``"kind": "real"``, the ``source`` and, under ``import_report``, one report per trace (same order as
the traces). A short summary of rows read, kept, repaired, dropped and flagged is printed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import typer

from ._common import cli_words, counted, fail

app = typer.Typer(help="Import real recordings as PhySynth datasets.", no_args_is_help=True)


def register(main_app: typer.Typer) -> None:
    """Add the ``import`` command group to the main app."""
    main_app.add_typer(app, name="import")

_OUT = typer.Option(..., "--out", "-o", metavar="DIR", help="Output dataset directory.")
_OVERWRITE = typer.Option(False, "--overwrite", help="Replace an existing dataset (only a dataset PhySynth wrote).")
_QUIET = typer.Option(False, "--quiet", "-q", help="No summary.")


def _run(importer: Callable[[Path], tuple[Any, Any]], inputs: Sequence[Path], out: Path, *,
         source: str, overwrite: bool, quiet: bool) -> None:
    from ..io import write_dataset
    from ..io.safety import check_output

    check_output(out, kind="dataset", overwrite=overwrite, inputs=inputs)  # before the (long) import
    seen: dict[Path, Path] = {}
    for path in inputs:
        real = path.resolve()
        if real in seen:
            same = f"{path} is given twice" if path == seen[real] else f"{seen[real]} and {path} are one folder"
            fail(f"{same}: each recording may be imported once")
        seen[real] = path
    traces, reports = [], []
    for path in inputs:
        trace, report = importer(path)
        traces.append(trace)
        reports.append(report)
    meta = {"kind": "real", "source": source, "import_report": [r.to_dict() for r in reports]}
    written = write_dataset(out, traces, meta=meta, overwrite=overwrite, inputs=inputs)
    if quiet:
        return
    for trace, report in zip(traces, reports, strict=True):
        for line in report.summary_lines():
            typer.echo(cli_words(line))  # a note may name an importer parameter: show its option
        typer.echo(f"  -> {len(trace.uwb)} UWB rows ({int(trace.uwb.valid.sum())} valid), "
                   f"{trace.truth.t_s.size} truth samples, "
                   f"{0 if trace.imu is None else trace.imu.t_s.size} IMU samples, "
                   f"{trace.duration_s:.1f} s")
    typer.echo(f"wrote {counted(len(traces), 'real trace')} from {source} to {written}")


@app.command("csv")
def import_csv_cmd(
    rec_dirs: list[Path] = typer.Argument(..., help="Recording folder(s) in the PhySynth format.",
                                          metavar="REC_DIR"),
    out: Path = _OUT,
    overwrite: bool = _OVERWRITE,
    quiet: bool = _QUIET,
) -> None:
    """Import recording folder(s) in the generic format (docs/recording-format.md)."""
    from ..io.importers import import_csv

    _run(import_csv, rec_dirs, out, source="csv", overwrite=overwrite, quiet=quiet)


@app.command("hanyang")
def import_hanyang_cmd(
    run_dirs: list[Path] = typer.Argument(..., help="Hanyang run folder(s) .../Trajectory_X/Case_N.",
                                          metavar="RUN_DIR"),
    out: Path = _OUT,
    overwrite: bool = _OVERWRITE,
    crop_to_uwb: bool = typer.Option(False, "--crop-to-uwb",
                                     help="Drop truth samples after the last UWB measurement."),
    quiet: bool = _QUIET,
) -> None:
    """Import dynamic runs of the Hanyang outdoor UWB dataset (one trace per run)."""
    from ..io.importers import import_hanyang

    _run(lambda p: import_hanyang(p, crop_to_uwb=crop_to_uwb), run_dirs, out, source="hanyang-uwb",
         overwrite=overwrite, quiet=quiet)


@app.command("broad")
def import_broad_cmd(
    trials: list[Path] = typer.Argument(..., help="BROAD trial file(s) data_mat/<trial>.mat.",
                                        metavar="TRIAL.mat"),
    out: Path = _OUT,
    overwrite: bool = _OVERWRITE,
    quiet: bool = _QUIET,
) -> None:
    """Import BROAD IMU trials (IMU + optical truth, no UWB; one trace per trial)."""
    from ..io.importers import import_broad

    _run(import_broad, trials, out, source="broad", overwrite=overwrite, quiet=quiet)
