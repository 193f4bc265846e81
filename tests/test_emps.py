"""EMPS benchmark (ident/studies/emps.py, ident/fitting/rigid.py) on the real data: the published IDIM-LS estimates, the CasADi/IPOPT solution
against lstsq, cross-test validation, closed-loop simulation, report; and the loader's errors."""
from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from ident.fitting.logs import LogError
from ident.fitting.rigid import identify_rigid, idim_system, validate_rigid
from ident.studies.emps import PAPER, advance, emps_report, load_emps, simulate_closed_loop


def _emps_dir() -> Path | None:
    env = os.environ.get("HDRIVE_SHARED")
    candidates = [Path(env) / "data" / "emps", Path(env)] if env else []
    candidates.append(Path(__file__).resolve().parents[2] / "shared" / "data" / "emps")
    for c in candidates:
        if (c / "DATA_EMPS.mat").is_file() and (c / "DATA_EMPS_PULSES.mat").is_file():
            return c
    return None


DATA = _emps_dir()
needs_data = pytest.mark.skipif(
    DATA is None, reason="EMPS data absent: neither $HDRIVE_SHARED/data/emps nor <repo>/../shared/data/emps holds "
                         "DATA_EMPS.mat and DATA_EMPS_PULSES.mat")


@pytest.fixture(scope="module")
def log():
    return load_emps(DATA / "DATA_EMPS.mat")


@pytest.fixture(scope="module")
def log_pulses():
    return load_emps(DATA / "DATA_EMPS_PULSES.mat")


@pytest.fixture(scope="module")
def fit_and_time(log):
    t0 = time.perf_counter()
    fit = identify_rigid(log)
    return fit, time.perf_counter() - t0


@pytest.fixture(scope="module")
def fit(fit_and_time):
    return fit_and_time[0]


# ------------------------------------------------------------------------------------------ loader ------------

@needs_data
def test_loader_builds_a_linear_drive_log(log, log_pulses):
    raw = scipy.io.loadmat(DATA / "DATA_EMPS.mat")
    assert log.kind == "linear" and log.load_pos_rad is None and log.n == raw["t"].size
    np.testing.assert_array_equal(log.motor_pos_rad, raw["qm"].ravel())
    np.testing.assert_allclose(log.motor_torque_Nm, raw["gtau"].item() * raw["vir"].ravel(), rtol=1e-15)
    np.testing.assert_array_equal(log.extra["qg"], raw["qg"].ravel())
    assert log.meta.r == 1.0 and log.meta.arm_length_m == 1.0 and log.meta.J_m_kgm2 is None
    assert log.meta.f_m_Nm is None and log.meta.encoder_counts_per_rev is None
    assert log.meta.sample_rate_hz == pytest.approx(1000.0, rel=1e-6)
    assert set(log.meta_extra) == {"gtau", "kp", "kv"} and log.meta_extra["kp"] == pytest.approx(160.18)
    assert "pulses_N" not in log.extra and set(log_pulses.extra) == {"qg", "pulses_N"}


def test_loader_names_file_and_missing_key(tmp_path):
    bad = tmp_path / "no_vir.mat"
    t = np.arange(500) * 1e-3
    scipy.io.savemat(bad, {"t": t[:, None], "qm": t[:, None], "qg": t[:, None], "gtau": 35.15, "kp": 160.18,
                           "kv": 243.45})
    with pytest.raises(LogError, match=r"no_vir\.mat.*'vir'"):
        load_emps(bad)
    with pytest.raises(LogError, match=r"nowhere\.mat"):
        load_emps(tmp_path / "nowhere.mat")
    short = tmp_path / "short_qm.mat"
    scipy.io.savemat(short, {"t": t[:, None], "qm": t[:-3, None], "qg": t[:, None], "vir": t[:, None],
                             "gtau": 35.15, "kp": 160.18, "kv": 243.45})
    with pytest.raises(LogError, match=r"short_qm\.mat.*'qm' has 497 samples"):
        load_emps(short)


# ------------------------------------------------------------------------------------------ IDIM-LS -----------

@needs_data
def test_idim_ls_reproduces_the_published_estimates(fit, fit_and_time):
    for p in fit.params:
        assert p.value == pytest.approx(PAPER[p.name], rel=0.01), p.name
    assert fit.relative_error_pct <= 4.1
    assert fit.cond == pytest.approx(PAPER["cond"], rel=0.01)
    s = fit.settings
    assert (s.butter_order, s.butter_cutoff_hz, s.decim_factor) == (4, 100.0, 10)
    assert fit.closed_loop_natural_freq_hz <= s.f_dyn_hz       # the PDF's cut-off rules hold for this fit
    assert fit_and_time[1] <= 10.0
    print(f"\nEMPS fit {fit_and_time[1]:.3f} s: M={fit.M.value:.4f} Fv={fit.Fv.value:.4f} Fc={fit.Fc.value:.4f} "
          f"offset={fit.offset.value:.4f} relerr={fit.relative_error_pct:.4f} % cond={fit.cond:.4f}")


