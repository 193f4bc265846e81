"""Data before physics: checks of a log that point at the data, not at missing physics (issue 21, item 5).

Each check returns ``{"check", "status", "detail"}`` with status ``ok``, ``warning``, ``error`` or ``skipped`` (the
log cannot tell); ``check_log`` runs them all and, with ``raise_errors``, raises one ``LogError`` naming every failed
check before anything is fitted.

- ``sample_rate``: the sidecar's rate against the time column (``logs.check_sample_rate``: above 1e-4 relative).
- ``encoder_quantization``: with ``encoder_counts_per_rev`` declared, every sample of ``motor_pos_rad`` must lie a
  whole number of counts from the first (the column's zero may sit anywhere; over the travel, a count size off by
  0.06 % shows where single steps would not). A sample off the grid by more than
  ``COUNT_TOLERANCE`` of a count (plus what a column printed with 10 significant digits can lose) is an error; steps
  that are all multiples of k > 1 counts are a warning (``encoder_counts_per_rev`` k times too large?).
- ``gear_ratio`` and ``load_sensor``: over the motor's standstills (runs of a constant encoder count, the load's
  mean over each), the load must travel r times the motor: there q_l = r q_m - d + offset with the deflection d
  bounded (the spring's), not growing with the travel. A least-squares slope s of load on motor standstill positions,
  with its standard error (at least what the deflections' spread or one encoder count could fake over the motor's
  travel, ``_travel_ratio``), is compared with r: consistent when within ``RATIO_TOLERANCE`` (1 %: one tooth on a
  100:1 drive) or three standard errors. Otherwise the ratio s/r is matched against the usual unit and sign mistakes of the load
  column (degrees, milliradians, microradians, arc-seconds, metres or micrometres at the arm tip, the motor side,
  each with either sign): a match names it, no match is a gear-ratio error naming both numbers. With too little
  motor travel to decide (standard error above ``DECIDABLE`` of r, or fewer than ``MIN_STANDSTILLS`` standstills)
  the check is skipped -- except for a unit or sign mistake clear even then (degrees: 57x).
- ``torque``: the work the torque column does on the motor, W = sum T_k (q_m[k+1] - q_m[k]) (the torque held over each
  sample interval), against what the motor's own Coulomb friction at the sidecar's ``f_m_Nm`` dissipates over its
  travel, f_m x (the motor's travel, reversals within one count left out: an encoder flickering at an edge does no
  work). The drive is passive and starts at rest, so the torque's work is what every friction dissipates plus what the
  bodies and the spring hold at the end, less the spring's energy at the start (within the static band: at most f_l^2
  / (2 K_s), small against the frictions' work over any real travel): at least the motor's Coulomb work, and at most
  what the library's frictions can dissipate, (1 + s)(1 + |a|)(1 + f_l* r) times it (the FMU's largest Stribeck excess
  s and asymmetry a, the identifier's largest f_l*; a viscous friction beside them may add more). The ratio rho = W /
  (f_m travel) is 1.00-1.28 on every log of the independent generator in the cache at the time of writing (about 100:
  clean, single- and two-effect, outside the library, 1-10 s, torque steps and the default design). Its error from the
  encoder's quantization is at most one count times the torque's total variation (summation by parts); where that is
  above ``WORK_ERROR`` of the larger of W and f_m x travel the log cannot tell (skipped). rho below -``WORK_LOW`` is
  an error (the motor moved against the torque: the column's sign, or the encoder's, is flipped; a flip turns rho >= 1
  into rho <= -1, and ``WORK_LOW`` = 0.5, halfway, leaves room for a Coulomb level down to half the sidecar's); |rho|
  below ``WORK_LOW`` is an error (the torque did less than half the work the motor's friction alone takes: the column
  reads too small, or ``f_m_Nm`` too large, by about 1/rho); rho above the largest dissipation is an error (the column
  reads too large, e.g. mN.m for N.m gives 1000x, or ``f_m_Nm`` is too small). Factors between those bounds are not
  caught.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from fmu_build import variables as V

from .logs import DriveLog, LogError, check_sample_rate
from .result import BOUNDS

COUNT_TOLERANCE = 0.01
RATIO_TOLERANCE = 0.01
DECIDABLE = 0.05
MIN_STANDSTILLS = 4
REST_SAMPLES = 16
WORK_LOW = 0.5      # see the module docstring (``torque``)
WORK_ERROR = 0.25


def _status(check: str, status: str, detail: str, **values: Any) -> dict[str, Any]:
    return {"check": check, "status": status, "detail": detail, **values}


def check_rate(log: DriveLog) -> dict[str, Any]:
    """The sidecar's sample rate against the time column."""
    try:
        rel = check_sample_rate(log.time_s, log.meta.sample_rate_hz, log.source)
    except LogError as exc:
        return _status("sample_rate", "error", str(exc))
    return _status("sample_rate", "ok", f"sidecar and time column agree to {rel:.2g} (relative)",
                   relative_difference=rel)


