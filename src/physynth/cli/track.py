"""``physynth study tracking``: the tracking case study (Table IV) on real runs.

Parses the options, calls :func:`physynth.studies.tracking.run_tracking_study`, writes the results and
prints the table. Bad input (no truth in the test run, a training run without UWB, an unknown method,
torch missing) is one line on stderr and exit 2 (raised as ``PhySynthError`` and turned into that line
by :func:`physynth.cli.main`).

The command joins the ``study`` group of :mod:`physynth.cli.study`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import typer

from ..errors import PhySynthError

FRAMES = {"route": {"route_frame": True, "random_isometry": False},
          "turned": {"route_frame": False, "random_isometry": True},
          "compass": {"route_frame": False, "random_isometry": False}}
"""``--frame`` choices and the study settings each one stands for."""

_NETWORKS = ("NOAUG", "AUG_GAN", "SYNTH_PHY", "bilstm")  # studies.tracking.NETWORK_METHODS, not imported here
_SYNTH = ("SYNTH_PHY",)
METHOD_OPTIONS = {"epochs": ("--epochs", ("NOAUG", "AUG_GAN", "bilstm")), "scenario": ("--scenario", _SYNTH),
                  "pretrain_epochs": ("--pretrain-epochs", _SYNTH), "finetune_epochs": ("--finetune-epochs", _SYNTH),
                  "n_synth_traces": ("--n-synth", _SYNTH), "synth_windows_per_trace": ("--synth-windows", _SYNTH),
                  "finetune_synth_ratio": ("--finetune-synth-ratio", _SYNTH), "ekf_prior": ("--ekf-prior", _NETWORKS),
                  "lr_schedule": ("--lr-schedule", _NETWORKS), "weight_average": ("--weight-average", _NETWORKS),
                  "frame": ("--frame", _NETWORKS), "ensemble": ("--ensemble", _NETWORKS),
                  "synth_nlos_spread": ("--synth-nlos-spread", _SYNTH), "synth_layouts": ("--synth-layouts", _SYNTH)}
"""Options (by the study setting they give) that set up some methods only, with those methods: given without
any of them, an option is refused, not silently ignored. ``--frame``
sets up how the networks see direction; ``--ensemble`` averages seeds, and the classical trackers draw none."""


SYNTH_LAYOUTS = ("drawn", "training")
"""``--synth-layouts`` choices."""
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
    from ..io.safety import check_study_output
    from ..studies.protocol import PROTOCOLS, plan, run_protocol
    from ..studies.protocol_report import write_protocol_results
    from ..studies.tracking import NETWORK_METHODS
    from ..track import require_torch

    check_study_output(out, marker="results.json", what="a tracking study", overwrite=overwrite,  # before the work
                       inputs=[*(train or []), *(test or [])])
    from ..studies.tracking_config import read_study_settings

    file_settings = read_study_settings(config) if config is not None else {}
    # "" is no method, as "," is (StudyConfig refuses it); leaving --methods out runs the file's or all
    chosen = tuple(m.strip() for m in methods.split(",") if m.strip()) if methods is not None else None
    if frame is not None and frame not in FRAMES:
        raise PhySynthError(f"--frame must be one of {', '.join(FRAMES)}, got '{frame}'")
    over = {"seed": seed, **FRAMES.get(frame, {})}
    over |= _given(methods=chosen, threads=threads, epochs=epochs, pretrain_epochs=pretrain_epochs,
                   finetune_epochs=finetune_epochs,
                   n_synth_traces=n_synth, synth_windows_per_trace=synth_windows, ekf_prior=ekf_prior,
                   finetune_synth_ratio=finetune_synth_ratio, train_trusted_truth=train_trusted_truth or None,
                   ensemble=ensemble if ensemble > 1 else None,
                   jobs=jobs if jobs is not None and jobs > 1 and ensemble > 1 else None)
    over |= _synth_variation(synth_nlos_spread, synth_layouts, file_settings.get("variation"))
    over |= _height(tag_height, tag_height_std, no_height)
    net = {**file_settings.get("net", {}), **_given(lr_schedule=lr_schedule, weight_average=weight_average)}
    over |= {"net": net} if net else {}
    cfg = _config(over, quick, None if protocol == "survey-only" else scenario, frame,  # survey-only: every method's
                  flags={"synth_nlos_spread": synth_nlos_spread, "synth_layouts": synth_layouts}, base=file_settings)
    if NETWORK_METHODS & set(cfg.methods):
        require_torch()
    if protocol is not None and protocol not in PROTOCOLS:
        raise PhySynthError(f"--protocol must be one of {', '.join(PROTOCOLS)}, got '{protocol}'")
    if protocol == "survey-only" and scenario is None:
        raise PhySynthError("--protocol survey-only needs --scenario: the site's scenario (its anchors, route and "
                            "channel) is all it trains on")
    train_runs, test_runs = _load_runs(train, test, protocol)
    scn = _scenario(scenario)
    if turn_test or mirror_test:
        if not test_runs:
            raise PhySynthError("--turn-test and --mirror-test turn the --test runs: give --test")
        test_runs = _turned(test_runs, turn_test, mirror_test)
    seed_list = list(range(seed, seed + seeds))
    _, folds, used = plan(train_runs, test_runs, protocol, seed_list, cfg)
    n_studies = len(folds) * len(used)
    if jobs is not None and jobs > 1 and ensemble == 1 and n_studies == 1:
        raise PhySynthError(f"--jobs {jobs} runs several studies at once, and this is one study (one fold, one "
                            "seed): give --seeds N, or --ensemble K to train K members at once")
    # with an ensemble, --jobs trains its members at once; else the studies, by default one per core
    study_jobs = 1 if ensemble > 1 else jobs or min(n_studies, len(os.sched_getaffinity(0)))
    if quiet:
        res = run_protocol(train_runs, test_runs, protocol=protocol, seeds=seed_list, scenario=scn, config=cfg,
                           jobs=study_jobs)
    else:
        from ._common import status_lines

        with status_lines("tracking study") as say:
            res = run_protocol(train_runs, test_runs, protocol=protocol, seeds=seed_list, scenario=scn, config=cfg,
                               jobs=study_jobs, progress=say)
    single = len(res.studies) == 1
    files = write_single(res, out) if single else write_protocol_results(res, out)
    warnings = dict.fromkeys(w for s in res.studies for w in s.data.get("warnings", []))
    for warning in warnings:  # even with --quiet: these seconds are in every row
        typer.echo(f"warning: {warning}", err=True)
    if quiet:
        return
    if single:
        _print_table(res.studies[0], [i.label for i in res.studies[0].test_inputs])
    _print_runs(res)
    typer.echo(f"wrote {', '.join(str(f) for f in files.values())} (wall time {res.wall_time_s:.0f} s)")


def _config(over: dict[str, Any], quick: bool, scenario: str | None, frame: str | None = None,
            flags: dict[str, Any] | None = None, base: dict[str, Any] | None = None) -> Any:
    """The study's configuration from the settings of the options given (``over``), over those of a
    configuration file (``base``; ``--quick``: its schedule for the rest); an option of :data:`METHOD_OPTIONS`
    given when none of the methods it sets up runs is refused (``flags``: options given that are not settings
    of their own, such as the parts of ``variation``); a file's settings are not options, and not refused."""
    from ..studies.tracking import StudyConfig, quick_config

    def make(settings: dict[str, Any]) -> Any:
        merged = {**(base or {}), **settings}
        return quick_config(**merged) if quick else StudyConfig(**merged)

    # bad values first, then options without use (named by their flag), then the ensemble's own settings
    cfg = make({k: v for k, v in over.items() if k not in ("ensemble", "jobs")})
    given = {**over, **over.get("net", {}), "scenario": scenario, "frame": frame, **(flags or {})}
    for name, (flag, users) in METHOD_OPTIONS.items():
        if given.get(name) is not None and not set(users) & set(cfg.methods):
            which = users[0] if len(users) == 1 else f"{', '.join(users[:-1])} or {users[-1]}"
            raise PhySynthError(f"{flag} only matters for {which}, which --methods leaves out "
                                f"({','.join(cfg.methods)}): add {'it' if len(users) == 1 else 'one'} or leave {flag} "
                                "out")
    return make(over)


