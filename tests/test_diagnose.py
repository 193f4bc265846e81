"""The discrepancy loop on logs it did not make (issue 16).

Every log here comes from the independent generator (``tests/reference/generator``: its own hybrid integrator, no
code shared with the FMU or ``ident``), in the product's file format, read by ``ident.read_log``; the seeds
(5501-5523) appear nowhere in the product. The default run keeps short logs (3 s at 5 kHz): a clean log (nothing
named, every candidate rejected by the screen with its statistic), a hidden hardening of the library's shape (named,
confident, magnitude within 10 %, its parameters holding between the halves of the log), the same answer serially and
on two workers, a budget too small to fit it (not named confidently: the candidate is not ruled out), the rigid start
(flexibility passes the same acceptance rule), the command line (JSON on stdout, progress on stderr, the fitted FMU),
Ctrl-C (stops within 2 s with workers running), the loop's rules with stand-in plug-ins, and the statistics of the
screen and the acceptance rule against closed forms. The end-to-end diagnoses of effects in other shapes than the
library's (a kinematic error with its 4/rev, Stribeck and Dahl shapes, viscous friction on either side of the gear)
are in ``test_diagnose_shapes.py``, so that the two groups run in two test processes.
Slow (marked; run with ``-m slow`` and in ``bench/``): the randomized matrix of the issue (166 logs, ``test_matrix``
and ``bench/diagnose.py``), the constancy check on two 10 s logs, and an end-to-end check moved out of the default
run to keep it within 10 minutes on a 2-core machine (stop 63): a friction ripple outside the library fitted in place
of a named effect (37 s; the rule it feeds stays, with a stand-in).
"""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from ident.diagnosis import screening
from ident.diagnosis.engine import MIN_GAIN, diagnose, dm_pvalue, verdict
from ident.diagnosis.models import Fitted
from ident.fitting.logs import LogError
from tests.diagnosis_matrix import SHORT, Case, coverage, diagnosed, library_truth, load

CLEAN = Case("clean", 5501)
HARDENING = Case("single", 5502, "hardening", "strong", "default", "cubic")


# ------------------------------------------------------------------------------------------ statistics ----------

def test_score_test_is_the_regression_lm_statistic():
    """On a linear model the score statistic is n R^2 of the residual on the new regressor (after the old ones),
    the step is the least-squares coefficient, and the statistic is chi-square distributed under the null."""
    rng = np.random.default_rng(11)
    n = 4000
    X = np.column_stack([np.ones(n), rng.normal(size=n)])
    z = rng.normal(size=n)
    y = X @ [1.0, 2.0] + 0.05 * z + rng.normal(size=n)
    beta = np.linalg.lstsq(X, y, rcond=None)[0]
    r = X @ beta - y                                  # model - data, the loop's convention
    lm, robust, step, ok = screening.score_test(r, screening.partial_out(X), z[:, None], (False,))
    resid_z = z - X @ np.linalg.lstsq(X, z, rcond=None)[0]
    r2 = (r @ resid_z) ** 2 / ((r @ r) * (resid_z @ resid_z))
    assert lm == pytest.approx((n - 3) * r2, rel=1e-9)
    full = np.linalg.lstsq(np.column_stack([X, z]), y, rcond=None)[0]
    assert step[0] == pytest.approx(full[2], rel=1e-9) and ok
    nulls = []
    for seed in range(200):                           # the null: no z in the data
        g = np.random.default_rng(seed)
        y0 = X @ [1.0, 2.0] + g.normal(size=n)
        r0 = X @ np.linalg.lstsq(X, y0, rcond=None)[0] - y0
        nulls.append(screening.score_test(r0, screening.partial_out(X), g.normal(size=(n, 1)), (False,))[0])
    assert 0.9 < np.mean(nulls) < 1.1                 # chi-square(1) has mean 1
    assert np.mean(np.array(nulls) > stats.chi2.ppf(0.95, 1)) < 0.1


def test_screen_bounded_parameters_and_grids():
    """A parameter that can only grow from 0 gets half the tail when the step points the right way, the whole tail
    when every grid point's step points the wrong way (the sign is not trusted: a model that stands in for the
    effect points it so); a grid's best point pays for the search (p-value x grid size)."""
    assert screening.p_value(4.0, 1, True, True) == pytest.approx(0.5 * stats.chi2.sf(4.0, 1))
    assert screening.p_value(4.0, 1, False, True) == 1.0
    pts = [({"v": 1.0}, 10.0, 9.0, np.array([0.1]), True), ({"v": 2.0}, 30.0, 20.0, np.array([0.2]), True),
           ({"v": 3.0}, 50.0, 40.0, np.array([-0.3]), False)]
    t = screening.best_of_grid("x", pts, 1, True)
    assert t.grid_point == {"v": 2.0} and t.statistic == 30.0
    assert t.p_value == pytest.approx(3 * 0.5 * stats.chi2.sf(30.0, 1))
    # every step points the wrong way: the sign is not trusted, a significant score still sends it to its refit
    # (whole tail, x grid size); a small one rules it out
    wrong = [({"v": 1.0}, 60.0, 9.0, np.array([-0.1]), False), ({"v": 2.0}, 40.0, 9.0, np.array([-0.2]), False)]
    t = screening.best_of_grid("x", wrong, 1, True)
    assert t.passed and t.statistic == 60.0 and t.p_value == pytest.approx(2 * stats.chi2.sf(60.0, 1))
    assert "significant: refitted" in t.note
    t = screening.best_of_grid("x", [({}, 4.0, 3.0, np.array([-0.1]), False)], 1, True)
    assert not t.passed and t.p_value == pytest.approx(stats.chi2.sf(4.0, 1)) and "not supported" in t.note


def test_a_one_sided_column_is_divided_by_the_step_it_was_made_with():
    """``problem.one_sided_column`` rescales its step up to twice until the residual moves by its target; where the
    response is not linear (here quadratic in the step) no step may land in range, and the column must still be the
    last difference over the step that made it, never over a step it was not made with."""
    from ident.diagnosis.models.problem import one_sided_column

    r = np.zeros(100)
    made = []

    def moved(h: float) -> np.ndarray:
        made.append(h)
        return r + np.full(r.size, 1e6 * h * h)

    col = one_sided_column(moved, r, 1.0, target=1.0)
    assert len(made) == 3
    np.testing.assert_allclose(col, np.full(r.size, 1e6 * made[-1]))   # (1e6 h^2) / h at the last step
    made.clear()
    linear = one_sided_column(lambda h: (made.append(h), r + 2.0 * h)[1], r, 1e-3, target=1.0)
    assert len(made) == 2   # rescaled once, then in range
    np.testing.assert_allclose(linear, 2.0)


def test_hysteresis_coordinates_stay_in_the_fmus_range():
    """A tiny hysteresis torque over the widest saturation deflection asked the FMU for a stiffness below its range
    (matrix log 5216 stopped with a ParameterError); the range's end now stands for it, everywhere on the box."""
    from ident.diagnosis.models.coordinates import LogScales, coordinates, fmu_values
    from ident.model.effects import EFFECTS

    lo, hi = next((f.lo, f.hi) for f in EFFECTS["hysteresis"].fit_vars if f.param == "hysteresis_stiffness")
    fields = LogScales.__dataclass_fields__
    scales = LogScales(**{k: (1e-5 if k == "d95" else (0.1, 1.0) if "percentiles" in k else 1.0) for k in fields})
    coords = coordinates("hysteresis", scales)
    for x_h in (1e-12, 1e-6, 1.0, coords[0].hi):
        for x_s in (coords[1].lo, 0.0, coords[1].hi):
            v = fmu_values("hysteresis", coords, np.array([x_h, x_s]))
            assert lo <= v["hysteresis_stiffness"] <= hi, (x_h, x_s, v)


def test_the_kinematic_errors_4_per_rev_is_fitted_where_the_motor_turned_far_enough_to_tell_it_apart():
    """Over a short motor arc the 2/rev and 4/rev are the same local curve (a fit of both only adds variance); over
    turns of the motor they are apart. The separation is the 2/rev's information left beside the 4/rev, the offset
    and ratio partialled out: the coordinates hold the 4/rev from 0.5, and map to the FMU's four parameters."""
    from ident.diagnosis.models.coordinates import LogScales, coordinates, fmu_values, harmonic_separation

    t = np.linspace(0.0, 1.0, 20001)
    short, turns = harmonic_separation(0.1 * t), harmonic_separation(21.0 * np.sin(2.0 * t))
    assert short < 1e-4 and turns > 0.9, (short, turns)
    assert harmonic_separation(1.0 * t) < 0.5 < harmonic_separation(2 * np.pi * t)   # from about a 2/rev period
    base = dict(v_m=1.0, v_l=1.0, d95=1e-5, v_l_percentiles=(0.1,) * 5, K_s=1.0, f_l=1.0, f_m=1.0)
    two = coordinates("kinematic_error", LogScales(**base, harmonic_separation=short))
    four = coordinates("kinematic_error", LogScales(**base, harmonic_separation=turns))
    assert [c.name for c in two] == ["kinematic_c", "kinematic_s"]
    assert [c.name for c in four] == ["kinematic_c", "kinematic_s", "kinematic_c4", "kinematic_s4"]
    v = fmu_values("kinematic_error", four, np.array([3.0, 4.0, -0.6, 0.8]))
    assert v["kinematic_error"] == pytest.approx(5e-5) and v["kinematic_error_phase"] == pytest.approx(math.atan2(4, 3))
    assert v["kinematic_error_4"] == pytest.approx(1e-5)
    assert v["kinematic_error_4_phase"] == pytest.approx(math.atan2(0.8, -0.6))
    assert fmu_values("kinematic_error", two, np.array([3.0, 4.0]))["kinematic_error_4"] == 0.0


def test_acceptance_rule():
    """Held-back gain, Diebold-Mariano and BIC: a model that predicts the held-back data better by a margin passes,
    one that only fits noise does not."""
    rng = np.random.default_rng(5)
    noise = rng.normal(size=3000)
    structure = 0.3 * np.sin(np.arange(3000) / 30.0)

    def model(held: np.ndarray, k: int, train: float) -> Fitted:
        return Fitted((), train, float(np.sum(held**2)), held**2, 7000, k)

    base = model(noise + structure, 4, 7000 * 1.05)
    better = model(noise, 5, 7000 * 1.0)
    v = verdict(base, better)
    assert v.accepted and v.gain > MIN_GAIN and v.dm_p < 1e-6
    same = model(noise + structure + 1e-3 * rng.normal(size=3000), 5, 7000 * 1.0499)
    v = verdict(base, same)
    assert not v.accepted and v.reasons
    assert dm_pvalue(noise**2, noise**2) == 1.0
    # a candidate that predicts the held-back data worse is said to raise its cost (not to "fall 0.8x")
    v = verdict(better, model(noise / math.sqrt(0.8), 5, 7000 * 1.0))
    assert v.reasons[0] == f"held-back cost rises {1 / 0.8:.4g}x, where the rule asks a fall of more than {MIN_GAIN:g}x"


# ------------------------------------------------------------------------------------------ diagnoses -----------

def test_the_detection_limit_is_the_size_the_screen_passes_with_its_power_or_the_rules_gain():
    """``screening.detection_limit`` on a linear model: an effect at the limit along the direction the log sees least
    passes the screen in 95 % of noise draws (binomial scatter over 600 draws: 0.9 %); where the acceptance rule's
    1 % gain binds (many samples), a fit at the limit removes exactly that share, and the screen passes it more
    often still. Two unknowns (a phase): the limit lies along the least-seen direction, and any other direction of
    the same size is seen better."""
    rng = np.random.default_rng(5)

    def pass_rate(B: np.ndarray, Q: np.ndarray, x: np.ndarray, one_sided: bool) -> float:
        passed = 0
        for seed in range(600):
            r = -B @ x + np.random.default_rng(seed).normal(size=B.shape[0])   # model - data, the effect missing
            lm, _, step, ok = screening.score_test(r, Q, B, (one_sided,) * B.shape[1])
            passed += screening.p_value(lm, B.shape[1], ok, one_sided) < screening.SCREEN_LEVEL
        return passed / 600

    for n, gain, share in ((3000, 1.0, None), (40000, 1.01, 1 - 1 / 1.01)):
        X = np.column_stack([np.ones(n), rng.normal(size=n)])
        Q = screening.partial_out(X)
        B = (0.3 * X[:, 1] + rng.normal(size=n))[:, None]
        r0 = rng.normal(size=n)
        x = screening.detection_limit(r0, Q, B, 1, True, gain)
        assert x[0] > 0
        rate = pass_rate(B, Q, x, True)
        Z = B - Q @ (Q.T @ B)
        if share is None:
            assert 0.92 < rate < 0.98, rate
        else:
            assert float(x @ Z.T @ Z @ x) == pytest.approx(share * float(r0 @ r0), rel=1e-9) and rate > 0.97, rate
    n = 3000
    Q = screening.partial_out(np.ones((n, 1)))
    q = np.linspace(0.0, 0.4, n)                      # a short arc of a 2/rev harmonic: sin is seen, cos hardly
    B = np.column_stack([np.sin(2 * q), np.cos(2 * q)]) * 40.0
    x = screening.detection_limit(rng.normal(size=n), Q, B, 1, False, 1.0)
    Z = B - Q @ (Q.T @ B)
    seen = float(x @ Z.T @ Z @ x)
    for angle in np.linspace(0.1, 3.0, 7):
        other = np.linalg.norm(x) * np.array([np.cos(angle), np.sin(angle)])
        assert float(other @ Z.T @ Z @ other) >= seen * (1 - 1e-9)
    assert 0.92 < pass_rate(B, Q, x, False) < 0.98


