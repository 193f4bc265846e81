"""FMI features of the FMU: state get/set/serialize, reset, several instances, validation, fmpy tooling."""
from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

from fmu_build import variables as V
from ident import DriveParams, Plant

PULSES = [(0.03, 1e-3), (0.0, 0.05), (-0.025, 1e-3), (0.0, 0.05)]


def trace(plant: Plant, pieces, dt: float = 1e-3) -> np.ndarray:
    return plant.run(pieces, dt=dt)[["q_m_rad", "q_l_rad", "v_m_rad_s", "v_l_rad_s"]].to_numpy()


@pytest.mark.parametrize("fmi", [2, 3])
def test_rollback_with_fmu_state(fmi: int) -> None:
    """Save the state, run on, restore, run again: bit-identical (serialized state, so it also crosses processes)."""
    with Plant(fmi_version=fmi) as plant:
        plant.run(PULSES[:2], dt=1e-3)
        saved = plant.save_state()
        first = trace(plant, PULSES)
        plant.run([(0.05, 3e-3), (0.0, 0.2)])  # wander off
        plant.restore_state(saved)
        again = trace(plant, PULSES)
        np.testing.assert_array_equal(first, again)
        assert plant.time == pytest.approx(saved.time + sum(d for _, d in PULSES))
    with Plant(fmi_version=fmi) as other:  # a serialized state restores into another instance
        other.restore_state(saved)
        np.testing.assert_array_equal(trace(other, PULSES), first)


@pytest.mark.parametrize("fmi", [2, 3])
def test_serialized_state_from_other_fmu_is_rejected(fmi: int) -> None:
    from ident import PlantError, PlantState

    with Plant(fmi_version=fmi) as plant:
        good = plant.save_state()
        bad = PlantState(good.data[:-8], good.time, fmi)
        with pytest.raises(PlantError, match="wrong size"):
            plant.restore_state(bad)
        corrupt = PlantState(b"XXXX" + good.data[4:], good.time, fmi)
        with pytest.raises(PlantError, match="does not come from this FMU"):
            plant.restore_state(corrupt)


@pytest.mark.parametrize("fmi", [2, 3])
def test_reset_reproduces_the_run(fmi: int) -> None:
    with Plant(fmi_version=fmi) as plant:
        a = trace(plant, PULSES)
        plant.reset()
        b = trace(plant, PULSES)
    np.testing.assert_array_equal(a, b)


def test_instances_are_independent() -> None:
    """Two instances with different parameters, stepped interleaved, equal each one run alone."""
    soft = DriveParams().with_values(K_s=2e3, f_l=5e-3)
    alone_a = trace(Plant(), PULSES)
    alone_b = trace(Plant(soft), PULSES)
    a, b, c = Plant(), Plant(soft), Plant(fmi_version=3)
    rows_a, rows_b, rows_c = [], [], []
    for torque, duration in PULSES:
        n = int(round(duration / 1e-3))
        for _ in range(max(n, 1)):
            for plant, rows in ((a, rows_a), (b, rows_b), (c, rows_c)):
                s = plant.step(torque, duration / max(n, 1))
                rows.append((s.q_m, s.q_l, s.v_m, s.v_l))
    np.testing.assert_array_equal(alone_a[1:], np.array(rows_a))
    np.testing.assert_array_equal(alone_b[1:], np.array(rows_b))
    np.testing.assert_array_equal(alone_a[1:], np.array(rows_c))  # FMI 3 instance: same physics
    assert not np.array_equal(alone_a, alone_b)


def test_fmpy_validate_reports_nothing(fmu_any: Path) -> None:
    assert validate_fmu(str(fmu_any)) == []


def test_model_description_matches_variable_table(fmu_any: Path) -> None:
    md = read_model_description(str(fmu_any))
    assert md.coSimulation.modelIdentifier == "HarmonicDrive"
    by_name = {v.name: v for v in md.modelVariables}
    assert set(by_name) == {v.name for v in V.VARIABLES}
    for var in V.VARIABLES:
        mv = by_name[var.name]
        assert mv.valueReference == var.vr and mv.causality == var.causality
        if var.start is not None:
            assert float(mv.start) == float(var.start), var.name
    with zipfile.ZipFile(fmu_any) as zf:
        names = set(zf.namelist())
        xml = zf.read("modelDescription.xml").decode()
    state = "FMUstate" if md.fmiVersion == "2.0" else "FMUState"  # the capability flags' spelling per version
    assert f'canGetAndSet{state}="true"' in xml and f'canSerialize{state}="true"' in xml
    assert {"sources/model.c", "sources/model.h", "sources/model_vars.h"} <= names
    if md.fmiVersion == "3.0":
        assert "sources/buildDescription.xml" in names


