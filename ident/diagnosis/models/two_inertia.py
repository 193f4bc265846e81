"""The two-inertia model as a plug-in of the discrepancy loop: the FMU is the model, fitted by output error.

- **Base**: ``ident.fitting.identify`` on the training part (the first 70 % of the log, or all of it with a second
  log held back); or, with ``start="rigid"``, the rigid kinematics q_l = r q_m (its only candidate is
  ``flexibility``, whose fit is the two-inertia identification).
- **Residuals**: the FMU simulates the whole log (training and held back) with the logged torque; the load sensor
  and the encoder are compared with it, each weighed by its noise (the load sensor's from the log,
  ``identify.white_noise_std``; the encoder's quantisation count/sqrt(12)). The acceptance rule compares the
  models' load-sensor residuals (the encoder's quantisation residual is not white noise: it stays put while the
  motor stands still).
- **Screen**: the score test of each candidate (``ident.diagnosis.screening``) on the load-sensor residuals of the
  training part, the Jacobian columns through the FMU: the current unknowns' by central differences, each
  candidate's by a one-sided difference at zero through the same propagator (``problem.same_propagator``), over the
  grid of its nonlinear coordinate (``coordinates.grid``).
- **Refit**: from the screen's Gauss-Newton step (the current unknowns and the candidate's), or that step scaled
  back when it lands higher (down to the current model with the candidate off: ``_heads``), IPOPT on the training
  part; when the current model leans on a parameter bound (it cannot fit the log inside the physical range, so a
  refit from it starts in the wrong basin) the candidate's model is identified from scratch
  (``identify.fit_pipeline``, the screen's step among its first window's starting points). Every fit runs within
  an evaluation budget (whole training logs simulated; a size probe's costlier simulations count more).
- **Converge**: an accepted model still above the noise is identified from scratch with its effects too (the base
  model's parameters may have bent to mimic the missing effect into a far basin); the better one is kept.
- **Polish**: the final model refitted from its optimum with finite-difference steps of a tenth of its unknowns'
  standard deviations, as the identifier's windows are (``identify.SEARCH_STEP``), before its sizes are searched;
  the final model's size probes use the same steps (``polish``, ``probe_size``).
- **Outside rival**: a ripple of the motor friction along its travel, fitted in place of each named effect at the
  final model (``ripple``).
- **Shape rival**: a named Stribeck friction refitted with an exponential decay in place of the Gaussian, a named
  Dahl hysteresis with exponent 2 in place of 1 (``SHAPES``; the FMU's ``stribeck_shape``, ``hysteresis_exponent``),
  every unknown free (``ident.diagnosis.shapes`` judges it).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pandas as pd

from ...common.elsewhere import Elsewhere
from ...fitting.identify import (
    SEARCH_STEP,
    Z95,
    BudgetExceeded,
    EvaluationBudget,
    at_bound,
    covariances,
    fit_ipopt,
    fit_pipeline,
    identify,
    lower_deflection_basin,
    search_steps_of,
)
from ...fitting.logs import DriveLog, LogError
from ...fitting.noise import at_noise_level, residual_noise_std
from ...fitting.result import BASE_UNKNOWNS, larger_variances
from ...model.effects import EFFECTS
from ...model.params import DriveParams
from .. import CONFIDENT_ALPHA, CONFIDENT_OVER_NOISE, MIN_GAIN, above_level
from ..result import DiagnosisStep
from ..screening import ScoreTest, best_of_grid, detection_limit, partial_out, quote_limits, score_test
from . import ripple
from . import two_inertia_report as report
from . import CandidateFit, Fitted, Magnitude, ModelPlugin, ShapeFit
from .coordinates import (
    SIZE_COORDS,
    TWO_INERTIA_EFFECTS,
    LogScales,
    coordinates,
    fmu_values,
    grid,
    grid_words,
    magnitude_of,
    record_advice,
)
from .problem import ModelProblem, Sensitivity, one_sided_column, rms, simulate_full

HOLDBACK_FRACTION = 0.3
#: IPOPT iterations of a drop / backward refit (a candidate's refit runs until its budget is spent)
REFIT_ITER = 30
#: the screen's one-sided difference: the candidate's coordinate is set to make the load move by about this many
#: noise sigmas (RMS over the training part): far above the FMU's round-off (accumulated over a log: ~5e-6 sigma,
#: ``problem.COORD_STEP``) and the propagators'
#: differences (~1e-3 sigma), small against the motion (a linear response)
SCREEN_RESPONSE_SIGMA = 1.0
FLEXIBILITY = "flexibility"
#: effects the gear makes near twins (``TwoInertiaPlugin.twin``): effect -> (its twin, its parameter, the twin's, the
#: power of the ratio r = q_l / q_m that carries the size over: b_m = r^2 b_l)
TWINS = {"viscous_motor": ("viscous_load", "b_m", "b_l", -2), "viscous_load": ("viscous_motor", "b_l", "b_m", 2)}


class Shape(NamedTuple):
    """An effect's other shape (``SHAPES``): the FMU parameter that selects it and its value there, the shape in
    short words, the rival in place of the library's and the library's back in place of it, in words, shifts of
    the effect's coordinates from the library's shape to the rival's start (taken back the other way), and FMU
    parameters the rival holds at values the log gives (``held``: from its ``LogScales``; let go with it)."""

    param: str
    value: float
    words: str
    rival: str
    library: str
    shifts: dict[str, float]
    held: Callable[[LogScales], dict[str, float]] | None = None


#: the other shape of each effect (``shape_rival``; the engine adopts it where the log prefers it, and checks the
#: named size against it): effect -> its ``Shape``.
#: Stribeck: the decay exp(-|v/v_s|^delta) of the generalised Stribeck law (Armstrong-Helouvry's exponent) at
#: delta = 1, the exponential (Tustin's) decay, beside the library's Gaussian delta = 2; it starts where its excess
#: has the same integral over speed as the Gaussian's (v_s sqrt(pi) / 2), so that both start with the same
#: breakaway excess and the same friction impulse over a slide through the decay. Measured on an independent
#: torque-step log with an exponential decay: the Gaussian fitted it to the noise (1.008x) with the ratio 37 % low
#: and a confident interval that missed the truth. Hysteresis: Dahl's element of exponent n = 2 (an algebraic
#: approach to its saturation torque) beside the library's n = 1 (an exponential one); it starts with the same
#: saturation torque and initial stiffness. Measured on the independent generator's logs of drive 5103, whose Dahl
#: exponent is 2: the library's sizes were 15-22 % low on five of the six (66 % on the sixth, above the noise), two
#: of them confident with intervals that missed. Hardening: a stiffening that grows with |d| (the excess torque
#: K_s h d |d| d95, exponent 1) beside the library's cubic K_s h d^3; both stiffen alike at the log's d95, so that the
#: size h (1/rad^2) means the same in either and starts where it was. Why: a catalog's harmonic drive stiffens in
#: three slopes (K1, K2, K3 beyond two break deflections), whose excess over K1 grows about linearly beyond the first
#: break; over the deflections of the independent generator's log 7696 a least-squares fit of that excess (with K_s
#: free) by d |d| leaves about a third of the cubic's misfit. On 7696 (three slopes, torque steps) the cubic was not
#: named and a kinematic error took its place.
SHAPES = {
    "stribeck": Shape("stribeck_shape", 1.0, "an exponential Stribeck decay exp(-|v/v_s|) (stribeck_shape = 1)",
                      "an exponential Stribeck decay exp(-|v/v_s|) (stribeck_shape = 1) in place of the library's "
                      "Gaussian exp(-(v/v_s)^2)",
                      "the library's Gaussian Stribeck decay exp(-(v/v_s)^2) (stribeck_shape = 2) in place of the "
                      "exponential one", {"ln_stribeck_velocity": math.log(math.sqrt(math.pi) / 2)}),
    "hysteresis": Shape("hysteresis_exponent", 2.0, "a Dahl element of exponent 2 (hysteresis_exponent = 2)",
                        "a Dahl element of exponent 2 (hysteresis_exponent = 2: an algebraic approach to its "
                        "saturation torque) in place of the library's exponential one",
                        "the library's Dahl element of exponent 1 (an exponential approach to its saturation "
                        "torque) in place of exponent 2", {}),
    "hardening": Shape("hardening_exponent", 1.0, "a stiffening that grows with |d| (hardening_exponent = 1)",
                       "a stiffening that grows with |d| (hardening_exponent = 1: K_s (d + h d |d| d95)) in place "
                       "of the library's cubic",
                       "the library's cubic stiffening (hardening_exponent = 2) in place of one that grows with |d|",
                       {}, lambda scales: {"hardening_deflection": scales.d95}),   # the size means the same
}
#: seconds per FMU simulation of 10 s at 5 kHz with each effect on (bench/README, "FMU with effects on": the nominal
#: drive, 2026-11-25): a candidate's refit costs about its effect's simulations, so the workers start the costliest
#: first (``refit_cost``). Measured on an outside log (a friction ripple): Stribeck refits took 56-65 s, the others
#: 4-45 s, and a step whose Stribeck refit started fifth waited on it.
SIMULATION_S = {"viscous_motor": 0.026, "viscous_load": 0.022, "stribeck": 0.094, "asymmetric_friction": 0.026,
                "hardening": 0.025, "hysteresis": 0.045, "kinematic_error": 0.046}


@dataclass
class TwoInertiaState:
    """A two-inertia model: its unknowns, the drive they give, the base drive and log scales its coordinates use,
    and (when kept) the simulation of the whole log; ``rigid``: the rigid kinematics (no unknowns); ``work``: what
    simulating its training part costs (model evaluations per sample), the unit of a size search's budgets."""

    theta: np.ndarray
    params: DriveParams
    base: DriveParams
    scales: LogScales | None
    sim: dict[str, np.ndarray] | None = None
    cov: np.ndarray | None = None
    covs: tuple[np.ndarray, np.ndarray] | None = None   # (noise-only, sandwich) that ``cov`` is made of
    rigid: bool = False
    sens: Sensitivity = field(default_factory=dict)
    work: float | None = None   # model evaluations per training sample of its simulation (``simulate_full``)
    #: FMU parameters held at a value other than their default (a shape rival's: ``TwoInertiaPlugin.shape_rival``)
    fixed: dict[str, float] = field(default_factory=dict)

    def problem(self, full: DriveLog, effects: tuple[str, ...], stop: int, sigma: float,
                fixed: dict[str, float] | None = None, **kw: Any) -> ModelProblem:
        """The output-error problem of this model's drive with ``effects`` on; ``fixed``: FMU parameters held on
        top of the model's own (``fixed``)."""
        return ModelProblem(full, self.base, _fmu_effects(effects), self.scales, stop, sigma, sens=self.sens,
                            fixed={**self.fixed, **(fixed or {})}, **kw)


