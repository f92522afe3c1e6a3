"""A seeded fuzz campaign through the command line (docs/reliability.md).

    python -m physynth.testing.fuzz --n 10000 --seed 0 [--timeout 10] [--json]

Each input is one of three kinds, mutated from a small valid base by a seeded generator:

- ``scenario``: a scenario YAML with one to three mutated fields (special numbers, wrong types, missing
  or unknown keys, emptied lists, alias bombs, truncated or garbled text), run as ``physynth generate``;
- ``dataset``: a copy of a valid dataset with one file truncated, bit-flipped, zeroed, extended,
  removed, or its ``dataset.json`` edited, read by ``physynth inspect --json`` or ``physynth verify``;
- ``recording``: a CSV recording with wrong or missing columns, times in ms/us/ns, ranges in mm, text
  cells, truncated or bit-flipped files, imported by ``physynth import csv``.

Every input runs through :func:`physynth.cli.main` in process under a time limit, and its outcome is
one of ``ok`` (exit 0 and the output checked complete), ``refused`` (exit 2, one line), ``system``
(exit 1, one line), or a failure: ``crash`` (exit 3 or an exception escaping ``main``), ``hang`` (over
the time limit), ``false_success`` (exit 0 with a missing, incomplete or damaged output, or exit 0 on a
damaged dataset) and ``multi_line`` (a message that is not one line). The command prints the counts
and exits 1 if any failure was found. The size budget is lowered to ``--budget-mb`` for the campaign,
so every accepted scenario generates in well under the time limit.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import io
import json
import os
import shutil
import signal
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

FAILURES = ("crash", "hang", "false_success", "multi_line")
OUTCOMES = ("ok", "refused", "system", *FAILURES)


class _Hang(BaseException):
    """Raised by the alarm when one input runs over the time limit."""


# ------------------------------------------------------------------ bases
def base_scenario() -> dict[str, Any]:
    """A 20 s walk past three anchors with every model switched on (a trace in milliseconds)."""
    return {
        "name": "fuzz-walk",
        "path": {"kind": "waypoints", "waypoints_enu_m": [[0, 0, 1], [30, 5, 1], [60, 0, 1]],
                 "perturbation": {"lateral_std_m": 0.5, "sag_std_m": 0.1}},
        "motion": {"cruise_speed_mps": 3.0, "profile": {"kind": "trapezoid", "accel_frac": 0.1, "decel_frac": 0.1},
                   "dwell_start_s": 1.0, "dwell_end_s": 1.0},
        "imu": {"rate_hz": 100.0, "white_noise_density_mps2_per_sqrt_hz": [0.1, 0.1, 0.1],
                "bias_rw_mps2_per_sqrt_s": 0.002, "vibration": {"amplitude_mps2": 0.1, "fundamental_hz": 2.0}},
        "uwb": {"burst_rate_hz": 10.0, "burst_jitter_s": 0.002, "slot_s": 0.001, "nlos_dwell_s": 0.5,
                "zones": [{"s_m": 30.0, "half_width_m": 5.0, "nlos_prob": 0.5}],
                "obstacles": [{"kind": "box", "min_enu_m": [25, -5, 0], "max_enu_m": [28, -2, 4]},
                              {"kind": "wall", "vertices_en_m": [[40, 5], [45, 8]], "top_m": 3.0}]},
        "attitude": {"kind": "pendulum", "pendulum_period_s": 4.0, "pendulum_damping_ratio": 0.1},
        "anchors": [{"id": "A1", "pos_enu_m": [10, 10, 3]}, {"id": "A2", "pos_enu_m": [30, -10, 3]},
                    {"id": "A3", "pos_enu_m": [50, 10, 3]}],
        "channel": {"rate_hz": 9.0, "los_std_m": 0.1, "nlos_prob": 0.1,
                    "nlos_modes": [{"weight": 1.0, "mean_m": 0.5, "std_m": 0.3}]},
        "channel_per_anchor": {"A2": {"rate_hz": 8.0}},
        "availability": {"dropout_prob": 0.05, "outage_onset_prob": 0.01, "outage_mean_s": 2.0},
        "truth_rate_hz": 50.0,
        "grid_rate_hz": 100.0,
    }


def write_base_recording(folder: Path, duration_s: float = 20.0) -> Path:
    """A clean CSV recording (docs/recording-format.md): 10 Hz truth on a circle, 10 Hz bursts of
    3 anchors, 100 Hz IMU, times from 0 s."""
    import pandas as pd

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(3)
    anchors = {"A1": (20.0, 0.0, 2.0), "A2": (0.0, 20.0, 2.0), "A3": (-20.0, 0.0, 2.0)}

    def circle(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ph = 0.2 * t
        pos = np.stack([10 * np.cos(ph), 10 * np.sin(ph), np.ones_like(t)], axis=1)
        acc = -10 * 0.04 * np.stack([np.cos(ph), np.sin(ph), np.zeros_like(t)], axis=1)
        return pos, acc

    t_truth = np.arange(0.0, duration_s + 1e-9, 0.1)
    pos, _ = circle(t_truth)
    t_b = np.arange(0.05, duration_s - 0.1, 0.1)
    t_uwb = (t_b[:, None] + 0.002 * np.arange(3)).ravel()
    aid = np.tile(np.arange(3), t_b.size)
    a_pos = np.array(list(anchors.values()))
    r = np.linalg.norm(circle(t_uwb)[0] - a_pos[aid], axis=1) + rng.normal(0, 0.02, t_uwb.size)
    t_imu = np.arange(0.0, duration_s, 0.01)
    acc = circle(t_imu)[1]
    pd.DataFrame({"anchor_id": list(anchors), "e_m": a_pos[:, 0], "n_m": a_pos[:, 1], "u_m": a_pos[:, 2]}
                 ).to_csv(folder / "anchors.csv", index=False)
    pd.DataFrame({"t_s": t_truth, "e_m": pos[:, 0], "n_m": pos[:, 1], "u_m": pos[:, 2]}
                 ).to_csv(folder / "truth.csv", index=False, float_format="%.6f")
    pd.DataFrame({"t_s": t_uwb, "anchor_id": np.array(list(anchors))[aid], "range_m": r,
                  "burst": np.repeat(np.arange(t_b.size), 3)}).to_csv(folder / "uwb.csv", index=False,
                                                                       float_format="%.6f")
    pd.DataFrame({"t_s": t_imu, "acc_e_mps2": acc[:, 0], "acc_n_mps2": acc[:, 1], "acc_u_mps2": acc[:, 2]}
                 ).to_csv(folder / "imu.csv", index=False, float_format="%.6f")
    return folder


# ------------------------------------------------------------------ mutations
SPECIAL = [0, -1, 1, 0.5, 1e-300, -1e-300, 1e300, -1e300, 1e7, 1e9, 2**63, -(2**63), 3, 7.5, 1e-6,
           "x", "", None, True, [], {}, [0, 0], [1.0, 2.0, 3.0], "nan", ".inf"]


def key_paths(obj: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path (a tuple of dict keys and list indices) to a node of the nested dicts and lists ``obj``."""
    out = [prefix] if prefix else []
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += key_paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += key_paths(v, (*prefix, i))
    return out


