"""``physynth study``: deployment studies on the generator.

    physynth study anchors   --scenario S [--real DATASET] [-n 50] [--seed S] [--counts 1..6]
                             [--regimes dense,sparse,degraded] [--order A,B,...] [--tracker-traces 50]
                             [--force] --out DIR
    physynth study placement --scenario S --candidates FILE -k K [--objective ge1|ge2|ge3|gdop|hdop]
                             [--force] --out DIR

Thin commands over :mod:`physynth.workflows`; bad input is one line on stderr and exit code 2, and so is
a study whose traces exceed the size budget (:func:`physynth.bounds.check_budget`) without ``--force``.
"""

from __future__ import annotations

import functools
import textwrap
from collections.abc import Callable
from pathlib import Path
from typing import Any

import typer

from ._common import counted, progress_bar

study_app = typer.Typer(help="Studies: anchor count x channel regime, anchor placement, tracking (Table IV).",
                        no_args_is_help=True)


def register(app: typer.Typer) -> None:
    """Add the ``study`` command group to the main app."""
    study_app.command("anchors")(holding_output_lock(anchors_cmd))
    study_app.command("placement")(holding_output_lock(placement_cmd))
    from .track import tracking_cmd  # torch is imported only when the study runs

    study_app.command("tracking")(holding_output_lock(tracking_cmd))
    app.add_typer(study_app, name="study")


def holding_output_lock(cmd: Callable[..., None]) -> Callable[..., None]:
    """``cmd`` holding the lock of its ``--out`` folder from before its checks to its last file, as
    ``generate`` holds its dataset's (:func:`physynth.io.safety.output_locked`): a second study writing the
    same folder is refused at once (exit 2) instead of interleaving its files with the first one's."""

    @functools.wraps(cmd)
    def locked(*args: Any, **kwargs: Any) -> None:
        from ..io.safety import output_locked

        with output_locked(kwargs["out"]):
            cmd(*args, **kwargs)

    return locked


WIDTH = 79
"""Summary lines are wrapped to this many characters (an 80-column terminal)."""

FORCE_HELP = "Go ahead even when the size estimate exceeds the budget."


def _shown(text: str, limit: int = 40) -> str:
    """``text`` as quoted in a one-line error: at most ``limit`` characters."""
    return text if len(text) <= limit else text[:limit - 3] + "..."


def parse_counts(text: str, n_anchors: int) -> list[int]:
    """``"1..6"``, ``"2,3,6"`` or ``"1..3,6"`` -> sorted unique ints; one-line error otherwise.

    Every count must lie in 1..``n_anchors`` (the scenario's anchors), checked before a range is
    expanded: ``1..99999999`` fails at once, in one short line.
    """
    from ..errors import PhySynthError

    spans = []
    try:
        for part in text.split(","):
            lo, dots, hi = part.strip().partition("..")
            spans.append((part.strip(), int(lo), int(hi) if dots else int(lo)))
    except ValueError:
        spans = []
    if not spans or any(hi < lo for _, lo, hi in spans):
        raise PhySynthError(f"--counts: expected a range like 1..6 or a list like 2,3,6, got '{_shown(text)}'")
    bad = next((part for part, lo, hi in spans if lo < 1 or hi > n_anchors), None)
    if bad is not None:
        raise PhySynthError(f"--counts: anchor counts must lie in 1..{n_anchors} (the scenario's anchors), "
                            f"got {_shown(bad)}")
    return sorted({k for _, lo, hi in spans for k in range(lo, hi + 1)})


def _echo_wrapped(text: str) -> None:
    """``text`` on stdout in lines of at most :data:`WIDTH` characters (words and paths kept whole)."""
    typer.echo(textwrap.fill(text, WIDTH, subsequent_indent="  ", break_long_words=False, break_on_hyphens=False))


ORDER_SOURCES = {"given": "as given", "real": "by real-run availability",
                 "reference run": "by reference-run availability"}
"""How the summary says where the anchor order came from (``AnchorStudy.reference["order_source"]``)."""


def _ids(text: str | None) -> list[str] | None:
    return None if text is None else [p.strip() for p in text.split(",")]


