"""A seeded, randomized FMI-call harness for HarmonicDrive.fmu (FMI 2.0 and 3.0), run by ``test_fmi_harness.py``.

It calls the FMU's C functions directly (ctypes, no fmpy wrapper in between, so any argument can be passed) in
random sequences: instantiate / free, parameters in and out of range (NaN, infinities, the range edges), setup and
initialization (non-finite start times too), doStep with degenerate sizes (0, subnormal, huge, negative, NaN,
infinite), outputs, FMU state get / set / serialize / deserialize - also corrupted, truncated and extended bytes -,
status getters, debug logging with valid and unknown categories, reset, terminate, with and without effects.

A model of the FMI state machine (``Tracker``) says which statuses each call may return: OK where the call is
allowed and its arguments valid, Discard for a value outside its range, Error for a call the state does not allow
or an argument it cannot take (after which only reset, free, state functions, getters and debug logging are
allowed). Asserted for every call: a legal status; finite outputs after OK; a log message that names the problem
after every Error; CPU time within ``CPU_BOUND_S``; and for every doStep the FMU's own count of model evaluations
(log category ``logSteps``) within its work budget - the deterministic bound behind the CPU bound. Crashes and
sanitizer reports end the process, which the test sees.

    python3 -m tests.fmi_harness --fmi 2 --effects --seed 1 --calls 300     # prints a JSON summary
"""
from __future__ import annotations

import argparse
import ctypes as C
import json
import math
import re
import shutil
import sys
import tempfile
import time
import zipfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fmu_build import build_fmu
from fmu_build import variables as V

OK, WARNING, DISCARD, ERROR = 0, 1, 2, 3
INST, INIT, STEP, TERM, ERR = range(5)
CPU_BOUND_S = 1.0  # the bound for one call; the FMU's work budget keeps doStep near 0.3 s at worst
REAL_PARAMS = [v for v in V.PARAMETERS if v.type == "Real"]
EFFECT_PARAMS = [v for v in REAL_PARAMS if v.vr >= 100]
OUT_REALS = [v.vr for v in V.OUTPUTS if v.type == "Real"]
STEPS = (0.0, -0.0, 5e-324, 1e-300, 1e-12, 1e-6, 1e-4, 1e-3, 1e-2, 0.1, 1.0, 1e3, 1e20, 1.7e308, -1e-3, -math.inf,
         math.inf, math.nan)


# ------------------------------------------------------------------------------------------ ctypes bindings ---

class _Fmi2Callbacks(C.Structure):
    _fields_ = [("logger", C.CFUNCTYPE(None, C.c_void_p, C.c_char_p, C.c_int, C.c_char_p, C.c_char_p)),
                ("allocateMemory", C.CFUNCTYPE(C.c_void_p, C.c_size_t, C.c_size_t)),
                ("freeMemory", C.CFUNCTYPE(None, C.c_void_p)),
                ("stepFinished", C.c_void_p), ("componentEnvironment", C.c_void_p)]


def _load(fmu: Path, fmi: int, tmp: Path) -> tuple[C.CDLL, str]:
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(tmp)
        xml = zf.read("modelDescription.xml").decode()
    token = re.search(r'(?:guid|instantiationToken)="([^"]+)"', xml).group(1)
    binary = next((tmp / "binaries").rglob(f"{V.MODEL_IDENTIFIER}.so"))
    return C.CDLL(str(binary)), token


