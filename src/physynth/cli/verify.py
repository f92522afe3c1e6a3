"""``physynth verify DATASET``: check a dataset against the sizes, row counts and SHA-256 recorded in
its ``dataset.json`` (:mod:`physynth.io.integrity`). Exit 0 only when every file matches; each damaged
file is named on its own line, exit 2."""

from __future__ import annotations

from pathlib import Path

import typer

from ._common import cli_words, fail_each


def register(app: typer.Typer) -> None:
    """Add the ``verify`` command to the main app."""
    app.command("verify")(verify_cmd)


def verify_cmd(
    datasets: list[Path] = typer.Argument(..., metavar="DATASET", help="Dataset directories to check."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing when every dataset is intact."),
) -> None:
    """Check datasets against the row counts and checksums recorded in their dataset.json."""
    from ..errors import IntegrityError, PhySynthError
    from ..io.dataset import read_meta
    from ..io.integrity import describe, verify_dataset

    bad: list[str] = []
    for ds in datasets:  # every dataset is checked; each problem is named on its own line
        try:
            meta = read_meta(ds)
            result = verify_dataset(ds, meta, hashes=True)
            if not result.recorded:
                raise IntegrityError(f"dataset {ds} has no integrity record (written by an older PhySynth): "
                                     "it cannot be verified")
        except PhySynthError as exc:
            if len(datasets) == 1:
                raise
            problems: tuple[str, ...] = (str(exc),)
        else:
            problems = result.problems
        if not problems:
            if not quiet:
                typer.echo(f"{ds}: ok, {describe(result)}")
            continue
        if len(datasets) == 1:
            fail_each(problems)
        for problem in problems:
            typer.echo(f"{ds}: {cli_words(problem.splitlines()[0])}", err=True)
        bad.append(str(ds))
    if bad:
        raise IntegrityError(f"{len(bad)} of {len(datasets)} datasets failed verification: {', '.join(bad)}")