class TwoInertiaPlugin(ModelPlugin):
    """See the module docstring. ``candidates``: library effects to try (default: all of the two-inertia
    model's)."""

    kind = "two-inertia"

    def __init__(self, log: DriveLog, holdout: DriveLog | None = None, *, start: str = "two-inertia",
                 candidates: tuple[str, ...] | None = None, resolution_pulses: int = 0):
        if log.load_pos_rad is None or log.meta.J_m_kgm2 is None or log.meta.f_m_Nm is None \
                or log.meta.encoder_counts_per_rev is None:
            raise LogError(f"{log.source}: the two-inertia diagnosis needs load_pos_rad and J_m_kgm2, f_m_Nm, "
                           "encoder_counts_per_rev in the sidecar; use model='rigid' for a motor-only log")
        names = TWO_INERTIA_EFFECTS if candidates is None else tuple(candidates)
        unknown = [c for c in names if c not in TWO_INERTIA_EFFECTS and c != FLEXIBILITY]
        if unknown:
            raise ValueError(f"unknown effect(s) {unknown}; the two-inertia library has {', '.join(TWO_INERTIA_EFFECTS)}")
        self.full, self.stop = split_training(log, holdout)
        self.motor_span = float(np.ptp(self.full.motor_pos_rad[:self.stop]))   # how far the motor turned [rad]
        self.start = start
        self.names = tuple(n for n in names if n != FLEXIBILITY)
        self.sigma = math.nan   # the load sensor's noise: the identifier's one estimate, set by fit_base
        self.identified: Any = None
        self.scales: LogScales | None = None   # what the log shows through the base fit (set by fit_base)
        self.resolution_pulses = resolution_pulses
        self.held_source = "the last 30 % of the log" if holdout is None else holdout.source

    # ---------------------------------------------------------------------------------------- models ----------

    def fit_base(self, elsewhere: Elsewhere | None = None) -> Fitted:
        """The identifier on the training part (``identify``: its data checks, its fit and its one load-noise
        estimate, which weighs every model of the diagnosis; its start's second path on ``elsewhere``); with the
        rigid start, the rigid kinematics (the identification is then flexibility's refit)."""
        self.identified = identify(truncate_log(self.full, self.stop), elsewhere=elsewhere)
        self.sigma = self.identified.sigma_load_rad
        if self.start == "rigid":
            return self._rigid()
        return self._identified()

    def _identified(self) -> Fitted:
        fit = self.identified
        base = fit.params
        problem = ModelProblem(self.full, base, (), None, self.stop, self.sigma)  # type: ignore[arg-type]
        try:
            sim, _ = simulate_full(self.full, problem, fit.theta)
        finally:
            problem.close()
        self.scales = LogScales.from_simulation(sim, self.stop, base)
        return self.evaluate((), fit.theta, base, self.scales, keep=True)

    def _rigid(self) -> Fitted:
        """The rigid kinematics q_l = r q_m (encoder reading's mid-count; the load sensor's zero fitted on the
        training part): no unknowns but the offset."""
        log, s = self.full, self.stop
        count = 2 * math.pi / log.meta.encoder_counts_per_rev
        q_l = log.meta.r * (log.motor_pos_rad + 0.5 * count)
        q_l = q_l + float(np.mean(log.load_pos_rad[:s] - q_l[:s]))
        res = (log.load_pos_rad - q_l) / self.sigma
        base = DriveParams(J_m=log.meta.J_m_kgm2, f_m=log.meta.f_m_Nm, r=log.meta.r,
                           arm_length=log.meta.arm_length_m, encoder_counts_per_rev=log.meta.encoder_counts_per_rev)
        held = res[s:] ** 2
        metrics = _metrics_of(log, res * self.sigma, np.zeros(log.n), s, self.sigma)
        return Fitted((), float(np.sum(res[:s] ** 2)), float(held.sum()), held, s, 1, metrics,
                      TwoInertiaState(np.zeros(0), base, base, None, None, rigid=True))

    def evaluate(self, effects: tuple[str, ...], theta: np.ndarray, base: DriveParams, scales: LogScales,
                 keep: bool = False, sens: Sensitivity | None = None, fixed: dict[str, float] | None = None
                 ) -> Fitted:
        """The model ``effects`` at ``theta`` simulated over the whole log; ``keep``: keep the simulation;
        ``fixed``: FMU parameters held (``TwoInertiaState.fixed``)."""
        problem = ModelProblem(self.full, base, _fmu_effects(effects), scales, self.stop, self.sigma, sens=sens,
                               fixed=fixed)
        try:
            sim, work = simulate_full(self.full, problem, theta)
            params = problem.params(theta)
        finally:
            problem.close()
        s = self.stop
        load = sim["res_l"] / self.sigma
        metrics = _metrics_of(self.full, sim["res_l"], sim["res_m"], s, self.sigma)
        held = load[s:] ** 2
        state = TwoInertiaState(np.asarray(theta, dtype=float), params, base, scales, sim if keep else None,
                                sens=dict(sens or {}), work=work, fixed=dict(fixed or {}))
        return Fitted(effects, float(np.sum(load[:s] ** 2)), float(held.sum()), held, s, int(np.size(theta)) + 2,
                      metrics, state)

    def resimulated(self, model: Fitted) -> Fitted:
        st = model.state
        if st.rigid or st.sim is not None:
            return model
        out = self.evaluate(model.effects, st.theta, st.base, st.scales, keep=True, sens=st.sens, fixed=st.fixed)
        out.state.cov, out.state.covs = st.cov, st.covs
        return out

    def candidates(self, model: Fitted) -> tuple[str, ...]:
        if model.state.rigid:
            return (FLEXIBILITY,)
        return tuple(n for n in self.names if n not in model.effects)

    # ---------------------------------------------------------------------------------------- screen ----------

    def screen(self, model: Fitted, names: tuple[str, ...]) -> list[ScoreTest]:
        if model.state.rigid:
            return [ScoreTest(FLEXIBILITY, math.nan, math.nan, 1, math.nan, screened=False,
                              note="the rigid kinematics has no parameter whose zero is the flexibility: fitted "
                                   "directly")]
        st = model.state
        problem = st.problem(self.full, model.effects, self.stop, self.sigma, general=True)
        try:
            rows = problem.load_rows()
            r = problem.residuals(st.theta)[rows]
            J = problem.jacobian(st.theta)[rows]
        finally:
            problem.close()
        Q = partial_out(J)
        return [self._score(model, name, r, J, Q) for name in names]

    def _score(self, model: Fitted, name: str, r: np.ndarray, J: np.ndarray, Q: np.ndarray) -> ScoreTest:
        """The score test of ``name`` over its grid; the result carries where its refit starts (``start``: the
        coordinates' values at the Gauss-Newton step) and each linear coordinate's one-sigma size
        (``sensitivity``)."""
        coords = coordinates(name, model.state.scales)
        points_x = grid(name, model.state.scales)
        gridded = {k for point in points_x for k in point}
        linear = [c for c in coords if c.name not in gridded]
        one_sided = len(linear) == 1 and linear[0].from_zero
        points, sizes, limits = [], [], []
        for point in points_x:
            entry, size, limit = self._grid_point(model, name, point, coords, linear, r, J, Q,
                                                  (len(points_x), one_sided))
            points.append(entry)
            sizes.append(size)
            limits.append(limit)
        test = best_of_grid(name, points, len(linear), one_sided)
        best = next(i for i, p in enumerate(points) if p[0] == test.grid_point)
        test.start = dict(test.grid_point)
        test.sensitivity = sizes[best]
        test.grid_point = {k: v for k, v in test.start.items() if k in gridded}
        test.step = test.step[:J.shape[1]]
        test.record = record_advice(name, model.state.scales, self.motor_span)
        quote_limits(test, limits, [", ".join(grid_words(c, p[c.name]) for c in coords if c.name in gridded)
                                    for p in points_x], EFFECTS[name].unit)
        return test

    def _grid_point(self, model: Fitted, name: str, point: dict[str, float], coords: tuple[Any, ...],
                    linear: list[Any], r: np.ndarray, J: np.ndarray, Q: np.ndarray, grid_of: tuple[int, bool]
                    ) -> tuple[tuple[Any, ...], dict[str, float], float]:
        """One grid point's score test: (the coordinates' values at the step, statistic, robust statistic, the
        whole step, admissible), the one-sigma size of each linear coordinate, and the effect's smallest size the
        loop could name there (``screening.detection_limit``; ``grid_of``: the grid's size and whether the test is
        one-sided)."""
        cols = [self._column(model, name, c.name, point, r) for c in linear]
        B = np.column_stack(cols)
        lm, robust, step, ok = score_test(r, Q, B, tuple(c.from_zero for c in linear))
        base_step = -np.linalg.lstsq(J, r + B @ step, rcond=None)[0]
        by_name = {c.name: c for c in coords}
        values = {**{k: by_name[k].value(v) for k, v in point.items()},
                  **{c.name: c.value(float(x)) for c, x in zip(linear, step)}}
        sizes = {c.name: c.scale * SCREEN_RESPONSE_SIGMA / max(rms(col), 1e-300) for c, col in zip(linear, cols)}
        x = np.array([point[c.name] if c.name in point else 0.0 for c in coords])
        x[[coords.index(c) for c in _sized(name, linear)]] = _limit(name, linear, r, Q, B, grid_of)
        limit = magnitude_of(name, fmu_values(name, coords, x)) if np.all(np.isfinite(x)) else math.inf
        return (values, lm, robust, np.concatenate([base_step, step]), ok), sizes, limit

    def _column(self, model: Fitted, name: str, coord: str, point: dict[str, float], r: np.ndarray) -> np.ndarray:
        """d(load residual)/dx of coordinate ``coord`` of effect ``name`` at 0 (the other coordinates at
        ``point``), by a one-sided difference whose size makes the load move by ~SCREEN_RESPONSE_SIGMA."""
        return one_sided_column(lambda h: self._difference(model, name, {**point, coord: h}), r, 1e-5,
                                SCREEN_RESPONSE_SIGMA)

    def _difference(self, model: Fitted, name: str, x: dict[str, float]) -> np.ndarray:
        """Load residuals of ``model`` with effect ``name`` held at coordinates ``x`` (through the same
        propagator as the screen's reference)."""
        st = model.state
        coords = coordinates(name, st.scales)
        values = fmu_values(name, coords, np.array([x.get(c.name, 0.0) for c in coords]))
        problem = st.problem(self.full, model.effects, self.stop, self.sigma, fixed=values, general=True)
        try:
            return problem.residuals(st.theta)[problem.load_rows()].copy()
        finally:
            problem.close()

    # ---------------------------------------------------------------------------------------- refits ----------

    def refit(self, model: Fitted, test: ScoreTest, budget: float | None) -> CandidateFit:
        if test.candidate == FLEXIBILITY:
            return self._flexibility()
        effects = model.effects + (test.candidate,)
        st = model.state
        sens = {**st.sens, test.candidate: dict(test.sensitivity)}
        meter = EvaluationBudget(None if budget is None else budget * self.stop)
        leaning = at_bound(st.theta)
        start = ("identified from scratch (the current model leans on " + ", ".join(leaning) + ")") if leaning \
            else "the screen's Gauss-Newton step"
        try:
            fit = self._from_scratch if leaning else self._from_step
            theta, spent = fit(model, effects, test, sens, meter)
        except BudgetExceeded as exc:
            return CandidateFit(test.candidate, error=str(exc), exhausted=True, evaluations=meter.used / self.stop,
                                start=start)
        fitted = self.evaluate(effects, theta, st.base, st.scales, sens=sens, fixed=st.fixed)
        return CandidateFit(test.candidate, fitted, evaluations=meter.used / self.stop, start=start, exhausted=spent)

    @staticmethod
    def _start(model: Fitted, test: ScoreTest, sens: Sensitivity) -> np.ndarray:
        """The candidate's coordinates at the screen's best point: outside their bounds where the step points to a
        size the effect cannot take (clipped for the step's heads, reflected for a retry: ``_retry_starts``)."""
        coords = coordinates(test.candidate, model.state.scales, sens.get(test.candidate))
        return np.array([c.x_of(test.start[c.name]) if c.name in test.start else 0.0 for c in coords])

    def _from_step(self, model: Fitted, effects: tuple[str, ...], test: ScoreTest, sens: Sensitivity,
                   meter: EvaluationBudget) -> tuple[np.ndarray, bool]:
        """The refit from the screen's step: (its unknowns, whether it used up its budget first). A fit that did
        returns the best point it simulated, to be judged like any other (``CandidateFit.exhausted``). A refit
        that did not test its candidate (``ScoreTest.tested_by`` on the problem's cost, against the current model's,
        at a model above its noise level) is run again from ``_retry_starts`` (scaled back as the step is, and not
        where every scaled start is uphill from the current model: ``_start_head``), within the same budget; the best
        point of all the runs is the refit's, and the budget counts as used up when any run used it up."""
        st = model.state
        coords = coordinates(test.candidate, st.scales, sens.get(test.candidate))
        x = self._start(model, test, sens)
        runs = [_heads(st.theta, test.step, _clipped(x, coords), coords)]
        if above_level(self.over_noise(model), self.confident_levels()):
            runs += [_heads(st.theta, np.zeros_like(st.theta), r, coords) for r in _retry_starts(test, coords, x)]
        best: tuple[float, np.ndarray] | None = None
        unmoved, spent = math.inf, False
        for i, heads in enumerate(runs):
            problem = ModelProblem(self.full, st.base, _fmu_effects(effects), st.scales, self.stop, self.sigma,
                                   budget=meter, sens=sens, central=False, fixed=st.fixed)
            try:
                lo, hi = problem.bounds()
                costs = [problem.cost(np.clip(h, lo, hi)) for h in heads]
                if i == 0:   # the current model itself, the effect off
                    unmoved = costs[1 + STEP_FRACTIONS.index(0.0)]
                start = _start_head(costs, retry=i > 0)
                if start is None:
                    continue
                theta, spent = _spent_or_best(problem, np.clip(heads[start], lo, hi), lo, hi)
                cost = problem.best[0] if problem.best is not None else math.inf
            finally:
                problem.close()
            if best is None or cost < best[0]:
                best = (cost, theta)
            if spent or test.tested_by(unmoved - best[0]):   # a run that used up the budget is the last
                break
        assert best is not None
        return best[1], spent

    def _from_scratch(self, model: Fitted, effects: tuple[str, ...], test: ScoreTest, sens: Sensitivity,
                      meter: EvaluationBudget) -> tuple[np.ndarray, bool]:
        """The refit identified from scratch (``fit_pipeline``'s continuation); (its unknowns, False): a budget used
        up there raises."""
        st = model.state
        x = self._start(model, test, sens)
        coords = coordinates(test.candidate, st.scales, sens.get(test.candidate))
        x = _reflected(x, coords)
        rows = [np.concatenate([st.theta[BASE_UNKNOWNS:], x])]
        for point in grid(test.candidate, st.scales):  # the grid's other points as further starts
            alt = np.array([point.get(c.name, xi) for c, xi in zip(coords, x)])
            rows.append(np.concatenate([st.theta[BASE_UNKNOWNS:], alt]))
        problem, theta, _, _, _ = fit_pipeline(truncate_log(self.full, self.stop), st.base,
                                               ModelProblem.maker(_fmu_effects(effects), st.scales, meter, sens,
                                                                  st.fixed),
                                               np.unique(np.array(rows), axis=0))
        problem.close()
        return theta, False

    def _flexibility(self) -> CandidateFit:
        try:
            model = self._identified()
        except Exception as exc:  # noqa: BLE001 - a log the identifier refuses: the candidate is reported, not fatal
            return CandidateFit(FLEXIBILITY, error=f"{type(exc).__name__}: {exc}", start="identify")
        model.effects = (FLEXIBILITY,)
        model.state.sim = None
        return CandidateFit(FLEXIBILITY, model, start="the two-inertia identification (identify)")

    def without(self, model: Fitted, name: str, budget: float | None) -> Fitted:
        st = model.state
        if name == FLEXIBILITY:
            if model.effects != (FLEXIBILITY,):  # the library effects need the flexible model
                return replace(model, held_cost=math.inf, train_cost=math.inf)
            return self._rigid()
        effects = tuple(e for e in model.effects if e != name)
        keep = [*range(BASE_UNKNOWNS), *(BASE_UNKNOWNS + i for i, c in enumerate(_layout(model)) if c.effect != name)]
        return self._fit_from(model, effects, st.theta[keep], budget, max_iter=REFIT_ITER, clip=False)

    def _fit_from(self, model: Fitted, effects: tuple[str, ...], head: np.ndarray, budget: float | None, *,
                  max_iter: int = 500, pin: list[int] | tuple[int, ...] = (), clip: bool = True,
                  unit: float | None = None, steps: np.ndarray | None = None) -> Fitted:
        """``model``'s drive with ``effects`` on, refitted on the training part by IPOPT from ``head`` within
        ``budget`` (``_refitted``), simulated over the whole log."""
        st = model.state
        theta, _ = self._refitted(model, effects, head, budget, max_iter=max_iter, pin=pin, clip=clip, unit=unit,
                                  steps=steps)
        return self.evaluate(effects, theta, st.base, st.scales, sens=st.sens, fixed=st.fixed)

    def _refitted(self, model: Fitted, effects: tuple[str, ...], head: np.ndarray, budget: float | None, *,
                  max_iter: int = 500, pin: list[int] | tuple[int, ...] = (), clip: bool = True,
                  unit: float | None = None, steps: np.ndarray | None = None) -> tuple[np.ndarray, bool]:
        """The unknowns of ``model``'s drive with ``effects`` on, refitted on the training part by IPOPT from
        ``head`` within ``budget`` (as ``refit``), and whether the budget ran out first (a fit that runs out keeps
        the best point it simulated, or its start when it simulated none). ``pin``: unknowns held where ``head``
        has them (inside their bounds); ``clip``: the start moved inside the bounds; ``unit``: the budget's
        reference cost (``EvaluationBudget``; None: simulations are counted); ``steps``: the Jacobian's
        finite-difference steps per unknown, where wider than its micro-steps (``search_steps``)."""
        st = model.state
        problem = st.problem(self.full, effects, self.stop, self.sigma, central=False,
                             budget=EvaluationBudget(None if budget is None else budget * self.stop, unit))
        problem.fd_steps = steps
        try:
            lo, hi = problem.bounds()
            if pin:
                problem.pinned = {i: float(np.clip(head[i], lo[i], hi[i])) for i in pin}
                lo, hi = problem.bounds()
            start = np.clip(head, lo, hi) if clip else head
            try:
                return _spent_or_best(problem, start, lo, hi, max_iter)
            except BudgetExceeded:
                return start, True
        finally:
            problem.close()

    def converge(self, model: Fitted, budget: float | None, unfinished: bool = False) -> tuple[Fitted, str]:
        """Identified from scratch with its effects when the accepted model leans on a parameter bound (it was
        fitted from a model that could not fit the log inside the physical range); else refitted on from where it
        stopped when its refit used up its budget first (``unfinished``); else as refitted. Then its initial
        deflection's basins are checked (``_basin_checked``)."""
        if model.state.rigid or model.effects == (FLEXIBILITY,):
            return self.resimulated(model), ""
        out, how = self._converged(model, budget, unfinished)
        return self._basin_checked(out, how, budget)

    def _converged(self, model: Fitted, budget: float | None, unfinished: bool) -> tuple[Fitted, str]:
        """``converge`` before the basins' check."""
        if not at_bound(model.state.theta):
            return self._continued(model, budget) if unfinished else (self.resimulated(model), "")
        st = model.state
        meter = EvaluationBudget(None if budget is None else budget * self.stop)
        try:
            problem, theta, _, _, _ = fit_pipeline(truncate_log(self.full, self.stop), st.base,
                                                   ModelProblem.maker(_fmu_effects(model.effects), st.scales,
                                                                      meter, st.sens, st.fixed),
                                                   st.theta[BASE_UNKNOWNS:][None, :])
            problem.close()
        except BudgetExceeded:
            return self.resimulated(model), (f"identifying {' + '.join(model.effects)} from scratch used up its "
                                              f"budget ({meter.used / self.stop:.0f} training logs simulated): the "
                                              "refitted model is kept")
        fresh = self.evaluate(model.effects, theta, st.base, st.scales, keep=True, sens=st.sens, fixed=st.fixed)
        if fresh.train_cost < model.train_cost:
            return fresh, (f"identified from scratch with {' + '.join(model.effects)}: training cost "
                           f"{model.train_cost:.6g} -> {fresh.train_cost:.6g}")
        return self.resimulated(model), ""

    def _basin_checked(self, model: Fitted, how: str, budget: float | None) -> tuple[Fitted, str]:
        """``model`` refitted from the lowest basin of its initial deflection where that is lower by more than one
        noise variance (``identify.lower_deflection_basin``, within ``budget``) and the refit fits the training data
        better; ``how`` with a sentence saying so. Why: the identifier checks the basins at the base model, and every
        refit stays in the basin it starts in, but an effect moves them. Measured on an independent default-design log
        with a strong exponential Stribeck friction (seed 7722, 8 s at 4 kHz): the base model's basin, -0.09 band,
        stayed the model's after Stribeck was accepted, while with Stribeck the basin at -0.89 band (the truth: -0.895)
        was 7,800 noise variances lower; the misfit of the log's first 0.15 s left the model at 1.2x the noise, every
        name tentative, and a stand-in (asymmetric friction) was named for it. The scan's refinement also finds lower
        points inside the model's own basin, where a refit stopped short along this kinked direction: on the matrix's
        two-effect and outside logs 9 of the 13 moves were of 0.013 band or less; the others -0.39 -> -0.12 (two
        right names turned confident), -0.44 -> -1.0, -1.0 -> -0.04 and +0.59 -> -0.39."""
        st = model.state
        problem = st.problem(self.full, model.effects, self.stop, self.sigma, central=False,
                             budget=EvaluationBudget(None if budget is None else budget * self.stop))
        try:
            head = lower_deflection_basin(problem, st.theta)
        except BudgetExceeded:
            head = None
        finally:
            problem.close()
        if head is None:
            return model, how
        moved = self._fit_from(model, model.effects, head, budget)
        if not moved.train_cost < model.train_cost:
            return model, how
        note = (f"the scan of its initial deflection across the static band found a lower cost at {head[3]:+.3f} "
                f"band (was {st.theta[3]:+.3f}); refitted from there: training cost {model.train_cost:.6g} -> "
                f"{moved.train_cost:.6g}")
        return moved, "; ".join(x for x in (how, note) if x)

    def _continued(self, model: Fitted, budget: float | None) -> tuple[Fitted, str]:
        """``model`` refitted on from its point, within ``budget``: the next screen is a score test at the current
        model's optimum, and a model stopped short of it leaves gradients that the candidates' scores would take up."""
        more = self._fit_from(model, model.effects, model.state.theta, budget)
        if not more.train_cost < model.train_cost:
            return self.resimulated(model), ""
        return more, (f"its refit had used up its budget; refitted on from where it stopped: training cost "
                      f"{model.train_cost:.6g} -> {more.train_cost:.6g}")

    # ---------------------------------------------------------------------------------------- naming ----------

    def magnitude(self, model: Fitted, name: str) -> Magnitude:
        st, cov = model.state, self._cov(model)
        if name == FLEXIBILITY:
            K, sd = st.params.K_s, math.sqrt(max(cov[0, 0], 0.0))
            return Magnitude(K, (K * math.exp(-Z95 * sd), K * math.exp(Z95 * sd)), "N.m/rad", {"K_s": K})
        idx = _effect_indices(model, name)
        coords = [c for c in _layout(model) if c.effect == name]
        x = st.theta[idx]
        values = {v.param: float(getattr(st.params, v.param)) for v in EFFECTS[name].fit_vars}
        mag = magnitude_of(name, values)
        grad = _magnitude_gradient(name, coords, x)
        sd = math.sqrt(max(float(grad @ cov[np.ix_(idx, idx)] @ grad), 0.0))
        lo, hi = mag - Z95 * sd, mag + Z95 * sd
        if name == "asymmetric_friction" and lo < 0 < hi:
            lo = 0.0
        return Magnitude(mag, (lo, hi), EFFECTS[name].unit, values, _size_doubt(name, st.scales))

    def probe_size(self, model: Fitted, name: str, factor: float, budget: float | None,
                   reference: Fitted | None = None) -> Fitted | None:
        """The effect's linear coordinates (its size: the only one for every effect but the kinematic error, whose
        sine and cosine parts, of its 2/rev and where fitted its 4/rev, are held together, fixing its phases too) held
        at ``factor`` times their values; the other unknowns start where the model's covariance predicts them along
        the valley (their regression on the held ones) and are refitted within ``budget``. A probe that runs out of
        budget returns the best point it simulated (its cost is then an upper bound of the profile's)."""
        st = model.state
        if st.rigid or name == FLEXIBILITY:
            return None
        held = _size_indices(model, name)
        free = [i for i in range(st.theta.size) if i not in held]
        delta = st.theta[held] * (factor - 1.0)
        cov = self._cov(model)
        head = st.theta.copy()
        head[held] += delta
        head[free] += cov[np.ix_(free, held)] @ np.linalg.lstsq(cov[np.ix_(held, held)], delta, rcond=None)[0]
        return self._fit_from(model, model.effects, head, budget, pin=held,
                              unit=None if reference is None else reference.state.work,
                              steps=self.search_steps(model))

    def polish(self, model: Fitted, budget: float | None) -> tuple[Fitted, str]:
        """``model`` refitted from its optimum, every unknown free, with the steps of ``search_steps``; kept where
        it fits the training data better.

        Why: the loop's refits take their Jacobians by micro-steps (1e-6), which resolve the last digits but catch
        the kinks of marginal stick/slip events, and Gauss-Newton then stalls on a long log (the identifier's
        windows avoid it so: ``identify._fit_window``). Measured on the independent generator's torque-step log of a
        strong kinematic error (seed 5102) with ten noise draws: the named size scattered 0.41 % (mean +0.15 %)
        against a 95 % interval of +-0.17 %, three intervals in ten holding the truth; refitted free from the final
        model held 10 % smaller or larger, micro-steps stayed there (+12000 noise variances), these steps came back
        to one point (to 2e-5 of the size) 59 noise variances below the final model. Polished, the size scattered
        0.14 % (mean +0.02 %) and seven intervals in ten held the truth: still narrower than the scatter, which the
        effects' finite-difference steps then explained (below the simulation's round-off: ``problem.COORD_STEP``)."""
        if model.state.rigid or not model.effects or model.effects == (FLEXIBILITY,):
            return model, ""
        st = model.state
        better = self._fit_from(model, model.effects, st.theta, budget, steps=self.search_steps(model))
        if not better.train_cost < model.train_cost:
            return model, ""
        self._cov(better)   # once, here: the size search's probes take their steps from it on every worker
        return better, (f"refitted from its optimum with finite-difference steps of {SEARCH_STEP:g} of its unknowns' "
                        f"standard deviations: training cost {model.train_cost:.6g} -> {better.train_cost:.6g} "
                        f"({model.train_cost - better.train_cost:.3g} noise variances)")

    def search_steps(self, model: Fitted) -> np.ndarray:
        """The identifier's search steps (``identify.search_steps_of``) from ``model``'s covariance (``polish``)."""
        return search_steps_of(self._cov(model))

    def half(self, model: Fitted, which: int, budget: float | None) -> Fitted | None:
        """``model`` refitted on the first (``which`` 0) or the second half of the training part alone, every unknown
        free from its optimum, within ``budget``; its covariance from that half alone. The second half is simulated
        from the log's start (the first half carries the state) but only its own samples are data."""
        st = model.state
        if st.rigid or not model.effects or model.effects == (FLEXIBILITY,):
            return None
        h = self.stop // 2
        problem = st.problem(self.full, model.effects, self.stop if which else h, self.sigma, central=False,
                             budget=EvaluationBudget(None if budget is None else budget * self.stop))
        problem.skip = h if which else 0
        try:
            lo, hi = problem.bounds()
            theta = _ipopt_or_best(problem, np.clip(st.theta, lo, hi), lo, hi)
            problem.budget, problem.central = None, True
            covs = covariances(problem, theta, self._block, skip=problem.skip)
        except BudgetExceeded:
            return None
        finally:
            problem.close()
        out = self.evaluate(model.effects, theta, st.base, st.scales, sens=st.sens, fixed=st.fixed)
        out.state.covs = covs[:2]
        return out

    def constancy(self, first: Fitted, second: Fitted) -> tuple[float, int]:
        """The Wald statistic of "both halves have the same K*, J_l*, f_l* and effect coordinates" and its degrees
        of freedom (the initial deflection is left out: it belongs to the log's start, which the second half does
        not see). The halves' data are independent, so the difference's covariance is the sum of theirs."""
        keep = [*range(BASE_UNKNOWNS - 1), *range(BASE_UNKNOWNS, first.state.theta.size)]   # not the deflection
        d = first.state.theta[keep] - second.state.theta[keep]
        V = (self._cov(first) + self._cov(second))[np.ix_(keep, keep)]
        return float(d @ np.linalg.pinv(V, rcond=1e-12) @ d), len(keep)

    def effect_start(self, model: Fitted, name: str) -> dict[str, float]:
        if model.state.rigid:
            return {}
        theta = model.state.theta
        return {c.name: c.value(float(theta[BASE_UNKNOWNS + i])) for i, c in enumerate(_layout(model))
                if c.effect == name}

    def refit_cost(self, name: str) -> float:
        """``SIMULATION_S`` of the candidate's effect; flexibility (an identification from scratch) and any effect
        not measured there: the costliest."""
        return SIMULATION_S.get(name, max(SIMULATION_S.values()))

    def twin_of(self, model: Fitted, name: str) -> tuple[str, str, str] | None:
        """Viscous friction on the other side of the gear (``TWINS``): a load-side coefficient b_l acts on the motor
        as r^2 b_l, so the two sides differ only through the spring's deflection, by about b d' / K in the load
        angle."""
        carried = _carried(model, name)
        if carried is None:
            return None
        rival, value = carried
        own_param, rival_param, power = TWINS[name][1:]
        how = f"{own_param} r^2" if power == 2 else f"{own_param} / r^2"
        return (rival, f"{rival_param} = {value:.4g} N.m.s/rad = {how}",
                "a log whose spring deflection changes fast (a ringing excited hard: b x the deflection rate / K "
                "above the load sensor's noise) would tell the two sides apart")

    def twin(self, model: Fitted, name: str, budget: float | None) -> Fitted | None:
        """The twin (``twin_of``) starts at the carried-over size, every other unknown where ``model`` has it."""
        carried = _carried(model, name)
        if carried is None:
            return None
        rival, value = carried
        st = model.state
        head = st.theta.copy()
        head[_effect_indices(model, name)] = coordinates(
            rival, st.scales, st.sens.get(rival))[0].x_of(value)
        return self._fit_from(model, tuple(rival if e == name else e for e in model.effects), head, budget)

    def shape_rival_of(self, name: str) -> str:
        return SHAPES[name].rival if name in SHAPES else ""

    def shape_of(self, model: Fitted, name: str) -> str:
        shape = SHAPES.get(name)
        return shape.words if shape and model.state.fixed.get(shape.param) == shape.value else ""

    def with_other_shape(self, model: Fitted, name: str) -> Fitted | None:
        """``model`` with the FMU parameter of ``name``'s other shape (``SHAPES``) held at that shape's value, or let
        go back to the library's where it holds it already (a model that dropped an adopted effect): the same model
        (``name`` is off in it), whose refits add ``name`` in the other shape."""
        if name not in SHAPES or model.state.rigid or name in model.effects:
            return None
        st = model.state
        return replace(model, state=replace(st, fixed=_toggled(st.fixed, SHAPES[name], st.scales)))

    def shape_rival(self, model: Fitted, name: str, budget: float | None) -> ShapeFit | None:
        """The effect in its other shape (``SHAPES``; the library's again where ``model`` has the rival's): the FMU
        parameter held at that shape's value, every unknown refitted from ``model``'s optimum, the effect's
        coordinates shifted as ``SHAPES`` says."""
        if name not in SHAPES or model.state.rigid or name not in model.effects:
            return None
        shape, st = SHAPES[name], model.state
        what, sign = (shape.library, -1.0) if self.shape_of(model, name) else (shape.rival, 1.0)
        fixed = _toggled(st.fixed, shape, st.scales)
        rival = replace(model, state=replace(st, fixed=fixed, sim=None, cov=None, covs=None))
        head = st.theta.copy()
        for i, c in enumerate(_layout(model)):
            if c.effect == name:
                head[BASE_UNKNOWNS + i] += sign * shape.shifts.get(c.name, 0.0)
        theta, unfinished = self._refitted(rival, model.effects, head, budget)
        out = self.evaluate(model.effects, theta, st.base, st.scales, sens=st.sens, fixed=fixed)
        size = self.magnitude(out, name)
        return ShapeFit(out, size.value, size.ci95, what, unfinished)

    def outside_rival(self, model: Fitted, names: list[str]) -> tuple[dict[str, float], str, str]:
        """A ripple of the motor friction in place of each named effect (``ripple``), linearized at ``model``."""
        named = [n for n in names if n != FLEXIBILITY and _size_indices(model, n)]
        if model.state.rigid or not named:
            return {}, "", ""
        model = self.resimulated(model)
        st = model.state
        problem = st.problem(self.full, model.effects, self.stop, self.sigma, general=True)
        try:
            rows = problem.load_rows()
            r = problem.residuals(st.theta)[rows].copy()
            J = problem.jacobian(st.theta)[rows]
        finally:
            problem.close()

        def residuals_with(extra: np.ndarray) -> np.ndarray:
            log = replace(self.full, motor_torque_Nm=self.full.motor_torque_Nm + extra)
            p = st.problem(log, model.effects, self.stop, self.sigma, general=True)
            try:
                return p.residuals(st.theta)[rows].copy()
            finally:
                p.close()

        H = ripple.columns(residuals_with, r, ripple.torques(st.sim["q_m"], st.sim["v_m"], st.params.f_m),
                           SCREEN_RESPONSE_SIGMA)
        costs = ripple.stand_in_costs(r, J, st.theta, {n: (_size_indices(model, n), _effect_indices(model, n))
                                                       for n in named}, H)
        what = (f"a ripple of the motor friction (its level varying along the motor's travel at "
                f"{', '.join(map(str, ripple.HARMONICS))} per motor revolution; outside the library)")
        return costs, what, self._ripple_advice(st.sim)

    def _ripple_advice(self, sim: dict[str, np.ndarray]) -> str:
        """What a log needs to tell a named effect from a friction ripple, with where this one's slides were."""
        q, v = sim["q_m"][:self.stop], sim["v_m"][:self.stop]
        where = [f"{np.mean(q[sel]):.3g} rad" if np.any(sel) else "none" for sel in (v > 0, v < 0)]
        return (f"record slides in both directions over the same motor angles and over at least a motor turn (here "
                f"the motor turned through {self.motor_span:.3g} rad; its forward slides at a mean angle of "
                f"{where[0]}, its backward ones at {where[1]})")

    def _cov(self, model: Fitted) -> np.ndarray:
        """The unknowns' covariance as ``identify`` reports it (``larger_variances``: per parameter the larger of
        the sandwich and noise-only variances, the sandwich's correlations; computed once per model)."""
        st = model.state
        if st.cov is None:
            noise, sand = self._covs(model)
            st.cov = larger_variances(sand, noise)
        return st.cov

    def _covs(self, model: Fitted) -> tuple[np.ndarray, np.ndarray]:
        """(noise-only, sandwich) covariances of the unknowns (``identify.covariances``, blocks of 20 ms)."""
        st = model.state
        if st.covs is None:
            problem = st.problem(self.full, model.effects, self.stop, self.sigma)
            try:
                noise, sand, _ = covariances(problem, st.theta, self._block)
            finally:
                problem.close()
            st.covs = (noise, sand)
        return st.covs

    @property
    def _block(self) -> int:
        """The sandwich covariance's block: 20 ms of samples (at least 10)."""
        return max(10, int(self.full.meta.sample_rate_hz / 50))

    def size_inflation(self, model: Fitted, name: str) -> float:
        """The sandwich variance of the effect's size over its noise-only variance, along the direction its size
        search moves (its linear coordinates scaled together)."""
        st = model.state
        held = _size_indices(model, name)
        if st.rigid or not held:
            return 1.0
        noise, sand = self._covs(model)
        v = st.theta[held]
        num, den = float(v @ sand[np.ix_(held, held)] @ v), float(v @ noise[np.ix_(held, held)] @ v)
        return num / den if den > 0 and math.isfinite(num / den) else 1.0

    def over_noise(self, model: Fitted) -> tuple[float, float]:
        m = model.metrics
        return m["train_over_noise_load"], m["heldback_over_noise_load"]

    def confident_levels(self) -> tuple[float, float]:
        """The chance level of each part (``at_noise_level``: the noise was estimated on the training part), never
        above ``CONFIDENT_OVER_NOISE``; on a short log the fixed level is within the noise's scatter, and names are
        then tentative more often than ``CONFIDENT_ALPHA``, the safe side."""
        parts = (self.stop, self.full.n - self.stop)
        low, high = (min(CONFIDENT_OVER_NOISE, at_noise_level(n, self.stop, CONFIDENT_ALPHA)) for n in parts)
        return low, high

    def regimes(self, model: Fitted) -> pd.DataFrame:
        model = self.resimulated(model)
        return report.residual_regimes(self.full, model.state.sim, model.metrics["noise_load_rad"],
                                       self.full.meta.f_m_Nm)

    def unexplained(self, model: Fitted, table: pd.DataFrame) -> list[dict[str, Any]]:
        over = self.over_noise(model)
        return report.unexplained(table, max(over)) if above_level(over, self.confident_levels()) else []

    def step(self, model: Fitted, added: str | None, score: float | None, extra: dict[str, Any]) -> DiagnosisStep:
        return report.step(model, added, score, extra, self.resolution_pulses)

    def derivations(self) -> list[str]:
        return report.derivations() + (self.scales.describe() if self.scales is not None else [])

    def notes(self) -> list[str]:
        return [f"held-back data: {self.held_source} (t >= {self.full.time_s[self.stop]:.3f} s), only ever "
                f"predicted; load sensor noise {self.sigma:.4g} rad (the identifier's estimate: the white part of "
                "the base fit's residual on the training part; it weighs every fit). Whether a model reaches the "
                "noise is read against the lower of that and the white part of the model's own training residual "
                "(noise_load_rad in each step): a base fit that misses an effect reads the noise high"]

    def export(self, model: Fitted, folder: Path) -> tuple[Path | None, str]:
        from ...model.export import export_fitted_fmu

        path = export_fitted_fmu(model.state.params, folder / "HarmonicDrive_fitted.fmu")
        return path, "the HarmonicDrive FMU with the final model's parameters as start values"

    def plots(self, models: list[Fitted], folder: Path) -> dict[str, str]:
        sims = [self.resimulated(m) for m in (models[0], models[-1])]
        return report.plots(self.full, self.stop, sims, folder)