def parent_of(obj: Any, path: tuple) -> tuple[Any, Any]:
    """The container holding the node at ``path`` in ``obj``, and its key there (``parent[key]`` is the node)."""
    for p in path[:-1]:
        obj = obj[p]
    return obj, path[-1]


def mutate_scenario(rng: np.random.Generator) -> tuple[str, str]:
    """A mutated scenario as YAML text, and a short description of the mutations."""
    d = base_scenario()
    what = []
    for _ in range(int(rng.integers(1, 4))):
        paths = key_paths(d)
        path = paths[int(rng.integers(len(paths)))]
        parent, key = parent_of(d, path)
        op = rng.choice(["special", "special", "scale", "delete", "unknown", "empty", "kind"])
        name = ".".join(map(str, path))
        if op == "special":
            parent[key] = copy.deepcopy(SPECIAL[int(rng.integers(len(SPECIAL)))])
        elif op == "scale" and isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool):
            parent[key] = parent[key] * float(10.0 ** rng.integers(-8, 9)) * float(rng.choice([1, -1]))
        elif op == "delete":
            if isinstance(parent, dict):
                del parent[key]
            else:
                parent.pop(key)
        elif op == "unknown" and isinstance(parent, dict):
            parent[f"{key}_typo"] = 1.0
        elif op == "empty":
            parent[key] = [] if isinstance(parent[key], list) else {}
        elif op == "kind":
            with contextlib.suppress(KeyError, TypeError, AttributeError):  # path or motion already mangled
                d["path"]["kind"] = str(rng.choice(["polynomial", "waypoints", "spiral"]))
                d["motion"].setdefault("profile", {})["kind"] = str(rng.choice(["trapezoid", "polynomial",
                                                                                 "empirical"]))
        what.append(f"{op} {name}")
    text = yaml.safe_dump(d, sort_keys=False)
    r = rng.random()
    if r < 0.04:
        text = text[: int(rng.integers(len(text)))]
        what.append("truncated text")
    elif r < 0.07:
        text = "a: &a [x,x,x,x,x,x,x,x,x]\n" + "".join(
            f"{chr(98 + i)}: &{chr(98 + i)} [{','.join(['*' + chr(97 + i)] * 9)}]\n" for i in range(9))
        what.append("alias bomb")
    elif r < 0.09:
        text = "name: &n [*n]\n" + text
        what.append("recursive alias")
    elif r < 0.12:
        b = bytearray(text.encode())
        for _ in range(int(rng.integers(1, 6))):
            b[int(rng.integers(len(b)))] = int(rng.integers(256))
        text = b.decode("utf-8", "replace")
        what.append("garbled bytes")
    return text, "; ".join(what)