def test_each_effect_not_named_says_why_in_numbers() -> None:
    """``engine._unseen``, from the last screen that ran: an effect that passed it but lost at the acceptance rule
    quotes its refit's reason and the size from which the loop names one (where the model computes it); one that
    did not pass quotes the size below which the log cannot tell it from none (and, on a grid, where it shows it
    best and least); a named effect and one without a limit (a model that computes none) get no sentence."""
    from ident.diagnosis.engine import _unseen
    from ident.diagnosis.result import DiagnosisStep, NamedEffect

    def step(screen: list[dict], candidates: list[dict]) -> DiagnosisStep:
        s = DiagnosisStep(None, None, None, math.nan, None, {})
        s.screen, s.candidates = pd.DataFrame(screen), pd.DataFrame(candidates)
        return s

    row = {"lm_statistic": 1.0, "p_value": 0.5, "passed": False, "unit": "1", "detectable_at": "",
           "detectable_worst": math.nan, "detectable_worst_at": "", "record": ""}
    old = step([{**row, "candidate": "hysteresis", "detectable": 9.0}], [])
    last = step([{**row, "candidate": "stribeck", "detectable": 2e-6, "detectable_at": "Stribeck velocity 0.01 rad/s",
                  "detectable_worst": 3e-5, "detectable_worst_at": "Stribeck velocity 0.001 rad/s",
                  "record": "slower slides"},
                 {**row, "candidate": "hardening", "lm_statistic": 90.0, "p_value": 1e-20, "passed": True,
                  "detectable": 60.0},
                 {**row, "candidate": "viscous_load", "detectable": 1e-5},
                 {**row, "candidate": "kinematic_error", "detectable": math.nan},
                 {**row, "candidate": "viscous_motor", "lm_statistic": 40.0, "p_value": 1e-9, "passed": True,
                  "detectable": math.nan}],
                [{"candidate": "hardening", "why": "held-back cost falls 1.002x, not more than 1.01x"},
                 {"candidate": "viscous_motor", "why": "its refit used up its budget"}])
    named = [NamedEffect("viscous_load", 1.0, (0.5, 1.5), "", "", None, None)]
    out = _unseen([step([], []), old, last, step([], [])], named)
    assert len(out) == 3
    assert out[0] == ("stribeck is not named: this log cannot tell one below 2e-06 from none (at step 2's model, "
                      "the size the screen passes with 95% power and a fit of it removes the 1% of the cost the rule "
                      "asks, where the log shows it best (Stribeck velocity 0.01 rad/s); where it shows it least "
                      "(Stribeck velocity 0.001 rad/s) only from 3e-05); to see a smaller one, record slower "
                      "slides")
    assert out[1] == ("hardening is not named: it passed the screen at step 2 (score 90, p = 1e-20); refitted: "
                      "held-back cost falls 1.002x, not more than 1.01x; the loop names one only from 60 here (at "
                      "step 2's model, the size the screen passes with 95% power and a fit of it removes the 1% of "
                      "the cost the rule asks)")
    assert out[2] == ("viscous_motor is not named: it passed the screen at step 2 (score 40, p = 1e-09); refitted: "
                      "its refit used up its budget")
    assert _unseen([step([], [])], []) == []


def test_clean_log_names_nothing():
    """A log without a hidden effect: every candidate is screened, reported with its statistic, none passes, nothing
    is refitted or named, and the conclusions say the model explains the log down to the noise."""
    d, _ = diagnosed(CLEAN, workers=0)
    assert d.effects == [] and len(d.steps) == 1
    screen = d.steps[0].screen
    assert len(screen) == 7 and not screen.passed.any() and screen.lm_statistic.notna().all()
    assert d.steps[0].candidates.empty
    assert any("no library effect" in s for s in d.summary)
    assert any("down to the sensor noise" in s for s in d.summary) and d.unexplained == []
    # every candidate not named: the size below which this log cannot tell it from none, from the same screen
    assert (screen.detectable > 0).all() and np.isfinite(screen.detectable).all()
    assert (screen.detectable_worst >= screen.detectable).all()
    # and what a log would have to show for a smaller one, with this log's own numbers
    ke = screen.set_index("candidate").loc["kinematic_error", "record"]
    assert "motor turned through" in ke and "pi rad" in ke
    for row in screen.itertuples():
        assert any(s.startswith(f"{row.candidate} is not named: this log cannot tell one below "
                                f"{row.detectable:.3g}{'' if row.unit == '1' else ' ' + row.unit} from none")
                   for s in d.summary), row.candidate


def test_hidden_hardening_is_named_with_its_magnitude():
    """A hardening of the library's (cubic) shape at the 'strong' class: the screen ranks it first, the refit names
    it confidently, its magnitude is within 10 % of the truth and its interval covers it; its parameters hold
    between the two halves of the training data (the constancy check, through the FMU)."""
    d, truth = diagnosed(HARDENING, workers=0)
    assert [e.name for e in d.effects] == ["hardening"], d.summary
    e = d.effects[0]
    ref = library_truth("hardening", truth)
    assert not e.tentative and abs(e.magnitude - ref) <= 0.10 * ref, (e.magnitude, ref)
    assert e.ci95[0] <= ref <= e.ci95[1] or abs(e.magnitude - ref) <= 1e-3 * ref
    assert d.steps[0].screen.iloc[0].candidate == "hardening"
    assert e.runner_up is not None and "runner-up" in e.evidence
    # the size probes ran through the FMU: held 10 % either side, the refitted model fits worse (the log pins it)
    assert [c["factor"] for c in e.size_check] == [0.9, 1.1] and all(c["delta_cost"] > 0 for c in e.size_check)
    c = d.constancy
    assert c["checked"] and c["df"] == 4 and c["p_value"] >= c["level"], c
    assert any(line.startswith("the final model's parameters hold between the two halves") for line in d.summary)


def test_the_same_answer_on_two_workers_as_serially():
    """No decision depends on time or the order the workers finish in: the hardening log diagnosed on two worker
    processes and in this process, under a budget its refits run out of (the budget is counted in simulations on
    whichever worker), gives the same names, sizes, intervals, candidate tables and notes."""
    parallel, _ = diagnosed(HARDENING, workers=2, budget=12.0, max_effects=1)
    serial, _ = diagnosed(HARDENING, workers=0, budget=12.0, max_effects=1)
    assert [x.name for x in parallel.effects] == [x.name for x in serial.effects] == ["hardening"]
    for a, b in zip(parallel.effects, serial.effects):
        assert (a.magnitude, a.ci95, a.tentative, a.why_tentative) == (b.magnitude, b.ci95, b.tentative,
                                                                       b.why_tentative)
    for a, b in zip(parallel.steps, serial.steps):
        pd.testing.assert_frame_equal(a.candidates, b.candidates)
    assert parallel.notes == serial.notes and parallel.summary == serial.summary
    assert parallel.fingerprint() == serial.fingerprint()   # and so is every other number and sentence


def test_the_answer_fingerprint_ignores_times_and_paths_and_sees_the_last_bit() -> None:
    """``Diagnosis.fingerprint``: two runs that differ only in their wall times and where they wrote share it (what a
    user compares between machines); a parameter one bit apart, a NaN turned number, or a sentence changed do not."""
    from ident.diagnosis.result import Diagnosis, DiagnosisStep, NamedEffect

    def made(k: float = 1.5, nrmse: float = math.nan, line: str = "x named", **kw) -> Diagnosis:
        step = DiagnosisStep("x", nrmse, 0.1, 1.0, 2.0, {"K_star": np.float64(k)},
                             candidates=pd.DataFrame([{"candidate": "x", "train_cost": 3.0}]))
        effect = NamedEffect("x", 1e-6, (0.9e-6, 1.1e-6), "rad", "gain", None, None)
        return Diagnosis("two-inertia", [step], [effect], [], pd.DataFrame(), summary=[line], **kw)

    one = made(elapsed_s=3.0, stage_s={"base fit": 1.0})
    assert one.fingerprint() == made(elapsed_s=9.0, stage_s={"base fit": 4.0}, files={"report": "a/diagnosis.md"},
                                     fmu="a/model.fmu").fingerprint()
    assert one.to_dict()["answer_sha256"] == one.fingerprint() and "elapsed_s" not in one.answer()
    for other in (made(k=float(np.nextafter(1.5, 2.0))), made(nrmse=0.1), made(line="x named tentatively")):
        assert other.fingerprint() != one.fingerprint()


def test_a_size_the_log_does_not_pin_is_tentative_and_its_interval_widens() -> None:
    """The size check (``sizes.widen``): a probe whose refit rises by d noise variances at 10 % off widens the
    interval to the secant's standard deviation, 10 % / sqrt(d), when that is wider than the local one; a probe that
    fits as well or better says the log does not pin the size (tentative, with its numbers) and the interval covers
    that size; an interval that widens across 0 is a doubt too, and so is a search that ran out of rounds. A
    well-pinned size keeps its interval; a plug-in without probes leaves it as it is."""
    from ident.diagnosis.result import NamedEffect
    from ident.diagnosis.sizes import SIZE_PROBE, Z95, widen

    final = Fitted(("stribeck",), 7000.0, 3000.0, np.ones(3000), 7000, 6, {})
    s2 = final.train_cost / (final.n_train - final.k)

    def checks(*rises: float) -> list:
        return [(f, Fitted(final.effects, final.train_cost + d * s2, 0.0, np.ones(1), 7000, 6))
                for f, d in zip((1 - SIZE_PROBE, 1 + SIZE_PROBE), rises)]

    def effect(lo: float = 0.99, hi: float = 1.01) -> NamedEffect:
        return NamedEffect("stribeck", 1.0, (lo, hi), "1", "", None, None)

    pinned, doubts = effect(), []
    widen(pinned, final, checks(1e6, 1e6), doubts)
    assert pinned.ci95 == (0.99, 1.01) and doubts == [] and len(pinned.size_check) == 2
    flat, doubts = effect(), []
    widen(flat, final, checks(4.0, 400.0), doubts)
    half = Z95 * SIZE_PROBE / 2.0   # the secant's sd at the flatter side: 10 % / sqrt(4)
    assert flat.ci95 == pytest.approx((1 - half, 1 + half)) and doubts == []
    loose, doubts = effect(), []
    widen(loose, final, checks(30.0, -5.0), doubts)
    assert len(doubts) == 1 and "does not pin its size to 10%" in doubts[0] and "-5 noise variances" in doubts[0]
    assert loose.ci95[1] >= 1 + SIZE_PROBE
    crossing, doubts = effect(0.05, 1.95), []
    widen(crossing, final, checks(0.01, 1e6), doubts)
    assert crossing.ci95[0] < 0 and any("includes 0" in d for d in doubts)
    kept, doubts = effect(), []
    widen(kept, final, [(0.9, None), (1.1, None)], doubts)
    assert kept.ci95 == (0.99, 1.01) and kept.size_check == [] and doubts == []
    restless, doubts = effect(), []
    widen(restless, final, [], doubts)
    assert len(doubts) == 1 and "used up its" in doubts[0]


def test_a_size_that_depends_on_the_effects_shape_is_tentative_and_its_interval_holds_both() -> None:
    """The shape check (``shapes.judge``): the named effect refitted in its other shape, judged by the training
    cost's change in noise variances against the loop's threshold. A shape the log rejects leaves the size as it is;
    one it prefers, or one it cannot tell apart whose size lies outside the interval, makes the name tentative and
    widens the interval to hold that size; one it cannot tell apart whose size lies inside says the size holds in
    either shape. A refit that used up its budget is no rejection (its cost is only an upper bound), nor is a worse
    fit from a final model that does not reproduce its log (neither refit need be its shape's best)."""
    from ident.diagnosis.engine import SEPARABLE
    from ident.diagnosis.models import ShapeFit
    from ident.diagnosis.result import NamedEffect
    from ident.diagnosis.shapes import judge

    final = Fitted(("stribeck",), 7000.0, 3000.0, np.ones(3000), 7000, 6, {})
    s2 = final.train_cost / (final.n_train - final.k)

    def case(d: float, size: float, unfinished: bool = False) -> tuple[NamedEffect, list[str], str]:
        e, doubts = NamedEffect("stribeck", 1.0, (0.95, 1.05), "1", "", None, None), []
        rival = ShapeFit(Fitted(final.effects, final.train_cost + d * s2, 0.0, np.ones(1), 7000, 6), size,
                         (0.98 * size, 1.01 * size), "an exponential decay", unfinished)
        return e, doubts, judge(e, final, rival, SEPARABLE, doubts, (1.0, 1.01))

    e, doubts, note = case(SEPARABLE + 1.0, 1.6)
    assert doubts == [] and e.ci95 == (0.95, 1.05) and note.endswith("the log rejects that shape")
    assert e.shape_check["magnitude"] == 1.6 and e.shape_check["delta_cost"] == pytest.approx(SEPARABLE + 1.0)
    assert e.shape_check["over_noise"] == [1.0, 1.01] and "it leaves 1x / 1.01x the sensor noise" in note
    e, doubts, note = case(SEPARABLE + 1.0, 1.6, unfinished=True)
    assert len(doubts) == 1 and "does not pin the shape" in doubts[0] and e.ci95 == (0.95, 1.01 * 1.6)
    e, doubts, _ = case(-SEPARABLE - 1.0, 1.02)
    assert len(doubts) == 1 and "a shape mismatch remains" in doubts[0] and e.ci95 == (0.95, 1.05)
    e, doubts, _ = case(-SEPARABLE - 1.0, 1.6)
    assert "a shape mismatch remains" in doubts[0] and e.ci95 == (0.95, 1.01 * 1.6)
    e, doubts, _ = case(3.0, 0.6)
    assert len(doubts) == 1 and "outside its interval" in doubts[0] and e.ci95 == (0.98 * 0.6, 1.05)
    e, doubts, note = case(-3.0, 1.01)
    assert doubts == [] and e.ci95 == (0.95, 1.05) and note.endswith("the size holds in either shape")
    # from a final model that does not reproduce its log, a worse fit is no rejection
    e, doubts = NamedEffect("stribeck", 1.0, (0.95, 1.05), "1", "", None, None), []
    rival = ShapeFit(Fitted(final.effects, final.train_cost + (SEPARABLE + 1.0) * s2, 0.0, np.ones(1), 7000, 6), 1.6,
                     (1.5, 1.7), "an exponential decay")
    note = judge(e, final, rival, SEPARABLE, doubts, None, reproduces=False)
    assert "no rejection" in doubts[0] and "outside its interval" in doubts[0] and e.ci95 == (0.95, 1.7), note


def test_the_shape_check_refits_each_named_effect_that_has_another_shape() -> None:
    """The loop's shape check (in ``_Search._final_checks``, one batch with the constancy check) refits, on the
    workers, each named effect that has another shape, on a final model at the noise and on one above it (a misfit
    there may be the shape's); a refit that failed is said in the notes and the check left undone. An effect its
    step refitted in its other shape from the final model itself (``_adopt_shape``) is not refitted again."""
    from ident.diagnosis import CONFIDENT_OVER_NOISE
    from ident.diagnosis.engine import _Say, _Search
    from ident.diagnosis.models import ShapeFit
    from ident.diagnosis.result import NamedEffect

    class Plugin(_OverInMetrics):
        @staticmethod
        def shape_rival_of(name: str) -> str:
            return "another decay" if name == "stribeck" else ""

    for over, halves in (((1.0, 1.0), True), ((CONFIDENT_OVER_NOISE * 1.5, 1.0), False)):
        pool = _Pool([None, None, "RuntimeError: no"] if halves else ["RuntimeError: no"])
        search = _Search(Plugin(), pool, 5.0, 3, _Say(False))
        search.named = [NamedEffect(n, 1.0, (0.9, 1.1), "", "", None, None) for n in ("hysteresis", "stribeck")]
        search._final_checks(Fitted(("hysteresis", "stribeck"), 100.0, 100.0, np.ones(10), 100, 8, {"over": over}))
        assert [t[1][2] for t in pool.tasks] == ([0, 1] if halves else []) + ["stribeck"], (over, pool.tasks)
        assert any("could not be refitted in its other shape (RuntimeError: no)" in n for n in search.notes)
        assert search.shapes == {} and bool(search.constancy) == halves
    # where the step that named it refitted it in its other shape from this very model, that refit is the check's
    final = Fitted(("hysteresis", "stribeck"), 100.0, 100.0, np.ones(10), 100, 8,
                   {"over": (CONFIDENT_OVER_NOISE * 1.5, 1.0)})
    rival = ShapeFit(replace(final, train_cost=90.0), 1.4, (1.3, 1.5), "another decay")
    for tried_at, again in ((final, False), (replace(final), True)):
        pool = _Pool([rival])
        search = _Search(Plugin(), pool, 5.0, 3, _Say(False))
        search.named = [NamedEffect(n, 1.0, (0.9, 1.1), "", "", None, None) for n in ("hysteresis", "stribeck")]
        search.shape_tried = {"stribeck": (tried_at, rival)}
        search._final_checks(final)
        assert [t[1][2] for t in pool.tasks] == (["stribeck"] if again else []) and search.shapes == {"stribeck": rival}


