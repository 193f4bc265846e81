"""The result of a two-inertia identification (``TwoInertiaFit``): estimates with intervals, the identifiability
verdict per parameter, the data checks, warnings, and the fit's details; its JSON form is the CLI's."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..common.plotting import figure, save
from ..model.params import DriveParams

NAMES = ("K_star", "J_l_star", "f_l_star")
#: the two-inertia fit's unknowns: the log of each of ``NAMES`` and the initial deflection (a fraction of the static
#: band); a diagnosis's effect coordinates follow them
BASE_UNKNOWNS = len(NAMES) + 1
BOUNDS = {"K_star": (1e3, 1e9), "J_l_star": (10.0, 1e6), "f_l_star": (1e-4, 100.0)}
Z95 = 1.959963984540054
AT_BOUND = 0.05  # a log-parameter this close to its bound leans on the box (IPOPT's barrier keeps it a few % off)


def param_bounds() -> tuple[np.ndarray, np.ndarray]:
    """Box bounds of (ln K*, ln J_l*, ln f_l*, d0/band). The log starts at rest, so the initial deflection lies
    within the static band: +-1 band (f_l/K_s; the band both bodies hold is never wider). A looser bound let a fit
    settle at d0 = -3.3 bands, a start the log cannot have, with the load's residual 1.13x its noise (a chirp log
    of issue 21's suite)."""
    lo = np.array([math.log(BOUNDS[k][0]) for k in NAMES] + [-1.0])
    hi = np.array([math.log(BOUNDS[k][1]) for k in NAMES] + [1.0])
    return lo, hi


def at_bound(theta: np.ndarray) -> list[str]:
    """The names of K*, J_l*, f_l* within 5 % of their bound (``BOUNDS``) in ``theta``: the fit did not find an
    optimum of the model inside the physical range, it leaned on the box."""
    lo, hi = param_bounds()
    return [name for i, name in enumerate(NAMES) if min(theta[i] - lo[i], hi[i] - theta[i]) < AT_BOUND]


def larger_variances(sandwich: np.ndarray, noise_only: np.ndarray) -> np.ndarray:
    """Per parameter the larger of the two variances, with the sandwich's correlations: the covariance behind the
    reported intervals. Symmetric and positive semi-definite like the sandwich (a row-wise choice between the two
    matrices would be neither), so a Wald statistic or a regression along the valley can use it."""
    s = np.sqrt(np.maximum(np.diag(sandwich), np.diag(noise_only)))
    d = np.sqrt(np.maximum(np.diag(sandwich), 1e-300))
    return sandwich / np.outer(d, d) * np.outer(s, s)


@dataclass
class Estimate:
    """A parameter estimate with its 95 % confidence interval and its identifiability verdict."""

    value: float
    ci95: tuple[float, float]
    std: float  # standard deviation (delta method from the log-parameter covariance)
    identifiable: bool = True
    reason: str = ""  # why not identifiable (empty when identifiable)
    at_bound: bool = False  # the fit leaned on the physical range's edge: no result

    def to_dict(self) -> dict[str, Any]:
        """JSON form; a parameter at a bound of the physical range has no value or interval (it is no result)."""
        edge = self.at_bound
        return {"value": None if edge else self.value, "ci95": None if edge else list(self.ci95),
                "std": None if edge else self.std, "identifiable": self.identifiable, "reason": self.reason}

    def describe(self, name: str) -> str:
        """One line for text output."""
        if self.at_bound:
            return f"{name:10s} no result (at the edge of the physical range)"
        return f"{name:10s} {self.value:.6g}  95 % [{self.ci95[0]:.6g}, {self.ci95[1]:.6g}]" + (
            "" if self.identifiable else "  NOT IDENTIFIABLE")


def _finite(value: Any) -> Any:
    """A JSON-ready copy: numpy numbers as Python ones, NaN and infinities as None (strict JSON has neither)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


@dataclass
class TwoInertiaFit:
    """Result of ``identify(log)`` for the two-inertia model."""

    estimates: dict[str, Estimate]
    params: DriveParams
    theta: np.ndarray
    cov_sandwich: np.ndarray       # covariance of (ln K*, ln J_l*, ln f_l*): residual-based
    cov_noise_only: np.ndarray     # (J^T J)^-1 in noise units: the Cramer-Rao bound at the estimate
    fit: dict[str, float]
    warnings: list[str]
    start: dict[str, Any]
    stages: list[dict[str, Any]]
    load_offset_rad: float
    sigma_load_rad: float          # the one load-noise estimate (white part of the residual), rad
    elapsed_s: float
    simulated: dict[str, np.ndarray] = field(repr=False, default_factory=dict)
    data_checks: list[dict[str, Any]] = field(default_factory=list)
    fix: str = ""                  # what to record instead, when a parameter is not identifiable
    alternatives: list[dict[str, Any]] = field(default_factory=list)  # competing optima the data do not reject

    @property
    def identifiable(self) -> bool:
        """All three parameters identifiable from this log."""
        return all(e.identifiable for e in self.estimates.values())

    @property
    def cov_reported(self) -> np.ndarray:
        """The covariance behind the reported intervals: per parameter the larger of the two variances, with the
        sandwich's correlations."""
        return larger_variances(self.cov_sandwich, self.cov_noise_only)

    @property
    def correlation(self) -> pd.DataFrame:
        s = np.sqrt(np.maximum(np.diag(self.cov_noise_only), 1e-300))
        return pd.DataFrame(self.cov_noise_only / np.outer(s, s), index=list(NAMES), columns=list(NAMES))

    def si(self) -> dict[str, float]:
        p = self.params
        return {"K_s_Nm_per_rad": p.K_s, "J_l_kgm2": p.J_l, "f_l_Nm": p.f_l, "J_m_kgm2": p.J_m, "f_m_Nm": p.f_m,
                "r": p.r}

    def to_frame(self) -> pd.DataFrame:
        rows = []
        for name in NAMES:
            e = self.estimates[name]
            rows.append({"parameter": name, "value": e.value, "ci95_lo": e.ci95[0], "ci95_hi": e.ci95[1],
                         "std": e.std, "rel_std_pct": 100 * e.std / e.value, "identifiable": e.identifiable,
                         "reason": e.reason})
        return pd.DataFrame(rows)

    def to_dict(self) -> dict[str, Any]:
        crb = np.sqrt(np.diag(self.cov_noise_only)) * np.array([self.estimates[k].value for k in NAMES])
        return {**{k: e.to_dict() for k, e in self.estimates.items()}, "identifiable": self.identifiable,
                "fix": self.fix, "sigma_load_rad": self.sigma_load_rad, "warnings": self.warnings,
                "data_checks": self.data_checks, "si": self.si(), "fit": self.fit,
                "covariance": "per parameter the larger of the Cramer-Rao bound (cramer_rao_std) and the sandwich "
                              "(residual-based, blocks of one ringing period)",
                "cramer_rao_std": dict(zip(NAMES, crb.tolist())),
                "correlation": self.correlation.round(6).to_dict(), "alternatives": self.alternatives,
                "start": _finite(self.start), "stages": _finite(self.stages),
                "load_offset_rad": self.load_offset_rad, "elapsed_s": self.elapsed_s}

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
