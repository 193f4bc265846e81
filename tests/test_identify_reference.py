"""Identification on logs the tool did not make (issue 21): the independent reference generator
(``tests/reference/generator``: its own hybrid integrator, sensors and excitations, no code shared with the FMU or
``ident``), read through the product's reader.

Per log: the Cramer-Rao bound at the truth (the product's model and the true noise: a property of the log, not of
the estimator); wherever it is <= 1 %, the estimate lies within 3 bound-sigmas of the truth; a parameter either is
identifiable (no reason) or is not (with a reason and a fix); no value at a bound is reported; the one load-noise
estimate is within 20 % of the true noise; the model-mismatch warning stays quiet on these clean logs.

The default run takes the generator's 12-case suite (every excitation twice) as 2 s logs; the slow suite runs the
60-case suite at the generator's 4 s and checks the coverage of the 95 % intervals over it (90-99 %).
"""
from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from ident.fitting.identify import NAMES, identify
from tests.ident_support import cramer_rao_at_truth, paper_pulse_train, read_back
from tests.reference.generator import (
    IDENTIFICATION_SLOW_SUITE,
    IDENTIFICATION_SUITE,
    identification_case,
)
from tests.reference.generator.plant import Drive

SHORT_S = 2.0


def check_log(g, fit, crb: np.ndarray) -> dict:
    """The per-log must-holds; returns per parameter (covered, identifiable) for the coverage count."""
    truth = g.truth
    assert fit.sigma_load_rad / truth.noise_sigma_rad == pytest.approx(1.0, abs=0.2), "noise estimate"
    out = {}
    for i, name in enumerate(NAMES):
        e, v = fit.estimates[name], getattr(truth, name)
        err = math.log(e.value / v)
        if crb[i] <= 0.01:
            assert abs(err) <= 3 * crb[i], (name, err, crb[i], e.reason)
        d = e.to_dict()
        if e.at_bound:
            assert d["value"] is None and not e.identifiable, "a value at a bound is no result"
        assert e.identifiable == (e.reason == ""), (name, e.reason)
        out[name] = (e.ci95[0] <= v <= e.ci95[1], e.identifiable)
    assert fit.identifiable == (fit.fix == "")
    if all(c <= 0.01 for c in crb):
        assert fit.identifiable, fit.warnings   # the log pins all three: no refusal
        assert not any("does not explain this log" in w for w in fit.warnings), fit.warnings
    return out


@pytest.mark.parametrize("seed, kind", IDENTIFICATION_SUITE, ids=[f"{s}-{k}" for s, k in IDENTIFICATION_SUITE])
def test_reference_log(seed: int, kind: str, tmp_path) -> None:
    g = identification_case(seed, kind, duration_s=SHORT_S)
    log = read_back(g, tmp_path)
    check_log(g, identify(log), cramer_rao_at_truth(log, g))


def test_paper_pulse_train_right_values_or_a_plain_no(tmp_path) -> None:
    """The paper's one-way impulse experiment (1 ms pulses at 1.2 f_m, 60 ms apart, 5 kHz, encoder, 2 nm): issue
    21 got J_l* 411x the truth at its bound. 40 pulses here (the full 150 in the slow suite)."""
    g = paper_pulse_train(pulses=40, seed=7)
    log = read_back(g, tmp_path)
    fit = identify(log)
    crb = cramer_rao_at_truth(log, g)
    check_log(g, fit, crb)
    for name in NAMES:
        e = fit.estimates[name]
        assert e.identifiable or e.reason, name
        if e.identifiable:  # never a confident wrong number
            assert abs(math.log(e.value / getattr(g.truth, name))) <= 3 * max(crb[NAMES.index(name)],
                                                                              e.std / e.value)


