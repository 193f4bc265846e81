"""Where a rigid model and its log disagree: the ranked residual regimes, the unexplained structure, the
residual spectrum's flexibility signature, and the rigid diagnosis's plots."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import scipy.signal as sg

from ...common.plotting import figure, save
from .rigid_idim import Processed, RigidModelFit

#: a regime holds structure when its share of the residual energy is this many times its share of the rows and its
#: bias is this many standard errors from zero; a strong bias alone counts on a regime of >= 10 % of the rows
UNEXPLAINED_ENERGY_RATIO = 2.0
UNEXPLAINED_BIAS_T = 3.0
UNEXPLAINED_STRONG_BIAS_T = 5.0


def regimes(e: np.ndarray, p: Processed) -> pd.DataFrame:
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


def unexplained(table: pd.DataFrame, data: str) -> list[dict[str, Any]]:
    out = []
    for _, r in table.iterrows():
        concentrated = r.energy_ratio >= UNEXPLAINED_ENERGY_RATIO and (
            abs(r.bias_t) >= UNEXPLAINED_BIAS_T
            # zero-mean but concentrated: oscillation after pulse steps, misfit around reversals
            or (r.kind in ("pulses", "stick-slip") and r.share_energy_pct >= 10.0))
        biased = abs(r.bias_t) >= UNEXPLAINED_STRONG_BIAS_T and r.share_samples_pct >= 10.0 \
            and r.kind in ("direction", "position", "speed")
        if concentrated or biased:
            out.append({"regime": f"{data}: {r.regime}", "share_pct": round(float(r.share_energy_pct), 2),
                        "detail": f"{r.share_energy_pct:.1f} % of the residual energy on {r.share_samples_pct:.1f} % "
                                  f"of the rows ({r.energy_ratio:.1f}x), bias {r.bias:+.3g} (t = {r.bias_t:+.1f}), "
                                  f"rms {r.rms:.3g}. No library effect explains it; it suggests "
                                  f"{_SUGGEST.get(r.kind, 'an effect outside the library')}."})
    return out


def spectrum_check(fit: RigidModelFit, p: Processed, data: str) -> tuple[dict[str, Any] | None, dict[str, Any]]:
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


def plots(out: Path, base: RigidModelFit, final: RigidModelFit, p: Processed, ph: Processed, final_h: np.ndarray,
          base_h: np.ndarray, spectra: list[dict[str, Any]], unit_f: str, unit_v: str) -> dict[str, str]:
    """The residuals of the base and final models vs time and velocity (training), the held-back data and the
    residual spectra; written into ``out``, returns {key: file name}."""
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
    files["residuals_png"] = "rigid_residuals.png"

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
    files["heldback_png"] = "rigid_heldback.png"
    return files


# ------------------------------------------------------------------------------------------ workflow -----------
