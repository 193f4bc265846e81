"""Practical identifiability of K*, J_l*, f_l* from one log, said plainly (issue 21, item 3).

A parameter is **not identifiable** from a log when

1. the fit leans on the edge of the physical range (``result.at_bound``): no optimum of the model inside it, so the
   number is no result at all;
2. its relative standard deviation (the larger of the Cramer-Rao bound at the estimate and the residual-based
   sandwich) exceeds ``MAX_REL_STD`` = 10 % (the issue's threshold): the log leaves it open;
3. the cost is multi-modal: another optimum that the data do not reject (likelihood ratio below the 99.9 % level,
   ``identify.REJECT_CHI2``) survived the continuation from the first window's multi-start, and the parameter differs
   between the two by more than ``Z95`` of its standard deviation;
4. the model does not explain the log at all: the residual stays above ``UNRELIABLE`` x the noise (then no value is
   trusted, whatever its interval; between the mismatch warning's threshold and this, the values stand with
   residual-based intervals and the warning).

The reason names the cause in the physics of the drive, from the Fisher information's structure: which parameters
move together (correlation above ``SEPARABLE`` = 0.99 in magnitude) and what the log lacks. The fix says what to
record instead (or to run ``hdrive design-experiment``).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from .result import BOUNDS, NAMES, Z95

MAX_REL_STD = 0.10
SEPARABLE = 0.99
# Residual over noise above which the misfit dominates (its power 8x the noise's) and the values are not trusted:
# the level at which the project's model-mismatch warning used to fire.
UNRELIABLE = 3.0

LABEL = {"K_star": "K*", "J_l_star": "J_l*", "f_l_star": "f_l*"}
# What each weak combination means physically, and what to record to pin it.
CAUSE = {
    ("K_star", "J_l_star"): "the load's ringing fixes K*/J_l* (its frequency) but not the scale, which only shows "
                            "while the motor slides with the load ringing on it",
    ("J_l_star", "f_l_star"): "the ringing's decay fixes f_l*/J_l* but not the scale, which only shows while the "
                              "motor slides with the load ringing on it",
    ("K_star", "f_l_star"): "the load's motion does not separate the spring from the load friction: it hardly rings "
                            "freely",
}
FIX_SCALE = ("record bidirectional 1 ms pulses of 2-5 f_m, each followed by 0.3 s of rest, and slow torque ramps "
             "to about 1.15 f_m held 40 ms (the motor slides while the load rings on it)")
FIX_RINGING = "let the load ring freely after each pulse: rests of at least 0.3 s (or 10 ringing periods)"
FIX_DESIGN = "or run `hdrive design-experiment --meta <sidecar>` for a schedule that pins all three"


def _pair(a: str, b: str) -> tuple[str, str]:
    return (a, b) if NAMES.index(a) < NAMES.index(b) else (b, a)


def _correlation_reason(name: str, corr: np.ndarray) -> tuple[str, tuple[str, str] | None]:
    """The strongest correlation of ``name`` with another parameter, as a sentence when above ``SEPARABLE``."""
    i = NAMES.index(name)
    others = [j for j in range(3) if j != i]
    j = max(others, key=lambda k: abs(corr[i, k]))
    if abs(corr[i, j]) < SEPARABLE:
        return "", None
    pair = _pair(name, NAMES[j])
    return (f"{LABEL[pair[0]]} and {LABEL[pair[1]]} are not separable from this log: correlation "
            f"{corr[i, j]:.4f}; {CAUSE[pair]}"), pair


def assess(theta: np.ndarray, std_ln: np.ndarray, cov: np.ndarray, bound: list[str],
           alternatives: list[np.ndarray], free_segments: int, over_noise: float = 1.0
           ) -> tuple[dict[str, tuple[bool, str]], str]:
    """Verdict and reason per parameter, and the recording fix (empty when all three are identifiable).

    ``theta``: the estimate (ln K*, ln J_l*, ln f_l*, ...); ``std_ln``: the reported standard deviations of the
    three log-parameters; ``cov``: their Cramer-Rao covariance (for the correlations); ``bound``: the names at a
    bound; ``alternatives``: the thetas of competing optima; ``free_segments``: free-ringing segments in the log;
    ``over_noise``: the whole-log residual over the noise (above ``UNRELIABLE`` no value is trusted)."""
    with np.errstate(all="ignore"):
        s = np.sqrt(np.maximum(np.diag(cov[:3, :3]), 1e-300))
        corr = cov[:3, :3] / np.outer(s, s)
    corr = np.where(np.isfinite(corr) & (np.abs(corr) <= 1.0 + 1e-9), corr, 0.0)  # a degenerate bound: no pair
    verdicts: dict[str, tuple[bool, str]] = {}
    pairs: set[tuple[str, str]] = set()
    for i, name in enumerate(NAMES):
        reasons = []
        if name in bound:
            reasons.append(f"{LABEL[name]} = {math.exp(theta[i]):.4g} sits at the edge of the physical range "
                           f"{BOUNDS[name]}: the fit found no optimum inside it")
        rel = float(math.expm1(min(std_ln[i], 700.0))) if math.isfinite(std_ln[i]) else math.inf
        if rel > MAX_REL_STD or name in bound:
            text, pair = _correlation_reason(name, corr)
            spread = f"+-{100 * rel:.3g} %" if rel <= 10 else "no better than a factor of 10"
            reasons.append(f"{LABEL[name]} is determined only to {spread} (1 sigma) by this log"
                           + (f": {text}" if text else ""))
            if pair:
                pairs.add(pair)
        reasons += _multimodal(i, theta, std_ln, alternatives)
        if over_noise > UNRELIABLE:
            reasons.append(f"the fitted model leaves residuals {over_noise:.3g}x the load sensor noise: it does not "
                           "explain this log, so no value from it can be trusted (an effect the model lacks -- see "
                           "`hdrive diagnose` -- or a fit trapped in a local optimum)")
        if free_segments == 0 and reasons:
            reasons.append("the load never rings freely (the motor never rests while it rings)")
        verdicts[name] = (not reasons, "; ".join(reasons))
    return verdicts, _fix(verdicts, pairs, free_segments)


def _multimodal(i: int, theta: np.ndarray, std_ln: np.ndarray, alternatives: list[np.ndarray]) -> list[str]:
    """Why the parameter ``i`` is not identifiable for its competing optima: one lies outside its 95 % interval
    and more than ``MAX_REL_STD`` from it (the verdict's own threshold). A nearer one leaves it identifiable and
    widens its interval instead (``identify.build_result``): measured on a 2 s chirp whose K* the log pins to
    3.6e-6, a second optimum 1e-5 away (both at the noise, the same to four digits) made K* and J_l* "not
    identifiable"."""
    out = []
    for alt in alternatives:
        d = abs(alt[i] - theta[i])
        if d > Z95 * std_ln[i] and math.expm1(d) > MAX_REL_STD:
            values = ", ".join(f"{LABEL[n]} = {math.exp(alt[k]):.4g}" for k, n in enumerate(NAMES))
            out.append(f"the log is explained as well (within the noise) by another optimum ({values}): the cost "
                       "has several minima")
    return out[:1]


def _fix(verdicts: dict[str, tuple[bool, str]], pairs: set[tuple[str, str]], free_segments: int) -> str:
    if all(ok for ok, _ in verdicts.values()):
        return ""
    parts = []
    if free_segments == 0 or ("K_star", "f_l_star") in pairs:
        parts.append(FIX_RINGING)
    if not pairs or pairs & {("K_star", "J_l_star"), ("J_l_star", "f_l_star")}:
        parts.append(FIX_SCALE)
    return "; ".join(parts + [FIX_DESIGN])


def summary(verdicts: dict[str, tuple[bool, str]]) -> dict[str, Any]:
    """The verdicts as a JSON-ready mapping."""
    return {name: {"identifiable": ok, "reason": reason} for name, (ok, reason) in verdicts.items()}