def _scenario(name: str | None):
    """The ``--scenario`` given (a preset name or a file), or None: SYNTH_PHY calibrates its own."""
    if name is None:
        return None
    from ..io.scenario_file import load_scenario

    return load_scenario(name)


def _synth_variation(nlos_spread: float | None, layouts: str | None = None, base: Any = None) -> dict[str, Any]:
    """``--synth-nlos-spread`` and ``--synth-layouts``: the study's pre-training variation (``base``, a
    configuration file's, else the default) with that NLOS spread and those layouts ({} when neither is given)."""
    if nlos_spread is None and layouts is None:
        return {}
    from ..studies.tracking import StudyConfig

    if layouts not in (None, *SYNTH_LAYOUTS):
        raise PhySynthError(f"--synth-layouts must be one of {', '.join(SYNTH_LAYOUTS)}, got '{layouts}'")
    v = base if base is not None else StudyConfig().variation
    if nlos_spread is not None:
        v = v.model_copy(update={"nlos_log_std": nlos_spread})
    if layouts == "training":
        v = v.model_copy(update={"layout_distribution": None})
    return {"variation": v}


def _given(**options: object) -> dict[str, object]:
    """The options the user gave (None: left to the schedule's default)."""
    return {k: v for k, v in options.items() if v is not None}


