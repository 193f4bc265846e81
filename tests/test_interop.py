"""Interoperability: third-party FMI importers run HarmonicDrive.fmu exactly as fmpy does.

One piecewise-constant motor-torque schedule (it changes only at communication points) drives the FMU for
200 steps of 1 ms in each importer; q_m, q_l, v_m, v_l and spring_torque must agree with fmpy's run at every
communication point to 1e-12 (relative, with an absolute floor of 1e-12 times the signal's largest magnitude,
for the samples at or near zero), and the discrete outputs (motor_stuck, load_stuck, encoder_count) exactly.

* libcosimpy (libcosim, FMI 2.0 only: it refuses FMI 3.0 FMUs) runs the FMI 2.0 FMU; the input is set through
  an override manipulator before each step and the outputs are read from a last-value observer after it.
* ecospy runs the FMI 2.0 and the FMI 3.0 FMU; the input is set with ``set_real`` before each step.
* ``fmutool -check`` (fmu-manipulation-toolbox) validates both modelDescription.xml files against the FMI XSD
  schemas and the standard's semantic rules; it exits non-zero (7) and logs ``ERROR`` lines on a violation.

Both importers apply an input set before a step to that very step (no one-step delay) and start at t = 0; the
test checks the importer's own clock at every communication point as well, so a shifted or delayed run fails
instead of being hidden by a looser tolerance. ecospy's run is bit-identical to fmpy's. libcosim's differs in
the last bits (~1e-15 relative) only because its nanosecond clock hands doStep step sizes that wobble by an ulp
around 1 ms; fmpy fed the same (t, h) sequence reproduces it bit for bit, which the test checks too.

An importer test is skipped only when that importer cannot be imported or its native library cannot be loaded
on this platform (ecospy needs Debian's ``libtbb12``). CI installs them with::

    apt-get install -y libtbb12
    pip install libcosimpy ecospy fmu-manipulation-toolbox
"""
from __future__ import annotations

import functools
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

DT = 1e-3
N_STEPS = 200
STEP_NS = 1_000_000  # libcosim counts time in integer nanoseconds

VR_TORQUE = 30
REAL_OUTPUTS = {"q_m": 40, "q_l": 41, "v_m": 42, "v_l": 43, "spring_torque": 44}
BOOL_OUTPUTS = {"motor_stuck": 45, "load_stuck": 46}
INT_OUTPUTS = {"encoder_count": 47}

RTOL = 1e-12


def torque_schedule() -> np.ndarray:
    """Motor torque held over step k, i.e. over [k DT, (k+1) DT]: 1 ms pulses of +-0.03 N.m separated by rests.

    The static motor friction is 0.01 N.m, so each pulse breaks the motor loose and the rests let the drive
    oscillate, slow down and stick again (stick-slip inside the steps).
    """
    u = np.zeros(N_STEPS)
    u[5] = 0.03               # a single 1 ms pulse from rest
    u[40] = 0.03              # a second one after a long rest
    u[41] = 0.03              # ... held for 2 ms
    u[90] = -0.03             # a negative pulse
    u[130] = 0.03             # positive again, then a 0.005 N.m hold below the static friction level
    u[131:150] = 0.005
    u[170] = -0.03
    return u


# ----------------------------------------------------------------------------------------------- reference: fmpy
def _fixed_clock() -> tuple[tuple[float, float], ...]:
    """(currentCommunicationPoint, communicationStepSize) of step k: (k DT, DT), as fmpy's own loops do."""
    return tuple((k * DT, DT) for k in range(N_STEPS))


def _libcosim_clock() -> tuple[tuple[float, float], ...]:
    """The (t, h) libcosim passes to fmi2DoStep: its clock counts integer nanoseconds and converts each time point
    to seconds (ns / 1e9), and h is the difference of two converted time points, so h wobbles by an ulp or so
    around DT from step 8 on (0.00099999999999999915, 0.0010000000000000009, ...)."""
    points = [k * STEP_NS / 1e9 for k in range(N_STEPS + 1)]
    return tuple((points[k], points[k + 1] - points[k]) for k in range(N_STEPS))


@functools.lru_cache(maxsize=None)
def _fmpy_run(fmu: Path, clock: tuple[tuple[float, float], ...] | None = None) -> dict[str, np.ndarray]:
    import fmpy
    from fmpy import extract, read_model_description

    md = read_model_description(str(fmu))
    unzipdir = extract(str(fmu))
    try:
        slave = fmpy.instantiate_fmu(unzipdir, md, fmi_type="CoSimulation")
        real_vrs = list(REAL_OUTPUTS.values())
        bool_vrs = list(BOOL_OUTPUTS.values())
        int_vrs = list(INT_OUTPUTS.values())
        fmi3 = md.fmiVersion.startswith("3")
        if fmi3:
            slave.enterInitializationMode(startTime=0.0)
            slave.exitInitializationMode()
            set_real, get_real, get_int = slave.setFloat64, slave.getFloat64, slave.getInt32
        else:
            slave.setupExperiment(startTime=0.0)
            slave.enterInitializationMode()
            slave.exitInitializationMode()
            set_real, get_real, get_int = slave.setReal, slave.getReal, slave.getInteger
        rows_r, rows_b, rows_i = [], [], []
        for u, (t, h) in zip(torque_schedule(), clock or _fixed_clock()):
            set_real([VR_TORQUE], [float(u)])
            slave.doStep(currentCommunicationPoint=t, communicationStepSize=h)
            rows_r.append(get_real(real_vrs))
            rows_b.append([bool(b) for b in slave.getBoolean(bool_vrs)])
            rows_i.append(get_int(int_vrs))
        slave.terminate()
        slave.freeInstance()
    finally:
        shutil.rmtree(unzipdir, ignore_errors=True)
    return _pack(rows_r, rows_b, rows_i, times=[t + h for t, h in (clock or _fixed_clock())])


