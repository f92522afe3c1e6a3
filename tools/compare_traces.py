"""Check that two versions of PhySynth generate the same traces, bit for bit.

    PYTHONPATH=<old>/src python tools/compare_traces.py dump old.npz [-n 20] [--seed 2026]
    PYTHONPATH=<new>/src python tools/compare_traces.py dump new.npz [-n 20] [--seed 2026]
    python tools/compare_traces.py compare old.npz new.npz

``dump`` writes every array of every record (truth, IMU, UWB, anchors) and every metadata value of
traces 0 .. n-1 of both cable-car presets, each with the ENU IMU, ENU + body-frame IMU and body-frame
IMU only, into one ``.npz``. ``compare`` checks that both files hold the same arrays with the same
dtype, shape and bytes (so NaN and -0.0 must match too) and exits 1 naming the first differences.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np


def dump(out: str, n: int, seed: int) -> None:
    from physynth.constants import IMU_BODY_FRAME, IMU_FRAME
    from physynth.generate import compile_scenario, generate_trace
    from physynth.io.scenario_file import load_scenario

    arrays = {}
    for preset in ("cablecar-descending", "cablecar-ascending"):
        base = load_scenario(preset)
        for label, frames in (("enu", [IMU_FRAME]), ("enu+body", [IMU_FRAME, IMU_BODY_FRAME]),
                              ("body", [IMU_BODY_FRAME])):
            cs = compile_scenario(base.model_copy(update={"imu_frames": frames}))
            for i in range(n):
                tr = generate_trace(cs, i, seed)
                for part in ("truth", "imu", "uwb", "anchors"):
                    rec = getattr(tr, part)
                    for f in dataclasses.fields(rec):
                        v = getattr(rec, f.name)
                        if isinstance(v, np.ndarray):
                            arrays[f"{preset}/{label}/{i}/{part}.{f.name}"] = v
                for k, v in tr.meta.items():
                    arrays[f"{preset}/{label}/{i}/meta.{k}"] = np.asarray(v)
    np.savez(out, **arrays)
    print(f"{len(arrays)} arrays written to {out}")


def compare(a_path: str, b_path: str) -> int:
    a, b = np.load(a_path), np.load(b_path)
    missing = sorted(set(a.files) ^ set(b.files))
    bad = [k for k in sorted(set(a.files) & set(b.files))
           if a[k].dtype != b[k].dtype or a[k].shape != b[k].shape or a[k].tobytes() != b[k].tobytes()]
    print(f"{len(a.files)} arrays compared: {len(bad)} differ, {len(missing)} in one file only")
    for k in (missing + bad)[:10]:
        print("  ", k)
    return 1 if bad or missing else 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("dump")
    d.add_argument("out")
    d.add_argument("-n", type=int, default=20)
    d.add_argument("--seed", type=int, default=2026)
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args()
    if args.cmd == "dump":
        dump(args.out, args.n, args.seed)
    else:
        sys.exit(compare(args.a, args.b))


if __name__ == "__main__":
    main()