def _load_runs(train: list[Path] | None, test: list[Path] | None, protocol: str | None) -> tuple[list, list]:
    """The runs and the test runs: the datasets given, or the default Hanyang runs (all four, held out by
    the protocol; the split protocol trains on the first three and tests on the last)."""
    from ..studies.tracking import hanyang_default_runs, runs_from_dataset

    def runs(paths: list[Path] | None) -> list:
        return [r for p in paths or [] for r in runs_from_dataset(p)]

    if protocol == "survey-only":
        if train:
            raise PhySynthError("--protocol survey-only trains on no real run: leave --train out")
        if test:
            return [], runs(test)
        train_runs, test_run = hanyang_default_runs()
        return [], [*train_runs, test_run]
    if test and not train:
        raise PhySynthError("--test needs --train (or --protocol survey-only with --scenario)")
    if train:
        if protocol == "split" and not test:
            raise PhySynthError("--protocol split trains on --train and scores --test: give --test")
        return runs(train), runs(test)
    train_runs, test_run = hanyang_default_runs()
    if protocol == "split":
        return train_runs, [test_run]
    return [*train_runs, test_run], []


def _turned(runs: list, turn_deg: float, mirror: bool) -> list:
    """``--turn-test`` / ``--mirror-test``: the test runs turned about their anchor centroids."""
    import dataclasses
    import math

    from ..transform import turn_trace

    if not math.isfinite(turn_deg):
        raise PhySynthError(f"--turn-test must be a finite angle in degrees, got {turn_deg}")
    how = f"turned {turn_deg:g} deg" + (", mirrored" if mirror else "")
    return [dataclasses.replace(r, label=f"{r.label} ({how})",
                                trace=turn_trace(r.trace, math.radians(turn_deg), mirror=mirror)) for r in runs]


def _height(tag_height: float | None, tag_height_std: float, no_height: bool) -> dict[str, Any]:
    """The study's height settings of ``--tag-height`` / ``--tag-height-std`` / ``--no-height``."""
    if no_height and tag_height is not None:
        raise PhySynthError("--no-height and --tag-height exclude each other")
    if no_height:
        return {"height": "none"}
    if tag_height is None:
        return {}
    return {"height": "given", "tag_height_m": tag_height, "tag_height_std_m": tag_height_std}


def write_single(res, out: Path) -> dict[str, Path]:
    """One study's files (:func:`physynth.studies.tracking_report.write_results`) with the per-run table in
    ``results.json`` (``per_run``) and ``results.md``."""
    import json

    from ..io.atomic import atomic_write_text
    from ..studies.protocol_report import protocol_markdown
    from ..studies.tracking_report import write_results

    files = write_results(res.studies[0], out)
    data = json.loads(files["json"].read_text())
    data["protocol"] = {k: v for k, v in res.to_json().items() if k != "config"}
    atomic_write_text(files["json"], json.dumps(data, indent=1, allow_nan=True) + "\n")
    atomic_write_text(files["md"], files["md"].read_text() + "\n" + protocol_markdown(res))
    return files


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