def test_a_candidate_that_does_not_carry_over_is_refitted_in_its_other_shape() -> None:
    """A step's candidate that has another shape and fits the training part more than ``MIN_GAIN`` better while
    predicting the held-back part more than ``MIN_GAIN`` worse (``_Search._other_shapes``) is screened and refitted in
    that shape from the current model (``plugin.with_other_shape``), on the workers; the refit takes its place where
    it predicts the held-back part better, and its ``start`` says why. A candidate that carries over, one without
    another shape, one whose screen in that shape fails, and a worse or failed refit stay as they were."""
    from ident.diagnosis.engine import _Say, _Search
    from ident.diagnosis.models import CandidateFit
    from ident.diagnosis.screening import ScoreTest

    current = Fitted((), 1000.0, 300.0, np.ones(300), 7000, 5, {})

    class Plugin:
        @staticmethod
        def shape_rival_of(name: str) -> str:
            return "" if name == "viscous_load" else f"another {name}"

        @staticmethod
        def with_other_shape(m: Fitted, name: str) -> Fitted | None:
            return None if name == "viscous_load" else replace(m, metrics={"shape": name})

        @staticmethod
        def shape_of(m: Fitted, name: str) -> str:
            return f"another {name}"

        @staticmethod
        def screen(m: Fitted, names: tuple[str, ...]) -> list[ScoreTest]:
            assert m.metrics == {"shape": names[0]}
            stat = 0.0 if names[0] == "kinematic_error" else 50.0   # kinematic error fails the screen
            return [ScoreTest(names[0], stat, stat, 1, 1.0 if stat == 0.0 else 1e-12)]

        @staticmethod
        def refit_cost(name: str) -> float:
            return 1.0

    def fit(name: str, train: float, held: float) -> CandidateFit:
        return CandidateFit(name, Fitted((name,), train, held, np.ones(300), 7000, 6, {}), start="the screen's step")

    overfits = [fit(n, 10.0, 600.0) for n in ("stribeck", "hysteresis", "viscous_load", "kinematic_error")]
    fits = overfits + [fit("hardening", 500.0, 200.0)]   # hardening carries over
    better = CandidateFit("stribeck", Fitted(("stribeck",), 9.0, 1.0, np.ones(300), 7000, 6, {}), exhausted=True,
                          start="the screen's step")
    for results, replaced in (([better, CandidateFit("hysteresis", error="RuntimeError: no")], True),
                              ([replace(better, model=replace(better.model, held_cost=700.0)),
                                fit("hysteresis", 9.0, 650.0)], False)):
        pool = _Pool(results)
        search = _Search(Plugin(), pool, 5.0, 3, _Say(False))
        out = search._other_shapes(current, fits, 0)
        assert [(t[1].metrics, t[2].candidate) for t in pool.tasks] == [
            ({"shape": "stribeck"}, "stribeck"), ({"shape": "hysteresis"}, "hysteresis")]
        assert out[1:] == fits[1:] and (out[0] is fits[0]) == (not replaced)
        if replaced:
            assert out[0].model is better.model and out[0].exhausted and out[0].name == "stribeck"
            assert out[0].start == ("the screen's step, with another stribeck: its refit in the first shape fitted "
                                    "the training part 100x better and predicted the held-back part 0.5x as well")
            assert any("hysteresis could not be refitted in its other shape (RuntimeError: no)" in n
                       for n in search.notes)
    pool = _Pool()
    assert _Search(Plugin(), pool, 5.0, 3, _Say(False))._other_shapes(current, fits[4:], 0) == fits[4:]
    assert pool.tasks == []


def test_an_effect_is_adopted_in_the_shape_the_log_prefers_where_it_is_named() -> None:
    """Where a step accepts an effect that has another shape (``_Search._adopt_shape``), it is refitted in it at
    once, and the loop goes on from that refit (converged, as an accepted model is) where it fits the training data
    better by more than the step resolves: the larger of the loop's threshold and the 1 % of the training cost
    (``MIN_GAIN``) a free refit may leave unresolved (on a long log the latter, on a short one the
    former). A refit within that, a worse one, or one that failed leaves the library's shape, and the notes say
    which. An effect without another shape is not refitted."""
    from ident.diagnosis import MIN_GAIN
    from ident.diagnosis.engine import SEPARABLE, _Say, _Search
    from ident.diagnosis.models import ShapeFit

    class Plugin:
        converged: list = []

        @staticmethod
        def shape_rival_of(name: str) -> str:
            return "an exponential decay" if name == "stribeck" else ""

        def converge(self, m: Fitted, budget: float | None, unfinished: bool = False) -> tuple[Fitted, str]:
            self.converged.append((m, unfinished))
            return m, "refitted on" if unfinished else ""

    for n in (7000, 1000):   # samples: the bar is 1 % of the cost (69.9 noise variances), then SEPARABLE
        model = Fitted(("stribeck",), float(n), 3000.0, np.ones(3000), n, 6, {})
        s2 = model.train_cost / (model.n_train - model.k)
        bar = max(SEPARABLE, (MIN_GAIN - 1.0) * (n - 6))
        assert (bar > SEPARABLE) == (n == 7000)
        for d, unfinished, adopted in ((-bar - 1.0, False, True), (-bar - 1.0, True, True), (-bar + 1.0, False, False),
                                       (SEPARABLE + 1.0, False, False)):
            rival = Fitted(model.effects, model.train_cost + d * s2, 2900.0, np.ones(3000), n, 6, {})
            plugin = Plugin()
            plugin.converged = []
            pool = _Pool([ShapeFit(rival, 1.4, (1.3, 1.5), "an exponential decay", unfinished)])
            search = _Search(plugin, pool, 5.0, 3, _Say(False))
            out = search._adopt_shape(model, "stribeck", 0)
            assert (out is rival) == adopted and (out is model) == (not adopted), (n, d)
            assert [t[2] for t in pool.tasks] == ["stribeck"]
            assert plugin.converged == ([(rival, unfinished)] if adopted else [])
            assert any(("adopted, the loop goes on from it" if adopted else "its shape is kept") in x
                       and f"training cost {d:+.4g} noise variances" in x and f"only beyond {bar:.4g}" in x
                       for x in search.notes), search.notes
        # better on the training part, significantly worse on the held-back part: kept
        rival = Fitted(model.effects, model.train_cost - 2 * bar * s2, 4000.0, np.full(3000, 4 / 3), n, 6, {})
        search = _Search(Plugin(), _Pool([ShapeFit(rival, 1.4, (1.3, 1.5), "an exponential decay")]), 5.0, 3,
                         _Say(False))
        assert search._adopt_shape(model, "stribeck", 0) is model
        assert "but it predicts the held-back part 0.75x as well" in search.notes[0], search.notes
        assert search.notes[0].endswith("its shape is kept")
    search = _Search(Plugin(), _Pool(["RuntimeError: no"]), 5.0, 3, _Say(False))
    assert search._adopt_shape(model, "stribeck", 0) is model
    assert search.notes == ["step 1: stribeck could not be refitted in its other shape (RuntimeError: no)"]
    pool = _Pool()
    search = _Search(Plugin(), pool, 5.0, 3, _Say(False))
    assert search._adopt_shape(model, "hysteresis", 0) is model and pool.tasks == [] and search.notes == []


def test_the_final_model_is_refitted_in_the_shape_the_final_check_prefers() -> None:
    """Where the final check (after the size search) finds a named effect's other shape better by the loop's
    threshold or more (``_Search._preferred``), that refit, converged, becomes the final model, the one whose sizes
    are searched and checked again; the doubts, notes and size checks of the first search are taken back (they were
    of the model given up), and the final step says why. Where several are preferred, the one preferred most; where
    none is, the final model stands and nothing is taken back."""
    from ident.diagnosis.engine import SEPARABLE, _Say, _Search
    from ident.diagnosis.models import Magnitude, ShapeFit

    class Plugin(_Recorded):
        @staticmethod
        def magnitude(m: Fitted, name: str) -> Magnitude:
            return Magnitude(0.8, (0.7, 0.9), "1")

        @staticmethod
        def converge(m: Fitted, budget: float | None, unfinished: bool = False) -> tuple[Fitted, str]:
            return m, ""

    final = Fitted(("stribeck", "hysteresis"), 7000.0, 3000.0, np.ones(3000), 7000, 8, {})
    s2 = final.train_cost / (final.n_train - final.k)

    def rival(d: float, size: float, held: float = 1.0) -> ShapeFit:
        return ShapeFit(Fitted(final.effects, final.train_cost + d * s2, 3000.0 * held, np.full(3000, held), 7000, 8,
                               {}), size, (0.95 * size, 1.05 * size), "another shape")

    # the third: stribeck's other shape is preferred most, but predicts the held-back part significantly worse
    for ds, chosen, worse in (((-SEPARABLE - 5.0, -SEPARABLE - 1.0), "stribeck", 1.0),
                              ((-SEPARABLE + 1.0, 3.0), None, 1.0),
                              ((-SEPARABLE - 5.0, -SEPARABLE - 1.0), "hysteresis", 1.5),
                              ((-SEPARABLE - 5.0, 3.0), None, 1.5)):
        search = _Search(Plugin(), _Pool(), 5.0, 3, _Say(False))
        search._record(final, "hysteresis", 2.0, {})
        search.doubts = {"stribeck": ["from its step"]}
        mark = ({k: list(v) for k, v in search.doubts.items()}, len(search.notes))
        search.doubts["stribeck"].append("from the size search")
        search.notes.append("size search: stribeck moved")
        search.constancy, search.size_checks = {"checked": False, "why": "x"}, {"stribeck": []}
        search.shapes = {"stribeck": rival(ds[0], 1.0, worse), "hysteresis": rival(ds[1], 2.0)}
        out = search._preferred(final, mark)
        if chosen is None:
            assert out is final and search.notes[0] == "size search: stribeck moved" and len(search.shapes) == 2
            assert len(search.notes) == 1 + (worse > 1.0)
            assert worse == 1.0 or ("fits the training data better, but it predicts the held-back part 0.6667x as "
                                    "well" in search.notes[1] and "keeps its shape" in search.notes[1])
            continue
        d, size = (ds[0], "1") if chosen == "stribeck" else (ds[1], "2")
        assert out is search.models[-1]
        assert out.train_cost == pytest.approx(final.train_cost + d * s2)
        assert search.doubts == {"stribeck": ["from its step"]} and search.shapes == {} and search.constancy == {}
        assert search.size_checks == {}
        assert len(search.notes) == 1 and f"the final check refitted {chosen} with another shape" in search.notes[0]
        assert f"better by {-d:.4g} noise variances" in search.notes[0]
        assert f"size {size} against 0.8" in search.notes[0]
        assert search.steps[-1].extra.get("refreshed") and search.steps[-1].added == "hysteresis"


def test_a_shape_rival_goes_back_to_the_librarys_shape_from_an_adopted_one(monkeypatch) -> None:
    """``TwoInertiaPlugin.shape_rival`` from the library's shape holds the FMU's shape parameter at the rival's
    value and shifts the Stribeck velocity's coordinate to the rival's start; from a model that adopted the rival
    it lets the parameter go back to the FMU's default (the library's shape) and shifts the coordinate back, and
    ``shape_of`` says which shape a model has."""
    from ident.diagnosis.models import two_inertia as ti

    plugin = object.__new__(ti.TwoInertiaPlugin)
    seen = []

    def refitted(model, effects, head, budget, **kw):
        seen.append((dict(model.state.fixed), head.copy()))
        return head, False

    monkeypatch.setattr(plugin, "_refitted", refitted)
    monkeypatch.setattr(plugin, "evaluate", lambda effects, theta, base, scales, sens=None, fixed=None:
                        Fitted(effects, 1.0, 1.0, np.ones(1), 1, 1, {}, ti.TwoInertiaState(theta, None, None, None,
                                                                                         fixed=dict(fixed))))
    monkeypatch.setattr(plugin, "magnitude", lambda m, name: ti.Magnitude(2.0, (1.0, 3.0), "1"))
    layout = [SimpleNamespace(effect="stribeck", name=n) for n in ("ratio", "ln_stribeck_velocity")]
    monkeypatch.setattr(ti, "_layout", lambda model: layout)
    shape = ti.SHAPES["stribeck"]
    theta = np.array([0.0, 0.0, 0.0, 0.0, 0.5, -9.0])
    library = Fitted(("stribeck",), 1.0, 1.0, np.ones(1), 1, 1, {}, ti.TwoInertiaState(theta, None, None, None))
    assert plugin.shape_of(library, "stribeck") == ""
    there = plugin.shape_rival(library, "stribeck", 5.0)
    assert seen[-1][0] == {shape.param: shape.value} and there.shape == shape.rival
    assert seen[-1][1][5] == pytest.approx(-9.0 + shape.shifts["ln_stribeck_velocity"]) and seen[-1][1][4] == 0.5
    assert plugin.shape_of(there.model, "stribeck") == shape.words
    back = plugin.shape_rival(there.model, "stribeck", 5.0)
    assert seen[-1][0] == {} and back.shape == shape.library and seen[-1][1][5] == pytest.approx(-9.0)
    assert plugin.shape_of(back.model, "stribeck") == ""
    # a model without the effect, set to add it in the other shape (a candidate's refit there); none where it has it
    bare = Fitted((), 1.0, 1.0, np.ones(1), 1, 1, {}, ti.TwoInertiaState(theta[:4], None, None, None))
    other = plugin.with_other_shape(bare, "stribeck")
    assert other.state.fixed == {shape.param: shape.value} and bare.state.fixed == {} and other.effects == ()
    assert plugin.with_other_shape(library, "stribeck") is None
    assert plugin.with_other_shape(bare, "viscous_load") is None   # no other shape
    assert plugin.with_other_shape(other, "stribeck").state.fixed == {}   # back to the library's
    # the hardening's other shape (exponent 1) holds its deflection at the log's d95, where both shapes stiffen
    # alike, so that its size means the same; both go back together
    scales = SimpleNamespace(d95=2e-4)
    hard = Fitted((), 1.0, 1.0, np.ones(1), 1, 1, {}, ti.TwoInertiaState(theta[:4], None, None, scales))
    other = plugin.with_other_shape(hard, "hardening")
    assert other.state.fixed == {"hardening_exponent": 1.0, "hardening_deflection": 2e-4}
    assert plugin.shape_of(other, "hardening") == ti.SHAPES["hardening"].words
    assert plugin.with_other_shape(other, "hardening").state.fixed == {}


