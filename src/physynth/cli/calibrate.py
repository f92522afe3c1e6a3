"""``physynth calibrate``: fit a scenario to one or several recorded datasets.

    physynth calibrate DATASET_DIR [DATASET_DIR...] --out scenario.yaml [--report fit.json]
                       [--path-kind auto|polynomial|waypoints] [--name NAME]
                       [--anchor-layout per-run|strict|first] [--layout-from RUN]
                       [--static-sweeps DIR] [--range-bias dynamic|static] [--link-budget]
                       [--long-outages] [--trusted-truth]
                       [--select-components all|evidence] [--evidence-traces N]
                       [--overwrite] [--quiet]

The command parses, calls :func:`physynth.workflows.calibrate_datasets`, writes the scenario with
:func:`physynth.io.scenario_file.save_scenario` (it loads back with ``load_scenario`` and feeds
``physynth generate``) and the JSON fit report, and prints a short summary table (:func:`print_summary`).
``--select-components evidence`` calibrates with
:func:`physynth.calibrate.held_out.calibrate_selected` instead (the held-out evidence on the datasets' own
runs first, a progress bar while it runs, then the per-component table in the summary). Bad input raises
:class:`~physynth.errors.PhySynthError`, which ``physynth.cli.main`` prints as one line (exit code 2).
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Literal

import typer

from ._common import cli_words, format_table


def register(app: typer.Typer) -> None:
    """Add the ``calibrate`` command to the main app."""
    app.command("calibrate")(calibrate_cmd)


def calibrate_cmd(
    datasets: list[Path] = typer.Argument(..., metavar="DATASET",
                                          help="Dataset directories (real or synthetic), pooled."),
    out: Path = typer.Option(..., "--out", "-o", metavar="FILE", help="Scenario YAML file to write."),
    report: Path | None = typer.Option(None, "--report", metavar="FILE",
                                       help="JSON fit report to write (default: none)."),
    path_kind: Literal["auto", "polynomial", "waypoints"] = typer.Option("auto", "--path-kind",
                                  help="Path geometry: auto, polynomial (degree 10, cable) or waypoints (walk)."),
    name: str | None = typer.Option(None, "--name", metavar="NAME",
                                    help="Scenario name (default: the output file's stem)."),
    anchor_layout: Literal["per-run", "strict", "first"] = typer.Option(
        "per-run", "--anchor-layout",
        help="per-run: datasets may place the anchors differently (each run against its own layout, "
             "channels per anchor id pooled, run-to-run offsets fitted; the scenario generates with the "
             "--layout-from run's layout and records the others); strict: an anchor placed differently "
             "by two datasets is an error; first: the same as per-run with the first dataset's layout "
             "(no --layout-from; kept for scripts that name it). Every policy fits each run against its "
             "own layout."),
    layout_from: str | None = typer.Option(None, "--layout-from", metavar="RUN",
                                           help="With --anchor-layout per-run: the recording (label, its "
                                                "last part such as r1, or 0-based index) whose anchor layout "
                                                "the scenario uses (default: the first)."),
    static_sweeps: Path | None = typer.Option(None, "--static-sweeps", metavar="DIR",
                                              help="Hanyang Static_measurements folder: also fit the range "
                                                   "bias on the static sweeps."),
    range_bias: Literal["dynamic", "static"] = typer.Option("dynamic", "--range-bias",
                                   help="dynamic: range bias per anchor from the recordings; static: the "
                                        "static-sweep slope for every anchor (needs --static-sweeps)."),
    range_bias_law: Literal["log", "linear"] = typer.Option(
        "log", "--range-bias-law",
        help="How the LOS range error grows with distance: log (received-power bias, per decade of range; "
             "the default) or linear (per metre, a clock-scale error). See docs/calibration.md."),
    long_outages: bool = typer.Option(False, "--long-outages",
                                      help="Also generate the long outages the fit finds (multi-second fades "
                                           "whose rate may grow with range; always reported). See "
                                           "docs/calibration.md."),
    tag_pattern: bool = typer.Option(False, "--tag-pattern",
                                     help="Also generate the tag antenna pattern the fit finds (range bias by "
                                          "the anchor's bearing from the direction of travel; always "
                                          "reported). See docs/calibration.md."),
    run_slopes: bool = typer.Option(False, "--run-slopes",
                                    help="Also generate the run-to-run tilts of the range law the fit finds "
                                         "(each trace's error grows with range at its own rate; needs several "
                                         "runs; always reported). See docs/calibration.md."),
    link_budget: bool = typer.Option(False, "--link-budget",
                                     help="Give every anchor a link budget: power law and tag height from the "
                                          "static sweeps, sensitivity from the datasets' own losses, so that "
                                          "detection falls where the ground reflection puts a null (needs "
                                          "--static-sweeps). See docs/calibration.md."),
    trusted_truth: bool = typer.Option(False, "--trusted-truth",
                                       help="Fit the ranging errors only on the ranges whose truth the recording "
                                            "trusts (e.g. RTK-fixed; the share is always reported). See "
                                            "docs/calibration.md."),
    select_components: Literal["all", "evidence"] = typer.Option(
        "all", "--select-components",
        help="all: generate every optional component the fit keeps (the default). evidence: first leave each "
             "run out in turn (calibrate on the others, validate the left-out run with and without each "
             "optional component: late stamps, run-to-run spreads, antenna sway, tag-side NLOS, link budget), "
             "then calibrate on all runs and take out the components whose mean held-out gain is negative; "
             "needs 2 or more runs, and the report gives each component's evidence. Not the default: measured "
             "by leave-one-out on the four Hanyang walks it did not bring the left-out runs closer (mean "
             "deviation 12.69 against 12.61 with all, seed 1; 13.42 against 13.43, seed 2), put the real P95 "
             "outside the band more often and widened the within-burst spread (docs/calibration.md, "
             "\"Selecting components by held-out evidence\")."),
    evidence_traces: int = typer.Option(20, "--evidence-traces", metavar="N",
                                        help="With --select-components evidence: synthetic traces per "
                                             "validation of the evidence."),
    allow_mixed: bool = typer.Option(False, "--allow-mixed",
                                     help="Pool datasets even when they are not the same kind of site."),
    overwrite: bool = typer.Option(False, "--overwrite",
                                   help="Replace existing output files (only files physynth calibrate wrote)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress display or summary."),
) -> None:
    """Calibrate a scenario (path, motion, IMU, UWB, availability) on recorded datasets."""
    from ..calibrate.held_out import check_selection
    from ..errors import PhySynthError
    from ..io.safety import check_distinct, check_output, guarded_outputs

    if layout_from is not None and anchor_layout != "per-run":
        raise PhySynthError("--layout-from needs --anchor-layout per-run")
    with _option_words():
        check_selection(select_components, evidence_traces)
    chosen: int | str | None = int(layout_from) if layout_from is not None and layout_from.isdigit() else layout_from
    inputs = [*datasets, *([static_sweeps] if static_sweeps else [])]
    check_distinct([("--out", out), ("--report", report)])
    for target, kind in [(out, "scenario")] + ([(report, "json")] if report else []):
        check_output(target, kind=kind, overwrite=overwrite, inputs=inputs)
    for target in [out] + ([report] if report else []):  # `--out runs/site.yaml` in a fresh checkout
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise PhySynthError(f"cannot create the output folder {target.parent}: {exc.strerror}") from None
    with guarded_outputs([out] + ([report] if report else [])) as real:  # locks; orphaned temp files removed
        for target, kind in [(out, "scenario")] + ([(report, "json")] if report else []):
            check_output(target, kind=kind, overwrite=overwrite, inputs=inputs)  # again, under the lock
        _calibrate(datasets, out, report, quiet, real[0], real[1] if report else None, name=name or out.stem,
                   path_kind=path_kind, anchor_policy=anchor_layout, layout_from=chosen,
                   static_sweeps=static_sweeps, range_bias=range_bias, range_bias_law=range_bias_law,
                   allow_mixed=allow_mixed,
                   long_outages=long_outages, tag_pattern=tag_pattern, run_slopes=run_slopes,
                   link_budget=link_budget, trusted_truth=trusted_truth,
                   **({"select_components": select_components, "evidence_traces": evidence_traces}
                      if select_components != "all" else {}))


def _calibrate(datasets: list[Path], out: Path, report: Path | None, quiet: bool, real_out: Path,
               real_report: Path | None, **kwargs) -> None:
    from .. import __version__
    from .._json import jsonable
    from ..io.scenario_file import save_scenario
    from ..workflows import calibrate_datasets

    if "select_components" in kwargs:
        result = _calibrate_selected(datasets, quiet, **kwargs)
    elif quiet:
        result = calibrate_datasets(datasets, **kwargs)
    else:
        from rich.console import Console

        console = Console(stderr=True)
        with console.status("calibrating") as status:
            def progress(msg: str, done: int | None = None, total: int | None = None) -> None:
                status.update(f"calibrating: {msg}")
                console.print(f"  - {msg}", highlight=False)

            status.update("reading datasets")
            result = calibrate_datasets(datasets, progress=progress, **kwargs)
    header = (f"Calibrated by physynth calibrate on {', '.join(str(d) for d in datasets)}\n"
              f"Fit report: {report if report else '(not written; use --report)'}")
    # both files written under temporary names, then renamed together: an interruption never leaves a new
    # scenario without its report
    from ..io.atomic import atomic_write_text, files_together

    with files_together([real_out, *([real_report] if real_report else [])]) as tmp:
        save_scenario(result.scenario, tmp[0], header=header)
        if real_report:
            marked = {"generator": {"name": "physynth", "version": __version__}, **result.report}  # safety marker
            atomic_write_text(tmp[1], json.dumps(jsonable(marked), indent=1))
    if quiet:
        return
    print_summary(result, out, report)


def _calibrate_selected(datasets: list[Path], quiet: bool, *, allow_mixed: bool, **kwargs):
    """The calibration with ``--select-components evidence``: the held-out evidence under a progress bar."""
    from ..calibrate.held_out import calibrate_selected
    from ..workflows import read_recordings
    from ._common import progress_bar

    traces, sources = read_recordings(datasets, allow_mixed=allow_mixed)
    with progress_bar(enabled=not quiet) as progress, _option_words():
        return calibrate_selected(traces, sources=sources, progress=progress, **kwargs)


@contextmanager
def _option_words() -> Iterator[None]:
    """The selection's parameter errors with the options that set them (``evidence_traces``:
    ``--evidence-traces``), one line through ``physynth.cli.main``."""
    from ..calibrate import CalibrationError
    from ..errors import PhySynthError

    try:
        yield
    except CalibrationError as exc:
        if not re.search(r"\b(select_components|evidence_traces)\b", str(exc)):
            raise
        words = re.sub(r"\b(select_components|evidence_traces)\b", lambda m: "--" + m.group(1).replace("_", "-"),
                       str(exc))
        raise PhySynthError(words.replace("--select-components='evidence'", "--select-components evidence")) from None


def print_summary(result, out: Path, report: Path | None, console=None) -> None:
    """What ``physynth calibrate`` prints after writing ``out`` (and ``report``): the scenario's fitted fields
    (parameter, value, uncertainty), the fit diagnostics, what is not identifiable, the warnings and, when
    the components were selected by held-out evidence, one row per optional component. ``console``: a rich
    Console (default: standard output at the terminal's width)."""
    from rich.console import Console

    console = console or Console()
    _print_rows(console, f"calibrated scenario '{result.scenario.name}'", result.summary_rows())
    diagnostics = result.summary_rows(fields=False)
    if diagnostics:  # goodness of fit, per-anchor fits the scenario pools, ...: no scenario field
        _print_rows(console, "fit diagnostics (not in the scenario)", diagnostics)
    missing = result.report.get("not_identifiable", [])
    if missing:
        console.print(cli_words(f"not identifiable ({len(missing)}): " + "; ".join(missing)), highlight=False)
    for w in result.report.get("warnings", []):
        console.print(f"warning: {cli_words(w)}", highlight=False)
    if "component_selection" in result.report:
        _print_selection(console, result.report)
    console.print(f"wrote {out}" + (f" and {report}" if report else ""))


def _print_selection(console, report: dict) -> None:
    """One row per optional component: fitted or not, its mean held-out gain, kept or taken out."""
    sel = report["component_selection"]
    rows = []
    for name, entry in report["components"].items():
        ev = entry.get("held_out")
        if ev is None:
            continue
        fitted = "yes" if entry["fitted"] else f"no ({cli_words(str(entry.get('why')))})"
        gain = "-" if ev["combined_gain"] is None else f"{ev['combined_gain']:+.2f}"
        rows.append((name, fitted, gain, "taken out" if name in sel["taken_out"] else ev["decision"]))
    console.print(f"components by held-out evidence ({len(sel['held_out_runs'])} runs left out in turn, "
                  f"{sel['n_traces']} traces each; combined gain: mean over runs and measures, > 0 helps)",
                  highlight=False)
    console.print(format_table(("component", "fitted", "combined gain", "selection"), rows), highlight=False)


def _print_rows(console, title: str, rows: list[tuple[str, str, str]]) -> None:
    """A table of (parameter, value, uncertainty) rows under ``title``; where the key, value and uncertainty
    do not fit side by side, each value goes on an indented line under its key."""
    from rich.table import Table

    rows = [(key, value, cli_words(unc)) for key, value, unc in rows]
    # keys are kept whole (a key broken mid-word reads badly); where the key, value and uncertainty do not
    # fit side by side (an IMU's three-axis values beside 53-character keys in 80 columns), each value and
    # its uncertainty go on an indented line under the key instead of wrapping into columns 10 wide
    key_width = max((len(k) for k, _, _ in rows), default=9)
    if console.width - key_width - 10 < 2 * 20:  # value and uncertainty columns of at least 20 each
        console.print(title)
        for key, value, unc in rows:
            console.print(key, highlight=False, overflow="fold")
            console.print(f"    {value}" + (f"   ({unc})" if unc else ""), highlight=False)
    else:
        table = Table(title=title, expand=True)
        table.add_column("parameter", no_wrap=True)
        table.add_column("value", justify="right", overflow="fold", ratio=1)
        table.add_column("uncertainty / samples", justify="right", overflow="fold", ratio=1)
        for key, value, unc in rows:
            table.add_row(key, value, unc)
        console.print(table)
