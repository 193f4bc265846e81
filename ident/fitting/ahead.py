"""Simulations run ahead on the second core: the points of a finite-difference Jacobian, a grid or a scan, half of
them on a second FMU instance in one helper thread, before the fit asks for them one by one.

Why: a fit in the main process runs alone. The base fit of a diagnosis runs before any worker has work (measured
on a 10 s torque-step log at 5 kHz with a hidden kinematic error, two workers: the base fit took 91 s of the 141 s
the diagnosis took, on one of the two cores), and so do ``hdrive identify`` and the diagnosis's serial steps. Most
of a fit's simulations are independent of each other: the 2n of a central-difference Jacobian, the points of a grid.

Why it is exact: a simulation is a function of its point alone (every one starts with a reset of the FMU, whose
doStep ignores the time it is called at; the FMU keeps no state between instances), so the helper's result for a
point is the one the fit's own instance would give, to the last bit. The results wait (``OutputError.ahead``) until
the fit asks for each point in its own order, and only then go through the cache, the budget's check and charge
and every count, exactly as if simulated then: the same input gives the same answer with and without the helper,
on any machine and under any load. A point the budget would have refused is simulated for nothing, never used.

Why a thread and not a process: the simulations run in C with the GIL released (ctypes), so a thread gets the
second core without copying the log to another process; IPOPT itself (whose linear solver is not thread-safe) runs
only in the calling thread. A Dask worker's task uses it too, when a core is idle (``idle_core``): the last refits
of a diagnosis step run while the other workers wait for the next step. Never the helper's own thread (it would
wait on itself).
"""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

import numpy as np

from ..model.params import DriveParams
from ..model.plant import Plant

#: "auto": the helper runs when a core is idle (``idle_core``); "on": whenever there are two cores; "off": never
MODE = "auto"
CORES = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
#: windows shorter than this many samples are simulated in the calling thread: each simulation also spends about
#: 0.2-0.3 ms in Python (parameters, reset), holding the GIL, about as long as a short window's simulation in C
MIN_SAMPLES = 2000

#: the memory a block of points run ahead may hold (``block``): a simulation's output is 16 bytes per sample
BLOCK_BYTES = 64 * 2 ** 20
#: a point's (simulation output, the FMU's work for it, the error it raised)
Result = tuple[Any, "float | None", "Exception | None"]
#: a point's simulation on a given FMU instance: (its output, the FMU's work for it)
Simulate = Callable[[np.ndarray, Plant], "tuple[Any, float | None]"]
_PREFIX = "hdrive-ahead"


class _Helper:
    """The helper thread and its own FMU instance (made in that thread on first use, kept for the process)."""

    def __init__(self) -> None:
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=_PREFIX)
        self.plant: Plant | None = None

    def plant_for(self, base: DriveParams) -> Plant:
        if self.plant is None:
            self.plant = Plant(base)
        return self.plant


_HELPER: _Helper | None = None
_LOCK = threading.Lock()
_COUNT = [0]


def usable(samples: int, points: int) -> bool:
    """Whether running ``points`` simulations of ``samples`` samples ahead can save time here."""
    if MODE == "off" or CORES < 2 or points < 2 or samples < MIN_SAMPLES:
        return False
    return not threading.current_thread().name.startswith(_PREFIX) and (MODE == "on" or idle_core())


def block(samples: int, most: int = 32) -> int:
    """How many points of a grid to run ahead at a time: ``most``, fewer where their outputs would hold more than
    ``BLOCK_BYTES`` (a long window), never fewer than two."""
    return max(2, min(most, BLOCK_BYTES // (16 * max(samples, 1))))


def idle_core() -> bool:
    """Whether a core is idle at this instant: fewer threads ready to run than cores, this one included (Linux's
    /proc/loadavg; elsewhere the one-minute load average under ``CORES`` - 1). Why: the helper costs about 9 % more
    CPU than the fit alone (measured: 95.5 s of CPU for 65.5 s of wall against 87.3 s alone, a 10 s torque-step log);
    where every core is busy (the test run's two processes, a loaded machine) that CPU is taken from the other
    work. Only the speed depends on it, never a result."""
    try:
        with open("/proc/loadavg") as f:
            running = int(f.read().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):
        return os.getloadavg()[0] < CORES - 1
    return running < CORES


def helped() -> int:
    """Simulations the helper thread has run in this process (the tests' evidence that it ran)."""
    return _COUNT[0]


def run_ahead(simulate: Simulate, own: Plant, base: DriveParams, points: list[np.ndarray],
              stop: Callable[[], bool]) -> dict[bytes, Result]:
    """Every point's ``Result`` by its bytes: every other point on the helper's instance in its thread, the rest on
    ``own`` here. ``stop()`` true (an interrupt) ends both at the next point; an exception here (Ctrl-C) stops the
    helper after the simulation it is in and is raised at once."""
    helper = _helper()
    cancel = threading.Event()
    theirs = helper.pool.submit(_run_helper, helper, simulate, base, points[1::2],
                                lambda: cancel.is_set() or stop())
    try:
        out = _run(simulate, own, points[0::2], stop)
        out.update(theirs.result())
    except BaseException:
        cancel.set()
        raise
    return out


def _helper() -> _Helper:
    global _HELPER
    with _LOCK:
        if _HELPER is None:
            _HELPER = _Helper()
        return _HELPER


def _forget() -> None:
    """In a forked child the helper's thread does not exist: a new one is made on first use."""
    global _HELPER, _LOCK
    _HELPER, _LOCK = None, threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget)


def _run_helper(helper: _Helper, simulate: Simulate, base: DriveParams, points: list[np.ndarray],
                stop: Callable[[], bool]) -> dict[bytes, Result]:
    out = _run(simulate, helper.plant_for(base), points, stop)
    _COUNT[0] += len(out)
    return out


def _run(simulate: Simulate, plant: Plant, points: list[np.ndarray], stop: Callable[[], bool]
         ) -> dict[bytes, Result]:
    out: dict[bytes, Result] = {}
    for theta in points:
        if stop():
            break
        try:
            done, work = simulate(theta, plant)
            out[theta.tobytes()] = (done, work, None)
        except Exception as exc:  # noqa: BLE001 - raised where the fit asks for this point, as it would have been
            out[theta.tobytes()] = (None, None, exc)
    return out
