"""``physynth study``: deployment studies on the generator.

    physynth study anchors   --scenario S [--real DATASET] [-n 50] [--seed S] [--counts 1..6]
                             [--regimes dense,sparse,degraded] [--order A,B,...] [--tracker-traces 50] --out DIR
    physynth study placement --scenario S --candidates FILE -k K [--objective ge1|ge2|ge3|gdop|hdop] --out DIR

Thin commands over :mod:`physynth.workflows`; bad input is one line on stderr and exit code 2.
"""

from __future__ import annotations

from pathlib import Path

import typer

from ._common import counted, progress_bar

study_app = typer.Typer(help="Studies: anchor count x channel regime, anchor placement, tracking (Table IV).",
                        no_args_is_help=True)


def register(app: typer.Typer) -> None:
    """Add the ``study`` command group to the main app."""
    study_app.command("anchors")(anchors_cmd)
    study_app.command("placement")(placement_cmd)
    from .track import tracking_cmd  # torch is imported only when the study runs

    study_app.command("tracking")(tracking_cmd)
    app.add_typer(study_app, name="study")


def parse_counts(text: str) -> list[int]:
    """``"1..6"``, ``"2,3,6"`` or ``"1..3,6"`` -> sorted unique ints; one-line error otherwise."""
    from ..errors import PhySynthError

    out: set[int] = set()
    try:
        for part in text.split(","):
            part = part.strip()
            if ".." in part:
                lo, hi = (int(v) for v in part.split(".."))
                if hi < lo:
                    raise ValueError
                out.update(range(lo, hi + 1))
            else:
                out.add(int(part))
    except ValueError:
        raise PhySynthError(f"--counts: expected a range like 1..6 or a list like 2,3,6, got '{text}'") from None
    return sorted(out)


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
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Anchor count x channel regime study (paper section IV.B: Table III, Figure 6)."""
    from ..io.safety import check_study_output
    from ..studies.anchors import write_anchor_study
    from ..validate.render import require_matplotlib
    from ..workflows import anchor_study

    check_study_output(out, marker="table.json", what="an anchor study", overwrite=overwrite,  # before the work
                       inputs=[real] if real is not None else [])
    if figures:
        require_matplotlib()
    with progress_bar(not quiet) as progress:
        study = anchor_study(scenario, real=real, n=n, seed=seed,
                             counts=None if counts is None else parse_counts(counts),
                             regimes=[r.strip() for r in regimes.split(",") if r.strip()],
                             order=_ids(order), workers=workers, tracker_traces=tracker_traces,
                             progress=progress)
    written = write_anchor_study(study, out, figures=figures, overwrite=overwrite)
    if quiet:
        return
    typer.echo(f"order: {', '.join(study.order)} (reference: {study.reference['kind']}); "
               f"{study.timing_s['total']:.1f} s on {counted(study.inputs['workers'], 'process', 'processes')}")
    counts_ = sorted(study.counts, reverse=True)
    typer.echo("anchors " + " ".join(f"{r:>9s}" for r in study.scores))
    for k in counts_:
        typer.echo(f"{k:7d} " + " ".join(f"{study.scores[r][k]:9.3f}" for r in study.scores))
    typer.echo(f"wrote {', '.join(written)} to {out}")


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
                                 workers=workers, progress=progress)
    written = write_placement(result, out, figures=figures, overwrite=overwrite)
    if quiet:
        return
    for step in result.steps:
        typer.echo(f"K={step['k']}: + {step['added']:>10s}  {result.objective} = {step['objective']:.4f}")
    typer.echo(f"wrote {', '.join(written)} to {out}")
