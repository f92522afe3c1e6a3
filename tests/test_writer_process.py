"""The writer process (physynth.io.writer_process): the same files as writing in this process, its errors
raised here with their class and message, and nothing left behind when either process stops early."""

from __future__ import annotations

import json
import os
import pickle
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

from physynth.constants import IMU_FRAME
from physynth.errors import DatasetError, OutputExistsError
from physynth.generate import compile_scenario, generate_trace
from physynth.io.dataset import DatasetWriter, iter_trace_meta
from physynth.io.scenario_file import load_scenario
from physynth.io.shards import partial_dir, write_shard
from physynth.io.writer_process import (
    ENV_VAR,
    MIN_TRACES,
    WriterProcess,
    _error_of,
    _error_record,
    local_writers,
)
from physynth.workflows import generate_dataset

SEED = 11


@pytest.fixture(scope="module")
def traces():
    cs = compile_scenario(load_scenario("cablecar-descending"))
    return [(i, generate_trace(cs, i, SEED)) for i in range(5)]


def _files(path: Path) -> dict[str, bytes]:
    """Every file of a dataset by relative path; dataset.json without its creation time."""
    out = {}
    for p in sorted(path.rglob("*")):
        if p.is_file():
            data = p.read_bytes()
            if p.name == "dataset.json":
                meta = json.loads(data)
                meta.pop("created_utc")
                data = json.dumps(meta).encode()
            out[str(p.relative_to(path))] = data
    return out


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_a_shard_written_by_the_process_is_the_same_file_for_file(traces, tmp_path):
    meta = {"kind": "synthetic", "imu_frames": [IMU_FRAME]}  # the preset's IMU stream
    assert write_shard(tmp_path / "here", 0, traces, meta) == len(traces)
    with WriterProcess() as proc:
        assert write_shard(tmp_path / "there", 0, traces, meta, proc.writer) == len(traces)
        assert write_shard(tmp_path / "there", 1, traces[:2], meta, proc.writer) == 2  # one process, many datasets
    here, there = _files(tmp_path / "here" / "shard-00000"), _files(tmp_path / "there" / "shard-00000")
    assert len(here) == 5 and here == there
    assert sorted(_files(tmp_path / "there" / "shard-00001")) == sorted(here)


def test_traces_too_large_for_the_ring_go_through_the_pipe(traces, tmp_path, monkeypatch):
    import physynth.io.writer_process as wp

    meta = {"kind": "synthetic", "imu_frames": [IMU_FRAME]}
    write_shard(tmp_path / "here", 0, traces, meta)
    monkeypatch.setattr(wp, "RING_BYTES", 1 << 20)  # a default trace has about 2.5 MB of arrays
    with WriterProcess() as proc:
        assert proc._ring is not None and len(proc._ring) == 1 << 20
        write_shard(tmp_path / "there", 0, traces, meta, proc.writer)
        assert proc._seq == 0  # none went through the ring
    assert _files(tmp_path / "here" / "shard-00000") == _files(tmp_path / "there" / "shard-00000")


def test_the_ring_is_reused_when_the_process_has_freed_it(traces, tmp_path, monkeypatch):
    import physynth.io.writer_process as wp

    meta = {"kind": "synthetic", "imu_frames": [IMU_FRAME]}
    write_shard(tmp_path / "here", 0, traces * 3, meta)
    monkeypatch.setattr(wp, "RING_BYTES", 8 << 20)  # room for about three traces: later ones wait for a place
    with WriterProcess() as proc:
        write_shard(tmp_path / "there", 0, traces * 3, meta, proc.writer)
        proc.finish()
        assert proc._seq == 15 and not proc._busy  # every trace through the ring, every place freed by the close
    assert _files(tmp_path / "here" / "shard-00000") == _files(tmp_path / "there" / "shard-00000")


