"""What the two-inertia plug-in reports: where the load residual lives (regimes), what is left unexplained, each
step's record, how its grids were derived, and its plots."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ...common.plotting import figure, save
from ...fitting.logs import DriveLog
from ...model.params import DriveParams
from ..result import DiagnosisStep

#: a regime holds structure when its share of the residual energy is this many times its share of the samples ...
EXCESS = 2.0
#: ... or its mean residual is this many standard errors from zero
BIAS_SIGMA = 10.0


def residual_regimes(log: DriveLog, sim: dict[str, np.ndarray], sigma_l: float, f_m: float) -> pd.DataFrame:
    """Ranked table of where the load residual lives: for each regime its share of the samples, its share of the
    residual energy, their ratio (``excess``), the mean residual in standard errors (``bias_sigma``) and the RMS."""
    res = sim["res_l"]
    e = res**2
    total = float(e.sum()) or 1.0
    rows = []
    for name, m in _masks(log, sim, f_m).items():
        cnt = int(m.sum())
        if cnt < 20:
            continue
        share_e, share_n = float(e[m].sum()) / total, cnt / res.size
        mean = float(res[m].mean())
        spread = max(float(np.mean(res[m] ** 2)) / sigma_l**2, 1.0)
        rows.append({"regime": name, "share_samples_pct": 100 * share_n, "share_residual_pct": 100 * share_e,
                     "excess": share_e / share_n, "bias_sigma": mean / sigma_l * math.sqrt(cnt / spread),
                     "rms_rad": float(np.sqrt(np.mean(res[m] ** 2))), "mean_rad": mean})
    return pd.DataFrame(rows).sort_values("excess", ascending=False, ignore_index=True)


def _masks(log: DriveLog, sim: dict[str, np.ndarray], f_m: float) -> dict[str, np.ndarray]:
    v_l, v_m = sim["v_l"], sim["v_m"]
    tau = np.abs(np.append(log.motor_torque_Nm[:-1], 0.0)) / f_m
    slipping = v_l != 0.0
    speeds = np.abs(v_l[slipping])
    qs = np.quantile(speeds, [0.5, 0.9]) if speeds.size > 10 else [np.inf, np.inf]
    phase = np.mod(2 * sim["q_m"], 2 * math.pi)
    masks = {
        "load stuck": ~slipping, "load slipping": slipping,
        "motor stuck": v_m == 0.0, "motor slipping": v_m != 0.0,
        "load slow (below median speed)": slipping & (np.abs(v_l) <= qs[0]),
        "load fast (above 90th percentile speed)": slipping & (np.abs(v_l) > qs[1]),
        "load moving +": v_l > 0, "load moving -": v_l < 0,
        "torque off": tau == 0, "torque below breakaway (tau* < 1)": (tau > 0) & (tau < 1),
        "torque 1-2 (slow moves)": (tau >= 1) & (tau < 2), "torque >= 2 (pulses)": tau >= 2,
    }
    for k in range(4):
        masks[f"motor angle phase 2q_m in [{k * 90}, {(k + 1) * 90}) deg"] = (
            (phase >= k * math.pi / 2) & (phase < (k + 1) * math.pi / 2))
    return masks


def unexplained(table: pd.DataFrame, over_noise: float) -> list[dict[str, Any]]:
    """Regimes still holding structure when the model is above the noise (``over_noise``: its residual RMS over the
    load sensor's noise, the larger of training and held-back): where the residual energy or bias sits (``EXCESS``,
    ``BIAS_SIGMA``)."""
    if table.empty:
        return []
    out = []
    for row in table.itertuples():  # ranked by excess; a regime holding no more than its share is not "where"
        if len(out) == 4 or row.excess <= 1.0:
            break
        if row.excess > EXCESS or abs(row.bias_sigma) > BIAS_SIGMA:
            out.append({"regime": row.regime, "share_pct": round(row.share_residual_pct, 2),
                        "detail": f"{row.share_residual_pct:.1f} % of the residual energy in "
                                  f"{row.share_samples_pct:.1f} % of the samples (x{row.excess:.1f}), mean "
                                  f"{row.mean_rad:.3g} rad ({row.bias_sigma:+.1f} standard errors); the final model "
                                  f"leaves the load {over_noise:.3g}x its sensor noise"})
    if not out:
        out.append({"regime": "whole log", "share_pct": 100.0,
                    "detail": f"residual {over_noise:.3g}x the load sensor noise, spread evenly over the regimes "
                              f"(no regime holds more than {EXCESS:g}x its share of the samples)"})
    return out


def step(model: Any, added: str | None, score: float | None, extra: dict[str, Any],
         resolution_pulses: int) -> DiagnosisStep:
    """The report's record of one two-inertia model."""
    m = model.metrics
    params = model.state.params
    values = {k: float(v) for k, v in params.to_dict().items()}
    rigid = model.state.rigid
    res = None if rigid or not resolution_pulses else _resolution_um(params, resolution_pulses)
    return DiagnosisStep(added, m["nrmse_load"], None if rigid else m["nrmse_motor"], m["relative_error_pct"], score,
                         values, pd.DataFrame(), res,
                         {**extra, "heldback_nrmse_load": m["heldback_nrmse_load"],
                          "heldback_relative_error_pct": m["heldback_relative_error_pct"], "bic": model.bic(),
                          "residual_over_noise_load": m["residual_over_noise_load"],
                          "train_over_noise_load": m["train_over_noise_load"],
                          "heldback_over_noise_load": m["heldback_over_noise_load"],
                          "noise_load_rad": m["noise_load_rad"],
                          "effects": list(model.effects),
                          **({"model": "rigid kinematics q_l = r q_m"} if rigid else {})})


