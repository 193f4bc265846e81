"""Idle ``Plant`` instances of this thread, kept for the next user instead of opening a new one.

Opening a ``Plant`` unpacks the FMU into a new folder, parses its modelDescription and loads its binary: about 20 ms.
The protocols would open one per resolution run, and the fits opened one per problem (every refit, size probe and
check of a diagnosis is a new problem). Measured: a serial diagnosis of a 3 s hardening log at 5 kHz opened 203
plants, 4.3 s of its 38 s under the profiler; with the protocols' loops compiled, a whole impulse resolution
simulates in tens of milliseconds, about as long as the opening. So a user ``take``s this thread's idle plant of the
default FMU and ``give_back``s it when done; ``pooled_plant`` does both around a ``with`` block.

Why it changes no result: an FMU reset re-initialises the instance from its start values completely (the same
results as a new instance, which the tests hold bit for bit), and ``take`` resets to the drive and to every initial
state, those not given at rest with zero deflection, as a new ``Plant`` starts. Nothing else of an instance outlives
a reset (the FMU's work count restarts with it, so budgets counted in it are charged the same).

A plant is out of the pool while in use (two users never share one) and goes back only when its user is done with
it; a ``with`` block that ends in an exception closes it instead. Unpacked FMUs are removed at exit like any
``Plant``'s. The pool is per thread, so that no lock is needed; the FMU is found by path, so a rebuilt FMU (changed
sources) is a new plant.
"""
from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Iterator

from fmu_build.build import default_fmu_path

from .params import DriveParams
from .plant import Plant

__all__ = ["give_back", "pooled_plant", "take"]

_LOCAL = threading.local()
_AT_REST = dict(q_m_start=0.0, q_l_start=0.0, v_m_start=0.0, v_l_start=0.0)


def take(params: DriveParams, fmi_version: int = 2, **initial: float) -> Plant:
    """This thread's idle Plant of the default FMU of ``fmi_version`` (a new one if the pool has none), reset to
    ``params`` and ``initial`` (every initial state not given at rest with zero deflection, as a new Plant starts).
    Hand it back with ``give_back`` once done."""
    path = default_fmu_path(fmi_version)
    idle = _idle().get(path)
    start = {**_AT_REST, **initial}
    if not idle:
        return Plant(params, fmi_version=fmi_version, fmu_path=path, **start)
    plant = idle.pop()
    try:
        plant.reset(params, **start)
    except BaseException:
        plant.close()
        raise
    return plant


def give_back(plant: Plant) -> None:
    """``plant`` is idle again: the next ``take`` of its FMU in this thread may hand it out. Giving back a plant
    already idle, or closed, does nothing."""
    idle = _idle().setdefault(plant.fmu_path, [])
    if plant.fmu is not None and all(p is not plant for p in idle):
        idle.append(plant)


@contextmanager
def pooled_plant(params: DriveParams, fmi_version: int = 2, **initial: float) -> Iterator[Plant]:
    """``take`` around a ``with`` block: given back after a block that ended normally, closed after any exception
    (it may have stopped in the middle of a call)."""
    plant = take(params, fmi_version, **initial)
    try:
        yield plant
    except BaseException:
        plant.close()
        raise
    give_back(plant)


def _idle() -> dict:
    return _LOCAL.__dict__.setdefault("idle", {})
