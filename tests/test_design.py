"""`hdrive design-experiment` (issue 21, item 6): a torque schedule, robust over a range of drives, and the bounds it
achieves; logs simulated by the independent reference generator from that schedule identify all three parameters
within their predicted bounds."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ident.fitting.design import LEVELS, Block, information, schedule
from ident.fitting.identify import NAMES, identify
from ident.model.params import DriveParams
from tests.ident_support import read_back, scheduled_log
from tests.reference.generator.plant import Drive

META = {"r": 0.01, "J_m_kgm2": 2e-5, "f_m_Nm": 0.01, "arm_length_m": 0.3, "encoder_counts_per_rev": 12566,
        "sample_rate_hz": 2000.0}
NOISE_M = 5e-9
MAX_TORQUE = 0.03  # 3 f_m: the family's 4 f_m pulses are not allowed


@pytest.fixture(scope="module")
def designed(tmp_path_factory) -> tuple[pd.DataFrame, dict, subprocess.CompletedProcess]:
    folder = tmp_path_factory.mktemp("design")
    (folder / "drive.json").write_text(json.dumps(META))
    proc = subprocess.run([sys.executable, "-m", "ident", "design-experiment", "--meta", str(folder / "drive.json"),
                           "--max-torque", str(MAX_TORQUE), "--max-travel", "0.02", "--duration", "3",
                           "--noise-m", str(NOISE_M), "--out", str(folder / "plan"), "--json"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return pd.read_csv(folder / "plan" / "schedule.csv"), json.loads((folder / "plan" / "design.json").read_text()), proc


def test_the_schedule_and_its_report(designed) -> None:
    table, report, proc = designed
    assert list(table.columns) == ["time_s", "motor_torque_Nm"] and len(table) == 3 * META["sample_rate_hz"]
    assert np.allclose(np.diff(table["time_s"]), 1 / META["sample_rate_hz"])
    assert table["motor_torque_Nm"].abs().max() <= MAX_TORQUE + 1e-12
    block = report["block"]
    assert block["pulse_star"] * META["f_m_Nm"] <= MAX_TORQUE and block["pulse_star"] in LEVELS["pulse_star"]
    bounds = pd.DataFrame(report["bounds"])
    assert set(bounds["kind"]) == {"prior", "corner"} and len(bounds) == 16
    assert (bounds["travel_rad"] <= 0.02).all()
    worst = report["worst_relative_bound"]
    assert set(worst) == set(NAMES) and all(0 < v < 0.01 for v in worst.values()), worst
    assert json.loads(proc.stdout)["files"]["schedule.csv"].endswith("schedule.csv")
    assert "designing over 8 drives" in proc.stderr


def test_bad_design_options_are_named_before_the_work(tmp_path) -> None:
    (tmp_path / "drive.json").write_text(json.dumps(META))
    proc = subprocess.run([sys.executable, "-m", "ident", "design-experiment", "--meta", str(tmp_path / "drive.json"),
                           "--max-torque", "0.001", "--max-travel", "0.02", "--duration", "3", "--out",
                           str(tmp_path / "plan")], capture_output=True, text=True)
    assert proc.returncode == 2 and "--max-torque = 0.001 N m: the smallest pulse of the family" in proc.stderr
    assert not (tmp_path / "plan").exists()


def _drives(count: int, seed: int = 21) -> list[Drive]:
    """Random drives in the issue's ranges (log-uniform), with the sidecar's known J_m, f_m, r, arm, encoder."""
    rng = np.random.default_rng(seed)
    known = {"J_m": META["J_m_kgm2"], "f_m": META["f_m_Nm"], "r": META["r"], "arm_length": META["arm_length_m"],
             "encoder_counts_per_rev": META["encoder_counts_per_rev"]}
    return [Drive.from_nondim(10 ** rng.uniform(5, 7), 10 ** rng.uniform(math.log10(500), 4),
                              10 ** rng.uniform(-2, 0), **known) for _ in range(count)]


def _identified_within_predicted_bounds(designed, drive: Drive, seed: int, tmp_path: Path) -> None:
    table, _, _ = designed
    torque = table["motor_torque_Nm"].to_numpy()
    g = scheduled_log(drive, torque, META["sample_rate_hz"], NOISE_M, seed=seed, offset_rad=1e-3,
                      d0_fraction=0.4 * (-1) ** seed)
    fit = identify(read_back(g, tmp_path))
    params = DriveParams.from_nondim(drive.K_star, drive.J_l_star, drive.f_l_star, J_m=drive.J_m, f_m=drive.f_m,
                                     r=drive.r, arm_length=drive.arm_length,
                                     encoder_counts_per_rev=drive.encoder_counts_per_rev)
    info, _ = information(params, torque, META["sample_rate_hz"], NOISE_M / drive.arm_length)
    predicted = np.sqrt(np.diag(np.linalg.inv(info)))
    assert fit.identifiable, fit.warnings
    for i, name in enumerate(NAMES):
        err = math.log(fit.estimates[name].value / getattr(drive, name))
        assert abs(err) <= 3 * predicted[i], (name, err, predicted[i])


@pytest.mark.parametrize("index", range(2))
def test_designed_schedule_identifies_random_drives(designed, index, tmp_path) -> None:
    _identified_within_predicted_bounds(designed, _drives(10)[index], index, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("index", range(2, 10))
def test_designed_schedule_identifies_random_drives_slow(designed, index, tmp_path) -> None:
    _identified_within_predicted_bounds(designed, _drives(10)[index], index, tmp_path)


def test_block_timing() -> None:
    b = Block(pulse_star=2.5, width_s=1e-3, move_star=1.2, hold_s=0.05, rest_s=0.2)
    tau = b.torque_star(1000.0)
    assert tau.size == round(b.seconds() * 1000) and tau.max() == 2.5 and tau.min() == -2.5
    assert schedule(b, 0.01, 1000.0, 2.0).size == 2000
