"""Exports in parts (one per shard of the dataset): the same bytes whatever order or worker the parts run on,
resumed after a kill, progress per trace, and the command's options."""

from __future__ import annotations

import filecmp
import importlib.util

import pytest

from physynth.cli import main
from physynth.io.export import export_dataset, partial_dir
from physynth.io.scenario_file import load_scenario
from physynth.workflows import export_dataset as export_on_workers
from physynth.workflows import generate_dataset

FORMATS = [f for f, mod in (("csv", "polars"), ("hdf5", "h5py"), ("rosbag2", "rosbags"))
           if importlib.util.find_spec(mod) is not None]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    path, _ = generate_dataset(load_scenario("cablecar-descending"), 5, tmp_path_factory.mktemp("parts") / "ds",
                               seed=3, shard_traces=2)  # three parts: 2, 2 and 1 traces
    return path


def _same(a, b) -> bool:
    if a.is_file():
        return a.read_bytes() == b.read_bytes()
    cmp = filecmp.dircmp(a, b)
    if cmp.left_only or cmp.right_only or cmp.funny_files:
        return False
    _, mismatch, errors = filecmp.cmpfiles(a, b, cmp.common_files, shallow=False)
    return not mismatch and not errors and all(_same(a / d, b / d) for d in cmp.common_dirs)


def _reversed_runner(fn, tasks, sizes, progress):
    """The parts in reverse order, as workers finishing in any order would."""
    results = [fn(*task) for task in reversed(tasks)]
    progress(sum(sizes))
    return results[::-1]


@pytest.mark.parametrize("fmt", FORMATS)
def test_parts_in_any_order_give_the_same_bytes(dataset, tmp_path, fmt):
    suffix = ".h5" if fmt == "hdf5" else ""
    said = []
    a = export_dataset(dataset, tmp_path / f"a{suffix}", fmt,
                       progress=lambda m, done=None, total=None: said.append((m, done, total)))
    b = export_dataset(dataset, tmp_path / f"b{suffix}", fmt, run=_reversed_runner)
    assert _same(a, b)
    assert ("exporting to " + fmt, 5, 5) in said and [d for m, d, t in said if m.startswith("exporting")] == \
        [0, 1, 2, 3, 4, 5]  # one step per trace in this process
    assert not partial_dir(a).exists() and not partial_dir(b).exists()


@pytest.mark.skipif(importlib.util.find_spec("distributed") is None or "hdf5" not in FORMATS,
                    reason="needs dask (physynth[scale]) and h5py")
def test_two_workers_write_the_same_file_as_one(dataset, tmp_path):
    one = export_on_workers(dataset, tmp_path / "one.h5", "hdf5", workers=1)
    two = export_on_workers(dataset, tmp_path / "two.h5", "hdf5", workers=2)
    assert one.read_bytes() == two.read_bytes()


class _Killed(KeyboardInterrupt):
    pass


@pytest.mark.parametrize("fmt", FORMATS)
def test_resume_after_a_kill_keeps_the_complete_parts(dataset, tmp_path, fmt):
    suffix = ".h5" if fmt == "hdf5" else ""
    out = tmp_path / f"out{suffix}"

    def killed_after_first(fn, tasks, sizes, progress):
        fn(*tasks[0])
        raise _Killed

    with pytest.raises(_Killed):
        export_dataset(dataset, out, fmt, run=killed_after_first)
    partial = partial_dir(out)
    assert not out.exists() and (partial / "part-00000.json").is_file()
    first = (partial / "part-00000.json").stat().st_mtime_ns
    with pytest.raises(Exception, match="unfinished export"):
        export_dataset(dataset, out, fmt)
    said = []
    export_dataset(dataset, out, fmt, resume=True, run=lambda fn, tasks, sizes, progress: [
        said.append(task[2].k) or fn(*task) for task in tasks])
    assert said == [1, 2]  # the complete part was kept, not written again
    assert first > 0 and not partial.exists()
    assert _same(out, export_dataset(dataset, tmp_path / f"clean{suffix}", fmt))