def test_a_log_that_cannot_pin_the_parameters_says_so(tmp_path) -> None:
    """15 weak pulses (1.05 f_m) with 20 nm of noise: the bound at the truth is ~28 % for K* and J_l*. The result
    marks them not identifiable, says why (the bound, which parameters move together) and what to record."""
    g = paper_pulse_train(pulses=15, amplitude_star=1.05, noise_m=20e-9, seed=2)
    log = read_back(g, tmp_path)
    crb = cramer_rao_at_truth(log, g)
    assert crb[0] > 0.1 and crb[1] > 0.1
    fit = identify(log)
    assert not fit.identifiable
    for name in ("K_star", "J_l_star"):
        e = fit.estimates[name]
        assert not e.identifiable and "determined only to" in e.reason, e.reason
        assert e.to_dict()["identifiable"] is False and e.to_dict()["reason"] == e.reason
    assert "design-experiment" in fit.fix and "pulses" in fit.fix
    assert any(w.startswith("K_star") and "not identifiable from this log" in w for w in fit.warnings)
    assert not any("does not explain this log" in w for w in fit.warnings)   # not blamed on missing physics


@pytest.mark.slow
def test_paper_pulse_train_150_pulses(tmp_path) -> None:
    g = paper_pulse_train(pulses=150, seed=7)
    log = read_back(g, tmp_path)
    check_log(g, identify(log), cramer_rao_at_truth(log, g))


def test_whole_log_optimum_leaves_no_lower_initial_deflection_basin(tmp_path) -> None:
    """A default-design log of the slow suite (4 s at 10 kHz) whose last window's fit once stopped in the initial
    deflection's basin at 0.44 band, 306 noise variances above the one at 0.19 band, with K*, J_l*, f_l* 3.3 bound
    sigmas off at 1.011x the noise (inside the noise's spread: no residual test sees it). The default fit lies
    within 3 bound sigmas. The check against every basin (``identify._other_basin``) is exercised from that basin
    itself: the whole-log optimum moved to 0.44 band and refitted there (a local optimum, hundreds of noise
    variances above the truth's) is refitted from the lower basin, back to the default's estimates. (Which path
    ends in that basin depends on the last bits of the log's numbers: read with an inexact decimal parser, the
    second start path did; read exactly, neither does.)"""
    import ident.fitting.identify as I

    g = identification_case(4219, "default")
    log = read_back(g, tmp_path)
    crb = cramer_rao_at_truth(log, g)
    fit = identify(log)
    check_log(g, fit, crb)
    problem = I.OutputError(log, I.base_params(log), sigma_load=fit.sigma_load_rad)
    try:
        lo, hi = problem.bounds()
        wrong = fit.theta.copy()
        wrong[3] = 0.44
        theta, info = I.fit_ipopt(problem, wrong, lo, hi, 30)
        tracks, _ = I._settle(problem, [I.Track(theta, info=info)])
        assert abs(theta[3] - 0.44) < 0.05 and tracks[0].cost > problem.cost(fit.theta) + 100.0, "a lower basin"
        stages = [{"window_s": log.n / log.meta.sample_rate_hz}]
        out = I._other_basin(problem, tracks, stages, 30, False)
    finally:
        problem.close()
    assert "basin_d0" in stages[-1], "the basin check refitted from the lower basin"
    assert np.abs(out[0].theta[:3] - fit.theta[:3]) == pytest.approx(0.0, abs=1e-4)
    assert out[0].theta[3] == pytest.approx(fit.theta[3], abs=0.01)


@pytest.mark.slow
def test_reference_suite_coverage_and_noise(tmp_path) -> None:
    """The 60-case suite at 4 s: per-log must-holds, and the 95 % intervals cover the truth for 90-99 % of the
    identifiable (log, parameter) pairs."""
    pairs = []
    for seed, kind in IDENTIFICATION_SLOW_SUITE:
        g = identification_case(seed, kind)
        log = read_back(g, tmp_path, f"{seed}")
        out = check_log(g, identify(log), cramer_rao_at_truth(log, g))
        pairs += [covered for covered, ok in out.values() if ok]
    assert len(pairs) >= 120
    assert 0.90 <= np.mean(pairs) <= 0.99, np.mean(pairs)


