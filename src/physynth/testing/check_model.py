"""A conformance check every PhySynth model must pass.

A model is a pure function of (inputs, its own parameters, a numpy Generator). :func:`check_model`
runs one on fixed inputs and checks what the rest of PhySynth relies on:

- **shapes**: every declared output field has the declared shape (``None`` matches any length);
- **units**: every declared output field lies inside its declared physical range (in the unit the
  field's name carries, e.g. ``_m``, ``_mps2``), NaN only where the model documents it;
- **finite outputs**: no NaN or infinity elsewhere;
- **determinism per seed**: the same seed gives identical outputs, a different seed different ones
  (for a model that draws anything);
- **inputs left unchanged**: every array reachable from the inputs is byte-identical afterwards;
- **batch independence** (for the generator as a whole, :func:`check_generator`): trace ``i`` is the
  same whether generated alone, in a batch, or in another order.

Use it in a test of a new model::

    case = ModelCase(name="my-model", run=lambda rng: my_model(inputs, params, rng=rng),
                     inputs=[inputs], shapes={"t_s": (None,)}, bounds={"t_s": (0.0, 1e6)})
    check_model(case)  # raises AssertionError listing every failed property
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class ModelCase:
    """One model on fixed inputs.

    Attributes
    ----------
    name : str
        Shown in failure messages.
    run : callable
        ``run(rng) -> output``; calls the model with the given Generator. The output is an array, a
        dataclass, a tuple of those, or a mapping of name -> array.
    inputs : sequence
        Every object handed to the model (arrays, dataclasses of arrays, parameter objects): they must
        be unchanged after ``run``.
    shapes : mapping
        Output field -> expected shape; ``None`` entries match any size. Fields are dataclass
        attributes, mapping keys or ``"0"``, ``"1"``... for tuple items.
    bounds : mapping
        Output field -> (low, high) physical range in the field's unit; checked on finite values.
    nan_ok : sequence of str
        Fields that may hold NaN by design (e.g. a range that was dropped).
    random : bool
        Whether the model draws random numbers (then two seeds must give different outputs).
    """

    name: str
    run: Callable[[np.random.Generator], Any]
    inputs: Sequence[Any] = ()
    shapes: Mapping[str, tuple[int | None, ...]] = field(default_factory=dict)
    bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    nan_ok: Sequence[str] = ()
    random: bool = True


def _fields(out: Any) -> dict[str, np.ndarray]:
    """Numeric array fields of an output, by name."""
    if isinstance(out, np.ndarray):
        return {"output": out}
    if isinstance(out, Mapping):
        items = out.items()
    elif dataclasses.is_dataclass(out):
        items = ((f.name, getattr(out, f.name)) for f in dataclasses.fields(out))
    elif isinstance(out, tuple):
        items = ((str(i), v) for i, v in enumerate(out))
    else:
        raise TypeError(f"cannot inspect a model output of type {type(out).__name__}")
    result = {}
    for name, value in items:
        arr = np.asarray(value) if isinstance(value, (np.ndarray, float, int, np.number)) else None
        if arr is not None and arr.dtype.kind in "biuf":
            result[name] = arr
    return result


def _arrays(obj: Any, prefix: str = "input", depth: int = 0) -> dict[str, np.ndarray]:
    """Every numpy array reachable from an input object (dataclass fields, mappings, sequences)."""
    if depth > 4:
        return {}
    if isinstance(obj, np.ndarray):
        return {prefix: obj}
    out: dict[str, np.ndarray] = {}
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        for f in dataclasses.fields(obj):
            out.update(_arrays(getattr(obj, f.name), f"{prefix}.{f.name}", depth + 1))
    elif isinstance(obj, Mapping):
        for k, v in obj.items():
            out.update(_arrays(v, f"{prefix}[{k!r}]", depth + 1))
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            out.update(_arrays(v, f"{prefix}[{i}]", depth + 1))
    return out


def _same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k], equal_nan=True) for k in a)


def check_model(case: ModelCase, seeds: tuple[int, int] = (11, 12)) -> None:
    """Run every conformance check on ``case``; raise AssertionError listing each failure."""
    problems: list[str] = []
    before = {k: v.copy() for i, x in enumerate(case.inputs) for k, v in _arrays(x, f"input[{i}]").items()}
    params_before = [copy.deepcopy(x) for x in case.inputs if not _arrays(x)]
    first = _fields(case.run(np.random.default_rng(seeds[0])))
    after = {k: v for i, x in enumerate(case.inputs) for k, v in _arrays(x, f"input[{i}]").items()}
    for name, arr in before.items():
        if not np.array_equal(arr, after[name], equal_nan=True):
            problems.append(f"changed its input {name}")
    if [x for x in case.inputs if not _arrays(x)] != params_before:
        problems.append("changed a parameter object it was given")

    for name, shape in case.shapes.items():
        if name not in first:
            problems.append(f"output has no field {name!r} (fields: {sorted(first)})")
            continue
        got = first[name].shape
        if len(got) != len(shape) or any(s is not None and s != g for s, g in zip(shape, got, strict=False)):
            problems.append(f"{name} has shape {got}, expected {shape}")
    for name, arr in first.items():
        if arr.dtype.kind == "f":
            bad = ~np.isfinite(arr) if name not in case.nan_ok else np.isinf(arr)
            if bad.any():
                problems.append(f"{name} has {int(bad.sum())} non-finite value(s)")
    for name, (lo, hi) in case.bounds.items():
        if name in first:
            vals = first[name][np.isfinite(first[name])] if first[name].dtype.kind == "f" else first[name]
            if vals.size and (vals.min() < lo or vals.max() > hi):
                problems.append(f"{name} spans [{vals.min():.4g}, {vals.max():.4g}], outside its physical "
                                f"range [{lo:.4g}, {hi:.4g}]")

    again = _fields(case.run(np.random.default_rng(seeds[0])))
    if not _same(first, again):
        problems.append(f"seed {seeds[0]} gave different outputs on two runs")
    other = _fields(case.run(np.random.default_rng(seeds[1])))
    if case.random and _same(first, other):
        problems.append(f"seeds {seeds[0]} and {seeds[1]} gave identical outputs (the rng is not used)")
    if not case.random and not _same(first, other):
        problems.append("declared deterministic but the output depends on the seed")
    if problems:
        raise AssertionError(f"model {case.name}: " + "; ".join(problems))


def check_generator(make_trace: Callable[[int], Any], make_batch: Callable[[int, int], Sequence[Any]],
                    indices: Sequence[int] = (0, 3, 1)) -> None:
    """Batch independence: trace ``i`` from ``make_trace(i)`` equals the same trace inside a batch
    ``make_batch(start, n)`` and does not depend on the order of generation."""
    problems = []
    alone = {i: make_trace(i) for i in indices}
    reversed_order = {i: make_trace(i) for i in reversed(indices)}
    top = max(indices) + 1
    batch = list(make_batch(0, top))
    for i in indices:
        a = _trace_arrays(alone[i])
        if not _same(a, _trace_arrays(batch[i])):
            problems.append(f"trace {i} differs between alone and in a batch of {top}")
        if not _same(a, _trace_arrays(reversed_order[i])):
            problems.append(f"trace {i} depends on the order of generation")
    if problems:
        raise AssertionError("; ".join(problems))


def _trace_arrays(trace: Any) -> dict[str, np.ndarray]:
    return _arrays(trace, "trace")
