"""The report of a diagnosis (any model): markdown, JSON, the model's plots and its exported FMU.

Written into a staging folder and moved into place only when everything succeeded (nothing half-written); the
markdown last, so that a report that exists is complete."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..common.markdown import md_table
from ..common.output import staged_folder
from ..common.units import after_number
from .result import Diagnosis, json_default

_STEP_COLUMNS = ("added", "removed", "nrmse_load", "nrmse_motor", "relative_error_pct", "heldback_nrmse_load",
                 "heldback_relative_error_pct", "train_over_noise_load", "heldback_over_noise_load", "score", "dm_p",
                 "delta_bic", "runner_up", "margin", "predicted_resolution_um")
_SCREEN_FORMATS = {"lm_statistic": ".4g", "lm_robust": ".4g", "p_value": ".3g", "detectable": ".3g",
                   "detectable_worst": ".3g"}
_CANDIDATE_FORMATS = {"evaluations": ".1f", "heldback_gain": ".5g", "train_gain": ".5g", "delta_bic": ".1f",
                      "dm_p": ".3g", "drop_test_gain": ".5g"}


def write_diagnosis(diag: Diagnosis, plugin: Any, models: list[Any], out_dir: str | Path, *,
                    export_fmu: bool = True) -> Path:
    """Write diagnosis.md, diagnosis.json, the plots and (``export_fmu``) the fitted model's FMU into ``out_dir``."""
    out = Path(out_dir)
    with staged_folder(out, last="diagnosis.md") as stage:
        files = plugin.plots(models, stage)
        if export_fmu:
            fmu, note = plugin.export(models[-1], stage)
            diag.fmu = None if fmu is None else str(out / fmu.name)
            diag.fmu_note = note
        else:
            diag.fmu_note = "not exported (export_fmu=False)"
        diag.files = {k: str(out / v) for k, v in files.items()}
        diag.files["report"] = str(out / "diagnosis.md")
        diag.files["json"] = str(out / "diagnosis.json")
        (stage / "diagnosis.json").write_text(json.dumps(diag.to_dict(), indent=2, default=json_default))
        (stage / "diagnosis.md").write_text(markdown(diag, files, plugin.report_sections(models)))
    return out


def markdown(diag: Diagnosis, files: dict[str, str], sections: list[str]) -> str:
    """The report's markdown."""
    lines = ["# hdrive diagnosis", "", f"Base model: **{diag.model}**. The first part of the log trains every "
             "model; the rest is held back and only predicted. Every candidate effect is first screened (score test "
             "at the current model); the few that pass are refitted; one is named only when its held-back gain is "
             "significant (see `ident/diagnosis/engine.py`).", "", "## Conclusions", ""]
    lines += [f"- {s}" for s in diag.summary] + ["", "## The gap after every step", "", _steps_table(diag), ""]
    lines += ["## Named effects", ""] + _effects(diag) + [""]
    lines += _screens(diag)
    lines += ["## Where the final model and the log still disagree", "",
              md_table(diag.residual_table) if len(diag.residual_table) else "(no table)", ""]
    lines += ["**Unexplained structure** (no library effect removes it):", ""] + \
        [f"- {u['regime']}: {u['detail']}" for u in diag.unexplained] if diag.unexplained else \
        ["Nothing significant is left unexplained."]
    lines += ["", "## How the grids were derived", ""] + [f"- {d}" for d in diag.derivations]
    lines += ["", f"Budget: {diag.budget if diag.budget is not None else 'unlimited'} training logs simulated per "
              "candidate fit (a count; a size probe's simulation of a model costlier than the one its search started "
              "from counts as many as the FMU's model evaluations say: the answer does not depend on the machine's "
              "speed).", ""]
    lines += ["## Final model parameters", ""] + [f"- {k} = {_num(v)}" for k, v in diag.steps[-1].params.items()]
    lines += ["", "## Fitted model as an FMU", "",
              (f"`{Path(diag.fmu).name}`: " if diag.fmu else "No FMU: ") + diag.fmu_note, ""]
    lines += sections
    lines += ["## Plots", ""] + [f"![{k}]({v})" for k, v in files.items()]
    lines += ["", "## Notes", ""] + [f"- {n}" for n in diag.notes]
    lines += ["", f"Answer fingerprint (SHA-256 of the answer without its wall times and file paths; another run "
              f"on this log gives the same one on this kind of CPU): `{diag.fingerprint()}`"]
    return "\n".join(lines) + "\n"


def _num(v: Any) -> str:
    return f"{v:.6g}" if isinstance(v, (float, int, np.floating)) else str(v)


def _steps_table(diag: Diagnosis) -> str:
    steps = diag.to_frame()
    if "removed" in steps:
        steps["removed"] = [", ".join(r) if isinstance(r, list) else "" for r in steps["removed"]]
    keep = [c for c in _STEP_COLUMNS if c in steps]
    return md_table(steps[keep])


def _effects(diag: Diagnosis) -> list[str]:
    if not diag.effects:
        return ["None: no library effect improves the held-back prediction significantly."]
    out = []
    for e in diag.effects:
        sure = f"**tentative**: {e.why_tentative}" if e.tentative else "confident"
        out.append(f"- **{e.name}**{' (' + e.shape + ', the shape the log preferred)' if e.shape else ''}: "
                   f"{e.magnitude:.5g}{after_number(e.unit)} (95 % interval {e.ci95[0]:.5g} .. {e.ci95[1]:.5g}); "
                   f"{sure}. Evidence: {e.evidence}." + (f" Size: {e.size_note()}." if e.size_check else "")
                   + (f" Shape: {e.shape_note()}." if e.shape_check else ""))
    return out


def _screens(diag: Diagnosis) -> list[str]:
    lines = ["## Screen and refits at each step", ""]
    for i, s in enumerate(diag.steps):
        if not len(s.screen) and not len(s.candidates):
            continue
        model = ", ".join(s.extra.get("effects", [])) or "base"
        screen = s.screen
        if "detectable" in screen and screen.detectable.isna().all():   # a model with no detection limit
            screen = screen.drop(columns=["detectable", "unit", "detectable_at", "detectable_worst",
                                         "detectable_worst_at"])
        screen = screen.drop(columns=["record"], errors="ignore")   # said in the conclusions
        lines += [f"### Step {i} (model: {model})", "", "Score test of every candidate (ranked):", "",
                  md_table(screen, _SCREEN_FORMATS), ""]
        if len(s.candidates):
            lines += ["Refitted:", "", md_table(s.candidates, _CANDIDATE_FORMATS), ""]
    if diag.not_ruled_out:
        lines += ["Not ruled out (could not be fitted):", ""]
        lines += [f"- step {c['step']}: {c['candidate']}: {c['reason']}" for c in diag.not_ruled_out] + [""]
    return lines
