"""The discrepancy workflow on a rigid, motor-only log (``hdrive diagnose`` for logs without a load sensor, and the
EMPS benchmark): fit a Coulomb-only rigid model, localise its residuals, name the missing friction effect, add it,
refit, repeat until no candidate improves the held-back fit significantly.

**Models.** Every model is the effect library's rigid force (:func:`ident.model.effects.rigid_force`, built with CasADi SX
symbols) fitted by the equation-error IDIM-LS pipeline of :mod:`ident.fitting.rigid`: zero-phase Butterworth position,
central-difference velocity and acceleration, the first ``n_border - 1`` samples dropped, parallel decimation of
every regressor column and of the force (MATLAB ``decimate``). EMPS logs (controller data in ``meta_extra``) use
the EMPS settings of :func:`ident.fitting.rigid.identify_rigid`; other logs the generic rule
(:func:`ident.fitting.rigid.generic_idim_settings`) and only the rows where the axis clearly slides
(:func:`ident.fitting.rigid.moving_mask`). The base model is ``tau = M q'' + Fc sgn(q') + offset``.

For fixed Stribeck parameters the force is linear in the model's *coordinates* (M, Fc or Fc+ / Fc-, Fv or Fv+ /
Fv-, offset); the regressor columns are the CasADi Jacobian of ``rigid_force`` with respect to them, evaluated on
the raw rows and decimated. The coordinates are solved by CasADi + IPOPT (:func:`ident.fitting.rigid.solve_ls_casadi`) and
checked against ``numpy.linalg.lstsq``. Stribeck's velocity (and, with asymmetric friction, its ratio) enter
nonlinearly: they are profiled (grid of log velocity, bounded 1-D search of the ratio, LS for the rest).

**Candidates** (``EFFECTS`` entries that apply to the rigid model):

- ``viscous_motor``: ``Fv q'`` (the rigid body is the motor-side axis).
- ``asymmetric_friction``: the friction levels of the two directions differ. The PDF's 3.11 % model (its eq. 12,
  ``Script_IDIM_LS_Asym_Fric``) is ``M, Fv+, Fc+, Fv-, Fc-`` **without offset**: Coulomb *and* viscous levels
  depend on the direction. The library's ``friction_asymmetry`` ``a`` (``Fc (1 + a sgn v)``) covers the Coulomb
  part only, and on sliding rows ``Fc a`` is the same regressor as the offset, so on its own it cannot improve a
  model that has an offset. Here the effect is therefore the PDF's: Coulomb asymmetry ``a`` (replacing the offset,
  which it absorbs) and, when the model has viscous friction, the viscous asymmetry ``Fv (1 + a_v sgn v)``: the
  library's (and the FMU's) ``viscous_asymmetry`` ``a_v``, the effect's second unknown. The exported rigid models
  and the FMU therefore share both parameters (``Fc+- = Fc (1 +- a)``, ``Fv+- = Fv (1 +- a_v)``).
- ``stribeck``: ``Fc (1 + s exp(-(v / v_s)^2))``; ``v_s`` is searched between 0.1 % and 50 % of the 99th
  percentile of |v| (a decay scale near the top speed only reshapes the friction-speed curve: that is not a
  Stribeck effect).
- ``flexibility`` cannot be fitted without a load sensor: its signature (narrow-band residual power the rigid model
  cannot produce, or residual power that keeps rising towards the filter's band edge) is tested on the residual
  spectrum and reported in ``unexplained`` with that evidence, never as a named effect.

**Held-back data and the acceptance rule.** The ``holdout`` log (processed with the training fit's settings, as
:func:`ident.fitting.rigid.validate_rigid` does) or else the last 30 % of the log. Each candidate is refitted on the
training data; its score is ``SSE_heldback(without) / SSE_heldback(with)``. It is accepted when all three hold:
the held-back SSE falls by more than 2 % (score > 1/0.98), a one-sided Diebold-Mariano test of the held-back
squared errors (Newey-West variance) gives p < 0.01, and the training BIC falls. The best-scoring accepted candidate
is added; the runner-up and the margin (winner's score / runner-up's) are recorded. The loop stops when no
candidate passes.

**Uncertainty**: the Newey-West (HAC) sandwich of :mod:`ident.fitting.rigid` on the Jacobian of the decimated prediction,
95 % normal intervals, delta method for derived numbers (Fv as the mean of Fv+ and Fv-, |a|, s).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
import pandas as pd
import scipy.optimize as so
import scipy.signal as sg
import scipy.stats

from ..common.markdown import md_table
from ..common.plotting import figure, save
from ..fitting.logs import DriveLog, LogError
from ..fitting.rigid import (
    IdimSettings,
    decimate,
    filtered_states,
    generic_idim_settings,
    hac_covariance,
    identify_rigid,
    moving_mask,
    solve_ls_casadi,
)
from ..model.effects import EFFECTS, rigid_force
from .result import Diagnosis, DiagnosisStep, NamedEffect, PublishedReference

__all__ = ["CANDIDATES", "RULE", "diagnose_rigid"]

#: Candidate effects of the rigid model, in library order (flexibility is tested by its signature only).
CANDIDATES: tuple[str, ...] = tuple(n for n, e in EFFECTS.items() if "rigid" in e.applies_to and e.fit_vars)

#: Acceptance rule of a candidate (see the module docstring).
RULE: dict[str, float] = {"min_heldback_sse_drop": 0.02, "dm_p_max": 0.01, "max_bic_change": 0.0,
                          "holdout_fraction": 0.30, "unexplained_energy_ratio": 2.0, "unexplained_bias_t": 3.0,
                          "unexplained_strong_bias_t": 5.0}

_Z95 = 1.959963984540054
_STRIBECK_GRID = 17


# ------------------------------------------------------------------------------------------- data -------------

@dataclass
class _Proc:
    """One log through the IDIM pipeline: raw rows after the border cut, decimated rows, the rows used."""

    a_raw: np.ndarray
    v_raw: np.ndarray
    y_raw: np.ndarray
    t: np.ndarray            # decimated times
    y: np.ndarray            # decimated force
    v: np.ndarray            # decimated velocity
    a: np.ndarray            # decimated acceleration
    q: np.ndarray            # decimated filtered position
    pulses: np.ndarray | None   # pulses active near the row (EMPS PULSES), decimated rows
    keep: np.ndarray         # rows used (all for EMPS, the sliding rows otherwise)
    settings: IdimSettings
    source: str

    def dec(self, x: np.ndarray) -> np.ndarray:
        return decimate(x, self.settings.decim_factor)


def _process(log: DriveLog, s: IdimSettings, generic: bool) -> _Proc:
    if log.n < 4 * s.n_border:
        raise LogError(f"{log.source}: {log.n} samples are too few for the IDIM pipeline (need {4 * s.n_border})")
    q_f, dq_f, ddq_f = filtered_states(log.motor_pos_rad, s)
    k0 = s.n_border - 1
    a_raw, v_raw, y_raw = ddq_f[k0:], dq_f[k0:], np.asarray(log.motor_torque_Nm[k0:], dtype=float)
    r = s.decim_factor
    td = log.time_s[k0:]
    nout = -(-td.size // r)
    t = td[r - (r * nout - td.size) - 1::r]
    dec = (lambda x: decimate(x, r))
    v = dec(v_raw)
    pulses = None
    if "pulses_N" in log.extra:
        p = (np.abs(np.asarray(log.extra["pulses_N"][k0:], dtype=float)) > 0).astype(float)
        # a row "has pulses" when a pulse edge lies within one decimation period of it
        edge = np.zeros_like(p)
        edge[1:] = np.abs(np.diff(p))
        near = np.convolve(edge, np.ones(2 * r + 1), mode="same") > 0
        idx = np.arange(td.size)[r - (r * nout - td.size) - 1::r]
        pulses = near[idx]
    keep = moving_mask(v) if generic else np.ones(v.size, dtype=bool)
    if generic and keep.sum() < 20:
        raise RuntimeError(f"{log.source}: the axis barely slides in this log (fewer than 20 sliding rows): the "
                           "rigid model's inertia and friction are not excited")
    if np.percentile(np.abs(v), 99) <= 0 or np.ptp(log.motor_pos_rad) <= 0:
        raise RuntimeError(f"{log.source}: the axis does not move: nothing to identify")
    return _Proc(a_raw, v_raw, y_raw, t, dec(y_raw), v, dec(a_raw), dec(q_f[k0:]), pulses, keep, s, log.source)


# ------------------------------------------------------------------------------------------ models -------------

@dataclass(frozen=True)
class _Spec:
    """A rigid model: the set of effects on top of Coulomb friction and the offset."""

    effects: frozenset

    @property
    def asym(self) -> bool:
        return "asymmetric_friction" in self.effects

    @property
    def viscous(self) -> bool:
        return "viscous_motor" in self.effects

    @property
    def stribeck(self) -> bool:
        return "stribeck" in self.effects

    def coords(self) -> list[str]:
        c = ["M"] + (["Fc_pos", "Fc_neg"] if self.asym else ["Fc"])
        if self.viscous:
            c += ["Fv_pos", "Fv_neg"] if self.asym else ["Fv"]
        if not self.asym:
            c.append("offset")
        return c

    def add(self, name: str) -> "_Spec":
        return _Spec(self.effects | {name})


_FUNCS: dict[tuple, ca.Function] = {}


def _library_theta(spec: _Spec, b: dict[str, Any], v: Any, s: Any, vs: Any) -> dict[str, Any]:
    """The library parameters of ``rigid_force`` from the model's coordinates (numbers or CasADi symbols)."""
    th: dict[str, Any] = {"M": b["M"]}
    if spec.asym:
        th["Fc"] = (b["Fc_pos"] + b["Fc_neg"]) / 2
        th["asymmetry"] = (b["Fc_pos"] - b["Fc_neg"]) / (b["Fc_pos"] + b["Fc_neg"])
    else:
        th["Fc"] = b["Fc"]
        th["offset"] = b["offset"]
    if spec.viscous:
        if spec.asym:   # the PDF's eq. 12: the viscous level depends on the direction too (library viscous_asymmetry)
            th["Fv"] = (b["Fv_pos"] + b["Fv_neg"]) / 2
            th["viscous_asymmetry"] = (b["Fv_pos"] - b["Fv_neg"]) / (b["Fv_pos"] + b["Fv_neg"])
        else:
            th["Fv"] = b["Fv"]
    if spec.stribeck:
        th["stribeck_ratio"] = s
        th["stribeck_velocity"] = vs
    return th


