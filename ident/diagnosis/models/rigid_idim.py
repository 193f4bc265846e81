"""The rigid model of a motor-only log by equation error (IDIM-LS): its coordinates, regressors, fits and
uncertainty; the rigid plug-in (``rigid.py``) builds the discrepancy loop's models from it.

Every model is the effect library's rigid force (:func:`ident.model.effects.rigid_force`, built with CasADi SX
symbols) fitted by the equation-error IDIM-LS pipeline of :mod:`ident.fitting.rigid`: zero-phase Butterworth
position, central-difference velocity and acceleration, the first ``n_border - 1`` samples dropped, parallel
decimation of every regressor column and of the force (MATLAB ``decimate``). EMPS logs (controller data in
``meta_extra``) use the EMPS settings of :func:`ident.fitting.rigid.identify_rigid`; other logs the generic rule
(:func:`ident.fitting.rigid.generic_idim_settings`) and only the rows where the axis clearly slides
(:func:`ident.fitting.rigid.moving_mask`). The base model is ``tau = M q'' + Fc sgn(q') + offset``.

For fixed Stribeck parameters the force is linear in the model's *coordinates* (M, Fc or Fc+ / Fc-, Fv or Fv+ /
Fv-, offset); the regressor columns are the CasADi Jacobian of ``rigid_force`` with respect to them, evaluated on
the raw rows and decimated. The coordinates are solved by CasADi + IPOPT (:func:`ident.fitting.rigid.solve_ls_casadi`)
and checked against ``numpy.linalg.lstsq``. Stribeck's velocity (and, with asymmetric friction, its ratio) enter
nonlinearly: they are profiled (grid of log velocity, bounded 1-D search of the ratio, LS for the rest).

Effects (``EFFECTS`` entries that apply to the rigid model):

- ``viscous_motor``: ``Fv q'`` (the rigid body is the motor-side axis).
- ``asymmetric_friction``: the friction levels of the two directions differ. The EMPS PDF's 3.11 % model (its eq.
  12, ``Script_IDIM_LS_Asym_Fric``) is ``M, Fv+, Fc+, Fv-, Fc-`` **without offset**: Coulomb *and* viscous levels
  depend on the direction. The library's ``friction_asymmetry`` ``a`` (``Fc (1 + a sgn v)``) covers the Coulomb
  part only, and on sliding rows ``Fc a`` is the same regressor as the offset, so on its own it cannot improve a
  model that has an offset. Here the effect is therefore the PDF's: Coulomb asymmetry ``a`` (replacing the offset,
  which it absorbs) and, when the model has viscous friction, the viscous asymmetry ``Fv (1 + a_v sgn v)``: the
  library's (and the FMU's) ``viscous_asymmetry`` ``a_v``, the effect's second unknown.
- ``stribeck``: ``Fc (1 + s exp(-(v / v_s)^2))``; ``v_s`` is searched between 0.1 % and 50 % of the 99th
  percentile of |v| (a decay scale near the top speed only reshapes the friction-speed curve: that is not a
  Stribeck effect).

**Uncertainty**: the Newey-West (HAC) sandwich of :mod:`ident.fitting.rigid` on the Jacobian of the decimated
prediction, 95 % normal intervals, delta method for derived numbers (Fv as the mean of Fv+ and Fv-, |a|, s).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
import scipy.optimize as so

from ...fitting.logs import DriveLog, LogError
from ...fitting.rigid import IdimSettings, decimate, filtered_states, hac_covariance, moving_mask, solve_ls_casadi
from ...model.effects import EFFECTS, rigid_force

#: effects of the rigid model, in library order (flexibility needs a load sensor)
RIGID_EFFECTS: tuple[str, ...] = tuple(n for n, e in EFFECTS.items() if "rigid" in e.applies_to and e.fit_vars)
Z95 = 1.959963984540054
STRIBECK_GRID = 17

# ------------------------------------------------------------------------------------------- data -------------

@dataclass
class Processed:
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


def process_log(log: DriveLog, s: IdimSettings, generic: bool) -> Processed:
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
    return Processed(a_raw, v_raw, y_raw, t, dec(y_raw), v, dec(a_raw), dec(q_f[k0:]), pulses, keep, s, log.source)


# ------------------------------------------------------------------------------------------ models -------------

@dataclass(frozen=True)
class Spec:
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

    def add(self, name: str) -> "Spec":
        return Spec(self.effects | {name})


FUNCTIONS: dict[tuple, ca.Function] = {}
MAPPED: dict[tuple[str, int], ca.Function] = {}
MAPPED_KEPT = 32


def library_theta(spec: Spec, b: dict[str, Any], v: Any, s: Any, vs: Any) -> dict[str, Any]:
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


def force_function(spec: Spec) -> ca.Function:
    """(a, v, coords, s, v_s) -> (force, d force / d coords) from ``ident.model.effects.rigid_force`` (SX). Cached
    per spec: its coordinates and whether it has the Stribeck term (whose s and v_s are arguments, not coordinates:
    a key of the coordinates alone served a Stribeck spec the function without the term, and its screen column was
    zero)."""
    coords = tuple(spec.coords())
    key = coords + (("stribeck",) if spec.stribeck else ())
    if key not in FUNCTIONS:
        a, v, s, vs = ca.SX.sym("a"), ca.SX.sym("v"), ca.SX.sym("s"), ca.SX.sym("vs")
        beta = ca.SX.sym("beta", len(coords))
        b = {n: beta[i] for i, n in enumerate(coords)}
        f = rigid_force(a, v, library_theta(spec, b, v, s, vs))
        FUNCTIONS[key] = ca.Function("rigid_" + "_".join(key), [a, v, beta, s, vs], [f, ca.jacobian(f, beta).T])
    return FUNCTIONS[key]


def mapped_force(spec: Spec, rows: int) -> ca.Function:
    """``force_function(spec)`` mapped over ``rows`` rows, kept: CasADi builds a new Function at each ``map`` (the EMPS
    diagnosis made 345 maps of a few; under the profiler they took 4.4 s of its 26 s). At most ``MAPPED_KEPT`` are
    kept (a process that reads logs of many lengths starts over)."""
    f = force_function(spec)
    key = (f.name(), rows)
    if key not in MAPPED:
        if len(MAPPED) >= MAPPED_KEPT:
            MAPPED.clear()
        MAPPED[key] = f.map(rows)
    return MAPPED[key]


def raw_columns(spec: Spec, p: Processed, s: float, vs: float) -> np.ndarray:
    """Regressor columns on the raw rows (exact: the force is linear in the coordinates; evaluated at 1)."""
    fm = mapped_force(spec, p.v_raw.size)
    _, J = fm(p.a_raw[None, :], p.v_raw[None, :], np.ones(len(spec.coords())), s, vs)
    return np.asarray(J, dtype=float).T


def columns(spec: Spec, p: Processed, s: float = 0.0, vs: float = 1.0) -> np.ndarray:
    J = raw_columns(spec, p, s, vs)
    return np.column_stack([p.dec(J[:, j]) for j in range(J.shape[1])])[p.keep]


@dataclass
class RigidModelFit:
    spec: Spec
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
    J: np.ndarray | None = None   # Jacobian of the prediction: the coordinates' columns (and Stribeck's two)

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

    def predict(self, p: Processed) -> np.ndarray:
        return columns(self.spec, p, self.s, self.vs) @ self.beta

    def predict_raw(self, p: Processed) -> np.ndarray:
        """The library's force on the raw rows, at the fitted parameters (CasADi ``rigid_force``)."""
        F, _ = mapped_force(self.spec, p.v_raw.size)(p.a_raw[None, :], p.v_raw[None, :], self.beta, self.s, self.vs)
        return np.asarray(F, dtype=float).ravel()


