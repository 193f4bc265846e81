"""The models a diagnosis can start from, as plug-ins of the one discrepancy loop (``ident.diagnosis.engine``).

A plug-in knows its model: how to fit it, simulate it, score its residuals, test and refit each candidate effect,
name an effect's magnitude, localise what is left, and export the result. The loop knows none of that: it screens,
refits the few candidates that pass, applies one acceptance rule to every effect, iterates, eliminates backwards and
writes the report. ``Fitted`` is the loop's view of a fitted model; ``ModelPlugin`` the contract.

- ``two_inertia.TwoInertiaPlugin``: torque, motor encoder and load sensor; the FMU is the model (output error), and
  the rigid kinematics q_l = r q_m can be its start (then ``flexibility`` is the first candidate).
- ``rigid.RigidPlugin``: a motor-only log (rotary or a linear axis, e.g. EMPS); the rigid inverse-dynamics model by
  equation error (IDIM-LS).
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ...common.elsewhere import Elsewhere
from .. import CONFIDENT_OVER_NOISE
from ..result import DiagnosisStep
from ..screening import ScoreTest


@dataclass
class Fitted:
    """A fitted model of the sequence, as the loop sees it.

    ``train_cost`` / ``held_cost``: sum of squared residuals on the training / held-back data (noise-normalised
    where the plug-in knows the noise); ``held_losses``: the held-back squared error per sample (the
    Diebold-Mariano test compares two models sample by sample); ``n_train``: training residuals; ``k``: unknowns;
    ``state``: the plug-in's own (parameters, simulation)."""

    effects: tuple[str, ...]
    train_cost: float
    held_cost: float
    held_losses: np.ndarray
    n_train: int
    k: int
    metrics: dict[str, float] = field(default_factory=dict)
    state: Any = None

    def bic(self) -> float:
        return self.n_train * math.log(max(self.train_cost, 1e-300) / self.n_train) + self.k * math.log(self.n_train)


@dataclass
class CandidateFit:
    """One candidate refitted (on a worker): the model with it, or why there is none.

    ``exhausted``: the fit used up its evaluation budget before it converged; ``model`` is then the best point it
    simulated (None if none), judged like any other, and the candidate is not ruled out unless it is named;
    ``veto``: a reason of the model's own not to name it even if it scores (e.g. a parameter at its bound);
    ``evaluations``: the simulations used, in whole training logs; ``start``: where the fit started."""

    name: str
    model: Fitted | None = None
    error: str | None = None
    exhausted: bool = False
    veto: str | None = None
    evaluations: float = 0.0
    start: str = ""


@dataclass
class Magnitude:
    """An effect's magnitude in a model: value, 95 % interval, unit and the FMU/model parameters of the effect;
    ``doubt``: why the log cannot pin the size the report quotes, though it is fitted ('' when it can)."""

    value: float
    ci95: tuple[float, float]
    unit: str
    params: dict[str, float] = field(default_factory=dict)
    doubt: str = ""

    @property
    def excludes_zero(self) -> bool:
        lo, hi = self.ci95
        return bool(np.isfinite(lo) and np.isfinite(hi) and (lo > 0 or hi < 0))


@dataclass
class ShapeFit:
    """A named effect refitted in another shape (``ModelPlugin.shape_rival``): the model, the effect's size (its
    magnitude) there with its 95 % interval, the shape in words, and whether the refit used up its budget before it
    converged (its cost is then an upper bound of the shape's best)."""

    model: Fitted
    size: float
    ci95: tuple[float, float]
    shape: str
    unfinished: bool = False


