"""``physynth export``: a dataset as HDF5, ROS 2 bags or CSV files for other tools."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import typer

from ._common import progress_bar


def register(app: typer.Typer) -> None:
    """Add the ``export`` command to the main app."""
    app.command("export")(export_cmd)


def export_cmd(
    dataset: Path = typer.Argument(..., metavar="DATASET", help="Dataset directory."),
    fmt: str = typer.Option(..., "--format", "-f", metavar="FORMAT",
                            help="hdf5 (one file, a group per trace), rosbag2 (a folder, a bag per trace) or csv (a "
                                 "folder, a file per table)."),
    out: Path = typer.Option(..., "--out", "-o", metavar="PATH", help="Output file (hdf5) or folder (rosbag2, csv)."),
    bag_storage: Literal["mcap", "sqlite3"] = typer.Option(
        "mcap", "--bag-storage", help="Storage of the ROS 2 bags: mcap (ROS 2 default since Iron, opened natively by "
                                      "Foxglove) or sqlite3."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing output."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Export a dataset to HDF5, ROS 2 bags (sensor_msgs/Imu, sensor_msgs/Range) or CSV (docs/export.md)."""
    from ..io.export import export_dataset

    with progress_bar(not quiet) as progress:
        path = export_dataset(dataset, out, fmt.lower(), overwrite=overwrite, progress=progress,
                              bag_storage=bag_storage)
    if not quiet:
        typer.echo(f"wrote {path} ({fmt})")
