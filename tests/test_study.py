"""Friction sweep, Dask execution, the study report and the resolution / sweep / study commands."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ident import DriveParams
from ident.cli import main
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
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        remote = friction_sweep(levels=levels, n_pulses=60, scheduler=cluster.scheduler_address)
    for a, b in zip(serial.results, remote.results):
        assert a.threshold_amplitude == b.threshold_amplitude
        np.testing.assert_array_equal(a.increments_m, b.increments_m)
    df = serial.to_frame()
    assert list(df["f_l_star"]) == levels and (df["resolution_um"] >= df["median_um"]).all()
    # each level is the single-drive protocol with f_l* changed, nothing else
    single = impulse_resolution(DriveParams().with_values(f_l_star=0.5), n_pulses=60)
    np.testing.assert_array_equal(single.increments_m, serial.results[2].increments_m)


def test_resolution_command_json_impulse() -> None:
    proc = run_cli("resolution", "--controller", "impulse", "--pulses", "40", "--fl-star", "0.2", "--json")
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    for key in ("resolution_um", "median_um", "min_um", "std_um", "increments_um", "threshold_amplitude",
                "operating_amplitude"):
        assert key in d
    assert len(d["increments_um"]) == 40 and d["resolution_um"] == max(d["increments_um"])
    assert d["operating_amplitude"] == pytest.approx(d["threshold_amplitude"] * 1.01)
    assert d["f_l_star"] == pytest.approx(0.2)


def test_resolution_command_json_linear() -> None:
    proc = run_cli("resolution", "--controller", "linear", "--steps", "30", "--param", "K_s=2e4", "--json")
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    assert d["counts"] >= 1 and len(d["increments_um"]) == 30
    assert min(d["increments_um"]) > 0.1 and d["params"]["K_s"] == 2e4


def test_sweep_command_writes_csv_and_plots(tmp_path: Path) -> None:
    proc = run_cli("sweep", "--levels", "3", "--pulses", "30", "--workers", "0", "--out", str(tmp_path), "--json")
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    assert len(d["levels"]) == 3 and {"slope_um", "r2"} <= set(d["trend"])
    for name in ("histogram_fl0.1", "sequence_fl0.1", "delta_vs_friction", "std_vs_friction"):
        assert (tmp_path / f"{name}.png").stat().st_size > 5000
    assert (tmp_path / "sweep.csv").read_text().startswith("f_l_star,")


def test_study_report(tmp_path: Path) -> None:
    out = tmp_path / "study"
    study, report = write_study(out, n_pulses=60, n_steps=30, levels=5, workers=0)
    text = report.read_text()
    for section in ("## Paper vs model", "## III. Linear", "## IV. Impulse", "## V. Friction sweep",
                    "## Where the base model differs"):
        assert section in text
    for png in ("linear.png", "impulse.png", "histogram_fl0.1.png", "delta_vs_friction.png"):
        assert f"({png})" in text and (out / png).is_file()
    cmp = study.comparison()
    assert "3 um (two counts)" in set(cmp["paper"]) and PAPER["impulse_resolution_um"] == 0.30
    assert f"{study.impulse.resolution_m * 1e6:.3f} um" in text  # the table reports what the model gave
    assert json.loads((out / "summary.json").read_text())["impulse"]["threshold_amplitude"] == \
        study.impulse.threshold_amplitude


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
