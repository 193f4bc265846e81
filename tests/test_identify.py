"""Identification on synthetic logs produced by the FMU (known generating parameters), prediction, CLI, errors.

The 20-random-drive accuracy and coverage study is a benchmark (bench/identify.py), not part of this run.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ident import DriveParams
from ident.fitting.identify import NAMES, IdentificationError, equation_error_start, identify
from ident.fitting.logs import LogError, write_log
from ident.fitting.predict import predict
from ident.fitting.synthetic import synthetic_log
from ident.protocols.resolution import impulse_resolution


@pytest.fixture(scope="module")
def nominal_fit():
    p = DriveParams()
    log = synthetic_log(p, duration_s=4.0, load_offset_rad=7e-6, seed=11)
    return p, log, identify(log)


def test_nominal_drive_within_0_1_percent(nominal_fit) -> None:
    p, _, fit = nominal_fit
    for name in NAMES:
        est = fit.estimates[name]
        assert est.value == pytest.approx(getattr(p, name), rel=1e-3), name
        assert est.ci95[0] < est.value < est.ci95[1] and est.std > 0
    assert fit.params.K_s == pytest.approx(p.K_s, rel=1e-3) and fit.params.J_l == pytest.approx(p.J_l, rel=1e-3)
    assert fit.fit["residual_over_noise"] == pytest.approx(1.0, abs=0.2)  # the fit reaches the sensor's noise
    # the load sensor's zero is found too, up to the encoder's sub-count start position (one count at the load)
    assert abs(fit.load_offset_rad - 7e-6) <= p.r * p.count_rad
    assert fit.warnings == []
    assert fit.correlation.shape == (3, 3) and np.allclose(np.diag(fit.correlation), 1.0)


def test_equation_error_start_is_data_driven(nominal_fit) -> None:
    p, log, fit = nominal_fit
    start = equation_error_start(log, p)
    assert start["w_l2"] == pytest.approx(p.K_s / p.J_l, rel=0.05)  # the free ringing's frequency
    assert start["f_peak_hz"] == pytest.approx(np.sqrt(p.K_s / p.J_l) / (2 * np.pi), rel=0.03)
    assert fit.stages[-1]["window_s"] == pytest.approx(log.time_s[-1], rel=1e-3)  # continuation to the full log


@pytest.mark.parametrize("K_star,J_l_star,f_l_star", [(3e5, 800.0, 0.03), (4e6, 6000.0, 0.6)])
def test_other_drives_within_0_1_percent(K_star: float, J_l_star: float, f_l_star: float) -> None:
    p = DriveParams.from_nondim(K_star, J_l_star, f_l_star)
    fit = identify(synthetic_log(p, duration_s=3.0, seed=3))
    for name in NAMES:
        assert fit.estimates[name].value == pytest.approx(getattr(p, name), rel=1e-3), name


def test_prediction_matches_the_true_plant(nominal_fit) -> None:
    p, _, fit = nominal_fit
    pred = predict(fit, n_draws=3, n_pulses=100, n_steps=40, workers=0)
    truth = impulse_resolution(p, n_pulses=100).resolution_m * 1e6
    assert pred.impulse_resolution_um == pytest.approx(truth, rel=0.05)
    lo, hi = pred.impulse_ci95_um
    assert lo <= hi and len(pred.draws) == 3
    assert pred.linear_counts >= 1 and pred.linear_resolution_um > 0


def test_cli_identify_and_predict_json(tmp_path: Path) -> None:
    p = DriveParams()
    csv, _ = write_log(synthetic_log(p, duration_s=2.0, seed=5), tmp_path / "run.csv")
    proc = subprocess.run([sys.executable, "-m", "ident.cli", "identify", str(csv), "--json"], capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    for name in NAMES:
        assert set(d[name]) >= {"value", "ci95"} and d[name]["value"] == pytest.approx(getattr(p, name), rel=1e-3)
    assert {"K_s_Nm_per_rad", "J_l_kgm2", "f_l_Nm"} <= set(d["si"])
    assert {"nrmse_motor", "nrmse_load", "relative_error_pct"} <= set(d["fit"]) and d["warnings"] == []
    proc = subprocess.run([sys.executable, "-m", "ident.cli", "predict", str(csv), "--draws", "2", "--pulses", "60",
                           "--steps", "30", "--workers", "0", "--json"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    assert set(d["impulse_resolution_m"]) == {"value", "ci95"} and d["impulse_resolution_m"]["value"] > 0
    assert set(d["linear_resolution_m"]) == {"value", "ci95"}   # the CLI's JSON is SI (ident.common.units)


def test_log_without_load_sensor_needs_the_rigid_model() -> None:
    log = synthetic_log(DriveParams(), duration_s=1.0)
    log.load_pos_rad = None
    with pytest.raises(LogError, match="needs the column load_pos_rad"):
        identify(log)


def test_motionless_log_is_refused() -> None:
    log = synthetic_log(DriveParams(), np.zeros(5000))
    with pytest.raises(IdentificationError):
        identify(log)


def test_rigid_model_refuses_a_log_it_cannot_explain() -> None:
    """Pulses through a flexible drive are not rigid-body motion: no confident wrong number."""
    log = synthetic_log(DriveParams(), duration_s=2.0)
    log.load_pos_rad = None
    with pytest.raises(RuntimeError, match="relative error"):
        identify(log, model="rigid")


def test_model_mismatch_widens_the_intervals_and_warns() -> None:
    """An effect the model lacks (a slow 30 nm sway of the load sensor) must show: a warning, and residual-based
    (sandwich) intervals wider than the noise-only Cramer-Rao bound, still covering the truth."""
    p = DriveParams()
    log = synthetic_log(p, duration_s=2.0, seed=4)
    log.load_pos_rad = log.load_pos_rad + 30e-9 / p.arm_length * np.sin(2 * np.pi * 3.0 * log.time_s)
    fit = identify(log)
    assert any("residuals" in w and "missing" in w for w in fit.warnings)
    for i, name in enumerate(NAMES):
        est = fit.estimates[name]
        assert est.std / est.value > 2 * np.sqrt(fit.cov_noise_only[i, i])
        assert est.ci95[0] <= getattr(p, name) <= est.ci95[1], name


def test_rigid_model_on_a_motor_encoder_only_log() -> None:
    """A stiff drive (effectively one body J_m + r^2 J_l, Coulomb f_m + r f_l) driven by a slow sinusoidal torque,
    motor encoder only: the rigid IDIM-LS (sliding rows only) finds the inertia to 2 %, and every parameter's
    residual-based (HAC) interval covers the truth. Viscous and Coulomb friction are hard to separate from one
    sine's sliding phases; the Coulomb estimate is correspondingly uncertain, and the fit says so."""
    from ident.fitting.rigid import rigid_warnings

    p = DriveParams(K_s=1e9, encoder_counts_per_rev=2**20)
    t = np.arange(4 * 5000) / 5000.0
    log = synthetic_log(p, 3 * p.f_m * np.sin(2 * np.pi * 2.0 * t), seed=1)
    log.load_pos_rad = None
    fit = identify(log, model="rigid")
    truth = {"M": p.J_m + p.r**2 * p.J_l, "Fv": 0.0, "Fc": p.f_m + p.r * p.f_l, "offset": 0.0}
    for param in fit.params:
        lo, hi = param.ci95_hac
        assert lo <= truth[param.name] <= hi, (param.name, param.value, param.ci95_hac)
    assert fit.M.value == pytest.approx(truth["M"], rel=0.02)
    assert (fit.Fc.std_hac / fit.Fc.value > 0.1) == any(w.startswith("Fc is poorly") for w in rigid_warnings(fit))


def test_a_fit_leaning_on_a_bound_is_flagged() -> None:
    """A log the base model cannot fit at all (Stribeck friction: breakaway 1.5x the sliding level) drives the fit
    onto the edge of the physical range; the result must say so rather than present the edge as an estimate."""
    from ident.fitting.identify import at_bound
    from ident.fitting.synthetic import hidden_effect_log

    log = hidden_effect_log("stribeck", 2.8)  # the training part of the 4 s diagnosis log
    fit = identify(log)
    leaning = at_bound(fit.theta)
    assert leaning, fit.estimates
    assert all(any(w.startswith(f"{name} = ") and "sits at its bound" in w for w in fit.warnings) for name in leaning)
    assert at_bound(identify(hidden_effect_log("clean", 2.0)).theta) == []
