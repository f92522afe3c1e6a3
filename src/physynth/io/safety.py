"""What PhySynth may do to the user's files: overwrite, lock, clean up (docs/reliability.md).

- :func:`resolve_output` follows symlinks, so a ``--out`` that is a link replaces the folder it
  points to and the link stays valid.
- :func:`check_output` lets ``overwrite`` replace only what PhySynth wrote: a dataset folder
  with a ``dataset.json`` written by PhySynth (and nothing else in it), a report folder with a
  PhySynth ``report.json``, or a scenario / fit-report file PhySynth wrote. Anything else, an output
  that is or holds an input of the same command, and the current folder are refused, with or without
  ``overwrite``; an empty folder (or empty file) is used as if it were new.
- :class:`OutputLock` is a lock file ``.<name>.lock`` beside an output, holding the owner's pid and
  host: a second writer is refused while the first runs; a lock whose owner is gone (killed) is
  stale and taken over.
- :func:`remove_orphans` removes the hidden temporary siblings (``.<name>.tmp-<pid>``,
  ``.<name>.old-<pid>``) that a killed run left behind, and says so through a
  :class:`~physynth.errors.PhySynthWarning`.

Nothing here knows the command line; the messages speak of paths and parameters.
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import socket
import time
import warnings
from collections.abc import Iterable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from pathlib import Path

from ..errors import OutputExistsError, OutputLockedError, PhySynthError, PhySynthWarning, UnsafeOutputError

try:  # POSIX; on other systems the pid in the lock file is the only check
    import fcntl
except ImportError:  # pragma: no cover
    fcntl = None  # type: ignore[assignment]

DATASET_FILES = frozenset({"dataset.json", "truth.parquet", "imu.parquet", "uwb.parquet", "anchors.parquet"})
"""Files PhySynth writes in a dataset folder (besides those listed in ``dataset.json`` ``files``)."""

DATASET_FOLDERS = frozenset({"truth", "imu", "uwb", "anchors", "traces"})
"""Folders of a dataset assembled from several shards (``truth/part-00000.parquet`` ..., and the per-trace
metadata ``traces/part-00000.jsonl``)."""

REPORT_FILE_PATTERN = re.compile(r"^(report\.(json|md|html)|scenario\.yaml|[a-z0-9_]+\.png)$")
"""Files PhySynth writes in a validation report folder."""

SCENARIO_MARKER = "# Calibrated by physynth"
"""First line of a scenario file written by ``physynth calibrate``."""
SURVEY_MARKER = "# Surveyed by physynth"
"""First line of a scenario file written by ``physynth scenario survey``."""

_TEMP = re.compile(r"^\.(?P<name>.+)\.(?P<kind>tmp|old)-(?P<pid>\d+)$")


def resolve_output(path: str | os.PathLike) -> Path:
    """The real location an output will be written to: absolute, symlinks followed."""
    return Path(os.path.realpath(os.path.abspath(os.fspath(path))))


def _is_within(inner: Path, outer: Path) -> bool:
    return inner == outer or outer in inner.parents


def _physynth_json(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _marked(data: dict | None) -> bool:
    gen = (data or {}).get("generator")
    return isinstance(gen, dict) and gen.get("name") == "physynth"


def _foreign_entries(folder: Path, allowed: Iterable[str], pattern: re.Pattern | None = None) -> list[str]:
    allowed = set(allowed)
    return sorted(p.name for p in folder.iterdir()
                  if p.name not in allowed and not (pattern is not None and pattern.match(p.name) and p.is_file()))


EXPORT_CSV_FILE = re.compile(r"^[a-z_]+\.csv$")
EXPORT_BAG_FOLDER = re.compile(r"^trace_\d{8}$")
FOLDER_KINDS = ("dataset", "report", "export-hdf5", "export-csv", "export-rosbag2")
"""Output kinds that may never be the current folder or one of its parents (folders, and files whose
parent would be replaced)."""
FILE_KINDS = ("scenario", "json", "export-hdf5")
"""Output kinds that are one file; the others are folders."""


def _why_not_export(path: Path, kind: str) -> str | None:
    """:func:`why_not_replaceable` for ``physynth export`` outputs (``export-hdf5|csv|rosbag2``)."""
    if kind == "export-hdf5":
        if not path.is_file():
            return "it is not a file"
        try:
            import h5py

            with h5py.File(path, "r") as f:
                fmt = f.attrs.get("format", "")
        except (ImportError, OSError):
            fmt = ""
        fmt = fmt.decode() if isinstance(fmt, bytes) else str(fmt)
        return None if fmt.startswith("physynth-hdf5") else "it is not an HDF5 file written by physynth export"
    if not path.is_dir():
        return "it is not a folder"
    if kind == "export-csv":
        if not _marked(_physynth_json(path / "dataset.json")):
            return "it is not a CSV export of physynth (no dataset.json written by physynth)"
        foreign = _foreign_entries(path, ("dataset.json", "traces.jsonl"), EXPORT_CSV_FILE)
    else:
        foreign = sorted(p.name for p in path.iterdir()
                         if not (EXPORT_BAG_FOLDER.match(p.name) and (p / "metadata.yaml").is_file()))
    return f"it holds {foreign[0]!r}, which PhySynth did not write" if foreign else None


def why_not_replaceable(path: Path, kind: str) -> str | None:
    """None when ``path`` is PhySynth output of ``kind`` ("dataset", "report", "scenario", "json",
    "export-hdf5", "export-csv", "export-rosbag2"); otherwise a short reason (naming the first file
    PhySynth did not write)."""
    if kind.startswith("export-"):
        return _why_not_export(path, kind)
    if kind in ("dataset", "report"):
        if not path.is_dir():
            return "it is not a folder"
        if kind == "dataset":
            meta = _physynth_json(path / "dataset.json")
            if not _marked(meta):
                return "it is not a PhySynth dataset (no dataset.json written by physynth)"
            listed = {str(n).split("/")[0] for n in ((meta.get("files") or {}) if isinstance(meta.get("files"), dict)
                                                    else ())}
            foreign = _foreign_entries(path, DATASET_FILES | DATASET_FOLDERS | listed)
        else:
            data = _physynth_json(path / "report.json")
            legacy = data is not None and {"inputs", "real", "synthetic", "ks_statistic"} <= set(data)
            if not (_marked(data) or legacy):
                return "it is not a PhySynth report folder (no report.json written by physynth)"
            foreign = _foreign_entries(path, (), REPORT_FILE_PATTERN)
        if foreign:
            return f"it holds {foreign[0]!r}, which PhySynth did not write"
        return None
    if not path.is_file():
        return "it is not a file"
    if kind == "scenario":
        try:
            with path.open(encoding="utf-8") as f:
                first = f.readline()
        except (OSError, UnicodeDecodeError):
            first = ""
        return None if first.startswith((SCENARIO_MARKER, SURVEY_MARKER)) else (
            "it is not a scenario file written by physynth calibrate or physynth scenario survey")
    return None if _marked(_physynth_json(path)) else "it is not a report written by physynth"


def _check_apart(out: str | os.PathLike, real: Path, inputs: Sequence[str | os.PathLike]) -> None:
    """Refuse an output that is, holds or lies inside one of the command's input files or folders (an
    output inside an input dataset would make that dataset hold a file PhySynth did not write there)."""
    for inp in inputs:
        r_in = resolve_output(inp)
        if _is_within(r_in, real):
            what = "is" if r_in == real else "holds"
            raise UnsafeOutputError(f"output {out} {what} the input {inp} of the same command; "
                                    "choose another output")
        if _is_within(real, r_in):
            raise UnsafeOutputError(f"output {out} lies inside the input {inp} of the same command; "
                                    "choose an output outside it")


def check_output(out: str | os.PathLike, *, kind: str, overwrite: bool,
                 inputs: Sequence[str | os.PathLike] = ()) -> Path:
    """Check that ``out`` may be written; return its resolved path.

    Raises
    ------
    UnsafeOutputError
        ``out`` is the current folder or one of its parents, is, holds or lies inside one of ``inputs``, or
        exists and is not PhySynth output of ``kind`` (with or without ``overwrite``: it would refuse it).
    OutputExistsError
        ``out`` is PhySynth output of ``kind`` (for a report folder: holds a report) and ``overwrite`` is
        False. An empty folder (an empty file for a file output) is used as if new (:func:`is_vacant`).
    """
    real = resolve_output(out)
    _check_apart(out, real, inputs)
    if kind in FOLDER_KINDS and _is_within(Path.cwd().resolve(), real):
        raise UnsafeOutputError(f"output {out} is the current folder or holds it; choose another output")
    if not os.path.lexists(real):
        return real
    if kind not in FILE_KINDS and real.exists() and not real.is_dir():  # --overwrite would not help: say so at once
        raise UnsafeOutputError(f"output {out} is a file, not a folder; choose another output")
    if kind in FILE_KINDS and real.is_dir():
        raise UnsafeOutputError(f"output {out} is a folder, not a file; give a file name")
    if is_vacant(real, kind):
        return real  # nothing to lose: used as if new (and replaced atomically)
    reason = why_not_replaceable(real, kind)
    if reason and not overwrite:  # --overwrite would refuse it too: say so at once
        what = "a report into " if kind == "report" else ""
        raise UnsafeOutputError(f"refusing to write {what}{out}: {reason}; choose another output")
    if reason:
        raise UnsafeOutputError(f"refusing to overwrite {out}: {reason}; remove it yourself or choose "
                                "another output")
    if not overwrite:
        raise OutputExistsError(out, "holds a report" if kind == "report" else "")
    return real


def is_vacant(path: Path, kind: str) -> bool:
    """True when the existing output ``path`` holds nothing to lose: an empty folder where a folder goes,
    an empty file where a file goes (``kind`` one of :data:`FILE_KINDS`). A writer uses it as if it were
    new, without ``overwrite``."""
    if kind in FILE_KINDS:
        return path.is_file() and path.stat().st_size == 0
    return path.is_dir() and not any(path.iterdir())


def check_study_output(out: str | os.PathLike, *, marker: str, what: str, overwrite: bool,
                       inputs: Sequence[str | os.PathLike] = ()) -> Path:
    """Check that a study may write its files into the folder ``out`` (``physynth study ...``).

    A study writes a fixed set of files, ``marker`` (its JSON) among them. Refused: the current folder or
    one of its parents; a folder that already holds files but no ``marker`` (the user's folder: a study
    would overwrite its files of the same names); a folder with ``marker`` without ``overwrite``; an
    output that is, holds or lies inside one of ``inputs``.
    """
    real = resolve_output(out)
    _check_apart(out, real, inputs)
    if _is_within(Path.cwd().resolve(), real):
        raise UnsafeOutputError(f"output {out} is the current folder or holds it; choose another output")
    if real.exists() and not real.is_dir():
        raise UnsafeOutputError(f"output {out} is a file, not a folder; choose another output")
    if real.is_dir() and any(real.iterdir()) and not (real / marker).is_file():
        raise UnsafeOutputError(f"refusing to write {what} into {out}: it holds files and no {marker}; "
                                "choose a new or empty folder")
    if (real / marker).is_file() and not overwrite:
        raise OutputExistsError(out, f"holds {what}")
    return real


def check_distinct(named: Sequence[tuple[str, str | os.PathLike | None]]) -> None:
    """Refuse two arguments of one command that name the same file (``[(label, path), ...]``)."""
    seen: dict[Path, str] = {}
    for label, p in named:
        if p is None:
            continue
        real = resolve_output(p)
        if real in seen:
            raise UnsafeOutputError(f"{seen[real]} and {label} are the same file ({p}); give two different files")
        seen[real] = label


# ---------------------------------------------------------------- interruption
_interrupt: list[int] = []
_active: set[Path] = set()


def set_interrupted(signum: int) -> None:
    """Record that a termination signal arrived (the command line's signal handler calls this)."""
    if not _interrupt:
        _interrupt.append(signum)


def clear_interrupted() -> None:
    """Forget a recorded signal (the command that received it has ended)."""
    _interrupt.clear()


def check_interrupted() -> None:
    """Raise :class:`~physynth.errors.Interrupted` if a signal arrived. Writers call it for every trace:
    a handler's exception can be swallowed when the signal lands inside a finaliser, so the flag is
    checked again at the next safe point."""
    if _interrupt:
        from ..errors import Interrupted

        raise Interrupted(_interrupt[0])


def register_temporary(path: Path) -> None:
    """A temporary file or folder being written: removed by :func:`remove_registered` on a hard exit."""
    _active.add(path)


def unregister_temporary(path: Path) -> None:
    _active.discard(path)


@contextmanager
def replacing(dest: Path, *, nested: bool = False) -> Iterator[Path]:
    """Write ``dest`` through its hidden temporary sibling (:func:`~physynth.io.atomic.temp_sibling`, emptied
    first): the block writes the temporary, which is moved onto ``dest`` when the block ends; any exception
    (an interrupt included) removes it. Registered meanwhile, so a forced exit removes it too.

    ``nested``: the temporary is a new folder and the block writes ``<temporary>/<dest's name>`` in it (for
    writers whose files are named after their folder, such as ``rosbags``' SQLite3 bag writer), which becomes
    ``dest``."""
    from .atomic import temp_sibling

    tmp = temp_sibling(dest)
    if os.path.lexists(tmp):  # left by a run that was killed
        remove_tree(tmp)
    register_temporary(tmp)
    done = False
    try:
        if nested:
            tmp.mkdir()
        yield tmp
        os.replace(tmp / dest.name if nested else tmp, dest)
        done = True
    finally:
        if not (done and (not nested or _removed_empty(tmp))):
            remove_tree(tmp)  # what is left of it after an exception
        unregister_temporary(tmp)


def _removed_empty(folder: Path) -> bool:
    """Remove ``folder`` if it is empty (one call, where a tree walk takes a dozen: a bag export empties one
    for every trace); False when it could not be."""
    try:
        folder.rmdir()
    except OSError:
        return False
    return True


def remove_registered() -> None:
    """Remove every registered temporary path (the last resort before a forced exit)."""
    for p in list(_active):
        remove_tree(p)
        _active.discard(p)


# ---------------------------------------------------------------- orphaned temporary files
def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _size_bytes(p: Path) -> int:
    if p.is_file() or p.is_symlink():
        return p.lstat().st_size
    total = 0
    for root, _, files in os.walk(p):
        for f in files:
            try:
                total += os.lstat(os.path.join(root, f)).st_size
            except OSError:
                pass
    return total


def remove_tree(p: Path) -> None:
    """Remove a file, a symlink or a folder (a symlink itself, never what it points to)."""
    if p.is_symlink() or p.is_file():
        p.unlink(missing_ok=True)
    elif p.exists():
        shutil.rmtree(p, ignore_errors=True)


def find_orphans(out: Path) -> list[Path]:
    """Hidden temporary siblings of ``out`` left by another process (not this one)."""
    parent = out.parent
    if not parent.is_dir():
        return []
    found = []
    for p in parent.iterdir():
        m = _TEMP.match(p.name)
        if m and m["name"] == out.name and int(m["pid"]) != os.getpid():
            found.append(p)
    return sorted(found)


def remove_orphans(out: Path) -> list[Path]:
    """Remove the temporary siblings of ``out`` that an interrupted run left; warn about each.

    Call it only while holding the :class:`OutputLock` of ``out``: then no other PhySynth process
    is writing them.
    """
    removed = []
    for p in find_orphans(out):
        pid = int(_TEMP.match(p.name)["pid"])  # type: ignore[index]
        size = _size_bytes(p)
        remove_tree(p)
        warnings.warn(f"removed {p} ({size / 1e6:.1f} MB), left behind by an interrupted run (pid {pid})",
                      PhySynthWarning, stacklevel=2)
        removed.append(p)
    return removed


# ---------------------------------------------------------------- locks
def lock_path(out: Path) -> Path:
    """The lock file of an output: ``.<name>.lock`` in the same folder."""
    return out.with_name(f".{out.name}.lock")


class OutputLock:
    """An exclusive lock on one output path, held by this process until :meth:`release`.

    The lock is the file ``.<name>.lock`` beside the output, created exclusively and holding
    ``pid host time``. It is also ``flock``-ed, so a lock whose process died (even by SIGKILL) is
    recognised as stale at once on the same machine; on another host only the pid written in the
    file can be shown (the message says so).
    """

    def __init__(self, out: str | os.PathLike) -> None:
        self.out = Path(out)
        self.path = lock_path(self.out)
        self._fd: int | None = None
        self.stale_owner: str | None = None

    def acquire(self) -> OutputLock:
        for _ in range(20):
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            except FileNotFoundError:
                raise PhySynthError(f"output folder {self.out.parent} does not exist") from None
            if fcntl is not None:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError as exc:
                    owner = self._owner(fd)
                    os.close(fd)
                    if exc.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                        raise OutputLockedError(f"{self.out} is being written by another physynth process "
                                                f"({owner}); wait for it to finish") from None
                    raise
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino  # not unlinked by a releasing owner
            except FileNotFoundError:
                same = False
            if not same:
                os.close(fd)
                continue
            owner = self._owner(fd)
            if fcntl is None and owner and not self._stale(owner):  # pragma: no cover
                os.close(fd)
                raise OutputLockedError(f"{self.out} is being written by another physynth process ({owner})")
            # a lock file with an owner but no flock: that process died (a killed run); it is taken over
            # quietly, and the run's leftovers are reported by remove_orphans or the unfinished-run check
            self.stale_owner = owner if owner != "owner unknown" else None
            os.ftruncate(fd, 0)
            os.write(fd, f"pid {os.getpid()} host {socket.gethostname()} since "
                         f"{time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())}\n".encode())
            self._fd = fd
            register_temporary(self.path)
            return self
        raise OutputLockedError(f"{self.out}: could not take the lock {self.path}")  # pragma: no cover

    @staticmethod
    def _owner(fd: int) -> str:
        try:
            os.lseek(fd, 0, os.SEEK_SET)
            return os.read(fd, 200).decode("utf-8", "replace").strip() or "owner unknown"
        except OSError:
            return "owner unknown"

    @staticmethod
    def _stale(owner: str) -> bool:  # pragma: no cover - only without flock
        m = re.match(r"pid (\d+) host (\S+)", owner)
        return bool(m) and m[2] == socket.gethostname() and not _pid_alive(int(m[1]))

    def release(self) -> None:
        if self._fd is None:
            return
        try:
            self.path.unlink(missing_ok=True)
        finally:
            os.close(self._fd)
            self._fd = None
            unregister_temporary(self.path)

    @property
    def held(self) -> bool:
        return self._fd is not None

    def __enter__(self) -> OutputLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


@contextmanager
def guarded_outputs(outputs: Sequence[str | os.PathLike]) -> Iterator[list[Path]]:
    """Lock every output (resolved), remove their orphaned temporary siblings, and yield the paths."""
    with ExitStack() as stack:
        paths = []
        for o in outputs:
            real = resolve_output(o)
            stack.enter_context(OutputLock(real))
            remove_orphans(real)
            paths.append(real)
        yield paths


@contextmanager
def output_locked(out: str | os.PathLike) -> Iterator[Path]:
    """Hold the lock of the output ``out`` (a study's folder) while the block works and writes.

    The lock ``generate`` takes on its dataset (:class:`OutputLock`): a second run writing the same
    output is refused at once (:class:`~physynth.errors.OutputLockedError`); orphaned temporary
    siblings of a killed run are removed (and reported). The parent folders are created.
    """
    real = resolve_output(out)
    try:
        real.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PhySynthError(f"cannot create the output folder {real.parent}: {exc.strerror}") from None
    with OutputLock(real):
        remove_orphans(real)
        yield real


def prepare_output(out: str | os.PathLike, *, kind: str, overwrite: bool,
                   inputs: Sequence[str | os.PathLike] = (), remove_orphaned: bool = True) -> tuple[Path, OutputLock]:
    """Everything a writer does before writing ``out``: check it may be written (:func:`check_output`),
    take its lock, remove orphaned temporary siblings (unless ``remove_orphaned`` is False, e.g. for a
    writer that resumes from them), and check again under the lock.

    Returns the resolved output path and the held lock (the caller releases it when done).
    """
    check_output(out, kind=kind, overwrite=overwrite, inputs=inputs)
    real = resolve_output(out)
    if kind == "dataset":  # `--out runs/default` in a fresh checkout: create the parent folders
        try:
            real.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise PhySynthError(f"cannot create the output folder {real.parent}: {exc.strerror}") from None
    lock = OutputLock(real).acquire()
    try:
        if remove_orphaned:
            remove_orphans(real)
        check_output(out, kind=kind, overwrite=overwrite, inputs=inputs)  # another run may have just finished
    except BaseException:
        lock.release()
        raise
    return real, lock


def swap_in(tmp: Path, out: Path) -> None:
    """Put the finished ``tmp`` (file or folder) in place of ``out``: a former ``out`` is first renamed to
    a hidden ``.<out>.old-<pid>`` sibling, removed once ``tmp`` is in place (a crash in between leaves
    that sibling, which :func:`remove_orphans` finds)."""
    old = out.with_name(f".{out.name}.old-{os.getpid()}")
    if os.path.lexists(out):
        os.replace(out, old)
    os.replace(tmp, out)
    remove_tree(old)


@contextmanager
def atomic_folder(out: Path) -> Iterator[Path]:
    """Write a folder atomically: yield a hidden temporary sibling, swap it in for ``out`` on success,
    remove it on failure or interruption. ``out`` must already have passed :func:`check_output`
    (it is absent, empty, or PhySynth output that may be replaced)."""
    from .atomic import temp_sibling

    tmp = temp_sibling(out)
    remove_tree(tmp)
    tmp.mkdir(parents=True)
    register_temporary(tmp)
    try:
        yield tmp
        swap_in(tmp, out)
    except BaseException:
        remove_tree(tmp)
        raise
    finally:
        unregister_temporary(tmp)
