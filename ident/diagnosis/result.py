"""Result types of the discrepancy workflow (``ident.diagnose``), shared by the two-inertia and the rigid path.

A diagnosis is a sequence of :class:`DiagnosisStep` (the base model, then one effect added per step), the effects it
named (:class:`NamedEffect`), the regimes where structure is left that no library effect explains, and the exported
FMU. ``to_dict()`` is the CLI's ``--json`` shape: ``steps``, ``effects``, ``unexplained``, ``fmu``.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from ..common.units import after_number


@dataclass
class DiagnosisStep:
    """One model of the sequence: what was added, how well it fits (on the held-back data) and its candidates.

    ``score``: the evidence for the added effect: the held-back cost ratio (cost without / cost with the effect;
    1 = no gain); ``None`` for the base model. ``screen`` holds the score test of every candidate at this step's
    model (``ident.diagnosis.screening``); ``candidates`` the ones refitted, with the acceptance rule's numbers.
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
    screen: pd.DataFrame = field(default_factory=pd.DataFrame)

    def to_dict(self) -> dict[str, Any]:
        return {"added": self.added, "nrmse_load": self.nrmse_load, "nrmse_motor": self.nrmse_motor,
                "relative_error_pct": self.relative_error_pct, "score": self.score,
                "predicted_resolution_um": self.predicted_resolution_um, "params": self.params,
                "screen": _records(self.screen), "candidates": _records(self.candidates), **self.extra}


