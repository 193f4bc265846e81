"""One ``Plant`` per thread and FMU, kept between protocol runs.

With the protocols' loops compiled (``ident.protocols.compiled``), a whole impulse resolution simulates in tens of
milliseconds, and opening a new ``Plant`` (unpacking the FMU, parsing its modelDescription, loading its binary,
~10-20 ms) would be a large part of it, repeated for every drive of a sweep. So the protocols, given drive
parameters, take this thread's plant and ``reset`` it to the drive (an FMU reset re-initialises the instance from
its start values completely: the same results as a new instance, which the tests hold bit for bit).

A plant is taken out of the pool while in use (a nested protocol call opens its own) and goes back only after a
run that ended normally; after any exception it is closed. Unpacked FMUs are removed at exit like any ``Plant``'s.
"""
from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Iterator

from fmu_build.build import default_fmu_path

from ..model.params import DriveParams
from ..model.plant import Plant

__all__ = ["pooled_plant"]

_LOCAL = threading.local()
_BUILDING = threading.Lock()
_ZERO_STATE = dict(q_m_start=0.0, q_l_start=0.0, v_m_start=0.0, v_l_start=0.0)


@contextmanager
def pooled_plant(params: DriveParams, fmi_version: int) -> Iterator[Plant]:
    """This thread's Plant of the default FMU of ``fmi_version``, reset to ``params`` at rest with zero
    deflection (a new one if the pool has none)."""
    with _BUILDING:   # the FMU cache stages a build under a per-process name: one builder per process
        path = default_fmu_path(fmi_version)   # keyed by path: a rebuilt FMU (changed sources) is a new plant
    plants: dict = _LOCAL.__dict__.setdefault("plants", {})
    plant = plants.pop(path, None)
    if plant is None:
        plant = Plant(params, fmi_version=fmi_version, fmu_path=path, **_ZERO_STATE)
    else:
        try:
            plant.reset(params, **_ZERO_STATE)
        except BaseException:
            plant.close()
            raise
    try:
        yield plant
    except BaseException:
        plant.close()
        raise
    plants[path] = plant