# ------------------------------------------------------------------------------------------- helpers -----------

#: fractions of the screen's Gauss-Newton step tried as the refit's start (a backtracking line search; 0: the current
#: model with the candidate off, so that a refit never ends worse than the model it extends)
STEP_FRACTIONS = (1.0, 0.5, 0.25, 0.125, 0.0)


def _heads(theta: np.ndarray, step: np.ndarray, x: np.ndarray, coords: list[Any]) -> list[np.ndarray]:
    """Starts of a candidate's refit: the current unknowns ``theta`` with the candidate's coordinates ``x`` at the
    screen's point, and the Gauss-Newton step scaled back (``STEP_FRACTIONS``: the unknowns' step and the
    candidate's linear coordinates together). The full step is a linearisation at the effect off, and an effect that
    reorders stick and slip answers it far from linearly: measured on a two-effect log, the kinematic error's full
    step started its refit at 100x the current model's cost, and the refit ended there."""
    linear = np.array([not c.log for c in coords], dtype=bool)
    heads = [np.concatenate([theta, x])]
    for a in STEP_FRACTIONS:
        heads.append(np.concatenate([theta + a * step, np.where(linear, a * x, x)]))
    return heads


def _start_head(costs: list[float], retry: bool) -> int | None:
    """Which of a run's heads (``_heads``, with their costs) IPOPT starts from: the cheapest; for a retry
    (``_retry_starts``: its heads are the current unknowns with the candidate's linear coordinates scaled back) None
    when none of them is below the current model (the head at fraction 0): every step along the retry's direction is
    uphill, and IPOPT from the current model is the first run, which ended where it began.

    Why: a retry from an uphill start spends most of the candidate's budget climbing back down to the current model.
    Measured on an actuator-lag log of the independent generator (outside the library, 27x the noise, seed 5407): at
    steps 1 and 2 the retries of viscous friction (either side) and hardening started at 1.6-2.1x the current cost,
    took 110-265 simulations each and ended 12-30 noise variances above the current model, using up three
    candidates' budgets of 300 simulations at step 2."""
    start = int(np.argmin(costs))
    if retry and not costs[start] < costs[1 + STEP_FRACTIONS.index(0.0)]:
        return None
    return start