def check_encoder(log: DriveLog) -> dict[str, Any]:
    """Changes of the motor encoder column are whole counts (module docstring)."""
    cpr = log.meta.encoder_counts_per_rev
    if cpr is None:
        return _status("encoder_quantization", "skipped", "no encoder_counts_per_rev in the sidecar")
    count = 2 * math.pi / cpr
    travel = (log.motor_pos_rad - log.motor_pos_rad[0]) / count   # from the first sample: the zero may be anywhere
    tol = COUNT_TOLERANCE + 1e-10 * float(np.max(np.abs(log.motor_pos_rad))) / count
    off = np.flatnonzero(np.abs(travel - np.round(travel)) > tol)
    if off.size:
        k = int(off[0])
        return _status("encoder_quantization", "error",
                       f"{log.source}: column motor_pos_rad, row {k + 1}: the encoder is {travel[k]:.6g} counts from "
                       f"the first sample (one count = 2 pi / encoder_counts_per_rev = {count:.6g} rad), not a whole "
                       f"number ({off.size} such samples): the column is not in rad of the motor, or "
                       f"encoder_counts_per_rev = {cpr} is wrong", off_grid=int(off.size))
    steps = np.round(np.diff(travel))
    moves = np.abs(steps[steps != 0]).astype(np.int64)
    if moves.size == 0:
        return _status("encoder_quantization", "ok", "the encoder never changes")
    g = int(np.gcd.reduce(moves))
    if g > 1 and moves.size >= 10:
        return _status("encoder_quantization", "warning",
                       f"every change of motor_pos_rad is a multiple of {g} counts: encoder_counts_per_rev = {cpr} "
                       f"may be {g}x too large (the fit assumes one count of quantization)", multiple=g)
    return _status("encoder_quantization", "ok", f"{moves.size} changes, all whole counts")


def rest_positions(log: DriveLog) -> tuple[np.ndarray, np.ndarray]:
    """(motor, load) positions over the runs of a constant encoder count of at least ``REST_SAMPLES`` samples: the
    count, and the load's mean over the run (a load still ringing averages towards its centre). The motor stands
    still over a run, so the deflection r q_m - q_l there is the spring's, bounded; a slow slide inside one count
    adds the load's lag, which is bounded too and enters the tolerance through the points' spread."""
    cpr = log.meta.encoder_counts_per_rev or 2 ** 20
    counts = np.round(log.motor_pos_rad / (2 * math.pi / cpr)).astype(np.int64)
    change = np.flatnonzero(np.diff(counts) != 0) + 1
    edges = np.concatenate([[0], change, [counts.size]])
    keep = [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b - a >= REST_SAMPLES]
    return (np.array([log.motor_pos_rad[a] for a, _ in keep]),
            np.array([float(np.mean(log.load_pos_rad[a:b])) for a, b in keep]))


def _unit_factors(log: DriveLog) -> dict[str, float]:
    """Load-column mistakes and the factor each puts on the load's travel."""
    L, r = log.meta.arm_length_m, log.meta.r
    base = {"in degrees": 180 / math.pi, "in milliradians": 1e3, "in microradians": 1e6,
            "in arc-seconds": 180 / math.pi * 3600, "in metres at the arm tip": L, "in micrometres at the arm tip":
            L * 1e6, "on the motor side (motor radians)": 1 / r}
    out = {"with the wrong sign": -1.0}
    for what, f in base.items():
        out[what] = f
        out[f"{what} and with the wrong sign"] = -f
    return out