@needs_data
def test_casadi_ipopt_equals_lstsq(fit, log):
    system = idim_system(log, fit.settings)
    ref = np.linalg.lstsq(system.X, system.y, rcond=None)[0]
    np.testing.assert_allclose(fit.theta, ref, rtol=1e-6)
    assert fit.solver["solver"] == "casadi/ipopt" and fit.solver["return_status"] == "Solve_Succeeded"


@needs_data
def test_uncertainties_are_consistent(fit):
    for p in fit.params:
        assert p.ci95_ls[0] < p.value < p.ci95_ls[1] and p.ci95_hac[0] < p.value < p.ci95_hac[1]
        assert p.std_ls == pytest.approx(PAPER["std"][p.name], rel=0.02)      # the PDF's printed stds
        assert p.std_hac > p.std_ls                   # correlated misfit (asymmetric friction) widens the HAC
    for c in (fit.corr_ls, fit.corr_hac):
        np.testing.assert_allclose(c, c.T, atol=1e-12)
        np.testing.assert_allclose(np.diag(c), 1.0)
        assert np.all(np.abs(c) <= 1 + 1e-12)
    assert fit.corr_ls[1, 2] < -0.5                   # Fv and Fc trade off
    assert fit.hac_lag >= 1


@needs_data
def test_cross_validation_on_pulses(fit, log_pulses):
    cv = validate_rigid(fit, log_pulses)
    print(f"\nEMPS cross-validation relative error {cv.relative_error_pct:.4f} % (paper 5.98 %)")
    assert math.isfinite(cv.relative_error_pct) and cv.relative_error_pct == pytest.approx(5.98, abs=0.3)
    assert cv.cond == pytest.approx(PAPER["ctv"]["cond"], rel=0.01)


# ------------------------------------------------------------------------------------- closed loop -------------

def test_exact_stick_slip_segment():
    M, Fv, Fc = 95.0, 200.0, 20.0
    T = M / Fv
    q, v, z = advance(0.0, 0.01, 0.0, 1.0, M, Fv, Fc)            # coasts to rest and sticks (|u| = 0 <= Fc)
    tz = T * math.log(1 + 0.01 * Fv / Fc)
    vinf = -Fc / Fv
    assert (v, z) == (0.0, 1)
    assert q == pytest.approx(vinf * tz + (0.01 - vinf) * T * (1 - math.exp(-tz / T)), rel=1e-12)
    assert advance(1.0, 0.0, 19.9, 1e-3, M, Fv, Fc) == (1.0, 0.0, 0)       # below breakaway: stays stuck
    q, v, z = advance(0.0, 0.0, 30.0, 1e-3, M, Fv, Fc)                      # breakaway
    assert v > 0 and q > 0 and z == 0
    q, v, z = advance(0.0, 0.001, -100.0, 1e-2, M, Fv, Fc)                  # reverses through zero
    assert v < 0 and z == 1


@needs_data
@pytest.mark.parametrize("which", ["DATA_EMPS", "DATA_EMPS_PULSES"])
def test_closed_loop_simulation(fit, log, log_pulses, which):
    lg = log if which == "DATA_EMPS" else log_pulses
    sim = simulate_closed_loop(fit, lg)
    err = sim.errors()
    paper = PAPER["sim" if which == "DATA_EMPS" else "sim_pulses"]
    print(f"\n{which} closed loop: " + ", ".join(f"{k} {v:.4g}" for k, v in err.items())
          + f" | paper {paper}")
    assert all(math.isfinite(v) for v in err.values())
    assert err["position_pct"] < 0.05 and err["velocity_pct"] < 1.0 and err["force_pct"] < 10.0
    assert err["acceleration_pct"] < 25.0
    assert sim.n_zero_velocity_events >= 14      # the reference reverses 14 times
    assert np.all(sim.v[sim.stuck] == 0.0)
    delayed = simulate_closed_loop(fit, lg, control_delay_samples=1)
    assert all(math.isfinite(v) for v in delayed.errors().values())


@needs_data
def test_report(tmp_path):
    path = emps_report(tmp_path, DATA)
    text = path.read_text()
    assert (tmp_path / "emps.png").stat().st_size > 10_000 and (tmp_path / "emps.json").is_file()
    for s in ("95.1089", "203.5034", "4.0834", "5.9824", "0.22911", "cross-validation"):
        assert s in text
