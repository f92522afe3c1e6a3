"""The Hanyang dataset authors' own position estimates (``LS.csv``, ``ESKF.csv``) as reference rows.

Each file has ``timestamp`` (Unix ns, UWB clock) and ``x, y, z`` [m] in the anchor frame, the frame of the
imported trace. An estimate stamped ``T`` is put on the trace's time base as
``(T - time_origin) - time_offset_s`` (the same UWB-to-truth lag removed as for every tracker), then
interpolated linearly onto the grid steps inside its time span (NaN outside), so that it is scored with
exactly the error definition of :mod:`physynth.track.scoring`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import RecordingError
from .inputs import TrackInput

REFERENCE_FILES = {"ref: authors' LS": "LS.csv", "ref: authors' ESKF": "ESKF.csv"}
"""Row name -> file name of the reference estimates shipped with a Hanyang run."""


def read_reference_csv(path: str | os.PathLike, time_origin_unix_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(t_s (N,), pos (N, 3)) of one estimate file; ``t_s`` relative to ``time_origin_unix_s`` [s]."""
    path = Path(path)
    try:
        df = pd.read_csv(path)
    except (OSError, pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise RecordingError(f"cannot read {path}: {str(exc).splitlines()[0]}") from None
    missing = [c for c in ("timestamp", "x", "y", "z") if c not in df.columns]
    if missing:
        raise RecordingError(f"{path}: missing column(s) {', '.join(missing)}")
    df = df.dropna(subset=["timestamp", "x", "y", "z"])
    stamp_ns = df["timestamp"].to_numpy(dtype=np.float64)
    # integer arithmetic where possible: float64 Unix ns carry ~0.2 us rounding, harmless at 100 Hz
    t_s = (stamp_ns - round(time_origin_unix_s * 1e9)) * 1e-9
    pos = df[["x", "y", "z"]].to_numpy(dtype=np.float64)
    order = np.argsort(t_s, kind="stable")
    return t_s[order], pos[order]


def reference_on_grid(t_s: np.ndarray, pos_m: np.ndarray, inp: TrackInput, time_offset_s: float) -> np.ndarray:
    """(K, 3) ENU [m] estimate on the grid of ``inp`` (NaN outside the estimate's time span)."""
    t = t_s - time_offset_s
    out = np.empty((inp.n_steps, 3))
    for c in range(3):
        out[:, c] = np.interp(inp.t_s, t, pos_m[:, c], left=np.nan, right=np.nan)
    return out


def reference_estimates(run_dir: str | os.PathLike | None, time_origin_unix_s: float | None, inp: TrackInput,
                        time_offset_s: float) -> dict[str, np.ndarray]:
    """Row name -> (K, 3) estimate on the grid, for each reference file present in ``run_dir``."""
    if run_dir is None or time_origin_unix_s is None:
        return {}
    out = {}
    for name, fname in REFERENCE_FILES.items():
        f = Path(run_dir) / fname
        if f.is_file():
            t_s, pos = read_reference_csv(f, time_origin_unix_s)
            out[name] = reference_on_grid(t_s, pos, inp, time_offset_s)
    return out
