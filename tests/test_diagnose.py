"""The discrepancy workflow on logs in which an effect is hidden (issue 5 item 6).

Each "measured" log comes from the FMU with one effect of the library switched on at a realistic magnitude
(``ident.fitting.synthetic.HIDDEN_EFFECT_CASES``), encoder quantization, 2 nm load noise and a seeded random excitation that
is not the identifier's default. The workflow starts from the base model and must name the hidden effect (nothing
on a clean log, both when two are hidden), shrink the load NRMSE at least 5x and recover the magnitude within 10 %.

The whole matrix (10 diagnoses of 4 s logs, plus an effect outside the library) takes ~30 minutes on 2 cores: it is
marked ``slow`` and run by ``bench/diagnose.py`` (figures in bench/README.md); the default run keeps the clean log,
one hidden effect, the CLI and the error handling.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from ident.diagnosis.engine import diagnose
from ident.fitting.logs import LogError, write_log
from ident.fitting.synthetic import HIDDEN_EFFECT_CASES, OUT_OF_LIBRARY_CASES, hidden_effect_log, out_of_library_log
from ident.model.effects import EFFECTS
from ident.model.params import DriveParams

_cache: dict[tuple[str, float], object] = {}


def run(case: str, duration: float = 6.0, stop_at_noise: bool = True):
    key = (case, duration, stop_at_noise)
    if key not in _cache:
        log = hidden_effect_log(case, duration)
        _cache[key] = diagnose(log, model="rigid" if case == "flexibility" else "two-inertia", resolution_pulses=0,
                               workers=2, stop_at_noise=stop_at_noise)
    return _cache[key]


def truth_of(case: str, name: str) -> float | None:
    """The hidden magnitude of effect ``name`` in ``case`` (flexibility: the nominal K_s)."""
    hidden = HIDDEN_EFFECT_CASES[case][0]
    if name == "flexibility":
        return DriveParams().K_s
    value = hidden.get(EFFECTS[name].magnitude_param)
    return None if value is None else abs(value)


def check_case(case: str, duration: float, stop_at_noise: bool = True) -> None:
    _, _, expected = HIDDEN_EFFECT_CASES[case]
    d = run(case, duration, stop_at_noise)
    assert sorted(e.name for e in d.effects) == sorted(expected), d.to_frame()
    added = [s.added for s in d.steps[1:] if s.added]
    removed = [n for s in d.steps for n in s.extra.get("removed", [])]
    assert [n for n in added if n not in removed] == [e.name for e in d.effects]
    if not expected:
        assert len(d.steps) == 1 and d.unexplained == []
        assert d.steps[0].extra["residual_over_noise_load"] < 1.5
        return
    assert d.steps[0].nrmse_load / d.steps[-1].nrmse_load >= 5.0
    for e in d.effects:  # every named effect's magnitude within 10 %, its interval covering the truth
        truth = truth_of(case, e.name)
        assert abs(e.magnitude - truth) <= 0.10 * truth, (e.name, e.magnitude, truth)
        assert e.ci95[0] <= truth <= e.ci95[1] or abs(e.magnitude - truth) <= 1e-3 * truth, (e.name, e.ci95)
    assert d.unexplained == [] and d.steps[-1].extra["residual_over_noise_load"] < 1.5


def test_clean_log_names_nothing():
    # every candidate is refitted and must be rejected on its merits (the noise-floor stop would skip them)
    check_case("clean", 3.0, stop_at_noise=False)
    d = run("clean", 3.0, False)
    assert len(d.steps[0].candidates) == 7 and d.steps[0].candidates["error"].isna().all()


def test_clean_log_stops_at_the_noise_floor():
    d = diagnose(hidden_effect_log("clean", 2.0), resolution_pulses=0, export_fmu=False)
    assert d.effects == [] and len(d.steps[0].candidates) == 0
    assert 0.97 < d.steps[0].extra["residual_over_noise_load"] < 1.03  # the log's noise is 2 nm at the arm tip
    assert any("down to its sensor noise" in n for n in d.notes)


def test_hidden_hardening_is_named_and_measured():
    check_case("hardening", 4.0)
    d = run("hardening", 4.0)
    row = d.steps[0].candidates.iloc[0]
    assert row["candidate"] == "hardening" and row["heldback_gain"] > 5
    assert d.effects[0].runner_up is not None and d.effects[0].margin > 1.5


@pytest.mark.slow
@pytest.mark.parametrize("case", list(HIDDEN_EFFECT_CASES))
def test_hidden_effect_matrix(case):
    check_case(case, 4.0)


@pytest.mark.slow
@pytest.mark.parametrize("case", list(OUT_OF_LIBRARY_CASES))
def test_effect_outside_the_library_is_not_attributed(case):
    """Issue 5 item 5: an effect the library does not have (the amplifier's lag between the logged torque command
    and the motor torque) leaves structure no candidate removes: nothing may be named, the report must say that the
    residual stays far above the noise and where it sits."""
    d = diagnose(out_of_library_log(case, 4.0), resolution_pulses=0, workers=2)
    assert d.effects == [], d.to_frame()
    assert d.unexplained and all(u["regime"] and "no library effect" in u["detail"] for u in d.unexplained)
    assert d.steps[-1].extra["residual_over_noise_load"] > 100
    assert any("x the load sensor noise" in n for n in d.notes)


def test_cli_json_and_report(tmp_path):
    from ident.cli import main

    log = hidden_effect_log("clean", 2.0)
    path = tmp_path / "log.csv"
    write_log(log, path)
    out = tmp_path / "out"
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["diagnose", str(path), "--json", "--out", str(out), "--max-effects", "0", "--pulses", "50"])
    assert code == 0
    data = json.loads(buf.getvalue())
    assert {"steps", "effects", "unexplained", "fmu"} <= set(data)
    step = data["steps"][0]
    assert step["added"] is None and {"nrmse_load", "nrmse_motor", "relative_error_pct", "score"} <= set(step)
    assert step["nrmse_load"] < 1e-3 and step["predicted_resolution_m"] > 0   # the CLI's JSON is SI
    assert (out / "diagnosis.md").is_file() and (out / "residual_vs_time.png").is_file()
    # the exported FMU carries the fitted values as start values and simulates with them
    from fmpy import read_model_description

    md = read_model_description(data["fmu"])
    starts = {v.name: v.start for v in md.modelVariables}
    assert math.isclose(float(starts["K_s"]), data["steps"][-1]["params"]["K_s"], rel_tol=1e-12)


def test_bad_input():
    log = hidden_effect_log("clean", 1.0)
    from dataclasses import replace

    with pytest.raises(LogError, match="load_pos_rad"):
        diagnose(replace(log, load_pos_rad=None))
    with pytest.raises(ValueError, match="unknown effect"):
        diagnose(log, candidates=("magic",))
    with pytest.raises(ValueError, match="model"):
        diagnose(log, model="three-inertia")
    other = replace(log, time_s=np.arange(log.n) / 1000.0, meta=replace(log.meta, sample_rate_hz=1000.0))
    with pytest.raises(LogError, match="sample rate"):
        diagnose(log, holdout=other)


def test_identify_with_an_effect_from_scratch():
    """``identify.fit_pipeline`` with an effect in the model (what a candidate 'from scratch' and the convergence
    of an accepted effect run): from the effect's library starting points alone, the hidden viscous load friction and
    the drive's K*, J_l*, f_l* come back to the generating values."""
    from ident.diagnosis.engine import EffectProblem
    from ident.fitting.identify import fit_pipeline, identify

    log = hidden_effect_log("viscous_load", 1.5)
    base = identify(log).params  # the base model (bent: it lacks the damping); only its meta data matter here
    rows = np.array(EFFECTS["viscous_load"].starts)
    problem, theta, _, _, stages = fit_pipeline(log, base, EffectProblem.maker(("viscous_load",), base), rows)
    try:
        p = problem.params(theta)
    finally:
        problem.close()
    truth = DriveParams()
    assert abs(p.b_l - 1.0) < 1e-3
    for name in ("K_star", "J_l_star", "f_l_star"):
        assert abs(getattr(p, name) / getattr(truth, name) - 1) < 1e-3, name