def anchors_cmd(
    scenario: str = typer.Option("cablecar-descending", "--scenario", "-s", metavar="SCENARIO",
                                 help="Preset name or scenario YAML with every anchor of the deployment."),
    real: Path | None = typer.Option(None, "--real", metavar="DATASET",
                                     help="Real dataset: reference of every cell and source of the availability order "
                                          "(default: a reference run)."),
    n: int = typer.Option(50, "-n", "--n-traces", metavar="N", min=1, help="Traces per cell."),
    seed: int | None = typer.Option(None, "--seed", metavar="SEED", min=0,
                                    help="Root seed (random when omitted; recorded)."),
    counts: str | None = typer.Option(None, "--counts", metavar="COUNTS",
                                      help="Anchor counts, e.g. 1..6 or 2,3,4,6 (default: 1..number of anchors)."),
    regimes: str = typer.Option("dense,sparse,degraded", "--regimes", metavar="REGIMES",
                                help="Comma-separated channel regimes (nominal, dense, sparse, degraded)."),
    order: str | None = typer.Option(None, "--order", metavar="IDS",
                                     help="Anchor ids in the order they are added (default: decreasing availability)."),
    workers: int | None = typer.Option(None, "--workers", metavar="N", min=1, help="Processes (default: all cores)."),
    tracker_traces: int = typer.Option(50, "--tracker-traces", metavar="N", min=0,  # studies.anchors.TRACKER_TRACES
                                       help="Traces per cell the ls and ekf trackers run on (traces 0..N-1 of "
                                            "every cell; 0: no tracker column)."),
    out: Path = typer.Option(..., "--out", "-o", metavar="DIR",
                             help="Output folder (table.json, table.md, anchors.png)."),
    figures: bool = typer.Option(True, "--figures/--no-figures", help="Draw the figure (needs matplotlib)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a study already in --out."),
    force: bool = typer.Option(False, "--force", help=FORCE_HELP),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Anchor count x channel regime study (paper section IV.B: Table III, Figure 6)."""
    from ..io.safety import check_study_output
    from ..io.scenario_file import load_scenario
    from ..studies.anchors import write_anchor_study
    from ..validate.render import require_matplotlib
    from ..workflows import anchor_study

    check_study_output(out, marker="table.json", what="an anchor study", overwrite=overwrite,  # before the work
                       inputs=[real] if real is not None else [])
    scn = load_scenario(scenario)
    chosen = None if counts is None else parse_counts(counts, len(scn.anchors))
    if figures:
        require_matplotlib()
    with progress_bar(not quiet) as progress:
        study = anchor_study(scn, real=real, n=n, seed=seed, counts=chosen,
                             regimes=[r.strip() for r in regimes.split(",") if r.strip()],
                             order=_ids(order), workers=workers, tracker_traces=tracker_traces,
                             progress=progress, force=force)
    written = write_anchor_study(study, out, figures=figures, overwrite=overwrite)
    if quiet:
        return
    _echo_wrapped(f"order: {', '.join(study.order)} ({ORDER_SOURCES[study.reference['order_source']]})")
    counts_ = sorted(study.counts, reverse=True)
    typer.echo("anchors " + " ".join(f"{r:>9s}" for r in study.scores))
    for k in counts_:
        typer.echo(f"{k:7d} " + " ".join(f"{study.scores[r][k]:9.3f}" for r in study.scores))
    _echo_wrapped(f"wrote {', '.join(written)} to {out} (wall time {study.timing_s['total']:.1f} s on "
                  f"{counted(study.inputs['workers'], 'process', 'processes')})")


def placement_cmd(
    scenario: str = typer.Option("cablecar-descending", "--scenario", "-s", metavar="SCENARIO",
                                 help="Preset name or scenario YAML (path, motion, channel; its anchors are "
                                      "replaced by the chosen candidates)."),
    candidates: Path = typer.Option(..., "--candidates", metavar="FILE",
                                    help="Candidate anchor positions: YAML/JSON list of {id, pos_enu_m} or CSV with "
                                         "columns id,e,n,u."),
    k: int = typer.Option(..., "-k", metavar="K", min=1, help="Number of anchors to place."),
    objective: str = typer.Option("ge1", "--objective", metavar="OBJECTIVE",
                                  help="ge1, ge2 or ge3 (availability: fraction of 10 ms bins with >= 1/2/3 fresh "
                                       "anchors, maximised), gdop (mean capped fresh GDOP, minimised) or hdop (the "
                                       "same with the tag height known)."),
    n: int = typer.Option(20, "-n", "--n-traces", metavar="N", min=1, help="Traces the objective is averaged over."),
    seed: int | None = typer.Option(None, "--seed", metavar="SEED", min=0,
                                    help="Root seed (random when omitted; recorded)."),
    regime: str = typer.Option("nominal", "--regime", metavar="REGIME", help="Channel regime applied to the scenario."),
    workers: int | None = typer.Option(None, "--workers", metavar="N", min=1, help="Processes (default: all cores)."),
    out: Path = typer.Option(..., "--out", "-o", metavar="DIR",
                             help="Output folder (placement.json, placement.md, placement.png, scenario.yaml)."),
    figures: bool = typer.Option(True, "--figures/--no-figures", help="Draw the figure (needs matplotlib)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a placement already in --out."),
    force: bool = typer.Option(False, "--force", help=FORCE_HELP),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Greedy anchor placement: pick K of the candidate positions to maximise availability or minimise GDOP."""
    from ..io.safety import check_study_output
    from ..studies.placement import write_placement
    from ..validate.render import require_matplotlib
    from ..workflows import placement_study

    check_study_output(out, marker="placement.json", what="a placement study", overwrite=overwrite,
                       inputs=[candidates])
    if figures:
        require_matplotlib()
    with progress_bar(not quiet) as progress:
        result = placement_study(scenario, candidates, k=k, objective=objective, n=n, seed=seed, regime=regime,
                                 workers=workers, progress=progress, force=force)
    written = write_placement(result, out, figures=figures, overwrite=overwrite)
    if quiet:
        return
    for step in result.steps:
        typer.echo(f"K={step['k']}: + {step['added']:>10s}  {result.objective} = {step['objective']:.4f}")
    _echo_wrapped(f"wrote {', '.join(written)} to {out}")
