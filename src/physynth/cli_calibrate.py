"""``physynth calibrate``: command registered on the main app (work in progress)."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    """Add the ``calibrate`` command to the main app."""