def _force_function(spec: _Spec) -> ca.Function:
    """(a, v, coords, s, v_s) -> (force, d force / d coords) from ``ident.model.effects.rigid_force`` (SX)."""
    key = tuple(spec.coords())
    if key not in _FUNCS:
        a, v, s, vs = ca.SX.sym("a"), ca.SX.sym("v"), ca.SX.sym("s"), ca.SX.sym("vs")
        beta = ca.SX.sym("beta", len(key))
        b = {n: beta[i] for i, n in enumerate(key)}
        f = rigid_force(a, v, _library_theta(spec, b, v, s, vs))
        _FUNCS[key] = ca.Function("rigid_" + "_".join(key), [a, v, beta, s, vs], [f, ca.jacobian(f, beta).T])
    return _FUNCS[key]


def _raw_columns(spec: _Spec, p: _Proc, s: float, vs: float) -> np.ndarray:
    """Regressor columns on the raw rows (exact: the force is linear in the coordinates; evaluated at 1)."""
    f = _force_function(spec)
    n = p.v_raw.size
    fm = f.map(n)
    _, J = fm(p.a_raw[None, :], p.v_raw[None, :], np.ones(len(spec.coords())), s, vs)
    return np.asarray(J, dtype=float).T


def _columns(spec: _Spec, p: _Proc, s: float = 0.0, vs: float = 1.0) -> np.ndarray:
    J = _raw_columns(spec, p, s, vs)
    return np.column_stack([p.dec(J[:, j]) for j in range(J.shape[1])])[p.keep]