def test_the_size_search_follows_the_profile_and_checks_where_it_ends() -> None:
    """The size search (``sizes.search_size``) on a profile whose minimum lies at 3x the free refit's size (the
    measured case: a viscous coefficient refitted to 1/13 of the truth, the profile falling all the way to it): it
    moves with steps that square, stops where neither side fits better, and returns the check around that point;
    on a profile whose minimum is where it starts it spends one round (the check) and does not move."""
    from ident.diagnosis.sizes import SIZE_PROBE, search_size

    def fitted(size: float, best: float) -> Fitted:
        m = Fitted(("viscous_motor",), 1000.0 + 1e4 * math.log(size / best) ** 2, 0.0, np.ones(1), 7000, 5)
        m.state = size
        return m

    for best in (3.0, 1.0):
        rounds = []

        def run(fn, tasks, best=best):
            rounds.append([t[3] for t in tasks])
            return [fitted(t[1].state * t[3], best) for t in tasks]

        found = search_size(run, None, fitted(1.0, best), "viscous_motor", None)
        end, check = found.model, found.checks
        assert [f for f, _ in check] == [1 - SIZE_PROBE, 1 + SIZE_PROBE]
        assert all(p.train_cost > end.train_cost for _, p in check)
        assert abs(math.log(end.state / best)) < math.log(1 + SIZE_PROBE)
        assert (found.doubt != "") == (best != 1.0) and (end.state == 1.0) == (best == 1.0)
        assert rounds[0] == [1 - SIZE_PROBE, 1 + SIZE_PROBE] and (len(rounds) <= 2) == (best == 1.0)


def test_a_check_that_rises_unequally_moves_the_size_to_its_profiles_vertex() -> None:
    """``sizes.vertex``: a check whose probes both fit worse, 4x more on one side, brackets a profile minimum 3 % from
    the point checked (the measured case: named viscous coefficients of torque-step logs 4-6 standard deviations from
    the truth, checks rising 1010 / 548 and 7090 / 4980 noise variances). One probe at the parabola's vertex finds
    it, and the check is repeated there. A fall below what the log tells apart (``SEPARABLE``) is a refinement and no
    doubt on the name; a larger one is a stall and is; a check that rises alike spends none."""
    from ident.diagnosis.engine import SEPARABLE
    from ident.diagnosis.sizes import SIZE_PROBE, search_size, vertex

    def fitted(size: float, a: float) -> Fitted:
        m = Fitted(("viscous_motor",), 35000.0 + a * (size - 1.03) ** 2, 0.0, np.ones(1), 35005, 5)
        m.state = size
        return m

    for a in (1e4, 1e5):   # falls of 9 and 90 noise variances
        rounds = []

        def run(fn, tasks, a=a):
            rounds.append([round(t[3], 6) for t in tasks])
            return [fitted(t[1].state * t[3], a) for t in tasks]

        found = search_size(run, None, fitted(1.0, a), "viscous_motor", None, separable=SEPARABLE)
        assert found.model.state == pytest.approx(1.03)
        assert rounds[:2] == [[1 - SIZE_PROBE, 1 + SIZE_PROBE], [1.03]]
        assert [f for f, _ in found.checks] == [1 - SIZE_PROBE, 1 + SIZE_PROBE]
        assert (found.doubt == "") == (a * 0.03 ** 2 < SEPARABLE) and (found.refined != "") == (found.doubt == "")
    level = fitted(1.03, 1e5)
    assert vertex(level, [fitted(1.03 * 0.9, 1e5), fitted(1.03 * 1.1, 1e5)]) is None


def test_the_confidence_level_is_the_noise_scatter_of_each_part_under_a_ceiling() -> None:
    """A model reproduces its log when its residual over the noise is within chance (``CONFIDENT_ALPHA``) of 1 on
    each part (``TwoInertiaPlugin.confident_levels``): the level falls with the part's length and the noise estimate's
    (the training part), and never rises above ``CONFIDENT_OVER_NOISE``. On a 3 s log at 5 kHz the training part
    (10,500 samples) is at 1.045x, the held-back part (4,500) would be above 1.05x and is held at it; a 10 s log's
    parts are at 1.024x and 1.028x, where a new drive's model with a wrong name ended at 1.041x; the summary then says
    the model does not reproduce the log and its sizes are not to be trusted (its viscous load was a tenth of the
    truth: the refits had stopped in another basin)."""
    from ident.diagnosis import CONFIDENT_ALPHA, CONFIDENT_OVER_NOISE, above_level
    from ident.diagnosis.engine import _summary
    from ident.diagnosis.models.two_inertia import TwoInertiaPlugin
    from ident.diagnosis.result import NamedEffect
    from ident.fitting.noise import at_noise_level

    log, _ = load(Case("single", 5102, "viscous_load", "medium", "default"), **SHORT)
    plugin = TwoInertiaPlugin(log)
    train, held = plugin.confident_levels()
    assert train == pytest.approx(at_noise_level(plugin.stop, plugin.stop, CONFIDENT_ALPHA))
    assert 1.03 < train < CONFIDENT_OVER_NOISE == held < at_noise_level(log.n - plugin.stop, plugin.stop,
                                                                         CONFIDENT_ALPHA)
    assert above_level((train * 1.001, 1.0), (train, held)) and above_level((1.0, held * 1.001), (train, held))
    assert not above_level((train * 0.999, held * 0.999), (train, held)) and not above_level(None, (train, held))
    ten_s = (at_noise_level(35000, 35000, CONFIDENT_ALPHA), at_noise_level(15000, 35000, CONFIDENT_ALPHA))
    assert above_level((1.041, 1.0), ten_s) and not above_level((1.041, 1.0), (CONFIDENT_OVER_NOISE,) * 2)
    named = [NamedEffect("viscous_load", 9.6e-4, (8.7e-4, 1.05e-3), "N.m.s/rad", "", None, None)]
    said = " ".join(_summary(named, [], (1.042, 1.043), ten_s, [], {}))
    assert "does not reproduce this log" in said and "1.042x / 1.043x" in said and "not to be trusted" in said


def test_a_model_is_read_against_the_lower_of_the_two_noise_estimates() -> None:
    """A base fit that misses an effect reads the sensor noise high (measured: up to 6.7 % on the independent
    generator's logs), and a model read against that estimate looks nearer the noise than it is. A model's residual
    is read against the lower of the identifier's estimate and the white part of its own training residual: white
    residuals of a model read against a 7 % high estimate are at 1.00x, not 0.93x; a smooth misfit on top stays
    above 1 either way, and a right estimate is kept."""
    from ident.diagnosis.models.two_inertia import _metrics_of

    log, _ = load(Case("single", 5102, "viscous_load", "medium", "default"), **SHORT)
    rng = np.random.default_rng(20261126)
    stop, sigma = int(0.7 * log.n), 2e-8
    white = rng.normal(0.0, sigma, log.n)
    smooth = white + 0.4 * sigma * np.sin(2 * np.pi * 3.0 * log.time_s)
    high = _metrics_of(log, white, np.zeros(log.n), stop, 1.07 * sigma)
    assert high["train_over_noise_load"] == pytest.approx(1.0, abs=0.02) and high["noise_load_rad"] < 1.03 * sigma
    misfit = _metrics_of(log, smooth, np.zeros(log.n), stop, 1.07 * sigma)
    assert misfit["train_over_noise_load"] > 1.03
    right = _metrics_of(log, white, np.zeros(log.n), stop, sigma)
    assert right["noise_load_rad"] <= sigma and right["train_over_noise_load"] == pytest.approx(1.0, abs=0.02)


def test_a_polish_that_finds_a_stall_is_a_doubt_on_every_name() -> None:
    """``_Search._polished``: the final model's polish (``plugin.polish``) is said in the notes; where it lowers the
    training cost by the ``SEPARABLE`` noise variances the log tells apart or more, every name gets a doubt (the
    final model had stalled, as a size search that moves says: the comparisons that chose the names rest on stalled
    refits); a smaller fall is a refinement, no doubt. Measured: the polish lowered the training cost 914 noise
    variances on a torque-step log of a kinematic error (drive 5103), 0.0003-0.25 on the quick sample's logs."""
    from ident.diagnosis.engine import SEPARABLE, _Say, _Search
    from ident.diagnosis.result import NamedEffect

    names = ("stribeck", "hysteresis")
    for fall, doubted in ((SEPARABLE * 0.9, False), (SEPARABLE * 1.1, True)):
        class Plugin(_OverInMetrics):
            @staticmethod
            def polish(model: Fitted, budget: float | None) -> tuple[Fitted, str]:
                return replace(model, train_cost=model.train_cost - fall), "refitted (stand-in)"

        search = _Search(Plugin(), _Pool(), None, 3, _Say(False))
        search.named = [NamedEffect(n, math.nan, (math.nan, math.nan), "", "", None, None) for n in names]
        model = Fitted(names, 35000.0, 15000.0, np.ones(100), 35000, 8, {"over": (1.0, 1.0)})
        polished = search._polished(model)
        assert polished.train_cost == model.train_cost - fall
        assert any(n.startswith("polish: the final model refitted") for n in search.notes)
        for n in names:
            assert any("the final model had stalled" in d for d in search.doubts.get(n, [])) == doubted, (fall, n)


def test_the_final_size_search_runs_only_where_a_name_can_be_confident() -> None:
    """The loop's last size search (``_Search._settle``) probes every named size on a final model at the noise, and
    none on one above ``CONFIDENT_OVER_NOISE`` times it on the training data (the data the search fits): its names
    are tentative for that reason whatever the search finds, and the report says the search was not run. On an
    actuator-lag log (outside the library) it took 210 s of 462 s for three tentative names. A model at the noise on
    the training data but above it on the held-back data is searched: a stalled refit mispredicts the held-back data
    (measured: hysteresis from 1.116x to 1.002x the noise held back). When no search moves the model each size is
    searched once (the earlier ones were searched again, though nothing had moved)."""
    from ident.diagnosis import CONFIDENT_OVER_NOISE
    from ident.diagnosis.engine import _Say, _Search
    from ident.diagnosis.models import ShapeFit
    from ident.diagnosis.result import NamedEffect

    class Plugin(_OverInMetrics):
        @staticmethod
        def size_inflation(model: Fitted, name: str) -> float:
            return 1.0

    losses = np.ones(100)
    for over, probed in (((1.0, 0.99), True), ((1.0, CONFIDENT_OVER_NOISE * 1.01), True),
                         ((CONFIDENT_OVER_NOISE * 1.01, 1.0), False)):
        pool = _Pool()   # probes that failed: the search ends at its first check
        search = _Search(Plugin(), pool, None, 3, _Say(False))
        search.named = [NamedEffect(n, math.nan, (math.nan, math.nan), "", "", None, None) for n in ("stribeck", "hysteresis")]
        model = Fitted(("stribeck", "hysteresis"), 100.0, 100.0, losses, 100, 8, {"over": over})
        assert search._settle(model) is model
        probes = len(pool.tasks)
        assert (probes == 4) == probed and (probes == 0) == (not probed), (over, probes)
        assert any("size search: not run" in n for n in search.notes) == (not probed)
        assert set(search.size_checks) == ({"stribeck", "hysteresis"} if probed else set())


class _OverInMetrics:
    """A stand-in plug-in's noise levels for the loop's tests: a model's residual over the noise is its metrics'
    ``over``, read against ``CONFIDENT_OVER_NOISE`` on both parts."""

    @staticmethod
    def over_noise(model: Fitted) -> tuple[float, float]:
        return model.metrics["over"]

    @staticmethod
    def confident_levels() -> tuple[float, float]:
        from ident.diagnosis import CONFIDENT_OVER_NOISE

        return CONFIDENT_OVER_NOISE, CONFIDENT_OVER_NOISE

    @staticmethod
    def polish(model: Fitted, budget: float | None) -> tuple[Fitted, str]:
        return model, ""   # the final model as the loop left it (``ModelPlugin.polish``'s default)


class _Pool:
    """A stand-in worker pool for the loop's tests: the plug-in as it is, and ``results`` for every batch (None:
    a None per task, a task that failed); every task it was given is kept in ``tasks``."""

    elsewhere = None   # no second core for the base fit

    def __init__(self, results: list | None = None) -> None:
        self.results, self.tasks = results, []

    @staticmethod
    def share(plugin: object) -> object:
        return plugin

    def map(self, fn: object, tasks: list[tuple], desc: str = "", cost: object = None, progress: bool = False) -> list:
        self.tasks += tasks
        return [None] * len(tasks) if self.results is None else list(self.results)


class _Recorded:
    """What ``_Search._record`` asks of a plug-in, for the loop's tests with stand-in plug-ins: the model as it is,
    and a bare step (and every refit alike in cost, carrying nothing to the next, no effect with another shape)."""

    @staticmethod
    def resimulated(m: Fitted) -> Fitted:
        return m

    @staticmethod
    def polish(model: Fitted, budget: float | None) -> tuple[Fitted, str]:
        return model, ""   # the final model as the loop left it (``ModelPlugin.polish``'s default)

    @staticmethod
    def step(m: Fitted, added: str | None, score: float | None, extra: dict) -> object:
        from ident.diagnosis.result import DiagnosisStep

        return DiagnosisStep(added, None, None, math.nan, score, {}, extra=dict(extra))

    @staticmethod
    def refit_cost(name: str) -> float:
        return 1.0

    @staticmethod
    def effect_start(m: Fitted, name: str) -> dict[str, float]:
        return {}

    @staticmethod
    def twin_of(m: Fitted, name: str) -> None:
        return None

    @staticmethod
    def with_other_shape(m: Fitted, name: str) -> None:
        return None


