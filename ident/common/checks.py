"""Argument checks shared by the protocols and controllers: a clear ValueError that names the argument."""
from __future__ import annotations

import math
import operator
from typing import Any


def number(name: str, value: Any, *, positive: bool = False, nonnegative: bool = False) -> float:
    """A finite float (optionally > 0 or >= 0), else ValueError naming ``name``."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r} is not a number") from None
    if not math.isfinite(x):
        raise ValueError(f"{name} = {value!r} must be finite")
    if positive and x <= 0:
        raise ValueError(f"{name} = {value!r} must be > 0")
    if nonnegative and x < 0:
        raise ValueError(f"{name} = {value!r} must be >= 0")
    return x


def whole(name: str, value: Any, minimum: int) -> int:
    """A whole number >= ``minimum`` (bools and floats refused), else ValueError naming ``name``."""
    if isinstance(value, bool):
        raise ValueError(f"{name} = {value!r} must be a whole number >= {minimum}")
    try:
        n = operator.index(value)
    except TypeError:
        raise ValueError(f"{name} = {value!r} must be a whole number >= {minimum}") from None
    if n < minimum:
        raise ValueError(f"{name} = {n} must be >= {minimum}")
    return n
