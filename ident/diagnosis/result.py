"""Result types of the discrepancy workflow (``ident.diagnose``), shared by the two-inertia and the rigid path.

A diagnosis is a sequence of :class:`DiagnosisStep` (the base model, then one effect added per step), the effects it
named (:class:`NamedEffect`), the regimes where structure is left that no library effect explains, and the exported
FMU. ``to_dict()`` is the CLI's ``--json`` shape: ``steps``, ``effects``, ``unexplained``, ``fmu``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import pandas as pd


@dataclass
class DiagnosisStep:
    """One model of the sequence: what was added, how well it fits (on the held-back data) and its candidates.

    ``score``: the evidence for the added effect: the held-back cost ratio (cost without / cost with the effect;
    1 = no gain); ``None`` for the base model. ``candidates`` ranks every candidate tried at this step.
    """

    added: str | None
    nrmse_load: float | None
    nrmse_motor: float | None
    relative_error_pct: float
    score: float | None
    params: dict[str, float]
    candidates: pd.DataFrame = field(default_factory=pd.DataFrame)
    predicted_resolution_um: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"added": self.added, "nrmse_load": self.nrmse_load, "nrmse_motor": self.nrmse_motor,
                "relative_error_pct": self.relative_error_pct, "score": self.score,
                "predicted_resolution_um": self.predicted_resolution_um, "params": self.params,
                "candidates": self.candidates.to_dict(orient="records"), **self.extra}


@dataclass
class NamedEffect:
    """An effect the workflow named: its fitted magnitude (``unit``) with a 95 % interval, the evidence, and how
    sure the choice was against the runner-up (``margin``: the winner's held-back score / the runner-up's)."""

    name: str
    magnitude: float
    ci95: tuple[float, float]
    unit: str
    evidence: str
    runner_up: str | None
    margin: float | None
    params: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "magnitude": self.magnitude, "ci95": list(self.ci95), "unit": self.unit,
                "evidence": self.evidence, "runner_up": self.runner_up, "margin": self.margin, "params": self.params}


@dataclass
class Diagnosis:
    """Result of ``ident.diagnose(log)``."""

    model: str                      # base model: "two-inertia" or "rigid"
    steps: list[DiagnosisStep]
    effects: list[NamedEffect]
    unexplained: list[dict[str, Any]]   # regimes with structure left: {"regime", "share_pct", "detail"}
    residual_table: pd.DataFrame        # ranked residual localisation of the final model
    fmu: str | None = None
    files: dict[str, str] = field(default_factory=dict)
    elapsed_s: float = 0.0
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.model, "steps": [s.to_dict() for s in self.steps],
                "effects": [e.to_dict() for e in self.effects], "unexplained": self.unexplained, "fmu": self.fmu,
                "residual_table": self.residual_table.to_dict(orient="records"), "files": self.files,
                "elapsed_s": self.elapsed_s, "notes": self.notes}

    def to_frame(self) -> pd.DataFrame:
        """One row per step: what was added and the gap after it."""
        return pd.DataFrame([{k: v for k, v in s.to_dict().items() if k not in ("params", "candidates")}
                             for s in self.steps])


@dataclass
class PublishedReference:
    """Published figures of a data set, printed beside the diagnosis's own (e.g. the EMPS paper's for its logs).

    ``step_errors`` maps a model label as the report writes it (e.g. ``"M, Fc, offset, Fv"``) to the published
    (training, held-back) relative errors as text; ``params`` holds the published parameters of the model labelled
    ``params_model``; ``notes`` are bullet lines for the report's "Against the paper" section. The diagnosis knows no
    data set: whoever loads one passes its reference (``ident.studies.emps.emps_reference``)."""

    citation: str
    step_errors: dict[str, tuple[str, str]]
    params_model: str
    params: dict[str, float]
    notes: list[str] = field(default_factory=list)

