"""``Plant``: the HarmonicDrive FMU driven through fmpy (the only module of hdrive that talks to fmpy).

The FMU is loaded once; ``reset()`` re-initialises it (optionally with new parameters) without reloading. The
per-step path calls the FMU's C functions directly with preallocated buffers, because a closed control loop at
1 kHz calls it hundreds of thousands of times.
"""
from __future__ import annotations

import atexit
import ctypes
import shutil
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, NamedTuple, NoReturn, Sequence

import numpy as np
import pandas as pd

from fmu_build import variables as V
from fmu_build.build import default_fmu_path

from ..common.scratch import owned_dir, remove_orphaned
from ..common.workdir import kept_working_directory
from .params import FIELD_NAMES, DriveParams, ParameterError, check_parameter

_RUNNER: ctypes.CDLL | None = None
_UNPACKED: set[str] = set()   # folders of unpacked FMUs still in use: removed at exit even if a plant was not closed
#: one modelDescription read at a time in a process: fmpy checks it against the FMI XML schema, and libxml2 sets up its
#: schema types lazily, on a process's first schema parse, without a lock (KWARC/rust-libxml#159 guards the same
#: call). Two threads opening their first plants at once (the lanes of a sweep) could then fail the parse: seen twice
#: in CI as "Document is not valid XML Schema", a sweep that exited 2 at its start. The read takes about 4 ms.
_READING = threading.Lock()


#: an unpacked FMU's folder: this prefix, then the process id and the host's tag, then mkdtemp's suffix (``owned_dir``)
_UNPACK_PREFIX = "hdrive-fmu-"


@atexit.register
def remove_unpacked_fmus() -> None:
    """Remove the folders of unpacked FMUs still in use (at exit, and before a fast exit that skips ``atexit``)."""
    for folder in list(_UNPACKED):
        shutil.rmtree(folder, ignore_errors=True)


def remove_orphaned_fmus(root: str | Path | None = None) -> list[Path]:
    """Remove the folders of unpacked FMUs (under ``root``, default the temporary folder) whose process is gone, made
    on this host; return them (``ident.common.scratch``). Each plant calls it before unpacking its own."""
    return remove_orphaned(_UNPACK_PREFIX, root)


def _runner() -> ctypes.CDLL:
    """The compiled stepping loop, built and loaded once per process."""
    global _RUNNER
    if _RUNNER is None:
        from fmu_build.build import build_runner

        lib = ctypes.CDLL(str(build_runner()))
        for name in ("hd_run_fmi2", "hd_run_fmi3"):
            fn = getattr(lib, name)
            fn.restype = ctypes.c_long
            fn.argtypes = [ctypes.c_void_p] * 4 + [ctypes.c_uint32, ctypes.POINTER(ctypes.c_uint32), ctypes.c_size_t,
                                                   ctypes.POINTER(ctypes.c_double), ctypes.c_size_t, ctypes.c_double,
                                                   ctypes.c_double, ctypes.POINTER(ctypes.c_double)]
        _RUNNER = lib
    return _RUNNER


class PlantError(RuntimeError):
    """The FMU rejected a call; the message is the FMU's own log message (it names the variable and range)."""


class SettleError(PlantError):
    """The plant did not come to a final rest within the allowed time (e.g. a limit cycle)."""


class Sample(NamedTuple):
    """Outputs of the plant at one communication point (SI)."""

    time: float           # s
    q_m: float            # rad
    q_l: float            # rad
    v_m: float            # rad/s
    v_l: float            # rad/s
    spring_torque: float  # N m
    arm_position: float   # m
    encoder_count: int    # counts
    motor_stuck: bool
    load_stuck: bool

    @property
    def at_rest(self) -> bool:
        """Both bodies stuck: with zero torque nothing can move again."""
        return self.motor_stuck and self.load_stuck


# Column names of output tables: SI units in the names.
COLUMN_UNITS = {"time": "time_s", "q_m": "q_m_rad", "q_l": "q_l_rad", "v_m": "v_m_rad_s", "v_l": "v_l_rad_s",
                "spring_torque": "spring_torque_Nm", "arm_position": "arm_position_m",
                "motor_torque": "motor_torque_Nm"}

