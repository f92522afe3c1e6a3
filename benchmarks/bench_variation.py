"""CPU time per trace of the default preset with and without a ``variation`` section, side by side.

    python benchmarks/bench_variation.py [-n 60] [--rounds 3]

Four scenarios, alternated ``--rounds`` times, ``-n`` traces each: the preset (one site), the preset
with a ``variation`` section of default values (anchor layout and path drawn per trace: the path's
geometry is rebuilt for every trace), with ``random_route_prob: 1.0`` (every trace on a random route) and
with ``layout_distribution: {}`` (a whole layout of 3-6 anchors per trace, its channel tables rebuilt).
Prints the best and every round's CPU milliseconds per trace (process time: less sensitive to the
machine's other load than wall time).
"""

from __future__ import annotations

import argparse
import time

from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import load_scenario
from physynth.scenario import scenario_from_dict, scenario_to_dict


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=60, help="traces per scenario and round")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    base = load_scenario("cablecar-descending")
    variants = {"one site": base}
    for label, section in (("variation (defaults)", {}), ("variation, random routes", {"random_route_prob": 1.0}),
                           ("variation, drawn layouts", {"layout_distribution": {}})):
        d = scenario_to_dict(base)
        d["variation"] = section
        variants[label] = scenario_from_dict(d, label)
    compiled = {k: compile_scenario(s) for k, s in variants.items()}
    for cs in compiled.values():
        generate_trace(cs, 0, 0)  # warm-up
    ms: dict[str, list[float]] = {k: [] for k in compiled}
    for r in range(args.rounds):
        for k, cs in compiled.items():
            t0 = time.process_time()
            for i in range(args.n):
                generate_trace(cs, i, r)
            ms[k].append(1e3 * (time.process_time() - t0) / args.n)
    for k, v in ms.items():
        print(f"{k:26s} CPU ms per trace, best of {args.rounds} x {args.n}: {min(v):.2f} "
              f"(rounds: {', '.join(f'{x:.2f}' for x in v)})")


if __name__ == "__main__":
    main()