class Api:
    """The FMU's functions for one FMI version behind one interface; every method returns the FMI status."""

    def __init__(self, fmu: Path, fmi: int, tmp: Path) -> None:
        self.fmi, self.lib = fmi, None
        self.lib, self.token = _load(fmu, fmi, tmp)
        self.p = "fmi2" if fmi == 2 else "fmi3"
        self.log: list[tuple[int, str, str]] = []
        if fmi == 2:
            from fmpy import calloc, free
            self._cb = _Fmi2Callbacks(_Fmi2Callbacks._fields_[0][1](self._log2),
                                      _Fmi2Callbacks._fields_[1][1](calloc), _Fmi2Callbacks._fields_[2][1](free),
                                      None, None)
        else:
            self._cb = C.CFUNCTYPE(None, C.c_void_p, C.c_int, C.c_char_p, C.c_char_p)(self._log3)
        self.fn("InstantiateCoSimulation" if fmi == 3 else "Instantiate").restype = C.c_void_p

    def _log2(self, env, name, status, category, message):  # noqa: ANN001 - ctypes callback
        self.log.append((status, category.decode(), message.decode("utf-8", "replace").replace("%%", "%")))

    def _log3(self, env, status, category, message):  # noqa: ANN001 - ctypes callback
        self.log.append((status, category.decode(), message.decode("utf-8", "replace")))

    def fn(self, name: str):
        return getattr(self.lib, self.p + name)

    def instantiate(self, logging: bool) -> int | None:
        if self.fmi == 2:
            return self.fn("Instantiate")(b"fuzz", 1, self.token.encode(), None, C.byref(self._cb), 0, int(logging))
        return self.fn("InstantiateCoSimulation")(b"fuzz", self.token.encode(), None, C.c_bool(False),
                                                  C.c_bool(logging), C.c_bool(False), C.c_bool(False), None,
                                                  C.c_size_t(0), None, self._cb, None)

    def reals(self, c, vrs, values=None, n_values=None):
        n = len(vrs)
        buf = (C.c_double * max(n, 1))(*(values or []))
        args = [C.c_void_p(c), (C.c_uint32 * max(n, 1))(*vrs), C.c_size_t(n), buf]
        if self.fmi == 3:
            args.append(C.c_size_t(n if n_values is None else n_values))
        status = self.fn(("Set" if values is not None else "Get") + ("Real" if self.fmi == 2 else "Float64"))(*args)
        return status, list(buf)[:n]

    def set_int(self, c, vr: int, value: int) -> int:
        args = [C.c_void_p(c), (C.c_uint32 * 1)(vr), C.c_size_t(1), (C.c_int32 * 1)(value)]
        return self.fn("SetInteger" if self.fmi == 2 else "SetInt32")(*(args + ([C.c_size_t(1)] if self.fmi == 3 else [])))

    def do_step(self, c, t: float, h: float) -> int:
        if self.fmi == 2:
            return self.fn("DoStep")(C.c_void_p(c), C.c_double(t), C.c_double(h), 1)
        flags = [C.c_bool() for _ in range(3)]
        last = C.c_double()
        return self.fn("DoStep")(C.c_void_p(c), C.c_double(t), C.c_double(h), C.c_bool(True),
                                 *map(C.byref, flags), C.byref(last))

    def enter_init(self, c, start: float) -> tuple[int, ...]:
        """FMI 2: SetupExperiment then EnterInitializationMode (two statuses); FMI 3: EnterInitializationMode."""
        if self.fmi == 2:
            s = self.fn("SetupExperiment")(C.c_void_p(c), 0, C.c_double(0.0), C.c_double(start), 0, C.c_double(0.0))
            return s, (self.fn("EnterInitializationMode")(C.c_void_p(c)) if s == OK else None)
        return (self.fn("EnterInitializationMode")(C.c_void_p(c), C.c_bool(False), C.c_double(0.0), C.c_double(start),
                                                   C.c_bool(False), C.c_double(0.0)),)

    def simple(self, c, name: str) -> int:
        return self.fn(name)(C.c_void_p(c))

    def debug_logging(self, c, on: bool, cats: list[str]) -> int:
        arr = (C.c_char_p * max(len(cats), 1))(*(x.encode() for x in cats))
        return self.fn("SetDebugLogging")(C.c_void_p(c), int(on) if self.fmi == 2 else C.c_bool(on),
                                          C.c_size_t(len(cats)), arr)

    def get_state(self, c) -> tuple[int, C.c_void_p]:
        h = C.c_void_p()
        return self.fn("GetFMUstate" if self.fmi == 2 else "GetFMUState")(C.c_void_p(c), C.byref(h)), h

    def set_state(self, c, h: C.c_void_p) -> int:
        return self.fn("SetFMUstate" if self.fmi == 2 else "SetFMUState")(C.c_void_p(c), h)

    def free_state(self, c, h: C.c_void_p) -> int:
        return self.fn("FreeFMUstate" if self.fmi == 2 else "FreeFMUState")(C.c_void_p(c), C.byref(h))

    def serialize(self, c, h: C.c_void_p) -> tuple[int, bytes]:
        size = C.c_size_t()
        sfx = "FMUstate" if self.fmi == 2 else "FMUState"
        s = self.fn(f"Serialized{sfx}Size")(C.c_void_p(c), h, C.byref(size))
        if s != OK:
            return s, b""
        buf = C.create_string_buffer(size.value)
        return self.fn(f"Serialize{sfx}")(C.c_void_p(c), h, buf, size), buf.raw

    def deserialize(self, c, data: bytes) -> tuple[int, C.c_void_p]:
        h = C.c_void_p()
        name = "DeSerializeFMUstate" if self.fmi == 2 else "DeserializeFMUState"
        return self.fn(name)(C.c_void_p(c), C.create_string_buffer(data, len(data)), C.c_size_t(len(data)),
                             C.byref(h)), h

    def status_getter(self, c, kind: str, which: int) -> int:
        out = {"Status": C.c_int(), "RealStatus": C.c_double(), "IntegerStatus": C.c_int(),
               "BooleanStatus": C.c_int(), "StringStatus": C.c_char_p()}[kind]
        return self.fn("Get" + kind)(C.c_void_p(c), C.c_int(which), C.byref(out))


