"""Write-behind of bulk outputs (io.pagecache): which byte ranges the kernel is asked to write out and
drop, and which outputs ask (an export's own files, not the parts that are read again at assembly)."""

from __future__ import annotations

import os

import pytest

from physynth.io import pagecache
from physynth.io.dataset import read_meta
from physynth.io.export import csv as csv_export
from physynth.io.export import export_dataset
from physynth.workflows import generate_dataset

pytestmark = pytest.mark.skipif(not hasattr(os, "posix_fadvise"), reason="no posix_fadvise here")


@pytest.fixture
def advised(monkeypatch):
    calls = []
    real = os.posix_fadvise

    def spy(fd, offset, length, advice):
        calls.append((os.fstat(fd).st_ino, offset, length, advice))
        return real(fd, offset, length, advice)

    monkeypatch.setattr(os, "posix_fadvise", spy)
    return calls


def test_each_piece_written_out_and_the_one_before_dropped(tmp_path, advised):
    path = tmp_path / "f.bin"
    pieces = [b"a" * 5000, b"b" * 7000, b"c" * 3000]
    with open(path, "wb") as f:
        behind = pagecache.WriteBehind(f.fileno(), f.tell())
        for p in pieces:
            f.write(p)
            f.flush()
            behind.advance(f.tell())
        behind.advance(f.tell())  # nothing new: the last piece is dropped in turn
    # the ranges asked: [piece before, end) each time, so every byte is asked twice (written out, dropped)
    assert [(o, n) for _, o, n, _ in advised] == [(0, 5000), (0, 12000), (5000, 10000), (12000, 3000)]
    assert {a for *_, a in advised} == {os.POSIX_FADV_DONTNEED}
    assert path.read_bytes() == b"".join(pieces)


def test_advice_refused_is_ignored(tmp_path):
    r, w = os.pipe()  # a pipe takes no advice (ESPIPE)
    try:
        pagecache.write_behind(w)
    finally:
        os.close(r)
        os.close(w)


def test_csv_export_written_behind_only_where_nothing_reads_it_again(tmp_path, advised):
    ds, _ = generate_dataset("cablecar-descending", 3, tmp_path / "ds", seed=1, shard_traces=2)
    export_dataset(ds, tmp_path / "csv", "csv")  # parts one after the other: appended in place
    tables = {os.stat(f).st_ino for f in (tmp_path / "csv").glob("*.csv")}
    assert tables and tables <= {ino for ino, *_ in advised}
    advised.clear()
    csv_export.write_csv_tables(ds, read_meta(ds), tmp_path / "apart")  # a part written apart, copied at
    # assembly: kept in the cache
    assert advised == []


def test_bags_written_behind(tmp_path, advised):
    ds, _ = generate_dataset("cablecar-descending", 2, tmp_path / "ds", seed=1)
    export_dataset(ds, tmp_path / "bags", "rosbag2")
    bags = {os.stat(f).st_ino for f in (tmp_path / "bags").rglob("*.mcap")}
    assert len(bags) == 2 and bags <= {ino for ino, *_ in advised}


def _kernel(tmp_path, cgroup_lines, files, background=("10", "0")):
    """A /proc and a /sys/fs/cgroup as the kernel shows them: the process's groups, the limit files."""
    proc, cgroups = tmp_path / "proc", tmp_path / "cgroup"
    (proc / "self").mkdir(parents=True)
    (proc / "sys" / "vm").mkdir(parents=True)
    (proc / "self" / "cgroup").write_text("\n".join(cgroup_lines) + "\n")
    (proc / "sys" / "vm" / "dirty_background_ratio").write_text(background[0] + "\n")
    (proc / "sys" / "vm" / "dirty_background_bytes").write_text(background[1] + "\n")
    for rel, text in files.items():
        (cgroups / rel).parent.mkdir(parents=True, exist_ok=True)
        (cgroups / rel).write_text(text + "\n")
    return str(proc), str(cgroups)


PHYSICAL = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def test_memory_is_the_lowest_limit_of_the_control_groups(tmp_path):
    gb = 1 << 30
    # cgroup v2: the container's group limited, its parent not ("max"), the root limited higher
    v2 = _kernel(tmp_path / "v2", ["0::/ctr/job"], {"ctr/job/memory.max": "max", "ctr/memory.max": str(2 * gb),
                                                     "memory.max": str(PHYSICAL + gb)})
    assert pagecache.memory_bytes(*v2) == min(PHYSICAL, 2 * gb)
    assert pagecache.cache_allowance(*v2) == min(PHYSICAL, 2 * gb) // 10
    # cgroup v1: the memory controller's own hierarchy, other controllers ignored
    v1 = _kernel(tmp_path / "v1", ["5:cpu,cpuacct:/x", "4:memory:/pa/c1", "0::/"],
                 {"memory/pa/c1/memory.limit_in_bytes": str(gb), "memory/pa/memory.limit_in_bytes": str(1 << 62),
                  "cpu/x/memory.limit_in_bytes": "1"})
    assert pagecache.memory_bytes(*v1) == min(PHYSICAL, gb)
    # no limit anywhere (v1's "unlimited" is a huge number): the machine's memory
    free = _kernel(tmp_path / "free", ["4:memory:/", "0::/"], {"memory/memory.limit_in_bytes": str((1 << 63) - 4096)})
    assert pagecache.memory_bytes(*free) == PHYSICAL


def test_cache_allowance_follows_the_kernels_writeback_settings(tmp_path):
    gb = 1 << 30
    ratio = _kernel(tmp_path / "r", ["0::/"], {"memory.max": str(4 * gb)}, background=("5", "0"))
    assert pagecache.cache_allowance(*ratio) == min(PHYSICAL, 4 * gb) * 5 // 100
    fixed = _kernel(tmp_path / "b", ["0::/"], {"memory.max": str(4 * gb)}, background=("10", str(300 << 20)))
    assert pagecache.cache_allowance(*fixed) == 300 << 20  # dirty_background_bytes wins over the ratio
    nothing = (str(tmp_path / "absent"), str(tmp_path / "absent"))  # no /proc (not Linux): a tenth of memory
    assert pagecache.cache_allowance(*nothing) == PHYSICAL // 10