@dataclass
class NamedEffect:
    """An effect the workflow named: its fitted magnitude (``unit``) with a 95 % interval, the evidence, and how
    sure the choice was against the runner-up (``margin``: the runner-up's held-back cost / the winner's).
    ``tentative``: the name is the library's best improvement, not an explanation; ``why_tentative`` says why
    (the final model stays above the noise, a candidate could not be fitted and was not ruled out, the runner-up
    predicts the held-back data as well, or the log does not pin the effect's size, or its size search moved it, or
    its size depends on a shape the log does not pin or prefers to the library's)."""

    name: str
    magnitude: float
    ci95: tuple[float, float]
    unit: str
    evidence: str
    runner_up: str | None
    margin: float | None
    params: dict[str, float] = field(default_factory=dict)
    tentative: bool = False
    why_tentative: str = ""
    #: the size's last check (``sizes.widen``): per probe the factor the size was held at, that size,
    #: the training cost's change in noise variances, and the local interval the probes were checked against
    size_check: list[dict[str, float]] = field(default_factory=list)
    #: the size's check against the effect's other shape (``ident.diagnosis.shapes``): the shape in words, its
    #: size there and 95 % interval, the training cost's change in noise variances, whether its refit was
    #: unfinished, and the residual it leaves over the noise (training, held back); {} when none
    shape_check: dict[str, Any] = field(default_factory=dict)
    #: the shape the size is measured in where it is not the library's ('' where it is): the log preferred it
    #: where the effect was named or at the final check (the engine's ``_adopt_shape``, ``_preferred``), and the
    #: exported FMU has it too
    shape: str = ""

    def size_note(self) -> str:
        """What the size probes showed, in words ('' when there were none)."""
        if not self.size_check:
            return ""
        rises = " and ".join(f"{c['delta_cost']:+.3g} at {c['factor']:.2g}x" for c in self.size_check)
        lo, hi = self.size_check[0]["local_lo"], self.size_check[0]["local_hi"]
        how = (f"wider than the local interval [{lo:.4g}, {hi:.4g}]" if self.ci95[0] < lo or self.ci95[1] > hi
               else "the local interval stands")
        return f"the size held either side, every other unknown refitted: training cost {rises} noise variances; {how}"

    def shape_note(self) -> str:
        """What the shape check showed, in words ('' when there was none)."""
        c = self.shape_check
        if not c:
            return ""
        return (f"refitted with {c['shape']}, the size is {c['magnitude']:.4g}{after_number(self.unit)} and the "
                f"training cost changes by {c['delta_cost']:+.3g} noise variances"
                + (" (that refit unfinished)" if c["unfinished"] else ""))

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "magnitude": self.magnitude, "ci95": list(self.ci95), "unit": self.unit,
                "evidence": self.evidence, "runner_up": self.runner_up, "margin": self.margin, "params": self.params,
                "tentative": self.tentative, "why_tentative": self.why_tentative, "size_check": self.size_check,
                "shape_check": self.shape_check, "shape": self.shape}


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
    not_ruled_out: list[dict[str, Any]] = field(default_factory=list)   # candidates that could not be fitted
    derivations: list[str] = field(default_factory=list)   # how the grids and scales follow from the data
    summary: list[str] = field(default_factory=list)       # the conclusions, each computed from the numbers
    fmu_note: str = ""                                      # what the exported FMU is, or why there is none
    budget: float | None = None                             # simulations allowed per candidate (training logs)
    constancy: dict[str, Any] = field(default_factory=dict)   # the final model's two-halves check (the engine's)
    stage_s: dict[str, float] = field(default_factory=dict)   # wall seconds per stage, in order (read by no decision)

    def to_dict(self) -> dict[str, Any]:
        """The CLI's ``--json`` and ``diagnosis.json``; ``answer_sha256``: ``fingerprint()`` (of the same fields,
        built once)."""
        fields = self._fields()
        return {**fields, "answer_sha256": _sha256(_answer_of(fields))}

    def answer(self) -> dict[str, Any]:
        """``to_dict()`` without what is not part of the answer: the wall times (``elapsed_s``, ``stage_s``) and
        where the files were written (``files``, ``fmu``).

        Why: two runs on the same log give the same answer to the last bit, alone or beside other work, on any
        number of workers (no decision reads a clock); on another CPU, NumPy's and the BLAS library's vector paths
        may round differently in the last bits, and a fit that ends on a stick-slip kink can then end elsewhere
        (``bench/determinism.py`` measures both). A user comparing two machines compares this."""
        return _answer_of(self._fields())

    def fingerprint(self) -> str:
        """SHA-256 of ``answer()`` as canonical JSON (sorted keys, floats to the last bit): equal for equal
        answers."""
        return _sha256(self.answer())

    def _fields(self) -> dict[str, Any]:
        return {"model": self.model, "summary": self.summary, "steps": [s.to_dict() for s in self.steps],
                "effects": [e.to_dict() for e in self.effects], "unexplained": self.unexplained,
                "not_ruled_out": self.not_ruled_out, "fmu": self.fmu, "fmu_note": self.fmu_note,
                "residual_table": _records(self.residual_table), "files": self.files, "elapsed_s": self.elapsed_s,
                "budget_training_logs": self.budget, "derivations": self.derivations, "notes": self.notes,
                "constancy": self.constancy, "stage_s": self.stage_s}

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



def _records(table: pd.DataFrame) -> list[dict[str, Any]]:
    """A table as JSON-ready records (NaN as None)."""
    if table is None or table.empty:
        return []
    return [{k: (None if isinstance(v, float) and v != v else v) for k, v in row.items()}
            for row in table.to_dict(orient="records")]


def _answer_of(fields: dict[str, Any]) -> dict[str, Any]:
    """A diagnosis's fields without its wall times and the paths it wrote to (``Diagnosis.answer``)."""
    return {k: v for k, v in fields.items() if k not in ("elapsed_s", "stage_s", "files", "fmu")}


def _sha256(answer: dict[str, Any]) -> str:
    text = json.dumps(answer, sort_keys=True, default=json_default, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def json_default(value: Any) -> Any:
    """JSON for what ``json`` does not know: NumPy scalars and arrays as Python's, anything else as its text."""
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.bool_):
        return bool(value)
    return str(value)
