"""Simulations already run, kept for the process: a fit that asks for a point that any fit in this process has
simulated (on the same log part, from the same start) gets that trajectory back without running the FMU again.

Why: a diagnosis fits one log many times over, and its fits start where others ended. A candidate's size probes start
on the valley of the refit they probe, a refit starts from the model it extends, a shape's refit from the refit in
the other shape; each problem keeps only its own last few simulations (``OutputError.CACHE``), so each new problem
simulated again the points (and the Jacobian columns around them) that an earlier one had. Measured, one process,
every simulation hashed: 22 % of the 26,553 simulations of a 10 s torque-step diagnosis at 5 kHz (drive 5103, weak
hysteresis, serial) repeated one run before them, 14 % of their FMU time within the last 128 distinct ones; on a 3 s
log with one candidate, 8 % of the simulations within 128. ``MEMO_BYTES`` keeps about 230 training parts of a 10 s
log at 5 kHz.

Why it is exact: a simulation is a function of the FMU, its parameters, the initial state, the torque samples and the
step alone (every one starts with a reset; the FMU keeps no state between resets). The key holds all of them bit for
bit (the parameters' and the start's bytes, not their values: -0.0 and 0.0 stay apart; the torque samples by a
128-bit digest of their bytes), and the FMU's work is kept with the trajectory, so a budget is charged what the
simulation cost when it ran. The same input gives the same answer with and without it, to the last bit; only the
time changes. The trajectories are kept read-only (a caller that wrote into one would change another's).
"""
from __future__ import annotations

import hashlib
import os
import threading
from collections import OrderedDict

import numpy as np

from ..model.params import DriveParams
from ..model.plant import Plant

#: "on": simulations are kept and looked up; "off": every simulation runs (the tests' comparison)
MODE = "on"
#: the memory the kept trajectories may hold in one process (16 bytes per sample: q_m and q_l)
MEMO_BYTES = 128 * 2 ** 20

#: a simulation's (q_m, q_l) [rad] at the start and after every step, and the FMU's model evaluations for it
Kept = tuple[np.ndarray, np.ndarray, float]

_KEPT: "OrderedDict[bytes, Kept]" = OrderedDict()
_SIZE = [0]
_HITS = [0]
_LOCK = threading.Lock()


def digest(torque: np.ndarray) -> bytes:
    """The key of a torque sequence [N m]: its length and a 128-bit digest of its bytes."""
    data = np.ascontiguousarray(torque, dtype=float)
    return data.size.to_bytes(8, "little") + hashlib.blake2b(data.tobytes(), digest_size=16).digest()


def positions(plant: Plant, params: DriveParams, initial: dict[str, float], torque: np.ndarray, torque_key: bytes,
              dt: float) -> Kept:
    """``plant`` reset to ``params`` and ``initial`` (every initial state, by name), then ``torque`` held over steps
    of ``dt`` [s]: (q_m, q_l, the FMU's work), kept or run now. ``torque_key`` is ``digest(torque)``, made once per
    log part by the caller rather than once per simulation."""
    key = _key(plant, params, initial, torque_key, dt) if MODE == "on" else None
    if key is not None:
        with _LOCK:
            kept = _KEPT.get(key)
            if kept is not None:
                _KEPT.move_to_end(key)
                _HITS[0] += 1
                return kept
    plant.reset(params, **initial)
    q_m, q_l = plant.positions(torque, dt)
    out = (q_m, q_l, plant.model_evaluations())
    if key is not None:
        _keep(key, out)
    return out


def hits() -> int:
    """Simulations found kept in this process (the tests' evidence that the memo served some)."""
    with _LOCK:
        return _HITS[0]


def forget() -> None:
    """Drop every kept simulation (the tests compare runs with and without; nothing else needs it)."""
    with _LOCK:
        _KEPT.clear()
        _SIZE[0] = 0


def _key(plant: Plant, params: DriveParams, initial: dict[str, float], torque_key: bytes, dt: float) -> bytes:
    start = sorted(initial.items())
    head = f"{plant.fmu_path}|{plant.fmi_version}|{','.join(k for k, _ in start)}|".encode()
    values = np.array([*params.to_dict().values(), *(v for _, v in start), dt], dtype=float)
    return head + values.tobytes() + torque_key


def _keep(key: bytes, out: Kept) -> None:
    q_m, q_l, _ = out
    size = q_m.nbytes + q_l.nbytes
    if size > MEMO_BYTES:
        return
    q_m.setflags(write=False)
    q_l.setflags(write=False)
    with _LOCK:
        if key in _KEPT:
            return
        _KEPT[key] = out
        _SIZE[0] += size
        while _SIZE[0] > MEMO_BYTES:
            _, (a, b, _) = _KEPT.popitem(last=False)
            _SIZE[0] -= a.nbytes + b.nbytes


def _after_fork() -> None:
    """In a forked child the lock may have been held by a thread that does not exist there: a new one."""
    global _LOCK
    _LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork)