@pytest.mark.slow
@pytest.mark.parametrize("drive", [Drive.from_nondim(1e7, 500, 0.02), Drive.from_nondim(1e5, 1e4, 0.5)])
def test_paper_pulse_train_extreme_drives(drive, tmp_path) -> None:
    g = paper_pulse_train(drive, pulses=80, seed=11)
    log = read_back(g, tmp_path)
    check_log(g, identify(log), cramer_rao_at_truth(log, g))


CHIRPS = [(seed, kind) for seed, kind in IDENTIFICATION_SLOW_SUITE if kind == "chirp"]


def test_chirp_start_candidates_hold_the_ringing(tmp_path) -> None:
    """A chirp never lets the motor rest, so the start reads the ringing off the whole log's spectra
    (``start.whole_log_candidates``). On the suite's ten chirps (2 s) one of the start's candidates is within 5 % of
    the locked-motor or the coupled ringing, also where the resonance lies above the sweep (the velocity spectrum
    and the unbanded ratio alone offered 8-15 Hz and 4.5-4.9 kHz there, and chirp 4242 ended in a local optimum)."""
    from ident.fitting.identify import base_params
    from ident.fitting.start import equation_error_start

    for seed, kind in CHIRPS:
        g = identification_case(seed, kind, duration_s=SHORT_S)
        log = read_back(g, tmp_path, f"{seed}")
        base, t = base_params(log), g.truth
        w_l = math.sqrt(t.K_star * base.f_m / (t.J_l_star * base.J_m)) / (2 * math.pi)
        modes = (w_l, w_l * math.sqrt(1 + base.r ** 2 * t.J_l_star))
        candidates = equation_error_start(log, base)["candidates_hz"]
        assert any(abs(f / m - 1) <= 0.05 for f in candidates for m in modes), (seed, modes, candidates)


def test_chirp_whose_resonance_lies_above_its_sweep(tmp_path) -> None:
    """Suite log 4242 (4 s at 10 kHz; the coupled mode at 198 Hz, the sweep's power ends near 173 Hz): identified,
    with the noise estimate right (it read 13.8x on the trapped fit)."""
    seed, kind = next(c for c in CHIRPS if c[0] == 4242)
    g = identification_case(seed, kind)
    log = read_back(g, tmp_path)
    fit = identify(log)
    check_log(g, fit, cramer_rao_at_truth(log, g))
    assert fit.identifiable, fit.warnings


def test_start_grid_spans_both_frequency_estimates(tmp_path) -> None:
    """A chirp (seed 4399, 6 s at 2 kHz, 35 free-ringing segments) whose spectral peak reads w_l^2 12 % below the
    truth and whose least-squares estimate reads 2.5 % below it: the first grid spans from the lower to the higher
    estimate, each widened by its own +-6 % floor (a span symmetric about the peak ended at the least-squares value
    and the fit was trapped, 1170x the noise). Found by running the CLI on a log the tool did not make."""
    from ident.fitting.identify import _frequency_factors
    from ident.fitting.start import W2_SPREAD

    factors = _frequency_factors({"w_l2": 1.0, "w_l2_ls": 1.13, "consistent": 1.0}, 1)
    assert factors.min() == pytest.approx(1 / (1 + W2_SPREAD))
    assert factors.max() == pytest.approx(1.13 * (1 + W2_SPREAD))
    assert np.all(np.diff(np.log(factors)) <= math.log(1.06) + 1e-12)
    g = identification_case(4399, "chirp", duration_s=6.0)
    log = read_back(g, tmp_path)
    fit = identify(log)
    check_log(g, fit, cramer_rao_at_truth(log, g))
    assert fit.identifiable, fit.warnings


@pytest.mark.parametrize("seed", [6405, 6416])
def test_first_window_holds_the_loads_first_motion(seed: int, tmp_path) -> None:
    """Default-design logs (4 s at 5 kHz) of drives with high load friction (f_l* 0.79, 0.65): the motor's first
    pulses move it, the load first moves 0.31 s later. A first window counted from the motor's motion ended before
    the load had moved, a model that moves nothing fit it to the noise, and the fit ended at 679x and 299x the noise
    (K* 3e4 and 4e6 bound sigmas off). Counted from the load's first motion: within 3 bound sigmas."""
    g = identification_case(seed, "default", rate_hz=5000.0)
    log = read_back(g, tmp_path)
    check_log(g, identify(log), cramer_rao_at_truth(log, g))


