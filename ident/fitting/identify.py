"""Identification of the two-inertia drive (K*, J_l*, f_l*) from a logged torque / motor encoder / load sensor log.

Method (the exact model inside the fit, never a smoothed copy):

1. **Equation-error start** (no user guess). While the motor encoder stands still the motor is stuck, so the load
   obeys a_l = -(K_s/J_l) q_l - (f_l/J_l) sgn(v_l) + const per standstill: a linear least-squares fit on
   Savitzky-Golay derivatives gives w_l^2 = K_s/J_l and f_l/J_l. The derivative window follows the load's dominant
   frequency (found in the data) and the velocity threshold the load sensor's noise (estimated from the data). The
   remaining scale J_l* is found by a 1-D search of the output-error cost on the first window.
2. **Output error with CasADi + IPOPT**: the residuals are the FMU's simulation of the logged torque compared with
   the load sensor (weight 1/sigma_l) and the motor encoder (mid-count, weight sqrt(12)/count). The FMU is wrapped
   as a CasADi callback whose Jacobian is a finite-difference callback through the same FMU, and IPOPT gets the
   Gauss-Newton Hessian J^T J. Unknowns: ln K*, ln J_l*, ln f_l*, the initial deflection (as a fraction of the
   static band f_l/K_s, the log starting at rest); the load sensor's zero offset is projected out in closed form.
3. **Horizon continuation**: the output-error cost over a long log is rugged (small parameter changes reorder
   stick/slip events), a short window is smooth; the fit starts on a window of the first motion plus 8 ringing
   periods and grows it by 1.3 up to the whole log, each stage starting from the previous optimum after a cheap
   grid over scale x frequency, friction and initial deflection (``_scale_scan``).
4. **Uncertainty**: at the optimum, two covariances of the log-parameters: *noise-only* (sigma^2 (J^T J)^-1, the
   Cramer-Rao bound for the model and the estimated noise) and *sandwich* (residual-based, with blocks of samples
   to allow for correlated misfit: it grows when the model does not fit). The reported 95 % intervals use the
   larger of the two for each parameter.
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pandas as pd
from scipy.signal import savgol_filter

from ..common.plotting import figure, save
from ..model.params import DriveParams
from ..model.plant import Plant, PlantError
from .logs import DriveLog, LogError

NAMES = ("K_star", "J_l_star", "f_l_star")
BOUNDS = {"K_star": (1e3, 1e9), "J_l_star": (10.0, 1e6), "f_l_star": (1e-4, 100.0)}
Z95 = 1.959963984540054


class IdentificationError(RuntimeError):
    """The log cannot support the requested estimate (e.g. nothing moved)."""


class BudgetExceeded(RuntimeError):
    """A fit used up the simulations its caller allowed it (``OutputError.budget``)."""


class EvaluationBudget:
    """Simulations a fit may run, counted in samples simulated (a simulation of ``stop`` samples costs ``stop``), so
    that a budget means the same on any machine and for any window length; one budget can span the many problems of
    a continuation (``fit_pipeline``). ``limit`` None: unlimited (the count is still kept)."""

    def __init__(self, limit: float | None = None):
        self.limit = limit
        self.used = 0.0

    def charge(self, samples: int) -> None:
        """Count a simulation of ``samples`` samples; raise ``BudgetExceeded`` if the budget is spent already."""
        if self.limit is not None and self.used + samples > self.limit:
            raise BudgetExceeded(f"the fit used up its budget of {self.limit:.4g} simulated samples")
        self.used += samples


@dataclass
class Estimate:
    """A parameter estimate with its 95 % confidence interval."""

    value: float
    ci95: tuple[float, float]
    std: float  # standard deviation (delta method from the log-parameter covariance)

    def to_dict(self) -> dict[str, Any]:
        return {"value": self.value, "ci95": list(self.ci95), "std": self.std}


# ------------------------------------------------------------------------------------------- helpers -----------

def noise_std(y: np.ndarray) -> float:
    """White-noise level of a signal from its quiet stretches: std of second differences / sqrt(6) in windows of
    25 samples; the windows within 1.5x of the 10th percentile hold nothing but noise (a stuck body), and their
    median is the estimate. It is the identifier's starting weight and the equation-error start's velocity
    threshold; it reads 0-35 % high when the load rings most of the time (``white_noise_std`` does not)."""
    d2 = np.diff(y, 2)
    w = 25
    if d2.size < 4 * w:
        return float(np.std(d2) / math.sqrt(6))
    stds = d2[: d2.size // w * w].reshape(-1, w).std(axis=1, ddof=1)
    quiet = stds[stds <= 1.5 * np.percentile(stds, 10)]
    return float(np.median(quiet) / math.sqrt(6))


def white_noise_std(y: np.ndarray) -> float:
    """White-noise level of a sampled signal: the median absolute 4th difference / (0.6745 sqrt(70)).

    A 4th difference of white noise has the variance 70 sigma^2, while a motion slow against the sample rate nearly
    vanishes in it ((w dt)^4: 1e-4 of the amplitude for an 80 Hz ringing at 5 kHz); the median ignores the pulses'
    jumps. Unbiased to ~1 % on the synthetic logs, where ``noise_std`` was 0-35 % high. It assumes the signal is
    slow for at least half of the samples. The discrepancy workflow's noise floor uses it."""
    d4 = np.diff(np.asarray(y, dtype=float), 4)
    if d4.size == 0:
        return 0.0
    return float(np.median(np.abs(d4 - np.median(d4))) / 0.6744897501960817 / math.sqrt(70.0))


