"""Generation on several cores or a Dask cluster, one shard of traces per task.

Trace ``i`` depends only on the scenario, the root seed and ``i`` (:mod:`physynth.rng`), and the shard
cut depends only on the number of traces (:mod:`physynth.io.shards`), so every way of running gives
the same dataset: in this process, on an embedded :class:`distributed.LocalCluster` of worker
processes, or on an existing Dask distributed cluster (whose workers must have PhySynth installed
and see the output directory at the same path, e.g. a shared file system).

Dask is an optional dependency (the extra ``physynth[scale]``); it is imported only here, and only
when more than one worker or a scheduler address is asked for.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ._children import TERMINAL_SIGNALS, apart
from .errors import PhySynthError
from .io.shards import ShardPlan, write_shard

if TYPE_CHECKING:
    from .generate import CompiledScenario
    from .scenario import Scenario


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


@functools.lru_cache(maxsize=4)
def _compiled(scenario_json: str) -> CompiledScenario:
    """A scenario compiled once per worker process (tasks of one run share it)."""
    from .generate import compile_scenario  # here: exports run tasks too, without the generator
    from .scenario import scenario_from_dict

    return compile_scenario(scenario_from_dict(json.loads(scenario_json)))


def shard_task(scenario_json: str, root_seed: int, partial: str, k: int, start: int, stop: int,
               meta: dict[str, Any], on_unit: Callable[[], None] | None = None,
               writer: Callable[..., Any] | None = None) -> int:
    """Generate traces ``start .. stop - 1`` and write them as shard ``k`` (what a worker runs; ``writer``: see
    :func:`~physynth.io.shards.write_shard`)."""
    from .generate import generate_trace

    cs = _compiled(scenario_json)

    def traces():
        for i in range(start, stop):
            yield i, generate_trace(cs, i, root_seed)
            if on_unit is not None:
                on_unit()

    return write_shard(partial, k, traces(), meta, writer)


WORKER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "500ms",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.worker.multiprocessing-method": "spawn",
}
"""Dask settings of the embedded cluster's workers: no statistical profiler (it samples every worker
thread's stack every 10 ms), a 500 ms event-loop tick and a 1 s memory monitor, for a dashboard nobody
looks at during a batch run. Measured side by side on the idle 2-core machine
(``benchmarks/bench_dask_overhead.py``): CPU per trace in a worker is 1.14-1.26x that of a plain
process with Dask's defaults and 1.16-1.26x with these, so they change nothing measurable; the
remaining overhead is the worker's own event loop and communication. The workers are started by
``spawn`` (a new interpreter), the start :func:`physynth._children.apart` keeps apart from the terminal."""


@contextlib.contextmanager
def _quiet_workers() -> Iterator[None]:
    import dask

    with dask.config.set(WORKER_CONFIG):
        yield


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP that arrive inside the block are held and raised at its end.

    Starting and closing a cluster cannot be cut short without leaving worker processes no one closes;
    a signal there is delivered (to whatever handler this process has) once the cluster is started or
    closed, inside the ``try`` that closes it. A second signal is delivered at once.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    previous: dict[int, Any] = {}

    def hold(signum: int, frame: Any) -> None:
        if not held:
            held.append(signum)
            return
        handler = previous.get(signum)
        if callable(handler):
            handler(signum, frame)

    for s in TERMINAL_SIGNALS:
        if signal.getsignal(s) not in (signal.SIG_IGN, None):
            previous[s] = signal.signal(s, hold)
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        if held:
            signal.raise_signal(held[0])


def require_dask() -> Any:
    """The ``distributed`` module, or a one-line error naming the extra to install."""
    from .extras import require

    return require("distributed", "scale", "more than one worker, or a scheduler,")


MAIN_GUARD_HINT = ('a script that starts worker processes (workers > 1) must make its calls under '
                   '`if __name__ == "__main__":`, since each worker process imports the script again')
"""The one line that tells a script author why an embedded cluster did not start (docs/scale.md)."""


def check_not_bootstrapping() -> None:
    """Refuse to start worker processes from a process that is itself starting as one.

    A worker process (started by spawn, as Dask's are) imports the calling script again; a script
    without the ``if __name__ == "__main__":`` guard then calls the generation again, while the process
    is still starting up. This is the test :mod:`multiprocessing` makes before it starts a process.

    Raises
    ------
    PhySynthError
        This process is importing the script that started it (:data:`MAIN_GUARD_HINT`).
    """
    import multiprocessing

    if getattr(multiprocessing.current_process(), "_inheriting", False):
        raise PhySynthError(f"this process is a worker process still starting up, which cannot start workers "
                            f"of its own: {MAIN_GUARD_HINT}")


def _local_cluster(distributed: Any, n_workers: int) -> Any:
    """An embedded cluster of ``n_workers`` worker processes (one thread each), or a one-line error."""
    import logging

    check_not_bootstrapping()
    try:
        with _quiet_workers():
            return distributed.LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                                            dashboard_address=":0", silence_logs=logging.ERROR)
    except Exception as exc:  # noqa: BLE001 - any failure to start ("Nanny failed to start") is reported so
        reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise PhySynthError(f"the Dask worker processes did not start ({reason}); {MAIN_GUARD_HINT}") from None


def run_shards(scn: Scenario, root_seed: int, partial: Path, plan: ShardPlan, todo: Sequence[int],
               meta: dict[str, Any], *, workers: int = 1, scheduler: str | None = None,
               progress: Callable[[int], None] | None = None, writer_process: bool = True) -> None:
    """Write the shards ``todo`` of ``plan`` into ``partial``.

    Parameters
    ----------
    workers : int
        Worker processes of an embedded local cluster; 1 runs in this process (no Dask needed).
    scheduler : str, optional
        Address of an existing Dask scheduler (e.g. ``tcp://10.0.0.5:8786``); ``workers`` is then ignored.
    progress : callable, optional
        ``progress(traces_done)`` after each trace (in this process) or each shard (on a cluster).
    writer_process : bool
        In this process, write the shards in a writer process on a spare core
        (:func:`physynth.io.writer_process.local_writers`); False: here.
    """
    from .scenario import scenario_to_dict

    scenario_json = json.dumps(scenario_to_dict(scn))
    partial = Path(partial).absolute()  # workers of a remote cluster may run in another directory
    tasks = [(scenario_json, root_seed, str(partial), k, *plan.bounds(k), meta) for k in todo]
    sizes = [t[5] - t[4] for t in tasks]
    if not tasks:
        return
    if scheduler is None and (workers <= 1 or len(tasks) <= 1):  # here, with a writer process on a spare core
        from .io.writer_process import local_writers

        with local_writers(available_cores() if writer_process else 1, sum(sizes)) as writer:
            run_tasks(functools.partial(shard_task, writer=writer), tasks, sizes, progress=progress)
        return
    run_tasks(shard_task, tasks, sizes, workers=workers, scheduler=scheduler,
              progress=progress, name="physynth-shard", unfinished=(partial, ".shard-*.tmp-*"))


def run_tasks(fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]], sizes: Sequence[int], *, workers: int = 1,
              scheduler: str | None = None, progress: Callable[[int], None] | None = None,
              name: str = "physynth-task", unfinished: tuple[Path, str] | None = None) -> list[Any]:
    """``[fn(*task) for task in tasks]``, in task order, in this process or on ``workers`` processes of an
    embedded cluster or the Dask ``scheduler`` (the shards of ``generate``, the parts of an export).

    ``sizes``: the units of work (traces) of each task; ``progress(done)`` with the units done so far, after
    each unit in this process (``fn`` is given ``on_unit=``, a callable it calls after each unit) or after
    each task on a cluster. ``fn`` must be importable by name. ``unfinished``: (folder, glob) of what a task
    leaves behind when its worker is killed, removed when an embedded cluster is stopped at once.
    """
    done = 0

    def count(n: int = 1) -> None:
        nonlocal done
        done += n
        if progress is not None:
            progress(done)

    if scheduler is None and (workers <= 1 or len(tasks) <= 1):
        return [fn(*task, on_unit=count) for task in tasks]
    distributed = require_dask()
    with apart():  # workers in a session of their own, their output to the log (physynth._children)
        return _run_on_cluster(distributed, fn, tasks, sizes, workers, scheduler, count, name, unfinished)


def _run_on_cluster(distributed: Any, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]],
                    sizes: Sequence[int], workers: int, scheduler: str | None, count: Callable[[int], None],
                    name: str, unfinished: tuple[Path, str] | None) -> list[Any]:
    """:func:`run_tasks` on a cluster: started and closed with signals held, stopped at once when interrupted."""
    cluster = client = None
    futures: dict[Any, int] = {}
    results: list[Any] = [None] * len(tasks)
    try:
        with _signals_held():
            if scheduler is not None:
                _refuse_closed_port(scheduler)
                try:
                    client = distributed.Client(scheduler, timeout="10s")
                except (OSError, TimeoutError, ValueError) as exc:
                    raise PhySynthError(f"cannot connect to the Dask scheduler {scheduler}: {exc}") from None
            else:
                cluster = _local_cluster(distributed, min(workers, len(tasks)))
                client = distributed.Client(cluster)
        for i, task in enumerate(tasks):
            futures[client.submit(fn, *task, key=f"{name}-{os.getpid()}-{i}", pure=False)] = i
        for fut in distributed.as_completed(futures):
            results[futures[fut]] = fut.result()  # re-raises a worker's error here
            count(sizes[futures[fut]])
    except BaseException:
        if cluster is not None:  # interrupted or failed: the tasks being run will not be finished
            _stop_workers_now(cluster, unfinished)
        elif client is not None and futures:
            with contextlib.suppress(Exception):  # a remote worker finishes the task it runs (atomically)
                client.cancel(list(futures), force=True)
        raise
    finally:
        with _signals_held():
            if client is not None:
                client.close()
            if cluster is not None:
                cluster.close()
    return results


def _refuse_closed_port(scheduler: str) -> None:
    """Fail at once when nothing listens at a TCP scheduler address (the connection is refused), rather than
    after the 10 s a Dask client spends retrying; other addresses and errors are left to the client."""
    import socket
    from urllib.parse import urlsplit

    if "://" in scheduler and not scheduler.startswith("tcp://"):
        return
    try:
        parts = urlsplit(scheduler if "://" in scheduler else f"tcp://{scheduler}")
        host, port = parts.hostname, parts.port
    except ValueError:
        return
    if host is None or port is None:
        return
    try:
        socket.create_connection((host, port), timeout=2.0).close()
    except ConnectionRefusedError:
        raise PhySynthError(f"cannot connect to the Dask scheduler {scheduler}: connection refused (is it "
                            "running?)") from None
    except OSError:
        pass  # unknown host, unreachable, slow: the client says what it finds


def _stop_workers_now(cluster: Any, unfinished: tuple[Path, str] | None, wait_s: float = 5.0) -> None:
    """Kill the embedded cluster's worker processes and remove what they were writing (``unfinished``: a
    folder and a glob, e.g. the hidden temporary shards).

    Their nannies are told first not to start them again. Complete shards stay (for a resumed run)."""
    import shutil
    import time

    nannies = list(getattr(cluster, "workers", {}).values())
    pids = []
    for nanny in nannies:
        with contextlib.suppress(Exception):
            nanny.close_gracefully(reason="physynth-stopped")
        pid = getattr(nanny, "pid", None)
        if pid:
            pids.append(pid)
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
    deadline = time.monotonic() + wait_s
    while any(_running(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.02)
    for tmp in Path(unfinished[0]).glob(unfinished[1]) if unfinished else ():
        shutil.rmtree(tmp, ignore_errors=True) if tmp.is_dir() else tmp.unlink(missing_ok=True)


def _running(pid: int) -> bool:
    """The process exists and has not ended (a zombie, ended but not yet reaped, has)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            state = f.read().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        try:
            os.kill(pid, 0)
        except OSError:
            return False
        return True  # no /proc (not Linux): alive as far as can be told
    return state not in ("Z", "X")