def check_travel(log: DriveLog) -> list[dict[str, Any]]:
    """The gear ratio and the load sensor's unit and sign from the load's travel against the motor's."""
    if log.load_pos_rad is None:
        return [_status("gear_ratio", "skipped", "no load sensor"), _status("load_sensor", "skipped", "no load sensor")]
    qm, ql = rest_positions(log)
    if qm.size < MIN_STANDSTILLS or np.ptp(qm) == 0:
        why = f"only {qm.size} standstill(s) of the motor: the load's travel cannot be compared with the motor's"
        return [_status("gear_ratio", "skipped", why), _status("load_sensor", "skipped", why)]
    s, k, se_k = _travel_ratio(log, qm, ql)
    values = {"ratio_over_r": k, "ratio_std_over_r": se_k, "standstills": int(qm.size),
              "motor_travel_rad": float(np.ptp(qm))}
    where = (f"{log.source}: over {qm.size} motor standstills spanning {np.ptp(qm) / (2 * math.pi):.3g} motor "
             f"revolutions the load travels {s:.6g} rad per motor rad = {k:.4g} x the sidecar's r = {log.meta.r:.6g}")
    consistent = abs(k - 1) <= max(RATIO_TOLERANCE, 3 * se_k)
    if consistent and se_k <= DECIDABLE:
        return [_status("gear_ratio", "ok", f"{where} (+-{se_k:.2g})", **values),
                _status("load_sensor", "ok", "unit and sign consistent with the gear ratio")]
    if not consistent:
        for what, f in _unit_factors(log).items():
            if abs(k / f - 1) <= max(RATIO_TOLERANCE, 3 * se_k / abs(f)):
                return [_status("gear_ratio", "skipped", "the load sensor's unit or sign is off (see load_sensor)"),
                        _status("load_sensor", "error", f"{where}: column load_pos_rad looks {what} (factor {f:.6g}; "
                                "or the sidecar's r is off by that factor); convert it to load-side radians, "
                                "positive with the motor", factor=f, **values)]
    if se_k > DECIDABLE:
        why = f"too little motor travel to check ({where}, +-{se_k:.2g})"
        return [_status("gear_ratio", "skipped", why, **values), _status("load_sensor", "skipped", why)]
    hint = " (the convention is r = q_l / q_m < 1)" if log.meta.r >= 1 else ""
    return [_status("gear_ratio", "error", f"{where}{hint}: the gear ratio is inconsistent with the log (or the "
                    "motor and load columns do not belong together)", **values),
            _status("load_sensor", "skipped", "the gear ratio is off (see gear_ratio)")]


def _travel_ratio(log: DriveLog, qm: np.ndarray, ql: np.ndarray) -> tuple[float, float, float]:
    """(slope of load on motor standstill positions, the slope over r, its standard error over r). The error is at
    least what the bounded deflections could fake (their spread, ~4 standard deviations, over the travel) and what
    the encoder's quantization could (a reading is up to one count off the motor: one count over the travel)."""
    r = log.meta.r
    x = qm - qm.mean()
    s = float(x @ (ql - ql.mean()) / (x @ x))
    e = ql - ql.mean() - s * x
    travel = float(np.ptp(qm))
    count = 2 * math.pi / (log.meta.encoder_counts_per_rev or 2 ** 20)
    se = float(np.sqrt(e @ e / max(qm.size - 2, 1) / (x @ x)))
    se_k = max(se / abs(r), 4 * float(np.std(e)) / travel / 3 / abs(r), count / travel)
    return s, s / r, se_k


def most_dissipation(r: float) -> float:
    """The largest ratio of the frictions' work to the motor's Coulomb work f_m x travel the library allows (module
    docstring, ``torque``): (1 + s)(1 + |a|)(1 + f_l* r) at the FMU's largest Stribeck excess and asymmetry and the
    identifier's largest f_l*."""
    s, a = V.BY_NAME["stribeck_ratio"].hi, V.BY_NAME["friction_asymmetry"].hi
    return (1 + s) * (1 + a) * (1 + BOUNDS["f_l_star"][1] * abs(r))