def test_generate_on_one_worker_writes_the_same_files_with_and_without_the_process(tmp_path, monkeypatch):
    import physynth.io.writer_process as wp
    import physynth.parallel as par

    monkeypatch.setattr(par, "available_cores", lambda: 2)  # a core to spare, on any machine
    monkeypatch.setattr(wp, "MIN_TRACES", 1)  # and a run of 7 traces would do
    used = []
    real = WriterProcess.writer
    monkeypatch.setattr(WriterProcess, "writer", lambda self, path, **kw: used.append(path) or real(self, path, **kw))
    a, _ = generate_dataset("cablecar-descending", 7, tmp_path / "a", seed=SEED, shard_traces=3)
    assert len(used) == 3  # every shard went through the writer process
    monkeypatch.setenv(ENV_VAR, "0")
    b, _ = generate_dataset("cablecar-descending", 7, tmp_path / "b", seed=SEED, shard_traces=3)
    assert len(used) == 3
    assert _files(a) == _files(b)
    assert [m["trace"] for _, m in iter_trace_meta(a)] == list(range(7))


def test_local_writers_only_with_a_core_to_spare_and_enough_traces(monkeypatch):
    with local_writers(1, 1000) as writer:
        assert writer is None
    with local_writers(2, MIN_TRACES - 1) as writer:
        assert writer is None
    monkeypatch.setenv(ENV_VAR, "off")
    with local_writers(2, 1000) as writer:
        assert writer is None
    monkeypatch.delenv(ENV_VAR)
    with local_writers(2, MIN_TRACES) as writer:
        assert writer is not None and isinstance(writer.__self__, WriterProcess)


def test_an_error_in_the_process_is_raised_here_with_its_class_and_message(traces, tmp_path):
    taken = tmp_path / "taken"
    with DatasetWriter(taken) as w:
        w.add(traces[0][1])
    with WriterProcess() as proc:
        w = proc.writer(taken)  # exists, no overwrite: refused there
        with pytest.raises(OutputExistsError, match="taken") as raised:
            for i, trace in traces:
                w.add(trace, index=i)
            w.close()  # returns at once: the datasets are in place when the process has finished
            proc.finish()
        assert str(raised.value) == f"{taken} already exists" and raised.value.path == str(taken)  # as raised there
        with pytest.raises(OutputExistsError):  # the process has ended: every later call says why
            proc.writer(tmp_path / "other")
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize("exc", [PermissionError(13, "Permission denied", "/data/out"), OSError("disk full"),
                                 OutputExistsError("/data/out", "holds a dataset"), ValueError("a bug")])
def test_errors_keep_their_class_message_and_attributes_across_the_pipe(exc):
    back = _error_of(pickle.loads(pickle.dumps(_error_record(exc))))
    if isinstance(exc, ValueError):
        assert type(back) is RuntimeError and str(back) == "the writer process failed: ValueError: a bug"
    else:
        assert type(back) is type(exc) and str(back) == str(exc) and vars(back) == vars(exc)
        assert getattr(back, "errno", None) == getattr(exc, "errno", None)
        assert getattr(back, "filename", None) == getattr(exc, "filename", None)


def test_a_relative_path_is_this_process_s_folder_even_after_a_change_of_folder(traces, tmp_path, monkeypatch):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    monkeypatch.chdir(tmp_path / "a")
    with WriterProcess() as proc:
        monkeypatch.chdir(tmp_path / "b")  # after the process started in a/
        with proc.writer("out") as w:
            w.add(traces[0][1], index=0)
    assert (tmp_path / "b" / "out" / "dataset.json").is_file() and not (tmp_path / "a" / "out").exists()


def test_abort_removes_what_was_written_and_the_process_goes_on(traces, tmp_path):
    with WriterProcess() as proc:
        with pytest.raises(KeyboardInterrupt), proc.writer(tmp_path / "stopped", meta={}) as w:
            for i, trace in traces:
                w.add(trace, index=i)
            raise KeyboardInterrupt
        with proc.writer(tmp_path / "next") as w:
            w.add(traces[0][1], index=0)
    assert not (tmp_path / "stopped").exists() and (tmp_path / "next" / "dataset.json").is_file()
    assert _leftovers(tmp_path) == []


def test_a_killed_process_is_an_error_that_says_so(traces, tmp_path):
    with WriterProcess() as proc:
        w = proc.writer(tmp_path / "out")
        w.add(traces[0][1], index=0)
        proc._proc.send_signal(signal.SIGKILL)
        proc._proc.wait()
        with pytest.raises(DatasetError, match="writer process ended unexpectedly .signal 9"):
            for i, trace in traces * 4:  # the pipe may take a few before it is found broken
                w.add(trace, index=i)
            w.close()
            proc.finish()