_REAL_OUTPUTS = ("q_m", "q_l", "v_m", "v_l", "spring_torque", "arm_position", "input_work", "friction_work",
                 "deflection", "hysteresis_state", "motor_friction_torque", "load_friction_torque")
_INITIAL_STATE = ("q_m_start", "q_l_start", "v_m_start", "v_l_start")


@dataclass(frozen=True)
class PlantState:
    """An opaque snapshot of the FMU (``Plant.save_state``); also serializable with ``bytes(state)``."""

    data: bytes
    time: float
    fmi_version: int

    def __bytes__(self) -> bytes:
        return self.data


class Plant:
    """The harmonic-drive plant FMU.

    Parameters
    ----------
    params:
        SI drive parameters (``DriveParams``); the nominal drive by default. Non-dimensional form:
        ``DriveParams.from_nondim(K_star, J_l_star, f_l_star, J_m=..., f_m=...)``.
    fmi_version:
        2 or 3: which of the two FMUs to load.
    fmu_path:
        An explicit HarmonicDrive.fmu; by default the one built (and cached) from this project's C sources.
    initial:
        Initial state: any of ``q_m_start, q_l_start`` [rad], ``v_m_start, v_l_start`` [rad/s].
    """

    def __init__(self, params: DriveParams | None = None, *, fmi_version: int = 2,
                 fmu_path: str | Path | None = None, **initial: float) -> None:
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave
        from fmpy.fmi3 import FMU3Slave

        path = Path(fmu_path) if fmu_path is not None else default_fmu_path(fmi_version)
        self.fmu_path = path
        self._fmu = None
        try:  # a damaged FMU file: a named error, not a traceback from deep inside zipfile or ctypes
            with _READING:
                self.model_description = read_model_description(str(path))
            self.fmi_version = int(self.model_description.fmiVersion[0])
        except Exception as exc:
            raise PlantError(f"cannot read the FMU {path}: {exc}") from None
        remove_orphaned_fmus()
        self._unzipdir = owned_dir(_UNPACK_PREFIX)
        _UNPACKED.add(self._unzipdir)
        kwargs = dict(guid=self.model_description.guid, unzipDirectory=self._unzipdir,
                      modelIdentifier=self.model_description.coSimulation.modelIdentifier, instanceName="plant")
        self._messages: list[str] = []
        try:
            extract(str(path), unzipdir=self._unzipdir)
            with kept_working_directory():  # fmpy switches it to the library's folder while it loads the library
                self._fmu = (FMU2Slave if self.fmi_version == 2 else FMU3Slave)(**kwargs)
            # loggingOn: the FMU then reports why it refuses a call (FMI 3 logs nothing at all without it).
            if self.fmi_version == 2:
                self._fmu.instantiate(callbacks=self._fmi2_callbacks(), loggingOn=True)
            else:
                self._fmu.instantiate(loggingOn=True, logMessage=self._fmi3_log)
        except Exception as exc:
            shutil.rmtree(self._unzipdir, ignore_errors=True)
            self._fmu = None
            raise PlantError(f"cannot load the FMU {path}: {exc}") from None
        self._bind_fast_path()
        self._params = params if params is not None else DriveParams()
        self._initial = {k: 0.0 for k in _INITIAL_STATE}
        self.reset(self._params, **initial)

    # -- logging and error handling --------------------------------------------------------------------------
    def _fmi2_callbacks(self) -> Any:
        from fmpy import calloc, free
        from fmpy.fmi2 import (
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
        )

        def log(env, name, status, category, message):  # noqa: ANN001 - ctypes callback
            self._messages.append(message.decode("utf-8", "replace").replace("%%", "%"))

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(log)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._callbacks = cb  # keep alive
        return cb

    def _fmi3_log(self, env, status, category, message) -> None:  # noqa: ANN001 - ctypes callback
        self._messages.append(message.decode("utf-8", "replace"))

    def _raise(self, what: str) -> None:
        detail = self._messages[-1] if self._messages else "no message from the FMU"
        self._messages.clear()
        raise PlantError(f"{what} failed: {detail}")

    def raise_fmu_error(self, what: str) -> NoReturn:
        """Raise ``PlantError("<what> failed: <the FMU's last log message>")``, as ``step`` does when the FMU refuses
        a call: for loops below ``Plant`` (over ``fmi_functions``) that must report a refusal in the same words."""
        self._raise(what)
        raise AssertionError("unreachable")  # pragma: no cover

    # -- fast per-step path -----------------------------------------------------------------------------------
    def _bind_fast_path(self) -> None:
        f = self._fmu._functions
        vr = {v.name: v.vr for v in V.VARIABLES}
        self._vr = vr
        n = len(_REAL_OUTPUTS)
        self._in_vr = (ctypes.c_uint32 * 1)(vr["motor_torque"])
        self._in_val = (ctypes.c_double * 1)()
        self._out_vr = (ctypes.c_uint32 * n)(*(vr[k] for k in _REAL_OUTPUTS))
        self._out = (ctypes.c_double * n)()
        self._int_vr = (ctypes.c_uint32 * 1)(vr["encoder_count"])
        self._int = (ctypes.c_int32 * 1)()
        self._bool_vr = (ctypes.c_uint32 * 2)(vr["motor_stuck"], vr["load_stuck"])
        self._bind_start_values(vr)
        self._outputs_cache: dict[tuple[str, ...], tuple[Any, Any]] = {}
        self._loop: tuple[Any, list[Any]] | None = None
        c = self._fmu.component
        if self.fmi_version == 2:
            self._bool = (ctypes.c_int * 2)()
            set_real, do_step = f["fmi2SetReal"], f["fmi2DoStep"]
            get_real, get_int, get_bool = f["fmi2GetReal"], f["fmi2GetInteger"], f["fmi2GetBoolean"]
            self._set_input = lambda: set_real(c, self._in_vr, 1, self._in_val)
            self._do_step = lambda t, h: do_step(c, t, h, 1)
            self._get_outputs = lambda: (get_real(c, self._out_vr, n, self._out)
                                         or get_int(c, self._int_vr, 1, self._int)
                                         or get_bool(c, self._bool_vr, 2, self._bool))
        else:
            self._bool = (ctypes.c_bool * 2)()
            flags = [ctypes.c_bool() for _ in range(3)]
            last = ctypes.c_double()
            refs = [ctypes.byref(x) for x in flags] + [ctypes.byref(last)]
            set_real, do_step = f["fmi3SetFloat64"], f["fmi3DoStep"]
            get_real, get_int, get_bool = f["fmi3GetFloat64"], f["fmi3GetInt32"], f["fmi3GetBoolean"]
            self._set_input = lambda: set_real(c, self._in_vr, 1, self._in_val, 1)
            self._do_step = lambda t, h: do_step(c, t, h, True, *refs)
            self._get_outputs = lambda: (get_real(c, self._out_vr, n, self._out, n)
                                         or get_int(c, self._int_vr, 1, self._int, 1)
                                         or get_bool(c, self._bool_vr, 2, self._bool, 2))

    # -- life cycle ------------------------------------------------------------------------------------------
    @property
    def params(self) -> DriveParams:
        return self._params

    # -- the raw FMI level, for importer-side tests and tools ---------------------------------------------------
    @property
    def fmu(self) -> Any:
        """The fmpy slave object (``fmpy.fmi2.FMU2Slave`` / ``fmpy.fmi3.FMU3Slave``) this plant drives."""
        return self._fmu

    @property
    def fmi_functions(self) -> dict[str, Any]:
        """The FMU's C functions as loaded (ctypes, by FMI name, e.g. ``"fmi2DoStep"``), for calls below ``Plant``."""
        return self._fmu._functions

    @property
    def component(self) -> Any:
        """The FMU instance handle (``fmi2Component`` / ``fmi3Instance``) to pass to ``fmi_functions``."""
        return self._fmu.component

    @property
    def messages(self) -> list[str]:
        """The FMU's log messages since the last error was raised (oldest first; cleared by ``reset``)."""
        return self._messages

    def reset(self, params: DriveParams | None = None, **initial: float) -> Sample:
        """Back to time 0 and the initial state, optionally with new parameters / initial state."""
        for name, value in initial.items():
            if name not in _INITIAL_STATE:
                raise ParameterError(f"unknown initial-state name {name!r}; use one of {', '.join(_INITIAL_STATE)}")
            self._initial[name] = check_parameter(name, value)
        if params is not None:
            if not isinstance(params, DriveParams):
                raise TypeError(f"params must be a DriveParams, got {type(params).__name__}")
            self._params = params
        self._messages.clear()
        try:
            self._fmu.reset()
            self._set_start_values()
            self._initialize()
        except Exception as exc:  # fmpy raises FMICallException; report the FMU's own message
            if isinstance(exc, PlantError):
                raise
            self._raise(f"initializing the plant ({exc})")
        self.time = 0.0
        self.torque = 0.0
        return self.sample()

    def _bind_start_values(self, vr: dict[str, int]) -> None:
        """The calls ``_set_start_values`` makes: every parameter and initial state, by type, in a fixed order, into
        a preallocated array (the values are checked numbers of their type: ``check_parameter``)."""
        from fmpy.fmi1 import FMICallException

        self._call_error = FMICallException
        names = (*FIELD_NAMES, *_INITIAL_STATE)
        self._start: list[tuple[tuple[str, ...], Any, Any, Any, str, int]] = []
        for kind, c_type, fmi2, fmi3 in (("Real", ctypes.c_double, "fmi2SetReal", "fmi3SetFloat64"),
                                         ("Integer", ctypes.c_int32, "fmi2SetInteger", "fmi3SetInt32")):
            chosen = [k for k in names if V.BY_NAME[k].type == kind]
            function = fmi2 if self.fmi_version == 2 else fmi3
            self._start.append((tuple(chosen), (ctypes.c_uint32 * len(chosen))(*(vr[k] for k in chosen)),
                                (c_type * len(chosen))(), self._fmu._functions[function], function, len(chosen)))

    def _set_start_values(self) -> None:
        """Every parameter (``self._params``) and initial state (``self._initial``) into the FMU, one call per type.
        Why not fmpy's ``setReal``: it builds two ctypes arrays per call, and with the value lists (a table lookup per
        name) that was most of a reset's 0.094 ms (0.02-0.04 ms now), beside a short fit window's 0.6 ms simulation
        (a fit resets once per simulation)."""
        values = self._params.to_dict()
        values.update(self._initial)
        c = self._fmu.component
        for names, refs, array, call, name, n in self._start:
            array[:] = [values[k] for k in names]
            status = call(c, refs, n, array) if self.fmi_version == 2 else call(c, refs, n, array, n)
            if status > 1:   # the words fmpy's own call would raise
                raise self._call_error(function=name, status=status)

    def _initialize(self) -> None:
        """Initialization mode at time 0, then out of it (FMI 2 sets up the experiment first)."""
        if self.fmi_version == 2:
            self._fmu.setupExperiment(startTime=0.0)
            self._fmu.enterInitializationMode()
        else:
            self._fmu.enterInitializationMode(startTime=0.0)
        self._fmu.exitInitializationMode()

    def close(self) -> None:
        """Free the FMU instance and its unpacked files."""
        if getattr(self, "_fmu", None) is not None:
            try:
                self._fmu.terminate()
            except Exception:
                pass
            self._fmu.freeInstance()
            self._fmu = None
            shutil.rmtree(self._unzipdir, ignore_errors=True)
            _UNPACKED.discard(self._unzipdir)

    def __enter__(self) -> "Plant":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass

    # -- stepping --------------------------------------------------------------------------------------------
    def step(self, torque: float, dt: float) -> Sample:
        """Hold ``torque`` [N m] for ``dt`` [s] (exact stick-slip inside) and return the outputs at the end."""
        if not (np.isfinite(dt) and dt >= 0):
            # Checked here: the FMU would refuse it with fmiError, after which the standard allows only a reset.
            raise PlantError(f"doStep(t = {self.time} s, dt = {dt!r} s) refused: the communication step size must "
                             "be finite and >= 0")
        self._in_val[0] = torque
        if self._set_input() > 1:
            self._raise(f"setting motor_torque = {torque!r} N.m")
        self.torque = torque
        if self._do_step(self.time, dt) > 1:
            self._raise(f"doStep(t = {self.time} s, dt = {dt!r} s)")
        self.time += dt
        return self.sample()

    def model_evaluations(self) -> float:
        """Evaluations of the model's equations the doSteps did since the last reset (the FMU's local variable
        ``model_evaluations``, the unit of its per-step work budget): what the simulation so far cost, counted the
        same on any machine (the diagnosis's fit budgets are counted in it)."""
        vr = self._vr["model_evaluations"]
        values = self._fmu.getReal([vr]) if self.fmi_version == 2 else self._fmu.getFloat64([vr])
        return float(values[0])

    def sample(self) -> Sample:
        """Outputs at the current communication point."""
        if self._get_outputs() > 1:
            self._raise("reading outputs")
        o = self._out
        return Sample(self.time, o[0], o[1], o[2], o[3], o[4], o[5], self._int[0], bool(self._bool[0]),
                      bool(self._bool[1]))

    def energy(self) -> tuple[float, float]:
        """(input work, friction work) [J] since the last reset, accumulated exactly by the FMU."""
        return self._out[6], self._out[7]

    def run(self, schedule: Iterable[tuple[float, float]] | pd.DataFrame, *, dt: float | None = None) -> pd.DataFrame:
        """Simulate a torque schedule and return a table of outputs at every communication point.

        ``schedule`` is a sequence of ``(torque [N m], duration [s])`` pieces, or a DataFrame with columns
        ``torque_Nm`` and ``duration_s``. With ``dt`` each piece is split into steps of at most ``dt`` seconds
        (the result is the same, exactly; only the sampling of the table changes).
        """
        if isinstance(schedule, pd.DataFrame):
            missing = {"torque_Nm", "duration_s"} - set(schedule.columns)
            if missing:
                raise ValueError(f"schedule DataFrame lacks column(s) {sorted(missing)}")
            pieces = list(zip(schedule["torque_Nm"], schedule["duration_s"]))
        else:
            pieces = list(schedule)
        rows = [self.sample() + (self.torque,)]
        for i, (torque, duration) in enumerate(pieces):
            if not (np.isfinite(torque) and np.isfinite(duration) and duration >= 0):
                raise ValueError(f"schedule piece {i}: torque {torque!r} N.m and duration {duration!r} s must be "
                                 "finite, duration >= 0")
            n = 1 if dt is None else max(1, int(np.ceil(duration / dt - 1e-9)))
            for _ in range(n):
                rows.append(self.step(float(torque), duration / n) + (float(torque),))
        return pd.DataFrame(rows, columns=[*Sample._fields, "motor_torque"]).rename(columns=COLUMN_UNITS)

    def _outputs_arrays(self, outputs: tuple[str, ...]) -> tuple[Any, Any]:
        """(value references, a buffer) for reading ``outputs``, made once per tuple of names (a fit asks for the
        same two outputs every simulation)."""
        arrays = self._outputs_cache.get(outputs)
        if arrays is None:
            m = len(outputs)
            arrays = self._outputs_cache[outputs] = ((ctypes.c_uint32 * m)(*(self._vr[o] for o in outputs)),
                                                     (ctypes.c_double * m)())
        return arrays

    def _run_loop(self) -> tuple[Any, list[Any]]:
        """The compiled loop for this FMI version and its first four arguments (the FMU's set-input, doStep and
        get-output functions and the instance), made once per plant."""
        if self._loop is None:
            f = self._fmu._functions
            names = (("fmi2SetReal", "fmi2DoStep", "fmi2GetReal") if self.fmi_version == 2 else
                     ("fmi3SetFloat64", "fmi3DoStep", "fmi3GetFloat64"))
            ptrs = [ctypes.cast(f[name], ctypes.c_void_p) for name in names]
            run = _runner().hd_run_fmi2 if self.fmi_version == 2 else _runner().hd_run_fmi3
            self._loop = (run, [*ptrs, ctypes.c_void_p(self._fmu.component)])
        return self._loop

    def positions(self, torques: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Hold ``torques[k]`` [N m] over the k-th step of ``dt`` [s]; return (q_m, q_l) [rad] at the start and after
        every step (length len(torques) + 1). The lean loop behind log simulation in identification."""
        out = self.trajectory(torques, dt, ("q_m", "q_l"))
        return out[:, 0], out[:, 1]

    def trajectory(self, torques: np.ndarray, dt: float, outputs: Sequence[str] = ("q_m", "q_l")) -> np.ndarray:
        """Real ``outputs`` at the start and after each of len(torques) steps of ``dt`` [s] holding ``torques[k]``
        [N m]: an array of shape (len(torques) + 1, len(outputs)).

        The per-sample FMI calls (set input, doStep, get outputs) run in a small compiled loop
        (``fmu_build/c/runner.c``) over the FMU's own functions as loaded by fmpy, ~10x faster than Python calls.
        """
        torques = np.ascontiguousarray(torques, dtype=float)
        if not np.all(np.isfinite(torques)):
            k = int(np.flatnonzero(~np.isfinite(torques))[0])
            raise PlantError(f"torque sample {k} is {float(torques[k])!r}: torques must be finite")
        n, m = torques.size, len(outputs)
        unknown = [o for o in outputs if o not in _REAL_OUTPUTS]
        if unknown:
            raise ValueError(f"unknown Real output(s) {unknown}; choose from {', '.join(_REAL_OUTPUTS)}")
        vr, first = self._outputs_arrays(tuple(outputs))
        out = np.empty((n + 1, m))
        get = self._fmu._functions["fmi2GetReal" if self.fmi_version == 2 else "fmi3GetFloat64"]
        if get(self._fmu.component, vr, m, first, *(() if self.fmi_version == 2 else (m,))) > 1:
            self._raise("reading outputs")
        out[0] = first
        if n:
            run, ptrs = self._run_loop()
            failed = run(*ptrs, self._vr["motor_torque"], vr, m,
                         torques.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), n, self.time, dt,
                         out[1:].ctypes.data_as(ctypes.POINTER(ctypes.c_double)))
            if failed:
                self.time += (failed - 1) * dt
                self._raise(f"simulating sample {failed - 1} (torque {float(torques[failed - 1])!r} N.m, dt {dt!r} s)")
            self.time += n * dt
            self.torque = float(torques[-1])
        self.sample()  # refresh the cached outputs of the fast path
        return out

    def run_to_rest(self, dt: float = 1e-3, max_time: float = 60.0) -> Sample:
        """Zero torque until both bodies are stuck; ``SettleError`` if that takes longer than ``max_time`` [s].

        At least one zero-torque step is always taken: a body stuck under a torque need not stay stuck when the
        torque drops to zero, so rest is only trusted after a step with zero torque. Since the FMU is event-exact,
        ``dt`` changes only how often rest is polled, never the state reached."""
        s = self.step(0.0, dt)
        t_end = self.time + max_time
        while not s.at_rest:
            if self.time > t_end:
                raise SettleError(f"the plant did not come to rest within {max_time} s")
            s = self.step(0.0, dt)
        return s

    # -- FMU state -------------------------------------------------------------------------------------------
    def save_state(self) -> PlantState:
        """Snapshot of the complete FMU state (serialized, so it survives pickling and other processes)."""
        fmu = self._fmu
        handle = fmu.getFMUState() if self.fmi_version == 3 else fmu.getFMUstate()
        try:
            data = fmu.serializeFMUState(handle) if self.fmi_version == 3 else fmu.serializeFMUstate(handle)
        finally:
            fmu.freeFMUState(handle) if self.fmi_version == 3 else fmu.freeFMUstate(handle)
        return PlantState(bytes(data), self.time, self.fmi_version)

    def restore_state(self, state: PlantState) -> Sample:
        """Return to a snapshot taken by ``save_state`` on a plant of the same FMU."""
        if state.fmi_version != self.fmi_version:
            raise PlantError(f"state comes from an FMI {state.fmi_version} plant, this is FMI {self.fmi_version}")
        fmu = self._fmu
        try:
            if self.fmi_version == 3:
                handle = fmu.deserializeFMUState(state.data)
                fmu.setFMUState(handle)
                fmu.freeFMUState(handle)
            else:
                handle = fmu.deSerializeFMUstate(state.data)
                fmu.setFMUstate(handle)
                fmu.freeFMUstate(handle)
        except PlantError:
            raise
        except Exception as exc:
            self._raise(f"restoring the FMU state ({exc})")
        self.time = state.time
        return self.sample()