def linear_fit(spec: Spec, p: Processed, X: np.ndarray, s: float, vs: float, at_bound: bool = False) -> RigidModelFit:
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
        d_s = (columns(spec, p, s + h, vs) - columns(spec, p, s - h, vs)) @ beta / (2 * h)
        d_lv = (columns(spec, p, s, vs * math.exp(h)) - columns(spec, p, s, vs * math.exp(-h))) @ beta / (2 * h)
        J = np.column_stack([X, d_s, d_lv])
        names += ["stribeck_ratio", "log_stribeck_velocity"]
    try:
        cov, lag, _ = hac_covariance(J, e)
    except np.linalg.LinAlgError:
        cov, lag = np.full((J.shape[1], J.shape[1]), np.nan), -1
    return RigidModelFit(spec, list(spec.coords()), beta, ref, s, vs, X, e, y, cov, names, lag, info, at_bound, J)


def fit_spec(spec: Spec, p: Processed) -> RigidModelFit:
    if not spec.stribeck:
        return linear_fit(spec, p, columns(spec, p), 0.0, 1.0)
    # Stribeck: profile over log v_s (grid, then bounded refinement); the ratio s by a bounded 1-D search (the
    # columns are affine in s: X(s) = X0 + s X1); LS for the coordinates.
    y = p.y[p.keep]
    v99 = float(np.percentile(np.abs(p.v[p.keep]), 99))
    lo, hi = math.log(1e-3 * v99), math.log(0.5 * v99)

    def inner(lvs: float) -> tuple[float, float]:
        vs = math.exp(lvs)
        X0 = columns(spec, p, 0.0, vs)
        X1 = columns(spec, p, 1.0, vs) - X0

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

    grid = np.linspace(lo, hi, STRIBECK_GRID)
    prof = [inner(g) for g in grid]
    i = int(np.argmin([q[0] for q in prof]))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    res = so.minimize_scalar(lambda g: inner(g)[0], bounds=(a, b), method="bounded", options={"xatol": 1e-3})
    lvs = float(res.x) if res.fun < prof[i][0] else float(grid[i])
    _, s = inner(lvs)
    at_bound = s <= 1e-6 or lvs <= lo + 1e-6 or lvs >= hi - 1e-6
    vs = math.exp(lvs)
    return linear_fit(spec, p, columns(spec, p, s, vs), s, vs, at_bound=at_bound or s <= 1e-6)