KILLED_PARENT = """
import sys
from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import load_scenario
from physynth.io.writer_process import WriterProcess
cs = compile_scenario(load_scenario("cablecar-descending"))
proc = WriterProcess()
print(proc._proc.pid, flush=True)
w = proc.writer(sys.argv[1])
i = 0
while True:
    w.add(generate_trace(cs, i, 1), index=i)
    i += 1
"""


def test_the_process_removes_its_work_and_exits_when_this_one_is_killed(tmp_path):
    out = tmp_path / "out"
    parent = subprocess.Popen([sys.executable, "-c", KILLED_PARENT, str(out)], stdout=subprocess.PIPE, text=True)
    try:
        child = int(parent.stdout.readline())
        deadline = time.monotonic() + 60
        while not any(p.name.startswith(".out") for p in tmp_path.iterdir()):  # the child is writing
            assert time.monotonic() < deadline and parent.poll() is None
            time.sleep(0.05)
        time.sleep(0.5)
    finally:
        parent.kill()
        parent.wait()
    deadline = time.monotonic() + 20
    while Path(f"/proc/{child}").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    still = Path(f"/proc/{child}").exists()
    if still:
        os.kill(child, signal.SIGKILL)
    assert not still, "the writer process outlived the process that started it"
    assert not out.exists() and _leftovers(tmp_path) == []


def test_a_run_stopped_midway_resumes_to_the_same_files(tmp_path, monkeypatch):
    import physynth.io.writer_process as wp
    import physynth.parallel as par

    monkeypatch.setattr(par, "available_cores", lambda: 2)
    monkeypatch.setattr(wp, "MIN_TRACES", 1)

    def stop(message, done=None, total=None):
        if done is not None and done >= 5:
            raise KeyboardInterrupt

    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        generate_dataset("cablecar-descending", 9, out, seed=SEED, shard_traces=2, progress=stop)
    part = partial_dir(out)
    assert sorted(p.name for p in part.iterdir() if p.name.startswith(".shard")) == []
    # shards 0 and 1 (traces 0-3) complete: the abort of shard 2 is answered after shard 1's close
    assert sorted(p.name for p in part.glob("shard-*")) == ["shard-00000", "shard-00001"]
    generate_dataset("cablecar-descending", 9, out, seed=SEED, shard_traces=2, resume=True)
    monkeypatch.setenv(ENV_VAR, "0")
    ref, _ = generate_dataset("cablecar-descending", 9, tmp_path / "ref", seed=SEED, shard_traces=2)
    assert _files(out) == _files(ref)


def test_an_interrupt_in_the_middle_of_a_message_stops_the_process(traces, tmp_path, monkeypatch):
    proc = WriterProcess()
    try:
        w = proc.writer(tmp_path / "out")
        w.add(traces[0][1], index=0)

        def cut(message):  # a signal's exception once half a message is in the pipe (Connection's frame: !i size)
            data = pickle.dumps(message)
            os.write(proc._send.fileno(), struct.pack("!i", len(data)) + data[: len(data) // 2])
            raise KeyboardInterrupt

        monkeypatch.setattr(proc._send, "send", cut)
        t0 = time.monotonic()
        with pytest.raises(KeyboardInterrupt), w:
            w.add(traces[1][1], index=1)
        assert proc.broken and proc._proc.poll() is not None  # stopped, not asked (it waits for the rest)
        assert time.monotonic() - t0 < 10
    finally:
        proc.stop()
    assert not (tmp_path / "out").exists() and _leftovers(tmp_path) == []


def test_a_process_that_cannot_start_leaves_no_descriptor_open(monkeypatch):
    import physynth.io.writer_process as wp

    before = set(os.listdir("/proc/self/fd"))
    monkeypatch.setattr(wp.sys, "executable", "/nonexistent/python")
    with pytest.raises(OSError):
        WriterProcess()
    assert set(os.listdir("/proc/self/fd")) == before
    with local_writers(2, 1000) as writer:  # a run then writes in its own process
        assert writer is None
