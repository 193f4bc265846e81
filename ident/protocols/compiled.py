"""The protocols' inner loops in compiled code over the FMU's own FMI functions (``fmu_build/c/protocols.c``).

What runs here is what ``ImpulseController.pulse`` and ``LinearPD.move`` do through ``Plant.step``, call for call:
the same setter / doStep / getter calls of the same FMU instance (the one binary ``Plant`` loaded through fmpy, no
second copy of the physics), with the same communication points, step sizes and floating-point operations, so the
increments are bit for bit those of the Python loops (``tests/test_compiled_protocols.py`` holds them equal). What
is gone is Python's overhead per communication step, which was almost all of the protocols' time.

``ident.protocols.resolution`` uses these loops by default (``loop="compiled"``); ``loop="python"`` runs the Python
controllers, which stay the API for loops a user writes around a ``Plant``.

The C loop returns to Python every ``CHUNK_STEPS`` doSteps (counted work, not time) and resumes where it stopped, so
Ctrl-C stops a long run between chunks; ``Plant.time`` / ``Plant.torque`` are kept in step however the run ends. A
refused FMI call raises the same ``PlantError`` (with the FMU's own message) as ``Plant.step``, a plant that does
not come to rest the same ``SettleError``.
"""
from __future__ import annotations

import ctypes
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from fmu_build import variables as V

from ..model.plant import Plant, SettleError
from .controllers import ImpulseController, LinearPD

__all__ = ["CHUNK_STEPS", "LOOPS", "LoopStats", "Stopped", "check_loop", "loop_stats", "pd_steps", "pulses",
           "stopped_by"]

LOOPS = ("compiled", "python")
# doSteps per call into C between returns to Python (counted work, never time). A closed-form doStep costs a few us,
# an effects-on (Runge-Kutta) doStep of a 20 ms rest poll while the load rings up to ~0.3 ms (hysteresis at
# f_l* = 0.01): a chunk is a few ms, at worst ~0.15 s (the Ctrl-C latency, bench/protocols.py), while a return to
# Python (~5 us) is negligible against it.
CHUNK_STEPS = 512

_FAIL_SET, _FAIL_STEP, _FAIL_GET, _FAIL_SETTLE = 1, 2, 3, 4
_DOUBLE_P = ctypes.POINTER(ctypes.c_double)


class Stopped(RuntimeError):
    """The batch this run belonged to was stopped (Ctrl-C, SIGTERM or another task's failure)."""


_STOP = threading.local()


@dataclass
class LoopStats:
    """Work of the compiled loops this thread ran: calls into C (chunks), doSteps, and thread CPU seconds inside
    those calls (almost all of it the FMU's own doSteps). For benchmarks; ``loop_stats(reset=True)`` starts over."""

    calls: int = 0
    do_steps: int = 0
    cpu_s: float = 0.0


def loop_stats(reset: bool = False) -> LoopStats:
    """This thread's ``LoopStats`` (a live object), optionally reset to zero first."""
    if reset or not hasattr(_STOP, "stats"):
        _STOP.stats = LoopStats()
    return _STOP.stats


@contextmanager
def stopped_by(event: threading.Event) -> Iterator[None]:
    """Compiled loops run by this thread inside the block raise ``Stopped`` at their next chunk once ``event`` is
    set (for runs in worker threads, which Ctrl-C does not reach)."""
    previous = getattr(_STOP, "event", None)
    _STOP.event = event
    try:
        yield
    finally:
        _STOP.event = previous


def check_loop(loop: str) -> str:
    """``loop`` is "compiled" or "python", else ValueError naming it."""
    if loop not in LOOPS:
        raise ValueError(f"loop = {loop!r}: use 'compiled' (the protocol loop in C over the FMU's functions) or "
                         "'python' (ImpulseController / LinearPD through Plant.step)")
    return loop


class _Plant(ctypes.Structure):
    _fields_ = [("fmi_version", ctypes.c_int), ("instance", ctypes.c_void_p),
                ("set_real", ctypes.c_void_p), ("do_step", ctypes.c_void_p), ("get_real", ctypes.c_void_p),
                ("get_int", ctypes.c_void_p), ("get_bool", ctypes.c_void_p),
                ("vr_torque", ctypes.c_uint32), ("vr_arm", ctypes.c_uint32), ("vr_count", ctypes.c_uint32),
                ("vr_stuck", ctypes.c_uint32 * 2),
                ("time", ctypes.c_double), ("torque", ctypes.c_double), ("arm", ctypes.c_double),
                ("count", ctypes.c_int32), ("motor_stuck", ctypes.c_int32), ("load_stuck", ctypes.c_int32),
                ("steps", ctypes.c_int64), ("budget", ctypes.c_int64),
                ("failed", ctypes.c_int32), ("fail_torque", ctypes.c_double), ("fail_time", ctypes.c_double),
                ("fail_dt", ctypes.c_double)]