def mutate_file_bytes(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """Truncate, flip bits, zero a block or append garbage."""
    op = rng.choice(["truncate", "flip", "flip", "zero", "append"])
    if not data:
        return b"x", "garbage into an empty file"
    if op == "truncate":
        n = int(rng.integers(len(data)))
        return data[:n], f"truncated to {n} of {len(data)} bytes"
    if op == "zero":
        a = int(rng.integers(len(data)))
        n = int(rng.integers(1, 64))
        return data[:a] + bytes(min(n, len(data) - a)) + data[a + n:], f"zeroed {n} bytes at {a}"
    if op == "append":
        return data + bytes(rng.integers(0, 256, int(rng.integers(1, 100)), dtype=np.uint8)), "appended garbage"
    b = bytearray(data)
    k = int(rng.integers(1, 9))
    for _ in range(k):
        i = int(rng.integers(len(b)))
        b[i] ^= 1 << int(rng.integers(8))
    return bytes(b), f"flipped {k} bit(s)"


def mutate_dataset(src: Path, dst: Path, rng: np.random.Generator) -> tuple[bool, str]:
    """Copy a dataset and damage one file; returns (a table file was changed, description)."""
    shutil.copytree(src, dst)
    files = sorted(p.name for p in dst.iterdir())
    name = files[int(rng.integers(len(files)))]
    f = dst / name
    if rng.random() < 0.1:
        f.unlink()
        return True, f"removed {name}"
    if name == "dataset.json" and rng.random() < 0.6:
        meta = json.loads(f.read_text())
        key = str(rng.choice(["n_traces", "traces", "files", "schema_version", "generator", "kind"]))
        op = rng.choice(["delete", "special"])
        if op == "delete":
            meta.pop(key, None)
        else:
            meta[key] = copy.deepcopy(SPECIAL[int(rng.integers(len(SPECIAL)))])
        f.write_text(json.dumps(meta))
        return False, f"dataset.json: {op} {key}"
    data = f.read_bytes()
    new, what = mutate_file_bytes(data, rng)
    f.write_bytes(new)
    return name != "dataset.json" and new != data, f"{name}: {what}"


RECORDING_MUTATIONS = ("rename_column", "drop_column", "time_ms", "time_ns", "time_us", "range_mm", "text_cell",
                       "bytes", "shuffle", "duplicate", "empty", "extra_column", "unknown_anchor", "nan_cells")


def mutate_recording(src: Path, dst: Path, rng: np.random.Generator) -> tuple[bool, str]:
    """Copy the base recording and break one table; returns (the units are known wrong, description)."""
    import pandas as pd

    shutil.copytree(src, dst)
    table = str(rng.choice(["truth", "uwb", "imu", "anchors"]))
    f = dst / f"{table}.csv"
    op = str(rng.choice(RECORDING_MUTATIONS))
    if op == "bytes":
        new, what = mutate_file_bytes(f.read_bytes(), rng)
        f.write_bytes(new)
        return False, f"{table}.csv: {what}"
    if op == "empty":
        f.write_text("")
        return False, f"{table}.csv: empty"
    df = pd.read_csv(f, dtype=str, keep_default_na=False)
    col = df.columns[int(rng.integers(len(df.columns)))]
    wrong_units = False
    if op == "rename_column":
        df = df.rename(columns={col: str(rng.choice([f"{col}x", col.replace("_m", "_mm").replace("_s", "_ms"),
                                                      col.upper()]))})
    elif op == "drop_column":
        df = df.drop(columns=[col])
    elif op in ("time_ms", "time_us", "time_ns") and "t_s" in df.columns and table in ("truth", "imu"):
        factor = {"time_ms": 1e3, "time_us": 1e6, "time_ns": 1e9}[op]
        df["t_s"] = (df["t_s"].astype(float) * factor).map(repr)
        wrong_units = True
    elif op == "range_mm" and table == "uwb":
        df["range_m"] = (df["range_m"].astype(float) * 1000).map(repr)
        wrong_units = True
    elif op == "text_cell":
        i = int(rng.integers(len(df)))
        df.loc[df.index[i], col] = str(rng.choice(["x", "", "1e400", "-", "nan", "1,5", "\u00e9"]))
    elif op == "shuffle":
        df = df.sample(frac=1.0, random_state=int(rng.integers(2**31)))
    elif op == "duplicate":
        df = pd.concat([df, df.sample(n=min(5, len(df)), random_state=1)])
    elif op == "extra_column":
        df["extra"] = "1"
    elif op == "unknown_anchor" and "anchor_id" in df.columns:
        df.loc[df.index[0], "anchor_id"] = "ZZ"
    elif op == "nan_cells":
        idx = rng.integers(len(df), size=int(rng.integers(1, 20)))
        df.loc[df.index[idx], col] = "nan"
    df.to_csv(f, index=False)
    return wrong_units, f"{table}.csv: {op} {col}"


# ------------------------------------------------------------------ running
@dataclass
class Campaign:
    """Counts by kind and outcome, and the first examples of each failure."""

    counts: Counter = field(default_factory=Counter)
    by_kind: dict[str, Counter] = field(default_factory=dict)
    examples: dict[str, list[str]] = field(default_factory=dict)
    seconds: float = 0.0
    slowest_s: float = 0.0

    def add(self, kind: str, outcome: str, detail: str) -> None:
        self.counts[outcome] += 1
        self.by_kind.setdefault(kind, Counter())[outcome] += 1
        if outcome in FAILURES and len(self.examples.setdefault(outcome, [])) < 5:
            self.examples[outcome].append(f"{kind}: {detail}")

    @property
    def failures(self) -> int:
        return sum(self.counts[o] for o in FAILURES)

    def to_dict(self) -> dict[str, Any]:
        return {"inputs": sum(self.counts.values()), "outcomes": {o: self.counts[o] for o in OUTCOMES},
                "by_kind": {k: {o: c[o] for o in OUTCOMES if c[o]} for k, c in sorted(self.by_kind.items())},
                "failures": self.failures, "examples": self.examples, "seconds": round(self.seconds, 1),
                "slowest_input_s": round(self.slowest_s, 2)}


def run_cli(args: list[str], timeout_s: float) -> tuple[int | str, str]:
    """Run ``physynth ARGS`` in process; (exit code or "crash"/"hang", stderr)."""
    from ..cli import main

    err = io.StringIO()

    def alarm(signum: int, frame: object) -> None:
        raise _Hang()

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout_s)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                main(args)
                code: int | str = 0
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
            except _Hang:
                code = "hang"
            except Exception as exc:  # noqa: BLE001 - an exception escaping main is what we look for
                print(f"escaped {type(exc).__name__}: {exc}", file=err)
                code = "crash"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    return code, err.getvalue()


