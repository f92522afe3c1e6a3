"""How quiet the machine was during ``physynth bench`` (physynth.bench.OthersCpu): the share of the cores'
time other processes took, from the kernel's CPU counters less the bench's own time."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import time

import pytest

from physynth.bench import OthersCpu

TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
CORES = os.cpu_count() or 1


def _stat(path, busy_ticks, idle_ticks=10_000):
    """A /proc/stat first line: user nice system idle iowait irq softirq steal (busy split over user and steal)."""
    user, steal = busy_ticks - busy_ticks // 4, busy_ticks // 4
    path.write_text(f"cpu  {user} 0 0 {idle_ticks} 7 0 0 {steal} 0 0\ncpu0 0 0 0 0 0 0 0 0 0 0\n")


def _own_s():
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def test_other_processes_share_of_the_cores(tmp_path):
    stat = tmp_path / "stat"
    _stat(stat, 5_000)
    others = OthersCpu(str(stat))
    t0 = time.perf_counter()
    time.sleep(1.0)
    # the machine busy for half its cores' time meanwhile (steal time included), none of it this process's
    _stat(stat, 5_000 + round(0.5 * CORES * (time.perf_counter() - t0) * TICK), idle_ticks=12_000)
    assert others.share() == pytest.approx(0.5, abs=0.03)
    _stat(stat, 10**9)  # more than the cores could: at most all of them
    assert others.share() == 1.0
    _stat(stat, 5_000, idle_ticks=99_999)  # idle and iowait are not busy
    assert others.share() == 0.0


def test_the_benchs_own_work_is_not_counted(tmp_path):
    stat = tmp_path / "stat"
    _stat(stat, 5_000)
    own0 = _own_s()
    others = OthersCpu(str(stat))
    t0, spent = time.process_time(), 0
    while time.process_time() - t0 < 0.4:  # this process busy: CPU time that is the bench's own
        spent += len(hashlib.sha256(bytes(65536)).digest())
    assert spent > 0
    _stat(stat, 5_000 + round((_own_s() - own0) * TICK))  # the machine's busy time: this process's alone
    assert others.share() < 0.05  # counted as the bench's own: about one core's worth (1 / cores) if not


@pytest.mark.skipif(not os.path.exists("/proc/stat"), reason="needs Linux's /proc/stat")
def test_a_busy_process_beside_the_bench_is_seen():
    others = OthersCpu()
    busy = subprocess.Popen([sys.executable, "-c", "import time\nt = time.process_time()\n"
                             "while time.process_time() - t < 1.0: pass"])
    try:
        time.sleep(1.2)
        share = others.share()  # before the child is waited for: not yet this process tree's own time
    finally:
        busy.wait()
    assert share is not None and share >= 0.6 / CORES  # one core of the machine's, less the child's start


def test_no_counters_no_share(tmp_path):
    assert OthersCpu(str(tmp_path / "absent")).share() is None
    (tmp_path / "odd").write_text("intr 1 2 3\n")
    assert OthersCpu(str(tmp_path / "odd")).share() is None
