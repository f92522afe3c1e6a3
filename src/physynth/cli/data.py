"""``physynth data``: the real recordings PhySynth calibrates on, fetched from where they are published.

    physynth data list  [--data-root DIR]
    physynth data fetch NAME [--data-root DIR] [--base-url URL] [--quiet]
    physynth data path  NAME [--data-root DIR]

Thin commands over :mod:`physynth.data`. The data root is ``--data-root``, else ``PHYSYNTH_DATA_DIR``, else
the user's cache; a folder holding a copy of a dataset works as the data root without any download. An
unknown dataset or a bad option is one line on stderr and exit 2; a download that fails (no network, an
error from the server, a file that fails its SHA-256 check) is one line and exit 1.
"""

from __future__ import annotations

from pathlib import Path

import typer

from ._common import EXIT_SYSTEM, fail, progress_bar

data_app = typer.Typer(help="The real datasets (Hanyang UWB, BROAD IMU): list, fetch, path.", no_args_is_help=True)

DATA_ROOT_HELP = ("Folder holding one folder per dataset (default: PHYSYNTH_DATA_DIR, else the user's "
                  "cache); a folder holding a copy needs no download.")


def register(app: typer.Typer) -> None:
    """Add the ``data`` command group to the main app."""
    data_app.command("list")(list_cmd)
    data_app.command("fetch")(fetch_cmd)
    data_app.command("path")(path_cmd)
    app.add_typer(data_app, name="data")


def _megabytes(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def list_cmd(
    data_root: Path | None = typer.Option(None, "--data-root", metavar="DIR", help=DATA_ROOT_HELP),
) -> None:
    """List the datasets: what each is, its licence, whether it is fetched, its size."""
    from ..data import data_root as root_of
    from ..data import fetched_state, list_datasets

    rows = [("dataset", "fetched", "size", "licence", "what")]
    rows += [(ds.name, fetched_state(ds.name, data_root), _megabytes(ds.size_bytes), ds.licence, ds.title)
             for ds in list_datasets()]
    widths = [max(len(r[j]) for r in rows) for j in range(len(rows[0]))]
    for r in rows:  # left-aligned text columns, two spaces apart
        typer.echo("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
    typer.echo(f"data root: {root_of(data_root)}")


def fetch_cmd(
    name: str = typer.Argument(..., metavar="NAME", help="The dataset (see `physynth data list`)."),
    data_root: Path | None = typer.Option(None, "--data-root", metavar="DIR", help=DATA_ROOT_HELP),
    base_url: str | None = typer.Option(None, "--base-url", metavar="URL",
                                        help="A mirror laid out like a data root (URL/NAME/...) instead of the "
                                             "upstream repository (default: PHYSYNTH_DATA_URL)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar; only the final line."),
) -> None:
    """Download a dataset's files (each checked against its published SHA-256) into the data root.

    Files already there with the right hash are kept; run it again to finish an interrupted fetch.
    """
    from ..data import DownloadError, fetch, get_dataset
    from ..errors import Interrupted

    ds = get_dataset(name)  # an unknown name: exit 2 before anything is drawn
    try:
        with progress_bar(not quiet) as progress:
            result = fetch(ds.name, root=data_root, base_url=base_url, progress=progress)
    except DownloadError as exc:
        fail(str(exc), EXIT_SYSTEM)
    except Interrupted as exc:  # physynth.cli.main prints one line and exits 128 + signal
        exc.note = f"the file being downloaded was removed, those done are kept: fetch {ds.name} again to finish"
        raise
    fresh = f"{result.downloaded} downloaded" if result.downloaded else "nothing to download"
    typer.echo(f"{ds.name}: {result.verified} files verified ({fresh}) in {result.path}")
    typer.echo(f"licence {ds.licence}; cite: {ds.citation}")


def path_cmd(
    name: str = typer.Argument(..., metavar="NAME", help="The dataset (see `physynth data list`)."),
    data_root: Path | None = typer.Option(None, "--data-root", metavar="DIR", help=DATA_ROOT_HELP),
) -> None:
    """Print the folder of a fetched dataset (exit 2 if it is not fetched)."""
    from ..data import dataset_path

    typer.echo(str(dataset_path(name, root=data_root)))
