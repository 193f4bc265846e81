"""Simulations run ahead on the second core (``ident.fitting.ahead``) change no answer, only how long it takes.

Logs from the independent generator (seeds 4301-4303, in neither the product nor its other tests). Each fit runs
twice in this process, with the helper thread and without it, and everything the fit reports must be equal to the
last bit: parameters, costs, simulation counts, the stages of the continuation; under an evaluation budget that runs
out in the middle of a Jacobian, the same simulations are charged and the same one is refused. Every simulation runs
here (none is kept for the process, ``ident.fitting.memo``), so that the helper's are compared with the fit's own.
"""
from __future__ import annotations

import threading

import numpy as np
import pytest

import ident.fitting.ahead as ahead
import ident.fitting.memo as memo
from ident.fitting.identify import BudgetExceeded, EvaluationBudget, OutputError, base_params, identify
from tests.ident_support import read_back
from tests.reference.generator import identification_case


@pytest.fixture(autouse=True)
def _every_simulation_runs(monkeypatch):
    """Simulations are not kept here (``memo``, its own test: test_memo.py): the second run of a fit must simulate
    its points again, on the helper's instance, for the comparison to test the helper."""
    monkeypatch.setattr(memo, "MODE", "off")


def _jacobian_point(tmp_path):
    """A 2 s default-design log (seed 4303), its base parameters and the base point of its output-error fit."""
    log = read_back(identification_case(4303, "default", duration_s=2.0), tmp_path)
    base = base_params(log)
    return log, base, np.array([np.log(base.K_star), np.log(base.J_l_star), np.log(base.f_l_star), 0.0])


def _jacobian(log, base, theta) -> np.ndarray:
    problem = OutputError(log, base)
    try:
        return problem.jacobian(theta)
    finally:
        problem.close()


@pytest.mark.parametrize("seed, kind", [(4301, "steps"), (4302, "chirp")])
def test_identify_gives_the_same_fit_with_and_without_the_helper(seed, kind, tmp_path, monkeypatch) -> None:
    log = read_back(identification_case(seed, kind, duration_s=2.0), tmp_path)
    monkeypatch.setattr(ahead, "MODE", "off")
    alone = identify(log)
    monkeypatch.setattr(ahead, "MODE", "on")
    before = ahead.helped()
    helped = identify(log)
    assert ahead.helped() > before   # the helper did run
    np.testing.assert_array_equal(helped.theta, alone.theta)
    assert helped.sigma_load_rad == alone.sigma_load_rad
    assert repr(helped.stages) == repr(alone.stages) and repr(helped.start) == repr(alone.start)
    assert {k: e.value for k, e in helped.estimates.items()} == {k: e.value for k, e in alone.estimates.items()}


def test_a_jacobian_and_a_budget_are_the_same_with_and_without_the_helper(tmp_path, monkeypatch) -> None:
    """The central-difference Jacobian (8 simulations) is equal to the last bit; a budget of 5.5 simulations runs out
    in its middle: the first five are charged and the sixth refused, whether the eight ran ahead or not."""
    log, base, theta = _jacobian_point(tmp_path)
    runs = {}
    for enabled in (False, True):
        monkeypatch.setattr(ahead, "MODE", "on" if enabled else "off")
        problem, limited = OutputError(log, base), OutputError(log, base)
        limited.budget = EvaluationBudget(limit=5.5 * limited.stop)
        before = ahead.helped()
        try:
            jac = problem.jacobian(theta)
            assert (ahead.helped() > before) == enabled   # the helper ran exactly when it was on
            with pytest.raises(BudgetExceeded):
                limited.jacobian(theta)
            runs[enabled] = (jac, (limited.budget.used, limited.evaluations, limited.exhausted))
        finally:
            problem.close()
            limited.close()
    np.testing.assert_array_equal(runs[True][0], runs[False][0])
    assert runs[True][1] == runs[False][1] == (5.0 * log.n, 5, True)


def test_a_task_in_another_thread_uses_the_helper_with_the_same_answer(tmp_path, monkeypatch) -> None:
    """A Dask worker runs its tasks outside the main thread: a fit there uses the helper too (when a core is idle),
    with the Jacobian equal to the last bit."""
    log, base, theta = _jacobian_point(tmp_path)
    monkeypatch.setattr(ahead, "MODE", "on")
    out: dict[str, object] = {}

    def task() -> None:
        before = ahead.helped()
        out["jac"] = _jacobian(log, base, theta)
        out["helped"] = ahead.helped() - before

    worker = threading.Thread(target=task, name="Dask-Worker-Threads'-1")
    worker.start()
    worker.join()
    assert out["helped"] > 0
    monkeypatch.setattr(ahead, "MODE", "off")
    np.testing.assert_array_equal(out["jac"], _jacobian(log, base, theta))
