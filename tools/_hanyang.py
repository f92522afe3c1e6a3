"""The four shared Hanyang Trajectory_A runs as the leave-one-out tools read them (not a tool itself)."""

from __future__ import annotations

import argparse
from pathlib import Path

from physynth.io import write_dataset
from physynth.io.importers import import_hanyang
from physynth.records import Trace

RUNS = (("LOS", "Case_1"), ("LOS", "Case_2"), ("NLOS", "Case_1"), ("NLOS", "Case_2"))
DEFAULT_DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb"


def import_runs(data: Path, tmp: Path) -> tuple[dict[str, Path], dict[str, Trace]]:
    """Each run imported with ``crop_to_uwb`` and written as a dataset under ``tmp`` (as
    ``physynth import hanyang RUN --crop-to-uwb`` does): (run name -> dataset folder, run name -> trace)."""
    dirs, traces = {}, {}
    for env, case in RUNS:
        name = f"{env} {case}"
        trace, _ = import_hanyang(data / "Dynamic_measurements" / env / "Trajectory_A" / case, crop_to_uwb=True)
        dirs[name] = Path(tmp) / f"{env}-{case}"
        write_dataset(dirs[name], [trace], meta={"kind": "real", "source": "hanyang-uwb"})
        traces[name] = trace
    return dirs, traces


def loo_arguments(ap: argparse.ArgumentParser, n: int) -> None:
    """The options every Hanyang leave-one-out tool takes: the data folder, traces per validation, the seed."""
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="hanyang-uwb folder")
    ap.add_argument("--n", type=int, default=n, help="synthetic traces per validation")
    ap.add_argument("--seed", type=int, default=1)
