"""Start-up of the command line: ``physynth --help`` and the time to the first generated trace.

    python benchmarks/bench_cli.py [--repeat 5]

``--help`` and ``--version`` are timed as whole processes (best of ``--repeat``). The first trace is
timed inside a ``physynth generate -n 2 --workers 1`` process, from the moment the parent starts it (its
wall clock, passed on the command line; the OS's process creation time counts from a boot time rounded
to the second in some containers) to the moment the generator reports its first trace; the whole command's wall time
is printed too, and the process's CPU time (user + system) when it reports the first trace. Goals:
``--help`` under 0.3 s, first trace under 0.5 s.

The processes run the ``physynth`` that this interpreter imports (``PYTHONPATH`` first): its folder
is printed. Compare trees with the same bytecode state: with ``PYTHONDONTWRITEBYTECODE=1`` a tree
without ``__pycache__`` is compiled at every start (``PYTHONPYCACHEPREFIX=/tmp/pyc`` caches the
bytecode of every tree outside the source folders).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

FIRST_TRACE = r"""
import sys, time
start = float(sys.argv[2])  # the parent's clock just before it started this process
from physynth.cli import _common, main
real_bar = _common.progress_bar
first = []
def bar(enabled=True):
    import contextlib
    @contextlib.contextmanager
    def cm():
        def progress(message, done=None, total=None):
            if done and not first:
                first.append(time.time() - start)
                first.append(time.process_time())  # user + system since the process started
        yield progress
    return cm()
_common.progress_bar = bar
import physynth.cli.generate as g
g.progress_bar = bar
try:
    main(["generate", "-n", "2", "-w", "1", "--seed", "1", "--out", sys.argv[1], "--overwrite"])
except SystemExit:
    pass
import physynth
print(physynth.__path__[0])
print(first[0], first[1])
"""


def _wall(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    exe = [sys.executable, "-m", "physynth.cli"]
    helps = [_wall([*exe, "--help"]) for _ in range(args.repeat)]
    versions = [_wall([*exe, "--version"]) for _ in range(args.repeat)]
    firsts, cpus, totals, trees = [], [], [], set()
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            out = subprocess.run([sys.executable, "-c", FIRST_TRACE, os.path.join(tmp, "d"), repr(time.time())],
                                 check=True, capture_output=True, text=True).stdout
            totals.append(time.perf_counter() - t0)
            wall, cpu = out.strip().splitlines()[-1].split()
            firsts.append(float(wall))
            cpus.append(float(cpu))
            trees.add(out.strip().splitlines()[-2])
    print(f"physynth --help     : best {min(helps):.3f} s, median {sorted(helps)[len(helps) // 2]:.3f} s")
    print(f"physynth --version  : best {min(versions):.3f} s")
    print(f"first trace         : best {min(firsts):.3f} s after process start, median "
          f"{sorted(firsts)[len(firsts) // 2]:.3f} s (whole generate -n 2: best {min(totals):.2f} s)")
    print(f"first trace CPU     : best {min(cpus):.3f} s, median {sorted(cpus)[len(cpus) // 2]:.3f} s (user + system "
          "of the process when it reports the first trace; less sensitive to other load than wall time)")
    print(f"machine: {os.cpu_count()} core(s), load average {os.getloadavg()[0]:.2f}")
    print(f"physynth: {', '.join(sorted(trees))}")
    if sys.flags.dont_write_bytecode and not sys.pycache_prefix:
        print("note: PYTHONDONTWRITEBYTECODE is set: modules without a cached .pyc are compiled at every start")


if __name__ == "__main__":
    main()
