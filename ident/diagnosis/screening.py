"""Screening of candidate effects before any refit: the score (Lagrange-multiplier) test of each candidate's
parameters at zero, at the current model.

For residuals ``r`` of the current model (noise-normalised, its unknowns at their optimum) and the Jacobian columns
``J`` of its unknowns, a candidate effect adds unknowns ``beta`` whose value 0 is the current model; their Jacobian
columns ``B`` at beta = 0 (through the same simulation, by a one-sided difference) give the score of the effect
after the current unknowns are partialled out::

    Z = B - J (J'J)^-1 J'B,      s = Z' r,      step = (Z'Z)^-1 s

* ``statistic`` = s' (Z'Z)^-1 s / sigma^2 with sigma^2 = |r_perp|^2 / (n - p): the LM statistic (n R^2 form),
  chi-square with ``df`` degrees of freedom under the null hypothesis "the effect is absent and the current model is
  right" with white sensor noise (what the sensor model of every fit here assumes). It is also the cost a
  Gauss-Newton step in the candidate's direction would remove, in noise units. The candidates are ranked by it and
  the decision uses it.
* ``robust`` = s' V^-1 s with V = sum over blocks of (Z_b' e_b)(Z_b' e_b)', e = r_perp - Z step: the same test with a
  variance that allows correlated residuals inside a block, reported beside it (``p_robust``). It is not the
  decision: an effect whose signature lives in a few blocks of a log (the slides of a torque-step log) cannot reach
  a robust statistic above the number of those blocks (measured: a viscous motor friction that leaves the base model
  1.22x the noise scored LM 2610 but robust 7.5, p = 0.003). Correlated sensor noise would make the LM statistic
  pass candidates that do not help; the acceptance rule after the refit (a Diebold-Mariano test with a Newey-West
  variance) then rejects them: the screen's errors cost time, not answers.
* A parameter that is bounded at zero (a viscous coefficient, a Stribeck ratio, a hardening, a hysteresis torque)
  can only move one way: when the step points the admissible way the p-value is half the chi-square tail (the
  chi-bar-square mixture of a boundary null). When it points out of the admissible side at every grid point, the
  sign is not trusted and the whole tail is the p-value: the current model may stand in for the effect with its
  other parameters, and then the first-order step points the wrong way. Measured on an independent torque-step log
  with a hidden motor-side viscous friction: the base model left 3.6x the noise, the viscous step pointed to a
  negative coefficient and the candidate was ruled out (statistic 0, p = 1); refitted anyway, it reached the truth
  to 0.03 % and 1.01x the noise, and kinematic error had been named instead, tentatively.
* An effect with a nonlinear parameter that the data cannot see at zero magnitude (a Stribeck velocity, a hysteresis
  saturation deflection) is tested on a small grid of it; the grid's best point is the candidate's result and its
  p-value is multiplied by the grid size (Bonferroni), so that searching the grid does not make the test liberal.
* ``detectable``: the smallest size of the effect the loop could name at this model (``detection_limit``). Two
  conditions bind: the screen must pass it (under the alternative the statistic is noncentral chi-square with
  noncentrality x'Z'Zx / sigma^2 at the true coordinates x, asked to reach ``DETECTION_POWER``), and, fitted, it
  must remove the practical share of the cost the acceptance rule asks (x'Z'Zx, the cost a fit of it removes, at
  least 1 - 1/MIN_GAIN of |r|^2). Near the noise the second binds: with 35,000 samples the screen alone would see
  an effect of 0.03 noise sigmas RMS, the rule asks 0.1. The limit is the size along the direction the log sees
  least (an unknown phase is the worst one), at the grid point where the log sees the effect best. An effect not
  named is then either smaller than that, and this log cannot tell, or absent. The limit is first-order, a lower
  bound: a refit of the current model can absorb more of an effect than the linear partialling says (its other
  unknowns move far along a stick/slip cost surface), and where a tiny change flips a stick/slip decision the
  columns are secants, not derivatives. Measured on the independent generator's logs (``bench/detection.py``, 3
  drives x 6 effects): at 0.3x the limit the effect was named on 1 of 18 logs (a kinematic error, tentatively); at
  3x on 10 of 18: asymmetric friction and hysteresis 3/3, kinematic error 2/3, Stribeck 1/3, viscous friction 1/6
  (a viscous load at 3x its limit left the screen a statistic of 21 where the first order says 3000: the base refit
  had absorbed it).

Nothing here knows a model: the plug-ins build ``r``, ``J`` and ``B`` (``ident.diagnosis.models``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from scipy import optimize, stats

#: a candidate passes the screen when its (grid-corrected) p-value is below this level
SCREEN_LEVEL = 1e-3
#: blocks of the robust variance: enough for a stable estimate of a 1-2 parameter score variance
ROBUST_BLOCKS = 50
#: the power at which a detection limit is quoted (the power the acceptance rule's ``SEPARABLE`` is quoted at)
DETECTION_POWER = 0.95


@dataclass
class ScoreTest:
    """The screen's verdict on one candidate (at its best grid point)."""

    candidate: str
    statistic: float                 # LM statistic (iid, residual variance): ranking, cost removed by one step
    robust: float                    # block-robust LM statistic: the decision
    df: int
    p_value: float                   # of the statistic; one-sided where the parameter is bounded; x grid size
    grid_size: int = 1
    grid_point: dict[str, float] = field(default_factory=dict)   # the nonlinear parameters at the best point
    step: np.ndarray | None = None   # Gauss-Newton step of [current unknowns, candidate unknowns] at that point
    screened: bool = True            # False: the candidate cannot be tested at zero and is always refitted
    note: str = ""
    p_robust: float = math.nan       # of the robust statistic, the same corrections (information only)
    start: dict[str, float] = field(default_factory=dict)   # the candidate's unknowns to start its refit from
    sensitivity: dict[str, float] = field(default_factory=dict)   # each unknown's size that moves the fit by 1 sigma
    detectable: float = math.nan     # the effect's smallest size the loop could name here (``unit``)
    unit: str = ""
    detectable_at: str = ""          # where the log sees it best (the grid point), in words
    detectable_worst: float = math.nan   # the same at the grid point where the log sees it least
    detectable_worst_at: str = ""
    record: str = ""                 # what a log would have to show for a smaller one to be seen
    carried: dict[str, float] = field(default_factory=dict)   # its unknowns where its last refit left them (the loop)

    @property
    def passed(self) -> bool:
        return (not self.screened) or self.p_value < SCREEN_LEVEL

    def tested_by(self, fall: float) -> bool:
        """Whether a refit that lowered a cost (in noise variances) by ``fall`` tested this candidate: it must
        remove at least the candidate's degrees of freedom, what as many parameters with no effect at all remove on
        average (the chi-square mean). A smaller fall, where the screen predicted ``statistic``, puts the score test
        and the refit's likelihood-ratio test in plain conflict: the refit stalled where stick and slip reorder, or
        the first-order step does not hold there; it did not rule the effect out. The loop applies it to the
        training cost (``engine``), the two-inertia refit to its own problem's cost (``two_inertia``), both above
        the model's noise level only."""
        return fall >= self.df

    def row(self) -> dict[str, Any]:
        return {"candidate": self.candidate, "lm_statistic": self.statistic, "lm_robust": self.robust,
                "df": self.df, "p_value": self.p_value, "p_robust": self.p_robust, "grid_size": self.grid_size,
                "grid_point": ", ".join(f"{k} = {v:.4g}" for k, v in self.grid_point.items()),
                "passed": self.passed, "detectable": self.detectable, "unit": self.unit,
                "detectable_at": self.detectable_at, "detectable_worst": self.detectable_worst,
                "detectable_worst_at": self.detectable_worst_at, "record": self.record, "note": self.note}


