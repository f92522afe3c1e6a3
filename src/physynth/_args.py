"""Checks of the arguments of the public functions, each failing with one :class:`~physynth.errors.ArgumentError`
line that names the parameter (``n``, ``seed``, ``rate_hz``, ...), never a command-line option.

Integers are Python or NumPy integers (``operator.index``), never a bool or a float, however whole: a
float seed or trace index would otherwise be truncated silently to another one.
"""

from __future__ import annotations

import math
import operator
from typing import Any

from .errors import ArgumentError


def check_int(value: Any, name: str, *, minimum: int = 0, what: str = "") -> int:
    """``value`` as an int of at least ``minimum``; ``what`` says in the message what it counts.

    >>> check_int(3, "n", what="the number of traces")
    3
    """
    about = f" ({what})" if what else ""
    if isinstance(value, bool) or not hasattr(type(value), "__index__"):
        raise ArgumentError(f"{name} must be an integer{about}, got {value!r} ({type(value).__name__})")
    number = operator.index(value)
    if number < minimum:
        raise ArgumentError(f"{name} must be >= {minimum}{about}, got {number}")
    return number


def check_seed(seed: Any, name: str = "seed") -> int | None:
    """A root seed: None (drawn later from OS entropy) or a non-negative integer."""
    return None if seed is None else check_int(seed, name, what="the root seed")


def check_number(value: Any, name: str, *, positive: bool = False, unit: str = "") -> float:
    """``value`` as a finite float (and > 0 when ``positive``); ``unit`` is shown after it."""
    shown = f"{value!r}{f' {unit}' if unit else ''}"
    if isinstance(value, bool) or not isinstance(value, (int, float)) and not hasattr(type(value), "__float__"):
        raise ArgumentError(f"{name} must be a number, got {shown} ({type(value).__name__})")
    number = float(value)
    if not math.isfinite(number):
        raise ArgumentError(f"{name} must be a finite number, got {shown}")
    if positive and not number > 0:
        raise ArgumentError(f"{name} must be positive, got {shown}")
    return number