@pytest.mark.parametrize("seed, kind", [(6378, "default"), (6435, "chirp"), (6431, "chirp")])
def test_candidate_frequency_is_judged_on_its_own_window(seed: int, kind: str, tmp_path) -> None:
    """Logs (4 s at 5 kHz) whose start offers several candidate frequencies (``identify._candidate_winner``).
    Compared on the longest candidate's window, a wrong one won on 6378 (2000 Hz for a 302 Hz ringing: 9x the noise,
    K* 1900 bound sigmas off) and on chirp 6435 (28000x the noise); the winner of its own window is right. Chirp 6431
    guards the tie-break: its 673 Hz candidate wins its own 0.09 s window too, and the 68 Hz one (the coupled mode)
    wins its longer window and every other."""
    g = identification_case(seed, kind, rate_hz=5000.0)
    log = read_back(g, tmp_path)
    fit = identify(log)
    check_log(g, fit, cramer_rao_at_truth(log, g))
    assert fit.identifiable, fit.warnings


@pytest.mark.parametrize("seed", [7415, 7461])
def test_no_long_step_from_a_window_the_fit_does_not_explain(seed: int, tmp_path) -> None:
    """Clean default-design logs (7 s at 5 kHz, the length of a diagnosis log's training part) of two new drives
    whose fit on a short window stays above the noise in another basin (13x the noise with the scale 1.9x off; 4.3x
    with K* 0.69x the truth). The model was nearly linear over that fit's uncertainty region far beyond it, and the
    long step ended at 616x and 62x the noise, K* 1.6 % and 43 % off. From a fit that leaves misfit the window now
    grows by 1.3x with the grid (``identify._next_window``): within 3 bound sigmas. Read exactly, 7461's windows to
    0.33 s fit at the noise with the scale 0.53x the truth and the next left it; the first window's full-span grid
    around the previous optimum (``identify._rescale``) finds the truth's basin there."""
    from tests.reference.generator.logs import clean_case

    g = clean_case(seed, "default", duration_s=7.0, rate_hz=5000.0)
    log = read_back(g, tmp_path)
    check_log(g, identify(log), cramer_rao_at_truth(log, g))


def test_a_grid_window_that_leaves_the_noise_refits_the_scales_minima(tmp_path) -> None:
    """A clean default-design log (7 s at 5 kHz) of a new drive: the windows up to 0.36 s fit to the noise with the
    scale 1.3 % low, the next (a grid window, 0.46 s) left it at 3.2x, and every later window further (the whole log
    at 17x the noise, K* 4 % low). The scale's 1 % minima around the previous optimum (``identify._rescale``) find
    the truth's basin on that window: within 3 bound sigmas."""
    from tests.reference.generator.logs import clean_case

    g = clean_case(7467, "default", duration_s=7.0, rate_hz=5000.0)
    log = read_back(g, tmp_path)
    fit = identify(log)
    check_log(g, fit, cramer_rao_at_truth(log, g))
    assert any(st.get("rescaled") for st in fit.stages), "the remedy is what fixed it"


def test_a_drift_at_the_bands_edge_is_no_trusted_peak(tmp_path) -> None:
    """A PD-step log (7 s at 5 kHz; the training part of a 10 s diagnosis log) of a drive ringing at 138.5 Hz: the
    free-ringing segments' largest bin is the band's lowest, 2.14 Hz, on the motor's creep within a count (no local
    maximum), and the longest segment spans 2.1 of its periods. Trusted alone as resolved, it ended the fit at 18000x
    the noise. Now it is no peak (``start.resolved_peak``): the largest local maximum, 137.5 Hz, is a candidate too,
    and the fit is within 3 bound sigmas."""
    g = identification_case(6430, "pd_steps", duration_s=7.0, rate_hz=5000.0)
    log = read_back(g, tmp_path)
    fit = identify(log)
    assert not fit.start["frequency_trusted"]
    assert any(abs(f / 138.5 - 1) < 0.02 for f in fit.start["candidates_hz"]), fit.start["candidates_hz"]
    check_log(g, fit, cramer_rao_at_truth(log, g))