@dataclass
class _Fit:
    spec: _Spec
    coords: list[str]
    beta: np.ndarray
    beta_lstsq: np.ndarray
    s: float
    vs: float
    X: np.ndarray
    e: np.ndarray
    y: np.ndarray
    cov: np.ndarray              # HAC covariance of [beta, (s, log vs)]
    cov_names: list[str]
    hac_lag: int
    solver: dict[str, Any]
    stribeck_at_bound: bool = False

    @property
    def sse(self) -> float:
        return float(self.e @ self.e)

    @property
    def n(self) -> int:
        return int(self.y.size)

    @property
    def k(self) -> int:
        return len(self.coords) + (2 if self.spec.stribeck else 0)

    @property
    def relative_error_pct(self) -> float:
        return 100.0 * math.sqrt(self.sse) / float(np.linalg.norm(self.y))

    @property
    def bic(self) -> float:
        return self.n * math.log(self.sse / self.n) + self.k * math.log(self.n)

    @property
    def casadi_vs_lstsq(self) -> float:
        return float(np.max(np.abs(self.beta - self.beta_lstsq) / np.maximum(np.abs(self.beta_lstsq), 1e-12)))

    def coord(self, name: str) -> float:
        return float(self.beta[self.coords.index(name)])

    def params(self) -> dict[str, float]:
        b = dict(zip(self.coords, (float(x) for x in self.beta)))
        out = {"M": b["M"]}
        if self.spec.asym:
            out.update(Fc=(b["Fc_pos"] + b["Fc_neg"]) / 2, Fc_pos=b["Fc_pos"], Fc_neg=b["Fc_neg"],
                       friction_asymmetry=(b["Fc_pos"] - b["Fc_neg"]) / (b["Fc_pos"] + b["Fc_neg"]), offset=0.0)
            if self.spec.viscous:
                out.update(Fv=(b["Fv_pos"] + b["Fv_neg"]) / 2, Fv_pos=b["Fv_pos"], Fv_neg=b["Fv_neg"],
                           viscous_asymmetry=(b["Fv_pos"] - b["Fv_neg"]) / (b["Fv_pos"] + b["Fv_neg"]))
        else:
            out.update(Fc=b["Fc"], offset=b["offset"])
            if self.spec.viscous:
                out["Fv"] = b["Fv"]
        if self.spec.stribeck:
            out.update(stribeck_ratio=self.s, stribeck_velocity=self.vs)
        return out

    def predict(self, p: _Proc) -> np.ndarray:
        return _columns(self.spec, p, self.s, self.vs) @ self.beta

    def predict_raw(self, p: _Proc) -> np.ndarray:
        """The library's force on the raw rows, at the fitted parameters (CasADi ``rigid_force``)."""
        f = _force_function(self.spec).map(p.v_raw.size)
        F, _ = f(p.a_raw[None, :], p.v_raw[None, :], self.beta, self.s, self.vs)
        return np.asarray(F, dtype=float).ravel()


def _linear_fit(spec: _Spec, p: _Proc, X: np.ndarray, s: float, vs: float, at_bound: bool = False) -> _Fit:
    y = p.y[p.keep]
    if np.linalg.matrix_rank(X) < X.shape[1]:
        raise RuntimeError(f"{p.source}: the regressors of {'+'.join(sorted(spec.effects)) or 'the base model'} "
                           "are collinear on this log (it does not excite them separately)")
    ref = np.linalg.lstsq(X, y, rcond=None)[0]
    beta, info = solve_ls_casadi(X, y)
    e = y - X @ beta
    # Jacobian of the prediction for the covariance: coordinates, then Stribeck's nonlinear parameters
    J, names = X, list(spec.coords())
    if spec.stribeck and not at_bound:
        h = 1e-4
        d_s = (_columns(spec, p, s + h, vs) - _columns(spec, p, s - h, vs)) @ beta / (2 * h)
        d_lv = (_columns(spec, p, s, vs * math.exp(h)) - _columns(spec, p, s, vs * math.exp(-h))) @ beta / (2 * h)
        J = np.column_stack([X, d_s, d_lv])
        names += ["stribeck_ratio", "log_stribeck_velocity"]
    try:
        cov, lag, _ = hac_covariance(J, e)
    except np.linalg.LinAlgError:
        cov, lag = np.full((J.shape[1], J.shape[1]), np.nan), -1
    return _Fit(spec, list(spec.coords()), beta, ref, s, vs, X, e, y, cov, names, lag, info, at_bound)


def _fit(spec: _Spec, p: _Proc) -> _Fit:
    if not spec.stribeck:
        return _linear_fit(spec, p, _columns(spec, p), 0.0, 1.0)
    # Stribeck: profile over log v_s (grid, then bounded refinement); the ratio s by a bounded 1-D search (the
    # columns are affine in s: X(s) = X0 + s X1); LS for the coordinates.
    y = p.y[p.keep]
    v99 = float(np.percentile(np.abs(p.v[p.keep]), 99))
    lo, hi = math.log(1e-3 * v99), math.log(0.5 * v99)

    def inner(lvs: float) -> tuple[float, float]:
        vs = math.exp(lvs)
        X0 = _columns(spec, p, 0.0, vs)
        X1 = _columns(spec, p, 1.0, vs) - X0

        def sse(s: float) -> float:
            X = X0 + s * X1
            r = y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
            return float(r @ r)

        grid = np.linspace(0.0, 10.0, 21)
        vals = [sse(g) for g in grid]
        i = int(np.argmin(vals))
        if i == 0 and vals[1] >= vals[0]:
            res = so.minimize_scalar(sse, bounds=(0.0, grid[1]), method="bounded", options={"xatol": 1e-6})
        else:
            res = so.minimize_scalar(sse, bounds=(grid[max(i - 1, 0)], grid[min(i + 1, 20)]), method="bounded",
                                     options={"xatol": 1e-6})
        best = (res.fun, res.x) if res.fun < vals[i] else (vals[i], grid[i])
        if sse(0.0) <= best[0]:
            best = (sse(0.0), 0.0)
        return float(best[0]), float(best[1])

    grid = np.linspace(lo, hi, _STRIBECK_GRID)
    prof = [inner(g) for g in grid]
    i = int(np.argmin([q[0] for q in prof]))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    res = so.minimize_scalar(lambda g: inner(g)[0], bounds=(a, b), method="bounded", options={"xatol": 1e-3})
    lvs = float(res.x) if res.fun < prof[i][0] else float(grid[i])
    _, s = inner(lvs)
    at_bound = s <= 1e-6 or lvs <= lo + 1e-6 or lvs >= hi - 1e-6
    vs = math.exp(lvs)
    return _linear_fit(spec, p, _columns(spec, p, s, vs), s, vs, at_bound=at_bound or s <= 1e-6)


# --------------------------------------------------------------------------------------- statistics -----------