# ------------------------------------------------------------------------------------------ the harness ------

@dataclass
class Summary:
    fmi: int
    effects: bool
    seed: int
    calls: int = 0
    by_call: Counter = field(default_factory=Counter)
    statuses: Counter = field(default_factory=Counter)
    worst_cpu_s: float = 0.0
    worst_call: str = ""
    worst_step_work: int = 0
    steps_ok: int = 0
    steps_refused: int = 0
    states_rejected: int = 0

    def to_dict(self) -> dict:
        out = {k: v for k, v in vars(self).items() if not isinstance(v, Counter)}
        return {**out, "by_call": dict(self.by_call), "statuses": {str(k): n for k, n in self.statuses.items()}}


class Harness:
    """One FMU instance driven by random calls; ``tracker`` phase, ``known`` False after an unchecked state."""

    def __init__(self, api: Api, rng: np.random.Generator, effects: bool, summary: Summary) -> None:
        self.api, self.rng, self.effects, self.s = api, rng, effects, summary
        self.c: int | None = None
        self.phase, self.known, self.time = INST, True, 0.0
        self.saved: list[tuple[bytes, int]] = []  # serialized states and the phase they were taken in

    # -- bookkeeping ------------------------------------------------------------------------------------------
    def call(self, name: str, fn, *args):
        self.api.log.clear()
        t0 = time.process_time()
        result = fn(*args)
        cpu = time.process_time() - t0
        self.s.calls += 1
        self.s.by_call[name] += 1
        if cpu > self.s.worst_cpu_s:
            self.s.worst_cpu_s, self.s.worst_call = cpu, name
        assert cpu <= CPU_BOUND_S, f"{name}{args[1:]} took {cpu:.3f} s of CPU (bound {CPU_BOUND_S} s)"
        return result

    def expect(self, name: str, status: int, allowed: set[int]) -> int:
        self.s.statuses[status] += 1
        if not self.known:
            allowed = allowed | {OK, DISCARD, ERROR}
        assert status in allowed, f"{name}: status {status}, expected one of {sorted(allowed)}; log {self.api.log}"
        if status == ERROR:
            assert any(s == ERROR and msg for s, _, msg in self.api.log) or not self.logging_errors, \
                f"{name} returned Error without a message"
            self.phase = ERR
        return status

    logging_errors = True  # errors are logged unless a random SetDebugLogging switched them off

    def allowed_in(self, *phases: int) -> bool:
        return self.phase in phases

    # -- calls ------------------------------------------------------------------------------------------------
    def instantiate(self) -> None:
        if self.c is not None:
            self.call("free", self.api.fn("FreeInstance"), C.c_void_p(self.c))
        self.c = self.call("instantiate", self.api.instantiate, True)
        assert self.c, f"instantiation failed: {self.api.log}"
        self.phase, self.known, self.time, self.logging_errors = INST, True, 0.0, True
        self.api.debug_logging(self.c, True, [])  # all categories: logSteps reports each step's work

    def set_param(self) -> None:
        if self.rng.random() < 0.1:
            return self.set_counts()
        var = EFFECT_PARAMS[self.rng.integers(len(EFFECT_PARAMS))] if self.effects and self.rng.random() < 0.5 \
            else REAL_PARAMS[self.rng.integers(len(REAL_PARAMS))]
        value, valid = self.param_value(var)
        status, _ = self.call("set_param", self.api.reals, self.c, [var.vr], [value])
        ok_phase = self.allowed_in(INST, INIT)
        self.expect("set_param", status, ({OK} if valid else {DISCARD}) if ok_phase else {ERROR})
        return None

    def set_counts(self) -> None:
        value = int(self.rng.choice([0, -5, 1, 12566, 2**31 - 1, -2**31]))
        status = self.call("set_param", self.api.set_int, self.c, V.BY_NAME["encoder_counts_per_rev"].vr, value)
        legal = ({OK} if value >= 1 else {DISCARD}) if self.allowed_in(INST, INIT) else {ERROR}
        self.expect("set_param", status, legal)

    def param_value(self, var: V.Variable) -> tuple[float, bool]:
        u = self.rng.random()
        if u < 0.12:
            return float(self.rng.choice([math.nan, math.inf, -math.inf, var.lo - abs(var.lo) - 1.0, var.hi * 10 + 1])), False
        if u < 0.2:
            return float(self.rng.choice([var.lo, var.hi])), True  # the range edges: the most extreme physics
        if var.name.endswith("_start"):
            return float(self.rng.uniform(-1, 1) * 10 ** self.rng.uniform(-6, 0)), True
        lo, hi = max(var.lo, 1e-12), var.hi
        if var.lo < 0:
            return float(self.rng.uniform(var.lo, var.hi)), True
        return float(min(hi, max(var.lo, 10 ** self.rng.uniform(math.log10(lo), math.log10(min(hi, 1e6)))))), True

    def set_torque(self) -> None:
        value = float(self.rng.choice([math.nan, math.inf, 2e6])) if self.rng.random() < 0.1 else \
            float(self.rng.uniform(-1, 1) * 10 ** self.rng.uniform(-4, 1))
        status, _ = self.call("set_input", self.api.reals, self.c, [V.BY_NAME["motor_torque"].vr], [value])
        valid = math.isfinite(value) and abs(value) <= 1e6
        self.expect("set_input", status, ({OK} if valid else {DISCARD}) if self.allowed_in(INST, INIT, STEP) else {ERROR})

    def initialize(self) -> None:
        """Enter initialization (with a start time, sometimes not finite), or exit it when already in it."""
        if self.phase != INIT or self.rng.random() < 0.1:
            start = float(self.rng.choice([0.0, 0.0, 0.0, 1.5, -3.0, 1e300, math.nan, math.inf, -math.inf]))
            statuses = self.call("enter_init", self.api.enter_init, self.c, start)
            legal = {OK} if self.allowed_in(INST) and math.isfinite(start) else {ERROR}
            self.expect("enter_init", statuses[0], legal)
            if len(statuses) == 2 and statuses[1] is not None:
                self.expect("enter_init", statuses[1], {OK})
            if self.phase == INST and all(s == OK for s in statuses if s is not None):
                self.phase, self.time = INIT, start
            if self.rng.random() < 0.3:
                return
        status = self.call("exit_init", self.api.simple, self.c, "ExitInitializationMode")
        self.expect("exit_init", status, {OK} if self.allowed_in(INIT) else {ERROR})
        if status == OK:
            self.phase = STEP

    def do_step(self) -> None:
        h = float(self.rng.choice(STEPS)) if self.rng.random() < 0.4 else float(10 ** self.rng.uniform(-7, 0))
        stepping = self.phase == STEP and self.known
        status = self.call("do_step", self.api.do_step, self.c, self.time, h)
        valid = math.isfinite(h) and h >= 0
        self.expect("do_step", status, {OK, ERROR} if self.allowed_in(STEP) and valid else {ERROR})
        work = [int(m.group(1)) for _, cat, msg in self.api.log if cat == "logSteps"
                for m in [re.search(r"(\d+) model evaluations \(budget (\d+)\)", msg)] if m
                and int(m.group(1)) <= int(m.group(2))]
        if status == OK:
            self.s.steps_ok += 1
            self.time += h
            if work:
                self.s.worst_step_work = max(self.s.worst_step_work, work[0])
            self.check_outputs()
        elif stepping and valid:
            self.s.steps_refused += 1
            assert any(re.search(r"model evaluations|overflowed|largest double|must not be called", m)
                       for _, _, m in self.api.log) or not self.logging_errors, self.api.log

    def check_outputs(self) -> None:
        status, values = self.call("get_outputs", self.api.reals, self.c, OUT_REALS)
        self.expect("get_outputs", status, {OK})
        assert all(math.isfinite(x) for x in values), f"non-finite output after OK: {values}"

    def get_outputs(self) -> None:
        status, values = self.call("get_outputs", self.api.reals, self.c, OUT_REALS)
        self.expect("get_outputs", status, {OK})
        assert all(math.isfinite(x) for x in values), f"non-finite output: {values}"
        if self.api.fmi == 3 and self.rng.random() < 0.2:  # nValues != nValueReferences: an illegal argument
            status, _ = self.call("get_outputs", self.api.reals, self.c, OUT_REALS[:2], None, 3)
            self.expect("get_outputs", status, {ERROR})

    def save_state(self) -> None:
        status, h = self.call("get_state", self.api.get_state, self.c)
        self.expect("get_state", status, {OK})
        status, data = self.call("serialize", self.api.serialize, self.c, h)
        self.expect("serialize", status, {OK})
        self.expect("free_state", self.call("free_state", self.api.free_state, self.c, h), {OK})
        if self.known:
            self.saved.append((data, self.phase))

    def restore_state(self) -> None:
        if not self.saved:
            return self.save_state()
        data, phase = self.saved[self.rng.integers(len(self.saved))]
        corrupt = self.rng.random() < 0.5
        blob = self.corrupt(data) if corrupt else data
        status, h = self.call("deserialize", self.api.deserialize, self.c, blob)
        if not corrupt or blob == data:
            self.expect("deserialize", status, {OK})
        else:
            self.expect("deserialize", status, {OK, ERROR} if len(blob) == len(data) else {ERROR})
            self.s.states_rejected += status == ERROR
        if status != OK:
            return None
        status = self.call("set_state", self.api.set_state, self.c, h)
        self.expect("set_state", status, {OK})
        self.call("free_state", self.api.free_state, self.c, h)
        self.phase, self.known = phase, blob == data
        return None

    def corrupt(self, data: bytes) -> bytes:
        b = bytearray(data)
        kind = self.rng.integers(5)
        if kind == 0:
            return bytes(b[: self.rng.integers(len(b))])  # truncated
        if kind == 1:
            return bytes(b) + bytes(self.rng.integers(1, 16))  # extended
        if kind == 2:  # a double-sized field overwritten with a hostile value
            off = 16 + 8 * self.rng.integers((len(b) - 24) // 8)
            b[off:off + 8] = np.array([self.rng.choice([math.nan, math.inf, -1.0, 1e300, 5e-324])]).tobytes()
            return bytes(b)
        for _ in range(self.rng.integers(1, 8)):  # random bytes, sometimes in the header
            b[self.rng.integers(0 if kind == 3 else 16, len(b))] = self.rng.integers(256)
        return bytes(b)

    def reset(self) -> None:
        self.expect("reset", self.call("reset", self.api.simple, self.c, "Reset"), {OK})
        self.phase, self.known, self.time = INST, True, 0.0

    def terminate(self) -> None:
        status = self.call("terminate", self.api.simple, self.c, "Terminate")
        self.expect("terminate", status, {OK} if self.allowed_in(STEP) else {ERROR})
        if status == OK:
            self.phase = TERM

    def status_getters(self) -> None:
        if self.api.fmi == 3:
            return self.debug_logging()
        kind = str(self.rng.choice(["Status", "RealStatus", "IntegerStatus", "BooleanStatus", "StringStatus"]))
        which = int(self.rng.integers(4))  # DoStepStatus, PendingStatus, LastSuccessfulTime, Terminated
        status = self.call("status", self.api.status_getter, self.c, kind, which)
        answers = (kind, which) in (("RealStatus", 2), ("BooleanStatus", 3))
        self.expect("status", status, ({OK} if answers else {DISCARD}) if self.allowed_in(STEP, TERM) else {ERROR})
        return None

    def debug_logging(self) -> None:
        names = [c.name for c in V.LOG_CATEGORIES]
        cats = list(self.rng.choice(names + ["noSuchCategory"], size=self.rng.integers(0, 3)))
        status = self.call("debug_logging", self.api.debug_logging, self.c, True, cats)
        self.expect("debug_logging", status, {ERROR} if "noSuchCategory" in cats else {OK})
        if status == OK:  # keep errors and the step reports visible for the checks above
            self.api.debug_logging(self.c, True, [])

    def effects_on(self) -> None:
        for var in EFFECT_PARAMS:
            value, _ = self.param_value(var)
            if math.isfinite(value) and var.lo <= value <= var.hi:
                self.api.reals(self.c, [var.vr], [value])

    # Weights of the actions per phase: mostly what the phase allows, sometimes what it does not.
    ACTIONS = ("set_param", "set_torque", "initialize", "do_step", "get_outputs", "save_state", "restore_state",
               "reset", "terminate", "status_getters", "instantiate")
    WEIGHTS = {INST: (30, 5, 25, 3, 5, 5, 5, 2, 2, 2, 2), INIT: (20, 5, 30, 3, 5, 5, 5, 2, 2, 2, 1),
               STEP: (3, 15, 2, 45, 8, 8, 8, 3, 3, 5, 1), TERM: (2, 2, 2, 5, 10, 5, 20, 20, 2, 10, 5),
               ERR: (2, 2, 2, 5, 10, 5, 30, 30, 2, 3, 5)}

    def run(self, n_calls: int) -> None:
        self.instantiate()
        while self.s.calls < n_calls:
            weights = np.array(self.WEIGHTS[self.phase], dtype=float)
            action = self.ACTIONS[self.rng.choice(len(self.ACTIONS), p=weights / weights.sum())]
            if action in ("reset", "instantiate") and self.effects:
                getattr(self, action)()
                self.effects_on()
            else:
                getattr(self, action)()
        self.call("free", self.api.fn("FreeInstance"), C.c_void_p(self.c))


def run(fmi: int, effects: bool, seed: int, n_calls: int, fmu: Path | None = None) -> Summary:
    """Run the harness on the FMU of ``fmi`` (the cached build; the sanitizer build with HDRIVE_SANITIZE=1)."""
    summary = Summary(fmi, effects, seed)
    tmp = Path(tempfile.mkdtemp(prefix="hdrive-harness-"))
    try:
        api = Api(fmu or build_fmu(fmi_version=fmi), fmi, tmp)
        Harness(api, np.random.default_rng(seed), effects, summary).run(n_calls)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fmi", type=int, choices=(2, 3), default=2)
    parser.add_argument("--effects", action="store_true")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--calls", type=int, default=300)
    args = parser.parse_args(argv)
    summary = run(args.fmi, args.effects, args.seed, args.calls)
    print(json.dumps(summary.to_dict()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