def test_resume_after_a_kill_while_assembling(dataset, tmp_path, monkeypatch):
    """Assembling a CSV export of one part takes the part away (moved into the output): stopped in the
    middle, the resumed export redoes exactly that part and gives the same output."""
    from physynth.io.export import parts as parts_mod

    out = tmp_path / "out"
    consume = parts_mod._consume
    taken = []

    def killed_after_taking(partial, part, take):
        consume(partial, part, take)
        taken.append(part.k)
        raise _Killed

    monkeypatch.setattr(parts_mod, "_consume", killed_after_taking)
    # one part (a one-shard dataset's): the only CSV part that is taken, not copied
    monkeypatch.setattr(parts_mod, "dataset_parts", lambda meta: [parts_mod.Part(0, meta["n_traces"], None)])
    monkeypatch.setattr("physynth.io.export.dataset_parts", parts_mod.dataset_parts)
    with pytest.raises(_Killed):
        export_dataset(dataset, out, "csv")
    monkeypatch.setattr(parts_mod, "_consume", consume)
    assert not out.exists() and partial_dir(out).is_dir()
    said = []
    export_dataset(dataset, out, "csv", resume=True, run=lambda fn, tasks, sizes, progress: [
        said.append(task[2].k) or fn(*task) for task in tasks])
    assert said == taken == [0]  # only the part the stopped assembly had taken is written again
    assert _same(out, export_dataset(dataset, tmp_path / "clean", "csv"))


@pytest.mark.skipif("hdf5" not in FORMATS, reason="needs h5py")
def test_hdf5_parts_run_one_after_the_other_are_appended_in_place(dataset, tmp_path):
    """Parts run in order go straight into the export's file (nothing written apart, nothing copied when
    assembling); parts run out of order are written apart and appended when assembling: the same bytes."""
    from physynth.io.export import parts as parts_mod

    out = tmp_path / "a.h5"
    partial = partial_dir(out)
    seen = []

    def in_order(fn, tasks, sizes, progress):
        for task in tasks:
            fn(*task)
            seen.append(sorted(p.name for p in partial.iterdir()))
        return [{}] * len(tasks)

    said = []
    export_dataset(dataset, out, "hdf5", run=in_order, progress=lambda m, done=None, total=None: said.append(m))
    assert not [m for m in said if "written apart" in m]  # nothing left to append when assembling
    assert seen[-1] == [parts_mod.H5_FILE, parts_mod.H5_SIZES, parts_mod.H5_LOCK, "part-00000.json",
                        "part-00001.json", "part-00002.json", "run.json"]  # no part of its own, no journal left
    apart = []

    def reversed_and_seen(fn, tasks, sizes, progress):
        results = _reversed_runner(fn, tasks, sizes, progress)
        apart.extend(sorted(p.name for p in partial_dir(tmp_path / "b.h5").glob("part-*.pkl")))
        return results

    said.clear()
    assert _same(out, export_dataset(dataset, tmp_path / "b.h5", "hdf5", run=reversed_and_seen,
                                     progress=lambda m, done=None, total=None: said.append(m)))
    assert apart == ["part-00001.pkl", "part-00002.pkl"]  # written before part 0: appended when assembling
    assert "appending the 2 part(s) written apart" in said


@pytest.mark.skipif("hdf5" not in FORMATS, reason="needs h5py")
def test_hdf5_part_whose_predecessors_are_complete_takes_in_those_written_apart(dataset, tmp_path):
    """Parts finishing out of order (1, then 0, then 2, as two workers may): part 1 is written apart, part 0
    creates the file, and part 2 appends part 1 from its pickle before itself, so nothing is left to append
    when assembling; the same bytes as parts run in order."""
    from physynth.io.export import parts as parts_mod

    out = tmp_path / "out.h5"
    partial = partial_dir(out)
    states = []

    def one_zero_two(fn, tasks, sizes, progress):
        for k in (1, 0, 2):
            fn(*tasks[k])
            states.append((sorted(p.name for p in partial.glob("part-*.pkl")), len(parts_mod._h5_sizes(partial))))
        return [{}] * len(tasks)

    export_dataset(dataset, out, "hdf5", run=one_zero_two)
    assert states == [(["part-00001.pkl"], 0), (["part-00001.pkl"], 1), ([], 3)]
    assert _same(out, export_dataset(dataset, tmp_path / "clean.h5", "hdf5"))