def _nw_var_of_mean(d: np.ndarray) -> float:
    """Newey-West variance of the mean of d (Bartlett, lag floor(4 (n/100)^(2/9)))."""
    n = d.size
    d = d - d.mean()
    lag = int(math.floor(4 * (n / 100.0) ** (2.0 / 9.0)))
    s = float(d @ d) / n
    for j in range(1, lag + 1):
        s += 2 * (1 - j / (lag + 1)) * float(d[j:] @ d[:-j]) / n
    return max(s, 1e-300) / n


def _dm_pvalue(e0: np.ndarray, e1: np.ndarray) -> float:
    """One-sided Diebold-Mariano p-value of 'model 1 predicts the held-back data better than model 0'."""
    d = e0**2 - e1**2
    if not np.any(d):
        return 1.0
    t = float(d.mean()) / math.sqrt(_nw_var_of_mean(d))
    return float(scipy.stats.norm.sf(t))


def _delta(fit: _Fit, g: Any) -> tuple[float, float]:
    """Value and HAC standard deviation of g(params dict) by the delta method (numerical gradient)."""
    names = fit.cov_names
    base = {n: float(fit.beta[i]) for i, n in enumerate(fit.coords)}
    if "stribeck_ratio" in names:
        base["stribeck_ratio"] = fit.s
        base["log_stribeck_velocity"] = math.log(fit.vs)
    val = float(g(base))
    grad = np.zeros(len(names))
    for i, n in enumerate(names):
        h = 1e-6 * max(abs(base[n]), 1e-3)
        up, dn = dict(base), dict(base)
        up[n] += h
        dn[n] -= h
        grad[i] = (g(up) - g(dn)) / (2 * h)
    var = float(grad @ fit.cov @ grad)
    return val, math.sqrt(var) if var >= 0 else math.nan


def _magnitude(name: str, fit: _Fit) -> tuple[float, float]:
    if name == "viscous_motor":
        if fit.spec.asym:
            return _delta(fit, lambda b: (b["Fv_pos"] + b["Fv_neg"]) / 2)
        return _delta(fit, lambda b: b["Fv"])
    if name == "asymmetric_friction":
        if fit.spec.viscous:   # the asymmetry the data carry is mostly viscous (PDF eq. 12): quote the larger one
            ac = _delta(fit, lambda b: abs(b["Fc_pos"] - b["Fc_neg"]) / (b["Fc_pos"] + b["Fc_neg"]))
            av = _delta(fit, lambda b: abs(b["Fv_pos"] - b["Fv_neg"]) / (b["Fv_pos"] + b["Fv_neg"]))
            return av if av[0] > ac[0] else ac
        return _delta(fit, lambda b: abs(b["Fc_pos"] - b["Fc_neg"]) / (b["Fc_pos"] + b["Fc_neg"]))
    if name == "stribeck":
        if fit.stribeck_at_bound:
            return fit.s, math.nan
        return _delta(fit, lambda b: b["stribeck_ratio"])
    raise KeyError(name)


# ----------------------------------------------------------------------------------- localisation -------------

def _regimes(e: np.ndarray, p: _Proc) -> pd.DataFrame:
    """Ranked table of regimes: share of the residual energy vs share of the rows, bias (and its t), rms."""
    v, a, q = p.v[p.keep], p.a[p.keep], p.q[p.keep]
    av = np.abs(v)
    thr = 0.1 * float(np.percentile(av, 99))
    slip = av > thr
    masks: list[tuple[str, str, np.ndarray]] = [("stick / near reversal (|v| < 10 % of v99)", "stick-slip", ~slip),
                                                ("sliding", "stick-slip", slip)]
    if slip.sum() >= 8:
        qs = np.quantile(av[slip], [0.25, 0.5, 0.75])
        edges = [thr, *qs, np.inf]
        for i in range(4):
            m = slip & (av > edges[i]) & (av <= edges[i + 1])
            masks.append((f"speed band {i + 1}/4 (|v| {edges[i]:.3g}..{edges[i + 1]:.3g})", "speed", m))
    masks += [("moving +", "direction", slip & (v > 0)), ("moving -", "direction", slip & (v < 0)),
              ("accelerating (a v > 0)", "acceleration", slip & (a * v > 0)),
              ("braking (a v < 0)", "acceleration", slip & (a * v < 0)),
              ("a > 0", "acceleration sign", a > 0), ("a < 0", "acceleration sign", a < 0)]
    qe = np.quantile(q, [1 / 3, 2 / 3])
    for lab, m in (("low", q <= qe[0]), ("middle", (q > qe[0]) & (q <= qe[1])), ("high", q > qe[1])):
        masks.append((f"position {lab} third", "position", m))
    if p.pulses is not None:
        pk = p.pulses[p.keep]
        masks += [("pulse edge within one decimated period", "pulses", pk), ("no pulse edge", "pulses", ~pk)]
    tot = float(e @ e)
    n = e.size
    rho = float(np.corrcoef(e[:-1], e[1:])[0, 1]) if n > 3 else 0.0
    infl = (1 + rho) / (1 - rho) if -1 < rho < 1 else 1.0
    rows = []
    for name, kind, m in masks:
        k = int(m.sum())
        if k == 0:
            continue
        em = e[m]
        se = math.sqrt(max(float(np.var(em)), 1e-300) * max(infl, 1.0) / k)
        rows.append({"regime": name, "kind": kind, "n": k, "share_samples_pct": 100.0 * k / n,
                     "share_energy_pct": 100.0 * float(em @ em) / tot, "bias": float(em.mean()),
                     "bias_t": float(em.mean()) / se, "rms": float(math.sqrt(em @ em / k))})
    df = pd.DataFrame(rows)
    df["energy_ratio"] = df["share_energy_pct"] / df["share_samples_pct"]
    df["excess_pct"] = df["share_energy_pct"] - df["share_samples_pct"]
    return df.sort_values("excess_pct", ascending=False, ignore_index=True)