def _clipped(x: np.ndarray, coords: list[Any]) -> np.ndarray:
    """``x`` with each coordinate outside its bounds set to the bound it crossed."""
    return np.clip(x, [c.lo for c in coords], [c.hi for c in coords])


def _reflected(x: np.ndarray, coords: list[Any]) -> np.ndarray:
    """``x`` with each coordinate outside its bounds reflected about the bound it crossed (then clipped, where the
    reflection overshoots the other bound)."""
    lo, hi = np.array([c.lo for c in coords]), np.array([c.hi for c in coords])
    return _clipped(np.where(x < lo, 2.0 * lo - x, np.where(x > hi, 2.0 * hi - x, x)), coords)


def _retry_starts(test: ScoreTest, coords: list[Any], x: np.ndarray) -> list[np.ndarray]:
    """Where a refit that did not test its candidate starts again (the current unknowns kept): the candidate's
    unknowns where its refit of the step before left them (``ScoreTest.carried``), then the screen's point
    reflected into the bounds where the step put a size outside them (``_reflected``).

    The exact stick-slip makes the cost kinked: at a model that stands in for the effect with its other parameters,
    the first order holds only a hair around it, or points to a size the effect cannot take, and every head of
    ``_heads`` is the current model or worse; the refit ends where it began. Measured on a two-effect log of the
    independent generator (a motor viscous friction of 9.08e-6 N.m.s/rad and a Stribeck friction with its own static
    level): step 0's refit of b_m alone reached 9.01e-6; after Stribeck (1.96x the noise) the step put b_m at
    -6.1e-6, and the refits of b_m, asymmetric friction and kinematic error each removed 0.02 noise variances, so
    none was tested and the missing effect was never named. From +6.1e-6 the b_m refit reached 9.12e-6 and a
    2.9x lower held-back cost. Both starts come from the log's own fits, nothing from a table."""
    out = []
    if test.carried:
        out.append(_clipped(np.array([c.x_of(test.carried[c.name]) if c.name in test.carried else xi
                                      for c, xi in zip(coords, x)]), coords))
    inside = _reflected(x, coords)   # already inside the bounds
    if not np.array_equal(inside, _clipped(x, coords)):
        out.append(inside)
    return out