@pytest.mark.skipif("hdf5" not in FORMATS, reason="needs h5py")
def test_hdf5_part_finding_the_file_busy_is_written_apart(dataset, tmp_path):
    """While another process holds the file's lock (it appends a part), a part does not wait: it is written
    apart, even the first, and assembling appends it; the same bytes."""
    import fcntl
    import os

    from physynth.io.export import parts as parts_mod

    out = tmp_path / "out.h5"
    partial = partial_dir(out)
    apart = []

    def first_part_while_locked(fn, tasks, sizes, progress):
        fd = os.open(partial / parts_mod.H5_LOCK, os.O_RDWR | os.O_CREAT)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)  # as another worker would hold it
            fn(*tasks[0])
        finally:
            os.close(fd)
        apart.extend(sorted(p.name for p in partial.glob("part-*.pkl")))
        return [fn(*tasks[0]), *(fn(*t) for t in tasks[1:])]

    export_dataset(dataset, out, "hdf5", run=first_part_while_locked)
    assert apart == ["part-00000.pkl"]
    assert _same(out, export_dataset(dataset, tmp_path / "clean.h5", "hdf5"))


@pytest.mark.skipif("hdf5" not in FORMATS, reason="needs h5py")
def test_hdf5_stopped_while_assembling_keeps_every_part(dataset, tmp_path, monkeypatch):
    """A stop in the middle of appending a part written apart restores the file as it was (its undo journal):
    the resumed export writes no part again, and the same bytes."""
    from physynth.io.export import parts as parts_mod

    out = tmp_path / "out.h5"
    pickled = parts_mod._pickled

    def stopped_after_one_trace(path):
        it = pickled(path)
        yield next(it)
        raise _Killed

    monkeypatch.setattr(parts_mod, "_pickled", stopped_after_one_trace)
    with pytest.raises(_Killed):
        export_dataset(dataset, out, "hdf5", run=_reversed_runner)
    monkeypatch.setattr(parts_mod, "_pickled", pickled)
    partial = partial_dir(out)
    assert parts_mod._h5_sizes(partial) == [(partial / parts_mod.H5_FILE).stat().st_size]  # part 0 only
    assert not list(partial.glob("*.undo"))
    said = []
    export_dataset(dataset, out, "hdf5", resume=True, run=lambda fn, tasks, sizes, progress: [
        said.append(task[2].k) or fn(*task) for task in tasks])
    assert said == []
    assert _same(out, export_dataset(dataset, tmp_path / "clean.h5", "hdf5"))


_SIGKILLED = """
import os, signal, sys
from physynth.io.export import export_dataset, hdf5

write = hdf5._write

def write_then_killed(f, traces):  # the part's first trace in the file, flushed (its earlier bytes
    write(f, [next(iter(traces))])  # rewritten in place), then SIGKILL
    f.flush()
    os.kill(os.getpid(), signal.SIGKILL)

calls = []

def run(fn, tasks, sizes, progress):
    for task in tasks:
        if task[2].k == 1:
            hdf5._write = write_then_killed
        fn(*task)

export_dataset(sys.argv[1], sys.argv[2], "hdf5", run=run)
"""


