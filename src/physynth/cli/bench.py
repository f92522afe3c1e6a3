"""``physynth bench``: generator throughput on this machine (in memory, to Parquet, scaling, memory)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from ._common import counted, format_table, progress_bar


def register(app: typer.Typer) -> None:
    """Add the ``bench`` command to the main app."""
    app.command("bench")(bench_cmd)


def bench_cmd(
    scenario: str = typer.Option("cablecar-descending", "--scenario", "-s", metavar="SCENARIO",
                                 help="Preset name or scenario file."),
    n: int = typer.Option(200, "-n", "--n-traces", metavar="N", min=1, help="Traces per one-worker measurement."),
    workers: int = typer.Option(0, "--workers", "-w", metavar="N", min=0,
                                help="Workers of the scaling measurement (0 = all cores, 1 = skip it)."),
    n_scaling: int = typer.Option(0, "--n-scaling", metavar="N", min=0,
                                  help="Traces of the scaling measurement (0 = twenty times -n)."),
    repeat: int = typer.Option(1, "--repeat", metavar="N", min=1,
                               help="Repetitions of every measurement, best kept (the scaling runs alternate)."),
    exports: bool = typer.Option(False, "--exports", help="Also time each export (hdf5, csv, rosbag2 in MCAP) of the "
                                                          "-n traces against generating them to Parquet, "
                                                          "side by side (ratios)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object (keys traces_per_s_memory, "
                                                       "traces_per_s_parquet, scaling_efficiency, "
                                                       "scaling_efficiency_steady, cluster_start_stop_s, "
                                                       "scaling_caveat, peak_rss_mb, export_vs_parquet)."),
    directory: Path = typer.Option(None, "--dir", metavar="DIR", exists=True, file_okay=False, dir_okay=True,
                                   writable=True, help="Folder to write the measured datasets and exports in "
                                                       "(a new folder inside, removed after; default: the "
                                                       "system's temporary folder): measure on the disk you "
                                                       "will write to."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Measure generation speed: traces/s in memory on one core and to Parquet on one worker (its writer on a
    spare core), scaling, peak memory, and with --exports each export's time against generating the same
    traces to Parquet."""
    from ..bench import run_bench
    from ..io.scenario_file import load_scenario
    from ..parallel import available_cores, require_dask

    scn = load_scenario(scenario)
    if (workers or available_cores()) > 1:
        require_dask()
    with progress_bar(not quiet and not as_json) as progress:
        res = run_bench(scn, n=n, n_scaling=n_scaling, workers=workers, repeat=repeat, exports=exports,
                        directory=directory, progress=progress)
    if res["scaling_caveat"]:  # one line on stderr, also with --json (where the key holds it too)
        typer.echo(f"physynth: warning: {res['scaling_caveat']} (raise --n-scaling)", err=True)
    if as_json:
        typer.echo(json.dumps(res, indent=1))
        return
    eff = res["scaling_efficiency"]
    m = res["machine"]
    rows = [
        ("in memory, 1 core", f"{res['traces_per_s_memory']:.1f} traces/s"),
        ("to Parquet, 1 worker", f"{res['traces_per_s_parquet']:.1f} traces/s"),
        ("on disk", f"{res['mb_per_trace_on_disk']:.2f} MB/trace"),
        (f"scaling, {m['workers']} worker{'s' if m['workers'] != 1 else ''}",
         "-" if eff is None else f"{100 * eff:.0f} %"),
        ("  without the cluster's start", "-" if res["scaling_efficiency_steady"] is None
         else f"{100 * res['scaling_efficiency_steady']:.0f} % (start and stop {res['cluster_start_stop_s']:.1f} s)"),
        ("peak memory", f"{res['peak_rss_mb']:.0f} MB"),
    ]
    ex = res["export_vs_parquet"]
    if ex is not None:
        rows.append(("to Parquet, same traces", f"{ex['parquet_s']:.2f} s (1.00)"))
        rows += [(f"export {fmt}{' (mcap)' if fmt == 'rosbag2' else ''}", f"{ex['export_s'][fmt]:.2f} s "
                  f"({ratio:.2f}x to Parquet)") for fmt, ratio in ex["ratios"].items()]
    typer.echo(format_table(("measure", "value"), rows))
    others = m["others_cpu_share"]
    quiet = "" if others is None else f", other processes {100 * others:.0f} % of the cores during the run"
    typer.echo(f"{scn.name}, n={n}; {counted(m['cores'], 'core')} {m['cpu']}{quiet}")
    typer.echo("(a busy machine lowers every figure)")