def _ipopt_or_best(problem: ModelProblem, head: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                   max_iter: int = 500) -> np.ndarray:
    """IPOPT from ``head``, checked between iterations: a fit that settles (``ModelProblem.settled``) or stalls
    (three iterations' simulations without progress, ``ModelProblem.stalled``) ends there; one whose budget cannot
    pay for another iteration raises ``BudgetExceeded``. The result is the best point simulated (every iterate
    IPOPT returns was simulated)."""
    per_iteration = head.size + 2
    theta, _ = fit_ipopt(problem, head, lo, hi, max_iter,
                         stop=lambda: problem.settled() or problem.stalled(3 * per_iteration)
                         or problem.spent(per_iteration))
    if problem.spent(per_iteration) and not (problem.settled() or problem.stalled(3 * per_iteration)):
        raise BudgetExceeded(f"the fit used up its budget of {problem.budget.limit / problem.stop:.4g} simulations "
                             "before it converged")
    return problem.best[1] if problem.best is not None else theta


def _spent_or_best(problem: ModelProblem, head: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                   max_iter: int = 500) -> tuple[np.ndarray, bool]:
    """``_ipopt_or_best``, and whether its budget ran out first: then the best point it simulated instead (a fit
    cut short keeps what it reached; ``BudgetExceeded`` only when it simulated none)."""
    try:
        return _ipopt_or_best(problem, head, lo, hi, max_iter), False
    except BudgetExceeded:
        if problem.best is None:
            raise
        return problem.best[1], True


