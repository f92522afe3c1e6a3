"""``physynth export``: a dataset as HDF5, ROS 2 bags or CSV files for other tools."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import typer

from ._common import check_run_options, progress_bar, resumable
from .generate import scheduler_option, worker_processes, workers_option


def register(app: typer.Typer) -> None:
    """Add the ``export`` command to the main app."""
    app.command("export")(export_cmd)


def export_cmd(
    dataset: Path = typer.Argument(..., metavar="DATASET", help="Dataset directory."),
    fmt: str = typer.Option(..., "--format", "-f", metavar="FORMAT",
                            help="hdf5 (one file, a group per trace), rosbag2 (a folder, a bag per trace) or csv (a "
                                 "folder, a file per table)."),
    out: Path = typer.Option(..., "--out", "-o", metavar="PATH", help="Output file (hdf5) or folder (rosbag2, csv)."),
    bag_storage: Literal["mcap", "mcap-uncompressed", "sqlite3"] | None = typer.Option(
        None, "--bag-storage", show_default=False,
        help="Storage of the ROS 2 bags: mcap (the default: ROS 2's since Iron, opened natively by Foxglove; "
             "zstd-compressed chunks), mcap-uncompressed or sqlite3."),
    workers: int = workers_option(each=", one part (a shard of the dataset) at a time each",
                                  below="; hdf5 and csv: one process (parts in order go straight into the "
                                        "output)"),
    scheduler: str | None = scheduler_option("DATASET and --out at the same paths"),
    resume: bool = typer.Option(False, "--resume", help="Complete a killed export to --out: keep its complete "
                                                        "parts, write the others."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing output or discard an unfinished "
                                                              "export to it."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Export a dataset to HDF5, ROS 2 bags (MCAP; sensor_msgs/Imu, sensor_msgs/Range) or CSV (docs/export.md)."""
    from ..errors import PhySynthError
    from ..io.dataset import n_traces, read_meta
    from ..workflows import export_dataset

    check_run_options(resume, overwrite, scheduler, workers, "export to --out")
    if bag_storage is not None and fmt.lower() != "rosbag2":
        raise PhySynthError(f"--bag-storage applies to --format rosbag2 only (given with --format {fmt})")
    bag_storage = bag_storage or "mcap"
    # HDF5 and CSV pick one process: parts run one after the other go straight into the output, where parts
    # from several workers are appended to it when assembling, on one core (docs/export.md); polars' CSV
    # writer formats on every core, and HDF5 reads and checks its input on a second thread
    n_workers = (1 if fmt.lower() in ("csv", "hdf5") and not workers and scheduler is None
                 else worker_processes(workers, n_traces(read_meta(dataset)) or 0, scheduler)[0])
    resume_hint = f"complete parts are kept: run the same command with --resume to finish {out}"
    with resumable(resume_hint), progress_bar(not quiet) as progress:
        path = export_dataset(dataset, out, fmt.lower(), overwrite=overwrite, progress=progress,
                              bag_storage=bag_storage, resume=resume, workers=n_workers, scheduler=scheduler)
    if not quiet:
        typer.echo(f"wrote {path} ({fmt}{', ' + bag_storage if fmt.lower() == 'rosbag2' else ''})")
