"""Time of ``physynth validate`` with N synthetic traces (default 50): generating and reducing the
traces, drawing the figures and writing the report, and peak memory. A benchmark that prints figures,
not a timed test; the target is under 60 s for 50 traces on one core.

    python benchmarks/bench_validate.py [--scenario NAME] [-n N] [--real DATASET] [--repeat R]

Without ``--real``, the real side is one trace of the scenario (seed 2026), so every figure (IMU ones
included) is drawn. Runs on one core: BLAS threads pinned to 1 and the process bound to one CPU.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from physynth.generate import generate_trace  # noqa: E402
from physynth.io import write_dataset  # noqa: E402
from physynth.io.scenario_file import load_scenario  # noqa: E402
from physynth.validate.render import write_report  # noqa: E402
from physynth.workflows import validate_datasets  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="cablecar-descending")
    ap.add_argument("-n", type=int, default=50, help="synthetic traces")
    ap.add_argument("--real", type=Path, default=None, help="real dataset (default: one scenario trace)")
    ap.add_argument("--transfer", action="store_true", help="validate with --transfer")
    ap.add_argument("--repeat", type=int, default=2, help="measurements; the best is reported")
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})

    tmp = Path(tempfile.mkdtemp(prefix="physynth-bench-validate-"))
    try:
        real = args.real
        if real is None:
            real = tmp / "real"
            write_dataset(real, [generate_trace(load_scenario(args.scenario), 0, 2026)],
                          meta={"kind": "real", "source": "bench"})
        best = None
        for r in range(args.repeat):
            t0 = time.perf_counter()
            report = validate_datasets(real, scenario=args.scenario, n=args.n, seed=r, transfer=args.transfer)
            t1 = time.perf_counter()
            written = write_report(report, tmp / f"report{r}", overwrite=True)
            t2 = time.perf_counter()
            run = (t2 - t0, t1 - t0, t2 - t1)
            best = run if best is None or run[0] < best[0] else best
        size_kb = sum(p.stat().st_size for p in written.values()) / 1024
        peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        total, compute, draw = best
        print(f"validate {args.scenario}: {args.n} synthetic traces, real {real}, "
              f"{report.inputs['n_residuals']['synthetic']} synthetic residuals")
        print(f"  generate + reduce + statistics : {compute:6.2f} s")
        print(f"  figures + report files         : {draw:6.2f} s  ({len(written)} files, {size_kb:.0f} kB)")
        print(f"  total                          : {total:6.2f} s  (best of {args.repeat}; target < 60 s)")
        print(f"  peak memory                    : {peak_mb:6.0f} MB")
        print(f"  KS {report.ks_statistic:.3f}, fidelity S {report.fidelity_score:.3f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