def test_between_twins_the_held_back_data_cannot_tell_apart_the_whole_log_decides() -> None:
    """``_Search._select`` (``_twin_or``): the candidate with the lowest held-back cost passes the rule; its twin
    (viscous friction on the other side of the gear) predicts the held-back data 2 noise variances worse, which the
    Diebold-Mariano test cannot tell from chance, and fits the training data 30 better: the twin explains the whole
    log better, passes the rule too, and is accepted, the table saying why. The winner stays when the twin explains
    the whole log worse, when the held-back data do tell them apart (the twin 200 worse there, though 300 better on
    the training data), when the twin fails the rule, and when the winner has no twin."""
    from ident.diagnosis.engine import _Say, _Search
    from ident.diagnosis.models import CandidateFit, Magnitude

    rng = np.random.default_rng(5611)
    base = rng.chisquare(1, 4000)

    def fitted(name: str, train: float, held: np.ndarray) -> Fitted:
        return Fitted((name,), train, float(held.sum()), held, 4000, 5)

    current = Fitted((), 9000.0, float(2 * base.sum()), 2 * base, 4000, 4)

    class Plugin(_Recorded):
        twins, zero = True, ()

        def twin_of(self, m: Fitted, name: str) -> tuple[str, str, str] | None:
            other = {"viscous_load": "viscous_motor", "viscous_motor": "viscous_load"}
            return (other[name], "b = 1", "record a ringing") if self.twins and name in other else None

        def magnitude(self, m: Fitted, name: str) -> Magnitude:
            return Magnitude(1.0, (-1.0, 3.0) if name in self.zero else (0.5, 1.5), "N.m.s/rad")

        @staticmethod
        def without(m: Fitted, name: str, budget: float | None) -> Fitted:
            return current

    def select(twin_train: float, twin_shift: float, plugin: Plugin | None = None) -> tuple[str, list[dict]]:
        winner = fitted("viscous_load", 4030.0, base + rng.normal(0.0, 0.1, base.size))
        twin = fitted("viscous_motor", twin_train, base + twin_shift + rng.normal(0.0, 0.1, base.size))
        twin.held_cost = winner.held_cost + twin_shift * base.size + 2.0
        search = _Search(plugin or Plugin(), None, None, 3, _Say(False))
        chosen, rows, _ = search._select(current, [CandidateFit("viscous_load", winner),
                                                   CandidateFit("viscous_motor", twin)], 0)
        return chosen.name, rows

    name, rows = select(4000.0, 0.0)
    assert name == "viscous_motor" and [r["accepted"] for r in rows] == [False, True]
    assert "its twin viscous_motor explains the whole log better" in rows[0]["why"]
    assert select(4040.0, 0.0)[0] == "viscous_load"
    assert select(3730.0, 0.05)[0] == "viscous_load"
    failing = Plugin()
    failing.zero = ("viscous_motor",)
    assert select(4000.0, 0.0, failing)[0] == "viscous_load"
    alone = Plugin()
    alone.twins = False
    assert select(4000.0, 0.0, alone)[0] == "viscous_load"


def test_a_better_model_without_a_candidate_replaces_a_stalled_current_model() -> None:
    """``_Search._step``: a candidate whose refit passes the rule with a size not told from 0 (or fails its drop
    test) gained by refitting the rest; the model without it, refitted from there (``plugin.without``), replaces the
    current model when it predicts the held-back data better than the current model and than the step's winner, and
    the step is run again against it. Measured on a two-effect log (viscous load and an exponential Stribeck): the
    viscous-load model had stalled at 47.5x the noise and 15x the true coefficient, and hysteresis of no significant
    size fitted 1000x better. A reduced model worse than the winner leaves the winner accepted; with no winner, one
    better than the current model by no more than ``MIN_GAIN`` (no practical gain) ends the search instead."""
    from ident.diagnosis.engine import _Say, _Search
    from ident.diagnosis.models import CandidateFit, Magnitude
    from ident.diagnosis.screening import ScoreTest

    rng = np.random.default_rng(11)
    noise = rng.normal(size=4000) ** 2

    def model(effects: tuple[str, ...], scale: float) -> Fitted:
        return Fitted(effects, 4000.0 * scale, 4000.0 * scale, noise * scale, 4000, 4 + len(effects))

    class Plugin(_Recorded):
        def __init__(self, reduced: Fitted) -> None:
            self.reduced, self.dropped = reduced, []

        @staticmethod
        def screen(current: Fitted, names: tuple[str, ...]) -> list[ScoreTest]:
            return [ScoreTest(n, 1e4, 1e4, 1, 0.0) for n in names]

        @staticmethod
        def magnitude(m: Fitted, name: str) -> Magnitude:
            return Magnitude(1.0, (-1.0, 3.0) if name == "hysteresis" else (0.5, 1.5), "1")

        def without(self, m: Fitted, name: str, budget: float | None) -> Fitted:
            self.dropped.append(name)
            return self.reduced if name == "hysteresis" else model(m.effects[:-1], 1.0)   # the viscous drop test holds

    for rival, reduced_scale, replaced in ((True, 1.0 / 1100.0, True), (True, 1.0 / 20.0, False),
                                           (False, 1.0 / 1.5, True), (False, 1.0 / 1.005, False)):
        current = model(("viscous_load",), 1.0)
        fits = [CandidateFit("hysteresis", model(("viscous_load", "hysteresis"), 1.0 / 1000.0))]
        fits += [CandidateFit("viscous_motor", model(("viscous_load", "viscous_motor"), 1.0 / 50.0))] if rival else []
        plugin = Plugin(model(("viscous_load",), reduced_scale))
        search = _Search(plugin, _Pool(fits), None, 3, _Say(False))
        search._record(current, None, None, {})
        search._accept = lambda cur, winner, fits, k: winner.model   # noqa: B023 - the winner, as accepted
        out = search._step(current, ("hysteresis", "viscous_motor"))
        table = search.steps[-1].candidates.set_index("candidate")
        assert "includes 0" in table.loc["hysteresis", "why"]
        assert table.loc["hysteresis", "drop_test_gain"] == pytest.approx(1000.0 * reduced_scale)
        assert plugin.dropped == ["hysteresis", "viscous_motor"][:len(fits)]
        if replaced:
            assert out is current and search.models[-1] is plugin.reduced
            assert any("had stalled" in n and ("better than the step's winner viscous_motor" in n) == rival
                       for n in search.notes)
        else:
            assert out is (fits[1].model if rival else None) and search.models[-1] is current and not search.notes


def test_a_refit_that_removes_less_than_chance_leaves_its_candidate_not_ruled_out() -> None:
    """``_Search._step``: a candidate the screen passes (its step predicts a fall of many noise variances) whose
    refit removes fewer noise variances of the training cost than its degrees of freedom remove by chance was not
    tested by that refit: at a model above its noise level it is listed as not ruled out with the numbers, and its
    table row says so; at the noise there was nothing to remove. A refit that removes more (even without passing
    the rule) rules it out as before. Measured on a two-effect log: every refit
    of a step ended within 0.02 noise variances of its start and read as tested and rejected. Nor does a refit test
    its candidate whose better fit of the training part does not carry over to the held-back part (1.5x better
    there, 0.8x as good held back: measured on the independent two-effect log 7607, the hidden Stribeck's refit
    at 7.7x the noise, 2.30x and 0.82x); one that fits the training part better by no more than ``MIN_GAIN`` does.
    A candidate named at a later step is not listed as not ruled out (it would make every name tentative)."""
    from ident.diagnosis import CONFIDENT_OVER_NOISE
    from ident.diagnosis.engine import _Say, _Search
    from ident.diagnosis.models import CandidateFit
    from ident.diagnosis.result import NamedEffect
    from ident.diagnosis.screening import ScoreTest

    noise = np.random.default_rng(5).normal(size=4000) ** 2

    def model(effects: tuple[str, ...], train: float, scale: float = 1.0) -> Fitted:
        return Fitted(effects, train, 4000.0 * scale, noise * scale, 4000, 4 + len(effects))

    fits = [CandidateFit("viscous_motor", model(("viscous_motor",), 4000.0 - 0.02)),
            CandidateFit("hardening", model(("hardening",), 4000.0 - 5.0, 1.0 / 1.001)),
            CandidateFit("stribeck", model(("stribeck",), 4000.0 / 1.5, 1.0 / 0.8)),
            CandidateFit("hysteresis", model(("hysteresis",), 4000.0 / 1.009, 1.0 / 0.8))]

    class Plugin(_Recorded):
        @staticmethod
        def screen(current: Fitted, names: tuple[str, ...]) -> list[ScoreTest]:
            return [ScoreTest("viscous_motor", 1141.0, 30.0, 1, 0.0), ScoreTest("hardening", 40.0, 9.0, 1, 1e-6),
                    ScoreTest("stribeck", 3000.0, 20.0, 1, 1e-9), ScoreTest("hysteresis", 50.0, 20.0, 1, 1e-9)]

        def __init__(self, over: float) -> None:
            self.over = over

        def over_noise(self, m: Fitted) -> tuple[float, float]:
            return self.over, self.over

        @staticmethod
        def confident_levels() -> tuple[float, float]:
            return CONFIDENT_OVER_NOISE, CONFIDENT_OVER_NOISE

    for over in (1.96, 0.998):   # above its noise level, and at the noise (nothing left for a refit to remove)
        search = _Search(Plugin(over), _Pool(fits), None, 3, _Say(False))
        current = model((), 4000.0)
        search._record(current, None, None, {})
        assert search._step(current, ("viscous_motor", "hardening", "stribeck", "hysteresis")) is None
        table = search.steps[-1].candidates.set_index("candidate")
        assert all("did not test it" not in table.loc[n, "why"] for n in ("hardening", "hysteresis"))
        if over < 1.0:
            assert not search.not_ruled_out and "did not test it" not in table.loc["viscous_motor", "why"]
            continue
        c, d = search.not_ruled_out
        assert c["candidate"] == "viscous_motor" and c["step"] == 0
        assert "removed 0.02 noise variances" in c["reason"] and "predicted 1141" in c["reason"]
        assert "did not test it" in table.loc["viscous_motor", "why"]
        assert d["candidate"] == "stribeck" and "lowers the training cost 1.5x" in d["reason"]
        assert "raises the held-back cost 1.25x" in d["reason"] and "did not test it" in table.loc["stribeck", "why"]
        search.named = [NamedEffect("stribeck", 1.0, (0.9, 1.1), "1", "named at a later step", None, None)]
        assert [c["candidate"] for c in search.not_ruled_out] == ["viscous_motor"]   # named: not "not ruled out"


def test_an_effect_named_first_gives_way_to_a_better_one_at_the_final_model() -> None:
    """``_Search._exchange``: every named effect but the last is refitted out of the final model and the candidates
    that pass the screen there are refitted in its place; the best takes its place when it passes the acceptance
    rule against the final model, and the report says so. Measured on a two-effect log of the independent generator
    (viscous load and an exponential Stribeck): hysteresis, named first against the base model, stood in for the
    viscous load (1.02x / 1.018x the noise with a kinematic error after it); with Stribeck in the model the viscous
    load predicts the held-back data 1.043x better and the pair reaches 0.998x the noise. A replacement that gains no
    more than ``MIN_GAIN`` leaves the names as they were; the last name is never exchanged; the refit without a name
    that backward elimination has just made is not made again; a model already within ``MIN_GAIN`` of the noise on
    the held-back data is not exchanged."""
    from ident.diagnosis.engine import _departed, _refit_task, _Say, _Search, _without_task
    from ident.diagnosis.models import CandidateFit, Magnitude
    from ident.diagnosis.result import NamedEffect
    from ident.diagnosis.screening import ScoreTest

    rng = np.random.default_rng(5304)
    noise = rng.normal(size=4000) ** 2

    def model(effects: tuple[str, ...], scale: float) -> Fitted:
        return Fitted(effects, 4000.0 * scale, 4000.0 * scale, noise * scale, 4000, 4 + len(effects))

    class Plugin(_Recorded):
        def __init__(self, gain: float) -> None:
            self.gain, self.dropped, self.over = gain, [], None

        def without(self, m: Fitted, name: str, budget: float | None) -> Fitted:
            self.dropped.append(name)
            return model(tuple(e for e in m.effects if e != name), 1.5)

        @staticmethod
        def magnitude(m: Fitted, name: str) -> Magnitude:
            return Magnitude(1.0, (0.5, 1.5), "1")

        @staticmethod
        def candidates(m: Fitted) -> tuple[str, ...]:
            return tuple(n for n in ("hysteresis", "stribeck", "viscous_load") if n not in m.effects)

        @staticmethod
        def screen(m: Fitted, names: tuple[str, ...]) -> list[ScoreTest]:
            return [ScoreTest(n, 1e4, 1e4, 1, 0.0) for n in names]

        def refit(self, m: Fitted, test: ScoreTest, budget: float | None) -> CandidateFit:
            return CandidateFit(test.candidate, model(m.effects + (test.candidate,), 1.0 / self.gain))

        @staticmethod
        def converge(m: Fitted, budget: float | None, unfinished: bool = False) -> tuple[Fitted, str]:
            return m, ""

        def over_noise(self, m: Fitted) -> tuple[float, float] | None:
            return self.over

    class Pool:
        elsewhere = None

        def __init__(self, plugin: Plugin) -> None:
            self.plugin = plugin

        def share(self, plugin: object) -> object:
            return plugin

        def map(self, fn: object, tasks: list[tuple], desc: str = "", cost: object = None,
                progress: bool = False) -> list[object]:
            if fn is _without_task:
                return [self.plugin.without(m, name, b) for _, m, name, b in tasks]
            assert fn is _refit_task
            return [self.plugin.refit(m, t, b) for _, m, t, b in tasks]

    def named_pair(gain: float) -> tuple[Plugin, _Search, Fitted]:
        """A search that has named hysteresis, then Stribeck; its final model."""
        plugin = Plugin(gain)
        search = _Search(plugin, Pool(plugin), None, 3, _Say(False))
        search.named = [NamedEffect(n, math.nan, (math.nan, math.nan), "", "", None, None)
                        for n in ("hysteresis", "stribeck")]
        return plugin, search, model(("hysteresis", "stribeck"), 1.0)

    for gain, exchanged in ((1.043, True), (1.005, False)):
        plugin, search, current = named_pair(gain)
        out = search._exchange(current)
        # the last name, stribeck, is not exchanged; a replacement that passes the rule's held-back test is also
        # drop-tested, as every named effect is
        assert plugin.dropped == (["hysteresis", "viscous_load"] if exchanged else ["hysteresis"]), plugin.dropped
        names = [e.name for e in search.named]
        if exchanged:
            assert names == ["viscous_load", "stribeck"] and out.effects == ("stribeck", "viscous_load")
            assert search.steps[-1].extra["exchanged"] == "hysteresis" and search.steps[-1].added == "viscous_load"
            assert any("hysteresis" in n and "gave way to viscous_load" in n and "1.043x" in n for n in search.notes)
            assert "exchanged for hysteresis" in search.named[0].evidence
            assert "exchanged for viscous_load" in _departed(search.steps)["hysteresis"]   # the report's "not named"
        else:
            assert names == ["hysteresis", "stribeck"] and out is current and not search.notes

    # after backward elimination kept the model, the exchange starts from backward's own refit without each name
    plugin, search, current = named_pair(1.043)
    assert search._backward(current) is current and plugin.dropped == ["hysteresis", "stribeck"]
    search._exchange(current)
    assert plugin.dropped == ["hysteresis", "stribeck", "viscous_load"], plugin.dropped

    # a model that predicts the held-back data within MIN_GAIN of the noise is not exchanged (a replacement would
    # have to predict below the noise), and the notes say so; at the measured 1.018x it is
    for held, exchanged in ((1.003, False), (1.018, True)):
        plugin, search, current = named_pair(1.043)
        plugin.over = (1.0, held)
        out = search._exchange(current)
        assert (out is current) == (not exchanged) and bool(plugin.dropped) == exchanged, (held, plugin.dropped)
        assert any(n.startswith("exchange: not run") and "1.003x" in n for n in search.notes) == (not exchanged)


