"""The paper's friction sweep (section V): the impulse protocol at every load-friction level, in parallel on Dask.

``friction_levels`` gives the paper's 25 log-spaced levels; ``friction_sweep`` runs them; ``FrictionSweep`` holds the
results with ``.to_frame()``, ``.trend()`` (the least-squares line the paper's "grows linearly" is judged by) and
``.plot(out_dir)``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from ..common.checks import whole
from ..common.plotting import figure, save
from ..model.params import DriveParams
from .resolution import ImpulseResolution, impulse_resolution

__all__ = ["FrictionSweep", "friction_levels", "friction_sweep"]


def friction_levels(n: int = 25) -> np.ndarray:
    """The paper's load-friction levels f_l* = 10^(-2 + 2 i/(n-1)), i = 0..n-1 (0.01 ... 1; 0.1 in the middle)."""
    n = whole("levels", n, 2)
    return 10.0 ** (-2.0 + 2.0 * np.arange(n) / (n - 1))


@dataclass
class FrictionSweep:
    """The impulse protocol at every load-friction level. ``results[i]`` belongs to ``f_l_star[i]``."""

    f_l_star: np.ndarray
    results: list[ImpulseResolution]

    def to_frame(self) -> pd.DataFrame:
        """One row per level: amplitudes (tau*), increments in um at the arm, the first increment, wall time."""
        rows = []
        for f, r in zip(self.f_l_star, self.results):
            first, median = r.increments_m[0], r.median_m
            rows.append(dict(f_l_star=f, threshold_amplitude=r.threshold_amplitude,
                             operating_amplitude=r.operating_amplitude, resolution_um=r.resolution_m * 1e6,
                             median_um=median * 1e6, min_um=r.min_m * 1e6, std_um=r.std_m * 1e6,
                             first_increment_um=first * 1e6, first_over_median=first / median if median else np.inf,
                             n_pulses=r.n_pulses, elapsed_s=r.elapsed_s))
        return pd.DataFrame(rows)

    def at(self, f_l_star: float) -> ImpulseResolution:
        """The result at the level nearest to ``f_l_star`` (in log scale)."""
        return self.results[int(np.argmin(abs(np.log(self.f_l_star) - math.log(f_l_star))))]

    def trend(self, column: str = "resolution_um") -> dict[str, float]:
        """Least-squares line ``column = slope * f_l* + intercept`` with R^2 (the paper says: linear in f_l*)."""
        df = self.to_frame()
        x, y = df["f_l_star"].to_numpy(), df[column].to_numpy()
        slope, intercept = np.polyfit(x, y, 1)
        resid = y - (slope * x + intercept)
        ss_tot = float(np.sum((y - y.mean()) ** 2))
        r2 = 1.0 - float(np.sum(resid**2)) / ss_tot if ss_tot > 0 else float("nan")
        return dict(slope_um=float(slope), intercept_um=float(intercept), r2=r2)

    def plot(self, out_dir: str | Path, at_f_l_star: float = 0.1) -> dict[str, Path]:
        """The four plots of the paper's section V as PNGs in ``out_dir``."""
        out = Path(out_dir)
        df, ref = self.to_frame(), self.at(at_f_l_star)
        um = ref.increments_m * 1e6
        fig, ax = figure()
        ax.hist(um, bins=50)
        ax.set(xlabel="arm increment [µm]", ylabel="pulses",
               title=f"Histogram, f_l* = {ref.params.f_l_star:.3g}, N = {um.size}")
        paths = {"histogram_fl0.1": save(fig, out / "histogram_fl0.1.png")}
        fig, ax = figure()
        ax.plot(np.arange(1, um.size + 1), um, ".", ms=3)
        ax.set(xlabel="pulse number", ylabel="arm increment [µm]",
               title=f"Increment vs pulse number, f_l* = {ref.params.f_l_star:.3g}")
        paths["sequence_fl0.1"] = save(fig, out / "sequence_fl0.1.png")
        fig, ax = figure()
        for col, label in (("resolution_um", "max (resolution)"), ("median_um", "median"), ("min_um", "min")):
            ax.plot(df["f_l_star"], df[col], "o-", ms=3, label=label)
        t = self.trend()
        ax.plot(df["f_l_star"], t["slope_um"] * df["f_l_star"] + t["intercept_um"], "k--", lw=0.8,
                label=f"linear fit of max: slope {t['slope_um']:.3g} µm, R^2 {t['r2']:.2f}")
        ax.set(xlabel="load friction level f_l*", ylabel="arm increment [µm]", title="Increment vs friction level")
        ax.legend(fontsize=8)
        paths["delta_vs_friction"] = save(fig, out / "delta_vs_friction.png")
        fig, ax = figure()
        ax.plot(df["f_l_star"], df["std_um"], "o-", ms=3)
        ax.set(xlabel="load friction level f_l*", ylabel="std of increments [µm]",
               title="Standard deviation vs friction level")
        paths["std_vs_friction"] = save(fig, out / "std_vs_friction.png")
        return paths


def _impulse_task(task: tuple[DriveParams, int, dict[str, Any]]) -> ImpulseResolution:
    params, n_pulses, kw = task
    return impulse_resolution(params, n_pulses, **kw)


def friction_sweep(params: DriveParams | None = None, levels: int | Sequence[float] = 25, n_pulses: int = 1000,
                   *, scheduler: str | None = None, workers: int | None = None, progress: bool = False,
                   **protocol: Any) -> FrictionSweep:
    """The impulse protocol at each load-friction level (f_l* = f_l/f_m), other parameters from ``params``.

    Levels run in parallel on Dask (``ident.protocols.batch.run_batch``: with the compiled protocol loops, the
    default, threads of this process; with ``loop="python"``, local worker processes; the cluster at ``scheduler``
    if given; serial with ``workers=0``); the results do not depend on where they ran.
    """
    from .batch import run_batch
    from .compiled import check_loop

    base = params or DriveParams()
    f = friction_levels(levels) if isinstance(levels, (int, np.integer)) else np.asarray(levels, dtype=float)
    if f.size == 0 or not np.all(np.isfinite(f) & (f >= 0)):
        raise ValueError(f"friction levels must be finite numbers >= 0, got {levels!r}")
    n_pulses = whole("n_pulses", n_pulses, 1)
    tasks = [(base.with_values(f_l_star=float(x)), n_pulses, protocol) for x in f]
    threads = check_loop(protocol.get("loop", "compiled")) == "compiled"
    results = run_batch(_impulse_task, tasks, scheduler=scheduler, workers=workers, progress=progress,
                        desc="friction levels", threads=threads)
    return FrictionSweep(f, results)