def test_simulate_fmu_with_input_table(fmu_any: Path) -> None:
    """fmpy's own simulate_fmu with an input table gives the same trajectory as ident.Plant."""
    dt = 1e-3
    times = np.arange(0, 0.06 + dt / 2, dt)
    torque = np.where(times < 1e-3 - 1e-12, 0.03, 0.0)
    signals = np.array(list(zip(times, torque)), dtype=[("time", float), ("motor_torque", float)])
    res = simulate_fmu(str(fmu_any), stop_time=0.06, step_size=dt, input=signals,
                       output=["q_m", "q_l", "v_m", "v_l"])
    fmi = 2 if read_model_description(str(fmu_any)).fmiVersion == "2.0" else 3
    with Plant(fmi_version=fmi, fmu_path=fmu_any) as plant:
        ref = trace(plant, [(0.03, 1e-3), (0.0, 0.059)])
    got = np.column_stack([res[k] for k in ("q_m", "q_l", "v_m", "v_l")])
    np.testing.assert_allclose(got, ref[: len(got)], rtol=1e-12, atol=1e-18)


def test_model_evaluations_count_the_work_and_follow_reset_and_state(fmu_any: Path) -> None:
    """The local ``model_evaluations`` (the doSteps' work since initialization, what the diagnosis's budgets count):
    readable by a plain FMI tool (fmpy's simulate_fmu), 0 after initialization, growing with the steps and with a
    costlier model (an effect on: the general propagator), back to 0 on reset, and part of the FMU state."""
    md = read_model_description(str(fmu_any))
    var = next(v for v in md.modelVariables if v.name == "model_evaluations")
    assert var.causality == "local" and var.variability == "discrete"
    res = simulate_fmu(str(fmu_any), stop_time=0.05, step_size=1e-3, output=["model_evaluations"],
                       start_values={"motor_torque": 0.03})
    counts = res["model_evaluations"]
    assert counts[0] == 0 and counts[-1] > 0 and np.all(np.diff(counts) >= 0)
    fmi = 2 if md.fmiVersion == "2.0" else 3
    torque = 0.03 * np.sin(np.arange(400) * 0.05)
    with Plant(fmi_version=fmi, fmu_path=fmu_any) as plant:
        assert plant.model_evaluations() == 0
        plant.positions(torque, 1e-3)
        base = plant.model_evaluations()
        saved = plant.save_state()
        plant.reset(DriveParams().with_values(b_l=1e-4))
        assert plant.model_evaluations() == 0
        plant.positions(torque, 1e-3)
        assert plant.model_evaluations() > 3 * base   # the general propagator's substeps cost more than segments
        plant.restore_state(saved)
        assert plant.model_evaluations() == base


@pytest.mark.skipif(shutil.which("cmake") is None and not Path(sys.executable).with_name("cmake").exists(),
                    reason="fmpy compile needs cmake (pip package 'cmake')")
def test_fmpy_compile_rebuilds_from_the_shipped_sources(fmu_any: Path, tmp_path: Path) -> None:
    """The FMU carries its sources: `fmpy compile` rebuilds a working binary from them alone."""
    copy = tmp_path / "HarmonicDrive.fmu"
    with zipfile.ZipFile(fmu_any) as src, zipfile.ZipFile(copy, "w") as dst:
        for item in src.infolist():
            if not item.filename.startswith("binaries/"):
                dst.writestr(item, src.read(item.filename))
    env_path = str(Path(sys.executable).parent)
    proc = subprocess.run([sys.executable, "-m", "fmpy.cli", "compile", str(copy)], capture_output=True, text=True,
                          env={**__import__("os").environ, "PATH": env_path + ":" + __import__("os").environ["PATH"]})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    fmi = 2 if read_model_description(str(copy)).fmiVersion == "2.0" else 3
    with Plant(fmi_version=fmi, fmu_path=copy) as rebuilt, Plant(fmi_version=fmi, fmu_path=fmu_any) as original:
        np.testing.assert_allclose(trace(rebuilt, PULSES), trace(original, PULSES), rtol=1e-12, atol=1e-18)


def test_fmu_cache_rebuilds_when_the_c_sources_change(tmp_path: Path, monkeypatch) -> None:
    """The cached FMU is keyed by the sources: an edited model.c gives a new build, an unchanged one is reused."""
    import fmu_build.build as build

    monkeypatch.setenv("HDRIVE_CACHE", str(tmp_path / "cache"))
    src = tmp_path / "c"
    shutil.copytree(build.C_DIR, src)
    monkeypatch.setattr(build, "C_DIR", src)
    first = build.build_fmu(fmi_version=2)
    assert build.build_fmu(fmi_version=2) == first  # cache hit
    stamp = first.stat().st_mtime_ns
    (src / "model.c").write_text((src / "model.c").read_text() + "\n/* edited */\n")
    second = build.build_fmu(fmi_version=2)
    assert second != first and second.is_file() and first.stat().st_mtime_ns == stamp
    with zipfile.ZipFile(second) as zf:
        assert "/* edited */" in zf.read("sources/model.c").decode()
