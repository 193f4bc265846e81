"""The rigid model's IDIM-LS identifier (inverse dynamic identification model, least squares), for any motor-only
log: a linear axis (positions in m, forces in N) or a rotary one.

Model (the EMPS PDF, eq. 1 and 7; Janot, Gautier, Brunot, "Data Set and Reference Models of EMPS")::

    tau = M q'' + Fv q' + Fc sign(q') + offset

**IDIM-LS** (PDF section 3, and the ``Script_IDIM_LS`` it describes), implemented by :func:`identify_rigid`:

1. ``qm`` is low-pass filtered forward and backward (zero phase) by a Butterworth filter of order 4 whose cut-off
   follows the PDF's rule ``w_fq >= 5 w_dyn``; velocity and acceleration are central differences of the filtered
   position (``diffcent`` twice); the first ``n_border - 1 = 49`` samples are dropped for the edge effects.
2. The observation matrix ``[q'' q' sign(q') 1]`` and the force ``gtau * vir`` are decimated *in parallel*
   (each column the same way): an order-8 Chebyshev-I low-pass (0.05 dB ripple) at ``0.8 f_nyq / n_d`` applied
   forward and backward, then one sample in ``n_d``, where ``n_d = round(0.8 f_nyq / (2 f_dyn))`` realises the rule
   ``w_Fp >= 2 w_dyn``. This is MATLAB's ``decimate`` (the script's tool): its filtfilt padding and its choice of
   the kept samples (the phase that ends on the last sample) are reproduced; ``scipy.signal.decimate`` keeps the
   phase that starts on the first sample and pads differently, which moves the estimates by up to 0.05 % and
   the relative error from 4.083 % to 4.137 %.
3. Least squares on the decimated system, solved with CasADi + IPOPT (the cost ``0.5 ||Phi theta - y||^2`` built
   with SX) and checked against ``numpy.linalg.lstsq``.

``w_dyn``, the natural frequency of the highest closed-loop mode: for a closed-loop log with the position loop's
constants (``gtau, kp, kv`` in ``meta_extra``, as :func:`ident.studies.emps.load_emps` gives them) it starts at the
PDF's 20 Hz (section 1.3: "the bandwidth of the position loop equal to 20 Hz"; the script uses the same number) and
is checked after the fit against the identified closed loop, ``M s^2 + (Fv + gtau kv) s + gtau kv kp``, whose natural
frequency ``sqrt(gtau kv kp / M) / 2 pi`` is 19.1 Hz on DATA_EMPS, so the rules hold; if they did not, the fit is
repeated with ``w_dyn`` set to that frequency. Any other log: the frequency below which 99 % of the motor velocity's
power lies (:func:`generic_idim_settings`), and only the rows where the axis clearly slides. Nothing about the
filters is user-supplied.

**Uncertainty** (:class:`RigidParam`): two covariances of the estimates are given side by side.

- *LS* (``std_ls``, ``ci95_ls``): ``sigma^2 (Phi^T Phi)^-1`` with ``sigma^2 = ||e||^2 / (N - 4)``: the textbook
  (Gautier) value, valid if the decimated residuals are white and the model is right. ``std_matlab`` is the
  script's slightly different formula ``std(e) sqrt(diag((Phi^T Phi)^-1))`` that the PDF prints.
- *HAC* (``std_hac``, ``ci95_hac``): the residual-based sandwich ``(Phi^T Phi)^-1 S (Phi^T Phi)^-1`` with a
  Newey-West (Bartlett) long-run covariance ``S`` of the scores ``phi_i e_i``, lag chosen from the data by
  Andrews' AR(1) plug-in rule. It does not assume the model is right: the correlated misfit of the symmetric friction
  model (the PDF's section 4 shows the friction is asymmetric) widens it, and it is the one to quote.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.signal as sg
import scipy.stats

from .logs import DriveLog, LogError

__all__ = ["CrossValidation", "IdimSettings", "RigidFit", "RigidParam", "closed_loop_gains", "generic_idim_settings",
           "identify_rigid", "idim_settings", "rigid_warnings", "validate_rigid"]

PARAM_NAMES = ("M", "Fv", "Fc", "offset")
PARAM_UNITS = {"M": "kg", "Fv": "N s/m", "Fc": "N", "offset": "N"}
PDF_LOOP_BANDWIDTH_HZ = 20.0   # PDF section 1.3: "the bandwidth of the position loop equal to 20 Hz"
BUTTER_ORDER = 4               # the script's Butterworth order (PDF 3.1: "usually a Butterworth one")
N_BORDER = 50                  # the script drops samples 1..49 (MATLAB indexing) for diffcent's edge effects
_Z95 = 1.959963984540054

def closed_loop_gains(log: DriveLog) -> tuple[float, float, float]:
    """(gtau, kp, kv): the position loop's constants of a closed-loop linear-axis log (as ``load_emps`` gives
    them), whose identified natural frequency sets the IDIM-LS filter rules; LogError naming what is missing."""
    if log.kind != "linear":
        raise LogError(f"{log.source}: the EMPS rigid model is for a linear-axis log (kind='linear'), got {log.kind!r}")
    missing = [k for k in ("gtau", "kp", "kv") if k not in log.meta_extra]
    if missing:
        raise LogError(f"{log.source}: meta_extra lacks {', '.join(missing)} (load the file with load_emps)")
    if "qg" not in log.extra:
        raise LogError(f"{log.source}: extra lacks the position reference 'qg' (load the file with load_emps)")
    return log.meta_extra["gtau"], log.meta_extra["kp"], log.meta_extra["kv"]


# ------------------------------------------------------------------------------------- IDIM-LS pieces -----------

@dataclass(frozen=True)
class IdimSettings:
    """Filter and decimation settings of the IDIM-LS procedure, derived from the sample rate and ``f_dyn_hz``."""

    sample_rate_hz: float
    f_dyn_hz: float              # natural frequency of the highest closed-loop mode (w_dyn)
    butter_order: int            # Butterworth order (4, as the script)
    butter_cutoff_hz: float      # w_fq = 5 w_dyn
    decim_band_hz: float         # w_Fp = 2 w_dyn
    decim_factor: int            # n_d = round(0.8 f_nyq / w_Fp)
    n_border: int                # samples 1 .. n_border-1 (MATLAB numbering) are dropped
    f_dyn_source: str

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def idim_settings(sample_rate_hz: float, f_dyn_hz: float = PDF_LOOP_BANDWIDTH_HZ,
                  f_dyn_source: str = "PDF 1.3: position-loop bandwidth 20 Hz") -> IdimSettings:
    """The PDF's rules: Butterworth cut-off 5 w_dyn, decimation band 2 w_dyn, n_d = round(0.8 f_nyq / (2 w_dyn))."""
    f_nyq = sample_rate_hz / 2.0
    cutoff = 5.0 * f_dyn_hz
    band = 2.0 * f_dyn_hz
    if cutoff >= f_nyq:
        raise ValueError(f"Butterworth cut-off 5 w_dyn = {cutoff:g} Hz is not below the Nyquist frequency "
                         f"{f_nyq:g} Hz: the log is sampled too slowly for the IDIM-LS rules")
    nd = max(1, int(round(0.8 * f_nyq / band)))
    return IdimSettings(sample_rate_hz, f_dyn_hz, BUTTER_ORDER, cutoff, band, nd, N_BORDER, f_dyn_source)