_SUGGEST = {
    "stick-slip": "friction at and near velocity reversals that Coulomb + viscous (+ Stribeck) does not capture: "
                  "pre-sliding (Dahl/LuGre-like) friction, or the filters smearing the stop into the neighbouring "
                  "rows",
    "speed": "the friction-speed curve is not what the model allows in this band (e.g. a nonlinear viscous term)",
    "direction": "a direction-dependent force the fitted levels do not capture; on held-back data with the "
                 "same regime well fitted in training it means the direction-dependent levels (Coulomb asymmetry / "
                 "offset) changed between the runs (drift, temperature, the screw's wear the PDF blames for the "
                 "asymmetry)",
    "acceleration": "a force that depends on the acceleration phase: an error in the force scale (gtau) or a lag "
                    "between the force command and the force the drive produces (current-loop dynamics), or a "
                    "flexibility",
    "acceleration sign": "an acceleration-dependent force: force-scale error, actuator lag or a flexibility",
    "position": "a position-dependent force (force ripple, cogging, screw wear or a load that depends on position)",
    "pulses": "the pulse steps excite dynamics above the rigid model's band: a flexibility (the PDF's explanation) "
              "or the drive's current loop (the force is gtau * vir, the command, not a measured force)",
}


def _unexplained(table: pd.DataFrame, data: str) -> list[dict[str, Any]]:
    out = []
    for _, r in table.iterrows():
        concentrated = r.energy_ratio >= RULE["unexplained_energy_ratio"] and (
            abs(r.bias_t) >= RULE["unexplained_bias_t"]
            # zero-mean but concentrated: oscillation after pulse steps, misfit around reversals
            or (r.kind in ("pulses", "stick-slip") and r.share_energy_pct >= 10.0))
        biased = abs(r.bias_t) >= RULE["unexplained_strong_bias_t"] and r.share_samples_pct >= 10.0 \
            and r.kind in ("direction", "position", "speed")
        if concentrated or biased:
            out.append({"regime": f"{data}: {r.regime}", "share_pct": round(float(r.share_energy_pct), 2),
                        "detail": f"{r.share_energy_pct:.1f} % of the residual energy on {r.share_samples_pct:.1f} % "
                                  f"of the rows ({r.energy_ratio:.1f}x), bias {r.bias:+.3g} (t = {r.bias_t:+.1f}), "
                                  f"rms {r.rms:.3g}. No library effect explains it; it suggests "
                                  f"{_SUGGEST.get(r.kind, 'an effect outside the library')}."})
    return out