def _resolution_um(params: DriveParams, n_pulses: int) -> float | None:
    from ...protocols.resolution import ThresholdNotFound, impulse_resolution

    try:
        return float(impulse_resolution(params, n_pulses=n_pulses).resolution_m * 1e6)
    except (ThresholdNotFound, RuntimeError):
        return None


def derivations() -> list[str]:
    """How the two-inertia screen's grids and the fits' scales follow from the data sheet and the log."""
    return ["every effect's unknowns are scaled by what the log shows through the base fit "
            "(ident/diagnosis/models/coordinates.py): viscous coefficients by the friction level over the typical "
            "slip speed, hardening by 1/d95^2, hysteresis torque by K_s d95 and its saturation deflection by d95, "
            "kinematic error by d95; the refits start from the screen's Gauss-Newton step, not from fixed values",
            "Stribeck velocity grid of the screen: 8 geometric steps from a tenth of the load's 5 % slip speed to its "
            "95 % slip speed; hysteresis saturation-deflection grid: 0.03, 0.1, 0.3 and 1 x d95; the "
            "other effects are linear at zero (kinematic error as the sine and cosine parts of its 2/rev and 4/rev "
            "harmonics) and need no grid"]


def plots(log: DriveLog, stop: int, models: list[Any], out: Path) -> dict[str, str]:
    """Residual vs time (base and final), residual vs state, measured vs simulated load."""
    first, last = models[0], models[-1]
    files = {}
    t = log.time_s
    fig, axes = figure(2, 1, size=(11, 6), sharex=True)
    for ax, m, title in ((axes[0], first, "base model"), (axes[1], last, "final model")):
        res = m.state.sim["res_l"] if m.state.sim is not None else None
        if res is not None:
            ax.plot(t, res * 1e9, lw=0.5)
        ax.axvline(t[stop], color="k", ls="--", lw=0.8)
        ax.set_ylabel("load residual [nrad]")
        ax.set_title(f"{title}: {' + '.join(m.effects) or 'no effects'} (dashed: start of the held-back part)")
    axes[1].set_xlabel("time [s]")
    files["residual_vs_time"] = save(fig, out / "residual_vs_time.png").name
    sims = [(m.state.sim, label) for m, label in ((first, "base"), (last, "final"))
            if m.state.sim is not None and "v_l" in m.state.sim]
    if sims:
        files["residual_vs_state"] = _state_plot(log, stop, sims, out)
        files["fit"] = _fit_plot(log, stop, sims, out)
    return files


def _state_plot(log: DriveLog, stop: int, sims: list[tuple[dict[str, np.ndarray], str]], out: Path) -> str:
    fig, axes = figure(1, 3, size=(15, 4.5))
    for sim, label in sims:
        axes[0].plot(sim["v_l"], sim["res_l"] * 1e9, ".", ms=1, alpha=0.4, label=label)
        axes[1].plot(np.mod(2 * sim["q_m"], 2 * math.pi), sim["res_l"] * 1e9, ".", ms=1, alpha=0.4, label=label)
    axes[0].set_xlabel("model load velocity [rad/s]")
    axes[1].set_xlabel("2 q_m mod 2 pi [rad] (kinematic-error phase)")
    for ax in axes[:2]:
        ax.set_ylabel("load residual [nrad]")
        ax.legend(markerscale=8)
    twist = log.meta.r * (log.motor_pos_rad + 0.5 * 2 * math.pi / log.meta.encoder_counts_per_rev) - log.load_pos_rad
    twist = twist - np.mean(twist[:stop])
    axes[2].plot(twist * 1e6, sims[-1][0]["spring_torque"], lw=0.3)
    axes[2].set_xlabel("measured twist r q_m - q_l (zero removed) [urad]")
    axes[2].set_ylabel("final model spring torque [N m]")
    return save(fig, out / "residual_vs_state.png").name


def _fit_plot(log: DriveLog, stop: int, sims: list[tuple[dict[str, np.ndarray], str]], out: Path) -> str:
    fig, ax = figure(size=(11, 4))
    t = log.time_s
    ax.plot(t, log.load_pos_rad * 1e6, lw=0.6, label="measured")
    for sim, label in sims:
        ax.plot(t, sim["q_l"] * 1e6, lw=0.5, label=f"{label} model")
    ax.axvline(t[stop], color="k", ls="--", lw=0.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("load angle [urad]")
    ax.legend()
    return save(fig, out / "fit.png").name
