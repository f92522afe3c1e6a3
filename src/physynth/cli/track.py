"""``physynth study tracking``: the tracking case study (Table IV) on real runs.

Parses the options, calls :func:`physynth.workflows.tracking_study` (which sets up, runs and writes the
study) and prints the tables. Bad input (no truth in the test run, a training run without UWB, an unknown
method, torch missing) is one line on stderr and exit 2 (raised as ``PhySynthError`` and turned into that
line by :func:`physynth.cli.main`); the library's errors name its parameters, said here with the options.

The command joins the ``study`` group of :mod:`physynth.cli.study`.
"""

from __future__ import annotations

from pathlib import Path

import typer

from ..errors import PhySynthError

OPTIONS = {"n_synth_traces": "--n-synth", "synth_windows_per_trace": "--synth-windows"}
"""The options of the library's parameters and settings whose option is not their name with dashes."""


def _option(name: str) -> str:
    """The option that gives the parameter or setting ``name`` of :func:`physynth.workflows.tracking_study`."""
    return OPTIONS.get(name, "--" + name.replace("_", "-"))


_PROTOCOL_HELP = ("How runs are held out: leave-one-layout-out (the default where the runs hold two or more anchor "
                  "layouts: each layout in turn is tested, trained on the others), leave-one-run-out (the default "
                  "for one layout), split (--train against --test; the default when --test is given) or "
                  "survey-only (no real training run: SYNTH_PHY pre-trained on --scenario, ls and ekf, scored on "
                  "the runs).")
_ENSEMBLE_HELP = ("Run the study for K seeds from --seed on and score the mean of their estimates (a seed "
                  "ensemble; K times the compute).")
_JOBS_HELP = ("Run this many studies (folds and seeds) at once, each in a process of its own (default: one per "
              "CPU core), or train this many members of a seed ensemble at once (default 1); the results do "
              "not depend on it.")
_TRUSTED_HELP = ("Train the networks only on the steps where the training runs' truth is trusted (their "
                 "recording flags the rest).")
_FRAME_HELP = ("How the networks see direction. turned (default): training windows turned and "
               "mirrored at random, 8 turned copies at test: no prior tied to a heading, so runs "
               "along other directions and of other shapes are tracked. route: every run turned so "
               "that its route, estimated from its own ranges, heads east: a prior on the route's "
               "shape, better on runs shaped like the training runs, lost on other shapes. "
               "compass: the world as recorded: learns the training runs' compass heading, lost on "
               "a run that heads elsewhere.")


