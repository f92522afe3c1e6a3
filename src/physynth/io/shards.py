"""Datasets generated in shards: resumable after a kill, identical whatever the number of workers.

A generation of ``n`` traces is cut by trace index into shards of ``shard_traces`` traces (shard ``k``
holds traces ``k * shard_traces`` .. ``(k + 1) * shard_traces - 1``). The cut depends only on ``n`` and
``shard_traces``, never on the number of workers, so the output is the same file for file.

While the run is under way everything lives in a hidden sibling ``.<name>.partial/`` of the output:

- ``run.json``: the plan (scenario, root seed, number of traces, shard size, generator version);
  ``--resume`` refuses a plan that differs from the one it is asked to complete;
- ``shard-00000/`` ...: each a small dataset written by :class:`~physynth.io.dataset.DatasetWriter`,
  hence atomic: a shard directory exists only when complete. A killed worker leaves at most a hidden
  ``.shard-*.tmp-*`` directory, removed when the run resumes. A resumed run keeps a shard only when it
  matches its own integrity record (:func:`shard_problem`); a damaged one (a file changed, truncated or
  removed after it was written) is removed, written again and reported (a
  :class:`~physynth.errors.PhySynthWarning`).

When every shard is complete the shards are hard-linked (copied where links are impossible) into a
hidden staging directory holding the final layout, which is renamed into place; the partial
directory is removed last. A dataset of one shard has the usual tables ``truth.parquet``, ...; a
dataset of several shards has one folder per table with a part per shard (``truth/part-00000.parquet``
...), which :func:`physynth.io.dataset.iter_traces` and :func:`~physynth.io.dataset.read_dataset`
read in trace order.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .. import __version__, bounds
from .._json import jsonable
from ..errors import DatasetError, OutputExistsError, PhySynthError, PhySynthWarning
from . import integrity
from .atomic import atomic_write_text, temp_sibling
from .dataset import TABLES, DatasetWriter, generated_column_groups, read_meta
from .safety import is_vacant, remove_tree, swap_in

DEFAULT_SHARD_TRACES = 128
"""Traces per shard: small enough that a killed run loses little, large enough to keep files few."""

ROW_GROUP_TRACES = bounds.ROW_GROUP_TRACES
"""Traces per Parquet row group inside a shard: what a streaming reader (an export's worker) holds at a
time, and the writing left to do after a shard's last trace is made (the writer thread overlaps the rest
with making traces). Eight row groups per shard of the default 128 traces: side by side
(``benchmarks/bench_parquet_write.py``), 16 writes as fast as 64 and an export's worker holds half the
memory (``benchmarks/bench_export.py --workers 2``)."""

_SHARD_RE = re.compile(r"^shard-(\d{5,})$")


def partial_dir(out: Path) -> Path:
    """The hidden directory of an unfinished sharded run writing ``out``."""
    return out.with_name(f".{out.name}.partial")


def shard_name(k: int) -> str:
    return f"shard-{k:05d}"


@dataclass(frozen=True, slots=True)
class ShardPlan:
    """Which traces go to which shard. Shard ``k`` holds traces ``start(k) .. stop(k) - 1``."""

    n_traces: int
    shard_traces: int

    @property
    def n_shards(self) -> int:
        return -(-self.n_traces // self.shard_traces)

    def bounds(self, k: int) -> tuple[int, int]:
        start = k * self.shard_traces
        return start, min(start + self.shard_traces, self.n_traces)


def write_shard(partial: str | os.PathLike, k: int, traces: Any, meta: dict[str, Any],
                writer: Callable[..., Any] | None = None) -> int:
    """Write shard ``k`` (an iterable of ``(index, Trace)``) atomically into ``partial``; returns its trace count.

    A shard that is already complete is left alone (a resumed run never writes a trace twice). ``writer``:
    what makes the dataset writer, :class:`~physynth.io.dataset.DatasetWriter` (None) or a writer process's
    (:func:`physynth.io.writer_process.local_writers`); the files are the same.
    """
    dest = Path(partial) / shard_name(k)
    if dest.is_dir():
        return 0
    n = 0
    groups = generated_column_groups(meta["imu_frames"]) if "imu_frames" in meta else None
    with (writer or DatasetWriter)(dest, meta=meta, row_group_traces=ROW_GROUP_TRACES, compact=True,
                                   column_groups=groups) as w:
        for index, trace in traces:
            w.add(trace, index=index)
            n += 1
    return n


def prepare(out: Path, plan_record: dict[str, Any], *, resume: bool, overwrite: bool) -> tuple[Path, set[int]]:
    """Create (or, with ``resume``, check and reuse) the partial directory; returns it and the complete shards.

    Raises
    ------
    OutputExistsError
        ``out`` exists and ``overwrite`` is False.
    PhySynthError
        An unfinished run exists and neither ``resume`` nor ``overwrite`` was asked, or ``resume`` was
        asked for a plan that differs from the unfinished one.
    """
    if out.exists() and not overwrite and not is_vacant(out, "dataset"):
        raise OutputExistsError(out)
    if out.exists() and not out.is_dir():
        raise DatasetError(f"{out} exists and is not a directory")
    partial = partial_dir(out)
    if partial.exists() and not resume:
        if not overwrite:
            raise PhySynthError(f"an unfinished run of {out} exists ({partial}); resume it or overwrite to start over")
        shutil.rmtree(partial)
    if partial.exists():
        try:
            old = json.loads((partial / "run.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            old = None
        diff = _differences(old, plan_record)
        if diff is not None:
            raise PhySynthError(f"cannot resume {out}: the unfinished run differs in {diff}")
        for junk in partial.glob(".shard-*"):  # a shard being written when the run was killed
            shutil.rmtree(junk, ignore_errors=True)
    else:
        try:
            partial.mkdir(parents=True)
        except OSError as exc:
            raise DatasetError(f"cannot create {partial}: {exc.strerror}") from None
        atomic_write_text(partial / "run.json", json.dumps(jsonable(plan_record), indent=1))
    done = {int(m.group(1)) for p in partial.iterdir() if p.is_dir() and (m := _SHARD_RE.match(p.name))}
    return partial, _drop_damaged(out, partial, done, plan_record) if done else done


def _differences(old: Any, record: dict[str, Any]) -> str | None:
    """The keys in which the plan ``old`` (read from a file; None when unreadable) differs from ``record``
    (comma-separated), or None when they agree."""
    new = jsonable(record)
    if old == new:
        return None
    prev = old if isinstance(old, dict) else {}
    return ", ".join(sorted(k for k in set(new) | set(prev) if prev.get(k) != new.get(k))) or "run.json"


def shard_problem(shard: Path, bounds: tuple[int, int], *, hashes: bool = True) -> str | None:
    """Why the shard folder ``shard``, to hold traces ``bounds[0] .. bounds[1] - 1``, cannot be used (one
    line), or None: its ``dataset.json`` is missing or unreadable, lists other traces or no integrity
    record, or a file disagrees with the record (:func:`physynth.io.integrity.check_dataset`: present,
    size, row count, SHA-256 when ``hashes``, trace ids)."""
    try:
        meta = read_meta(shard)
        listed = [t.get("trace") if isinstance(t, dict) else None for t in meta.get("traces") or []]
        if listed != list(range(*bounds)):
            return f"{shard.name} does not list traces {bounds[0]}..{bounds[1] - 1}"
        if not isinstance(meta.get("files"), dict):
            return f"{shard.name} has no integrity record"
        integrity.check_dataset(shard, meta, hashes=hashes)
    except DatasetError as exc:
        return str(exc)
    return None


def _drop_damaged(out: Path, partial: Path, done: set[int], record: dict[str, Any]) -> set[int]:
    """The complete shards ``done`` of a resumed run that match their integrity records; the others are
    removed (to be written again) and reported in one :class:`PhySynthWarning`."""
    plan = ShardPlan(int(record["n_traces"]), int(record["shard_traces"]))
    hashes = not integrity.environ_skip_hashes()
    damaged = {}
    for k in sorted(done):
        problem = (f"{shard_name(k)} lies beyond the run's {plan.n_shards} shard(s)" if k >= plan.n_shards
                   else shard_problem(partial / shard_name(k), plan.bounds(k), hashes=hashes))
        if problem is not None:
            damaged[k] = problem
            remove_tree(partial / shard_name(k))
    if damaged:
        first = next(iter(damaged.values())).splitlines()[0]
        warnings.warn(f"{len(damaged)} of the {len(done)} complete shard(s) of the unfinished run of {out} "
                      f"did not match their integrity records and are written again ({first})",
                      PhySynthWarning, stacklevel=3)
    return done - set(damaged)


def finished_run(out: Path, scenario: dict[str, Any], seed: int | None, n: int, shard_traces: int) -> int | None:
    """What a resumed run does with an output that is already complete: its root seed when ``out`` is the
    complete dataset of the run asked for (``scenario``, root ``seed`` (None: any), ``n`` traces,
    ``shard_traces``, this generator version) and matches its integrity record, so nothing is left to
    do; None when ``out`` is no dataset generated in shards (absent, empty, anything else).

    Raises
    ------
    PhySynthError
        ``out`` is the complete dataset of another run (naming what differs).
    IntegrityError
        ``out`` is the run asked for but damaged (:func:`physynth.io.integrity.check_dataset`).
    """
    try:
        meta = json.loads((Path(out) / "dataset.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(meta, dict) or not isinstance(meta.get("shards"), dict) or meta.get("kind") != "synthetic":
        return None
    gen = meta.get("generator") if isinstance(meta.get("generator"), dict) else {}
    done = {"scenario": meta.get("scenario"), "root_seed": meta.get("root_seed"), "n_traces": meta.get("n_traces"),
            "shard_traces": meta["shards"].get("shard_traces"), "generator": f"{gen.get('name')} {gen.get('version')}"}
    root = done["root_seed"] if seed is None else int(seed)
    diff = _differences(done, plan_record(scenario, root, n, shard_traces)) if isinstance(root, int) else "root_seed"
    if diff is not None:
        raise PhySynthError(f"cannot resume {out}: it is a complete dataset, of a run that differs in {diff}")
    integrity.check_dataset(Path(out), meta, hashes=not integrity.environ_skip_hashes())
    return root


def read_plan(out: Path) -> dict[str, Any] | None:
    """The plan (``run.json``) of an unfinished run of ``out``, or None."""
    try:
        return json.loads((partial_dir(out) / "run.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _link(src: Path, dst: Path) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def finalize(out: Path, partial: Path, plan: ShardPlan, meta: dict[str, Any]) -> Path:
    """Assemble the complete shards into the dataset ``out`` (renamed into place) and remove ``partial``.

    Every shard is checked against its integrity record first (:func:`shard_problem`, without the hashes,
    which a resumed run checked when it kept the shard): the records of the dataset are the shards' own,
    so a shard damaged since it was written raises :class:`DatasetError` instead of being assembled.
    """
    shards = [partial / shard_name(k) for k in range(plan.n_shards)]
    missing = [s.name for s in shards if not s.is_dir()]
    if missing:
        raise DatasetError(f"cannot finish {out}: shard(s) {', '.join(missing[:3])} missing")
    for k, shard in enumerate(shards):
        problem = shard_problem(shard, plan.bounds(k), hashes=False)
        if problem is not None:
            raise DatasetError(f"cannot finish {out}: {problem}; resume the run to write that shard again")
    stage = temp_sibling(out)
    if stage.exists():
        shutil.rmtree(stage)
    stage.mkdir()
    traces_meta: list[dict[str, Any]] = []  # one shard: in dataset.json; several: traces/part-<k>.jsonl
    n_total = 0
    try:
        for k, shard in enumerate(shards):
            for name in TABLES:
                if plan.n_shards == 1:
                    _link(shard / f"{name}.parquet", stage / f"{name}.parquet")
                else:
                    (stage / name).mkdir(exist_ok=True)
                    _link(shard / f"{name}.parquet", stage / name / f"part-{k:05d}.parquet")
            part = json.loads((shard / "dataset.json").read_text(encoding="utf-8"))["traces"]
            n_total += len(part)
            if plan.n_shards == 1:
                traces_meta = part
            else:  # one shard's list at a time: memory does not grow with the number of traces
                (stage / "traces").mkdir(exist_ok=True)
                (stage / "traces" / f"part-{k:05d}.jsonl").write_text(
                    "".join(json.dumps(m) + "\n" for m in part), encoding="utf-8")
        first = json.loads((shards[0] / "dataset.json").read_text(encoding="utf-8"))
        first.pop("traces", None)
        first.pop("shard", None)
        # integrity records (physynth.io.integrity) of the assembled layout: the shards' own
        files = integrity.shard_file_records(shards, TABLES, single=plan.n_shards == 1)
        record = {**first, **jsonable(meta), "n_traces": n_total, "files": files,
                  "shards": {"n_shards": plan.n_shards, "shard_traces": plan.shard_traces,
                             "layout": "single" if plan.n_shards == 1 else "parts"}}
        if plan.n_shards == 1:
            record["traces"] = traces_meta
        else:
            record["traces_meta"] = "traces/part-<shard>.jsonl: one JSON object per trace, in trace order"
        (stage / "dataset.json").write_text(json.dumps(record, indent=1), encoding="utf-8")
        swap_in(stage, out)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    shutil.rmtree(partial, ignore_errors=True)
    return out


def plan_record(scenario: dict[str, Any], root_seed: int, n: int, shard_traces: int) -> dict[str, Any]:
    """What a resumed run must agree on."""
    return {"scenario": scenario, "root_seed": int(root_seed), "n_traces": int(n),
            "shard_traces": int(shard_traces), "generator": f"physynth {__version__}"}