def classify(code: int | str, err: str) -> str:
    if code in ("hang", "crash") or code == 3:
        return "hang" if code == "hang" else "crash"
    if code != 0 and (err.count("\n") != 1 or "Traceback" in err):
        return "multi_line"
    return {0: "ok", 1: "system", 2: "refused"}.get(code, "crash")  # type: ignore[arg-type]


def _complete_dataset(out: Path, n_expected: int | None) -> str | None:
    """None when ``out`` is a complete, verified dataset (with ``n_expected`` traces); else why not."""
    from ..errors import PhySynthError
    from ..io import read_dataset

    leftovers = [p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.")]
    if leftovers:
        return f"left {leftovers[0]}"
    try:
        ds = read_dataset(out)
    except PhySynthError as exc:
        return f"output unreadable: {exc}"
    if "files" not in ds.meta:
        return "output has no integrity record"
    if n_expected is not None and len(ds) != n_expected:
        return f"{len(ds)} traces instead of {n_expected}"
    return None


def fuzz(n: int, seed: int = 0, *, timeout_s: float = 10.0, budget_mb: float = 50.0,
         workdir: str | os.PathLike | None = None,
         progress: Callable[[int, Campaign], None] | None = None) -> Campaign:
    """Run ``n`` mutated inputs (seeded) through the command line; return the counts by outcome."""
    from .. import bounds

    rng = np.random.default_rng(seed)
    camp = Campaign()
    saved = bounds.MEMORY_BUDGET_BYTES, bounds.OUTPUT_BUDGET_BYTES
    bounds.MEMORY_BUDGET_BYTES = bounds.OUTPUT_BUDGET_BYTES = budget_mb * 1e6
    tmp_ctx = tempfile.TemporaryDirectory(prefix="physynth-fuzz-") if workdir is None else None
    root = Path(tmp_ctx.name if tmp_ctx else workdir)
    root.mkdir(parents=True, exist_ok=True)
    t_start = time.monotonic()
    try:
        scn_file = root / "base.yaml"
        scn_file.write_text(yaml.safe_dump(base_scenario()))
        base_ds = root / "base-ds"
        code, err = run_cli(["generate", "-s", str(scn_file), "-n", "2", "--seed", "1", "--out", str(base_ds), "-q"],
                            60.0)
        if code != 0:
            raise RuntimeError(f"cannot build the base dataset: {err}")
        base_rec = write_base_recording(root / "base-rec")
        code, err = run_cli(["import", "csv", str(base_rec), "--out", str(root / "base-imp"), "-q"], 60.0)
        if code != 0:
            raise RuntimeError(f"the base recording does not import: {err}")
        for i in range(n):
            case = root / f"case-{i}"
            case.mkdir()
            kind = str(rng.choice(["scenario", "dataset", "recording"], p=[0.4, 0.35, 0.25]))
            t0 = time.monotonic()
            if kind == "scenario":
                text, what = mutate_scenario(rng)
                f = case / "s.yaml"
                f.write_bytes(text.encode("utf-8", "surrogateescape"))
                k = int(rng.integers(1, 4))
                out = case / "out"
                code, err = run_cli(["generate", "-s", str(f), "-n", str(k), "--seed", str(int(rng.integers(2**32))),
                                     "--out", str(out), "-q"], timeout_s)
                outcome = classify(code, err)
                if outcome == "ok":
                    why = _complete_dataset(out, k)
                    if why:
                        outcome, what = "false_success", f"{what}: {why}"
                elif code in (1, 2) and out.exists():
                    outcome, what = "false_success", f"{what}: exit {code} but {out.name} exists"
            elif kind == "dataset":
                ds = case / "ds"
                damaged, what = mutate_dataset(base_ds, ds, rng)
                cmd = str(rng.choice(["inspect", "verify"]))
                code, err = run_cli([cmd, str(ds), *(["--json"] if cmd == "inspect" else ["-q"])], timeout_s)
                outcome = classify(code, err)
                if outcome == "ok" and damaged:
                    outcome = "false_success"
                what = f"{cmd} after {what}"
            else:
                rec = case / "rec"
                wrong_units, what = mutate_recording(base_rec, rec, rng)
                out = case / "imp"
                code, err = run_cli(["import", "csv", str(rec), "--out", str(out), "-q"], timeout_s)
                outcome = classify(code, err)
                if outcome == "ok":
                    why = "wrong units accepted" if wrong_units else _complete_dataset(out, 1)
                    if why:
                        outcome, what = "false_success", f"{what}: {why}"
            dt = time.monotonic() - t0
            camp.slowest_s = max(camp.slowest_s, dt)
            camp.add(kind, outcome, f"{what} -> {str(code)}: {err.strip()[:300]}")
            shutil.rmtree(case, ignore_errors=True)
            if progress is not None:
                progress(i + 1, camp)
    finally:
        bounds.MEMORY_BUDGET_BYTES, bounds.OUTPUT_BUDGET_BYTES = saved
        camp.seconds = time.monotonic() - t_start
        if tmp_ctx is not None:
            tmp_ctx.cleanup()
    return camp


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m physynth.testing.fuzz", description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000, help="number of mutated inputs (default 10000)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the campaign (default 0)")
    ap.add_argument("--timeout", type=float, default=10.0, help="time limit per input [s] (default 10)")
    ap.add_argument("--budget-mb", type=float, default=50.0,
                    help="memory and output budget during the campaign [MB] (default 50)")
    ap.add_argument("--workdir", default=None, help="folder for the inputs (default: a temporary folder)")
    ap.add_argument("--json", action="store_true", help="print the counts as one JSON object")
    args = ap.parse_args(argv)

    def progress(i: int, camp: Campaign) -> None:
        if not args.json and (i % 500 == 0 or i == args.n):
            print(f"  {i}/{args.n}: " + ", ".join(f"{o} {camp.counts[o]}" for o in OUTCOMES if camp.counts[o]),
                  file=sys.stderr, flush=True)

    camp = fuzz(args.n, args.seed, timeout_s=args.timeout, budget_mb=args.budget_mb, workdir=args.workdir,
                progress=progress)
    d = camp.to_dict()
    if args.json:
        print(json.dumps(d, indent=1))
    else:
        print(f"fuzz: {d['inputs']} inputs, seed {args.seed}, time limit {args.timeout:g} s per input, "
              f"{d['seconds']} s in all (slowest input {d['slowest_input_s']} s)")
        for o in OUTCOMES:
            print(f"  {o:14s} {d['outcomes'][o]}")
        for k, c in d["by_kind"].items():
            print(f"  {k:10s} " + ", ".join(f"{o} {v}" for o, v in c.items()))
        for o, ex in d["examples"].items():
            for e in ex:
                print(f"  {o}: {e}")
    return 1 if camp.failures else 0


if __name__ == "__main__":
    sys.exit(main())