def _carried(model: Fitted, name: str) -> tuple[str, float] | None:
    """(the twin of effect ``name``, its size carried over by the gear ratio) in ``model`` (``TWINS``); None when
    ``name`` has no twin or the twin is already in the model."""
    if name not in TWINS or model.state.rigid or TWINS[name][0] in model.effects:
        return None
    rival, own_param, _, power = TWINS[name]
    return rival, float(getattr(model.state.params, own_param)) * model.state.params.r ** power


def _toggled(fixed: dict[str, float], shape: Shape, scales: LogScales | None) -> dict[str, float]:
    """``fixed`` with ``shape``'s FMU parameter switched: held at the other shape's value (with the parameters it
    holds at the log's values), or let go back to the FMU's default (the library's shape) where ``fixed`` holds it
    already."""
    held = shape.held(scales) if shape.held is not None and scales is not None else {}
    out = {k: v for k, v in fixed.items() if k != shape.param and k not in held}
    if fixed.get(shape.param) != shape.value:
        out.update({shape.param: shape.value, **held})
    return out


def _effect_indices(model: Fitted, name: str) -> list[int]:
    """Indices in the unknowns of all of effect ``name``'s coordinates."""
    return [BASE_UNKNOWNS + i for i, c in enumerate(_layout(model)) if c.effect == name]