@pytest.mark.slow
@pytest.mark.parametrize("ratio,v_s", [(0.7, 5e-5), (0.35, 2e-4), (0.5, 1e-4), pytest.param(1.2, 3e-4, marks=(
    pytest.mark.xfail(strict=False, reason="measured 2026-11-22 (still failing 2026-11-23): the first window (1.5 s) "
                      "fits s 0.87, v_s 8.6e-4 to its noise; the later windows cannot leave that basin (ends at "
                      "s 0.91, load NRMSE 13 %)")))])
def test_stribeck_candidate_from_scratch(ratio, v_s):
    """A Stribeck candidate identified from scratch (what the diagnosis runs when the base model leans on a bound)
    recovers generating values that are not among the library's starting points: the static/Coulomb ratio within
    10 %, v_s within a factor 1.5, K*, J_l*, f_l* within 1 %."""
    from ident.diagnosis.engine import FRESH_STAGE_ITER, EffectProblem, split_training, truncate_log
    from ident.fitting.identify import fit_pipeline, identify
    from ident.fitting.synthetic import diagnosis_excitation, synthetic_log

    truth = DriveParams().with_values(stribeck_ratio=ratio, stribeck_velocity=v_s)
    log = synthetic_log(truth, diagnosis_excitation(truth, 4.0, 5000.0, seed=3), duration_s=4.0, seed=5,
                        load_offset_rad=1e-3)
    train = truncate_log(*split_training(log, None))
    base = identify(train).params
    rows = np.array(EFFECTS["stribeck"].starts)
    problem, theta, _, _, _ = fit_pipeline(train, base, EffectProblem.maker(("stribeck",), base), rows,
                                           stage_iter=FRESH_STAGE_ITER)
    try:
        p = problem.params(theta)
    finally:
        problem.close()
    assert abs(p.stribeck_ratio / ratio - 1) < 0.1, p.stribeck_ratio
    assert 1 / 1.5 < p.stribeck_velocity / v_s < 1.5, p.stribeck_velocity
    for name in ("K_star", "J_l_star", "f_l_star"):
        assert abs(getattr(p, name) / getattr(truth, name) - 1) < 0.01, name