@pytest.mark.skipif("hdf5" not in FORMATS, reason="needs h5py")
def test_hdf5_resume_after_sigkill_while_appending_in_place(dataset, tmp_path):
    """SIGKILL while a part is being appended to the export's file leaves its undo journal: the resumed
    export rolls the file back to the parts before it and writes that part again, with the same bytes."""
    import signal
    import subprocess
    import sys

    from physynth.io.export import parts as parts_mod

    out = tmp_path / "out.h5"
    proc = subprocess.run([sys.executable, "-c", _SIGKILLED, str(dataset), str(out)], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    partial = partial_dir(out)
    journal = partial / "appended-00001.undo"
    assert journal.stat().st_size > 100  # bytes of part 0 were rewritten in place and saved first
    size0 = parts_mod._h5_sizes(partial)[0]
    assert (partial / parts_mod.H5_FILE).stat().st_size > size0  # part 1's first trace is in the file
    said = []
    export_dataset(dataset, out, "hdf5", resume=True, run=lambda fn, tasks, sizes, progress: [
        said.append(task[2].k) or fn(*task) for task in tasks])
    assert said == [1, 2]
    assert _same(out, export_dataset(dataset, tmp_path / "clean.h5", "hdf5"))


@pytest.mark.parametrize("stop", ["while appending", "before marking"])
def test_csv_parts_appended_in_place_resume_after_a_stop(dataset, tmp_path, stop):
    """Parts run one after the other append their CSV rows to the export's tables as they go (nothing is
    copied when assembling); a stop in the middle of a part's rows, or after its rows and sizes but before
    its marker, is cut back and written again: the same bytes as an export that ran through."""
    from physynth.io.export import parts as parts_mod

    out = tmp_path / "csv"
    partial = partial_dir(out)

    def stopped(fn, tasks, sizes, progress):
        fn(*tasks[0])
        fn(*tasks[1])
        assert sorted(p.name for p in partial.iterdir()) == ["part-00000.json", "part-00001.json", "run.json",
                                                             "tables", "tables.json"]  # no part of its own
        if stop == "while appending":
            with open(partial / parts_mod.APPENDED / "imu.csv", "ab") as fh:
                fh.write(b"2,0.5,1.0,2.0")  # a part's first rows, cut short
        else:
            parts_mod.marker(partial, 1).unlink()
        raise _Killed

    with pytest.raises(_Killed):
        export_dataset(dataset, out, "csv", run=stopped)
    said = []
    export_dataset(dataset, out, "csv", resume=True, run=lambda fn, tasks, sizes, progress: [
        said.append(task[2].k) or fn(*task) for task in tasks])
    assert said == ([2] if stop == "while appending" else [1, 2])
    assert _same(out, export_dataset(dataset, tmp_path / "clean", "csv"))
    assert not partial.exists()


@pytest.mark.parametrize("taken", [1, 2])
def test_csv_resume_after_a_kill_while_assembling_parts_appended_in_place(dataset, tmp_path, monkeypatch, taken):
    """The tables of parts appended in place are taken with the first part's marker last: a stop after one or
    two markers (of three parts) leaves the parts before them complete, and the resumed export writes again
    exactly the unmarked ones, with the same bytes."""
    from physynth.io.export import parts as parts_mod

    out = tmp_path / "csv"
    consume = parts_mod._consume
    unmarked = []

    def killed_after(partial, part, take):
        consume(partial, part, take)
        unmarked.append(part.k)
        if len(unmarked) == taken:
            raise _Killed

    monkeypatch.setattr(parts_mod, "_consume", killed_after)
    with pytest.raises(_Killed):
        export_dataset(dataset, out, "csv")
    monkeypatch.setattr(parts_mod, "_consume", consume)
    said = []
    export_dataset(dataset, out, "csv", resume=True, run=lambda fn, tasks, sizes, progress: [
        said.append(task[2].k) or fn(*task) for task in tasks])
    assert unmarked == [2, 1][:taken] and said == sorted(unmarked)
    assert _same(out, export_dataset(dataset, tmp_path / "clean", "csv"))


def test_csv_part_written_again_before_parts_appended_after_it_writes_those_again(dataset, tmp_path):
    """Should the first part lose its marker while the parts after it were appended (no stop does that; a
    file removed by hand), writing it again cuts their rows off and unmarks them, and the export writes them
    again in the same run: the same bytes, no missing marker."""
    from physynth.io.export import parts as parts_mod

    out = tmp_path / "csv"
    partial = partial_dir(out)

    def all_parts_then_killed(fn, tasks, sizes, progress):
        for task in tasks:
            fn(*task)
        raise _Killed

    with pytest.raises(_Killed):
        export_dataset(dataset, out, "csv", run=all_parts_then_killed)
    parts_mod.marker(partial, 0).unlink()
    said = []
    export_dataset(dataset, out, "csv", resume=True, run=lambda fn, tasks, sizes, progress: [
        said.append(task[2].k) or fn(*task) for task in tasks])
    assert said == [0, 1, 2]
    assert _same(out, export_dataset(dataset, tmp_path / "clean", "csv"))


def test_resume_refuses_another_run(dataset, tmp_path):
    out = tmp_path / "csv"

    def killed(fn, tasks, sizes, progress):
        fn(*tasks[0])
        raise _Killed

    with pytest.raises(_Killed):
        export_dataset(dataset, out, "csv", run=killed)
    with pytest.raises(Exception, match="differs in bag_storage, format"):
        export_dataset(dataset, out, "rosbag2", resume=True)


def test_export_cli_options_are_checked_in_one_line(dataset, tmp_path, capsys):
    for argv, needle in (
            (["--resume", "--overwrite"], "--resume and --overwrite exclude each other"),
            (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--scheduler and --workers exclude each other"),
            (["--bag-storage", "zip"], "'zip' is not one of"),
            (["-f", "csv", "--bag-storage", "sqlite3"], "--bag-storage applies to --format rosbag2 only (given with "
                                                        "--format csv)"),
            (["-f", "hdf5", "--bag-storage", "mcap"], "--bag-storage applies to --format rosbag2 only")):
        with pytest.raises(SystemExit) as e:
            main(["export", str(dataset), "-f", "rosbag2", "-o", str(tmp_path / "x"), *argv])
        err = capsys.readouterr().err
        assert e.value.code == 2 and needle in err and err.count("\n") == 1, err
    assert not (tmp_path / "x").exists()


def test_csv_and_hdf5_exports_pick_one_process_where_bags_pick_all_cores(dataset, tmp_path, monkeypatch, capsys):
    """Without --workers, a dataset large enough for all cores exports to CSV and HDF5 in one process (parts run
    one after the other are appended in place instead of apart and then appended when assembling); bags take
    all."""
    import physynth.workflows
    from physynth.cli import generate as cli_generate

    monkeypatch.setattr(cli_generate, "AUTO_CLUSTER_MIN_TRACES", 1)  # as if the dataset were large
    monkeypatch.setattr("physynth.parallel.available_cores", lambda: 2)
    asked = {}
    real = physynth.workflows.export_dataset

    class _Asked(Exception):
        pass

    def recording(dataset, out, fmt, **kw):
        asked[fmt] = kw["workers"]
        if kw["workers"] > 1:
            raise _Asked  # the choice is what is tested; no cluster started for it (the command exits 3)
        return real(dataset, out, fmt, **kw)

    monkeypatch.setattr(physynth.workflows, "export_dataset", recording)
    main(["export", str(dataset), "-f", "csv", "-o", str(tmp_path / "csv"), "-q"])
    main(["export", str(dataset), "-f", "hdf5", "-o", str(tmp_path / "x.h5"), "-q"])
    with pytest.raises(SystemExit):
        main(["export", str(dataset), "-f", "rosbag2", "-o", str(tmp_path / "bags"), "-q"])
    capsys.readouterr()
    assert asked == {"csv": 1, "hdf5": 1, "rosbag2": 2}
    assert (tmp_path / "csv" / "uwb.csv").is_file() and (tmp_path / "x.h5").is_file()


@pytest.mark.parametrize("fmt", [f for f in FORMATS if f != "csv"])
def test_a_part_whose_file_disagrees_with_its_record_keeps_nothing(dataset, tmp_path, fmt):
    """The files are checked while they are read: a part whose file reads but disagrees with its recorded
    SHA-256 leaves none of its bags and nothing of it in the HDF5 file; the parts before it stay complete."""
    import json
    import shutil

    from physynth.errors import IntegrityError
    from physynth.io.export import parts as parts_mod

    copy = tmp_path / "ds"
    shutil.copytree(dataset, copy)
    meta = json.loads((copy / "dataset.json").read_text())
    meta["files"]["uwb/part-00001.parquet"]["sha256"] = "0" * 64  # part 1: traces 2 and 3
    (copy / "dataset.json").write_text(json.dumps(meta))
    out = tmp_path / ("out.h5" if fmt == "hdf5" else "bags")
    with pytest.raises(IntegrityError, match="uwb/part-00001.parquet"):
        export_dataset(copy, out, fmt)
    partial = partial_dir(out)
    assert not out.exists()
    assert sorted(p.name for p in partial.glob("part-*.json")) == ["part-00000.json"]
    if fmt == "rosbag2":
        assert sorted(p.name for p in partial.glob("trace_*")) == ["trace_00000000", "trace_00000001"]
    else:
        sizes = parts_mod._h5_sizes(partial)
        assert len(sizes) == 1 and (partial / parts_mod.H5_FILE).stat().st_size == sizes[0]
        assert not list(partial.glob("*.undo")) and not list(partial.glob("part-*.pkl"))


@pytest.mark.skipif("hdf5" not in FORMATS, reason="needs h5py")
def test_hdf5_file_larger_than_the_cache_allowance_is_written_behind(dataset, tmp_path, monkeypatch):
    """Past io.pagecache.cache_allowance() bytes, each appended part asks the kernel to write out the bytes
    that fell behind the allowance since the part before and to drop those asked out before: windows that
    follow each other from byte 0 to the allowance before the end; the file is the same."""
    from physynth.io import pagecache
    from physynth.io.export import parts as parts_mod

    keep = 100_000
    asked = []
    monkeypatch.setattr(pagecache, "cache_allowance", lambda: keep)
    monkeypatch.setattr(pagecache, "write_behind", lambda fd, start, length: asked.append((start, start + length)))
    out = export_dataset(dataset, tmp_path / "out.h5", "hdf5")
    sizes = []

    def record(partial, k, meta, groups, got, real=parts_mod._append_h5_part):
        real(partial, k, meta, groups, got)
        sizes.append(got[-1])

    monkeypatch.setattr(parts_mod, "_append_h5_part", record)
    asked.clear()
    again = export_dataset(dataset, tmp_path / "again.h5", "hdf5")
    assert len(sizes) == 3 and sizes[-1] > 2 * keep
    assert asked == [(0, sizes[0] - keep), (0, sizes[1] - keep), (sizes[0] - keep, sizes[2] - keep)]
    assert _same(out, again)
    monkeypatch.setattr(pagecache, "cache_allowance", lambda: 1 << 62)  # a file below it: nothing asked
    asked.clear()
    export_dataset(dataset, tmp_path / "small.h5", "hdf5")
    assert asked == []


@pytest.mark.skipif("hdf5" not in FORMATS, reason="needs h5py")
def test_hdf5_record_that_does_not_read_has_its_parts_written_again(dataset, tmp_path):
    """An unfinished export whose record of the file's parts does not read (damaged by hand or by a power
    cut): the file goes, and the parts marked complete that were only in it are written again on --resume,
    not taken for complete (before: 'No such file or directory' of a part's pickle, exit 1)."""
    from physynth.io.export import parts as parts_mod

    out = tmp_path / "out.h5"

    def two_parts_then_killed(fn, tasks, sizes, progress):
        fn(*tasks[0])
        fn(*tasks[1])
        raise _Killed

    with pytest.raises(_Killed):
        export_dataset(dataset, out, "hdf5", run=two_parts_then_killed)
    partial = partial_dir(out)
    assert len(parts_mod._h5_sizes(partial)) == 2
    (partial / parts_mod.H5_SIZES).write_text("not json")
    said = []
    export_dataset(dataset, out, "hdf5", resume=True, run=lambda fn, tasks, sizes, progress: [
        said.append(task[2].k) or fn(*task) for task in tasks])
    assert said == [0, 1, 2]
    assert _same(out, export_dataset(dataset, tmp_path / "clean.h5", "hdf5"))
