"""DriveParams (SI <-> non-dimensional, validation) and the command line (build-fmu, demo, --json)."""
from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

import pandas as pd
import pytest

from ident import DriveParams, ParameterError
from ident.cli import main


def test_nominal_drive_groups() -> None:
    p = DriveParams.nominal()
    assert (p.K_star, p.J_l_star, p.f_l_star, p.r) == pytest.approx((1e6, 2500, 0.1, 0.01))
    assert p.T_c == pytest.approx(44.72e-3, rel=1e-3)
    assert 1e-3 / p.T_c == pytest.approx(0.02236, rel=1e-3)  # W*


def test_nondimensional_round_trip() -> None:
    p = DriveParams.from_nondim(K_star=3e5, J_l_star=800, f_l_star=0.5, J_m=1e-4, f_m=0.02)
    assert (p.K_s, p.J_l, p.f_l) == pytest.approx((6e3, 0.08, 0.01))
    q = p.with_values(f_l_star=0.25, J_m=2e-4)
    assert q.f_l_star == pytest.approx(0.25) and q.J_m == 2e-4 and q.J_l == pytest.approx(0.08)


def test_bad_parameters_name_the_problem() -> None:
    with pytest.raises(ParameterError, match=r"r = 2 is outside the allowed range \[1e-06, 1\]"):
        DriveParams(r=2)
    with pytest.raises(ParameterError, match="encoder_counts_per_rev = 10.5 must be a whole number"):
        DriveParams(encoder_counts_per_rev=10.5)
    with pytest.raises(ParameterError, match="f_m must be > 0"):
        DriveParams(f_m=0.0).T_c


def test_cli_build_fmu_prints_path(tmp_path: Path, capsys) -> None:
    assert main(["build-fmu", "--fmi", "3", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out.strip()
    assert printed == str(tmp_path / "HarmonicDrive.fmu")
    with zipfile.ZipFile(printed) as zf:
        assert 'fmiVersion="3.0"' in zf.read("modelDescription.xml").decode()


def test_cli_demo_writes_csv_png_and_json(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, "-m", "ident.cli", "demo", "--out", str(out), "--pulses", "3", "--json"],
                          capture_output=True, text=True, check=True)
    summary = json.loads(proc.stdout)
    df = pd.read_csv(out / "pulse_train.csv")
    assert list(df.columns[:4]) == ["time_s", "motor_torque_Nm", "motor_pos_rad", "load_pos_rad"]
    assert {"arm_position_m", "encoder_count", "v_m_rad_s", "motor_stuck"} <= set(df.columns)
    assert (out / "pulse_train.png").stat().st_size > 10_000 and (out / "pulse_train.json").is_file()
    assert len(summary["increments_m"]) == 3 and all(x > 0 for x in summary["increments_m"])
    # increments are arm motion between rests, so they add up to the final arm position
    assert sum(summary["increments_m"]) == pytest.approx(df["arm_position_m"].iloc[-1], rel=1e-9)


def test_cli_rejects_bad_parameter(capsys) -> None:
    assert main(["demo", "--out", "unused", "--param", "K_s=-5"]) == 2
    err = capsys.readouterr().err
    assert "K_s = -5" in err and "allowed range" in err
    assert not Path("unused").exists()


@pytest.mark.parametrize("command", ["", "build-fmu", "demo", "resolution", "sweep", "study", "identify", "predict",
                                     "emps-report"])
def test_help_of_every_command(command: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "ident.cli", *([command] if command else []), "--help"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert "usage: hdrive" in proc.stdout