def test_extra_scan_steps_each_effect_jointly():
    """The continuation's scan of effect unknowns: per effect a product grid (log-variables +-0.55, +-1.1; others
    +-15 %, +-30 % of their value), the base unknowns untouched; the identifier's own problem has none."""
    from ident.diagnosis.engine import EffectProblem
    from ident.fitting.identify import OutputError

    log = hidden_effect_log("clean", 0.3)
    with_effects = EffectProblem(log, DriveParams(), ("stribeck", "hardening"), 500, 1e-8)
    plain = OutputError(log, DriveParams(), 500, 1e-8)
    try:
        theta = np.array([13.8, 7.8, -2.3, 0.1, 0.5, -4.6, 0.2])
        steps = np.array(with_effects.extra_scan(theta))
        assert plain.extra_scan(theta[:4]) == []
    finally:
        with_effects.close()
        plain.close()
    assert steps.shape == (5 * 5 - 1 + 4, 7) and not steps[:, :4].any()
    stribeck, hardening = steps[:24], steps[24:]
    assert not stribeck[:, 6].any() and not hardening[:, 4:6].any()
    assert sorted(set(np.round(stribeck[:, 5], 6))) == [-1.1, -0.55, 0.0, 0.55, 1.1]
    assert sorted(set(np.round(stribeck[:, 4], 6))) == [-0.15, -0.075, 0.0, 0.075, 0.15]
    assert sorted(np.round(hardening[:, 6], 6)) == [-0.06, -0.03, 0.03, 0.06]


def test_a_point_the_fmu_cannot_simulate_scores_inf_in_grids():
    """Grids and scans score every point; one where the FMU's state overflows (here a far too hard spring, the corner
    a from-scratch hardening candidate reached on the Stribeck log) must rank last, not abort the candidate, while
    the residuals themselves still raise (IPOPT treats that as an evaluation error and steps back)."""
    from ident.diagnosis.engine import EffectProblem
    from ident.model.plant import PlantError

    problem = EffectProblem(hidden_effect_log("clean", 0.5), DriveParams(), ("hardening",), 2000, 1e-8)
    try:
        wild = np.array([9.36863, 13.8155, 2.71448, -5.10527, 219.5])
        assert problem.cost(wild) == math.inf
        with pytest.raises(PlantError, match="overflowed"):
            problem.residuals(wild)
        assert math.isfinite(problem.cost(np.array([math.log(1e6), math.log(2500.0), math.log(0.1), 0.0, 0.0])))
    finally:
        problem.close()


def test_a_refreshed_step_reports_its_new_models_metrics():
    """A step re-recorded after a better-converged model replaced its model passes its old extras along; the
    metrics must be the new model's (a stale residual/noise of 233,115 was reported beside an NRMSE of 1.4e-4)."""
    from ident.diagnosis.engine import EffectProblem, diagnosis_step, evaluate_model

    log = hidden_effect_log("clean", 0.5)
    problem = EffectProblem(log, DriveParams(), (), 1500, 6.7e-9)
    try:
        model = evaluate_model(log, problem, np.array([math.log(1e6), math.log(2500.0), math.log(0.1), 0.0]), 6.7e-9)
    finally:
        problem.close()
    step = diagnosis_step(None, model, None, pd.DataFrame(), 0, {"residual_over_noise_load": 233115.0, "refreshed": True})
    m = model.metrics
    assert step.extra["refreshed"] and step.extra["residual_over_noise_load"] == m["residual_over_noise_load"]
    assert math.isclose(m["residual_over_noise_load"] * 6.7e-9 / step.nrmse_load, np.std(log.load_pos_rad))


def test_candidates_out_of_time_are_reported_not_named():
    """When the candidates' fits run out of their time budget, nothing is named in their place: the candidate
    table gives the reason, and the diagnosis says it cannot rule them out and where the residual sits."""
    d = diagnose(hidden_effect_log("hardening", 2.0), resolution_pulses=0, export_fmu=False,
                 candidates=("hardening", "viscous_load"), candidate_budget_s=1e-3)
    assert d.effects == [] and len(d.steps) == 1
    table = d.steps[0].candidates
    assert sorted(set(table.candidate)) == ["hardening", "viscous_load"]
    assert table.error.str.contains("time budget of 0.001 s").all()
    assert any("hardening, viscous_load could not be fitted" in n and "cannot rule them out" in n for n in d.notes)
    assert d.unexplained
