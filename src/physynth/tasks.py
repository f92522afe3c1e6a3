"""Independent tasks on the workers ``generate`` uses: in this process, on an embedded Dask cluster or on an
existing scheduler (:mod:`physynth.parallel` starts and configures the cluster).

:func:`run_tasks` runs ``fn(*args)`` for every task and returns the results in task order, whatever the
order the workers finish them in, so an output assembled from them is the same for any number of workers.
Exports (:func:`physynth.workflows.export_dataset`) run one task per part of a dataset.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any

from .errors import PhySynthError


def run_tasks(fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]], sizes: Sequence[int], *, workers: int = 1,
              scheduler: str | None = None, progress: Callable[[int], None] | None = None,
              name: str = "physynth-task") -> list[Any]:
    """``[fn(*task) for task in tasks]``, on ``workers`` processes or the Dask ``scheduler``.

    ``sizes``: the units of work (traces) of each task. ``progress(done)`` is called with the units done so
    far: after each unit in this process (``fn`` is then given ``on_unit=`` a callable it calls after each
    unit), after each task on a cluster. ``fn`` must be importable by name (a module-level function).
    """
    done = 0

    def count(n: int = 1) -> None:
        nonlocal done
        done += n
        if progress is not None:
            progress(done)

    if scheduler is None and (workers <= 1 or len(tasks) <= 1):
        return [fn(*task, on_unit=count) for task in tasks]
    from .parallel import _local_cluster, require_dask

    distributed = require_dask()
    if scheduler is not None:
        try:
            client = distributed.Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise PhySynthError(f"cannot connect to the Dask scheduler {scheduler}: {exc}") from None
        cluster = None
    else:
        cluster = _local_cluster(distributed, min(workers, len(tasks)))
        client = distributed.Client(cluster)
    try:
        futures = {client.submit(fn, *task, key=f"{name}-{os.getpid()}-{k}", pure=False): k
                   for k, task in enumerate(tasks)}
        results: list[Any] = [None] * len(tasks)
        for fut in distributed.as_completed(futures):
            k = futures[fut]
            results[k] = fut.result()  # re-raises a worker's error here
            count(sizes[k])
        return results
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