def _pack(rows_r, rows_b, rows_i, times) -> dict[str, np.ndarray]:
    r, b, i = np.array(rows_r, dtype=float), np.array(rows_b, dtype=bool), np.array(rows_i, dtype=np.int64)
    out = {name: r[:, j] for j, name in enumerate(REAL_OUTPUTS)}
    out.update({name: b[:, j] for j, name in enumerate(BOOL_OUTPUTS)})
    out.update({name: i[:, j] for j, name in enumerate(INT_OUTPUTS)})
    out["time"] = np.array(times, dtype=float)
    return out


def _assert_same_trajectory(ref: dict[str, np.ndarray], got: dict[str, np.ndarray], who: str) -> None:
    expected_t = (np.arange(N_STEPS) + 1) * DT
    np.testing.assert_allclose(got["time"], expected_t, rtol=1e-12, atol=1e-15,
                               err_msg=f"{who}: communication points differ from k*{DT}")
    for name in REAL_OUTPUTS:
        scale = float(np.max(np.abs(ref[name])))
        np.testing.assert_allclose(got[name], ref[name], rtol=RTOL, atol=RTOL * scale,
                                   err_msg=f"{who}: {name} differs from fmpy")
    for name in (*BOOL_OUTPUTS, *INT_OUTPUTS):
        np.testing.assert_array_equal(got[name], ref[name], err_msg=f"{who}: {name} differs from fmpy")


def _check_reference_is_nontrivial(ref: dict[str, np.ndarray]) -> None:
    """The schedule must really move the drive, and let it stick again, or the comparison proves little."""
    assert np.max(np.abs(ref["q_m"])) > 0.0 and np.max(np.abs(ref["spring_torque"])) > 0.0
    assert ref["v_m"][5] != 0.0, "the first pulse should break the motor loose within its step"
    assert ref["motor_stuck"].any() and not ref["motor_stuck"].all()


# -------------------------------------------------------------------------------------------------- libcosimpy
def _import_libcosimpy():
    reason = None
    try:
        from libcosimpy import CosimExecution, CosimLogging, CosimManipulator, CosimObserver, CosimSlave
        from libcosimpy._internal import libcosimc

        libcosimc()  # loads the bundled native libcosimc.so
    except (ImportError, OSError) as exc:
        reason = f"libcosimpy cannot be imported/loaded on this platform ({exc!r}); pip install libcosimpy"
    if reason:
        pytest.skip(reason)
    return CosimExecution, CosimLogging, CosimManipulator, CosimObserver, CosimSlave


def _libcosim_run(fmu: Path) -> dict[str, np.ndarray]:
    CosimExecution, CosimLogging, CosimManipulator, CosimObserver, CosimSlave = _import_libcosimpy()
    from libcosimpy._internal import get_last_error_message

    CosimLogging.log_output_level(CosimLogging.CosimLogLevel.ERROR)
    execution = CosimExecution.CosimExecution.from_step_size(step_size=STEP_NS)  # starts at t = 0
    slave = CosimSlave.CosimLocalSlave(fmu_path=str(fmu), instance_name="hd")
    # A NULL slave (e.g. an FMI version libcosim does not support) would crash add_local_slave: fail cleanly.
    assert slave.ptr(), f"libcosim cannot load {fmu}: {get_last_error_message()}"
    index = execution.add_local_slave(slave)
    assert index >= 0, f"libcosim cannot add {fmu}: {get_last_error_message()}"
    manipulator = CosimManipulator.CosimManipulator.create_override()
    observer = CosimObserver.CosimObserver.create_last_value()
    assert execution.add_manipulator(manipulator), get_last_error_message()
    assert execution.add_observer(observer), get_last_error_message()

    real_vrs = list(REAL_OUTPUTS.values())
    rows_r, rows_b, rows_i, times = [], [], [], []
    for u in torque_schedule():
        # The override is applied to the input before the slave's next doStep: no one-step delay.
        assert manipulator.slave_real_values(index, [VR_TORQUE], [float(u)]), get_last_error_message()
        assert execution.step(), f"libcosim step failed: {get_last_error_message()}"
        times.append(execution.status().current_time * 1e-9)
        rows_r.append(observer.last_real_values(index, real_vrs))
        rows_b.append(observer.last_boolean_values(index, list(BOOL_OUTPUTS.values())))
        rows_i.append(observer.last_integer_values(index, list(INT_OUTPUTS.values())))
    # Destroy the execution before the objects it refers to.
    del execution
    del manipulator, observer, slave
    return _pack(rows_r, rows_b, rows_i, times)


