"""The rigid, motor-only model as a plug-in of the discrepancy loop (``hdrive diagnose --model rigid`` for logs
without a load sensor, and the EMPS benchmark): the rigid inverse-dynamics model by equation error
(``rigid_idim``), whose held-back data is a second log (``holdout``) or the last 30 % of the log.

- **Screen**: the score test of each candidate on the decimated force residual: the candidate model's regressor
  columns beyond the current model's (its new directions: viscous ``q'``; for the asymmetric friction the
  direction-dependent levels, which on sliding rows without viscous friction are the offset's own regressor and add
  nothing; for Stribeck the derivative of the force in the ratio at 0, ``Fc sgn(q') exp(-(q'/v_s)^2)``, over a grid
  of v_s spanning the speeds the log shows).
- **Refit**: the candidate's model by IDIM-LS (linear least squares, Stribeck profiled), an exact and fast fit.
- **Noise**: the force's noise is not known (it is a controller's command), so the loop cannot tell whether the
  final model explains the log down to the noise; the report says so.
- **Export**: the equivalent one-body drive as the HarmonicDrive FMU (see ``RigidPlugin.export``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ...common.elsewhere import Elsewhere
from ...fitting.logs import DriveLog, LogError
from ...fitting.rigid import generic_idim_settings, identify_rigid
from ..result import DiagnosisStep, PublishedReference
from .. import MIN_GAIN
from ..screening import ScoreTest, best_of_grid, detection_limit, partial_out, quote_limits, score_test
from . import CandidateFit, Fitted, Magnitude, ModelPlugin
from . import rigid_residuals as residuals
from .rigid_idim import RIGID_EFFECTS, Z95, RigidModelFit, Spec, columns, fit_spec, magnitude_of_fit, process_log

HOLDOUT_FRACTION = 0.30
#: Stribeck velocities of the screen: 8 geometric steps over the search range of its fit (0.1 % .. 50 % of the 99th
#: percentile of |v| the log shows)
STRIBECK_SCREEN = 8


@dataclass
class RigidState:
    """A rigid model: its IDIM-LS fit and its held-back residual."""

    fit: RigidModelFit
    held: np.ndarray


class RigidPlugin(ModelPlugin):
    """See the module docstring."""

    kind = "rigid"

    def __init__(self, log: DriveLog, holdout: DriveLog | None = None, *, candidates: tuple[str, ...] | None = None,
                 reference: PublishedReference | None = None):
        names = RIGID_EFFECTS if candidates is None else tuple(candidates)
        unknown = [c for c in names if c not in RIGID_EFFECTS]
        if unknown:
            raise ValueError(f"unknown effect(s) {unknown} for the rigid model; it has {', '.join(RIGID_EFFECTS)}")
        if log.n < 200:
            raise LogError(f"{log.source}: {log.n} samples are too few for the rigid diagnosis (need a few hundred)")
        self.names, self.reference, self.log = names, reference, log
        self.emps = {"gtau", "kp", "kv"} <= set(log.meta_extra) and "qg" in log.extra and log.kind == "linear"
        self.train, self.held_log = _split(log, holdout)
        if np.ptp(self.train.motor_pos_rad) <= 0:
            raise RuntimeError(f"{log.source}: the motor position never changes: the log does not move the axis")
        # EMPS: the closed loop's rules (w_dyn checked against the identified loop); other logs: the generic rule
        self.settings = identify_rigid(self.train).settings if self.emps else generic_idim_settings(self.train)
        s = self.settings
        if abs(self.held_log.meta.sample_rate_hz - s.sample_rate_hz) > 1e-3 * s.sample_rate_hz:
            raise LogError(f"{self.held_log.source}: sampled at {self.held_log.meta.sample_rate_hz:g} Hz, the "
                           f"training log at {s.sample_rate_hz:g} Hz: the held-back log must use the training fit's "
                           "filter settings")
        self.p = process_log(self.train, s, generic=not self.emps)
        self.ph = process_log(self.held_log, s, generic=not self.emps)
        if self.ph.keep.sum() < 20:
            raise RuntimeError(f"{self.held_log.source}: fewer than 20 usable held-back rows")
        linear = log.kind == "linear"
        self.unit_f, self.unit_v = ("N", "m/s") if linear else ("N.m", "rad/s")
        self.units = {"viscous_motor": "N s/m" if linear else "N.m.s/rad", "asymmetric_friction": "1",
                      "stribeck": "1"}
        self.holdout_given = holdout is not None

    # ---------------------------------------------------------------------------------------- models ----------

    def fit_base(self, elsewhere: Elsewhere | None = None) -> Fitted:
        """The rigid base model: one linear least-squares fit (``elsewhere`` has nothing to take)."""
        fit = fit_spec(Spec(frozenset()), self.p)
        if fit.coord("M") <= 0:
            raise RuntimeError(f"{self.log.source}: identified inertia {fit.coord('M'):g} is not positive: the log "
                               "does not excite the dynamics")
        return self._fitted((), fit)

    def _fitted(self, effects: tuple[str, ...], fit: RigidModelFit) -> Fitted:
        e = self.ph.y[self.ph.keep] - fit.predict(self.ph)
        held = e**2
        yh = float(np.linalg.norm(self.ph.y[self.ph.keep]))
        metrics = {"relative_error_pct": fit.relative_error_pct,
                   "heldback_relative_error_pct": 100 * float(np.linalg.norm(e)) / yh}
        return Fitted(effects, fit.sse, float(held.sum()), held, fit.n, fit.k, metrics, RigidState(fit, e))

    def resimulated(self, model: Fitted) -> Fitted:
        return model

    def candidates(self, model: Fitted) -> tuple[str, ...]:
        return tuple(n for n in self.names if n not in model.effects)

    def screen(self, model: Fitted, names: tuple[str, ...]) -> list[ScoreTest]:
        fit = model.state.fit
        Q = partial_out(fit.J if fit.J is not None else fit.X)
        return [self._score(fit, name, Q) for name in names]

    def _score(self, fit: RigidModelFit, name: str, Q: np.ndarray) -> ScoreTest:
        """The score test of ``name``, with its detection limit where the force is linear in the magnitude (the limit
        is then exact to first order): the viscous level (one for both directions), the Stribeck ratio at each
        velocity of the grid, and the asymmetry of a model with viscous friction (``_asymmetry_limit``)."""
        spec = fit.spec.add(name)
        r = -fit.e  # the loop's residual convention: model - data
        if name == "stribeck":
            v99 = float(np.percentile(np.abs(self.p.v[self.p.keep]), 99))
            points, limits = [], []
            speeds = np.geomspace(1e-3 * v99, 0.5 * v99, STRIBECK_SCREEN)
            for vs in speeds:
                col = (columns(spec, self.p, 1.0, vs) - columns(spec, self.p, 0.0, vs)) @ fit.beta
                lm, robust, step, ok = score_test(r, Q, col[:, None], (True,))
                points.append(({"stribeck_velocity": float(vs)}, lm, robust, step, ok))
                limits.append(float(detection_limit(r, Q, col[:, None], STRIBECK_SCREEN, True, MIN_GAIN)[0]))
            test = best_of_grid(name, points, 1, True)
            quote_limits(test, limits, [f"Stribeck velocity {vs:.3g} {self.unit_v}" for vs in speeds],
                         self.units[name])
            return test
        B = columns(spec, self.p, fit.s, fit.vs)
        test = self._score_columns(name, r, Q, B)
        if name == "viscous_motor":
            level = B[:, [i for i, c in enumerate(spec.coords()) if c.startswith("Fv")]].sum(axis=1)
            quote_limits(test, [float(detection_limit(r, Q, level[:, None], 1, True, MIN_GAIN)[0])], [""],
                         self.units[name])
        if name == "asymmetric_friction" and "Fv" in fit.coords:
            quote_limits(test, [_asymmetry_limit(fit, spec, B, r, Q)], [""], self.units[name])
            test.record = "moves in both directions at the same speeds"
        return test

    @staticmethod
    def _score_columns(name: str, r: np.ndarray, Q: np.ndarray, B: np.ndarray) -> ScoreTest:
        """The score test of the directions ``B`` adds to the current model."""
        Z = B - Q @ (Q.T @ B)
        U, sv, _ = np.linalg.svd(Z, full_matrices=False)
        new = U[:, sv > 1e-8 * max(float(np.linalg.norm(B)), 1e-300)] if sv.size else U
        if new.shape[1] == 0:
            return ScoreTest(name, 0.0, 0.0, 0, 1.0, note="adds no direction to the current model on this log (e.g. "
                             "the Coulomb asymmetry without viscous friction is the offset's own regressor)")
        lm, robust, step, ok = score_test(r, Q, new, (False,) * new.shape[1])
        return best_of_grid(name, [({}, lm, robust, step, ok)], new.shape[1], False)

    def refit(self, model: Fitted, test: ScoreTest, budget: float | None) -> CandidateFit:
        spec = model.state.fit.spec.add(test.candidate)
        try:
            fit = fit_spec(spec, self.p)
        except RuntimeError as exc:
            return CandidateFit(test.candidate, error=str(exc), start="IDIM-LS")
        veto = None
        if test.candidate == "stribeck" and fit.stribeck_at_bound:
            veto = f"Stribeck parameters at a bound of their search (s = {fit.s:.3g}, v_s = {fit.vs:.3g})"
        return CandidateFit(test.candidate, self._fitted(model.effects + (test.candidate,), fit), veto=veto,
                            start="IDIM-LS (exact least squares)")

    def without(self, model: Fitted, name: str, budget: float | None) -> Fitted:
        effects = tuple(e for e in model.effects if e != name)
        return self._fitted(effects, fit_spec(Spec(frozenset(effects)), self.p))

    # ---------------------------------------------------------------------------------------- naming ----------

    def magnitude(self, model: Fitted, name: str) -> Magnitude:
        fit = model.state.fit
        mag, sd = magnitude_of_fit(name, fit)
        return Magnitude(mag, (mag - Z95 * sd, mag + Z95 * sd), self.units[name], fit.params())

    def over_noise(self, model: Fitted) -> None:
        return None

    def regimes(self, model: Fitted) -> pd.DataFrame:
        final = model.state.fit
        return pd.concat([residuals.regimes(final.e, self.p).assign(data="training"),
                          residuals.regimes(model.state.held, self.ph).assign(data="held-back")], ignore_index=True)

    def unexplained(self, model: Fitted, table: pd.DataFrame) -> list[dict[str, Any]]:
        out = []
        for data in ("training", "held-back"):
            out += residuals.unexplained(table[table.data == data], data)
        for pp, data in ((self.p, "training"), (self.ph, "held-back")):
            flag, _ = residuals.spectrum_check(model.state.fit, pp, data)
            if flag:
                out.append(flag)
        return out

    def step(self, model: Fitted, added: str | None, score: float | None, extra: dict[str, Any]) -> DiagnosisStep:
        fit = model.state.fit
        return DiagnosisStep(added, None, None, fit.relative_error_pct, score, fit.params(), pd.DataFrame(),
                             extra={**extra, "heldback_relative_error_pct": model.metrics["heldback_relative_error_pct"],
                                    "bic": fit.bic, "casadi_vs_lstsq": fit.casadi_vs_lstsq,
                                    "effects": list(model.effects)})

    def derivations(self) -> list[str]:
        v99 = float(np.percentile(np.abs(self.p.v[self.p.keep]), 99))
        s = self.settings
        return [f"IDIM-LS settings from the log: w_dyn = {s.f_dyn_hz:.4g} Hz ({s.f_dyn_source}), Butterworth "
                f"{s.butter_order} at {s.butter_cutoff_hz:.4g} Hz, decimation by {s.decim_factor}",
                f"Stribeck velocity grid of the screen: {STRIBECK_SCREEN} geometric steps from 0.1 % to 50 % of the "
                f"99th percentile of |v| the log shows ({v99:.4g} {self.unit_v}), the range its fit searches; the "
                "other candidates are linear in their coordinates and need no grid"]

    def notes(self) -> list[str]:
        out = []
        if not self.holdout_given:
            out.append(f"held-back data: the last {100 * HOLDOUT_FRACTION:.0f} % of the log (t >= "
                       f"{self.held_log.time_s[0]:.3f} s); pass a second log as holdout for a stronger test")
        return out

    def export(self, model: Fitted, folder: Path) -> tuple[Path | None, str]:
        from .rigid_export import export_one_body

        return export_one_body(model.state.fit, self.log, folder, self.units)

    def plots(self, models: list[Fitted], folder: Path) -> dict[str, str]:
        base, final = models[0], models[-1]
        spectra = [residuals.spectrum_check(final.state.fit, pp, lab)[1]
                   for pp, lab in ((self.p, "training"), (self.ph, "held-back"))]
        return residuals.plots(folder, base.state.fit, final.state.fit, self.p, self.ph, final.state.held,
                               base.state.held, spectra, self.unit_f, self.unit_v)

    def report_sections(self, models: list[Fitted]) -> list[str]:
        from .rigid_report import sections

        return sections(self, models)


def _asymmetry_limit(fit: RigidModelFit, spec: Spec, B: np.ndarray, r: np.ndarray, Q: np.ndarray) -> float:
    """The asymmetry the log could name at a model with viscous friction Fv: the PDF's direction-dependent levels,
    Fv (1 + a_v sgn v) v = Fv v + a_v Fv |v|, add the column Fv |v| (the difference of the two directions' viscous
    columns) per unit of a_v, linear in it (its Coulomb part, Fc a, is the offset's own regressor and adds nothing
    a model with an offset does not have)."""
    coords = spec.coords()
    fv = float(fit.beta[fit.coords.index("Fv")])
    col = fv * (B[:, coords.index("Fv_pos")] - B[:, coords.index("Fv_neg")])
    return abs(float(detection_limit(r, Q, col[:, None], 1, False, MIN_GAIN)[0]))


def _split(log: DriveLog, holdout: DriveLog | None) -> tuple[DriveLog, DriveLog]:
    if holdout is not None:
        return log, holdout
    cut = int(round((1 - HOLDOUT_FRACTION) * log.n))
    return log.window(0, cut), log.window(cut, log.n)


def model_label(spec: Spec) -> str:
    """The model's coordinates as the report names them (and a published reference keys its figures)."""
    label = "M, Fc+, Fc-" if spec.asym else "M, Fc, offset"
    if spec.viscous:
        label += ", Fv+, Fv-" if spec.asym else ", Fv"
    if spec.stribeck:
        label += ", Stribeck (s, v_s)"
    return label