def tracking_cmd(
    train: list[Path] = typer.Option(None, "--train", metavar="DATASET",
                                     help="Training dataset directory (repeat for several; every trace is one "
                                          "training run). Default: Hanyang Trajectory_A runs."),
    test: list[Path] = typer.Option(None, "--test", metavar="DATASET", help="Test dataset directory (repeatable)."),
    scenario: str = typer.Option(None, "--scenario", "-s", metavar="SCENARIO",
                                 help="Scenario (preset or YAML) for SYNTH_PHY pre-training instead of calibrating one "
                                      "on the training runs."),
    quick: bool = typer.Option(False, "--quick", help="Short schedule (a few minutes per study on one CPU core)."),
    seed: int = typer.Option(0, "--seed", metavar="SEED", min=0,
                             help="Seed of every random choice (deterministic on CPU)."),
    methods: str = typer.Option(None, "--methods", metavar="METHODS",
                                help="Comma-separated subset of NOAUG,AUG_GAN,SYNTH_PHY,bilstm,ls,ekf (default: all)."),
    epochs: int = typer.Option(None, "--epochs", metavar="N", min=1,
                               help="Epochs of NOAUG, AUG_GAN and bilstm (paper: 200).", hidden=True),
    pretrain_epochs: int = typer.Option(None, "--pretrain-epochs", metavar="N", min=1,
                                        help="SYNTH_PHY pre-training epochs (300).", hidden=True),
    finetune_epochs: int = typer.Option(None, "--finetune-epochs", metavar="N", min=1,
                                        help="SYNTH_PHY fine-tuning epochs (200).", hidden=True),
    n_synth: int = typer.Option(None, "--n-synth", metavar="N", min=1, help="Number of synthetic pre-training traces.",
                                hidden=True),
    synth_windows: int = typer.Option(None, "--synth-windows", metavar="N", min=1,
                                      help="Windows taken from each synthetic trace, evenly spaced over it (quick: "
                                           "48; full: 64).", hidden=True),
    finetune_synth_ratio: float = typer.Option(None, "--finetune-synth-ratio", metavar="RATIO",
                                               help="Synthetic windows kept per real window while SYNTH_PHY fine-tunes "
                                                    "(0: real only).", hidden=True),
    lr_schedule: str = typer.Option(None, "--lr-schedule", metavar="SCHEDULE",
                                    help="Learning rate within each training stage: constant (default) or cosine "
                                         "(falls to 0 over the stage).", hidden=True),
    weight_average: str = typer.Option(None, "--weight-average", metavar="HOW",
                                       help="Weights each training stage ends on: none (its last, default) or swa "
                                            "(the average over the epochs of its second half).", hidden=True),
    ekf_prior: str = typer.Option(None, "--ekf-prior", metavar="HOW", help="How the networks use the classical ekf's "
                                  "position: residual (default: they correct it), input (one more input) or none.",
                                  hidden=True),
    turn_test: float = typer.Option(0.0, "--turn-test", metavar="DEGREES",
                                    help="Turn every test run by this many degrees (counter-clockwise) about the "
                                         "vertical through its anchor centroid: the same ranges along another "
                                         "direction.", hidden=True),
    mirror_test: bool = typer.Option(False, "--mirror-test", help="Mirror every test run (y -> -y about its "
                                     "anchor centroid) before the turn.", hidden=True),
    frame: str = typer.Option(None, "--frame", metavar="FRAME", help=_FRAME_HELP, hidden=True),
    ensemble: int = typer.Option(1, "--ensemble", metavar="K", min=1, help=_ENSEMBLE_HELP, hidden=True),
    jobs: int = typer.Option(None, "--jobs", metavar="N", min=1, help=_JOBS_HELP),
    train_trusted_truth: bool = typer.Option(False, "--train-trusted-truth", help=_TRUSTED_HELP, hidden=True),
    synth_nlos_spread: float = typer.Option(None, "--synth-nlos-spread", metavar="S", min=0.0, max=3.0,
                                            help="Give each synthetic pre-training trace its own NLOS frequency: the "
                                                 "calibrated NLOS probabilities times exp(N(0, S)) (default 0: the "
                                                 "calibrated ones in every trace).", hidden=True),
    synth_layouts: str = typer.Option(None, "--synth-layouts", metavar="HOW",
                                      help="Anchor layouts of the synthetic pre-training traces: drawn (default: each "
                                           "trace a whole layout of its own, 3-6 anchors, 1.5-10 m, heights 0.2-3 m) "
                                           "or training (the training runs' layouts, jittered).", hidden=True),
    protocol: str = typer.Option(None, "--protocol", metavar="PROTOCOL", help=_PROTOCOL_HELP),
    seeds: int = typer.Option(3, "--seeds", metavar="N", min=1,
                              help="Run every fold for N seeds from --seed on; the tables give the mean and spread "
                                   "over seeds and paired tests between methods."),
    tag_height: float = typer.Option(None, "--tag-height", metavar="METRES",
                                     help="The tag's height in the site's frame, known without the ranges (a walker's "
                                          "tag: about 1 m above the ground); default: from the training runs' truth."),
    tag_height_std: float = typer.Option(0.2, "--tag-height-std", metavar="METRES",
                                         help="Spread of --tag-height."),
    no_height: bool = typer.Option(False, "--no-height", help="Give the trackers no tag height: the vertical from the "
                                   "ranges alone."),
    threads: int = typer.Option(None, "--threads", metavar="N", min=1,
                                help="CPU threads for PyTorch (1: small recurrent nets gain nothing from more, and "
                                     "lose a lot on a shared machine).", hidden=True),
    config: Path = typer.Option(None, "--config", metavar="YAML",
                                help="Study configuration file: the study's settings beyond these options (schedules, "
                                     "network settings, pre-training variation; docs/tracking.md, \"Study "
                                     "configuration file\"); the options given here win."),
    out: Path = typer.Option(..., "--out", "-o", metavar="DIR",
                             help="Output folder (results.json, results.md, paths.png)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a tracking study already in --out."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress and no table."),
) -> None:
    """Train NOAUG, AUG_GAN, SYNTH_PHY, bilstm, ls and ekf on real runs; score them on held-out runs.

    Research settings (schedules, network and pre-training options) go in a --config file; their older
    options still work and are listed in docs/tracking.md.
    """
    from functools import partial

    from ..studies.tracking_setup import PARAMETERS, TrackingArgumentError
    from ..workflows import tracking_study

    # "" is no method, as "," is (StudyConfig refuses it); leaving --methods out runs the file's or all
    chosen = tuple(m.strip() for m in methods.split(",") if m.strip()) if methods is not None else None
    settings = {"threads": threads, "epochs": epochs, "pretrain_epochs": pretrain_epochs,
                "finetune_epochs": finetune_epochs, "n_synth_traces": n_synth, "synth_windows_per_trace": synth_windows,
                "ekf_prior": ekf_prior, "finetune_synth_ratio": finetune_synth_ratio,
                "train_trusted_truth": train_trusted_truth or None,
                "net": {"lr_schedule": lr_schedule, "weight_average": weight_average}}
    study = partial(tracking_study, out, train=train, test=test, scenario=scenario, methods=chosen, seed=seed,
                    seeds=seeds, protocol=protocol, quick=quick, config=config, settings=settings, frame=frame,
                    synth_nlos_spread=synth_nlos_spread, synth_layouts=synth_layouts, tag_height=tag_height,
                    tag_height_std=tag_height_std, no_height=no_height, turn_test=turn_test,
                    mirror_test=mirror_test, ensemble=ensemble, jobs=jobs, overwrite=overwrite)
    try:
        if quiet:
            run = study()
        else:
            from ._common import status_lines

            with status_lines("tracking study") as say:
                run = study(progress=say)
    except TrackingArgumentError as exc:  # said with the options
        raise PhySynthError(exc.worded({name: _option(name) for name in PARAMETERS})) from None
    for warning in run.warnings:  # even with --quiet: these seconds are in every row
        typer.echo(f"warning: {warning}", err=True)
    if quiet:
        return
    res = run.result
    if run.single:
        _print_table(res.studies[0], [i.label for i in res.studies[0].test_inputs])
    _print_runs(res)
    typer.echo(f"wrote {', '.join(str(f) for f in run.files.values())} (wall time {res.wall_time_s:.0f} s)")


def _print_runs(res) -> None:
    """Per test run and method: 3-D, horizontal and vertical RMSE (mean ± spread over seeds)."""
    from rich.console import Console
    from rich.table import Table

    spread = len(res.seeds) > 1
    table = Table(title=f"{res.protocol}: per test run" + (f", mean ± std over {len(res.seeds)} seeds" if spread
                                                           else ""), caption="errors in metres")
    table.add_column("test run", ratio=1)
    table.add_column("method", ratio=1)
    for col in ("RMSE", "2D", "vertical", "P95"):
        table.add_column(col, justify="right", no_wrap=True)
    for r in res.summary:
        if r["method"].startswith("ref:"):
            continue
        cells = [f"{r[k]:.3f}" + (f"±{r[k + '_std']:.2f}" if spread else "")
                 for k in ("rmse_m", "rmse_2d_m", "rmse_v_m", "p95_m")]
        table.add_row(r["run"], r["method"], *cells)
    Console().print(table)
    for c in res.comparisons:
        p = c["p_wilcoxon"] if c["p_wilcoxon"] is not None else c["p_ttest"]
        typer.echo(f"{c['method']} against {c['against']}: {c['mean_diff_m']:+.3f} m ({c['rel_diff_pct']:+.1f} %), "
                   f"better in {c['wins']} of {c['n_pairs']}" + ("" if p is None else f", p = {p:.3g}"))


def _print_table(result, test_runs: list) -> None:
    """The study's rows as a table on stdout, readable in 80 columns: short number columns that never
    wrap, and each method's description in its cell under its name."""
    from rich.console import Console
    from rich.table import Table

    from ..studies.tracking_report import compared_with_noaug, missing_text

    delta = compared_with_noaug(result.rows)  # no Δ column without NOAUG, the row it is relative to
    table = Table(title=f"test run {', '.join(test_runs)}",
                  caption="errors in metres" + ("; Δ RMSE: against NOAUG, in %" if delta else ""))
    table.add_column("method", ratio=1)
    for col in ("RMSE", "RMSE 2D", "MAE", "P50", "P95", *(("Δ RMSE",) if delta else ())):
        table.add_column(col, justify="right", no_wrap=True)
    for r in result.rows:
        shown = "-" if r["delta_rmse_pct"] is None else f"{r['delta_rmse_pct']:+.1f}"
        name, _, about = r["method"].partition(" (")
        notes = [n for n in (about.removesuffix(")"), missing_text(r)) if n]  # scored share when not whole
        label = "\n".join([name, *(f"[dim]{n}[/dim]" for n in notes)])
        table.add_row(label, *(f"{r[k]:.3f}" for k in ("rmse_m", "rmse_2d_m", "mae_m", "p50_m", "p95_m")),
                      *((shown,) if delta else ()))
    Console().print(table)