def partial_out(J: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the current unknowns' columns (rank-revealing: a direction the data do not see is
    dropped rather than inverted)."""
    if J.size == 0:
        return np.zeros((J.shape[0], 0))
    U, sv, _ = np.linalg.svd(J, full_matrices=False)
    keep = sv > sv[0] * 1e-10 if sv.size else np.zeros(0, dtype=bool)
    return U[:, keep]


def _partialled(r: np.ndarray, Q: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The residuals and the candidate's columns with the current unknowns partialled out, and the residual
    variance sigma^2 = |r_perp|^2 / (n - p)."""
    rr = r - Q @ (Q.T @ r)
    Z = B - Q @ (Q.T @ B)
    n, p = r.size, Q.shape[1] + B.shape[1]
    return rr, Z, max(float(rr @ rr) / max(n - p, 1), 1e-300)


def score_test(r: np.ndarray, Q: np.ndarray, B: np.ndarray, bounded: tuple[bool, ...],
               blocks: int = ROBUST_BLOCKS) -> tuple[float, float, np.ndarray, bool]:
    """(statistic, robust statistic, step of the candidate's unknowns, admissible) for residuals ``r``, the
    orthonormal basis ``Q`` of the current unknowns' columns (``partial_out``) and the candidate's columns ``B``.
    ``bounded[j]``: unknown j may only grow from 0. The step is the Gauss-Newton step that lowers |r|^2."""
    rr, Z, sigma2 = _partialled(r, Q, B)
    A = Z.T @ Z
    if not np.all(np.isfinite(A)) or np.linalg.matrix_rank(A) < A.shape[0]:
        return 0.0, 0.0, np.zeros(B.shape[1]), False
    s = Z.T @ rr
    step = -np.linalg.solve(A, s)         # r is model - data: the step that lowers the cost is -A^-1 s
    n = r.size
    lm = float(s @ np.linalg.solve(A, s)) / sigma2
    size = max(1, n // blocks)
    e = rr + Z @ step
    parts = np.array([Z[i:i + size].T @ e[i:i + size] for i in range(0, n, size)])
    V = parts.T @ parts
    try:
        robust = float(s @ np.linalg.solve(V, s))
    except np.linalg.LinAlgError:
        robust = 0.0
    admissible = all(not b or x > 0 for b, x in zip(bounded, step))
    return lm, robust, step, admissible


def detection_limit(r: np.ndarray, Q: np.ndarray, B: np.ndarray, grid_size: int, one_sided: bool,
                    min_gain: float, df: int | None = None) -> np.ndarray:
    """The candidate's coordinates (``B``'s columns) along the direction the log sees least, at the smallest size
    the loop could name (see the module docstring): the screen passes it with ``DETECTION_POWER``, and fitted it
    would remove the share 1 - 1/``min_gain`` of the current cost |r|^2 that the acceptance rule asks (the training
    part standing in for the held-back one). Infinite where the log does not see a direction at all (a column the
    current unknowns already span). ``df``: the screen's degrees of freedom when ``B`` holds only the coordinates
    of the effect's size (its other ones partialled out in ``Q``); default ``B``'s columns."""
    _, Z, sigma2 = _partialled(r, Q, B)
    info, vecs = np.linalg.eigh(Z.T @ Z)
    if not np.all(np.isfinite(info)) or not info[0] > 0:
        return np.full(B.shape[1], math.inf)
    df = df or B.shape[1]
    crit = float(stats.chi2.isf(SCREEN_LEVEL / grid_size * (2.0 if one_sided else 1.0), df))
    lam = optimize.brentq(lambda x: float(stats.ncx2.sf(crit, df, x)) - DETECTION_POWER, 1e-6, 1e4 * (crit + df))
    removed = max(lam * sigma2, float(r @ r) * (1.0 - 1.0 / min_gain))   # x'Z'Zx at the limit
    u = vecs[:, 0] * (1.0 if vecs[:, 0].sum() >= 0 else -1.0)   # a bounded size grows from 0 in every column
    return u * math.sqrt(removed / info[0])


def quote_limits(test: ScoreTest, limits: list[float], where: list[str], unit: str) -> None:
    """Give ``test`` its detection limits from one per grid point (``where``: each point in words, '' without a
    grid): the smallest, where the log sees the effect best, and the largest, where it sees it least."""
    best, worst = int(np.argmin(limits)), int(np.argmax(limits))
    test.unit = unit
    test.detectable, test.detectable_at = limits[best], where[best]
    test.detectable_worst, test.detectable_worst_at = limits[worst], where[worst]


def p_value(statistic: float, df: int, admissible: bool, one_sided: bool) -> float:
    """Chi-square tail of a statistic; a boundary null (one bounded unknown) halves it, an inadmissible step
    gives 1."""
    if not admissible:
        return 1.0
    p = float(stats.chi2.sf(statistic, df))
    return 0.5 * p if one_sided else p


def best_of_grid(name: str, points: list[tuple[dict[str, float], float, float, np.ndarray, bool]], df: int,
                 one_sided: bool) -> ScoreTest:
    """The candidate's result over its grid: the admissible point with the largest statistic; its p-value times
    the grid size (Bonferroni). ``points``: (grid point, statistic, robust, step, admissible)."""
    scored = [(pt, lm, rb, st, ok) for pt, lm, rb, st, ok in points]
    usable = [x for x in scored if x[4]] or scored
    pt, lm, rb, step, ok = max(usable, key=lambda x: x[1])
    g = len(points)
    if not ok:   # every point's step points the wrong way: the sign is not trusted, the size of the score is
        p, p_rb = (min(1.0, g * float(stats.chi2.sf(x, df))) for x in (lm, rb))
        note = ("the first-order step points to a value the effect cannot take (e.g. negative friction)" +
                (", but its score is significant: refitted (a model that stands in for the effect with its other "
                 "parameters can point the step the wrong way)" if p < SCREEN_LEVEL else ": not supported"))
        return ScoreTest(name, lm, rb, df, p, g, dict(pt), step, True, note, p_rb)
    p = min(1.0, g * p_value(lm, df, ok, one_sided))
    return ScoreTest(name, lm, rb, df, p, g, dict(pt), step, True, "",
                     min(1.0, g * p_value(rb, df, ok, one_sided)))


def screen_table(tests: list[ScoreTest]) -> pd.DataFrame:
    """The screen's results, ranked by the statistic (the order the candidates are refitted in)."""
    rows = [t.row() for t in ranked(tests)]
    return pd.DataFrame(rows)


def ranked(tests: list[ScoreTest]) -> list[ScoreTest]:
    """Candidates that cannot be screened first (they are always refitted), then by decreasing statistic."""
    return sorted(tests, key=lambda t: (t.screened, -t.statistic if math.isfinite(t.statistic) else 0.0))
