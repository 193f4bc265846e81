"""The rigid diagnosis's own report sections: the IDIM-LS settings, every step's relative errors beside a published
reference (e.g. the EMPS paper's), the final parameters, and the regime tables of the base and final models."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from ...common.markdown import md_table
from .rigid_idim import Spec

_REGIME_COLUMNS = ["regime", "n", "share_samples_pct", "share_energy_pct", "energy_ratio", "bias", "bias_t", "rms"]
_REGIME_FORMATS = {"share_samples_pct": ".1f", "share_energy_pct": ".1f", "energy_ratio": ".2f", "bias": ".3g",
                   "bias_t": ".1f", "rms": ".3g"}


def sections(plugin: Any, models: list[Any]) -> list[str]:
    """Markdown sections of a rigid diagnosis (``plugin``: the rigid plug-in, ``models``: the sequence)."""
    from .rigid import model_label
    from .rigid_residuals import regimes

    s, ref, final = plugin.settings, plugin.reference, models[-1].state.fit
    out = [f"## Rigid model: {Path(plugin.log.source).name}", "",
           f"Training: `{plugin.train.source}`; held-back: `{plugin.held_log.source}`. Equation-error IDIM pipeline "
           f"(`ident/fitting/rigid.py`): w_dyn = {s.f_dyn_hz:.4g} Hz ({s.f_dyn_source}), Butterworth "
           f"{s.butter_order} at {s.butter_cutoff_hz:.4g} Hz, decimation by {s.decim_factor}"
           f"{'' if plugin.emps else ', sliding rows only'}. Every model is `ident.model.effects.rigid_force` "
           "(CasADi SX); the coordinates are solved by IPOPT and checked against lstsq (largest relative difference "
           f"in the final model {final.casadi_vs_lstsq:.1e}).", "",
           "### Steps (relative error = the EMPS PDF's eq. 11 on the decimated force)", "", _steps(models, ref), ""]
    published = ref.params if ref is not None and model_label(final.spec) == ref.params_model else {}
    out += ["### Final parameters", "",
            md_table(pd.DataFrame([(k, f"{v:.6g}", f"{published[k]:.4f}" if k in published else "")
                                   for k, v in final.params().items()],
                                  columns=["parameter", "value", "published"])), ""]
    if final.spec.asym:
        p = final.params()
        out += [f"asymmetric_friction is the PDF's eq. 12 (Fc+, Fc-, and Fv+, Fv- when viscous friction is in the "
                f"model; no offset, which the Coulomb asymmetry absorbs). In library/FMU parameters: "
                f"friction_asymmetry = {p['friction_asymmetry']:+.4f} (Coulomb), viscous_asymmetry = "
                f"{p.get('viscous_asymmetry', 0.0):+.4f} on Fv = (Fv+ + Fv-)/2.", ""]
    if ref is not None:
        out += [f"### Against the paper ({ref.citation})", ""] + [f"- {n}" for n in ref.notes] + [""]
    out += ["### Residual regimes of the base model (training)", "",
            md_table(regimes(models[0].state.fit.e, plugin.p)[_REGIME_COLUMNS], _REGIME_FORMATS), "",
            "### Residual regimes of the final model (training)", "",
            md_table(regimes(final.e, plugin.p)[_REGIME_COLUMNS], _REGIME_FORMATS), ""]
    return out


def _steps(models: list[Any], ref: Any) -> str:
    from .rigid import model_label

    rows = []
    for i, m in enumerate(models):
        label = model_label(Spec(frozenset(m.effects)))
        paper_train, paper_held = ("", "") if ref is None else ref.step_errors.get(label, ("-", "-"))
        rows.append((i, ", ".join(m.effects) or "(base)", label, f"{m.metrics['relative_error_pct']:.4f}",
                     paper_train, f"{m.metrics['heldback_relative_error_pct']:.4f}", paper_held, f"{m.bic():.1f}"))
    return md_table(pd.DataFrame(rows, columns=["step", "effects", "model", "training rel. error [%]", "paper",
                                                "held-back rel. error [%]", "paper (held back)", "BIC"]))
