"""Datasets written by a process of their own while this one generates the traces.

A :class:`~physynth.io.dataset.DatasetWriter` converts, encodes, compresses and hashes about as much CPU time
per trace as generating the trace takes. Its writer thread runs beside the generating thread, but threads of
one process slow each other down (``benchmarks/bench_writer_interference.py``): a generating thread beside a
Parquet-writing thread lost 21-40 % of its speed where beside a writing *process* it lost nothing. So a run on
one worker of a machine with a core to spare, of at least :data:`MIN_TRACES` traces (:func:`local_writers`),
hands its traces to a writer process:

- the process is ``python -m physynth.io.writer_process`` (a subprocess of its own, not :mod:`multiprocessing`,
  whose ``spawn`` would run a user's script again), started once per run and given one dataset after another;
- each trace goes as a pickle whose NumPy arrays are out of band (protocol 5): the arrays are copied into a ring
  of shared memory (:data:`RING_BYTES`, an anonymous ``memfd`` both processes map; Linux), the pickle and where
  the arrays lie go through a pipe (:class:`multiprocessing.connection.Connection` frames the messages), and
  the process copies the arrays out and frees their place before it writes them. A trace larger than half the
  ring, or a system without ``memfd``, sends its arrays through the pipe (a copy more, in the kernel). The
  process writes with the same :class:`~physynth.io.dataset.DatasetWriter`, so the files are the same, byte
  for byte;
- it runs in a session of its own (a terminal's Ctrl-C reaches only this process, which stops it) with its
  output sent where the worker processes' goes (:mod:`physynth._children`); it aborts the dataset it is writing
  (its temporary folder removed) and exits when this process says so or its end of the pipe closes, so it
  never outlives a killed run;
- a dataset's close does not wait for the process to finish it (the next traces are made meanwhile):
  :meth:`WriterProcess.finish` waits for every one, once, at the end of the run;
- an error there (a full disk, a held lock) comes back as the same exception class with its message and
  attributes, raised by the next call here (:meth:`RemoteDatasetWriter.add`, ``close`` or
  :meth:`WriterProcess.finish`).

The environment variable :data:`ENV_VAR` set to ``0`` (or ``false``, ``no``, ``off``) keeps the writing in this
process (:class:`~physynth.io.dataset.DatasetWriter`'s thread), as on a machine of one core.
"""

from __future__ import annotations

import collections
import contextlib
import mmap
import os
import pickle
import subprocess
import sys
from collections.abc import Callable, Iterator, Sequence
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from .. import errors
from .._children import output_fd
from ..errors import DatasetError, PhySynthError
from . import safety
from .atomic import ClosesOrAborts

ENV_VAR = "PHYSYNTH_WRITER_PROCESS"
PIPE_BYTES = 1 << 20
"""Size asked for the pipe (Linux; 64 KiB otherwise): the messages, and the arrays of a trace that does not go
through the ring, in fewer turns between the two processes."""
RING_BYTES = 32 << 20
"""Shared memory between the processes for the arrays of the traces on their way (a default trace has about
2.5 MB): several traces, so that this process rarely waits for the other to free a place."""
MIN_TRACES = 500
"""Runs of fewer traces write in their own process (a writer thread): the writer process's start (about 0.3 s:
Python, NumPy, pyarrow) and the copy of every trace into the ring outweigh what it saves the generating thread
(about 0.5 ms per trace) on shorter runs. Where the two cross depends on the machine (docs/scale.md "Writing on
a spare core", 2026-12-06): on a 2-core AMD EPYC the thread was as fast or faster up to 500-700 traces, on a
2-core Intel Xeon the process was faster from 200."""
ALIGN = 64
STOP_WAIT_S = 10.0
"""How long :meth:`WriterProcess.stop` waits for the process to abort and exit before it kills it."""


def opted_out() -> bool:
    """True when :data:`ENV_VAR` asks to keep the writing in this process."""
    return os.environ.get(ENV_VAR, "").strip().lower() in {"0", "false", "no", "off"}


def _error_record(exc: Exception) -> tuple[Any, ...]:
    """What the writer process sends of an error: ``("error", class name, message, attributes)``."""
    if isinstance(exc, OSError):
        return ("error", "OSError", str(exc), {"errno": exc.errno, "strerror": exc.strerror,
                                                "filename": None if exc.filename is None else str(exc.filename)})
    return ("error", type(exc).__name__, str(exc),
            {k: v for k, v in vars(exc).items() if isinstance(v, (str, int, float, Path))})