def test_each_step_may_replace_its_stalled_model_twice() -> None:
    """``_Search.run``: a step whose model gives way to a better-converged one (``_step`` returns the current model)
    is run again, twice per step (the count starts afresh once a step names an effect); a third replacement ends the
    forward search on the replacing model, never on the one it replaced."""
    from ident.diagnosis.engine import _Say, _Search

    def model(effects: tuple[str, ...], cost: float) -> Fitted:
        return Fitted(effects, cost, cost, np.ones(10), 10, 4 + len(effects))

    class Plugin(_Recorded):
        kind = "test"

        @staticmethod
        def fit_base(elsewhere: object = None) -> Fitted:
            return model((), 100.0)

        @staticmethod
        def candidates(m: Fitted) -> tuple[str, ...]:
            return ("stribeck",)

        @staticmethod
        def over_noise(m: Fitted) -> None:
            return None

    # per call of _step: "r" replaces the current model, "a" names an effect
    for script, models in (("rrarr", 2), ("rrrr", 1)):
        search = _Search(Plugin(), _Pool(), None, 5, _Say(False))
        calls = iter(script)

        def step(current: Fitted, names: tuple[str, ...]) -> Fitted | None:
            what = next(calls, None)
            if what == "r":
                search.models[-1] = model(current.effects, current.train_cost / 2)
                return current
            if what == "a":
                search._record(model(current.effects + (f"e{len(current.effects)}",), 1.0), "e", 2.0, {})
                return search.models[-1]
            return None

        search._step = step
        final = search.run()
        assert len(search.models) == models and final is search.models[-1], script
        assert final.train_cost == (0.25 if script == "rrarr" else 100.0 / 8), script


def test_a_name_chosen_against_a_stalled_model_is_tentative() -> None:
    """``_Search._settle``: when a named effect's size search moves the model beyond a refinement (a stall), every
    effect named after it was chosen by comparisons against models that had stalled along that size, and is
    tentative, with the training cost the search removed; effects named before it keep their confidence. Measured
    on a friction-ripple log (outside the library): asymmetric friction's search moved the final model 106 noise
    variances and Stribeck, named after it, was confident."""
    from ident.diagnosis.engine import _Say, _Search
    from ident.diagnosis.result import NamedEffect
    from ident.diagnosis.sizes import SizeSearch

    class Plugin(_Recorded):
        @staticmethod
        def over_noise(model: Fitted) -> tuple[float, float]:
            return 1.0, 1.0

        @staticmethod
        def confident_levels() -> tuple[float, float]:
            return 1.02, 1.02

    names = ("viscous_motor", "asymmetric_friction", "stribeck")
    for stalled, refined in ((True, False), (False, True)):
        search = _Search(Plugin(), None, None, 3, _Say(False))
        search.named = [NamedEffect(n, math.nan, (math.nan, math.nan), "", "", None, None) for n in names]
        model = Fitted(names, 34099.7, 100.0, np.ones(10), 100, 8)
        search._record(model, "stribeck", 2.0, {})
        moved = Fitted(names, 33993.8, 100.0, np.ones(10), 100, 8)

        def fake(m: Fitted, name: str) -> SizeSearch:
            if name == "asymmetric_friction" and m is model:
                return SizeSearch(moved, [], "held ... stalled" if stalled else "", "" if stalled else "refined")
            return SizeSearch(m, [])

        search._search_size = fake
        assert search._settle(model) is moved
        doubts = {n: " ".join(search.doubts.get(n, [])) for n in names}
        assert not doubts["viscous_motor"] and not doubts["asymmetric_friction"]
        assert ("named against models that had stalled" in doubts["stribeck"]) == stalled, doubts
        assert ("asymmetric_friction (named before it) lowered the training cost 106 noise variances"
                in doubts["stribeck"]) == stalled, doubts


def test_the_size_search_counts_chance_with_the_residuals_correlation() -> None:
    """``sizes._better``: a probe fits better only when its training cost falls by more than one residual variance
    times the size's inflation (``size_inflation``: its sandwich over its noise-only variance). On the stalled profile
    of a size at 1/6 of its profile's minimum the first check falls by 50 residual variances: a move with white
    residuals, chance with
    residuals correlated 100x (a model far from its log: measured on an actuator-lag log, a rival's search moved 8
    rounds for 10-280 residual variances a round). Through the FMU, the inflation is about 1 for the right candidate
    refitted to the noise and far above it for a wrong one that leaves the load's misfit (the other wrong one here,
    hardening, is refitted to none at all since the effects' finite-difference steps clear the simulation's round-off:
    ``problem.COORD_STEP``)."""
    from types import SimpleNamespace

    from ident.diagnosis.models.two_inertia import TwoInertiaPlugin
    from ident.diagnosis.sizes import search_size

    class Stalled:
        def __init__(self, inflation: float):
            self.inflation = inflation

        @staticmethod
        def fitted(size: float) -> Fitted:
            m = Fitted(("viscous_motor",), 1000.0 + 1e4 * math.log(size / 6.0) ** 2, 0.0, np.ones(1), 500, 5)
            m.state = SimpleNamespace(size=size, sim=None)
            return m

        def probe_size(self, model, name, factor, budget, reference=None):
            return self.fitted(model.state.size * factor)

    def searched(inflation: float) -> tuple[Fitted, Fitted, int]:
        probes, start, plugin = [], Stalled.fitted(1.0), Stalled(inflation)

        def run(fn, tasks):
            probes.extend(tasks)
            return [fn(t) for t in tasks]

        found = search_size(run, plugin, start, "viscous_motor", None, inflation=lambda m: plugin.inflation)
        return start, found.model, len(probes)

    start, white, _ = searched(1.0)
    assert white.train_cost < start.train_cost
    start, correlated, probes = searched(100.0)
    assert correlated is start and probes == 2
    log, _ = load(Case("single", 5102, "viscous_load", "medium", "default"), **SHORT)
    plugin = TwoInertiaPlugin(log)
    base = plugin.fit_base()
    tests = {t.candidate: t for t in plugin.screen(base, ("viscous_load", "asymmetric_friction", "hardening"))}
    fits = {name: plugin.refit(base, t, 300.0).model for name, t in tests.items()}
    assert plugin.over_noise(fits["viscous_load"])[0] < 1.01
    assert plugin.size_inflation(fits["viscous_load"], "viscous_load") < 2.0
    for wrong in ("asymmetric_friction", "hardening"):
        assert plugin.over_noise(fits[wrong])[0] > 1.2
    assert plugin.size_inflation(fits["asymmetric_friction"], "asymmetric_friction") > 20.0
    # the hardening refit goes to no hardening at all (the log has none): no size to search
    assert plugin.magnitude(fits["hardening"], "hardening").value == 0.0


def test_the_constancy_check_refits_each_half_and_a_moving_model_names_nothing_confidently() -> None:
    """The constancy check (in ``_Search._final_checks``) with a stand-in plug-in (the real one, through the FMU, runs
    on every diagnosis at the noise: the hardening test above, and on two 10 s logs in the slow test below): a final
    model at the noise with a name is refitted on each half (two tasks on the workers), the Wald statistic's chi-square
    p-value is recorded; below ``DM_LEVEL`` every name is tentative with the numbers and the summary says a shape may
    remain, above it the summary says the parameters hold. Above the noise (every name tentative already) or with
    nothing named it is not run; a half that could not be refitted leaves it unchecked, and the summary says why."""
    from ident.diagnosis import CONFIDENT_OVER_NOISE
    from ident.diagnosis.engine import DM_LEVEL, _reasons, _Say, _Search, _summary
    from ident.diagnosis.result import NamedEffect

    losses = np.ones(100)
    final = Fitted(("hysteresis",), 100.0, 100.0, losses, 100, 6)

    class Plugin:
        def __init__(self, over: float, wald: float) -> None:
            self.over, self.wald = over, wald

        def over_noise(self, m: Fitted) -> tuple[float, float]:
            return self.over, self.over

        @staticmethod
        def confident_levels() -> tuple[float, float]:
            return CONFIDENT_OVER_NOISE, CONFIDENT_OVER_NOISE

        def constancy(self, first: Fitted, second: Fitted) -> tuple[float, int]:
            assert (first, second) == ("half 0", "half 1")
            return self.wald, 5

        @staticmethod
        def shape_rival_of(name: str) -> str:
            return ""

    def check(over: float, wald: float, halves: list, named: bool = True) -> tuple[_Search, _Pool]:
        pool = _Pool(halves)
        search = _Search(Plugin(over, wald), pool, None, 3, _Say(False))
        search.named = [NamedEffect("hysteresis", math.nan, (math.nan, math.nan), "", "", None, None)] if named else []
        search._final_checks(final)
        return search, pool

    for wald, holds in ((47.7, False), (0.98, True)):   # the two 10 s logs' statistics (slow test below)
        search, pool = check(1.0, wald, ["half 0", "half 1"])
        c = search.constancy
        assert [t[1][2] for t in pool.tasks] == [0, 1] and c["checked"] and c["df"] == 5 and c["level"] == DM_LEVEL
        assert c["p_value"] == pytest.approx(stats.chi2.sf(wald, 5), rel=1e-12)
        reasons = _reasons(search, (1.0, 1.0), (CONFIDENT_OVER_NOISE, CONFIDENT_OVER_NOISE))
        summary = _summary([], [], (1.0, 1.0), (CONFIDENT_OVER_NOISE, CONFIDENT_OVER_NOISE), [], c)
        assert bool(reasons) is not holds
        if not holds:
            assert "differ between the two halves" in reasons[0] and f"Wald {wald:.3g} on 5" in reasons[0]
        assert any("may remain" in line for line in summary) is not holds
        assert any(line.startswith("the final model's parameters hold between the two halves") for line in summary) \
            is holds
    for over, named in ((CONFIDENT_OVER_NOISE * 1.01, True), (1.0, False)):
        search, pool = check(over, 47.7, ["half 0", "half 1"], named)
        assert search.constancy == {} and pool.tasks == []
    search, _ = check(1.0, 47.7, ["half 0", None])
    assert search.constancy == {"checked": False, "why": "a half could not be refitted within its budget"}
    assert not _reasons(search, (1.0, 1.0), (CONFIDENT_OVER_NOISE, CONFIDENT_OVER_NOISE))
    summary = _summary([], [], (1.0, 1.0), (CONFIDENT_OVER_NOISE, CONFIDENT_OVER_NOISE), [], search.constancy)
    assert any(line.startswith("whether the final model's parameters hold along the log was not checked: a half")
               for line in summary)


@pytest.mark.slow
def test_a_final_model_that_does_not_hold_along_the_log_names_nothing_confidently() -> None:
    """The constancy check (``engine._Search._final_checks``): the final model at the noise, refitted on each
    half of the training data alone, must keep its parameters (Wald test at p < 0.01). A hidden Dahl hysteresis of
    exponent 2 (the library's is exponent 1) is fitted to the noise by the library's, but its parameters move
    between the halves: named tentatively, and the report says a shape may remain. With exponent 1 (the library's
    shape) the check passes and the name is confident. Measured on the independent generator's logs: flagged a
    friction ripple stood in for by asymmetric friction and Stribeck (p = 0.0025), a three-slope hardening with a
    false asymmetric friction (6e-7) and a Maxwell-slip hysteresis with a false hardening (5e-16); passed 9 logs of
    library shapes (p = 0.085-0.96) and two other Stribeck decays (0.37, 0.40)."""
    out = {}
    for seed in (5103, 5101):
        log, truth = load(Case("single", seed, "hysteresis", "medium", "default", "dahl"), 10.0, 5000.0)
        out[truth["variants"]["hysteresis"]["exponent"]] = diagnose(log, candidates=("hysteresis",), workers=0,
                                                                    export_fmu=False)
    other, own = out[2.0], out[1.0]
    assert [e.name for e in other.effects] == ["hysteresis"] and other.effects[0].tentative
    assert "differ between the two halves" in other.effects[0].why_tentative
    assert other.constancy["p_value"] < 0.01 and any("may remain" in line for line in other.summary)
    assert [(e.name, e.tentative) for e in own.effects] == [("hysteresis", False)]
    assert own.constancy["p_value"] > 0.01 and any("hold between the two halves" in line for line in own.summary)
    assert own.to_dict()["constancy"]["df"] == 5


def test_a_budget_with_a_reference_cost_counts_a_costlier_simulation_as_often_as_its_work():
    """A size probe's budget counts from the cost of the search's origin (``EvaluationBudget.unit``): a model that
    is costlier to simulate (a Dahl hysteresis held at a large size with a stiff element: small substeps) pays what
    the FMU counted relative to it, so a walk to such sizes runs out after fewer simulations; a cheaper one still
    counts once (the bound is never looser than a count). Without a reference cost (a refit) every simulation counts
    once, whatever its model costs. A simulation the budget cannot pay for is refused before it runs."""
    from ident.diagnosis.models.problem import ModelProblem
    from ident.fitting.identify import BudgetExceeded, EvaluationBudget, identify

    log, _ = load(CLEAN, **SHORT)
    fit = identify(log)
    stop = log.n // 2
    big = {"hysteresis_torque": 100 * fit.params.f_l, "hysteresis_stiffness": 1e3 * fit.params.K_s}

    def problem(fixed: dict, meter: EvaluationBudget | None = None) -> ModelProblem:
        return ModelProblem(log, fit.params, (), None, stop, fit.sigma_load_rad, fixed=fixed, budget=meter)

    cheap, costly = problem({"b_l": 1e-9}), problem(big)
    try:
        cheap.residuals(fit.theta)
        costly.residuals(fit.theta)
        unit = cheap.plant.model_evaluations() / stop
        ratio = costly.plant.model_evaluations() / cheap.plant.model_evaluations()
    finally:
        cheap.close()
        costly.close()
    assert ratio > 3.0
    for reference, charged in ((unit, ratio * stop), (None, stop), (unit * 10 * ratio, stop)):
        meter = EvaluationBudget(6.0 * stop, reference)
        p = problem(big, meter)
        try:
            p.residuals(fit.theta)
            assert meter.used == pytest.approx(charged)
            while meter.used + stop <= meter.limit:
                p.residuals(fit.theta + 1e-9 * (meter.used / stop))   # a new point: simulated and charged again
            before = meter.used
            with pytest.raises(BudgetExceeded):
                p.residuals(fit.theta + 1e-3)
            assert meter.used == before and p.exhausted
        finally:
            p.close()