def test_libcosimpy_fmi2_matches_fmpy(fmu2: Path) -> None:
    _import_libcosimpy()
    ref = _fmpy_run(fmu2)
    _check_reference_is_nontrivial(ref)
    got = _libcosim_run(fmu2)
    _assert_same_trajectory(ref, got, "libcosimpy (FMI 2.0)")
    # The last-bit differences left (~1e-15 relative) come from libcosim's nanosecond clock alone: fed the very
    # same (t, h) sequence, fmpy gives the libcosim trajectory bit for bit.
    replay = _fmpy_run(fmu2, _libcosim_clock())
    for name in (*REAL_OUTPUTS, *BOOL_OUTPUTS, *INT_OUTPUTS):
        np.testing.assert_array_equal(got[name], replay[name],
                                      err_msg=f"libcosimpy: {name} differs from fmpy run on libcosim's clock")


# ------------------------------------------------------------------------------------------------------ ecospy
def _import_ecospy():
    reason = None
    try:
        import ecospy  # loads the bundled libecosc.so, which links against libtbb.so.12
    except (ImportError, OSError) as exc:
        reason = (f"ecospy cannot be imported/loaded on this platform ({exc!r}); "
                  "pip install ecospy, and on Debian apt-get install libtbb12")
    if reason:
        pytest.skip(reason)
    return ecospy


def _ecos_run(fmu: Path) -> dict[str, np.ndarray]:
    ecospy = _import_ecospy()
    structure = ecospy.EcosSimulationStructure()
    structure.add_model("hd", str(fmu))
    sim = ecospy.EcosSimulation(structure=structure, step_size=DT)
    try:
        assert sim.init(start_time=0), f"ecos init failed: {ecospy.EcosLib.get_last_error()}"
        assert sim.get_time() == 0.0
        rows_r, rows_b, rows_i, times = [], [], [], []
        for u in torque_schedule():
            # The value set here is written to the FMU before the next doStep: no one-step delay.
            sim.set_real("hd::motor_torque", float(u))
            times.append(sim.step())
            rows_r.append([sim.get_real(f"hd::{name}") for name in REAL_OUTPUTS])
            rows_b.append([sim.get_bool(f"hd::{name}") for name in BOOL_OUTPUTS])
            rows_i.append([sim.get_integer(f"hd::{name}") for name in INT_OUTPUTS])
        sim.terminate()
    finally:
        sim.free()
        structure.free()
    return _pack(rows_r, rows_b, rows_i, times)


@pytest.mark.parametrize("fmi_version", [2, 3], ids=["fmi2", "fmi3"])
def test_ecospy_matches_fmpy(fmi_version: int, request) -> None:
    _import_ecospy()
    fmu = request.getfixturevalue(f"fmu{fmi_version}")
    ref = _fmpy_run(fmu)
    _check_reference_is_nontrivial(ref)
    _assert_same_trajectory(ref, _ecos_run(fmu), f"ecospy (FMI {fmi_version}.0)")


# ----------------------------------------------------------------------------------------------- fmutool -check
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


@pytest.mark.parametrize("fmi_version", [2, 3], ids=["fmi2", "fmi3"])
def test_fmutool_check_passes(fmi_version: int, request) -> None:
    pytest.importorskip("fmu_manipulation_toolbox",
                        reason="fmu-manipulation-toolbox (fmutool) is not installed: "
                               "pip install fmu-manipulation-toolbox")
    fmu = request.getfixturevalue(f"fmu{fmi_version}")
    # `python -m fmu_manipulation_toolbox ARGS` is the `fmutool` command line of the same interpreter.
    proc = subprocess.run([sys.executable, "-m", "fmu_manipulation_toolbox", "-input", str(fmu), "-check"],
                          capture_output=True, text=True, timeout=300)
    log = _ANSI.sub("", proc.stdout + proc.stderr)
    # fmutool >= 2.0 exits with 7 when a checker logged an error (3/4: unreadable input / not an FMU);
    # older versions exit 0 whatever the checkers say, so the ERROR lines are checked as well.
    assert proc.returncode == 0, f"fmutool -check exited with {proc.returncode}:\n{log}"
    problems = [line for line in log.splitlines() if re.match(r"\s*(ERROR|CRITICAL)\b", line)]
    assert not problems, "fmutool -check reported:\n" + "\n".join(problems)
    assert f"This FMU seems to be compliant with FMI-{fmi_version}.0." in log, log
    assert "FMU Semantic Checks" in log, f"the semantic checker did not run:\n{log}"
    assert f"No semantic error against the FMI-{fmi_version} standard." in log, log