def motor_travel(q: np.ndarray, count: float) -> float:
    """The motor's travel [rad] with reversals within one count left out (a play of one count: an encoder
    flickering at an edge adds nothing)."""
    moved = q[np.flatnonzero(np.diff(q)) + 1]
    travel, pos = 0.0, float(q[0])
    for x in moved:
        if x > pos + count:
            travel, pos = travel + x - count - pos, x - count
        elif x < pos - count:
            travel, pos = travel + pos - count - x, x + count
    return travel


def check_torque(log: DriveLog) -> dict[str, Any]:
    """The torque column's work on the motor against the motor's Coulomb work (module docstring, ``torque``)."""
    q, T, f_m = log.motor_pos_rad, log.motor_torque_Nm, log.meta.f_m_Nm
    if not f_m or f_m <= 0:
        return _status("torque", "skipped", "no motor Coulomb friction f_m_Nm in the sidecar to measure the work by")
    steps = np.abs(np.diff(q))
    count = 2 * math.pi / log.meta.encoder_counts_per_rev if log.meta.encoder_counts_per_rev else \
        float(np.min(steps[steps > 0])) if np.any(steps > 0) else 0.0
    coulomb = f_m * motor_travel(q, count)
    error = count * (float(np.sum(np.abs(np.diff(T)))) + abs(float(T[0])) + abs(float(T[-1])))
    work = float(np.sum(T[:-1] * np.diff(q)))
    if coulomb <= 0 or error > WORK_ERROR * max(coulomb, abs(work)):
        return _status("torque", "skipped", f"the motor's travel ({coulomb / f_m:.3g} rad) is too short "
                       "for the torque's work to be measured against its friction's (within a quarter)")
    rho = work / coulomb
    top = most_dissipation(log.meta.r)
    where = (f"{log.source}: column motor_torque_Nm does {rho:.3g} x the work the motor's Coulomb friction "
             f"(the sidecar's f_m_Nm = {f_m:.4g}) dissipates over its travel of {coulomb / f_m:.4g} rad "
             f"(+-{error / coulomb:.2g})")
    values = {"work_over_coulomb": rho, "work_error": error / coulomb, "most_dissipation": top}
    if rho < -WORK_LOW:
        return _status("torque", "error", f"{where}: the motor moved against the torque; the torque's sign (or the "
                       "encoder's) looks flipped: make motor_torque_Nm positive where it drives motor_pos_rad up",
                       **values)
    if rho < WORK_LOW:
        return _status("torque", "error", f"{where}, less than half what a passive drive needs (at least 1): the "
                       f"column reads too small{f' by about {1 / rho:.3g}x' if rho > 0 else ''} (another unit, or "
                       "a current?), or f_m_Nm is too large; give the motor torque in N.m", **values)
    if rho > top:
        return _status("torque", "error", f"{where}, more than the library's frictions can dissipate ({top:.3g} x "
                       "at the largest Stribeck excess, asymmetry and f_l*): the column reads too large (mN.m gives "
                       "1000x, N.cm 100x), or f_m_Nm is too small; give the motor torque in N.m", **values)
    return _status("torque", "ok", f"{where}: a passive drive's (from 1x up to {top:.3g}x; an error below "
                   f"{WORK_LOW:g}x or above {top:.3g}x)", **values)


def check_log(log: DriveLog, raise_errors: bool = False) -> list[dict[str, Any]]:
    """All checks of the module docstring; with ``raise_errors`` a ``LogError`` naming every failed one."""
    results = [check_rate(log), check_encoder(log), *check_travel(log), check_torque(log)]
    errors = [c["detail"] for c in results if c["status"] == "error"]
    if errors and raise_errors:
        raise DataCheckError("; ".join(errors), results)
    return results


class DataCheckError(LogError):
    """A log failed a data check; ``checks`` holds every check's result (for the JSON output)."""

    def __init__(self, message: str, checks: list[dict[str, Any]]):
        super().__init__(message)
        self.checks = checks
