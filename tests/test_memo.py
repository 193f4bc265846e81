"""Simulations kept for the process (``ident.fitting.memo``) change no answer, only how long it takes.

Logs from the independent generator (seeds 4304-4305, in neither the product nor its other tests). A fit or a
diagnosis runs with every simulation run and again with simulations kept, and everything it reports must be equal to
the last bit; a kept simulation is charged to a budget what it cost when it ran (counted in simulations and in the
FMU's work); a trajectory handed out twice cannot be written into.
"""
from __future__ import annotations

import numpy as np
import pytest

import ident.fitting.ahead as ahead
import ident.fitting.memo as memo
from ident.diagnosis.engine import diagnose
from ident.fitting.identify import BudgetExceeded, EvaluationBudget, OutputError, base_params, identify
from tests.diagnosis_matrix import Case, load
from tests.ident_support import read_back
from tests.reference.generator import identification_case


@pytest.fixture(autouse=True)
def _fresh(monkeypatch):
    """Each test starts with nothing kept and the helper thread off (its own test: test_ahead.py)."""
    monkeypatch.setattr(ahead, "MODE", "off")
    memo.forget()
    yield
    memo.forget()


def _runs(monkeypatch, fit):
    """``fit()`` with every simulation run, then with simulations kept (from none): both outputs and the kept
    simulations found during the second."""
    monkeypatch.setattr(memo, "MODE", "off")
    alone = fit()
    monkeypatch.setattr(memo, "MODE", "on")
    before = memo.hits()
    kept = fit()
    return alone, kept, memo.hits() - before


def test_identify_gives_the_same_fit_with_and_without_kept_simulations(tmp_path, monkeypatch) -> None:
    log = read_back(identification_case(4304, "steps", duration_s=2.0), tmp_path)
    alone, kept, hits = _runs(monkeypatch, lambda: identify(log))
    assert hits > 0   # the fit asked again for points an earlier problem of it had simulated
    np.testing.assert_array_equal(kept.theta, alone.theta)
    assert kept.sigma_load_rad == alone.sigma_load_rad
    assert repr(kept.stages) == repr(alone.stages) and repr(kept.start) == repr(alone.start)
    assert {k: e.value for k, e in kept.estimates.items()} == {k: e.value for k, e in alone.estimates.items()}


def test_a_diagnosis_gives_the_same_answer_with_and_without_kept_simulations(monkeypatch) -> None:
    """A 1 s torque-step log with a hidden hardening, one candidate refitted and its size searched (probes start
    where the refit ended): the same names, sizes, intervals, candidate tables, notes and summary."""
    log, _ = load(Case("single", 4305, "hardening", "strong", "steps"), duration_s=1.0, rate_hz=5000.0)
    alone, kept, hits = _runs(monkeypatch, lambda: diagnose(log, resolution_pulses=0, export_fmu=False, workers=0,
                                                            candidates=("hardening",)))
    assert hits > 0 and [e.name for e in kept.effects] == ["hardening"] and kept.effects[0].size_check
    assert [(e.name, e.magnitude, e.ci95, e.tentative) for e in kept.effects] == \
        [(e.name, e.magnitude, e.ci95, e.tentative) for e in alone.effects]
    for a, b in zip(kept.steps, alone.steps):
        assert a.candidates.to_json() == b.candidates.to_json() and a.screen.to_json() == b.screen.to_json()
    assert kept.notes == alone.notes and kept.summary == alone.summary
    assert kept.fingerprint() == alone.fingerprint()   # and so is every other number and sentence


@pytest.mark.parametrize("unit", [None, 0.5], ids=["simulations", "work"])
def test_a_kept_simulation_is_charged_what_it_cost_when_it_ran(tmp_path, monkeypatch, unit) -> None:
    """A central-difference Jacobian (8 simulations) under a budget of 5.5 simulations' samples (or of the FMU's
    work, ``unit``, which charges each simulation more than its samples): the same simulations charged, to the last
    bit, and the same one refused, whether its points were simulated then or kept from another problem's Jacobian at
    the same point."""
    log = read_back(identification_case(4304, "steps", duration_s=2.0), tmp_path)
    base = base_params(log)
    theta = np.array([np.log(base.K_star), np.log(base.J_l_star), np.log(base.f_l_star), 0.0])
    runs = []
    for mode in ("off", "on"):
        monkeypatch.setattr(memo, "MODE", mode)
        full, limited = OutputError(log, base), OutputError(log, base)
        limited.budget = EvaluationBudget(limit=5.5 * limited.stop * (1.0 if unit is None else 6.5), unit=unit)
        try:
            jac = full.jacobian(theta)
            hits = memo.hits()
            with pytest.raises(BudgetExceeded):
                limited.jacobian(theta)
            runs.append((jac, limited.budget.used, limited.evaluations, memo.hits() - hits))
        finally:
            full.close()
            limited.close()
    (jac_off, used_off, n_off, hits_off), (jac_on, used_on, n_on, hits_on) = runs
    np.testing.assert_array_equal(jac_on, jac_off)
    assert (used_on, n_on) == (used_off, n_off) and hits_off == 0 and hits_on == n_on > 0
    if unit is None:
        assert used_on == 5.0 * limited.stop
    else:
        assert used_on > 5.0 * limited.stop   # charged the FMU's work: more than one per sample


def test_a_kept_trajectory_cannot_be_written_into(tmp_path) -> None:
    log = read_back(identification_case(4304, "steps", duration_s=2.0), tmp_path)
    base = base_params(log)
    problem = OutputError(log, base)
    try:
        start = dict(q_m_start=0.0, q_l_start=0.0, v_m_start=0.0, v_l_start=0.0)
        key = memo.digest(problem.torque)
        first = memo.positions(problem.plant, base, start, problem.torque, key, log.dt)
        again = memo.positions(problem.plant, base, start, problem.torque, key, log.dt)
        assert again[0] is first[0]   # handed out from the memo, not run again
        with pytest.raises(ValueError):
            again[0][0] = 1.0
        # -0.0 and 0.0 are different keys: the memo never equates two values the FMU could tell apart
        moved = memo.positions(problem.plant, base, {**start, "v_l_start": -0.0}, problem.torque, key, log.dt)
        assert moved[0] is not first[0]
    finally:
        problem.close()
