"""CPU time per trace in a plain process and inside a one-thread Dask worker, side by side.

    python benchmarks/bench_dask_overhead.py [-n 60] [--rounds 2]

The same loop of ``generate_trace`` (default preset) runs in this process, in a worker of a
``LocalCluster`` with Dask's default settings, and in one with ``physynth.parallel.WORKER_CONFIG``
(what ``physynth generate --workers N`` uses). The worker's figure is the process CPU time of the task,
so it includes what the worker's other threads (profiler, event-loop tick, memory monitor) burn
meanwhile. Alternated ``--rounds`` times; each line prints ms of CPU per trace.
"""

from __future__ import annotations

import argparse
import logging
import time


def work(n: int) -> float:
    """CPU ms per trace of n default-preset traces in the calling process."""
    from physynth.generate import compile_scenario, generate_trace
    from physynth.io.scenario_file import load_scenario

    cs = compile_scenario(load_scenario("cablecar-descending"))
    generate_trace(cs, 0, 0)
    t0 = time.process_time()
    for i in range(n):
        generate_trace(cs, i, 1)
    return 1e3 * (time.process_time() - t0) / n


def in_worker(n: int, config: dict) -> float:
    import dask
    import distributed

    with dask.config.set(config), distributed.LocalCluster(
            n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0",
            silence_logs=logging.ERROR) as cluster, distributed.Client(cluster) as client:
        client.submit(work, 2, pure=False).result()  # warm-up: imports in the worker
        return client.submit(work, n, pure=False).result()


def main() -> None:
    from physynth.parallel import WORKER_CONFIG

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    for _ in range(args.rounds):
        plain = work(args.n)
        default = in_worker(args.n, {})
        quiet = in_worker(args.n, WORKER_CONFIG)
        print(f"CPU per trace: plain process {plain:.2f} ms, Dask worker (defaults) {default:.2f} ms "
              f"({default / plain:.2f}x), Dask worker (WORKER_CONFIG) {quiet:.2f} ms ({quiet / plain:.2f}x)")


if __name__ == "__main__":
    main()
