"""The protocols' compiled loops (ident.protocols.compiled, fmu_build/c/protocols.c) against the Python loops
(ImpulseController / LinearPD through Plant.step): the same FMU, the same results bit for bit, on every level of the
friction sweep, on the linear protocol over several drives and step sizes, with effects on, for FMI 2 and FMI 3;
the same errors; a run that Ctrl-C or a stopped batch can end between chunks.

The Python side always runs on a new Plant of its own (no pool, no threads), the compiled side through the
default path (the thread's pooled plant, the sweep's threads), so the comparison also covers those.
"""
from __future__ import annotations

import _thread
import threading
import time

import numpy as np
import pytest

from fmu_build import variables as V
from ident import DriveParams, Plant, PlantError
from ident.protocols import compiled
from ident.protocols.batch import run_batch
from ident.protocols.controllers import ImpulseController, LinearPD
from ident.protocols.resolution import (
    ImpulseResolution,
    impulse_experiment,
    impulse_resolution,
    linear_resolution,
    linear_steps,
)
from ident.protocols.sweep import friction_levels, friction_sweep
from ident.studies.paper_effects import EFFECT_CASES

FMI = [2, 3]


def bits(x: np.ndarray) -> bytes:
    """The exact bit pattern (np.array_equal would take -0.0 for 0.0)."""
    return np.ascontiguousarray(x, dtype=np.float64).tobytes()


def python_impulse(params: DriveParams, n_pulses: int, fmi_version: int) -> ImpulseResolution:
    with Plant(params, fmi_version=fmi_version) as plant:
        return impulse_resolution(plant, n_pulses, loop="python")


def assert_same_impulse(a: ImpulseResolution, b: ImpulseResolution, what: str) -> None:
    assert a.median_tests == b.median_tests, f"{what}: the threshold searches differ"
    assert (a.threshold_amplitude, a.operating_amplitude) == (b.threshold_amplitude, b.operating_amplitude), what
    assert bits(a.increments_m) == bits(b.increments_m), f"{what}: increments differ"


def sweep_equal(n_pulses: int, fmi_version: int) -> None:
    nominal = DriveParams()
    fast = friction_sweep(nominal, 25, n_pulses, fmi_version=fmi_version)   # threads, pooled plants
    for f, got in zip(friction_levels(25), fast.results):
        want = python_impulse(nominal.with_values(f_l_star=float(f)), n_pulses, fmi_version)
        assert_same_impulse(got, want, f"f_l* = {f:.4g}, FMI {fmi_version}")


# -- the impulse protocol: the 25-level sweep ---------------------------------------------------------------------
@pytest.mark.parametrize("fmi_version", FMI)
def test_sweep_compiled_equals_python_loop(fmi_version: int) -> None:
    sweep_equal(100, fmi_version)


@pytest.mark.slow
@pytest.mark.parametrize("fmi_version", FMI)
def test_sweep_compiled_equals_python_loop_full_n(fmi_version: int) -> None:
    sweep_equal(1000, fmi_version)


# -- effects on -------------------------------------------------------------------------------------------------
def effects_equal(levels: list[float], n_pulses: int, fmi_version: int) -> None:
    for case in EFFECT_CASES:
        for f in levels:
            params = case.params(DriveParams(), f)
            got = impulse_resolution(params, n_pulses, fmi_version=fmi_version)
            assert_same_impulse(got, python_impulse(params, n_pulses, fmi_version),
                                f"{case.name}, f_l* = {f}, FMI {fmi_version}")


@pytest.mark.parametrize("fmi_version", FMI)
def test_effects_compiled_equals_python_loop(fmi_version: int) -> None:
    effects_equal([0.3], 20, fmi_version)


@pytest.mark.slow
@pytest.mark.parametrize("fmi_version", FMI)
def test_effects_compiled_equals_python_loop_slow(fmi_version: int) -> None:
    effects_equal([0.01, 0.1, 1.0], 100, fmi_version)


# -- the linear protocol ------------------------------------------------------------------------------------------
LINEAR_DRIVES = [dict(K_star=1e6, J_l_star=2500, f_l_star=0.01), dict(K_star=1e6, J_l_star=2500, f_l_star=0.1),
                 dict(K_star=1e6, J_l_star=2500, f_l_star=1.0), dict(K_star=1e5, J_l_star=500, f_l_star=0.3),
                 dict(K_star=1e7, J_l_star=1e4, f_l_star=0.05)]


@pytest.mark.parametrize("fmi_version", FMI)
@pytest.mark.parametrize("drive", LINEAR_DRIVES, ids=lambda d: "-".join(f"{v:g}" for v in d.values()))
def test_linear_resolution_compiled_equals_python_loop(drive: dict, fmi_version: int) -> None:
    params = DriveParams.from_nondim(**drive)
    got = linear_resolution(params, n_steps=60, warmup=10, fmi_version=fmi_version)
    with Plant(params, fmi_version=fmi_version) as plant:
        want = linear_resolution(plant, n_steps=60, warmup=10, loop="python")
    assert (got.counts, got.tried) == (want.counts, want.tried)
    assert bits(got.increments_m) == bits(want.increments_m)


@pytest.mark.parametrize("fmi_version", FMI)
@pytest.mark.parametrize("case", ["base", "viscous_load_2pct", "stribeck_fast", "hysteresis_fl",
                                  "kinematic_error_3arcsec"])
