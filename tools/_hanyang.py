"""The four shared Hanyang Trajectory_A runs as the leave-one-out tools read them (not a tool itself)."""

from __future__ import annotations

import argparse
from pathlib import Path

from physynth.data import HANYANG_TRAJECTORY_A_RUNS
from physynth.io import write_dataset
from physynth.io.importers import import_hanyang
from physynth.records import Trace

DEFAULT_DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb"


def import_runs(data: Path, tmp: Path) -> tuple[dict[str, Path], dict[str, Trace]]:
    """Each run imported with ``crop_to_uwb`` and written as a dataset under ``tmp`` (as
    ``physynth import hanyang RUN --crop-to-uwb`` does): (run name -> dataset folder, run name -> trace)."""
    dirs, traces = {}, {}
    for rel in HANYANG_TRAJECTORY_A_RUNS:
        env, _, case = rel.split("/")
        name = f"{env} {case}"
        trace, _ = import_hanyang(data / "Dynamic_measurements" / rel, crop_to_uwb=True)
        dirs[name] = Path(tmp) / f"{env}-{case}"
        write_dataset(dirs[name], [trace], meta={"kind": "real", "source": "hanyang-uwb"})
        traces[name] = trace
    return dirs, traces


def loo_arguments(ap: argparse.ArgumentParser, n: int) -> None:
    """The options every Hanyang leave-one-out tool takes: the data folder, traces per validation, the seed."""
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="hanyang-uwb folder")
    ap.add_argument("--n", type=int, default=n, help="synthetic traces per validation")
    ap.add_argument("--seed", type=int, default=1)