def dominant_frequency(segments: list[np.ndarray], rate_hz: float) -> float:
    """Frequency [Hz] of the largest spectral peak above 2 Hz of the (demeaned, concatenated) segments."""
    x = np.concatenate([s - s.mean() for s in segments])
    spec = np.abs(np.fft.rfft(x * np.hanning(x.size)))
    freq = np.fft.rfftfreq(x.size, 1.0 / rate_hz)
    band = np.flatnonzero(freq > 2.0)
    k = band[np.argmax(spec[band])]
    if 0 < k < spec.size - 1:  # parabolic interpolation of the log-spectrum around the peak bin
        a, b, c = np.log(spec[k - 1:k + 2] + 1e-300)
        k = k + 0.5 * (a - c) / (a - 2 * b + c)
    return float(k * rate_hz / x.size)


def standstill_runs(counts: np.ndarray, min_len: int) -> list[tuple[int, int]]:
    """Runs [start, stop) of at least ``min_len`` samples over which the encoder count does not change."""
    change = np.flatnonzero(np.diff(counts) != 0) + 1
    edges = np.concatenate([[0], change, [counts.size]])
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b - a >= min_len]


# ------------------------------------------------------------------------------------------- problem -----------

class OutputError:
    """Weighted residuals of the FMU simulation of (the first ``stop`` samples of) a log."""

    def __init__(self, log: DriveLog, base: DriveParams, stop: int | None = None, sigma_load: float | None = None):
        stop = log.n if stop is None else stop
        self.log, self.base, self.stop = log, base, stop
        self.count = base.count_rad
        self.torque = log.motor_torque_Nm[: stop - 1]
        self.y_l = log.load_pos_rad[:stop]
        self.y_m = log.motor_pos_rad[:stop] + 0.5 * self.count  # an encoder reading's expected value
        self.sigma_l = sigma_load if sigma_load is not None else max(noise_std(log.load_pos_rad), 1e-15)
        self.sigma_m = self.count / math.sqrt(12.0)
        self.plant = Plant(base)
        self.evaluations = 0
        self.budget: EvaluationBudget | None = None  # simulations allowed (None: unlimited)
        self.interrupted = False  # Ctrl-C arrived inside a simulation (CasADi wraps it into a RuntimeError)
        self.exhausted = False    # a simulation was refused by the budget
        self._cache: dict[bytes, np.ndarray] = {}

    def params(self, theta: np.ndarray) -> DriveParams:
        K, J, f = np.exp(theta[:3])
        return self.base.with_values(K_star=float(K), J_l_star=float(J), f_l_star=float(f))

    def simulate(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(q_m, q_l + offset, offset): the model's view of the log for parameters ``theta``."""
        p = self.params(theta)
        d0 = float(theta[3]) * p.f_l / p.K_s  # initial deflection, a fraction of the static band
        q_m0 = float(self.y_m[0])
        self.plant.reset(p, q_m_start=q_m0, q_l_start=p.r * q_m0 - d0, v_m_start=0.0, v_l_start=0.0)
        q_m, q_l = self.plant.positions(self.torque, self.log.dt)
        offset = float(np.mean(self.y_l - q_l))  # the load sensor's zero, projected out
        q_m = q_m + float(np.mean(self.y_m - q_m))  # and the encoder's unknown sub-count start position
        return q_m, q_l + offset, offset

    def load_residual_rms(self, theta: np.ndarray) -> float:
        """RMS of the load misfit [rad]: at the optimum of a model that fits, the load sensor's noise. It replaces
        the estimate from quiet stretches (too high for a load that never stops ringing) in the next stage."""
        n = self.y_l.size
        return max(float(np.sqrt(np.mean(self.residuals(theta)[:n] ** 2))) * self.sigma_l, 1e-15)

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        if self.interrupted:  # IPOPT may take an interrupted evaluation for a failed one and try another
            raise KeyboardInterrupt
        key = np.asarray(theta, dtype=float).tobytes()
        if key not in self._cache:
            if self.budget is not None:
                try:
                    self.budget.charge(self.stop)
                except BudgetExceeded:
                    self.exhausted = True
                    raise
            if len(self._cache) > 64:
                self._cache.clear()
            try:
                q_m, q_l, _ = self.simulate(np.asarray(theta, dtype=float))
            except KeyboardInterrupt:
                self.interrupted = True
                raise
            self.evaluations += 1
            self._cache[key] = np.concatenate([(q_l - self.y_l) / self.sigma_l, (q_m - self.y_m) / self.sigma_m])
        return self._cache[key]

    def clear_cache(self) -> None:
        """Forget the cached simulations (a grid visits each point once; keeping them only costs memory)."""
        self._cache.clear()

    def cost(self, theta: np.ndarray) -> float:
        """Sum of squared residuals, for grids and scans: inf where the FMU cannot simulate ``theta`` (a grid corner
        can make the state overflow; measured: a hardening grid point in a from-scratch candidate). Inside IPOPT
        such a failure is an evaluation error, and the line search steps back."""
        try:
            return float(np.sum(self.residuals(theta) ** 2))
        except PlantError:
            return math.inf

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        """Central differences through the FMU. A long log pins the parameters down to ~1e-7 (the ringing's phase
        accumulates), so the steps are far below that: 3e-8 in the log-parameters, 1e-6 of the static band for the
        initial deflection; central, so that a kink where a marginal stick/slip decision flips is averaged rather
        than taken from one side. The FMU's round-off (~1e-16 of the angles) stays ~1e-6 of the differences."""
        theta = np.asarray(theta, dtype=float)
        cols = []
        for i in range(theta.size):
            h = 3e-8 if i < 3 else 1e-6
            up, down = theta.copy(), theta.copy()
            up[i] += h
            down[i] -= h
            cols.append((self.residuals(up) - self.residuals(down)) / (2 * h))
        return np.column_stack(cols)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Box bounds of the unknowns."""
        return _bounds()

    def extra_scan(self, theta: np.ndarray) -> list[np.ndarray]:
        """Steps (whole-length vectors) that ``_scale_scan`` tries jointly on unknowns beyond the base four; the
        base problem has none."""
        return []

    def check_budget(self) -> None:
        """Re-raise what stopped a fit inside a CasADi callback: Ctrl-C, or a spent ``budget``."""
        if self.interrupted:
            raise KeyboardInterrupt
        if self.exhausted:
            raise BudgetExceeded(f"the fit used up its budget of {self.budget.limit:.4g} simulated samples")

    def close(self) -> None:
        self.plant.close()


def _residual_callback(problem: OutputError, n: int, m: int) -> Any:
    """The FMU's weighted residuals as a CasADi callback of theta (n unknowns, m residuals), whose Jacobian is a
    second callback: central differences through the same FMU (``OutputError.jacobian``)."""
    import casadi as ca

    class Jac(ca.Callback):
        def __init__(self, name: str):
            ca.Callback.__init__(self)
            self.construct(name, {})

        def get_n_in(self): return 2
        def get_n_out(self): return 1
        def get_sparsity_in(self, i): return ca.Sparsity.dense(n, 1) if i == 0 else ca.Sparsity.dense(m, 1)
        def get_sparsity_out(self, i): return ca.Sparsity.dense(m, n)
        def eval(self, arg): return [problem.jacobian(np.array(arg[0]).ravel())]

    class Res(ca.Callback):
        def __init__(self, name: str):
            ca.Callback.__init__(self)
            self.construct(name, {})

        def get_n_in(self): return 1
        def get_n_out(self): return 1
        def get_sparsity_in(self, i): return ca.Sparsity.dense(n, 1)
        def get_sparsity_out(self, i): return ca.Sparsity.dense(m, 1)
        def eval(self, arg): return [problem.residuals(np.array(arg[0]).ravel())]
        def has_jacobian(self): return True

        def get_jacobian(self, name, inames, onames, opts):
            self.jac_cb = Jac(name + "_fd")
            x, out = ca.MX.sym("x", n), ca.MX.sym("out", m)
            return ca.Function(name, [x, out], [self.jac_cb(x, out)], inames, onames)

    return Res("fmu_residuals")


def _stop_callback(n: int, stop: Callable[[], bool]) -> Any:
    """An IPOPT iteration callback that ends the solve (``User_Requested_Stop``) once ``stop()`` is true: a caller's
    budget in evaluations, checked between iterations rather than by raising inside a simulation."""
    import casadi as ca

    class Stop(ca.Callback):
        def __init__(self) -> None:
            ca.Callback.__init__(self)
            self.construct("stop", {})

        def get_n_in(self): return ca.nlpsol_n_out()
        def get_n_out(self): return 1
        def get_name_in(self, i): return ca.nlpsol_out(i)
        def get_name_out(self, i): return "stop"

        def get_sparsity_in(self, i):
            name = ca.nlpsol_out(i)
            if name == "f":
                return ca.Sparsity.scalar()
            return ca.Sparsity.dense(n) if name in ("x", "lam_x") else ca.Sparsity(0, 0)

        def eval(self, arg): return [1 if stop() else 0]

    return Stop()


def _gauss_newton_solver(res: Any, n: int, m: int, max_iter: int, stop: Any = None) -> Any:
    """IPOPT on 0.5 |r(theta)|^2 / m with the Gauss-Newton Hessian J^T J / m (r: the callback ``res``)."""
    import casadi as ca

    x = ca.MX.sym("theta", n)
    r = res(x)
    f = 0.5 * ca.sumsqr(r) / m
    jr = ca.jacobian(r, x)
    lam_f, lam_g, p = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", 0), ca.MX.sym("p", 0)
    hess = ca.Function("nlp_hess_l", [x, p, lam_f, lam_g], [ca.triu(lam_f * ca.mtimes(jr.T, jr) / m)])
    extra = {} if stop is None else {"iteration_callback": stop}
    return ca.nlpsol("output_error", "ipopt", {"x": x, "f": f},
                     {**extra, "hess_lag": hess, "print_time": False,
                      # The exact model's cost has micro-steps where a marginal stick/slip decision flips (a
                      # 1e-6 relative change of a parameter can reorder one event): stop once the objective no
                      # longer changes rather than insisting on a gradient below the finite-difference noise:
                      # three iterations in a row that change it by < 1e-8 (relative) end the fit, whatever the
                      # optimality error (measured on a 10 s log: the last stage sat at its optimum from iteration
                      # 22 to 40, its line search stuck at step 1e-11 on a kink, scaled dual infeasibility 3.6e-4;
                      # a from-scratch fit with an effect took 97 s, now 34 s, same optimum to 5e-9)
                      "ipopt": {"print_level": 0, "max_iter": max_iter, "tol": 1e-10, "mu_init": 1e-6,
                                "acceptable_tol": 1e19, "acceptable_obj_change_tol": 1e-8, "acceptable_iter": 3,
                                # backtrack fast: a failed step on a kink is not worth 40 halvings
                                "alpha_red_factor": 0.1,
                                "sb": "yes"}})


def fit_ipopt(problem: OutputError, theta0: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              max_iter: int = 40, stop: Callable[[], bool] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """min 0.5 |r(theta)|^2 / m with IPOPT; r is the FMU through a CasADi callback, Hessian Gauss-Newton.
    ``stop``: checked after every iteration; true ends the fit at that iterate (a caller's evaluation budget)."""
    n, m = theta0.size, problem.residuals(theta0).size
    res = _residual_callback(problem, n, m)
    stopper = None if stop is None else _stop_callback(n, stop)
    solver = _gauss_newton_solver(res, n, m, max_iter, stopper)
    try:
        sol = solver(x0=theta0, lbx=lower, ubx=upper)
    except RuntimeError:  # CasADi wraps an exception raised in a callback: say so if it was Ctrl-C or the budget
        problem.check_budget()
        raise
    # IPOPT may also take the refused evaluations for failed ones and stop early: that is not an optimum either
    problem.check_budget()
    stats = solver.stats()
    return np.array(sol["x"]).ravel(), {"status": stats["return_status"], "iterations": stats["iter_count"],
                                        "cost": float(sol["f"])}


# ------------------------------------------------------------------------------------------- start -----------

def equation_error_start(log: DriveLog, base: DriveParams) -> dict[str, float]:
    """w_l^2 = K_s/J_l and f_l/J_l from the load's motion while the motor stands still (see module docstring)."""
    rate = log.meta.sample_rate_hz
    y = log.load_pos_rad
    counts = np.round(log.motor_pos_rad / base.count_rad).astype(np.int64)
    runs = standstill_runs(counts, int(0.05 * rate))
    if not runs:
        raise IdentificationError("the motor encoder never stands still for 50 ms: the load's free ringing, which "
                                  "determines K*/J_l* and f_l*/J_l*, is not in this log")
    f_peak = dominant_frequency([y[s:e] for s, e in runs], rate)
    window = int(max(7, 2 * round(rate / (16.0 * f_peak)) + 1))  # ~1/8 of a ringing period, odd
    v = savgol_filter(y, window, 3, deriv=1, delta=log.dt)
    a = savgol_filter(y, window, 3, deriv=2, delta=log.dt)
    sigma_v = noise_std(y) * math.sqrt(12.0 / (window**3)) / log.dt  # LS slope noise over the window
    rows, cols_run, target = [], [], []
    # rows within a smoothing window of a stop or reversal are left out: there the friction force jumps and the
    # window smears the jump into the estimated acceleration
    slow = np.abs(v) <= 5 * sigma_v
    near_stop = np.convolve(slow.astype(float), np.ones(2 * window + 1), mode="same") > 0
    for j, (s, e) in enumerate(runs):
        idx = np.arange(s + window, e - window)
        idx = idx[~near_stop[idx]]
        rows.append(np.column_stack([-y[idx], -np.sign(v[idx])]))
        cols_run.append(np.full(idx.size, j))
        target.append(a[idx])
    if not rows or sum(r.shape[0] for r in rows) < 50:
        raise IdentificationError("the load sensor shows no ringing while the motor stands still: K*, J_l* and "
                                  "f_l* are not excited by this log (apply pulses and let the load ring)")
    X = np.vstack(rows)
    run_id = np.concatenate(cols_run)
    D = np.zeros((X.shape[0], len(runs)))
    D[np.arange(X.shape[0]), run_id] = 1.0
    coef, *_ = np.linalg.lstsq(np.hstack([X, D]), np.concatenate(target), rcond=None)
    w2_ls, f_over_J = float(coef[0]), float(coef[1])
    if not w2_ls > 0:
        raise IdentificationError("equation-error start found no restoring spring in the load's motion")
    # the spectral peak of the free ringing gives w_l^2 without the smoothing filter's attenuation
    w2 = (2 * math.pi * f_peak) ** 2
    return {"w_l2": w2, "w_l2_ls": w2_ls, "f_l_over_J_l": max(f_over_J, 1e-12), "f_peak_hz": f_peak,
            "window": window, "velocity_threshold": 5 * sigma_v, "rows": int(X.shape[0])}


def _theta(base: DriveParams, J_l_star: float, w2: float, f_over_J: float, d0_frac: float = 0.0) -> np.ndarray:
    J_l = J_l_star * base.J_m
    K_star = w2 * J_l / base.f_m
    f_l_star = f_over_J * J_l / base.f_m
    return np.array([math.log(K_star), math.log(J_l_star), math.log(f_l_star), d0_frac])


def _bounds() -> tuple[np.ndarray, np.ndarray]:
    # The initial deflection is physically within +-1 band; the bound is kept loose so that its barrier term does
    # not compete with a cost whose gradient near the optimum is tiny.
    lo = np.array([math.log(BOUNDS[k][0]) for k in NAMES] + [-50.0])
    hi = np.array([math.log(BOUNDS[k][1]) for k in NAMES] + [50.0])
    return lo, hi


# ------------------------------------------------------------------------------------------- result -----------

@dataclass
class TwoInertiaFit:
    """Result of ``identify(log)`` for the two-inertia model."""

    estimates: dict[str, Estimate]
    params: DriveParams
    theta: np.ndarray
    cov_sandwich: np.ndarray       # covariance of (ln K*, ln J_l*, ln f_l*): residual-based (reported intervals)
    cov_noise_only: np.ndarray     # sigma^2 (J^T J)^-1: the Cramer-Rao bound for this model and noise level
    fit: dict[str, float]
    warnings: list[str]
    start: dict[str, float]
    stages: list[dict[str, Any]]
    load_offset_rad: float
    sigma_load_rad: float
    elapsed_s: float
    simulated: dict[str, np.ndarray] = field(repr=False, default_factory=dict)

    @property
    def correlation(self) -> pd.DataFrame:
        s = np.sqrt(np.diag(self.cov_sandwich))
        return pd.DataFrame(self.cov_sandwich / np.outer(s, s), index=list(NAMES), columns=list(NAMES))

    def si(self) -> dict[str, float]:
        p = self.params
        return {"K_s_Nm_per_rad": p.K_s, "J_l_kgm2": p.J_l, "f_l_Nm": p.f_l, "J_m_kgm2": p.J_m, "f_m_Nm": p.f_m,
                "r": p.r}

    def to_frame(self) -> pd.DataFrame:
        rows = []
        for name in NAMES:
            e = self.estimates[name]
            rows.append({"parameter": name, "value": e.value, "ci95_lo": e.ci95[0], "ci95_hi": e.ci95[1],
                         "std": e.std, "rel_std_pct": 100 * e.std / e.value})
        return pd.DataFrame(rows)

    def to_dict(self) -> dict[str, Any]:
        return {**{k: e.to_dict() for k, e in self.estimates.items()}, "si": self.si(), "fit": self.fit,
                "warnings": self.warnings, "covariance": "sandwich (residual-based, blocks of samples); "
                "noise-only Cramer-Rao std in cramer_rao_std",
                "cramer_rao_std": dict(zip(NAMES, (np.sqrt(np.diag(self.cov_noise_only))
                                                   * np.array([self.estimates[k].value for k in NAMES])).tolist())),
                "correlation": self.correlation.round(4).to_dict(), "start": self.start, "stages": self.stages,
                "load_offset_rad": self.load_offset_rad, "sigma_load_rad": self.sigma_load_rad,
                "elapsed_s": self.elapsed_s}

    def plot(self, path: str | Path) -> Path:
        """Measured vs fitted load angle and the residual, as a PNG at ``path``."""
        sim = self.simulated
        fig, (a1, a2) = figure(2, 1, size=(10, 6), sharex=True)
        a1.plot(sim["time_s"], sim["load_measured"] * 1e6, lw=0.6, label="measured")
        a1.plot(sim["time_s"], sim["load_model"] * 1e6, lw=0.6, label="fitted model (FMU)")
        a1.set_ylabel("load angle [urad]")
        a1.legend()
        a2.plot(sim["time_s"], (sim["load_model"] - sim["load_measured"]) * 1e9, lw=0.5)
        a2.set_ylabel("residual [nrad]")
        a2.set_xlabel("time [s]")
        return save(fig, path)


def covariances(problem: OutputError, theta: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    J = problem.jacobian(theta)
    r = problem.residuals(theta)
    info = J.T @ J
    inv = np.linalg.pinv(info)
    m, n = J.shape
    dof = max(m - n, 1)
    noise_only = inv * (float(r @ r) / dof)  # residual variance ~ 1 when the model and noise level are right
    # sandwich with blocks: residual correlation inside a block (misfit has structure) is accounted for
    meat = np.zeros((n, n))
    half = problem.y_l.size
    for part in (slice(0, half), slice(half, m)):
        Jp, rp = J[part], r[part]
        for s in range(0, Jp.shape[0], block):
            g = Jp[s:s + block].T @ rp[s:s + block]
            meat += np.outer(g, g)
    sandwich = inv @ meat @ inv * (m / dof)
    return noise_only, sandwich, J


def _scale_scan(problem: OutputError, theta: np.ndarray, lo: np.ndarray, hi: np.ndarray, stage: int,
                f_peak_hz: float) -> np.ndarray:
    """Best point of a grid around ``theta`` over the scale J_l* (K* and f_l* scaled with it, so that the ringing
    frequency and the Coulomb decay stay put), the friction f_l* alone, and the ringing frequency (K* alone).

    A short window pins the frequency and the decay but hardly the scale, which only the motor's longer slides
    reveal; a longer window narrows the frequency's basin to about one period of phase over the window. The grid
    spans what the previous, shorter window left open: the scale and friction spans halve at every stage, the
    frequency span is a third of a period of phase over the new window."""
    span_J = max(1.05, 3.0 ** (0.5 ** (stage - 1)))
    span_f = max(1.05, 2.0 ** (0.5 ** (stage - 1)))
    periods = max(1.0, f_peak_hz * problem.stop / problem.log.meta.sample_rate_hz)
    span_w2 = 2.0 / (3.0 * periods)  # relative span of w^2 = 2 x relative span of w
    best, best_cost = theta, problem.cost(theta)

    def scan(steps: list[np.ndarray]) -> None:
        nonlocal best, best_cost
        base = best
        for step in steps:
            cand = np.clip(base + np.pad(step, (0, base.size - step.size)), lo, hi)
            cost = problem.cost(cand)
            if cost < best_cost:
                best, best_cost = cand, cost
        problem.clear_cache()

    # scale and frequency together (they trade off in the both-slipping phases), then the friction
    scan([np.array([ln_a + ln_c, ln_a, ln_a, 0.0]) for ln_a in np.log(np.geomspace(1 / span_J, span_J, 13))
          for ln_c in np.log1p(np.linspace(-span_w2, span_w2, 7))])
    scan([np.array([0.0, 0.0, ln_b, 0.0]) for ln_b in np.log(np.geomspace(1 / span_f, span_f, 9))])
    # further unknowns (an effect's) whose cost is a staircase, e.g. Stribeck's static level deciding which pulse
    # breaks away: a new window's first such event needs a jump that the gradient cannot make
    scan(problem.extra_scan(best))
    # the initial deflection (a fraction of the static band) shapes the load's first breakaway; a wrong one is a
    # local minimum that the other parameters cannot compensate
    scan([np.array([0.0, 0.0, 0.0, d - best[3]]) for d in np.linspace(-1.0, 1.0, 21)])
    return best


def _first_window(log: DriveLog, sigma_l: float, f_peak: float, periods: float) -> int:
    """End of the first fitting window: the first motion plus ``periods`` ringing periods. Short on purpose: the
    start's few-% error in the ringing frequency must not add up to a whole period of phase inside it."""
    moved = np.flatnonzero((np.abs(log.load_pos_rad - log.load_pos_rad[0]) > 20 * sigma_l)
                           | (np.abs(log.motor_pos_rad - log.motor_pos_rad[0]) > 0))
    if moved.size == 0:
        raise IdentificationError("nothing moves in this log: neither the motor encoder nor the load sensor "
                                  "changes beyond its noise; K*, J_l* and f_l* cannot be estimated")
    return int(min(log.n, max(200, moved[0] + periods * log.meta.sample_rate_hz / f_peak)))


def identify(log: DriveLog, *, model: str = "two-inertia", progress: bool = False,
             first_window_periods: float = 8.0, max_iter: int = 40, stage_iter: int = 12,
             growth: float = 1.3) -> TwoInertiaFit:
    """Estimate K*, J_l*, f_l* (two-inertia model) or the rigid model (``model="rigid"``) from ``log``."""
    if model == "rigid":
        from .rigid import identify_rigid

        return identify_rigid(log)  # type: ignore[return-value]
    if model != "two-inertia":
        raise ValueError(f"model = {model!r}: use 'two-inertia' or 'rigid'")
    if log.load_pos_rad is None:
        raise LogError(f"{log.source}: the two-inertia model needs the column load_pos_rad (a load sensor); "
                       "use model='rigid' for motor-encoder-only drives")
    meta = log.meta
    if meta.J_m_kgm2 is None or meta.f_m_Nm is None or meta.encoder_counts_per_rev is None:
        raise LogError(f"{log.source}: the two-inertia fit needs J_m_kgm2, f_m_Nm and encoder_counts_per_rev in "
                       "the sidecar")
    t0 = time.perf_counter()
    base = DriveParams(J_m=meta.J_m_kgm2, f_m=meta.f_m_Nm, r=meta.r, arm_length=meta.arm_length_m,
                       encoder_counts_per_rev=meta.encoder_counts_per_rev)
    problem, theta, sigma_l, start, stages = fit_pipeline(log, base, OutputError, np.zeros(0), progress=progress,
                                                          first_window_periods=first_window_periods,
                                                          max_iter=max_iter, stage_iter=stage_iter, growth=growth)
    try:
        return _result(log, problem, theta, start, stages, sigma_l, start["sigma_quiet_rad"], time.perf_counter() - t0)
    finally:
        problem.close()


def fit_pipeline(log: DriveLog, base: DriveParams, make: Callable[..., OutputError], extra: np.ndarray, *,
                 progress: bool = False, first_window_periods: float = 8.0, max_iter: int = 40, stage_iter: int = 12,
                 growth: float = 1.3) -> tuple[OutputError, np.ndarray, float, dict[str, Any], list[dict[str, Any]]]:
    """Steps 1-3 of the module docstring for any output-error problem ``make(log, base, stop, sigma_l)`` whose
    unknowns are ``[ln K*, ln J_l*, ln f_l*, d0/band]`` followed by ``extra`` (held at its given value by the grids,
    fitted by IPOPT; the discrepancy workflow passes its effects' unknowns there; a 2-D ``extra`` gives
    alternatives that the first window's grid searches too). Returns the whole-log problem
    (open), the optimum, the load residual level, the start and the stages."""
    start = equation_error_start(log, base)
    sigma_quiet = start["sigma_quiet_rad"] = max(noise_std(log.load_pos_rad), 1e-15)
    stop = _first_window(log, sigma_quiet, start["f_peak_hz"], first_window_periods)
    theta, sigma_l, stages = _first_stage(log, base, start, stop, sigma_quiet, max_iter, make, extra)
    problem, theta, sigma_l = _continuation(log, base, start, theta, sigma_l, stages, stop, growth, stage_iter,
                                            max_iter, progress, make)
    return problem, theta, sigma_l, start, stages


def _first_stage(log: DriveLog, base: DriveParams, start: dict[str, float], stop: int, sigma_l: float,
                 max_iter: int, make: Callable[..., OutputError] = OutputError,
                 extra: np.ndarray = np.zeros(0)) -> tuple[np.ndarray, float, list[dict[str, Any]]]:
    """The first window. The equation-error start fixes w_l^2 to a few % and f_l/J_l to a factor ~2, not the scale
    J_l*: search the output-error cost over a grid (J_l* x friction factor x frequency factor), run IPOPT from the
    three best grid points and keep the best optimum. Records the grid's best point in ``start``. ``extra``: the
    further unknowns, one row per alternative to put in the grid too (then without the frequency factor)."""
    first = make(log, base, stop, sigma_l)
    lo, hi = first.bounds()
    extras = np.atleast_2d(np.asarray(extra, dtype=float))
    try:
        grid = []
        for row in extras:
            for J in np.geomspace(50.0, 5e4, 25):
                for fm in np.geomspace(1 / 3, 3, 7):
                    for wm in ((0.97, 1.0, 1.03) if len(extras) == 1 else (1.0,)):
                        th = np.clip(np.concatenate([_theta(base, J, start["w_l2"] * wm,
                                                            start["f_l_over_J_l"] * fm), row]), lo, hi)
                        grid.append((first.cost(th), tuple(th)))
                        first.clear_cache()
        grid.sort()
        start.update(zip(NAMES, map(float, np.exp(np.array(grid[0][1][:3])))))
        fits = [fit_ipopt(first, np.array(th), lo, hi, max_iter) for _, th in grid[:3]]
        theta, info = min(fits, key=lambda f: f[1]["cost"])
        stage = {"window_s": stop / log.meta.sample_rate_hz, **info, "evaluations": first.evaluations,
                 "multistart": 3, **dict(zip(NAMES, map(float, np.exp(theta[:3]))))}
        return theta, first.load_residual_rms(theta), [stage]
    finally:
        first.close()


def _continuation(log: DriveLog, base: DriveParams, start: dict[str, float], theta: np.ndarray, sigma_l: float,
                  stages: list[dict[str, Any]], stop: int, growth: float, stage_iter: int, final_iter: int,
                  progress: bool, make: Callable[..., OutputError] = OutputError
                  ) -> tuple[OutputError, np.ndarray, float]:
    """Grow the window by ``growth`` up to the whole log, each stage a scan then IPOPT from the previous optimum
    (``stage_iter`` iterations; the whole log, whose optimum is the answer, ``final_iter``); returns the whole-log
    problem (open), the optimum and the load residual level."""
    rate = log.meta.sample_rate_hz
    while True:
        stop = min(log.n, int(growth * stop))
        if growth * stop >= log.n:  # the next stage would add only a sliver: take the whole log now
            stop = log.n
        problem = make(log, base, stop, sigma_l)
        lo, hi = problem.bounds()
        theta = _scale_scan(problem, theta, lo, hi, len(stages), start["f_peak_hz"])
        # each stage starts at the previous optimum, where Gauss-Newton needs a handful of iterations; more only
        # chase the finite-difference noise of a cost with many stick/slip kinks. The last stage may need more: a
        # model with a narrow basin (e.g. Stribeck's ratio x velocity) can still be walking towards the optimum
        # after ``stage_iter`` (measured: 12 left the residual 1700x the noise, 33 reached it); IPOPT stops by
        # itself once the objective no longer changes.
        theta, info = fit_ipopt(problem, theta, lo, hi, final_iter if stop >= log.n else stage_iter)
        stages.append({"window_s": stop / rate, **info, "evaluations": problem.evaluations,
                       **dict(zip(NAMES, map(float, np.exp(theta[:3]))))})
        if progress:
            print(f"  window {stop / rate:6.2f} s: {info['status']}, {info['iterations']} iterations, "
                  f"K* {math.exp(theta[0]):.6g}, J_l* {math.exp(theta[1]):.6g}, f_l* {math.exp(theta[2]):.6g}",
                  file=sys.stderr)
        # at the optimum of a model that fits, the load misfit is the sensor's noise: the next stage's weight
        sigma_l = problem.load_residual_rms(theta)
        if stop >= log.n:
            return problem, theta, sigma_l
        problem.close()


def _result(log: DriveLog, problem: OutputError, theta: np.ndarray, start: dict[str, float],
            stages: list[dict[str, Any]], sigma_l: float, sigma_quiet: float, elapsed: float) -> TwoInertiaFit:
    """Estimates with intervals, fit quality and warnings at the whole-log optimum."""
    block = max(10, int(log.meta.sample_rate_hz / max(start["f_peak_hz"], 1.0)))  # one ringing period
    cov_noise, cov_sand, _ = covariances(problem, theta, block)
    q_m, q_l, offset = problem.simulate(theta)
    cov_noise, cov_sand = cov_noise[:3, :3], cov_sand[:3, :3]
    std_ln = np.sqrt(np.maximum(np.diag(cov_sand), np.diag(cov_noise)))
    estimates = {}
    for i, name in enumerate(NAMES):
        v = float(math.exp(theta[i]))
        half = min(Z95 * float(std_ln[i]), 700.0)  # a parameter the log does not determine: (0, inf), not a crash
        estimates[name] = Estimate(v, (v * math.exp(-half), v * math.exp(half)),
                                   v * float(std_ln[i]))
    y_l, y_m = problem.y_l, problem.y_m
    fit = {"nrmse_load": float(np.sqrt(np.mean((q_l - y_l) ** 2)) / np.std(y_l)),
           "nrmse_motor": float(np.sqrt(np.mean((q_m - y_m) ** 2)) / np.std(y_m)),
           "relative_error_pct": float(100 * np.linalg.norm(q_l - y_l) / np.linalg.norm(y_l - y_l.mean())),
           "residual_rms_load_rad": float(np.sqrt(np.mean((q_l - y_l) ** 2))),
           "residual_over_noise": float(np.sqrt(np.mean((q_l - y_l) ** 2)) / sigma_quiet)}
    return TwoInertiaFit(estimates, problem.params(theta), theta, cov_sand, cov_noise, fit,
                         _warnings(estimates, fit, at_bound(theta)),
                         start, stages, offset, sigma_l, elapsed,
                         {"time_s": log.time_s, "load_measured": y_l, "load_model": q_l, "motor_model": q_m})


def at_bound(theta: np.ndarray) -> list[str]:
    """The names of K*, J_l*, f_l* within 5 % of their bound (``BOUNDS``) in ``theta``: the fit did not find an
    optimum of the model inside the physical range, it leaned on the box (IPOPT's barrier keeps it a few % off)."""
    lo, hi = _bounds()
    return [name for i, name in enumerate(NAMES) if min(theta[i] - lo[i], hi[i] - theta[i]) < 0.05]


def _warnings(estimates: dict[str, Estimate], fit: dict[str, float], bound: list[str]) -> list[str]:
    out = [f"{name} = {estimates[name].value:.4g} sits at its bound {BOUNDS[name]}: the model cannot fit this "
           "log inside the physical range (an effect is missing, or the sidecar's J_m, f_m, r are wrong)"
           for name in bound]
    for name, e in estimates.items():
        rel = e.std / e.value
        if rel > 0.05:
            out.append(f"{name} is poorly determined by this log (1-sigma {100 * rel:.1f} %): the excitation does "
                       "not separate it; add pulses of several amplitudes and slow torque ramps")
    if fit["residual_over_noise"] > 3:
        out.append(f"the fitted model leaves residuals {fit['residual_over_noise']:.1f}x the load sensor noise: "
                   "an effect missing from the base model (see `hdrive diagnose`); the intervals are residual-based")
    return out