def test_a_candidate_out_of_budget_blocks_a_confident_name():
    """With a budget too small to fit any candidate, nothing is named confidently: the candidates are listed as
    not ruled out, and the conclusions say so."""
    d, _ = diagnosed(HARDENING, workers=0, budget=1.0, max_effects=1)
    assert all(e.tentative for e in d.effects)
    assert d.not_ruled_out and {"step", "candidate", "reason"} <= set(d.not_ruled_out[0])
    assert any("cannot be ruled out" in s for s in d.summary)


def test_a_fit_that_runs_out_of_budget_is_judged_at_the_best_point_it_reached():
    """A budget that pays for the refit's starts and a few iterations, not its convergence: the best point reached
    is a model like any other. The strong hardening it holds passes the rule there and is named, tentatively with
    that reason, and the accepted model is refitted on from where the budget ended; it is not listed as not ruled
    out. Before, the candidate was "not fitted" and nothing was named."""
    d, truth = diagnosed(HARDENING, workers=0, budget=12.0, max_effects=1)
    cand = d.steps[0].candidates.set_index("candidate")
    assert cand.loc["hardening", "accepted"] and "judged at the best point it reached" in cand.loc["hardening", "why"]
    assert cand.loc["hardening", "evaluations"] <= 12.0
    [e] = d.effects
    assert e.name == "hardening" and e.tentative
    assert "before it converged" in e.why_tentative
    assert all(r["candidate"] != "hardening" for r in d.not_ruled_out)
    assert any("refitted on from where it stopped" in n for n in d.notes)


def test_rigid_start_names_flexibility_by_the_acceptance_rule():
    """From the rigid kinematics q_l = r q_m, flexibility is named only through the rule every effect passes (its
    held-back gain, Diebold-Mariano p and BIC change are reported), with K_s and an interval covering the truth."""
    d, truth = diagnosed(CLEAN, workers=0, model="rigid", max_effects=1)
    assert d.steps[0].extra.get("model", "").startswith("rigid kinematics")
    assert d.steps[1].added == "flexibility"
    assert d.steps[1].extra["dm_p"] < 0.01 and d.steps[1].extra["delta_bic"] < 0 and d.steps[1].score > 1.01
    e = d.effects[0]
    K = truth["si"]["K_s"]
    assert e.name == "flexibility" and e.ci95[0] <= K <= e.ci95[1] and abs(e.magnitude / K - 1) < 1e-3
    assert d.steps[0].screen.iloc[0].candidate == "flexibility" and "fitted directly" in d.steps[0].screen.iloc[0].note


def test_cli_json_progress_and_fmu(tmp_path):
    """``hdrive diagnose --json``: JSON on stdout, progress on stderr, the report, diagnosis.json and the fitted
    FMU whose start values are the final model."""
    log, _ = load(CLEAN, duration_s=2.0, rate_hz=5000.0)
    from ident.fitting.logs import write_log

    path = tmp_path / "log.csv"
    write_log(log, path)
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "ident", "diagnose", str(path), "--json", "--out", str(out),
                           "--max-effects", "1", "--pulses", "20", "--workers", "0"], capture_output=True, text=True,
                          env=_env(), timeout=600)
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert "[diagnose" in proc.stderr and "fitting the base" in proc.stderr
    assert {"summary", "steps", "effects", "unexplained", "not_ruled_out", "fmu", "derivations"} <= set(data)
    # the scales the log showed, in numbers; which kinematic-error harmonics it can tell apart (a 2 s log: 2/rev)
    assert any(d.startswith("deflection scale d95") for d in data["derivations"]), data["derivations"]
    assert any(d.startswith("kinematic error: its 2/rev alone fitted") for d in data["derivations"])
    assert data["steps"][0]["predicted_resolution_m"] > 0
    assert (out / "diagnosis.md").is_file() and (out / "diagnosis.json").is_file()
    # where the time went, stage by stage: disjoint parts of the whole, the base fit first, said on stderr too
    stages = data["stage_s"]
    assert list(stages)[0] == "base fit" and "report and FMU" in stages and "step 0" in stages, stages
    assert 0 < sum(stages.values()) <= data["elapsed_s"]
    assert "time: base fit" in proc.stderr
    from fmpy import read_model_description

    starts = {v.name: v.start for v in read_model_description(data["fmu"]).modelVariables}
    assert math.isclose(float(starts["K_s"]), data["steps"][-1]["params"]["K_s"], rel_tol=1e-12)


def test_ctrl_c_stops_the_diagnosis_and_its_workers(tmp_path):
    """Ctrl-C while the candidates are refitted on two worker processes: the command exits (non-zero), leaves no
    worker behind and writes no report (a diagnosis that carried on would write one and exit 0)."""
    log, _ = load(HARDENING, **SHORT)
    from ident.fitting.logs import write_log

    path = tmp_path / "log.csv"
    write_log(log, path)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "ident", "diagnose", str(path), "--out", str(out), "--pulses", "0",
                             "--workers", "2"], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            env=_env())
    try:
        for line in proc.stderr:
            if "refitting" in line:
                break
        time.sleep(0.5)
        workers = _descendants(proc.pid)
        t0 = time.perf_counter()
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
        elapsed = time.perf_counter() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
    # It stopped (no report; the candidates' refits alone last longer than this bound). How fast (issue 16: within
    # 2 s) is measured in bench/interrupts.py, not here: a loaded machine must not turn this test red.
    assert elapsed < 25.0, elapsed
    assert proc.returncode != 0 and not out.exists()
    assert workers, "no worker processes were running"
    time.sleep(0.5)
    assert not [p for p in workers if _alive(p)]


def test_bad_input():
    log, _ = load(CLEAN, duration_s=1.0, rate_hz=5000.0)
    from dataclasses import replace

    with pytest.raises(LogError, match="load_pos_rad"):
        diagnose(replace(log, load_pos_rad=None))
    with pytest.raises(ValueError, match="unknown effect"):
        diagnose(log, candidates=("magic",), workers=0)
    with pytest.raises(ValueError, match="model"):
        diagnose(log, model="three-inertia")
    with pytest.raises(ValueError, match="budget"):
        diagnose(log, budget=0.0)
    other = replace(log, time_s=np.arange(log.n) / 1000.0, meta=replace(log.meta, sample_rate_hz=1000.0))
    with pytest.raises(LogError, match="sample rate"):
        diagnose(log, holdout=other, workers=0)


def test_data_errors_are_caught_before_any_effect_is_named():
    """Issue 16 item 6: a sidecar sample rate 0.8 % off the time column, or a gear ratio twice the true one, is the
    identifier's data-check error before anything is fitted (before: a phantom kinematic error was named)."""
    from dataclasses import replace

    log, _ = load(CLEAN, **SHORT)
    with pytest.raises(LogError, match="sample"):
        diagnose(replace(log, meta=replace(log.meta, sample_rate_hz=log.meta.sample_rate_hz * 1.008)), workers=0)
    with pytest.raises(LogError, match="ratio|gear"):
        diagnose(replace(log, meta=replace(log.meta, r=2 * log.meta.r)), workers=0)


# ------------------------------------------------------------------------------------------ the matrix (slow) ----

def test_the_matrix_counts_an_interval_by_the_side_that_faces_the_truth() -> None:
    """The matrix's coverage (``tests.diagnosis_matrix.coverage``): a 95 % interval holds the truth within its own
    half-width on the truth's side; a widened, lopsided interval is read on that side, so a wide far side does not
    hide a miss."""
    def mag(value: float, lo: float, hi: float, truth: float) -> dict:
        return {"magnitude": value, "ci95": [lo, hi], "truth": truth}
    held, missed = mag(1.0, 0.9, 1.1, 1.05), mag(1.0, 0.99, 1.5, 0.9)   # 0.9 is 19.6 sd below on its side
    c = coverage([held, missed])
    assert (c["n"], c["covered"]) == (2, 1)
    assert math.isclose(c["max_abs_z"], 0.1 / (0.01 / 1.959964), rel_tol=1e-5)
    assert coverage([])["n"] == 0


@pytest.mark.slow
def test_matrix(tmp_path_factory):
    """The issue's randomized matrix (``tests/diagnosis_matrix.py``) at the generator's own durations and rates:
    the right effect named in >= 90 % of single-effect logs, nothing named on any clean log, both effects in >= 80 %
    of two-effect logs, no confident name on any log with an effect outside the library and "unexplained" on most;
    magnitudes within 10 % where the shape is the library's (>= 90 % of them), and their confident 95 % intervals
    holding the truth as often as 95 % intervals do (fewer has a chance below 0.1 %)."""
    from tests.diagnosis_matrix import matrix, run_case, summarize

    results = [run_case(c, workers=2) for c in matrix()]
    s = summarize(results)
    (tmp_path_factory.mktemp("matrix") / "matrix.json").write_text(json.dumps({"summary": s, "results": results},
                                                                             default=str))
    c = s["classes"]
    assert c["single"]["success"] >= 0.9 * c["single"]["logs"], s
    assert c["clean"]["success"] == c["clean"]["logs"], s
    assert c["two_effect"]["success"] >= 0.8 * c["two_effect"]["logs"], s
    assert c["outside"]["success"] == c["outside"]["logs"], s
    assert c["outside"]["logs_with_unexplained"] > 0.5 * c["outside"]["logs"], s
    assert s["magnitudes"]["within_10pct"] >= 0.9 * s["magnitudes"]["n"], s
    iv = s["intervals"]["confident"]   # 95 % intervals: fewer hits than this has a chance of 0.1 %
    assert iv["covered"] >= stats.binom.ppf(1e-3, iv["n"], 0.95), s


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1]) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (its Dask workers and their helpers)."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parents[int(entry.name)] = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in parents.items() if pp == p]
        out += kids
        todo += kids
    return out


def _alive(pid: int) -> bool:
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except OSError:
        return False


def test_a_candidates_refit_starts_no_worse_than_the_model_it_extends() -> None:
    """The refit's starts (``two_inertia._heads``): the screen's point, the Gauss-Newton step and that step scaled
    back to nothing; the last is the current model with the candidate's linear coordinates at 0 (the effect off)
    and its nonlinear ones where the screen put them, so the best start, and the refit (which returns the best point
    it simulated), is never worse than the current model. A two-effect log's kinematic-error refit ended at 100x the
    current model's training cost when only the full step was tried."""
    from ident.diagnosis.models.coordinates import LogScales, coordinates
    from ident.diagnosis.models.two_inertia import STEP_FRACTIONS, _heads

    scales = LogScales(v_m=1e-2, v_l=1e-4, d95=1e-6, v_l_percentiles=(1e-5, 3e-5, 1e-4, 3e-4, 1e-3), K_s=10.0,
                       f_l=1e-4, f_m=1e-3)
    for name in ("kinematic_error", "stribeck", "hysteresis"):
        coords = coordinates(name, scales)
        theta, step = np.array([1.0, 2.0, 3.0, 0.1]), np.array([0.5, -0.5, 0.2, 0.0])
        x = np.array([0.7 if not c.log else -2.0 for c in coords])
        heads = _heads(theta, step, x, list(coords))
        assert len(heads) == 1 + len(STEP_FRACTIONS) and 0.0 in STEP_FRACTIONS and 1.0 in STEP_FRACTIONS
        off = heads[1 + STEP_FRACTIONS.index(0.0)]
        assert np.array_equal(off[:4], theta)
        assert all((v == 0.0) if not c.log else (v == -2.0) for c, v in zip(coords, off[4:]))
        assert np.array_equal(heads[1 + STEP_FRACTIONS.index(1.0)], np.concatenate([theta + step, x]))


def test_a_refit_that_did_not_test_its_candidate_starts_again_from_its_last_fit_or_the_reflected_step() -> None:
    """``two_inertia._retry_starts``: a refit that ended where it began (every head of the screen's step the current
    model or worse) starts again from the candidate's unknowns where its last refit left them, then from the
    screen's point reflected into the bounds where the step put a size outside them (a negative friction), each
    inside the bounds; neither when there is no last fit and the step stayed inside. Measured on a two-effect log
    (a motor viscous friction and a Stribeck friction with its own static level): after Stribeck the step put b_m
    at -6.1e-6 and every refit of the step removed 0.02 noise variances; retried, b_m reached 9.12e-6 (truth
    9.08e-6) and was named."""
    from ident.diagnosis.models.coordinates import LogScales, coordinates
    from ident.diagnosis.models.two_inertia import _retry_starts
    from ident.diagnosis.screening import ScoreTest

    scales = LogScales(v_m=1e-2, v_l=1e-4, d95=1e-6, v_l_percentiles=(1e-5, 3e-5, 1e-4, 3e-4, 1e-3), K_s=10.0,
                       f_l=1e-4, f_m=1e-3)
    coords = coordinates("stribeck", scales)
    size, speed = coords   # a bounded size (from 0) and a log-scaled Stribeck velocity
    inside = np.array([0.5, -1.0])
    assert _retry_starts(ScoreTest("stribeck", 90.0, 9.0, 2, 1e-9), coords, inside) == []
    carried = {size.name: size.value(0.25), speed.name: speed.value(-2.0)}
    [start] = _retry_starts(ScoreTest("stribeck", 90.0, 9.0, 2, 1e-9, carried=carried), coords, inside)
    assert np.allclose(start, [0.25, -2.0])
    outside = np.array([size.lo - 0.5, -1.0])
    first, second = _retry_starts(ScoreTest("stribeck", 90.0, 9.0, 2, 1e-9, carried=carried), coords, outside)
    assert np.allclose(first, [0.25, -2.0]) and np.allclose(second, [size.lo + 0.5, -1.0])
    far = {size.name: size.value(size.hi * 3.0)}
    [start] = _retry_starts(ScoreTest("stribeck", 90.0, 9.0, 2, 1e-9, carried=far), coords, inside)
    assert np.allclose(start, [size.hi, -1.0])