def delta_method(fit: RigidModelFit, g: Any) -> tuple[float, float]:
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


def magnitude_of_fit(name: str, fit: RigidModelFit) -> tuple[float, float]:
    if name == "viscous_motor":
        if fit.spec.asym:
            return delta_method(fit, lambda b: (b["Fv_pos"] + b["Fv_neg"]) / 2)
        return delta_method(fit, lambda b: b["Fv"])
    if name == "asymmetric_friction":
        if fit.spec.viscous:   # the asymmetry the data carry is mostly viscous (PDF eq. 12): quote the larger one
            ac = delta_method(fit, lambda b: abs(b["Fc_pos"] - b["Fc_neg"]) / (b["Fc_pos"] + b["Fc_neg"]))
            av = delta_method(fit, lambda b: abs(b["Fv_pos"] - b["Fv_neg"]) / (b["Fv_pos"] + b["Fv_neg"]))
            return av if av[0] > ac[0] else ac
        return delta_method(fit, lambda b: abs(b["Fc_pos"] - b["Fc_neg"]) / (b["Fc_pos"] + b["Fc_neg"]))
    if name == "stribeck":
        if fit.stribeck_at_bound:
            return fit.s, math.nan
        return delta_method(fit, lambda b: b["stribeck_ratio"])
    raise KeyError(name)


# ----------------------------------------------------------------------------------- localisation -------------
