"""The paper's claims, and whether the model reproduces each one, decided from the study's numbers.

Every verdict here is computed from the figures it compares, with a criterion stated beside it, so the report's
sentences cannot contradict its tables on another drive:

- a figure matches the paper when it rounds to the paper's figure at the paper's own precision (3 µm: to 1 µm;
  0.30 µm: to 0.01 µm); counts must be equal;
- "more than an order of magnitude" (the paper's conclusion): linear / impulse resolution > 10;
- "grows linearly with f_l*" and "avalanche": the criteria of the paper-effects study
  (``ident.studies.paper_effects``: ``LINEAR_R2``, ``LINEAR_GROWTH``, ``AVALANCHE_RATIO``), one definition for both
  reports.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .paper_effects import AVALANCHE_RATIO, LINEAR_GROWTH, LINEAR_R2

if TYPE_CHECKING:
    from ..protocols.sweep import FrictionSweep

# What the paper reports (sections III-V and VI), for the side-by-side table.
PAPER = {
    "linear_resolution_um": 3.0,
    "linear_counts": 2,
    "impulse_resolution_um": 0.30,
    "ratio": 10.0,
}
PAPER_TITLE = "Study of Resolution for Harmonic Drives Controller with Friction in Precision Robotic System"
PAPER_AUTHORS = None   # the project's copy of the paper (text only) does not name them: not guessed


@dataclass(frozen=True)
class Claim:
    """One claim of the paper against the model. ``holds`` is None when the study cannot tell (e.g. one level)."""

    key: str
    claim: str
    paper: str
    model: str
    holds: bool | None
    criterion: str

    @property
    def verdict(self) -> str:
        return {True: "agrees", False: "differs", None: "can't tell"}[self.holds]


def rounds_to(value: float, paper: float, precision: float) -> bool:
    """Does ``value`` round to ``paper`` at the paper's ``precision`` (half a unit of its last digit either way)?"""
    return abs(value - paper) < precision / 2


def first_motion(x: np.ndarray) -> tuple[float, int]:
    """The first nonzero increment and its pulse (1-based); (0, N + 1) when the arm never moves."""
    moving = np.flatnonzero(np.asarray(x) != 0)
    return (float(x[moving[0]]), int(moving[0]) + 1) if moving.size else (0.0, int(np.size(x)) + 1)


def growth(sweep: "FrictionSweep") -> dict[str, Any]:
    """The linear-growth criterion on the sweep's max increments: slope, R^2, max(highest) / max(lowest level)."""
    df = sweep.to_frame().sort_values("f_l_star")
    t = sweep.trend()
    lo, hi = df["resolution_um"].iloc[0], df["resolution_um"].iloc[-1]
    g = float(hi / lo) if lo > 0 else math.inf
    holds = None if len(df) < 3 or not math.isfinite(t["r2"]) else \
        bool(t["slope_um"] > 0 and t["r2"] >= LINEAR_R2 and g >= LINEAR_GROWTH)
    return dict(slope_um=t["slope_um"], intercept_um=t["intercept_um"], r2=t["r2"], growth=g, holds=holds,
                f_lo=float(df["f_l_star"].iloc[0]), f_hi=float(df["f_l_star"].iloc[-1]))


def avalanche(sweep: "FrictionSweep") -> dict[str, Any]:
    """The highest-friction experiment: leading pulses without arm motion, the first motion and the max against the
    median, and the avalanche criterion (first motion > ``AVALANCHE_RATIO`` x median)."""
    r = sweep.results[int(np.argmax(sweep.f_l_star))]
    x = r.increments_m
    med = float(np.median(x))
    first, first_pulse = first_motion(x)
    ratio = first / med if med > 0 else math.inf
    return {"f_l_star": float(r.params.f_l_star), "leading_zero_pulses": first_pulse - 1, "first_motion_um": first * 1e6,
            "first_motion_pulse": first_pulse, "first_over_median": ratio, "max_pulse": int(np.argmax(x)) + 1,
            "max_over_median": float(x.max() / med) if med > 0 else math.inf, "holds": bool(ratio > AVALANCHE_RATIO)}


def claims(linear_m: float, counts: int, impulse_m: float, sweep: "FrictionSweep") -> list[Claim]:
    """The paper's five claims against the model's figures (linear and impulse resolution [m], the sweep)."""
    lin_um, imp_um = linear_m * 1e6, impulse_m * 1e6
    ratio = linear_m / impulse_m if impulse_m > 0 else math.inf
    g, av = growth(sweep), avalanche(sweep)
    return [
        Claim("linear_resolution", "linear resolution (PD on the motor encoder)", "3 µm (two counts)",
              f"{lin_um:.2f} µm ({counts} counts)",
              counts == PAPER["linear_counts"] and rounds_to(lin_um, PAPER["linear_resolution_um"], 1.0),
              "same number of counts, and the max rounds to 3 µm (the paper's precision: 1 µm)"),
        Claim("impulse_resolution", "impulse resolution", "0.30 µm", f"{imp_um:.3f} µm",
              rounds_to(imp_um, PAPER["impulse_resolution_um"], 0.01),
              "the max rounds to 0.30 µm (the paper's precision: 0.01 µm)"),
        Claim("ratio", "linear / impulse resolution", "more than an order of magnitude (3 / 0.30 = 10)",
              f"{ratio:.1f}x", bool(ratio > PAPER["ratio"]), "ratio > 10"),
        Claim("linear_growth", "resolution vs load friction f_l*", "grows linearly",
              f"slope {g['slope_um']:.3g} µm per unit f_l*, R² {g['r2']:.2f}, max x{g['growth']:.2f} from f_l* = "
              f"{g['f_lo']:.3g} to {g['f_hi']:.3g}", g["holds"],
              f"slope > 0, R² >= {LINEAR_R2:g} and max at the highest level >= {LINEAR_GROWTH:g} x the lowest's "
              "(as in the paper-effects study)"),
        Claim("avalanche", "first motion at high friction", "large ('avalanche'), then smooth",
              f"at f_l* = {av['f_l_star']:.3g}: first motion {av['first_motion_um']:.3g} µm (pulse "
              f"{av['first_motion_pulse']}) = {av['first_over_median']:.2f} x median", av["holds"],
              f"first motion > {AVALANCHE_RATIO:g} x the median at the highest level (as in the paper-effects study)"),
    ]


__all__ = ["PAPER", "PAPER_AUTHORS", "PAPER_TITLE", "Claim", "avalanche", "claims", "first_motion", "growth",
           "rounds_to"]