class ModelPlugin(ABC):
    """The contract between the discrepancy loop and a model (see the module docstring). Instances travel to the
    workers (candidate refits), so they hold data and settings only, never an open FMU."""

    kind: str = ""
    #: the relative gain of the held-back cost below which an improvement is not worth naming (model-specific:
    #: how well the model's noise level is known)
    min_gain: float = 1.02

    @abstractmethod
    def fit_base(self, elsewhere: Elsewhere | None = None) -> Fitted:
        """The base model on the training data; ``elsewhere``: a second core the fit may use beside this one
        (``ident.common.elsewhere``: the same result, sooner)."""

    @abstractmethod
    def candidates(self, model: Fitted) -> tuple[str, ...]:
        """Effects that can extend ``model``, in library order."""

    @abstractmethod
    def screen(self, model: Fitted, names: tuple[str, ...]) -> list[ScoreTest]:
        """The score test of each candidate at ``model`` (``ident.diagnosis.screening``)."""

    @abstractmethod
    def refit(self, model: Fitted, test: ScoreTest, budget: float | None) -> CandidateFit:
        """``model`` with the candidate of ``test`` added, fitted from the screen's step; ``budget``: simulations
        allowed, in whole training logs (``EvaluationBudget``; None: unlimited)."""

    @abstractmethod
    def without(self, model: Fitted, name: str, budget: float | None) -> Fitted:
        """``model`` without effect ``name``, refitted from ``model``'s optimum (the drop test, the backward
        elimination)."""

    def converge(self, model: Fitted, budget: float | None, unfinished: bool = False) -> tuple[Fitted, str]:
        """The accepted model, converged further if the plug-in can (e.g. identified from scratch with the new
        effect; ``unfinished``: its refit used up its budget before it converged); returns it and a sentence on what
        was done. Default: as it is."""
        return model, ""

    def polish(self, model: Fitted, budget: float | None) -> tuple[Fitted, str]:
        """The final model refitted from its own optimum where the plug-in can refit it more precisely than the
        loop's refits did (the engine's size search starts from it); returns it (or ``model`` when the refit fits
        the training data no better) and a sentence on what was done. Default: as it is."""
        return model, ""

    @abstractmethod
    def resimulated(self, model: Fitted) -> Fitted:
        """``model`` with whatever its report needs recomputed (a refit on a worker returns it lean)."""

    @abstractmethod
    def magnitude(self, model: Fitted, name: str) -> Magnitude:
        """Effect ``name``'s magnitude in ``model``, with its interval."""

    def probe_size(self, model: Fitted, name: str, factor: float, budget: float | None,
                   reference: Fitted | None = None) -> Fitted | None:
        """``model`` refitted with effect ``name``'s size held at ``factor`` times its value and every other unknown
        free (a point of the size's profile: the engine's check that the log pins the size as closely as the local
        interval says), as ``polish`` refits; ``budget`` as ``refit``, counted at the cost of simulating
        ``reference`` (None: of the probe's start). None: the plug-in has no such refit (the local interval
        stands)."""
        return None

    def size_inflation(self, model: Fitted, name: str) -> float:
        """How much more effect ``name``'s size varies with the residual's correlation allowed than with white
        noise: its sandwich variance over its noise-only variance in ``model`` (1 where the residual is the
        sensor's white noise). The size search scales what chance gives a profile point by it
        (``ident.diagnosis.sizes``). Default 1: a plug-in without ``probe_size`` never searches."""
        return 1.0

    def half(self, model: Fitted, which: int, budget: float | None) -> Fitted | None:
        """``model`` refitted on the first (``which`` 0) or the second half of its training data alone, every
        unknown free (the engine's constancy check); ``budget`` as ``refit``. None: the plug-in has no such refit,
        or it ran out of budget."""
        return None

    def constancy(self, first: Fitted, second: Fitted) -> tuple[float, int]:
        """The Wald statistic of "the two halves' models (``half``) have the same parameters" and its degrees of
        freedom."""
        raise NotImplementedError(f"{type(self).__name__} has no constancy check")

    def twin_of(self, model: Fitted, name: str) -> tuple[str, str, str] | None:
        """The rival effect that the model's own physics makes a near twin of effect ``name`` in ``model`` (e.g.
        viscous friction on the other side of the gear, its size carried over by the ratio): (rival, the size
        carried over, what a log needs to tell the two apart). None: ``name`` has no twin here."""
        return None

    def effect_start(self, model: Fitted, name: str) -> dict[str, float]:
        """Effect ``name``'s unknowns in ``model`` (a candidate's refit), as a later refit of it may start from
        (``ScoreTest.carried``; the names and values of ``ScoreTest.start``). Default: none."""
        return {}

    def refit_cost(self, name: str) -> float:
        """The expected cost of refitting candidate ``name``, relative to the others (any unit): the order the
        workers start a step's refits in, costliest first. Never a decision: the results are the same in any order.
        Default: all alike."""
        return 1.0

    def twin(self, model: Fitted, name: str, budget: float | None) -> Fitted | None:
        """``model`` with ``twin_of``'s rival in place of ``name`` at the carried-over size, refitted from there
        (``budget`` as ``refit``). None: no twin."""
        return None

    def shape_rival_of(self, name: str) -> str:
        """The other shape of effect ``name``, in place of the library's, in words ('' when it has none): real
        effects never have the library's exact shape, and where two shapes fit a log alike their sizes may differ.
        The engine tries it where the effect is named (``_adopt_shape``) and checks the final size against it."""
        return ""

    def shape_of(self, model: Fitted, name: str) -> str:
        """The shape effect ``name`` has in ``model``, in words, where it is not the library's ('' where it is):
        a model that adopted its other shape (the engine's ``_adopt_shape``, ``_preferred``)."""
        return ""

    def with_other_shape(self, model: Fitted, name: str) -> Fitted | None:
        """``model``, which lacks effect ``name``, set so that a candidate's refit adds ``name`` in its other shape
        (``shape_rival_of``'s): the engine refits a candidate so where the library's shape does not carry over to
        the held-back data. None: no such shape."""
        return None

    def shape_rival(self, model: Fitted, name: str, budget: float | None) -> ShapeFit | None:
        """``model`` with effect ``name`` in its other shape (``shape_rival_of``'s; the library's where ``model`` has
        that one, ``shape_of``), every unknown refitted from ``model``'s optimum within ``budget`` (as ``refit``).
        None: no such shape."""
        return None

    def outside_rival(self, model: Fitted, names: list[str]) -> tuple[dict[str, float], str, str]:
        """An effect outside the library fitted in place of each named effect of ``model``: ({name: its training
        cost minus the named model's, in noise variances}, what the rival is, what a log needs to tell the two
        apart). Default: none ({})."""
        return {}, "", ""

    @abstractmethod
    def over_noise(self, model: Fitted) -> tuple[float, float] | None:
        """(training, held-back) residual RMS over the sensor noise, or None where the noise is not known."""

    def confident_levels(self) -> tuple[float, float]:
        """(training, held-back) levels of ``over_noise`` above which a model does not reproduce its log (its names
        are then tentative). Default: ``CONFIDENT_OVER_NOISE`` on both."""
        return CONFIDENT_OVER_NOISE, CONFIDENT_OVER_NOISE

    @abstractmethod
    def regimes(self, model: Fitted) -> pd.DataFrame:
        """Where ``model``'s residual lives: a ranked table of regimes."""

    @abstractmethod
    def unexplained(self, model: Fitted, table: pd.DataFrame) -> list[dict[str, Any]]:
        """Regimes with structure left that no named effect explains: {"regime", "share_pct", "detail"}."""

    @abstractmethod
    def step(self, model: Fitted, added: str | None, score: float | None, extra: dict[str, Any]) -> DiagnosisStep:
        """The report's record of one model of the sequence."""

    def derivations(self) -> list[str]:
        """Sentences saying how the screen's grids and the fits' scales were derived from the data sheet and the
        log (printed in the report)."""
        return []

    def notes(self) -> list[str]:
        """Notes of the plug-in's own for the report (e.g. how the held-back data were chosen)."""
        return []

    @abstractmethod
    def export(self, model: Fitted, folder: Path) -> tuple[Path | None, str]:
        """The fitted model as an FMU in ``folder``: (path, what it is) or (None, why it cannot be)."""

    @abstractmethod
    def plots(self, models: list[Fitted], folder: Path) -> dict[str, str]:
        """The report's plots written into ``folder``: {key: file name}."""

    def report_sections(self, models: list[Fitted]) -> list[str]:
        """Extra markdown sections of the model's own (e.g. a published reference beside the numbers)."""
        return []
