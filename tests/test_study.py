"""Friction sweep, Dask execution, the study report and the resolution / sweep / study commands."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ident import DriveParams
from ident.cli import main
from ident.common.units import non_si_keys
from ident.protocols.resolution import impulse_resolution
from ident.protocols.sweep import friction_levels, friction_sweep
from ident.studies.paper import PAPER, write_study


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ident.cli", *args], capture_output=True, text=True)


def test_friction_levels_are_the_papers() -> None:
    f = friction_levels(25)
    assert f[0] == pytest.approx(0.01) and f[12] == pytest.approx(0.1) and f[-1] == pytest.approx(1.0)
    np.testing.assert_allclose(np.diff(np.log10(f)), 2 / 24)


def test_sweep_on_a_local_dask_cluster_equals_the_serial_run() -> None:
    """A real dask.distributed LocalCluster with separate worker processes gives exactly the serial results."""
    from dask.distributed import LocalCluster

    levels = [0.01, 0.1, 0.5, 1.0]
    serial = friction_sweep(levels=levels, n_pulses=60, workers=0)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        remote = friction_sweep(levels=levels, n_pulses=60, scheduler=cluster.scheduler_address)
    for a, b in zip(serial.results, remote.results):
        assert a.threshold_amplitude == b.threshold_amplitude
        np.testing.assert_array_equal(a.increments_m, b.increments_m)
    df = serial.to_frame()
    assert list(df["f_l_star"]) == levels and (df["resolution_um"] >= df["median_um"]).all()
    # each level is the single-drive protocol with f_l* changed, nothing else
    single = impulse_resolution(DriveParams().with_values(f_l_star=0.5), n_pulses=60)
    np.testing.assert_array_equal(single.increments_m, serial.results[2].increments_m)


def test_resolution_command_json_impulse(tmp_path: Path) -> None:
    """Summary figures in SI by default; every increment only with --increments (JSON) or --out (CSV); progress on
    stderr although --json is given."""
    proc = run_cli("resolution", "--controller", "impulse", "--pulses", "40", "--fl-star", "0.2", "--json",
                   "--out", str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    for key in ("resolution_m", "median_m", "min_m", "std_m", "threshold_amplitude", "operating_amplitude",
                "max_pulse", "transient_end_pulse", "steady_max_m"):
        assert key in d
    assert "increments_m" not in d and len(proc.stdout.splitlines()) < 60
    csv = pd.read_csv(d["csv"])
    assert len(csv) == 40 and d["resolution_m"] == csv["increment_m"].max()
    assert d["operating_amplitude"] == pytest.approx(d["threshold_amplitude"] * 1.01)
    assert d["f_l_star"] == pytest.approx(0.2)
    assert "impulse protocol" in proc.stderr   # the progress bar
    proc = run_cli("resolution", "--controller", "impulse", "--pulses", "40", "--fl-star", "0.2", "--json",
                   "--increments")
    e = json.loads(proc.stdout)
    assert e["increments_m"] == csv["increment_m"].tolist() and e["resolution_m"] == max(e["increments_m"])


def test_resolution_command_json_linear() -> None:
    proc = run_cli("resolution", "--controller", "linear", "--steps", "30", "--param", "K_s=2e4", "--json",
                   "--increments")
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    assert d["counts"] >= 1 and len(d["increments_m"]) == 30
    assert min(d["increments_m"]) > 0.1e-6 and d["params"]["K_s"] == 2e4
    assert "linear protocol" in proc.stderr


def test_sweep_command_writes_csv_and_plots(tmp_path: Path) -> None:
    proc = run_cli("sweep", "--levels", "3", "--pulses", "30", "--workers", "0", "--out", str(tmp_path), "--json")
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    assert len(d["levels"]) == 3 and {"slope_m", "r2"} <= set(d["trend"])
    assert d["levels"][1]["resolution_m"] == pytest.approx(
        pd.read_csv(tmp_path / "sweep.csv")["resolution_um"][1] * 1e-6, rel=1e-12)
    for name in ("increments_fl0.1", "delta_vs_friction", "std_vs_friction"):
        assert (tmp_path / f"{name}.png").stat().st_size > 5000
    assert sorted(p.name for p in tmp_path.glob("*.png")) == ["delta_vs_friction.png", "increments_fl0.1.png",
                                                                "std_vs_friction.png"]
    assert (tmp_path / "sweep.csv").read_text().startswith("f_l_star,")


def test_study_report(tmp_path: Path) -> None:
    out = tmp_path / "study"
    study, report = write_study(out, n_pulses=60, n_steps=30, levels=5, workers=0)
    text = report.read_text()
    for section in ("## Findings", "## Paper vs model", "## Glossary", "## Drive", "## III. Linear", "## IV. Impulse",
                    "**Start-up transient.**", "## V. Friction sweep", "## Why the base model behaves this way"):
        assert section in text
    for png in ("linear.png", "impulse.png", "delta_vs_friction.png", "std_vs_friction.png"):
        assert f"({png})" in text and (out / png).is_file()
    # the nominal drive's own level is f_l* = 0.1: its histogram and sequence are section IV's, not drawn twice
    assert sorted(p.name for p in out.glob("*.png")) == ["delta_vs_friction.png", "impulse.png", "linear.png",
                                                           "std_vs_friction.png"]
    assert "(`impulse.png`), not drawn twice" in text
    cmp = study.comparison()
    assert "3 µm (two counts)" in set(cmp["paper"]) and PAPER["impulse_resolution_um"] == 0.30
    assert f"{study.impulse.resolution_m * 1e6:.3f} µm" in text  # the table reports what the model gave
    assert "Study of Resolution for Harmonic Drives Controller with Friction in Precision Robotic System" in text
    assert "docs/physics.md" in text and "../shared" not in text
    assert re.search(r"(?<![-\w])um\b", text) is None   # µm, never "um"
    assert "| encoder counts per rev | 12566 |" in text
    summary = json.loads((out / "summary.json").read_text())
    assert summary["impulse"]["threshold_amplitude"] == study.impulse.threshold_amplitude
    assert non_si_keys(summary) == [] and summary["trend"]["slope_m"] == pytest.approx(
        study.sweep.trend()["slope_um"] * 1e-6)


def test_failed_study_leaves_no_report(tmp_path: Path, monkeypatch) -> None:
    """A study that fails while writing leaves neither a report nor its staging folder behind."""
    import ident.studies.paper as report

    real = report.write_report

    def write_then_fail(study, out_dir):
        real(study, out_dir)  # every file is written into the staging folder ...
        raise OSError("disk full")  # ... and then something goes wrong

    monkeypatch.setattr(report, "write_report", write_then_fail)
    out = tmp_path / "study"
    with pytest.raises(OSError, match="disk full"):
        write_study(out, n_pulses=20, n_steps=10, levels=2, workers=0)
    assert not out.exists() or not any(out.iterdir())
    assert [p.name for p in tmp_path.iterdir() if p.name != "study"] == []


@pytest.mark.parametrize("args,message", [
    (["resolution", "--controller", "impulse", "--pulses", "0"], "--pulses = 0: must be >= 1"),
    (["resolution", "--controller", "linear", "--param", "K=1"], "unknown drive parameter 'K'"),
    (["resolution", "--controller", "impulse", "--fl-star", "-1"], "f_l"),
    (["resolution", "--controller", "impulse", "--eps1-um", "1e5", "--pulses", "5"],
     "no pulse amplitude up to tau* = 20"),
])
def test_bad_input_is_named(args: list[str], message: str, capsys) -> None:
    assert main(args) == 2
    assert message in capsys.readouterr().err
