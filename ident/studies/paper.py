"""The resolution study of the paper (sections III-V) on one drive, written as a markdown report with plots.

``run_study`` computes; ``write_study`` writes everything into a staging folder and moves it into place only when
complete, so a failed run never leaves a report that looks finished. The verdicts are in ``paper_claims``, the
report's text in ``paper_report`` (every sentence that states a finding is chosen by the numbers it describes).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from tqdm import tqdm

from ..common.output import staged_folder
from ..common.units import plain_json, si_keys
from ..model.params import DriveParams
from ..protocols.resolution import ImpulseResolution, LinearResolution, impulse_resolution, linear_resolution
from ..protocols.sweep import FrictionSweep, friction_sweep
from ..protocols.transient import Transient, start_up_transient
from .paper_claims import PAPER, Verdict, avalanche, growth, study_verdicts
from .paper_report import report_markdown

__all__ = ["PAPER", "Study", "run_study", "shows_own_level", "write_report", "write_study"]



@dataclass
class Study:
    """Linear and impulse resolution of one drive plus the friction sweep around it."""

    params: DriveParams
    linear: LinearResolution
    impulse: ImpulseResolution
    sweep: FrictionSweep

    def claims(self) -> list[Verdict]:
        """The paper's claims against this study's figures, each with its computed verdict."""
        return study_verdicts(self.linear.resolution_m, self.linear.counts, self.impulse.resolution_m, self.sweep)

    def comparison(self) -> pd.DataFrame:
        """Paper vs model, one row per claim, with the verdict and its criterion."""
        return pd.DataFrame([(c.claim, c.paper, c.model, c.verdict, c.criterion) for c in self.claims()],
                            columns=["claim", "paper", "model", "verdict", "criterion"])

    def avalanche(self) -> dict[str, Any]:
        """The start of the highest-friction experiment (``paper_claims.avalanche``)."""
        return avalanche(self.sweep)

    def transient(self) -> Transient:
        """The start-up transient of the impulse experiment at A_op (``protocols.transient``)."""
        return start_up_transient(self.impulse.increments_m)

    def sweep_transients(self) -> list[Transient]:
        """The start-up transient of every level's experiment, in the sweep's order."""
        return [start_up_transient(r.increments_m) for r in self.sweep.results]

    def summary(self) -> dict[str, Any]:
        """Everything the report states, as plain numbers (SI keys once passed through ``common.units.si_keys``)."""
        return {
            "params": self.params.to_dict(),
            "linear": dict(self.linear.summary()),
            "impulse": {**self.impulse.summary(), "transient": self.transient().to_dict()},
            "trend": self.sweep.trend(),
            "trend_median": self.sweep.trend("median_um"),
            "growth": growth(self.sweep),
            "avalanche": self.avalanche(),
            "claims": [{"key": c.key, "holds": c.holds, "model": c.model, "criterion": c.criterion}
                       for c in self.claims()],
        }


def run_study(params: DriveParams | None = None, *, n_pulses: int = 1000, n_steps: int = 1000, levels: int = 25,
              scheduler: str | None = None, workers: int | None = None, progress: bool = False) -> Study:
    """Linear resolution, impulse resolution and the friction sweep of ``params`` (nominal drive by default)."""
    params = params or DriveParams()
    with tqdm(total=3, desc="study", disable=not progress) as bar:
        bar.set_postfix_str("linear PD")
        linear = linear_resolution(params, n_steps=n_steps)
        bar.update()
        bar.set_postfix_str("impulse")
        impulse = impulse_resolution(params, n_pulses=n_pulses)
        bar.update()
        bar.set_postfix_str("friction sweep")
        sweep = friction_sweep(params, levels, n_pulses, scheduler=scheduler, workers=workers, progress=progress)
        bar.update()
    return Study(params, linear, impulse, sweep)


def write_report(study: Study, out_dir: str | Path) -> Path:
    """Write report.md, CSV tables, JSON summary and PNG plots of ``study`` into ``out_dir`` (created)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    study.sweep.to_frame().to_csv(out / "sweep.csv", index=False)
    study.impulse.to_frame().to_csv(out / "impulse_increments.csv", index=False)
    study.linear.to_frame().to_csv(out / "linear_increments.csv", index=False)
    study.linear.plot(out / "linear.png")
    study.impulse.plot(out / "impulse.png")
    own = shows_own_level(study)
    plots = study.sweep.plot(out, at_f_l_star=None if own else 0.1)
    (out / "summary.json").write_text(json.dumps(plain_json(si_keys(study.summary())), indent=2))
    (out / "report.md").write_text(report_markdown(study, plots, own))
    return out / "report.md"


def shows_own_level(study: Study) -> bool:
    """Is the sweep's experiment at f_l* = 0.1 (the paper's figs. 7-8) the study's own impulse experiment? Then
    section IV already shows it and the sweep draws no copy."""
    ref = study.sweep.at(0.1)
    return bool(np.isclose(ref.params.f_l_star, study.params.f_l_star, rtol=1e-12)
                and np.array_equal(ref.increments_m, study.impulse.increments_m))


def write_study(out_dir: str | Path, params: DriveParams | None = None, **kw: Any) -> tuple[Study, Path]:
    """Run the study and write its report; files appear in ``out_dir`` only once everything has succeeded."""
    study = run_study(params, **kw)
    with staged_folder(out_dir, last="report.md") as staging:
        write_report(study, staging)
    return study, Path(out_dir) / "report.md"
