"""Calibration on thin data: calibrate 1, 2 and 3 traces of each cable-car preset for a few seeds and
say which calibrations fail (before the fixes of 2026-11-26, 2 of 18 stopped with an out-of-bounds
parameter: an outage mean of 1e15 s, a link horizon of -18 m).

    .venv/bin/python tools/calibrate_thin_check.py [--seeds 1,2,3] [--counts 1,2,3]
"""

from __future__ import annotations

import argparse
import time

from physynth.calibrate import calibrate
from physynth.generate import generate_traces
from physynth.io.scenario_file import load_scenario

PRESETS = ("cablecar-descending", "cablecar-ascending")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--counts", default="1,2,3")
    args = ap.parse_args()
    failed = total = 0
    for preset in PRESETS:
        scn = load_scenario(preset)
        for n in (int(x) for x in args.counts.split(",")):
            for seed in (int(x) for x in args.seeds.split(",")):
                traces = list(generate_traces(scn, n, seed=seed))
                t0 = time.perf_counter()
                try:
                    res = calibrate(traces, name="thin")
                    msg = f"ok ({len(res.report.get('not_identifiable', []))} not identifiable)"
                except Exception as exc:  # noqa: BLE001 - the point is to list every failure
                    failed += 1
                    msg = f"FAILED {type(exc).__name__}: {str(exc).splitlines()[0][:200]}"
                total += 1
                print(f"{preset:20s} {n} trace(s) seed {seed}: {time.perf_counter() - t0:5.1f} s  {msg}", flush=True)
    print(f"{failed} of {total} calibrations failed")


if __name__ == "__main__":
    main()