class _Rest(ctypes.Structure):
    _fields_ = [("started", ctypes.c_int32), ("t_end", ctypes.c_double)]


class _Pulses(ctypes.Structure):
    _fields_ = [("torque", ctypes.c_double), ("width", ctypes.c_double), ("rest_dt", ctypes.c_double),
                ("max_rest", ctypes.c_double), ("eps1", ctypes.c_double),
                ("n", ctypes.c_int64), ("done", ctypes.c_int64), ("above", ctypes.c_int64), ("below", ctypes.c_int64),
                ("decide", ctypes.c_int32), ("decision", ctypes.c_int32), ("phase", ctypes.c_int32),
                ("before", ctypes.c_double), ("rest", _Rest), ("increments", _DOUBLE_P)]


class _PD(ctypes.Structure):
    _fields_ = [(name, ctypes.c_double) for name in ("Kp", "Kd", "saturation", "count_rad", "dt_star", "f_m", "dt",
                                                     "max_time", "eps1")] + [
        ("counts", ctypes.c_int64), ("warmup", ctypes.c_int64), ("n_steps", ctypes.c_int64), ("done", ctypes.c_int64),
        ("stop_at_failure", ctypes.c_int32), ("stopped", ctypes.c_int32),
        ("setpoint", ctypes.c_int64), ("count_prev", ctypes.c_int64),
        ("has_prev", ctypes.c_int32), ("derivative_zero", ctypes.c_int32), ("last_torque", ctypes.c_double),
        ("in_move", ctypes.c_int32), ("start", ctypes.c_double), ("t_end", ctypes.c_double),
        ("increments", _DOUBLE_P)]


_LIB: ctypes.CDLL | None = None
_LOADING = threading.Lock()


def _lib() -> ctypes.CDLL:
    """``c/runner.c`` + ``c/protocols.c``, built (``fmu_build.build.build_runner``) and loaded once per process."""
    global _LIB
    with _LOADING:   # the threads of a batch: one build and one load per process
        if _LIB is None:
            from fmu_build.build import build_runner

            lib = ctypes.CDLL(str(build_runner()))
            for name, job in (("hd_plant_read", None), ("hd_pulses_run", _Pulses), ("hd_pd_run", _PD)):
                fn = getattr(lib, name)
                fn.restype = ctypes.c_int
                fn.argtypes = [ctypes.POINTER(_Plant)] + ([ctypes.POINTER(job)] if job else [])
            _LIB = lib
    return _LIB


_FUNCTIONS = {2: ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal", "fmi2GetInteger", "fmi2GetBoolean"),
              3: ("fmi3SetFloat64", "fmi3DoStep", "fmi3GetFloat64", "fmi3GetInt32", "fmi3GetBoolean")}


def _bind(plant: Plant) -> _Plant:
    """The C view of ``plant``: its FMU's functions and instance, its time and held torque, its current outputs."""
    f = plant.fmi_functions
    ptrs = [ctypes.cast(f[name], ctypes.c_void_p) for name in _FUNCTIONS[plant.fmi_version]]
    vr = {name: V.BY_NAME[name].vr for name in ("motor_torque", "arm_position", "encoder_count", "motor_stuck",
                                                "load_stuck")}
    p = _Plant(fmi_version=plant.fmi_version, instance=ctypes.c_void_p(plant.component),
               set_real=ptrs[0], do_step=ptrs[1], get_real=ptrs[2], get_int=ptrs[3], get_bool=ptrs[4],
               vr_torque=vr["motor_torque"], vr_arm=vr["arm_position"], vr_count=vr["encoder_count"],
               vr_stuck=(ctypes.c_uint32 * 2)(vr["motor_stuck"], vr["load_stuck"]),
               time=plant.time, torque=plant.torque, budget=CHUNK_STEPS)
    if _lib().hd_plant_read(ctypes.byref(p)):
        plant.raise_fmu_error("reading outputs")
    return p


