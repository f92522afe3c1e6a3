"""``physynth import ...``: turn real recordings into PhySynth datasets."""

from __future__ import annotations

import typer

app = typer.Typer(help="Import real recordings as PhySynth datasets.", no_args_is_help=True)
