"""Resolution predicted from a fitted drive, with an interval propagated from the parameter uncertainty.

The point prediction runs the paper's protocols (``impulse_resolution``, ``linear_resolution``) on the FMU with the
fitted parameters; the interval comes from Monte Carlo: parameter draws from the fit's (sandwich) covariance of
(ln K*, ln J_l*, ln f_l*), each run through the same protocols on Dask (``ident.protocols.batch``), then the 2.5 / 97.5
percentiles of the draws.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from ..common.checks import whole
from ..model.params import DriveParams
from ..protocols.resolution import impulse_resolution, linear_resolution
from .identify import NAMES, TwoInertiaFit


def _resolutions(task: tuple[DriveParams, int, int]) -> tuple[float, float, int]:
    """(impulse resolution [m], linear resolution [m], linear counts) of one drive."""
    params, n_pulses, n_steps = task
    imp = impulse_resolution(params, n_pulses=n_pulses)
    lin = linear_resolution(params, n_steps=n_steps)
    return imp.resolution_m, lin.resolution_m, lin.counts


@dataclass
class Prediction:
    """Predicted impulse and linear resolution [um at the arm] of a fitted drive, with 95 % intervals."""

    params: DriveParams
    impulse_resolution_um: float
    impulse_ci95_um: tuple[float, float]
    linear_resolution_um: float
    linear_ci95_um: tuple[float, float]
    linear_counts: int
    draws: pd.DataFrame  # one row per parameter draw: K_star, J_l_star, f_l_star, impulse_um, linear_um, counts

    def to_dict(self) -> dict[str, Any]:
        return {"impulse_resolution_um": {"value": self.impulse_resolution_um, "ci95": list(self.impulse_ci95_um)},
                "linear_resolution_um": {"value": self.linear_resolution_um, "ci95": list(self.linear_ci95_um)},
                "linear_counts": self.linear_counts, "n_draws": len(self.draws),
                "interval": "2.5/97.5 percentiles over parameter draws from the fit's sandwich covariance"}

    def to_frame(self) -> pd.DataFrame:
        return self.draws


def predict(fit: TwoInertiaFit, *, n_draws: int = 20, n_pulses: int = 1000, n_steps: int = 1000, seed: int = 0,
            scheduler: str | None = None, workers: int | None = None, progress: bool = False) -> Prediction:
    """Impulse and linear resolution of the fitted drive; the interval from ``n_draws`` parameter draws."""
    n_draws = whole("n_draws", n_draws, 0)
    rng = np.random.default_rng(seed)
    theta = np.asarray(fit.theta[:3], dtype=float)
    chol = np.linalg.cholesky(fit.cov_sandwich + 1e-300 * np.eye(3))
    thetas = [theta] + [theta + chol @ rng.standard_normal(3) for _ in range(n_draws)]
    drives = [fit.params.with_values(**dict(zip(NAMES, map(float, np.exp(t))))) for t in thetas]
    from ..protocols.batch import run_batch

    results = run_batch(_resolutions, [(p, n_pulses, n_steps) for p in drives], scheduler=scheduler,
                        workers=workers if n_draws else 0, progress=progress, desc="resolution draws",
                        threads=True)  # the protocols' compiled loops release the GIL
    table = pd.DataFrame([{**dict(zip(NAMES, np.exp(t))), "impulse_um": r[0] * 1e6, "linear_um": r[1] * 1e6,
                           "counts": r[2]} for t, r in zip(thetas, results)])
    draws = table.iloc[1:] if n_draws else table

    def ci(col: str) -> tuple[float, float]:
        return float(np.percentile(draws[col], 2.5)), float(np.percentile(draws[col], 97.5))

    imp0, lin0, counts0 = results[0]
    return Prediction(fit.params, imp0 * 1e6, ci("impulse_um"), lin0 * 1e6, ci("linear_um"), counts0,
                      draws.reset_index(drop=True))
