"""The discrepancy report of a two-inertia diagnosis: markdown, JSON, plots and the fitted FMU.

Written into a staging folder and moved into place only when everything succeeded (nothing half-written).
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..common.markdown import md_table
from ..common.output import staged_folder
from ..common.plotting import figure, save
from ..fitting.logs import DriveLog
from .result import Diagnosis


def _plots(log: DriveLog, stop: int, models: list[Any], out: Path) -> dict[str, str]:
    first, last = models[0], models[-1]
    files = {}
    t = log.time_s
    fig, axes = figure(2, 1, size=(11, 6), sharex=True)
    for ax, m, title in ((axes[0], first, "base model"), (axes[1], last, "final model")):
        ax.plot(t, m.sim["res_l"] * 1e9, lw=0.5)
        ax.axvline(t[stop], color="k", ls="--", lw=0.8)
        ax.set_ylabel("load residual [nrad]")
        ax.set_title(f"{title}: {' + '.join(m.effects) or 'no effects'} (dashed: start of the held-back part)")
    axes[1].set_xlabel("time [s]")
    files["residual_vs_time"] = save(fig, out / "residual_vs_time.png").name

    fig, axes = figure(1, 3, size=(15, 4.5))
    for m, label in ((first, "base"), (last, "final")):
        axes[0].plot(m.sim["v_l"], m.sim["res_l"] * 1e9, ".", ms=1, alpha=0.4, label=label)
        axes[1].plot(np.mod(2 * m.sim["q_m"], 2 * math.pi), m.sim["res_l"] * 1e9, ".", ms=1, alpha=0.4, label=label)
    axes[0].set_xlabel("model load velocity [rad/s]")
    axes[1].set_xlabel("2 q_m mod 2 pi [rad] (kinematic-error phase)")
    for ax in axes[:2]:
        ax.set_ylabel("load residual [nrad]")
        ax.legend(markerscale=8)
    # torque vs twist: the measured twist (encoder and load sensor) against the final model's spring torque
    twist = log.meta.r * (log.motor_pos_rad + 0.5 * 2 * math.pi / log.meta.encoder_counts_per_rev) - log.load_pos_rad
    twist = twist - np.mean(twist[:stop])
    axes[2].plot(twist * 1e6, last.sim["spring_torque"], lw=0.3)
    axes[2].set_xlabel("measured twist r q_m - q_l (zero removed) [urad]")
    axes[2].set_ylabel("final model spring torque [N m]")
    files["residual_vs_state"] = save(fig, out / "residual_vs_state.png").name

    fig, ax = figure(size=(11, 4))
    ax.plot(t, log.load_pos_rad * 1e6, lw=0.6, label="measured")
    for m, label in ((first, "base"), (last, "final")):
        ax.plot(t, m.sim["q_l"] * 1e6, lw=0.5, label=f"{label} model")
    ax.axvline(t[stop], color="k", ls="--", lw=0.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("load angle [urad]")
    ax.legend()
    files["fit"] = save(fig, out / "fit.png").name
    return files


def _markdown(diag: Diagnosis, files: dict[str, str]) -> str:
    steps = diag.to_frame()
    if "removed" in steps:  # the backward elimination's step lists what it took out
        steps["removed"] = [", ".join(r) if isinstance(r, list) else "" for r in steps["removed"]]
    keep = [c for c in ("added", "removed", "nrmse_load", "nrmse_motor", "relative_error_pct", "heldback_nrmse_load",
                        "heldback_relative_error_pct", "residual_over_noise_load", "score",
                        "predicted_resolution_um") if c in steps]
    lines = ["# hdrive diagnosis", "",
             f"Base model: **{diag.model}**. The first part of the log trains every model; the rest is held back and "
             "only predicted (the model simulates the whole log). A candidate effect is accepted only when the "
             "held-back cost falls significantly and the model without it, refitted, predicts worse; the model with "
             "it is then identified from scratch; at the end every named effect must survive backward elimination "
             "(see `ident/diagnosis/engine.py`). `residual_over_noise_load`: load residual RMS / load sensor noise (1 = the "
             "model explains everything but the noise).", "",
             "## The gap after every step", "", md_table(steps[keep]), "",
             "## Named effects", ""]
    if diag.effects:
        for e in diag.effects:
            lines.append(f"- **{e.name}**: {e.magnitude:.4g} {e.unit} (95 % interval {e.ci95[0]:.4g} .. "
                         f"{e.ci95[1]:.4g}); runner-up {e.runner_up or '-'}"
                         + (f", margin {e.margin:.3g}x" if e.margin else "") + f". Evidence: {e.evidence}.")
    else:
        lines.append("None: no library effect improves the held-back fit significantly.")
    lines += ["", "## Candidates at each step", ""]
    for i, s in enumerate(diag.steps):
        if len(s.candidates):
            lines += [f"### Step {i} (model: {', '.join(s.extra.get('effects', [])) or 'base'})", "",
                      md_table(s.candidates), ""]
    lines += ["## Where the final model and the log still disagree", "", md_table(diag.residual_table), ""]
    if diag.unexplained:
        lines += ["**Unexplained structure** (no library effect removes it):", ""]
        lines += [f"- {u['regime']}: {u['detail']}" for u in diag.unexplained]
    else:
        lines.append("Nothing significant is left unexplained.")
    lines += ["", "## Final model parameters (SI)", ""]
    for k, v in diag.steps[-1].params.items():
        lines.append(f"- {k} = {v:.6g}")
    if diag.fmu:
        lines += ["", f"Fitted FMU (start values = the final model): `{Path(diag.fmu).name}`"]
    lines += ["", "## Plots", ""] + [f"![{k}]({v})" for k, v in files.items()]
    lines += ["", "## Notes", ""] + [f"- {n}" for n in diag.notes]
    return "\n".join(lines) + "\n"


def write_diagnosis(diag: Diagnosis, log: DriveLog, stop: int, models: list[Any], sigma_l: float,
                    out_dir: str | Path, *, export_fmu: bool = True) -> Path:
    """Write diagnosis.md, diagnosis.json, the plots and (``export_fmu``) the fitted FMU into ``out_dir``."""
    out = Path(out_dir)
    with staged_folder(out, last="diagnosis.md") as stage:
        files = _plots(log, stop, models, stage)
        if export_fmu:
            from ..model.export import export_fitted_fmu

            fmu = export_fitted_fmu(models[-1].params, stage / "HarmonicDrive_fitted.fmu")
            diag.fmu = str(out / fmu.name)
        diag.files = {k: str(out / v) for k, v in files.items()}
        diag.files["report"] = str(out / "diagnosis.md")
        (stage / "diagnosis.md").write_text(_markdown(diag, files))
        (stage / "diagnosis.json").write_text(json.dumps(diag.to_dict(), indent=2, default=float))
    return out