def test_linear_steps_every_k_compiled_equals_python_loop(case: str, fmi_version: int) -> None:
    """Every k from 1 to 5 run to the end (no early stop), effects on too; the controller ends in the same state."""
    params = next(c for c in EFFECT_CASES if c.name == case).params(DriveParams(), 0.2)
    with Plant(params, fmi_version=fmi_version) as fast, Plant(params, fmi_version=fmi_version) as slow:
        for k in range(1, 6):
            pd_fast, pd_slow = LinearPD(Kd_star=25.0), LinearPD(Kd_star=25.0)
            got = linear_steps(fast, k, 25, 5, controller=pd_fast)
            want = linear_steps(slow, k, 25, 5, controller=pd_slow, loop="python")
            assert bits(got) == bits(want), f"k = {k}"
            assert (fast.time, fast.torque, fast.sample()) == (slow.time, slow.torque, slow.sample())
            assert (pd_fast.setpoint_count, pd_fast.last_torque, pd_fast.last_derivative_zero) == \
                   (pd_slow.setpoint_count, pd_slow.last_torque, pd_slow.last_derivative_zero)
            s = fast.sample()   # and the derivative memory: the next control() agrees
            assert pd_fast.control(s) == pd_slow.control(s)


def test_a_pd_subclass_runs_its_own_control_in_python() -> None:
    class Stiffer(LinearPD):
        def control(self, sample):  # noqa: ANN001, ANN202
            return 2.0 * super().control(sample)

    with Plant(DriveParams()) as plant:
        got = linear_steps(plant, 3, 5, 2, controller=Stiffer())
        want = linear_steps(plant, 3, 5, 2, controller=Stiffer(), loop="python")
    assert bits(got) == bits(want)


# -- the same errors --------------------------------------------------------------------------------------------
def outcome(params: DriveParams, fmi_version: int, run) -> tuple:  # noqa: ANN001
    with Plant(params, fmi_version=fmi_version) as plant:
        try:
            result = run(plant)
        except PlantError as exc:   # SettleError included
            return type(exc).__name__, str(exc), plant.time, plant.torque
    return "no error", bits(np.asarray(result)), plant.time, plant.torque


@pytest.mark.parametrize("fmi_version", FMI)
@pytest.mark.parametrize("what", ["setter refuses", "doStep refuses", "no rest", "PD does not settle"])
def test_errors_are_the_python_loops_errors(what: str, fmi_version: int) -> None:
    low = DriveParams().with_values(f_l_star=0.01)
    stiff = DriveParams().with_values(b_m=1e6)   # substeps of 5e-12 s: the FMU refuses a 1 ms step
    runs = {
        "setter refuses": (low, lambda p, loop: impulse_experiment(p, 1e9, 3, loop=loop)),
        "doStep refuses": (stiff, lambda p, loop: impulse_experiment(p, 3.0, 3, loop=loop)),
        "no rest": (low, lambda p, loop: compiled.pulses(p, ImpulseController(3.0, max_rest_s=1e-3), 2)[0]
                    if loop == "compiled" else ImpulseController(3.0, max_rest_s=1e-3).pulse(p)),
        "PD does not settle": (low, lambda p, loop: linear_steps(p, 3, 5, 0, max_settle_s=0.002, loop=loop)),
    }
    params, run = runs[what]
    got = outcome(params, fmi_version, lambda p: run(p, "compiled"))
    want = outcome(params, fmi_version, lambda p: run(p, "python"))
    assert got == want
    assert got[0] == ("SettleError" if what in ("no rest", "PD does not settle") else "PlantError")
    if what.endswith("refuses"):
        assert f"fmi{fmi_version}" in got[1]   # the FMU's own message


# -- stopping between chunks ------------------------------------------------------------------------------------
def fmu_time(plant: Plant) -> float:
    vr = V.BY_NAME["time"].vr
    return (plant.fmu.getReal if plant.fmi_version == 2 else plant.fmu.getFloat64)([vr])[0]


def test_ctrl_c_stops_a_compiled_run_between_chunks() -> None:
    """An interrupt reaches Python between two chunks of the C loop: the run ends with KeyboardInterrupt long before
    its 10^6 pulses, and the Plant's time is its FMU's time. (How fast: bench/protocols.py.)"""
    with Plant(DriveParams()) as plant:
        started = threading.Event()

        def interrupt() -> None:
            started.wait()
            time.sleep(0.2)
            _thread.interrupt_main()

        threading.Thread(target=interrupt, daemon=True).start()
        with pytest.raises(KeyboardInterrupt):
            started.set()
            impulse_experiment(plant, 1.2, 10**6)
        assert 0.0 < plant.time < 10**6 * 0.021 and plant.time == fmu_time(plant)
        plant.step(0.0, 1e-3)   # still usable


def test_a_stopped_batch_stops_its_compiled_runs() -> None:
    stop = threading.Event()
    stop.set()
    with Plant(DriveParams()) as plant, compiled.stopped_by(stop), pytest.raises(compiled.Stopped):
        compiled.pulses(plant, ImpulseController(1.2), 10**6)
    assert plant.time < 10**6 * 0.021


def _fails_on_two(x: int) -> int:
    if x == 2:
        raise ValueError("two")
    return impulse_experiment(DriveParams(), 1.2, 5 + x).size


def test_threaded_batch_keeps_the_input_order_and_raises_a_task_error() -> None:
    assert run_batch(_fails_on_two, [0, 1, 3, 4, 5], workers=2, threads=True) == [5, 6, 8, 9, 10]
    with pytest.raises(ValueError, match="two"):
        run_batch(_fails_on_two, [0, 1, 2, 3], workers=2, threads=True)


def test_bad_loop_is_named() -> None:
    with pytest.raises(ValueError, match="loop = 'fast'"):
        impulse_resolution(DriveParams(), 10, loop="fast")
    with pytest.raises(ValueError, match="loop = 'C'"):
        friction_sweep(DriveParams(), 2, 5, loop="C")