def test_a_retry_starts_where_its_scaled_starts_go_downhill_and_is_not_run_where_none_does() -> None:
    """``two_inertia._start_head``: the first run starts from its cheapest head whatever it costs (the head at
    fraction 0 is the current model); a retry starts from its cheapest head only when that one is below the current
    model, else it is not run (IPOPT from the current model is the first run, which ended there). Measured on an
    actuator-lag log: retries from uphill starts used up three candidates' budgets climbing back to the current
    model."""
    from ident.diagnosis.models.two_inertia import STEP_FRACTIONS, _start_head

    zero = 1 + STEP_FRACTIONS.index(0.0)
    uphill = [9.0, 9.0, 7.0, 6.0, 5.5, 5.0]   # the heads' costs: falling towards the current model (5.0)
    assert uphill[zero] == 5.0 and _start_head(uphill, retry=False) == zero
    assert _start_head(uphill, retry=True) is None
    level = [5.0] * len(uphill)   # a size that changes nothing: no head is below the current model
    assert _start_head(level, retry=True) is None
    dip = list(uphill)
    dip[zero - 1] = 4.9   # a small step along the retry's direction goes downhill: run from there
    assert _start_head(dip, retry=True) == zero - 1 == _start_head(dip, retry=False)


def test_a_refit_tests_its_candidate_when_it_removes_at_least_its_degrees_of_freedom() -> None:
    """``ScoreTest.tested_by``: the one rule the loop (training cost) and the two-inertia refit's retry (its
    problem's cost) share; a fall below the candidate's degrees of freedom (the chi-square mean of as many
    parameters with no effect) did not test it, whatever the screen's statistic."""
    from ident.diagnosis.screening import ScoreTest

    two = ScoreTest("stribeck", 1141.0, 900.0, 2, 1e-9)
    assert not two.tested_by(0.02) and not two.tested_by(1.99) and two.tested_by(2.0) and two.tested_by(500.0)
    assert ScoreTest("viscous_motor", 3.0, 3.0, 1, 0.08).tested_by(1.0)


def test_a_candidates_next_refit_carries_where_its_last_refit_ended() -> None:
    """``_Search._refits``: each refit's candidate unknowns (``plugin.effect_start``) go with the candidate's next
    refit (``ScoreTest.carried``), the retry start of a refit that does not test it; a refit that ended above the
    model it extended carries nothing, and the screen's own results are left as they were."""
    from ident.diagnosis.engine import _Say, _Search
    from ident.diagnosis.models import CandidateFit
    from ident.diagnosis.screening import ScoreTest

    def model(effects: tuple[str, ...], train: float) -> Fitted:
        return Fitted(effects, train, 100.0, np.ones(100), 100, 4 + len(effects))

    class Plugin(_Recorded):
        @staticmethod
        def effect_start(m: Fitted, name: str) -> dict[str, float]:
            return {f"{name} size": m.train_cost}

    current = model((), 1000.0)
    pool = _Pool([CandidateFit("viscous_motor", model(("viscous_motor",), 900.0)),
                  CandidateFit("hardening", model(("hardening",), 1100.0))])
    search = _Search(Plugin(), pool, None, 3, _Say(False))
    tests = [ScoreTest("viscous_motor", 50.0, 5.0, 1, 1e-9), ScoreTest("hardening", 40.0, 4.0, 1, 1e-8)]
    search._refits(current, tests, "step 0")
    search._refits(current, tests, "step 1")
    assert [task[2].carried for task in pool.tasks] == [{}, {}, {"viscous_motor size": 900.0}, {}]
    assert not tests[0].carried


def test_an_effect_accepted_after_the_model_reached_the_noise_is_tentative() -> None:
    """An effect accepted at a model whose named effects already explain the log down to the fixed ceiling of the
    confidence level (``CONFIDENT_OVER_NOISE``, not the model's own chance level) is tentative, with the numbers that made it so: it may stand in for a named effect's
    shape the library lacks (two-effect logs of the independent generator named kinematic error after a Maxwell-slip
    hysteresis and a three-slope hardening left 1.00x / 1.015x the noise). Not so for the first effect (there is no
    named shape to stand in for), nor above the level; a runner-up the Diebold-Mariano test cannot tell apart is
    the other doubt."""
    from ident.diagnosis import CONFIDENT_OVER_NOISE
    from ident.diagnosis.engine import _doubts
    from ident.diagnosis.models import CandidateFit

    class Noise:
        @staticmethod
        def over_noise(model: Fitted) -> tuple[float, float]:
            return model.metrics["over"]

    rng = np.random.default_rng(16)
    held = rng.normal(size=2000) ** 2

    def fitted(effects: tuple[str, ...], over: tuple[float, float], losses: np.ndarray = held) -> Fitted:
        return Fitted(effects, 7000.0, float(losses.sum()), losses, 7000, 6, {"over": over})

    winner = CandidateFit("kinematic_error", fitted(("hysteresis", "hardening", "kinematic_error"), (0.99, 0.99)))
    at_noise = fitted(("hysteresis", "hardening"), (1.0, CONFIDENT_OVER_NOISE * 0.99))
    doubts = _doubts(Noise(), at_noise, winner, [winner], None, 1.036)
    assert len(doubts) == 1 and "already explained" in doubts[0] and "1.036x" in doubts[0]
    above = fitted(("hysteresis",), (1.0, CONFIDENT_OVER_NOISE * 1.01))
    assert _doubts(Noise(), above, winner, [winner], None, 1.5) == []
    first = fitted((), (1.0, 1.0))
    assert _doubts(Noise(), first, winner, [winner], None, 1.5) == []
    rival = CandidateFit("stribeck", fitted(("hysteresis", "stribeck"), (0.99, 0.99), held[::-1].copy()))
    doubts = _doubts(Noise(), above, winner, [winner, rival], "stribeck", 1.5)
    assert len(doubts) == 1 and "cannot tell kinematic_error from stribeck" in doubts[0]


def test_the_stribeck_velocity_is_searched_no_lower_than_the_log_shows() -> None:
    """The fits' lower bound of the Stribeck velocity is the screen grid's lowest point, a tenth of the load's 5 %
    slip speed: below every speed the log shows a decay is one static level whatever its velocity, and the exact
    simulation's substeps shrink with it (a stand-in Stribeck refit that drifted to 1e-4 of the median slip speed
    took 0.9 s per simulation instead of 0.06 s, 230 s in all)."""
    from ident.diagnosis.models.coordinates import LogScales, coordinates, grid

    scales = LogScales(v_m=1e-2, v_l=4e-3, d95=1e-6, v_l_percentiles=(9.7e-5, 1e-3, 4e-3, 8e-3, 2e-2), K_s=10.0,
                       f_l=1e-4, f_m=1e-3)
    velocity = coordinates("stribeck", scales)[1]
    assert velocity.name == "ln_stribeck_velocity" and velocity.log
    assert velocity.value(velocity.lo) == pytest.approx(0.1 * scales.v_l_percentiles[0], rel=1e-12)
    points = [p["ln_stribeck_velocity"] for p in grid("stribeck", scales)]
    assert min(points) == pytest.approx(velocity.lo, abs=1e-12) and max(points) < velocity.hi


@pytest.mark.slow   # 37 s; the rule it feeds is tested with a stand-in in the default run (the next test)
def test_a_friction_ripple_outside_the_library_is_fitted_in_place_of_a_named_effect() -> None:
    """The outside rival (``TwoInertiaPlugin.outside_rival``): a ripple of the motor friction along its travel (1, 2
    and 4 per motor revolution; not a library effect) fitted in place of a named effect, linearized at the model. On
    a default-design log with a 4/rev friction ripple (the generator's outside effect) the ripple fits the training
    part far better than asymmetric friction refitted alone; on a log with a real asymmetric friction (medium, the
    same design) it fits worse by far more than ``SEPARABLE`` noise variances."""
    from ident.diagnosis.engine import SEPARABLE
    from ident.diagnosis.models.two_inertia import TwoInertiaPlugin

    deltas = {}
    for case in (Case("outside", 5510, "friction_ripple"), Case("single", 5514, "asymmetric_friction", "medium")):
        log, _ = load(case, **SHORT)
        plugin = TwoInertiaPlugin(log)
        base = plugin.fit_base()
        model = plugin.refit(base, plugin.screen(base, ("asymmetric_friction",))[0], 300.0).model
        costs, what, advice = plugin.outside_rival(model, ["asymmetric_friction"])
        assert "ripple of the motor friction" in what and "same motor angles" in advice
        deltas[case.cls] = costs["asymmetric_friction"]
        assert plugin.outside_rival(model, ["flexibility"]) == ({}, "", "")
    assert deltas["outside"] <= -SEPARABLE < SEPARABLE < deltas["single"], deltas


def test_a_rival_outside_the_library_that_fits_as_well_puts_a_name_in_doubt_at_the_noise() -> None:
    """``engine._outside_doubts``: a named effect whose outside rival fits the training part better, or worse by less
    than ``SEPARABLE`` noise variances, gets a doubt (the log prefers the rival, or cannot tell the two apart, with
    what to record); one that the rival fits far worse gets none; above the noise level nothing is fitted (the
    residual's leftover structure would be fitted by the rival's free torques, and the names are tentative anyway).
    Measured on a 10 s default-design log with a 2/rev ripple of 5.3e-5 of the motor friction: asymmetric friction
    was named confidently at 1.011x the noise before this rule; the rival fitted 634 noise variances better."""
    from ident.diagnosis import CONFIDENT_OVER_NOISE
    from ident.diagnosis.engine import SEPARABLE, _outside_doubts

    class Plugin:
        def __init__(self, over: float) -> None:
            self.over, self.asked = over, 0

        def over_noise(self, model: Fitted) -> tuple[float, float]:
            return self.over, self.over

        @staticmethod
        def confident_levels() -> tuple[float, float]:
            return CONFIDENT_OVER_NOISE, CONFIDENT_OVER_NOISE

        def outside_rival(self, model: Fitted, names: list[str]) -> tuple[dict[str, float], str, str]:
            self.asked += 1
            return {"asymmetric_friction": -634.0, "hysteresis": SEPARABLE * 0.5, "hardening": SEPARABLE * 1.01}, \
                "a ripple", "record slides over the same angles"

    final = Fitted(("asymmetric_friction", "hysteresis", "hardening"), 100.0, 100.0, np.ones(100), 100, 8)
    names = list(final.effects)
    notes: list[str] = []
    plugin = Plugin(1.0)
    doubts = _outside_doubts(plugin, final, names, notes)
    assert set(doubts) == {"asymmetric_friction", "hysteresis"}, doubts
    assert "the log prefers that ripple, and asymmetric_friction may stand in for it" in doubts["asymmetric_friction"]
    assert "cannot tell hysteresis from that ripple; record slides over the same angles" in doubts["hysteresis"]
    assert "fits the training data better (cost change -634" in doubts["asymmetric_friction"]
    assert len(notes) == 1 and "asymmetric_friction -634" in notes[0] and "hardening +" in notes[0]
    above = Plugin(CONFIDENT_OVER_NOISE * 1.01)
    assert _outside_doubts(above, final, names, notes) == {} and above.asked == 0 and "not fitted" in notes[-1]
    assert _outside_doubts(plugin, final, [], notes) == {} and plugin.asked == 1


def test_the_gauss_newton_decrement_is_the_linear_models_least_squares_drop():
    """``gauss_newton_decrement``: what the least-squares step of the linear model removes from |r|^2, which is
    also that step's squared length in the fit's standard errors (Delta^T J^T J Delta); a column of zeros (an
    unknown its bounds hold) adds nothing, and with none left nothing can be removed."""
    from ident.fitting.identify import gauss_newton_decrement

    rng = np.random.default_rng(20261202)
    J = rng.normal(size=(400, 3)) @ np.array([[1.0, 0.9, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 1e3]])  # correlated
    r = rng.normal(size=400) + J @ np.array([0.3, -2.0, 1e-3])
    step, *_ = np.linalg.lstsq(J, -r, rcond=None)
    left = r + J @ step
    held = np.column_stack([J[:, :2], np.zeros(400), J[:, 2:]])
    assert gauss_newton_decrement(held, r) == pytest.approx(r @ r - left @ left, rel=1e-9)
    assert gauss_newton_decrement(held, r) == pytest.approx(step @ (J.T @ J) @ step, rel=1e-9)
    assert gauss_newton_decrement(np.zeros((400, 2)), r) == 0.0


@pytest.mark.parametrize("noise_scale", [1.0, 0.1])
def test_a_settled_fit_ends_within_a_tenth_of_a_standard_error_of_ipopts_own_end(monkeypatch, noise_scale):
    """A refit ends once the Gauss-Newton step at its best point would lower the cost by less than ``SETTLED``
    noise variances (``ModelProblem.settled``), with fewer simulations than IPOPT's own stops take, at a cost
    within ``SETTLED`` of theirs and a point within a tenth of a standard error (the linear model's, at their end)
    of theirs. The base model on a clean log of the independent generator, from a start 30 standard errors off
    (the length of its step in the fit's own metric). With the load noise taken 10x too small (``noise_scale``
    0.1), the model leaves ~100x the noise variance there (``misfit``), as a model far from its log does, and both
    tolerances and the standard errors are those scaled by the residual variance."""
    from ident.diagnosis.models import problem as problem_mod
    from ident.diagnosis.models import two_inertia
    from ident.diagnosis.models.problem import SETTLED, ModelProblem
    from ident.fitting.identify import identify

    log, _ = load(CLEAN, **SHORT)
    fit = identify(log)
    stop = log.n // 2

    def problem() -> ModelProblem:
        return ModelProblem(log, fit.params, (), None, stop, fit.sigma_load_rad * noise_scale)

    p = problem()
    try:
        lo, hi = p.bounds()
        J = p.jacobian(fit.theta)
        misfit = max(1.0, p.misfit(p.cost(fit.theta)))
    finally:
        p.close()
    assert (misfit > 30.0) == (noise_scale < 1.0)
    off = np.linalg.cholesky(np.linalg.inv(J.T @ J / misfit)) @ (15.0 * np.array([1, -1, 1, -1]))
    start = np.clip(fit.theta + off, lo, hi)

    def run(settle: bool) -> tuple[float, np.ndarray, int, np.ndarray]:
        monkeypatch.setattr(problem_mod, "SETTLED", SETTLED if settle else -1.0)
        p = problem()
        try:
            theta = two_inertia._ipopt_or_best(p, start, lo, hi)
            assert p.settled() == settle
            return p.cost(theta), theta, p.evaluations, p.jacobian(theta)
        finally:
            p.close()

    settled_cost, settled_at, settled_sims, _ = run(True)
    own_cost, own_at, own_sims, J = run(False)
    assert settled_sims < own_sims
    assert settled_cost - own_cost < SETTLED * misfit
    d = settled_at - own_at
    assert d @ (J.T @ J / misfit) @ d < SETTLED