def _drive(plant: Plant, p: _Plant, run: Callable[..., int], job: ctypes.Structure,
           settle_message: Callable[[], str]) -> None:
    """Call ``run(p, job)`` until the job is done; raise what ``Plant.step`` / the controllers would have raised."""
    stop, stats = getattr(_STOP, "event", None), loop_stats()
    try:
        while True:
            t0 = time.thread_time()
            status = run(ctypes.byref(p), ctypes.byref(job))
            stats.cpu_s += time.thread_time() - t0
            stats.calls += 1
            stats.do_steps += p.steps
            if status == 0:
                break
            if status < 0:
                _raise(plant, p, settle_message)
            if stop is not None and stop.is_set():
                raise Stopped("stopped: the batch was interrupted or another of its runs failed")
    finally:  # also on Ctrl-C between chunks: the Plant knows where its FMU is
        plant.time, plant.torque = p.time, p.torque
    plant.sample()  # refresh the Plant's cached outputs (e.g. Plant.energy)


def _raise(plant: Plant, p: _Plant, settle_message: Callable[[], str]) -> None:
    if p.failed == _FAIL_SETTLE:
        raise SettleError(settle_message())
    if p.failed == _FAIL_SET:
        plant.raise_fmu_error(f"setting motor_torque = {p.fail_torque!r} N.m")
    if p.failed == _FAIL_STEP:
        plant.raise_fmu_error(f"doStep(t = {p.fail_time} s, dt = {p.fail_dt!r} s)")
    plant.raise_fmu_error("reading outputs")


def pulses(plant: Plant, controller: ImpulseController, n_pulses: int,
           eps1_m: float | None = None) -> tuple[np.ndarray, bool | None]:
    """``n_pulses`` times ``controller.pulse(plant)`` (from the plant's current state); returns the increments [m].

    With ``eps1_m``, the early-deciding median test: stop once more than n/2 increments are > eps1 (decision True)
    or more than n/2 are <= eps1 (False); the increments run so far are returned. Decision None: all N ran and
    neither side has a majority (even N); the caller takes the plain median."""
    incs = np.empty(n_pulses)
    job = _Pulses(torque=controller.amplitude_star * plant.params.f_m, width=controller.width_s,
                  rest_dt=controller.rest_step_s, max_rest=controller.max_rest_s,
                  eps1=0.0 if eps1_m is None else eps1_m, n=n_pulses, decide=eps1_m is not None, decision=-1,
                  increments=incs.ctypes.data_as(_DOUBLE_P))
    message = f"the plant did not come to rest within {controller.max_rest_s} s"
    _drive(plant, _bind(plant), _lib().hd_pulses_run, job, lambda: message)
    return incs[:job.done].copy(), None if job.decision < 0 else bool(job.decision)


def pd_steps(plant: Plant, controller: LinearPD, counts: int, n_steps: int, warmup: int, *,
             eps1_m: float | None = None, max_settle_s: float = 10.0) -> np.ndarray:
    """``controller`` reset to the plant's drive and current sample, then ``warmup`` + ``n_steps`` times
    ``controller.move(plant, counts, max_time_s=max_settle_s)``; returns the measured steps' increments [m]. With
    ``eps1_m``, stops after the first measured step of eps1 or less. The controller ends in the state the Python
    loop leaves it in (set-point, last torque, derivative memory)."""
    controller.reset(plant.params, plant.sample())
    params = plant.params
    incs = np.empty(n_steps)
    job = _PD(Kp=controller.Kp_star, Kd=controller.Kd_star, saturation=controller.saturation_star,
              count_rad=params.count_rad, dt_star=controller.dt_s / params.T_c, f_m=params.f_m, dt=controller.dt_s,
              max_time=max_settle_s, eps1=0.0 if eps1_m is None else eps1_m, counts=counts, warmup=warmup,
              n_steps=n_steps, stop_at_failure=eps1_m is not None, setpoint=controller.setpoint_count,
              count_prev=plant.sample().encoder_count, has_prev=1, derivative_zero=1,
              increments=incs.ctypes.data_as(_DOUBLE_P))

    def message() -> str:
        return (f"LinearPD.move({counts}) did not settle within {max_settle_s} s (encoder {p.count}, "
                f"set-point {job.setpoint})")

    p = _bind(plant)
    _drive(plant, p, _lib().hd_pd_run, job, message)
    # the last control() call saw the current sample, so reset(sample=...) restores its derivative memory
    controller.reset(sample=plant.sample(), setpoint_count=job.setpoint)
    controller.last_torque, controller.last_derivative_zero = job.last_torque, bool(job.derivative_zero)
    return incs[:max(0, job.done - warmup)].copy()