def _matlab_filtfilt(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """MATLAB's filtfilt: odd reflection of 3 * (filter order) samples at each end, steady-state initial state."""
    return sg.filtfilt(b, a, x, padtype="odd", padlen=3 * (max(len(a), len(b)) - 1))


def decimate(x: np.ndarray, r: int) -> np.ndarray:
    """MATLAB's ``decimate(x, r)``: order-8 Chebyshev-I low-pass (0.05 dB) at 0.8 / r of Nyquist, forward and
    backward, then every r-th sample of the phase that ends on the last sample."""
    if r == 1:
        return np.asarray(x, dtype=float).copy()
    rip, order = 0.05, 8
    b, a = sg.cheby1(order, rip, 0.8 / r)
    while order > 1:  # MATLAB lowers the order while the design is numerically off at the edge of the band
        _, h = sg.freqz(b, a, worN=[0.8 / r * np.pi])
        if np.all(b != 0) and abs(20 * np.log10(abs(h[0])) + rip) <= 1e-6:
            break
        order -= 1
        b, a = sg.cheby1(order, rip, 0.8 / r)
    y = _matlab_filtfilt(b, a, x)
    nd = x.size
    nout = -(-nd // r)
    nbeg = r - (r * nout - nd)          # MATLAB 1-based index of the first kept sample
    return y[nbeg - 1::r]


def _diffcent(x: np.ndarray, h: float) -> np.ndarray:
    """Central differences (one-sided at the two ends)."""
    d = np.empty_like(x)
    d[1:-1] = (x[2:] - x[:-2]) / (2.0 * h)
    d[0] = (x[1] - x[0]) / h
    d[-1] = (x[-1] - x[-2]) / h
    return d


def filtered_states(qm: np.ndarray, s: IdimSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Zero-phase Butterworth position and its central-difference velocity and acceleration (full length)."""
    b, a = sg.butter(s.butter_order, s.butter_cutoff_hz / (s.sample_rate_hz / 2.0))
    q_f = _matlab_filtfilt(b, a, qm)
    dq_f = _diffcent(q_f, 1.0 / s.sample_rate_hz)
    ddq_f = _diffcent(dq_f, 1.0 / s.sample_rate_hz)
    return q_f, dq_f, ddq_f


@dataclass
class _Idim:
    X0: np.ndarray      # raw observation matrix (after the border cut, before decimation)
    X: np.ndarray       # decimated observation matrix
    y: np.ndarray       # decimated force
    t: np.ndarray       # times of the decimated rows


def idim_system(log: DriveLog, s: IdimSettings) -> _Idim:
    _, dq_f, ddq_f = filtered_states(log.motor_pos_rad, s)
    k0 = s.n_border - 1
    dq, ddq = dq_f[k0:], ddq_f[k0:]
    X0 = np.column_stack([ddq, dq, np.sign(dq), np.ones_like(dq)])
    X = np.column_stack([decimate(X0[:, j], s.decim_factor) for j in range(X0.shape[1])])
    y = decimate(log.motor_torque_Nm[k0:], s.decim_factor)
    td = log.time_s[k0:]
    nout = -(-td.size // s.decim_factor)
    t = td[s.decim_factor - (s.decim_factor * nout - td.size) - 1::s.decim_factor]
    return _Idim(X0, X, y, t)


def solve_ls_casadi(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
    """min 0.5 ||X theta - y||^2 with CasADi (SX cost) + IPOPT, in column- and output-normalised variables."""
    import casadi as ca

    p = X.shape[1]
    cn = np.linalg.norm(X, axis=0)
    cn[cn == 0] = 1.0
    ys = float(np.linalg.norm(y)) or 1.0
    z = ca.SX.sym("z", p)
    r = ca.mtimes(ca.DM(X / cn), z) - ca.DM(y / ys)
    nlp = {"x": z, "f": 0.5 * ca.dot(r, r)}
    opts = {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-14,
            "ipopt.acceptable_tol": 1e-12}
    solver = ca.nlpsol("idim_ls", "ipopt", nlp, opts)
    sol = solver(x0=np.zeros(p))
    st = solver.stats()
    if not st.get("success", False):
        raise RuntimeError(f"IPOPT did not solve the IDIM-LS problem: {st.get('return_status')}")
    theta = np.asarray(sol["x"], dtype=float).ravel() * ys / cn
    return theta, {"solver": "casadi/ipopt", "return_status": st.get("return_status"),
                   "iterations": int(st.get("iter_count", -1))}


def hac_covariance(X: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, int, float]:
    """Newey-West (Bartlett) sandwich covariance of the LS estimate, Andrews (1991) AR(1) plug-in bandwidth.

    Returns (covariance, lag, bandwidth)."""
    n, p = X.shape
    g = X * e[:, None]                                     # scores
    num = den = 0.0
    for a in range(p):
        x0, x1 = g[:-1, a], g[1:, a]
        rho = float(np.dot(x0, x1) / np.dot(x0, x0)) if np.dot(x0, x0) > 0 else 0.0
        rho = min(max(rho, -0.99), 0.99)
        s2 = float(np.mean((x1 - rho * x0) ** 2))
        num += 4 * rho**2 * s2**2 / ((1 - rho) ** 6 * (1 + rho) ** 2)
        den += s2**2 / (1 - rho) ** 4
    alpha = num / den if den > 0 else 0.0
    bw = 1.1447 * (alpha * n) ** (1.0 / 3.0)
    lag = int(min(math.floor(bw), n // 4))
    S = g.T @ g
    for j in range(1, lag + 1):
        w = 1.0 - j / (lag + 1.0) if bw <= 0 else 1.0 - j / bw
        if w <= 0:
            break
        G = g[j:].T @ g[:-j]
        S += w * (G + G.T)
    A = np.linalg.inv(X.T @ X)
    cov = A @ S @ A * n / (n - p)
    return 0.5 * (cov + cov.T), lag, bw


def _corr(cov: np.ndarray) -> np.ndarray:
    d = np.sqrt(np.diag(cov))
    return cov / np.outer(d, d)


# ----------------------------------------------------------------------------------------- results -------------

@dataclass
class RigidParam:
    """One estimate with two uncertainties.

    ``std_ls`` / ``ci95_ls``: classical LS, ``sigma^2 (Phi^T Phi)^-1``, ``sigma^2 = ||e||^2/(N-4)``, Student t
    interval (white residuals, model assumed right). ``std_hac`` / ``ci95_hac``: residual-based Newey-West sandwich
    (serially correlated residuals and model mismatch allowed), normal interval. ``std_matlab``: the script's
    ``std(e) sqrt(diag((Phi^T Phi)^-1))`` as printed in the PDF.
    """

    name: str
    unit: str
    value: float
    std_ls: float
    ci95_ls: tuple[float, float]
    std_hac: float
    ci95_hac: tuple[float, float]
    std_matlab: float

    @property
    def rel_std_hac_pct(self) -> float:
        return 100.0 * self.std_hac / abs(self.value)

    def to_dict(self) -> dict[str, Any]:
        return {"value": self.value, "unit": self.unit, "std_ls": self.std_ls, "ci95_ls": list(self.ci95_ls),
                "std_hac": self.std_hac, "ci95_hac": list(self.ci95_hac), "std_matlab": self.std_matlab}


@dataclass
class RigidFit:
    """IDIM-LS estimate of ``theta = [M, Fv, Fc, offset]`` (SI: kg, N s/m, N, N) and its diagnostics.

    ``cov_ls`` / ``corr_ls``: classical LS covariance and correlation; ``cov_hac`` / ``corr_hac``: Newey-West
    sandwich (lag ``hac_lag``). ``relative_error_pct`` is the PDF's eq. 11 on the decimated force,
    ``cond`` the condition number of the decimated observation matrix, ``abs_diag_R`` the |diag R| of the QR of the
    raw (undecimated) observation matrix, as the script prints them.
    """

    M: RigidParam
    Fv: RigidParam
    Fc: RigidParam
    offset: RigidParam
    theta: np.ndarray
    theta_lstsq: np.ndarray
    cov_ls: np.ndarray
    cov_hac: np.ndarray
    corr_ls: np.ndarray
    corr_hac: np.ndarray
    hac_lag: int
    relative_error_pct: float
    error_norm: float
    error_std: float               # std(e, ddof=1), the PDF's "deviation of error"
    sigma: float                   # sqrt(||e||^2 / (N - 4))
    cond: float
    abs_diag_R: np.ndarray
    n_obs: int
    settings: IdimSettings
    closed_loop_natural_freq_hz: float
    solver: dict[str, Any]
    runtime_s: float
    source: str
    t: np.ndarray = field(repr=False)       # decimated times
    y: np.ndarray = field(repr=False)       # decimated measured force
    y_hat: np.ndarray = field(repr=False)   # reconstructed force Phi theta

    @property
    def params(self) -> tuple[RigidParam, ...]:
        return (self.M, self.Fv, self.Fc, self.offset)

    @property
    def casadi_vs_lstsq(self) -> float:
        """max_i |theta_i(IPOPT) - theta_i(lstsq)| / |theta_i(lstsq)|."""
        return float(np.max(np.abs(self.theta - self.theta_lstsq) / np.abs(self.theta_lstsq)))

    def to_dict(self) -> dict[str, Any]:
        return {**{p.name: p.to_dict() for p in self.params},
                "relative_error_pct": self.relative_error_pct, "error_norm": self.error_norm,
                "error_std": self.error_std, "sigma": self.sigma, "cond": self.cond,
                "abs_diag_R": self.abs_diag_R.tolist(), "n_obs": self.n_obs, "hac_lag": self.hac_lag,
                "corr_ls": self.corr_ls.tolist(), "corr_hac": self.corr_hac.tolist(),
                "settings": self.settings.to_dict(),
                "closed_loop_natural_freq_hz": self.closed_loop_natural_freq_hz, "solver": self.solver,
                "casadi_vs_lstsq": self.casadi_vs_lstsq, "runtime_s": self.runtime_s, "source": self.source}


def _fit_once(log: DriveLog, s: IdimSettings) -> tuple[_Idim, np.ndarray, np.ndarray, dict[str, Any]]:
    sysm = idim_system(log, s)
    theta_ref = np.linalg.lstsq(sysm.X, sysm.y, rcond=None)[0]
    theta, info = solve_ls_casadi(sysm.X, sysm.y)
    return sysm, theta, theta_ref, info


def identify_rigid(log: DriveLog) -> RigidFit:
    """IDIM-LS of the EMPS rigid model on ``log`` (from :func:`load_emps`), exactly as the PDF's section 3.

    The filter and decimation settings follow the PDF's rules from the log's sample rate and the closed loop's
    natural frequency (see the module docstring); the LS problem is solved by CasADi + IPOPT and cross-checked with
    ``numpy.linalg.lstsq`` (``RigidFit.theta_lstsq``, ``RigidFit.casadi_vs_lstsq``).
    """
    t0 = time.perf_counter()
    if not {"gtau", "kp", "kv"} <= set(log.meta_extra):
        return _identify_rigid_generic(log, t0)
    gtau, kp, kv = closed_loop_gains(log)
    s = idim_settings(log.meta.sample_rate_hz)
    for _ in range(4):
        sysm, theta, theta_ref, info = _fit_once(log, s)
        M = theta[0]
        if M <= 0:
            raise RuntimeError(f"{log.source}: identified mass {M:g} kg is not positive; the log does not excite "
                               "the dynamics")
        f_cl = math.sqrt(gtau * kv * kp / M) / (2 * math.pi)
        if f_cl <= s.f_dyn_hz * (1 + 1e-9):
            break  # 5 w_dyn >= 5 f_cl and 2 w_dyn >= 2 f_cl: the PDF's rules hold
        s = idim_settings(log.meta.sample_rate_hz, f_cl, "identified closed-loop natural frequency")
    return _rigid_result(log, s, sysm, theta, theta_ref, info, f_cl, t0)


def generic_idim_settings(log: DriveLog) -> IdimSettings:
    """The filter settings of a log without the EMPS controller data: w_dyn is the frequency below which 99 % of
    the motor velocity's power lies (kept low enough for the 5 w_dyn cut-off to stay below Nyquist)."""
    v = np.diff(log.motor_pos_rad) * log.meta.sample_rate_hz
    power = np.abs(np.fft.rfft(v - v.mean())) ** 2
    if not np.isfinite(power.sum()) or power.sum() <= 0:
        raise RuntimeError(f"{log.source}: the motor position never changes: the log does not move the axis")
    freq = np.fft.rfftfreq(v.size, 1.0 / log.meta.sample_rate_hz)
    f_dyn = float(max(1.0, freq[np.searchsorted(np.cumsum(power) / power.sum(), 0.99)]))
    f_dyn = min(f_dyn, 0.99 * log.meta.sample_rate_hz / 10.0)  # keep the 5 w_dyn cut-off below Nyquist
    return idim_settings(log.meta.sample_rate_hz, f_dyn, "99 % of the motor velocity's power")


def _identify_rigid_generic(log: DriveLog, t0: float) -> RigidFit:
    """IDIM-LS for a log without the EMPS controller data: the dynamics bandwidth w_dyn of the filter rules is the
    frequency below which 99 % of the motor velocity's power lies (from the data, never the user)."""
    s = generic_idim_settings(log)
    sysm = _moving_rows(idim_system(log, s))
    theta_ref = np.linalg.lstsq(sysm.X, sysm.y, rcond=None)[0]
    theta, info = solve_ls_casadi(sysm.X, sysm.y)
    if theta[0] <= 0:
        raise RuntimeError(f"{log.source}: identified inertia {theta[0]:g} is not positive; the log does not excite "
                           "the dynamics")
    fit = _rigid_result(log, s, sysm, theta, theta_ref, info, float("nan"), t0)
    if fit.relative_error_pct > 25.0:
        raise RuntimeError(f"{log.source}: the rigid model reconstructs the logged torque with "
                           f"{fit.relative_error_pct:.0f} % relative error: this log is not rigid-body motion at "
                           "the filter bandwidth (too fast an excitation, or a flexible drive: use the two-inertia "
                           "model); no estimate is returned")
    return fit


def rigid_warnings(fit: RigidFit) -> list[str]:
    """A warning for each of M and Fc whose residual-based (HAC) 1-sigma exceeds 10 % of its value."""
    out = []
    for param in (fit.M, fit.Fc):
        rel = param.std_hac / abs(param.value) if param.value else math.inf
        if rel > 0.10:
            out.append(f"{param.name} is poorly determined by this log (1-sigma {100 * rel:.0f} %, residual-based): "
                       "excite the axis with slower, larger sweeps in both directions")
    return out


def moving_mask(v: np.ndarray) -> np.ndarray:
    """The rows of :func:`_moving_rows` (decimated velocity ``v``): |v| above 10 % of its 99th percentile, two rows
    on each side of a stop dropped, and no sign change from the previous row."""
    moving = np.abs(v) > 0.1 * np.percentile(np.abs(v), 99)
    keep = moving.copy()
    for k in (1, 2):
        keep[k:] &= moving[:-k]
        keep[:-k] &= moving[k:]
    keep &= np.sign(v) == np.sign(np.roll(v, 1))
    return keep


def _moving_rows(sysm: _Idim) -> _Idim:
    """Only the rows where the axis clearly slides: in a stick phase the friction force is whatever holds the
    axis (not +-Fc), and the filters smear the stop into the neighbouring rows, so both would bias Fc and M. The
    threshold is 10 % of the 99th percentile of |velocity|, and two rows on each side of a stop are dropped too."""
    keep = moving_mask(sysm.X[:, 1])
    if keep.sum() < 20:
        raise RuntimeError("the axis barely slides in this log: the rigid model's inertia and friction are not "
                           "excited (fewer than 20 moving rows)")
    return _Idim(sysm.X0, sysm.X[keep], sysm.y[keep], sysm.t[keep])


def _rigid_result(log: DriveLog, s: IdimSettings, sysm: Any, theta: np.ndarray, theta_ref: np.ndarray,
                  info: dict[str, Any], f_cl: float, t0: float) -> RigidFit:
    X, y = sysm.X, sysm.y
    n, p = X.shape
    e = y - X @ theta
    sse = float(e @ e)
    A = np.linalg.inv(X.T @ X)
    sigma2 = sse / (n - p)
    cov_ls = sigma2 * A
    cov_hac, lag, _ = hac_covariance(X, e)
    std_m = float(np.std(e, ddof=1)) * np.sqrt(np.diag(A))
    tq = float(scipy.stats.t.ppf(0.975, n - p))
    params = []
    for i, name in enumerate(PARAM_NAMES):
        v, sl, sh = float(theta[i]), float(math.sqrt(cov_ls[i, i])), float(math.sqrt(cov_hac[i, i]))
        params.append(RigidParam(name, PARAM_UNITS[name], v, sl, (v - tq * sl, v + tq * sl), sh,
                                 (v - _Z95 * sh, v + _Z95 * sh), float(std_m[i])))
    R = np.linalg.qr(sysm.X0, mode="r")
    return RigidFit(*params, theta=theta, theta_lstsq=theta_ref, cov_ls=cov_ls, cov_hac=cov_hac,
                    corr_ls=_corr(cov_ls), corr_hac=_corr(cov_hac), hac_lag=lag,
                    relative_error_pct=100.0 * math.sqrt(sse) / float(np.linalg.norm(y)),
                    error_norm=math.sqrt(sse), error_std=float(np.std(e, ddof=1)), sigma=math.sqrt(sigma2),
                    cond=float(np.linalg.cond(X)), abs_diag_R=np.abs(np.diag(R)), n_obs=n, settings=s,
                    closed_loop_natural_freq_hz=f_cl, solver=info, runtime_s=time.perf_counter() - t0,
                    source=log.source, t=sysm.t, y=y, y_hat=X @ theta)


@dataclass
class CrossValidation:
    """Cross-test validation (PDF eq. 11 with the CTV observation matrix): the fit's theta on another log, processed
    with the fit's filter and decimation settings."""

    relative_error_pct: float
    error_norm: float
    error_std: float
    cond: float
    abs_diag_R: np.ndarray
    n_obs: int
    source: str
    t: np.ndarray = field(repr=False)
    y: np.ndarray = field(repr=False)
    y_hat: np.ndarray = field(repr=False)

    def to_dict(self) -> dict[str, Any]:
        return {"relative_error_pct": self.relative_error_pct, "error_norm": self.error_norm,
                "error_std": self.error_std, "cond": self.cond, "abs_diag_R": self.abs_diag_R.tolist(),
                "n_obs": self.n_obs, "source": self.source}


def validate_rigid(fit: RigidFit, log: DriveLog) -> CrossValidation:
    """Relative error of the force reconstructed on ``log`` (e.g. DATA_EMPS_PULSES) with ``fit``'s estimates."""
    closed_loop_gains(log)
    s = fit.settings
    if abs(log.meta.sample_rate_hz - s.sample_rate_hz) > 1e-3 * s.sample_rate_hz:
        s = idim_settings(log.meta.sample_rate_hz, s.f_dyn_hz, s.f_dyn_source)
    sysm = idim_system(log, s)
    y_hat = sysm.X @ fit.theta
    e = sysm.y - y_hat
    R = np.linalg.qr(sysm.X0, mode="r")
    return CrossValidation(relative_error_pct=100.0 * float(np.linalg.norm(e) / np.linalg.norm(sysm.y)),
                           error_norm=float(np.linalg.norm(e)), error_std=float(np.std(e, ddof=1)),
                           cond=float(np.linalg.cond(sysm.X)), abs_diag_R=np.abs(np.diag(R)), n_obs=sysm.y.size,
                           source=log.source, t=sysm.t, y=sysm.y, y_hat=y_hat)
