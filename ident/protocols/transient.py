"""Where the start-up transient of an increment sequence ends, and the steady-state statistics after it.

An impulse experiment starts from rest with zero spring deflection, so its first pulses wind the spring up and
the load's stick-slip settles only after a while (often a period-two alternation that decays). The resolution of
the protocol is the MAX increment, which can therefore be pulse 1 of that transient; a reader also needs the
steady-state max.

How the end is found (from the data only, no constant tuned to a drive): the last quarter of the experiment is
taken as the reference of the steady state, with its range [min, max]. The transient's size is the largest
distance of any increment outside that range. If it is not larger than the range's own width, no transient stands
out from the steady scatter. Otherwise a pulse is settled when its increment lies within the range widened on both
sides by ``SETTLING_BAND`` (2 %) of the transient's size: the 2 % settling criterion of control engineering,
applied to the size of the transient itself. The transient ends after the last pulse outside that band. The steady
state is trusted only when the settled tail covers at least the second half of the experiment (so the reference
quarter lies well inside it); otherwise the sequence has not settled within the experiment and the steady-state
figures are None ("I can't tell").
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

SETTLING_BAND = 0.02   # fraction of the transient's size added on both sides of the reference range
MIN_PULSES = 8         # fewer pulses leave no quarter to serve as a reference


@dataclass(frozen=True)
class Transient:
    """The start-up transient of one increment sequence (lengths in metres at the arm; pulses 1-based).

    ``end_pulse``: the last pulse outside the settling band (0: none, the sequence is settled from pulse 1);
    ``settled``: whether a steady state was reached within the experiment (None: too few pulses to tell);
    ``steady_max_m`` / ``steady_median_m`` / ``steady_min_m``: statistics of the pulses after ``end_pulse`` (None
    when not settled); ``max_pulse``: the pulse of the overall max; ``band_m``: the settling band [low, high]."""

    n_pulses: int
    end_pulse: int
    settled: bool | None
    max_pulse: int
    max_m: float
    steady_max_m: float | None
    steady_median_m: float | None
    steady_min_m: float | None
    band_m: tuple[float, float] | None

    @property
    def max_in_transient(self) -> bool:
        """Is the overall max one of the transient's pulses (so the steady state's max is smaller)?"""
        return bool(self.settled) and self.max_pulse <= self.end_pulse

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["band_m"] = list(self.band_m) if self.band_m is not None else None
        return d


def start_up_transient(increments_m: np.ndarray, band: float = SETTLING_BAND) -> Transient:
    """The transient of ``increments_m`` (see the module docstring for the rule)."""
    x = np.asarray(increments_m, dtype=float)
    n = int(x.size)
    max_pulse = int(np.argmax(x)) + 1 if n else 0
    max_m = float(x.max()) if n else float("nan")
    if n < MIN_PULSES:
        return Transient(n, 0, None, max_pulse, max_m, None, None, None, None)
    ref = x[(3 * n) // 4:]
    lo, hi = float(ref.min()), float(ref.max())
    size = float(np.max(np.maximum(lo - x, x - hi)))
    tol = band * size
    low, high = lo - tol, hi + tol
    outside = np.flatnonzero((x < low) | (x > high))
    end = int(outside[-1]) + 1 if outside.size and size > hi - lo else 0
    if end > n // 2:
        return Transient(n, end, False, max_pulse, max_m, None, None, None, (low, high))
    tail = x[end:]
    return Transient(n, end, True, max_pulse, max_m, float(tail.max()), float(np.median(tail)), float(tail.min()),
                     (low, high))


def alternation(increments_m: np.ndarray, start: int, stop: int) -> tuple[int, int]:
    """(sign changes, comparisons) of the successive differences of increments ``start`` .. ``stop`` (1-based pulse
    numbers, inclusive): a period-two alternation changes sign at every comparison."""
    x = np.asarray(increments_m, dtype=float)[max(start - 1, 0):stop]
    d = np.sign(np.diff(x))
    d = d[d != 0]
    if d.size < 2:
        return 0, 0
    return int(np.sum(d[1:] != d[:-1])), int(d.size - 1)


__all__ = ["SETTLING_BAND", "Transient", "alternation", "start_up_transient"]