def _spectrum_check(fit: _Fit, p: _Proc, data: str) -> tuple[dict[str, Any] | None, dict[str, Any]]:
    """Flexibility signature on the raw-rate residual of the final model (Welch, ~4 Hz resolution): a broad bump of
    the residual's power inside [f_dyn / 2, 0.8 x Butterworth cut-off] standing >= 3x above the residual's own level
    below f_dyn / 2 and >= 2 bins wide at half height (a damped resonance the rigid model cannot produce, not a
    line such as the 50/60 Hz mains, which are skipped)."""
    s = p.settings
    fs = s.sample_rate_hz
    r = p.y_raw - fit.predict_raw(p)
    nper = int(min(r.size // 4, 2 ** round(math.log2(max(16.0, fs / 4.0)))))
    f, Pr = sg.welch(r, fs=fs, nperseg=nper)
    _, Py = sg.welch(p.y_raw - p.y_raw.mean(), fs=fs, nperseg=nper)
    band = (f >= 0.5 * s.f_dyn_hz) & (f <= 0.8 * s.butter_cutoff_hz)
    low = (f > 0) & (f < 0.5 * s.f_dyn_hz)
    info: dict[str, Any] = {"data": data, "freq_hz": f[f <= s.butter_cutoff_hz].tolist(),
                            "residual_psd": Pr[f <= s.butter_cutoff_hz].tolist(),
                            "force_psd": Py[f <= s.butter_cutoff_hz].tolist()}
    if band.sum() < 4 or not low.any():
        return None, info
    mains = np.zeros_like(f, dtype=bool)
    for fm in (50.0, 60.0, 100.0, 120.0):
        mains |= np.abs(f - fm) <= 2.0 * (f[1] - f[0])
    cand = band & ~mains
    level = float(np.median(Pr[low]))
    i = int(np.flatnonzero(cand)[np.argmax(Pr[cand])])
    half = Pr >= 0.5 * Pr[i]
    width = 1
    for step in (-1, 1):
        j = i + step
        while 0 <= j < f.size and half[j] and not mains[j]:
            width, j = width + 1, j + step
    info.update(peak_hz=float(f[i]), peak_over_low=float(Pr[i] / level), peak_width_bins=width,
                residual_to_force_at_peak=float(Pr[i] / Py[i]))
    if Pr[i] >= 3 * level and width >= 2:
        return {"regime": f"{data}: residual spectrum bump near {f[i]:.0f} Hz", "share_pct": None,
                "detail": f"the residual's power near {f[i]:.0f} Hz is {Pr[i] / level:.1f}x its level below "
                          f"{0.5 * s.f_dyn_hz:.0f} Hz ({100 * Pr[i] / Py[i]:.1f} % of the force's power there), a "
                          f"broad bump ({width} bins of {f[1] - f[0]:.1f} Hz): the signature of a resonance the rigid "
                          "model cannot produce (flexibility), or of actuator dynamics (the logged force is a "
                          "command). A motor-only log cannot fit or tell them apart: it needs a load-side sensor "
                          "(two-inertia model). Not named as an effect."}, info
    return None, info


# ------------------------------------------------------------------------------------------- plots --------------

def _plots(out: Path, base: _Fit, final: _Fit, p: _Proc, ph: _Proc, final_h: np.ndarray, base_h: np.ndarray,
           spectra: list[dict[str, Any]], unit_f: str, unit_v: str) -> dict[str, str]:
    files = {}
    t, v = p.t[p.keep], p.v[p.keep]
    fig, ax = figure(2, 3, size=(15, 8))
    for row, (fit, lab) in enumerate(((base, "base (Coulomb + offset)"), (final, "final"))):
        ax[row, 0].plot(t, fit.e, "k", lw=0.6)
        ax[row, 0].set(title=f"{lab}: residual vs time (training)", xlabel="t [s]", ylabel=f"residual [{unit_f}]")
        ax[row, 1].plot(v, fit.e, ".", ms=2)
        ax[row, 1].set(title=f"{lab}: residual vs velocity", xlabel=f"v [{unit_v}]", ylabel=f"residual [{unit_f}]")
        yf = fit.y - fit.X[:, 0] * fit.coord("M")          # friction + offset part: force minus inertia
        ax[row, 2].plot(v, yf, ".", ms=2, label="measured - M a")
        ax[row, 2].plot(v, fit.y - fit.e - fit.X[:, 0] * fit.coord("M"), ".", ms=2, label="model - M a")
        ax[row, 2].set(title=f"{lab}: friction force vs velocity", xlabel=f"v [{unit_v}]", ylabel=f"[{unit_f}]")
        ax[row, 2].legend(fontsize=8)
        for a_ in ax[row]:
            a_.grid(True)
    save(fig, out / "rigid_residuals.png")
    files["residuals_png"] = str(out / "rigid_residuals.png")

    fig, ax = figure(1, 3, size=(15, 4.5))
    th, vh, yh = ph.t[ph.keep], ph.v[ph.keep], ph.y[ph.keep]
    ax[0].plot(th, yh, "b", lw=1, label="measured")
    ax[0].plot(th, yh - final_h, "--r", lw=0.8, label="final model")
    ax[0].plot(th, final_h, "k", lw=0.6, label="residual (final)")
    ax[0].set(title="held-back data: force and residual", xlabel="t [s]", ylabel=f"[{unit_f}]")
    ax[0].legend(fontsize=8)
    ax[1].plot(vh, base_h, ".", ms=2, label="base")
    ax[1].plot(vh, final_h, ".", ms=2, label="final")
    ax[1].set(title="held-back residual vs velocity", xlabel=f"v [{unit_v}]", ylabel=f"[{unit_f}]")
    ax[1].legend(fontsize=8)
    for sp in spectra:
        if "freq_hz" in sp:
            ax[2].semilogy(sp["freq_hz"], sp["residual_psd"], label=f"residual, {sp['data']}")
    ax[2].set(title="residual power spectrum (final model, raw rate)", xlabel="f [Hz]", ylabel=f"[{unit_f}^2/Hz]")
    ax[2].legend(fontsize=8)
    for a_ in ax:
        a_.grid(True)
    save(fig, out / "rigid_heldback.png")
    files["heldback_png"] = str(out / "rigid_heldback.png")
    return files


# ------------------------------------------------------------------------------------------ workflow -----------

def _is_closed_loop(log: DriveLog) -> bool:
    """A closed-loop linear-axis log with the position loop's constants (EMPS-like): its IDIM settings follow the
    identified closed loop."""
    return {"gtau", "kp", "kv"} <= set(log.meta_extra) and "qg" in log.extra and log.kind == "linear"


def _say(progress: bool, msg: str) -> None:
    if progress:
        import sys

        print(f"[diagnose-rigid] {msg}", file=sys.stderr, flush=True)


def diagnose_rigid(log: DriveLog, *, holdout: DriveLog | None = None, out_dir: str | Path | None = None,
                   progress: bool = False, reference: PublishedReference | None = None) -> Diagnosis:
    """Run the rigid-model discrepancy workflow on ``log`` (see the module docstring); ``holdout`` is the
    held-back log (else the last 30 % of ``log``). Writes ``rigid_diagnosis.md`` and plots into ``out_dir``;
    ``reference``: published figures of this data set to print beside the diagnosis's."""
    t0 = time.perf_counter()
    notes: list[str] = []
    emps = _is_closed_loop(log)
    if log.n < 200:
        raise LogError(f"{log.source}: {log.n} samples are too few for the rigid diagnosis (need a few hundred)")
    train_log, held_log = log, holdout
    if holdout is None:
        cut = int(round((1 - RULE["holdout_fraction"]) * log.n))
        train_log, held_log = log.window(0, cut), log.window(cut, log.n)
        notes.append(f"held-back data: the last {100 * RULE['holdout_fraction']:.0f} % of the log "
                     f"(t >= {log.time_s[cut]:.3f} s); pass a second log as holdout for a stronger test")
    if np.ptp(train_log.motor_pos_rad) <= 0:
        raise RuntimeError(f"{log.source}: the motor position never changes: the log does not move the axis")
    if emps:
        s = identify_rigid(train_log).settings      # the EMPS rules (w_dyn checked against the closed loop)
    else:
        s = generic_idim_settings(train_log)
    if held_log.meta.sample_rate_hz != s.sample_rate_hz and \
            abs(held_log.meta.sample_rate_hz - s.sample_rate_hz) > 1e-3 * s.sample_rate_hz:
        raise LogError(f"{held_log.source}: sampled at {held_log.meta.sample_rate_hz:g} Hz, the training log at "
                       f"{s.sample_rate_hz:g} Hz: the held-back log must use the training fit's filter settings")
    _say(progress, f"processing {train_log.source} and the held-back {held_log.source}")
    p = _process(train_log, s, generic=not emps)
    ph = _process(held_log, s, generic=not emps)
    if ph.keep.sum() < 20:
        raise RuntimeError(f"{held_log.source}: fewer than 20 usable held-back rows")
    lin = log.kind == "linear"
    unit_f, unit_v = ("N", "m/s") if lin else ("N.m", "rad/s")
    units = {"viscous_motor": "N s/m" if lin else "N.m.s/rad", "asymmetric_friction": "1", "stribeck": "1"}

    spec = _Spec(frozenset())
    cur = _fit(spec, p)
    if cur.coord("M") <= 0:
        raise RuntimeError(f"{log.source}: identified inertia {cur.coord('M'):g} is not positive: the log does not "
                           "excite the dynamics")
    cur_h = ph.y[ph.keep] - cur.predict(ph)
    yh_norm = float(np.linalg.norm(ph.y[ph.keep]))
    fits = [cur]
    held = [cur_h]
    steps = [DiagnosisStep(None, None, None, cur.relative_error_pct, None, cur.params(), pd.DataFrame(),
                           extra={"heldback_relative_error_pct": 100 * float(np.linalg.norm(cur_h)) / yh_norm,
                                  "bic": cur.bic, "casadi_vs_lstsq": cur.casadi_vs_lstsq})]
    _say(progress, f"base: training {cur.relative_error_pct:.3f} %, held-back "
                   f"{steps[0].extra['heldback_relative_error_pct']:.3f} %")
    named: list[NamedEffect] = []
    while True:
        rows, cand_fits = [], {}
        for name in CANDIDATES:
            if name in spec.effects:
                continue
            try:
                f = _fit(spec.add(name), p)
            except RuntimeError as exc:
                rows.append({"effect": name, "score": math.nan, "heldback_relative_error_pct": math.nan,
                             "training_relative_error_pct": math.nan, "delta_bic": math.nan, "dm_p": math.nan,
                             "accepted": False, "why": f"not fitted: {exc}"})
                continue
            eh = ph.y[ph.keep] - f.predict(ph)
            score = float(cur_h @ cur_h) / float(eh @ eh)
            dbic = f.bic - cur.bic
            pdm = _dm_pvalue(cur_h, eh)
            ok_gain = score > 1.0 / (1.0 - RULE["min_heldback_sse_drop"])
            ok = ok_gain and pdm < RULE["dm_p_max"] and dbic < RULE["max_bic_change"]
            why = []
            if not ok_gain:
                why.append(f"held-back SSE drop {100 * (1 - 1 / score):.2f} % <= {100 * RULE['min_heldback_sse_drop']:g} %")
            if pdm >= RULE["dm_p_max"]:
                why.append(f"DM p = {pdm:.3g} >= {RULE['dm_p_max']:g}")
            if dbic >= RULE["max_bic_change"]:
                why.append(f"BIC rises by {dbic:.1f}")
            if name == "stribeck" and f.stribeck_at_bound:
                why.append(f"Stribeck parameters at a bound (s = {f.s:.3g}, v_s = {f.vs:.3g})")
                ok = False
            if name == "asymmetric_friction" and not spec.viscous:
                why.append("without viscous friction the Coulomb asymmetry is the offset's regressor: same model")
            rows.append({"effect": name, "score": score,
                         "heldback_relative_error_pct": 100 * float(np.linalg.norm(eh)) / yh_norm,
                         "training_relative_error_pct": f.relative_error_pct, "delta_bic": dbic, "dm_p": pdm,
                         "accepted": ok, "why": "; ".join(why) if why else "passes the rule"})
            cand_fits[name] = (f, eh)
        table = pd.DataFrame(rows)
        if table.empty:
            break
        table = table.sort_values("score", ascending=False, na_position="last", ignore_index=True)
        steps[-1].candidates = table
        _say(progress, "candidates: " + ", ".join(f"{r.effect} {r.score:.3f}" for r in table.itertuples()))
        acc = table[table["accepted"]]
        if acc.empty:
            break
        win = acc.iloc[0]
        others = table[table["effect"] != win.effect]
        runner = others.iloc[0] if not others.empty else None
        margin = float(win.score / runner.score) if runner is not None and runner.score > 0 else None
        f, eh = cand_fits[win.effect]
        mag, sd = _magnitude(win.effect, f)
        ci = (mag - _Z95 * sd, mag + _Z95 * sd)
        spec, cur, cur_h = f.spec, f, eh
        evid = (f"held-back SSE {100 * (1 - 1 / win.score):.1f} % lower (score {win.score:.3f}, Diebold-Mariano "
                f"p = {win.dm_p:.2g}), training BIC {win.delta_bic:+.0f}; relative error "
                f"{steps[-1].relative_error_pct:.3f} -> {f.relative_error_pct:.3f} % (training), "
                f"{steps[-1].extra['heldback_relative_error_pct']:.3f} -> {win.heldback_relative_error_pct:.3f} % "
                f"(held-back). Signature: {EFFECTS[win.effect].signature}.")
        if runner is not None:
            evid += f" Runner-up {runner.effect} (score {runner.score:.3f})."
        named.append(NamedEffect(win.effect, mag, ci, units[win.effect], evid,
                                 None if runner is None else str(runner.effect), margin, f.params()))
        fits.append(f)
        held.append(eh)
        steps.append(DiagnosisStep(str(win.effect), None, None, f.relative_error_pct, float(win.score), f.params(),
                                   pd.DataFrame(),
                                   extra={"heldback_relative_error_pct": float(win.heldback_relative_error_pct),
                                          "bic": f.bic, "casadi_vs_lstsq": f.casadi_vs_lstsq,
                                          "dm_p": float(win.dm_p), "delta_bic": float(win.delta_bic),
                                          "runner_up": None if runner is None else str(runner.effect),
                                          "margin": margin}))
        _say(progress, f"added {win.effect}: training {f.relative_error_pct:.3f} %, held-back "
                       f"{win.heldback_relative_error_pct:.3f} %")

    # the named effects' final magnitudes (in the final model) with their intervals
    final = fits[-1]
    for ne in named:
        mag, sd = _magnitude(ne.name, final)
        ne.magnitude, ne.ci95, ne.params = mag, (mag - _Z95 * sd, mag + _Z95 * sd), final.params()
        if ne.name == "asymmetric_friction":
            parts = [("Coulomb |Fc+ - Fc-| / (Fc+ + Fc-)", "Fc_pos", "Fc_neg")]
            if final.spec.viscous:
                parts.append(("viscous |Fv+ - Fv-| / (Fv+ + Fv-)", "Fv_pos", "Fv_neg"))
            txt = []
            for lab, kp, km in parts:
                m_, s_ = _delta(final, lambda b, kp=kp, km=km: abs(b[kp] - b[km]) / (b[kp] + b[km]))
                txt.append(f"{lab} = {m_:.4f}, 95 % CI [{m_ - _Z95 * s_:.4f}, {m_ + _Z95 * s_:.4f}]")
            ne.evidence += " Magnitude: the larger of " + "; ".join(txt) + "."
    if final.spec.asym:
        notes.append("asymmetric_friction is the PDF's eq. 12 (Fc+, Fc-, and Fv+, Fv- when viscous friction is in the "
                     "model; no offset, which the Coulomb asymmetry absorbs). In library/FMU parameters: "
                     f"friction_asymmetry = {final.params()['friction_asymmetry']:+.4f} (Coulomb), viscous asymmetry "
                     f"viscous_asymmetry = {final.params().get('viscous_asymmetry', 0.0):+.4f} on Fv = (Fv+ + Fv-)/2, "
                     "so an exported FMU carries the whole model.")
    # where the final (and base) model still disagree
    table_base = _regimes(fits[0].e, p)
    table_final = _regimes(final.e, p)
    table_held = _regimes(cur_h, ph)
    unexplained = _unexplained(table_final, "training") + _unexplained(table_held, "held-back")
    spectra = []
    for pp, lab in ((p, "training"), (ph, "held-back")):
        flag, info = _spectrum_check(final, pp, lab)
        spectra.append(info)
        if flag:
            unexplained.append(flag)
    residual_table = pd.concat([table_final.assign(data="training"), table_held.assign(data="held-back")],
                               ignore_index=True)
    files: dict[str, str] = {}
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        files.update(_plots(out, fits[0], final, p, ph, cur_h, held[0], spectra, unit_f, unit_v))
        md = _report(log, held_log, emps, steps, named, unexplained, table_base, table_final, table_held, final,
                     notes, s, reference)
        (out / "rigid_diagnosis.md").write_text(md)
        files["report"] = str(out / "rigid_diagnosis.md")
    return Diagnosis(model="rigid", steps=steps, effects=named, unexplained=unexplained,
                     residual_table=residual_table, fmu=None, files=files, elapsed_s=time.perf_counter() - t0,
                     notes=notes)


# ------------------------------------------------------------------------------------------- report -------------

def _model_label(spec: _Spec) -> str:
    """The model's coordinates as the report names them (and a published reference keys its figures)."""
    label = "M, Fc+, Fc-" if spec.asym else "M, Fc, offset"
    if spec.viscous:
        label += ", Fv+, Fv-" if spec.asym else ", Fv"
    if spec.stribeck:
        label += ", Stribeck (s, v_s)"
    return label


def _steps_md(steps: list[DiagnosisStep], reference: PublishedReference | None) -> str:
    rows = []
    spec = _Spec(frozenset())
    for i, st in enumerate(steps):
        if st.added is not None:
            spec = spec.add(st.added)
        label = _model_label(spec)
        paper_train, paper_ctv = ("", "") if reference is None else reference.step_errors.get(label, ("-", "-"))
        rows.append((i, st.added or "(base)", label, f"{st.relative_error_pct:.4f}", paper_train,
                     f"{st.extra['heldback_relative_error_pct']:.4f}", paper_ctv,
                     "" if st.score is None else f"{st.score:.3f}", f"{st.extra['bic']:.1f}",
                     "" if st.extra.get("dm_p") is None else f"{st.extra['dm_p']:.2g}",
                     "" if st.extra.get("runner_up") is None else
                     f"{st.extra['runner_up']} ({st.extra['margin']:.3f})" if st.extra.get("margin") else
                     str(st.extra.get("runner_up"))))
    hdr = ["step", "added", "model", "training rel. error [%]", "paper", "held-back rel. error [%]",
           "paper (CTV on PULSES)", "score", "BIC", "DM p", "runner-up (margin)"]
    return md_table(pd.DataFrame(rows, columns=hdr))


def _report(log: DriveLog, held: DriveLog, emps: bool, steps: list[DiagnosisStep], named: list[NamedEffect],
            unexplained: list[dict[str, Any]], tb: pd.DataFrame, tf: pd.DataFrame, th: pd.DataFrame, final: _Fit,
            notes: list[str], s: IdimSettings, reference: PublishedReference | None) -> str:
    steps_md = _steps_md(steps, reference)
    cand_md = []
    for i, st in enumerate(steps):
        if st.candidates is not None and not st.candidates.empty:
            cand_md.append(f"Candidates tried on top of step {i} ({st.added or 'base'}):\n\n" + md_table(
                st.candidates[["effect", "score", "training_relative_error_pct", "heldback_relative_error_pct",
                               "delta_bic", "dm_p", "accepted", "why"]],
                {"score": ".4f", "training_relative_error_pct": ".4f", "heldback_relative_error_pct": ".4f",
                 "delta_bic": ".1f", "dm_p": ".2g"}))
    eff_md = "\n".join(f"- **{e.name}**: {e.magnitude:.5g} {e.unit}, 95 % CI [{e.ci95[0]:.5g}, {e.ci95[1]:.5g}] "
                       f"(HAC); runner-up {e.runner_up}, margin {e.margin if e.margin is None else round(e.margin, 3)}."
                       f" Evidence: {e.evidence}" for e in named) or "- none"
    published = reference.params if reference is not None and _model_label(final.spec) == reference.params_model \
        else {}
    par_md = md_table(pd.DataFrame([(k, f"{v:.6g}", f"{published[k]:.4f}" if k in published else "")
                                    for k, v in final.params().items()],
                                   columns=["parameter", "value", "paper (asymmetric model)"]))
    regcols = ["regime", "n", "share_samples_pct", "share_energy_pct", "energy_ratio", "bias", "bias_t", "rms"]
    regfmt = {"share_samples_pct": ".1f", "share_energy_pct": ".1f", "energy_ratio": ".2f", "bias": ".3g",
              "bias_t": ".1f", "rms": ".3g"}
    unx = "\n".join(f"- **{u['regime']}**" + (f" ({u['share_pct']} % of the residual energy)" if u.get("share_pct")
                                               is not None else "") + f": {u['detail']}" for u in unexplained) or \
        "- none: no regime holds residual energy well above its share with a significant bias."
    paper_md = "" if reference is None else (f"\n## Against the paper ({reference.citation})\n\n" +
                                             "\n".join(f"- {n}" for n in reference.notes) + "\n")
    return f"""# Rigid-model diagnosis: {Path(log.source).name}

Training: `{log.source}`; held-back: `{held.source}`. Equation-error IDIM pipeline (`ident/fitting/rigid.py`): w_dyn =
{s.f_dyn_hz:.4g} Hz ({s.f_dyn_source}), Butterworth {s.butter_order} at {s.butter_cutoff_hz:.4g} Hz, decimation by
{s.decim_factor}{'' if emps else ', sliding rows only'}. Every model is `ident.model.effects.rigid_force` (CasADi SX); the
coordinates are solved by IPOPT and checked against lstsq (largest relative difference in the final model
{final.casadi_vs_lstsq:.1e}).

Acceptance rule: a candidate is added when the held-back SSE falls by more than
{100 * RULE['min_heldback_sse_drop']:g} % (score = SSE without / SSE with), a one-sided Diebold-Mariano test of the
held-back squared errors gives p < {RULE['dm_p_max']:g}, and the training BIC falls; the best such candidate is
added, and the loop stops when none passes.

## Steps (relative error = PDF eq. 11 on the decimated force)

{steps_md}

{chr(10).join(cand_md)}

## Named effects (final model)

{eff_md}

## Final parameters

{par_md}
{paper_md}
## Where the models disagree (ranked by residual energy share minus row share)

Base model, training:

{md_table(tb[regcols], regfmt)}

Final model, training:

{md_table(tf[regcols], regfmt)}

Final model, held-back:

{md_table(th[regcols], regfmt)}

![residuals](rigid_residuals.png)

![held-back](rigid_heldback.png)

## Left unexplained

{unx}

## Notes

{chr(10).join('- ' + n for n in notes) or '- none'}
"""