def _error_of(reply: tuple[Any, ...]) -> BaseException:
    """The exception a reply ``("error", class name, message, attributes)`` stands for: the PhySynth error of
    that class, message and attributes (e.g. :class:`~physynth.errors.OutputExistsError`'s ``path``); an
    :class:`OSError` (a full disk, a permission) with its errno, text and file name; anything else as a
    RuntimeError."""
    _, name, message, attributes = reply
    cls = getattr(errors, name, None)
    if isinstance(cls, type) and issubclass(cls, PhySynthError):
        exc = cls.__new__(cls)
        Exception.__init__(exc, message)  # not the class's own __init__, which would format the message again
        exc.__dict__.update(attributes)
        return exc
    if name == "OSError":  # errno picks the subclass (PermissionError, ...), as the failed call there raised it
        if attributes["errno"] is None:
            return OSError(message)
        return OSError(attributes["errno"], attributes["strerror"], attributes["filename"])
    return RuntimeError(f"the writer process failed: {name}: {message}")


class WriterProcess:
    """A writer process (module docstring) and the two ends of its pipes in this process.

    >>> with WriterProcess() as proc:                                      # doctest: +SKIP
    ...     with proc.writer(out, meta={"kind": "synthetic"}) as w:
    ...         for i, trace in enumerate(traces):
    ...             w.add(trace, index=i)
    """

    def __init__(self) -> None:
        import fcntl

        to_child_r, to_child_w = os.pipe()
        from_child_r, from_child_w = os.pipe()
        with contextlib.suppress(OSError, AttributeError):  # a larger pipe where the system allows it
            fcntl.fcntl(to_child_w, fcntl.F_SETPIPE_SZ, PIPE_BYTES)
        ring_fd = _memfd(RING_BYTES)
        self._ring = mmap.mmap(ring_fd, RING_BYTES) if ring_fd is not None else None
        self._head = 0  # where the next trace's arrays go in the ring
        self._busy: collections.deque[tuple[int, int, int]] = collections.deque()  # (seq, start, end) not yet freed
        self._seq = 0
        self._closing = 0  # datasets asked to close, not yet reported closed
        passed = (to_child_r, from_child_w) + (() if ring_fd is None else (ring_fd,))
        package_root = str(Path(__file__).resolve().parents[2])  # the folder holding the physynth package
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (package_root, env.get("PYTHONPATH", "")) if p)
        out = output_fd()
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "physynth.io.writer_process", *map(str, passed), str(RING_BYTES)],
                pass_fds=passed, stdin=subprocess.DEVNULL, stdout=out, stderr=out, env=env, start_new_session=True)
        except BaseException:
            for fd in (to_child_r, to_child_w, from_child_r, from_child_w):
                os.close(fd)
            if self._ring is not None:
                self._ring.close()
            raise
        finally:
            os.close(out)
            if ring_fd is not None:
                os.close(ring_fd)  # the mapping stays
        os.close(to_child_r)
        os.close(from_child_w)
        self._send = Connection(to_child_w, readable=False)
        self._recv = Connection(from_child_r, writable=False)
        self._failed: BaseException | None = None
        self.broken = False
        """True once a message was cut short or a reply not awaited (an interrupt): only :meth:`stop` is left."""

    def writer(self, path: str | os.PathLike, **options: Any) -> RemoteDatasetWriter:
        """A :class:`RemoteDatasetWriter` of a new dataset ``path``; ``options`` are those of
        :class:`~physynth.io.dataset.DatasetWriter` (it is opened there, by the process)."""
        path = Path(path).absolute()  # the process keeps the folder it started in
        self._post(("open", str(path), options))
        return RemoteDatasetWriter(self, path)

    def _post(self, message: tuple[Any, ...], buffers: Sequence[pickle.PickleBuffer] = ()) -> None:
        """Send ``message`` (and the out-of-band ``buffers`` that follow it); a process that has ended
        raises its error instead. Anything that stops a send half way (an interrupt) leaves the pipe
        holding part of a message: the process is then only stopped (:attr:`broken`)."""
        self._check()
        try:
            self._send.send(message)
            for buf in buffers:
                self._send.send_bytes(buf.raw())
        except OSError:  # a broken pipe: the process has ended
            raise self._fail() from None
        except BaseException:
            self.broken = True
            raise

    def _post_trace(self, index: int, trace: Any) -> None:
        """Send a trace: its arrays into the ring (or the pipe), its pickle and their places through the pipe."""
        buffers: list[pickle.PickleBuffer] = []
        header = pickle.dumps((int(index), trace), protocol=5, buffer_callback=buffers.append)
        raws = [b.raw() for b in buffers]
        offsets, end = [], 0
        for r in raws:
            offsets.append(end)
            end += -(-r.nbytes // ALIGN) * ALIGN
        if self._ring is None or end > len(self._ring) // 2:
            self._post(("trace", header, len(raws), None), buffers)
            return
        self._take_notes()
        if not self._busy:  # everything freed: start at the beginning, so that memory is touched only as needed
            self._head = 0
        start = self._head if self._head + end <= len(self._ring) else 0
        while any(s < start + end and start < e for _, s, e in self._busy):  # wait until the process freed it
            self._reply("freed")
        for r, off in zip(raws, offsets, strict=True):
            self._ring[start + off:start + off + r.nbytes] = r
        self._seq += 1
        self._busy.append((self._seq, start, start + end))
        self._head = start + end
        spans = [(start + off, r.nbytes) for r, off in zip(raws, offsets, strict=True)]
        self._post(("trace", header, self._seq, spans))

    def _take_notes(self) -> None:
        """Take the notes the process has sent (places freed, datasets closed) without waiting."""
        while self._busy and self._recv.poll(0):
            self._reply("")

    def _reply(self, until: str, timeout_s: float | None = None) -> tuple[Any, ...]:
        """Read the process's messages until one of kind ``until`` (``"freed"``, ``"closed"``, ``"aborted"``;
        ``""``: the next one); its error raised, or a DatasetError when it ended without one (or sent nothing
        for ``timeout_s``). Notes on the way are taken into account: a place in the ring freed, a dataset closed."""
        self._check()
        while True:
            reply = self._next(timeout_s)
            if reply[0] == "error":
                raise self._failing(_error_of(reply))
            if reply[0] == "freed":
                while self._busy and self._busy[0][0] <= reply[1]:
                    self._busy.popleft()
            elif reply[0] == "closed":
                self._closing -= 1
            if reply[0] == until or not until:
                return reply

    def _close_dataset(self) -> None:
        self._post(("close",))
        self._closing += 1

    def _abort_dataset(self) -> None:
        """Ask the process to abort the dataset it writes and wait for it; stop the process instead when a
        message was cut short (it then aborts the dataset as its pipe closes)."""
        if not self.broken and self._failed is None:
            with contextlib.suppress(Exception):
                self._post(("abort",))
                self._reply("aborted", timeout_s=STOP_WAIT_S)
        if self.broken:
            self.stop()

    def finish(self) -> None:
        """Wait until every dataset this process was asked to close is in place (raising its error)."""
        while self._closing:
            self._reply("closed")

    def _next(self, timeout_s: float | None) -> tuple[Any, ...]:
        """The next message from the process, waited for while it runs (at most ``timeout_s``)."""
        try:
            waited = 0.0
            while not self._recv.poll(1.0):
                waited += 1.0
                if self._proc.poll() is not None and not self._recv.poll(0):
                    raise self._fail()
                if timeout_s is not None and waited >= timeout_s:
                    self.broken = True
                    raise DatasetError(f"the writer process gave no answer within {timeout_s:g} s")
            return self._recv.recv()
        except (EOFError, OSError):
            raise self._fail() from None
        except BaseException:
            self.broken = True  # an interrupt while waiting: the reply may come later, out of turn
            raise

    def _check(self) -> None:
        if self._failed is not None:
            raise self._failed
        if self.broken:
            raise DatasetError("the writer process was stopped by an interruption")

    def _fail(self) -> BaseException:
        """The error that ended the process: the one it sent, or one that says how it ended."""
        if self._failed is None:
            with contextlib.suppress(EOFError, OSError):
                while self._recv.poll(0):
                    reply = self._recv.recv()
                    if reply[0] == "error":
                        return self._failing(_error_of(reply))
            try:
                code = self._proc.wait(timeout=STOP_WAIT_S)
            except subprocess.TimeoutExpired:  # its pipe closed, it still runs: it will not write for us again
                self._proc.kill()
                code = self._proc.wait()
            how = f"signal {-code}" if code < 0 else f"exit code {code}"
            self._failing(DatasetError(f"the writer process ended unexpectedly ({how}); nothing was lost that "
                                       "a resumed run would not write again"))
        return self._failed  # type: ignore[return-value]

    def _failing(self, exc: BaseException) -> BaseException:
        """Record the error that ended the process (raised by every later call; no dataset will close)."""
        self._failed = exc
        self._closing = 0
        return exc

    def stop(self) -> None:
        """Tell the process to abort what it writes and exit; wait for it (killed after :data:`STOP_WAIT_S`)."""
        with contextlib.suppress(OSError):
            self._send.close()  # its end of the pipe closes: it aborts and exits
        try:
            self._proc.wait(timeout=STOP_WAIT_S)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        finally:
            with contextlib.suppress(OSError):
                self._recv.close()
            if self._ring is not None:
                self._ring.close()
                self._ring = None

    def __enter__(self) -> WriterProcess:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                self.finish()
        finally:
            self.stop()


class RemoteDatasetWriter(ClosesOrAborts):
    """What :class:`~physynth.io.dataset.DatasetWriter` does, done by a :class:`WriterProcess`: :meth:`add`
    sends a trace, :meth:`close` asks for the dataset to be finished (:meth:`WriterProcess.finish` waits for
    it), :meth:`abort` removes what was written."""

    def __init__(self, proc: WriterProcess, path: Path) -> None:
        self._proc = proc
        self.path = path
        self._done = False

    def add(self, trace: Any, index: int) -> None:
        safety.check_interrupted()
        self._proc._post_trace(index, trace)

    def close(self) -> Path:
        """Ask the process to finish the dataset, and return at once: the traces of the next dataset are made
        while it writes the last row group of this one. :meth:`WriterProcess.finish` waits until every
        dataset is in place (an error shows there, or at the next call)."""
        self._done = True
        self._proc._close_dataset()
        return self.path

    def abort(self) -> None:
        """Remove what was written (after an interruption that cut a message short, by stopping the process)."""
        if not self._done:
            self._done = True
            self._proc._abort_dataset()


@contextlib.contextmanager
def local_writers(cores: int, n_traces: int) -> Iterator[Callable[..., Any] | None]:
    """The dataset writer factory for a run of ``n_traces`` in this process on a machine of ``cores`` cores:
    a :class:`WriterProcess`'s :meth:`~WriterProcess.writer` when a core is to spare and the run has at least
    :data:`MIN_TRACES` (and :data:`ENV_VAR` does not opt out), else None (write here, with
    :class:`~physynth.io.dataset.DatasetWriter`). When the block ends every dataset is in place (or its error
    raised) and the process stopped."""
    if (cores < 2 or n_traces < MIN_TRACES or opted_out() or os.name != "posix" or not sys.executable
            or getattr(sys, "frozen", False)):
        yield None  # no core to spare, too short a run, asked not to, no pass_fds (POSIX), no interpreter
        return
    try:
        proc = WriterProcess()
    except OSError:  # the interpreter cannot be started (a deleted virtual environment): write here
        yield None
        return
    with proc:
        yield proc.writer


def _memfd(size: int) -> int | None:
    """A new anonymous file of ``size`` bytes in memory, or None where the system has none (not Linux)."""
    try:
        fd = os.memfd_create("physynth-writer", os.MFD_CLOEXEC)
    except (AttributeError, OSError):
        return None
    try:
        os.ftruncate(fd, size)
    except OSError:
        os.close(fd)
        return None
    return fd


def _serve(recv: Connection, send: Connection, ring: mmap.mmap | None) -> None:
    """The writer process's loop: open, fill and close datasets as told, until told to stop or the pipe closes."""
    from .dataset import DatasetWriter

    writer: DatasetWriter | None = None
    try:
        while True:
            try:
                message = recv.recv()
            except EOFError:
                return  # the other process stopped us, or ended: abort what is being written (finally)
            kind = message[0]
            if kind == "trace":
                _, header, seq, spans = message
                if spans is None:  # the arrays follow through the pipe
                    buffers = [recv.recv_bytes() for _ in range(seq)]
                else:  # copied out of the ring, whose place is then free
                    buffers = [ring[off:off + n] for off, n in spans]  # type: ignore[index]
                    send.send(("freed", seq))
                index, trace = pickle.loads(header, buffers=buffers)
                writer.add(trace, index=index)  # type: ignore[union-attr]
            elif kind == "open":
                _, path, options = message
                writer = DatasetWriter(path, **options)
                writer.write_in_thread = False  # one thread: this process has one core, the other generates
            elif kind == "close":
                closing, writer = writer, None  # a close that fails has aborted the dataset itself
                path = closing.close()  # type: ignore[union-attr]
                send.send(("closed", str(path)))
            elif kind == "abort":
                if writer is not None:
                    aborting, writer = writer, None
                    aborting.abort()
                send.send(("aborted",))
    except Exception as exc:  # noqa: BLE001 - every error goes back to the other process, which raises it
        with contextlib.suppress(OSError):
            send.send(_error_record(exc))
    finally:
        if writer is not None:
            writer.abort()


def main(argv: list[str]) -> None:
    """Entry point of ``python -m physynth.io.writer_process RECV_FD SEND_FD [RING_FD] RING_BYTES``."""
    ring = mmap.mmap(int(argv[2]), int(argv[3])) if len(argv) == 4 else None
    _serve(Connection(int(argv[0]), writable=False), Connection(int(argv[1]), readable=False), ring)
    sys.stderr.flush()
    os._exit(0)  # every file is closed and every answer sent: no interpreter teardown (0.1 s) to wait for


if __name__ == "__main__":
    main(sys.argv[1:])