def _size_indices(model: Fitted, name: str) -> list[int]:
    """Indices in the unknowns of effect ``name``'s linear coordinates: its size, which ``probe_size`` holds."""
    return [BASE_UNKNOWNS + i for i, c in enumerate(_layout(model)) if c.effect == name and not c.log]


def _fmu_effects(effects: tuple[str, ...]) -> tuple[str, ...]:
    """The library effects among ``effects`` (flexibility is the model itself, not an FMU effect)."""
    return tuple(e for e in effects if e != FLEXIBILITY)


def _layout(model: Fitted) -> list[Any]:
    st = model.state
    return [c for name in _fmu_effects(model.effects) for c in coordinates(name, st.scales, st.sens.get(name))]


def _sized(name: str, linear: list[Any]) -> list[Any]:
    """The linear coordinates whose values make effect ``name``'s magnitude (``SIZE_COORDS``; default all)."""
    keep = SIZE_COORDS.get(name)
    return [c for c in linear if keep is None or c.name in keep]


def _limit(name: str, linear: list[Any], r: np.ndarray, Q: np.ndarray, B: np.ndarray, grid_of: tuple[int, bool]
           ) -> np.ndarray:
    """The coordinates of effect ``name``'s size at its detection limit (``screening.detection_limit``): its other
    linear coordinates (the kinematic error's 4/rev) are unknowns a fit would free too, partialled out with the
    current model's, and the screen's degrees of freedom count them."""
    sized = _sized(name, linear)
    own = [i for i, c in enumerate(linear) if c in sized]
    rest = [i for i in range(len(linear)) if i not in own]
    Qx = partial_out(np.column_stack([Q, B[:, rest]])) if rest else Q
    return detection_limit(r, Qx, B[:, own], *grid_of, MIN_GAIN, df=len(linear))