def test_second_start_path_where_the_first_misses_the_noise(tmp_path, monkeypatch) -> None:
    """Suite log 4231 (default design, 4 s at 4 kHz): the first start path (``identify.START_PATHS``: the window from
    the load's first motion, three samples after the motor's) led the fit to 12.6x the noise, K* 1.4 % off; the
    second (the window from the motor's first motion) to the noise. Both run, the lower whole-log cost wins.
    Since the continuation refits the scale's minima where a grid window leaves the noise (``identify._rescale``)
    the first path reaches the noise on this log too, so that remedy is switched off here to test the other."""
    import ident.fitting.identify as identify_module
    from ident.fitting.identify import START_PATHS

    g = identification_case(4231, "default")
    log = read_back(g, tmp_path)
    beside = _Deferred()
    assert identify(log, elsewhere=beside).start["start_path"] == START_PATHS[0].describe()  # the first suffices
    assert beside.started == 1 and beside.cancelled and not beside.asked   # started beside it, then not needed
    monkeypatch.setattr(identify_module, "_rescale", lambda problem, fitted, previous, iterations, f_peak_hz:
                        (fitted, problem.sigma_l))
    fit = identify(log)
    check_log(g, fit, cramer_rao_at_truth(log, g))
    assert fit.start["start_path"] == START_PATHS[1].describe()
    first, second = fit.start["other_path_costs"]
    assert second < first
    # run elsewhere (its task and its result through pickle, as to a worker and back): the very same fit
    beside = _Deferred()
    again = identify(log, elsewhere=beside)
    assert beside.started == 1 and beside.asked and not beside.cancelled
    np.testing.assert_array_equal(again.theta, fit.theta)
    assert again.start == fit.start and again.sigma_load_rad == fit.sigma_load_rad


class _Deferred:
    """A stand-in for another core (``ident.common.elsewhere``): the task and its result go through pickle as to a
    worker process; it runs when its result is asked (the first path's IPOPT must not share the process with it)."""

    def __init__(self) -> None:
        self.started, self.asked, self.cancelled = 0, False, False

    def __call__(self, fn: object, args: tuple) -> "_Deferred":
        self.started += 1
        self.task = pickle.dumps((fn, args))
        return self

    def result(self) -> object:
        self.asked = True
        fn, args = pickle.loads(self.task)
        return pickle.loads(pickle.dumps(fn(args, lambda: self.cancelled)))

    def cancel(self) -> None:
        self.cancelled = True


def test_the_second_start_path_is_skipped_where_it_would_repeat_the_first(monkeypatch) -> None:
    """A diagnosis matrix log with a hidden medium viscous motor friction (3 s at 5 kHz, its training part): the
    whole-log fit misses the noise (the effect is missing), but the second start path would pick the same window and
    candidate (``identify._paths_differ``), so it is not run; run anyway (both paths set to the second), it ends at
    the very same optimum."""
    import ident.fitting.identify as identify_module
    from ident.diagnosis.models.two_inertia import split_training, truncate_log
    from tests.diagnosis_matrix import Case, load

    log, _ = load(Case("single", 5102, "viscous_motor", "medium", "default"), duration_s=3.0, rate_hz=5000.0)
    full, stop = split_training(log, None)
    training = truncate_log(full, stop)
    fit = identify(training)
    assert fit.fit["residual_over_noise"] > 1.1
    assert fit.start["other_path"].startswith("not run") and "other_path_costs" not in fit.start
    second = identify_module.START_PATHS[1]
    monkeypatch.setattr(identify_module, "START_PATHS", (second, second))
    again = identify(training)
    assert again.start["start_path"] == second.describe()
    np.testing.assert_array_equal(again.theta, fit.theta)