def _size_doubt(name: str, scales: LogScales) -> str:
    """Why the log cannot pin the size quoted for effect ``name`` ('' when it can): a kinematic error fitted as its
    2/rev alone, over motor angles that cannot tell the 4/rev from it. The amplitude is then the 2/rev that
    reproduces the local shape, not the drive's 2/rev, and its interval knows nothing of the 4/rev (measured on the
    independent generator's default-design logs: 76-77 % high on one drive's three, two of them with confident
    intervals that missed the truth)."""
    return scales.kinematic_doubt if name == "kinematic_error" else ""


def _magnitude_gradient(name: str, coords: list[Any], x: np.ndarray) -> np.ndarray:
    """d(magnitude)/dx of effect ``name`` (for the delta method)."""
    g = np.zeros(len(coords))
    if name == "kinematic_error":   # A = hypot(c, s) of the 2/rev (``SIZE_COORDS``); the 4/rev does not enter it
        own = [i for i, c in enumerate(coords) if c.name in SIZE_COORDS[name]]
        v = np.array([coords[i].value(x[i]) for i in own])
        g[own] = v / (math.hypot(*v) or 1e-300) * np.array([coords[i].scale for i in own])
        return g
    g[0] = coords[0].scale * (1.0 if name != "asymmetric_friction" else math.copysign(1.0, x[0] or 1.0))
    return g


def _metrics_of(log: DriveLog, rl: np.ndarray, rm: np.ndarray, stop: int, sigma: float) -> dict[str, float]:
    """The model's fit to the log. Its residual is compared with the sensor noise (``*_over_noise_load``) as the
    lower of two estimates of that noise: the identifier's (``sigma``, the white part of the base fit's residual)
    and the white part of this model's own training residual (``residual_noise_std``). Both are the noise plus what
    the fit misses at frequencies the estimate counts as noise, so the lower is the nearer: measured on the
    independent generator's logs, the base fit's estimate was up to 6.7 % above the truth where it missed an effect
    (an actuator lag; 5.5 % a strong Maxwell-slip hysteresis), and a model read against it looked that much nearer
    the noise than it was."""
    y_l, y_m = log.load_pos_rad, log.motor_pos_rad
    held = slice(stop, None)
    own = residual_noise_std(rl[:stop])
    noise = min(sigma, own) if own > 0 else sigma
    return {"nrmse_load": rms(rl) / float(np.std(y_l)), "nrmse_motor": rms(rm) / float(np.std(y_m)),
            "relative_error_pct": float(100 * np.linalg.norm(rl) / np.linalg.norm(y_l - y_l.mean())),
            "heldback_nrmse_load": rms(rl[held]) / float(np.std(y_l[held])),
            "heldback_relative_error_pct": float(100 * np.linalg.norm(rl[held])
                                                 / np.linalg.norm(y_l[held] - y_l[held].mean())),
            "residual_rms_load_rad": rms(rl), "noise_load_rad": noise, "residual_over_noise_load": rms(rl) / noise,
            "train_over_noise_load": rms(rl[:stop]) / noise, "heldback_over_noise_load": rms(rl[held]) / noise}


def split_training(log: DriveLog, holdout: DriveLog | None) -> tuple[DriveLog, int]:
    """The log to simulate (training first) and the training length."""
    if holdout is None:
        return log, int(round((1 - HOLDBACK_FRACTION) * log.n))
    if abs(holdout.dt - log.dt) > 1e-9 * log.dt:
        raise LogError(f"{holdout.source}: the held-back log must have the training log's sample rate "
                       f"({log.meta.sample_rate_hz} Hz), got {holdout.meta.sample_rate_hz} Hz")
    if holdout.load_pos_rad is None:
        raise LogError(f"{holdout.source}: the held-back log needs load_pos_rad like the training log")
    # the held-back log continues the training log: its torque is applied after the training log's last sample
    joined = DriveLog(np.concatenate([log.time_s, log.time_s[-1] + log.dt + holdout.time_s - holdout.time_s[0]]),
                      np.concatenate([log.motor_torque_Nm, holdout.motor_torque_Nm]),
                      np.concatenate([log.motor_pos_rad, holdout.motor_pos_rad - holdout.motor_pos_rad[0]
                                      + log.motor_pos_rad[-1]]),
                      np.concatenate([log.load_pos_rad, holdout.load_pos_rad - holdout.load_pos_rad[0]
                                      + log.load_pos_rad[-1]]), log.meta, source=f"{log.source}+{holdout.source}")
    return joined, log.n


def truncate_log(log: DriveLog, stop: int) -> DriveLog:
    return replace(log, time_s=log.time_s[:stop], motor_torque_Nm=log.motor_torque_Nm[:stop],
                   motor_pos_rad=log.motor_pos_rad[:stop], load_pos_rad=log.load_pos_rad[:stop])
